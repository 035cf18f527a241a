"""observer.fmu, luenberger.fmu and plant.fmu through fmpy's FMU2Slave.

Every FMU result is compared with an independent computation: the in-process numpy runtime
stepped the same way, a second run of the FMU, or the modelDescription parsed here.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import fhobs
import numpy as np
import pytest
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import SCHEMES, FilteringObserver, LuenbergerObserver
from fmpy.validation import validate_fmu
from fmu_fixtures import (
    NOISE_AMPLITUDE,
    NOISE_SEED,
    PENDULUM_X0,
    H,
    assert_error,
    names,
    random_walk,
    steps_until_error,
)

# the session fixtures this module uses, made visible to pytest here

DT = 1e-3  # communication step: 20 internal steps of H
STEPS = 120


def observer_inputs(gains, seed: int = 1, steps: int = STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Seeded y and u sequences for an observer."""
    return (random_walk(seed, steps, gains.plant.k, 0.05),
            random_walk(seed + 1, steps, gains.plant.m, 0.1))


def run_filtering_fmu(driver, gains, ys, us, first_step: int = 0) -> np.ndarray:
    """Step an initialised observer FMU; rows = [x_hat, q_hat, psi, xi, sigma] after each step
    (q_hat: the disturbance model's states, none without one)."""
    rows = []
    n_q = gains.model.n_model - gains.plant.n
    for k, (y, u) in enumerate(zip(ys, us, strict=True), start=first_step):
        driver.set("y", y)
        driver.set("u", u)
        driver.fmu.doStep(k * DT, DT)
        q_hat = driver.get("q_hat", (n_q,)) if n_q else np.zeros(0)
        rows.append(np.concatenate([
            driver.get("x_hat", (gains.plant.n,)), q_hat, driver.get("psi", (gains.plant.k,)),
            driver.get("xi", ()).ravel(), driver.get("sigma", ()).ravel(),
        ]))
    return np.array(rows)


def run_filtering_runtime(gains, ys, us) -> np.ndarray:
    """The same rows from the in-process runtime, started at zero like the FMU's defaults."""
    obs = FilteringObserver(gains.filtering, h=H, scheme=SCHEMES[0])
    rows = []
    for y, u in zip(ys, us, strict=True):
        obs.step(y, u, DT)
        d = obs.diagnostics()
        rows.append(np.concatenate([obs.z, np.ravel(d["psi"]), [d["xi"], d["sigma"]]]))
    return np.array(rows)


# -- model description -----------------------------------------------------------------------
def model_variables(fmu: Path) -> list[ET.Element]:
    with zipfile.ZipFile(fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    return list(root.find("ModelVariables"))


@pytest.mark.parametrize("kind", ["observer", "luenberger", "plant"])
def test_fmpy_validate_reports_no_problem(pendulum_fmus, kind):
    assert validate_fmu(str(pendulum_fmus[kind])) == []


def test_fmpy_validate_second_design(chain_observer):
    assert validate_fmu(str(chain_observer)) == []


@pytest.mark.parametrize("kind", ["observer", "luenberger", "plant"])
def test_array_elements_consecutive_and_row_major(pendulum_fmus, kind):
    """Elements of one array: adjacent in the file, value references consecutive, row-major."""
    variables = model_variables(pendulum_fmus[kind])
    groups: dict[str, list[tuple[int, tuple[int, ...], int]]] = {}
    for position, var in enumerate(variables):
        match = re.fullmatch(r"(\w+)\[(\d+)(?:,(\d+))?\]", var.get("name"))
        if match:
            index = tuple(int(g) for g in match.groups()[1:] if g is not None)
            groups.setdefault(match.group(1), []).append(
                (position, index, int(var.get("valueReference")))
            )
    assert {"A", "B", "C", "u", "y"} <= set(groups)
    for base, elements in groups.items():
        positions = [p for p, _, _ in elements]
        refs = [r for _, _, r in elements]
        assert positions == list(range(positions[0], positions[0] + len(elements))), base
        assert refs == list(range(refs[0], refs[0] + len(elements))), base
        indices = [i for _, i, _ in elements]
        shape = tuple(max(i[d] for i in indices) for d in range(len(indices[0])))
        expected = [tuple(int(v) for v in n[len(base):].strip("[]").split(","))
                    for n in names(base, shape)]
        assert indices == expected, base


def test_observer_interface_and_start_values(pendulum_fmus, tuned_design):
    g = tuned_design
    variables = {v.get("name"): v for v in model_variables(pendulum_fmus["observer"])}

    def start(name):
        return float(variables[name].find("Real").get("start"))

    matrices = {"A": g.plant.A, "B": g.plant.B, "C": g.plant.C, "L0": g.model.L0,
                "G_d": g.model.G_d, "L_tilde": g.filtering.L_tilde, "L": g.filtering.L,
                "P_bar": g.filtering.P_bar}
    for base, value in matrices.items():
        starts = np.array([start(n) for n in names(base, value.shape)]).reshape(value.shape)
        np.testing.assert_allclose(starts, value, rtol=1e-15, atol=0, err_msg=base)
        assert variables[names(base, value.shape)[0]].get("causality") == "parameter"
    for name, value in (("nu", g.model.nu), ("gamma", g.filtering.gamma),
                        ("rho", g.filtering.rho)):
        assert start(name) == pytest.approx(value, rel=1e-15)
    for name in ["h", "xi0", *names("z0", (g.plant.n,)), *names("psi0", (g.plant.k,))]:
        assert variables[name].get("causality") == "parameter"
    assert start("h") == H
    assert variables["scheme"].get("causality") == "parameter"
    causality = {
        "input": names("y", (g.plant.k,)) + names("u", (g.plant.m,)),
        "output": names("x_hat", (g.plant.n,)) + names("psi", (g.plant.k,)) + ["xi", "sigma"],
    }
    for expected, listed in causality.items():
        assert all(variables[n].get("causality") == expected for n in listed)


def test_plant_and_luenberger_interface(pendulum_fmus, tuned_design):
    g = tuned_design
    plant = {v.get("name"): v.get("causality") for v in model_variables(pendulum_fmus["plant"])}
    for name in names("u", (g.plant.m,)) + names("q", (g.plant.E.shape[1],)):
        assert plant[name] == "input"
    for name in names("y", (g.plant.k,)) + names("x", (g.plant.n,)):
        assert plant[name] == "output"
    for name in [*names("x0", (g.plant.n,)), "noise_amplitude", "noise_seed"]:
        assert plant[name] == "parameter"
    luen = {v.get("name"): v.get("causality") for v in model_variables(pendulum_fmus["luenberger"])}
    assert all(luen[n] == "parameter" for n in names("L_lin", g.luenberger.L_lin.shape))
    assert all(luen[n] == "output" for n in names("x_hat", (g.plant.n,)))


# -- results against the in-process runtime ----------------------------------------------------
def test_observer_equals_runtime(open_fmu, tuned_design):
    ys, us = observer_inputs(tuned_design)
    driver = open_fmu("observer")
    driver.start()
    fmu_rows = run_filtering_fmu(driver, tuned_design, ys, us)
    runtime_rows = run_filtering_runtime(tuned_design, ys, us)
    assert np.max(np.abs(runtime_rows)) > 1e-3  # the estimate moved
    np.testing.assert_allclose(fmu_rows, runtime_rows, rtol=0, atol=1e-12)


def test_luenberger_equals_runtime(open_fmu, tuned_design):
    g = tuned_design
    ys, us = observer_inputs(g, seed=5)
    driver = open_fmu("luenberger")
    z0 = np.array([0.1, -0.2, 0.3, -0.4])
    driver.start({"z0": z0})
    obs = LuenbergerObserver(g.luenberger, h=H, scheme=SCHEMES[0], z0=z0)
    for k, (y, u) in enumerate(zip(ys, us, strict=True)):
        driver.set("y", y)
        driver.set("u", u)
        driver.fmu.doStep(k * DT, DT)
        obs.step(y, u, DT)
        np.testing.assert_allclose(driver.get("x_hat", (g.plant.n,)), obs.x_hat, rtol=0, atol=1e-12)


def test_plant_equals_runtime_with_noise(open_fmu, tuned_design):
    g = tuned_design
    us = random_walk(9, STEPS, g.plant.m, 0.1)
    qs = random_walk(10, STEPS, g.plant.E.shape[1], 0.1)
    driver = open_fmu("plant")
    driver.start()
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, g.plant.E, x0=PENDULUM_X0,
                     noise_amplitude=NOISE_AMPLITUDE,
                     seed=NOISE_SEED)
    np.testing.assert_allclose(driver.get("y", (g.plant.k,)), plant.y, rtol=0, atol=1e-12)
    for k, (u, q) in enumerate(zip(us, qs, strict=True)):
        driver.set("u", u)
        driver.set("q", q)
        driver.fmu.doStep(k * DT, DT)
        plant.step(u, q, DT)
        np.testing.assert_allclose(driver.get("x", (g.plant.n,)), plant.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(driver.get("y", (g.plant.k,)), plant.y, rtol=0, atol=1e-12)
    assert np.ptp(driver.get("y", (g.plant.k,)) - g.plant.C @ plant.x) > 0  # noise is on


def test_edited_initial_state_is_used(open_fmu, tuned_design):
    g = tuned_design
    driver = open_fmu("observer")
    z0, psi0 = np.arange(1.0, g.plant.n + 1), np.full(g.plant.k, 0.5)
    driver.start({"z0": z0, "psi0": psi0, "xi0": 2.0})
    np.testing.assert_array_equal(driver.get("x_hat", (g.plant.n,)), z0)
    ys, us = observer_inputs(g, steps=3)
    # the q states start at zero
    z0_model = np.concatenate([z0, np.zeros(g.model.n_model - g.plant.n)])
    obs = FilteringObserver(g.filtering, h=H, scheme=SCHEMES[0], z0=z0_model, psi0=psi0, xi0=2.0)
    for k, (y, u) in enumerate(zip(ys, us, strict=True)):
        run_filtering_fmu(driver, g, [y], [u], first_step=k)
        obs.step(y, u, DT)
    np.testing.assert_allclose(driver.get("x_hat", (g.plant.n,)), obs.x_hat, rtol=0, atol=1e-12)


# -- FMU state ---------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["observer", "plant"])
def test_restore_and_replay_is_bit_identical(open_fmu, tuned_design, kind):
    g = tuned_design
    driver = open_fmu(kind)
    driver.start()
    inputs = {"y": random_walk(3, 40, g.plant.k, 0.05), "u": random_walk(4, 40, g.plant.m, 0.1)}
    if kind == "plant":
        inputs = {"u": inputs["u"], "q": random_walk(5, 40, g.plant.E.shape[1], 0.1)}
    outputs = ["x_hat", "psi", "xi", "sigma"] if kind == "observer" else ["x", "y"]
    out_vrs = [driver.vr[n] for n in driver.vr if n.split("[")[0] in outputs]

    def run(fmu_driver, ks):
        rows = []
        for k in ks:
            for base, seq in inputs.items():
                fmu_driver.set(base, seq[k])
            fmu_driver.fmu.doStep(k * DT, DT)
            rows.append(fmu_driver.fmu.getReal(out_vrs))
        return np.array(rows)

    run(driver, range(20))
    state = driver.fmu.getFMUstate()
    first = run(driver, range(20, 40))
    driver.fmu.setFMUstate(state)
    replay = run(driver, range(20, 40))
    np.testing.assert_array_equal(replay, first)

    fresh = open_fmu(kind, "fresh")
    fresh.start()
    fresh.fmu.setFMUstate(fresh.fmu.deSerializeFMUstate(driver.fmu.serializeFMUstate(state)))
    np.testing.assert_array_equal(run(fresh, range(20, 40)), first)
    driver.fmu.freeFMUstate(state)


def test_reset_returns_to_initial_state(open_fmu, tuned_design):
    g = tuned_design
    ys, us = observer_inputs(g, steps=30)
    driver = open_fmu("observer")
    driver.start({"xi0": 0.7})
    first = run_filtering_fmu(driver, g, ys, us)
    driver.fmu.reset()
    driver.start({"xi0": 0.7})
    np.testing.assert_array_equal(driver.get("x_hat", (g.plant.n,)), np.zeros(g.plant.n))
    np.testing.assert_array_equal(run_filtering_fmu(driver, g, ys, us), first)
    driver.fmu.reset()
    driver.start()  # parameters are back at their start values (xi0 = 0)
    np.testing.assert_array_equal(run_filtering_fmu(driver, g, ys, us),
                                  run_filtering_runtime(g, ys, us))


# -- rejected inputs and parameters ---------------------------------------------------------
@pytest.mark.parametrize(
    ("bad", "words"),
    [(np.nan, "not finite"), (np.inf, "not finite"), (-np.inf, "not finite"),
     (1e20, "exceeds input_bound")],
)
def test_bad_input_is_an_error_state_kept_instance_usable(open_fmu, tuned_design, bad, words):
    g = tuned_design
    ys, us = observer_inputs(g, steps=20)
    driver = open_fmu("observer")
    driver.start()
    before = run_filtering_fmu(driver, g, ys[:10], us[:10])[-1]
    driver.set("y", np.array([ys[10][0], bad]))
    driver.set("u", us[10])
    assert "y[2]" in assert_error(driver, driver.fmu.doStep, 10 * DT, DT, words=words)
    np.testing.assert_array_equal(driver.get("x_hat", (g.plant.n,)), before[: g.plant.n])
    # still usable: the rest of the run equals an uninterrupted run
    rest = run_filtering_fmu(driver, g, ys[10:], us[10:], first_step=10)
    np.testing.assert_array_equal(rest, run_filtering_runtime(g, ys, us)[10:])


def test_inputs_at_the_bound_are_accepted_beyond_it_rejected(open_fmu):
    """The bound is inclusive: the fast acceptance (a hypot below the bound) hands inputs at
    the bound, or several near it, to the exact checks, which accept them; one ulp above is
    rejected."""
    driver = open_fmu("plant")
    driver.start({"input_bound": 2.0})
    driver.set("u", np.array([2.0]))
    driver.set("q", np.array([-2.0]))  # hypot 2.83 > bound, each |input| = bound
    driver.fmu.doStep(0.0, 1e-3)
    driver.set("u", np.array([np.nextafter(2.0, 3.0)]))
    assert_error(driver, driver.fmu.doStep, 1e-3, 1e-3, words="exceeds input_bound")


def test_bad_step_size_is_an_error(open_fmu):
    driver = open_fmu("plant")
    driver.start()
    assert_error(driver, driver.fmu.doStep, 0.0, -1e-3, words="step size")
    driver.fmu.doStep(0.0, 1e-3)


def test_absurd_step_size_is_an_error_not_a_hang(open_fmu):
    """A communication step of a day (1.7e9 internal steps) is refused at once with fmi2Error;
    the instance stays usable."""
    driver = open_fmu("observer")
    driver.start()
    assert_error(driver, driver.fmu.doStep, 0.0, 86400.0, words="internal steps")
    driver.fmu.doStep(0.0, 1e-3)


@pytest.mark.parametrize(
    ("edit", "check"),
    [
        ({"A[3,2]": 160.0}, "nilpotency"),
        ({"G_d[1,1]": 0.9}, "output_homogeneity"),
        ({"rho": 1.0}, "rho = 1.0 must be > gamma/2 = 3.0"),
        ({"h": -1.0}, "internal step h"),
        ({"A[1,1]": np.nan}, "A[1,1]"),
    ],
)
def test_edited_parameters_fail_initialisation_with_fmi_error(open_fmu, tuned_design, edit, check):
    driver = open_fmu("observer")
    driver.fmu.setupExperiment(startTime=0.0)
    for name, value in edit.items():
        driver.fmu.setReal([driver.vr[name]], [value])
    driver.fmu.enterInitializationMode()
    message = assert_error(driver, driver.fmu.exitInitializationMode, words=check)
    if check not in ("internal step h", "A[1,1]") and "must be" not in check:
        assert re.search(rf"{check} = [-+0-9.e]+ \(required", message)  # says by how much
    assert_error(driver, driver.fmu.doStep, 0.0, DT,  # no rejected design runs
                 words="fmi2DoStep is not allowed in the state initialisation mode")
    driver.fmu.reset()  # usable again
    driver.start()
    driver.fmu.doStep(0.0, DT)


def test_scheme_index_checked(open_fmu):
    driver = open_fmu("luenberger")
    driver.fmu.setupExperiment(startTime=0.0)
    driver.fmu.setInteger([driver.vr["scheme"]], [99])
    driver.fmu.enterInitializationMode()
    assert_error(driver, driver.fmu.exitInitializationMode, words="scheme = 99")


def test_luenberger_rejects_unstable_gain(open_fmu, tuned_design):
    driver = open_fmu("luenberger")
    driver.fmu.setupExperiment(startTime=0.0)
    driver.set("L_lin", -tuned_design.luenberger.L_lin)
    driver.fmu.enterInitializationMode()
    assert_error(driver, driver.fmu.exitInitializationMode, words="hurwitz_luenberger")


# -- several instances, several designs -------------------------------------------------------
def test_instances_and_designs_are_independent(open_fmu, tuned_design, chain_design):
    """Two pendulum instances and a triple-integrator observer, stepped interleaved."""
    assert ((chain_design.plant.n, chain_design.plant.k)
            != (tuned_design.plant.n, tuned_design.plant.k))
    cases = [
        (open_fmu("observer", "p1"), tuned_design, observer_inputs(tuned_design, seed=11)),
        (open_fmu("chain", "c1"), chain_design, observer_inputs(chain_design, seed=12)),
        (open_fmu("observer", "p2"), tuned_design, observer_inputs(tuned_design, seed=13)),
    ]
    for driver, _, _ in cases:
        driver.start()
    rows = [[] for _ in cases]
    for k in range(STEPS):
        for i, (driver, g, (ys, us)) in enumerate(cases):
            rows[i].append(run_filtering_fmu(driver, g, [ys[k]], [us[k]], first_step=k)[0])
    for i, (_, g, (ys, us)) in enumerate(cases):
        np.testing.assert_allclose(np.array(rows[i]), run_filtering_runtime(g, ys, us),
                                   rtol=0, atol=1e-12)


# -- what the FMU ships and imports ----------------------------------------------------------
def test_shipped_code_imports_numpy_only(pendulum_fmus):
    """Each FMU ships fhobs.core and fhobs.fmu whole under its own package name; the core
    imports only itself (relatively), numpy and the standard library, the slaves also pythonfmu."""
    stdlib = {"__future__"} | set(sys.stdlib_module_names)
    for kind, path in pendulum_fmus.items():
        with zipfile.ZipFile(path) as z:
            sources = {n: z.read(n) for n in z.namelist()
                       if n.endswith(".py") and not n.startswith("resources/pythonfmu/")}
        packages = {n.split("/")[1] for n in sources if n.count("/") > 1}
        assert len(packages) == 1, packages
        package = packages.pop()
        assert re.fullmatch(rf"fhobs_{kind}_[0-9a-f]{{12}}", package), package
        shipped = {n.split("/", 2)[2] for n in sources if n.count("/") > 1}
        source_tree = Path(fhobs.__file__).parent
        assert shipped == {"__init__.py"} | {
            p.relative_to(source_tree).as_posix()
            for sub in ("core", "fmu") for p in (source_tree / sub).rglob("*.py")}
        for name, source in sources.items():
            layer = name.split("/")[2] if name.count("/") > 1 else "script"
            allowed = stdlib | {"numpy"} | ({"pythonfmu"} if layer != "core" else set())
            for top in absolute_imports(source):
                assert top in allowed or (layer == "script" and top == package), (name, top)


def absolute_imports(source: str | bytes) -> list[str]:
    """Top-level names of a source's absolute imports."""
    tops = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            tops += [a.name.split(".")[0] for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            tops.append(node.module.split(".")[0])
    return tops


def test_core_imports_only_itself_numpy_and_the_standard_library():
    core = Path(fhobs.__file__).parent / "core"
    allowed = {"numpy", "__future__"} | set(sys.stdlib_module_names)
    for path in core.rglob("*.py"):
        assert set(absolute_imports(path.read_text())) <= allowed, path.name


@pytest.mark.parametrize("first, second", [
    ("luenberger", "observer"),
    pytest.param("observer", "luenberger", marks=pytest.mark.slow)])
def test_fmus_of_one_design_do_not_share_modules(pendulum_fmus, tmp_path, first, second):
    """One FMU is run and its unpack folder deleted; another FMU of the same design then runs in
    the same process from its own shipped package (the observer needs a module the Luenberger
    slave does not import), with the results of a run in a fresh process."""
    script = tmp_path / "run.py"
    script.write_text(
        "import shutil, sys\n"
        "import numpy as np\n"
        "from fmpy import extract, simulate_fmu\n"
        "paths, out = sys.argv[1:-1], sys.argv[-1]\n"
        "t = np.linspace(0.0, 0.02, 21)\n"
        "signal = np.array(list(zip(t, np.sin(50 * t), np.cos(30 * t))),\n"
        "                  dtype=[('time', float), ('y[1]', float), ('y[2]', float)])\n"
        "for path in paths:\n"
        "    folder = extract(path)\n"
        "    result = simulate_fmu(folder, stop_time=0.02, output_interval=0.001, input=signal)\n"
        "    shutil.rmtree(folder)\n"
        "np.save(out, np.array(result.tolist()))\n"
    )
    paths = [str(pendulum_fmus[first]), str(pendulum_fmus[second])]
    both, alone = tmp_path / "both.npy", tmp_path / "alone.npy"
    for args in ([*paths, both], [paths[1], alone]):
        done = subprocess.run([sys.executable, str(script), *map(str, args)],
                              capture_output=True, text=True, check=False)
        assert done.returncode == 0, done.stderr[-2000:]
    after, fresh = np.load(both), np.load(alone)
    assert np.abs(fresh[:, 1:]).max() > 0.0
    np.testing.assert_array_equal(after, fresh)


def test_runs_without_scipy_or_cvxpy(pendulum_fmus, tuned_design, tmp_path):
    """In a fresh interpreter where importing scipy/cvxpy/fhobs fails, the FMU still runs."""
    script = tmp_path / "run.py"
    script.write_text(
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in ('scipy', 'cvxpy', 'matplotlib', 'fhobs'):\n"
        "            raise ImportError('blocked ' + name)\n"
        "sys.meta_path.insert(0, Block())\n"
        "from fmpy import simulate_fmu\n"
        f"r = simulate_fmu({str(pendulum_fmus['observer'])!r}, stop_time=0.01,"
        " output_interval=0.001, input=None)\n"
        "assert not [m for m in sys.modules if m.split('.')[0] in ('scipy', 'cvxpy')]\n"
        "print(len(r), flush=True)\n"
        # pythonfmu 0.7.0 sometimes aborts at interpreter teardown after the FMU library was
        # unloaded (seen with and without fhobs' wrapper): leave without the teardown.
        "import os; os._exit(0)\n"
    )
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "11"


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
def test_overflowing_step_is_rolled_back(open_fmu, tuned_design):
    """A step whose new outputs are not finite (y = C x overflows) is an fmi2Error; outputs and
    the serialized FMU state stay exactly as before the call (the slaves' rollback)."""
    C = tuned_design.plant.C.copy()
    C[0, 0] = 1.7e308
    driver = open_fmu("plant")
    driver.start({"C": C, "x0": np.ones(tuned_design.plant.n)})
    outputs = [*names("y", (tuned_design.plant.k,)), *names("x", (tuned_design.plant.n,))]
    refs = [driver.vr[name] for name in outputs]
    k, (before, state) = steps_until_error(
        driver, 1e-2, lambda: (driver.fmu.getReal(refs), serialized_state(driver)))
    assert k > 0  # some steps succeeded before the overflow
    assert driver.fmu.getReal(refs) == before
    assert serialized_state(driver) == state


def serialized_state(driver) -> bytes:
    """The instance's serialized FMU state (the state object freed again)."""
    state = driver.fmu.getFMUstate()
    data = bytes(driver.fmu.serializeFMUstate(state))
    driver.fmu.freeFMUstate(state)
    return data


@pytest.mark.skipif(sys.platform != "linux", reason="the status wrapper is linux64 only")
def test_calls_served_by_the_wrapper_equal_pythonfmus(open_fmu, tuned_design):
    """With the status wrapper, fmi2GetReal / fmi2SetReal of Real variables use the slave's
    buffer without entering Python: the values are those the slave itself holds, in any order,
    and fmi2Reset hands the wrapper the new slave's buffer. fmi2DoStep calls the slave through
    a callback; the last successful time is reported as pythonfmu reports it (t + h after a
    step, t after a rejected one). (Other references are checked by the slave first, see
    test_fault_injection.py; an exception in do_step still goes to pythonfmu, whose answer is
    fmi2Fatal: not exercised here, since nothing may be called on an instance after it.)"""
    import gc

    g = tuned_design
    driver = open_fmu("observer", "direct")

    def slaves() -> list:
        return [o for o in gc.get_objects()
                if type(o).__name__.startswith("FhobsObserver") and o.instance_name == "direct"]

    (slave,) = slaves()
    assert slave.via_wrapper
    driver.set("y", [0.25, -0.5])
    np.testing.assert_array_equal(slave.array("y"), [0.25, -0.5])
    driver.start({"xi0": 0.3})
    run_filtering_fmu(driver, g, *observer_inputs(g, steps=5))
    reals = [v.valueReference for v in driver.description.modelVariables if v.type == "Real"]
    for refs in (reals, reals[::-1], reals[3::7] + reals[:2]):
        assert driver.fmu.getReal(refs) == slave.get_real(refs)
    assert driver.fmu.getReal([]) == []
    last_successful_time = 2  # fmi2LastSuccessfulTime
    t = driver.fmu.getRealStatus(last_successful_time)
    driver.fmu.doStep(t, 0.125)
    assert driver.fmu.getRealStatus(last_successful_time) == t + 0.125
    driver.set("u", [np.nan])
    assert_error(driver, driver.fmu.doStep, t + 0.125, 0.125, words="u[1]")
    assert driver.fmu.getRealStatus(last_successful_time) == t + 0.125
    driver.fmu.reset()
    (new,) = [s for s in slaves() if s is not slave]
    assert new.via_wrapper
    assert new.array("xi0") == 0.0
    driver.set("xi0", 0.6)
    assert new.array("xi0") == 0.6 and slave.array("xi0") == 0.3
    assert_error(driver, driver.fmu.getReal, [driver.vr["x_hat[1]"]],
                 words="fmi2GetReal is not allowed in the state instantiated")
    driver.start()
    np.testing.assert_array_equal(driver.get("x_hat", (g.plant.n,)), np.zeros(g.plant.n))
