"""Native FMUs (fhobs.native): compiled C, no Python at run time, against the pythonfmu FMUs.

The pythonfmu FMUs of the same design and options are the reference (themselves checked against
the numpy runtime and the paper elsewhere): the native ones must have their interface, give
their results to 1e-12 relative (both run kernel.c; the native FMU's step plans are computed
in C, tests/unit/test_native_plan.py), and answer caller
mistakes with fmi2Error, a log message and the state kept. Independent checks: fmpy's
validation, ``ldd`` of the binaries, fmpy's compile of ``sources/``, and a C host that loads a
native FMU with an empty environment.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import fmu_fixtures
import numpy as np
import pytest
from fhobs.build import build_fmus
from fhobs.cli import main as cli_main
from fhobs.errors import BuildError
from fhobs.fmu.kinds import KINDS as ALL
from fhobs.native.build import FAMILIES, build_native_fmus
from fmpy import extract, read_model_description
from fmpy.validation import validate_fmu
from fmu_fixtures import (
    COMPARED_KINDS,
    FMI_ERROR,
    PENDULUM_X0,
    SHARED_KINDS,
    FmuDriver,
    assert_error,
    random_walk,
)
from host_runner import read_outputs, run_host, write_inputs
from reference_math import relative

from harness.cli import load_scenario
from harness.master import run_system
from harness.system import resolve_system

pytestmark = pytest.mark.skipif(
    sys.platform != "linux" or shutil.which("cc") is None,
    reason="native FMUs are built for linux64 with cc",
)

KINDS = COMPARED_KINDS
OBSERVERS = tuple(kind for kind in KINDS if ALL[kind].label)
RTOL = 1e-12
STEPS = (5e-5, 1e-4, 1e-3)
"""Step sizes of the bundled scenarios (5e-5) and the zoo bench (1e-4, 1e-3)."""


@pytest.fixture
def open_pair(pendulum_fmus, native_fmus, tmp_path):
    """Factory ``open_pair(kind, parameters=None)`` -> (pythonfmu driver, native driver), both
    started; freed after the test."""
    opened = []

    def factory(kind: str, parameters: dict | None = None, start: bool = True):
        pair = []
        for label, path in (("pythonfmu", pendulum_fmus[kind]), ("native", native_fmus[kind])):
            driver = FmuDriver(path, extract(str(path), str(tmp_path / f"{label}_{kind}_"
                                                            f"{len(opened)}")), label)
            opened.append(driver)
            if start:
                driver.start(parameters)
            pair.append(driver)
        return tuple(pair)

    yield factory
    for driver in opened:
        driver.fmu.freeInstance()


def inputs(kind: str, steps: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Seeded input sequences of a kind: the observers' (y, u), the plant's (u, q)."""
    if kind == "plant":
        return {"u": random_walk(seed, steps, 1, 0.3), "q": random_walk(seed + 1, steps, 1, 0.1)}
    return {"y": 1.0 + random_walk(seed, steps, 2, 0.05), "u": random_walk(seed + 1, steps, 1,
                                                                              0.3)}


def outputs(driver: FmuDriver, kind: str) -> np.ndarray:
    """Every output of the FMU (of a kind), flat, in value-reference order."""
    return np.array(driver.fmu.getReal([v.valueReference for v in driver.description.modelVariables
                                        if v.causality == "output"]))


def run(driver: FmuDriver, kind: str, signals: dict[str, np.ndarray], dt: float,
        first: int = 0) -> np.ndarray:
    """Step through the input sequences; the outputs after each step (rows)."""
    rows = []
    for k in range(len(next(iter(signals.values())))):
        for name, values in signals.items():
            driver.set(name, values[k])
        driver.fmu.doStep((first + k) * dt, dt)
        rows.append(outputs(driver, kind))
    return np.array(rows)


def fnv1a(data: bytes) -> int:
    """64-bit FNV-1a, written out here (the native FMUs' state checksum)."""
    value = 14695981039346656037
    for byte in data:
        value = ((value ^ byte) * 1099511628211) % 2**64
    return value


# -- interface -------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
def test_interface_is_the_pythonfmu_fmus(pendulum_fmus, native_fmus, kind, tuned_design):
    """Names, value references, types, causalities, variabilities and initial attributes are
    the pythonfmu FMU's; the start values are the same numbers, written exactly (the pythonfmu
    XML rounds them to 16 digits)."""
    python, native = (read_model_description(str(p[kind])) for p in (pendulum_fmus, native_fmus))
    keys = ("name", "valueReference", "type", "causality", "variability", "initial")
    assert [[getattr(v, key) for key in keys] for v in native.modelVariables] == [
        [getattr(v, key) for key in keys] for v in python.modelVariables]
    for a, b in zip(native.modelVariables, python.modelVariables, strict=True):
        assert math.isclose(float(a.start), float(b.start), rel_tol=1e-15, abs_tol=1e-300)
    if kind == "observer":
        start = {v.name: float(v.start) for v in native.modelVariables}
        assert start["L[1,1]"] == tuned_design.filtering.L[0, 0]
        assert start["nu"] == tuned_design.model.nu
    assert native.coSimulation.needsExecutionTool is False
    files = native.buildConfigurations[0].sourceFileSets[0].sourceFiles
    units = ["fmi2_layer.c", "gain_levels.c", "instance.c", "kernel.c", "model_common.c",
             "model_data.c", "planner.c"]
    family = [name for name in FAMILIES[ALL[kind].family].units if name.endswith(".c")]
    assert family and f"family_{ALL[kind].family}.c" in family
    assert files == sorted(units + family)


def test_start_values_of_moved_starts_are_the_pythonfmu_fmus(kalman_design, tmp_path):
    """The native build computes its outputs' start values from the kind's declaration (its
    runtime model at the initial state, no pythonfmu slave): with start values that move the
    outputs off zero (z0, psi0, xi0, T0, x0, the plant's noise) every variable's start is the
    pythonfmu FMU's of every kind the design builds, to the pythonfmu XML's 16 digits."""
    plant = kalman_design.plant
    options = {"z0": np.linspace(0.3, -0.4, plant.n), "psi0": np.linspace(0.05, -0.1, plant.k),
               "xi0": 0.7, "T0": 0.4, "x0": np.linspace(-0.2, 0.6, plant.n),
               "noise_amplitude": 1e-3, "noise_seed": 11}
    python = build_fmus(kalman_design, tmp_path / "python", kinds=SHARED_KINDS,
                        status_wrapper=False, kernel=False, **options)
    native = build_native_fmus(kalman_design, tmp_path / "native", kinds=SHARED_KINDS,
                               **options)
    moved = 0
    for kind in SHARED_KINDS:
        a, b = (read_model_description(str(fmus[kind])).modelVariables for fmus in (native, python))
        assert [v.name for v in a] == [v.name for v in b]
        for x, y in zip(a, b, strict=True):
            assert math.isclose(float(x.start), float(y.start), rel_tol=1e-15, abs_tol=1e-300), (
                kind, x.name, x.start, y.start)
            moved += x.causality == "output" and float(x.start) != 0.0
    assert moved >= 3 * plant.n  # x_hat of the observers, the plant's x and y: not all zero


@pytest.mark.parametrize("kind", KINDS)
def test_fmpy_validates_the_native_fmu(native_fmus, kind):
    assert validate_fmu(str(native_fmus[kind])) == []


@pytest.mark.parametrize("kind", KINDS)
def test_binary_needs_no_python(native_fmus, kind, tmp_path):
    """``ldd``: no libpython (nor anything beyond the C library and libm); the library exports
    the FMI functions only."""
    with zipfile.ZipFile(native_fmus[kind]) as archive:
        (name,) = [n for n in archive.namelist() if n.startswith("binaries/linux64/")]
        binary = Path(archive.extract(name, tmp_path))
    linked = subprocess.run(["ldd", str(binary)], capture_output=True, text=True,
                            check=True).stdout
    assert "python" not in linked.lower()
    libraries = {line.split()[0] for line in linked.splitlines() if "=>" in line}
    assert libraries <= {"libm.so.6", "libc.so.6"}, libraries
    symbols = subprocess.run(["nm", "-D", "--defined-only", str(binary)], capture_output=True,
                             text=True, check=True).stdout.split()
    exported = {s for s in symbols if s.startswith(("fmi2", "fhobs"))}
    assert exported and all(s.startswith("fmi2") for s in exported), exported


# -- results -----------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("dt", STEPS)
def test_results_equal_the_pythonfmu_fmus(open_pair, kind, dt):
    """Random-walk inputs from the start values (the observers from zero: the level search of
    the filtering observer's first steps), 300 steps of each step size."""
    python, native = open_pair(kind)
    signals = inputs(kind, 300)
    a, b = run(native, kind, signals, dt), run(python, kind, signals, dt)
    assert relative(a, b) <= RTOL
    assert not native.messages


@pytest.mark.parametrize("kind", ["observer", "luenberger", "plant"])
def test_euler_scheme_equals_the_pythonfmu_fmus(open_pair, kind):
    """scheme = 1 (euler) takes any step size: 4 substeps of h per step of 2e-4."""
    python, native = open_pair(kind, start=False)
    for driver in (python, native):
        driver.fmu.setInteger([driver.vr["scheme"]], [1])
        driver.start()
    signals = inputs(kind, 200, seed=3)
    assert relative(run(native, kind, signals, 2e-4), run(python, kind, signals, 2e-4)) <= RTOL


def test_settable_parameters_act_as_in_the_pythonfmu_fmu(open_pair):
    """z0, psi0, xi0 are per-instance values; input_bound too."""
    start = {"z0": np.array([0.5, -1.0, 0.25, 2.0]), "psi0": np.array([0.1, -0.2]), "xi0": 0.3}
    python, native = open_pair("observer", start)
    assert np.array_equal(outputs(native, "observer"), outputs(python, "observer"))
    signals = inputs("observer", 100, seed=5)
    assert relative(run(native, "observer", signals, 1e-3),
                    run(python, "observer", signals, 1e-3)) <= RTOL


def test_kalman_takes_any_multiple_of_its_sample_time(open_pair):
    python, native = open_pair("kalman")
    dt = 7 * float(native.get("Ts", ()))
    signals = inputs("kalman", 50, seed=2)
    assert relative(run(native, "kalman", signals, dt), run(python, "kalman", signals, dt)) <= RTOL


def test_state_get_set_serialize_and_reset_are_bit_exact(open_pair, native_fmus, tmp_path):
    """Serialized after 50 steps and restored into a second instance, the next 50 steps are
    the first instance's bit for bit; fmi2Reset gives the fresh run again."""
    _, native = open_pair("observer")
    signals = inputs("observer", 150, seed=4)
    first = {name: values[:50] for name, values in signals.items()}
    rest = {name: values[50:100] for name, values in signals.items()}
    fresh = run(native, "observer", first, 1e-3)
    state = native.fmu.getFMUstate()
    data = bytes(native.fmu.serializeFMUstate(state))
    continued = run(native, "observer", rest, 1e-3, 50)
    native.fmu.setFMUstate(state)
    assert np.array_equal(run(native, "observer", rest, 1e-3, 50), continued)
    native.fmu.freeFMUstate(state)
    other = FmuDriver(native_fmus["observer"], extract(str(native_fmus["observer"]),
                                                       str(tmp_path / "other")), "other")
    other.fmu.setupExperiment(startTime=0.0)
    restored = other.fmu.deSerializeFMUstate(data)
    other.fmu.setFMUstate(restored)
    assert np.array_equal(run(other, "observer", rest, 1e-3, 50), continued)
    other.fmu.freeFMUstate(restored)
    other.fmu.freeInstance()
    native.fmu.reset()
    native.start()
    assert np.array_equal(run(native, "observer", first, 1e-3), fresh)


def test_many_instances_are_independent(open_pair):
    """Two native instances stepped alternately with different inputs give what each gives
    alone (no shared state)."""
    _, a = open_pair("observer")
    _, b = open_pair("observer")
    _, alone = open_pair("observer")
    sa, sb = inputs("observer", 60, seed=6), inputs("observer", 60, seed=7)
    rows_a, rows_b = [], []
    for k in range(60):
        for driver, signals, rows in ((a, sa, rows_a), (b, sb, rows_b)):
            run_one = {name: values[k:k + 1] for name, values in signals.items()}
            rows.append(run(driver, "observer", run_one, 1e-3, k)[0])
    assert np.array_equal(np.array(rows_a), run(alone, "observer", sa, 1e-3))
    assert not np.array_equal(np.array(rows_a), np.array(rows_b))


# -- caller mistakes -----------------------------------------------------------------------------
def test_step_size_the_observer_cannot_follow_is_an_error_naming_the_reason(open_pair):
    """dt = 0.5: no gain level makes the split step contractive (the numpy runtime refuses it
    too); fmi2Error naming the reason and the smallest spectral radius, every time it is
    asked, the state unchanged; then the instance steps on as a fresh one."""
    python, native = open_pair("observer")
    before = outputs(native, "observer")
    for _ in range(2):
        assert_error(native, native.fmu.doStep, 0.0, 0.5,
                     words="no gain level makes the split step of size 0.5 contractive "
                           "(smallest spectral radius ")
        assert "state left unchanged" in native.messages[-1][1]
        assert np.array_equal(outputs(native, "observer"), before)
    signals = inputs("observer", 3)
    assert relative(run(native, "observer", signals, 1e-3),
                    run(python, "observer", signals, 1e-3)) <= RTOL


@pytest.mark.parametrize("kind", KINDS)
def test_compiled_parameter_accepts_only_its_built_value(open_pair, kind):
    """Writing the start value of every parameter is accepted (what importers do); another
    value of a compiled-in one is refused, naming it and the rebuild."""
    _, native = open_pair(kind, start=False)
    description = native.description
    reals = [v for v in description.modelVariables
             if v.causality == "parameter" and v.type == "Real"]
    native.fmu.setReal([v.valueReference for v in reals], [float(v.start) for v in reals])
    gain = next(v for v in ALL[kind].variables  # the kind's own gain (the plant: A)
                if v.role == "design" and not v.field.startswith("plant."))
    name = f"{gain.name}[1,1]"
    value = float(next(v.start for v in reals if v.name == name))
    assert_error(native, native.fmu.setReal, [native.vr[name]], [value * (1 + 1e-15) + 1e-300],
                 words=f"parameter {name}")
    assert "rebuild with build_fmu.py" in native.messages[-1][1]
    native.start()
    assert native.messages[-1][0] == FMI_ERROR  # the refusal only: initialisation went through


def test_caller_mistakes_are_errors_with_the_state_kept(open_pair, pendulum_fmus, native_fmus):
    """Unknown value reference, wrong type, writes to outputs and status, non-finite and too
    large inputs, a bad step size, wrong call sequence, parameters after initialisation,
    foreign and damaged FMU state bytes: each fmi2Error with its message; afterwards the
    instance continues exactly as a clean one."""
    python, native = open_pair("observer")
    fmu, vr = native.fmu, native.vr
    signals = inputs("observer", 20, seed=8)
    head = {name: values[:10] for name, values in signals.items()}
    tail = {name: values[10:] for name, values in signals.items()}
    run(native, "observer", head, 1e-3)
    run(python, "observer", head, 1e-3)
    count = len(native.description.modelVariables)
    own = bytes(fmu.serializeFMUstate(state := fmu.getFMUstate()))
    fmu.freeFMUstate(state)
    luenberger = FmuDriver(native_fmus["luenberger"], extract(str(native_fmus["luenberger"])))
    luenberger.start()
    foreign_state = luenberger.fmu.getFMUstate()
    foreign_native = bytes(luenberger.fmu.serializeFMUstate(foreign_state))
    foreign_python = bytes(python.fmu.serializeFMUstate(python.fmu.getFMUstate()))
    tampered = bytearray(own)
    tampered[80:88] = np.float64(123.0).tobytes()  # a compiled-in parameter's value
    resigned = bytes(tampered[:-8]) + fnv1a(bytes(tampered[:-8])).to_bytes(8, "little")
    cases = [
        (fmu.getReal, ([count + 5],), "is not a variable of this FMU"),
        (fmu.getInteger, ([vr["x_hat[1]"]],), "is of type Real, not Integer"),
        (fmu.setReal, ([vr["status"]], [1.0]), "is of type Integer, not Real"),
        (fmu.setInteger, ([vr["status"]], [1]), "local variable"),
        (fmu.setReal, ([vr["x_hat[1]"]], [1.0]), "is an output"),
        (fmu.getBoolean, ([0],), "not Boolean"),
        (fmu.setReal, ([vr["z0[1]"]], [1.0]), "fixed parameter"),
        (fmu.setInteger, ([vr["scheme"]], [1]), "fixed parameter"),
        (fmu.enterInitializationMode, (), "not allowed in the state step mode"),
        (fmu.doStep, (0.01, -1e-3), "not a positive finite number"),
        (fmu.doStep, (0.01, math.nan), "not a positive finite number"),
        (fmu.deSerializeFMUstate, (foreign_native,), "another FMU"),
        (fmu.deSerializeFMUstate, (foreign_python,), "not a serialized FMU state"),
        (fmu.deSerializeFMUstate, (own[:-8],), "not a serialized FMU state"),
        (fmu.deSerializeFMUstate, (bytes(tampered),), "checksum does not match"),
        (fmu.deSerializeFMUstate, (resigned,), "not the value compiled into this FMU"),
        (fmu.setFMUstate, (foreign_state,), "not an FMU state of this FMU"),
    ]
    for _ in range(3):  # repeated mistakes: the same answers, the host unharmed
        for call, args, words in cases:
            assert_error(native, call, *args, words=words)
    luenberger.fmu.freeFMUstate(foreign_state)
    luenberger.fmu.freeInstance()
    for value, words in ((math.nan, "is not finite"), (math.inf, "is not finite"),
                         (2e8, "exceeds input_bound")):
        native.set("y", np.array([value, 0.0]))
        assert_error(native, fmu.doStep, 0.01, 1e-3, words=words)
    assert relative(run(native, "observer", tail, 1e-3, 10),
                    run(python, "observer", tail, 1e-3, 10)) <= RTOL
    fmu.terminate()
    assert_error(native, fmu.doStep, 0.03, 1e-3, words="not allowed in the state terminated")


def test_wrong_call_sequence_and_bad_parameters(native_fmus):
    """doStep before initialisation; exitInitializationMode without enter; a non-finite or
    negative per-instance parameter fails initialisation, which can then be corrected."""
    driver = FmuDriver(native_fmus["plant"], extract(str(native_fmus["plant"])))
    fmu = driver.fmu
    assert_error(driver, fmu.doStep, 0.0, 1e-3,
                 words="fmi2DoStep is not allowed in the state instantiated")
    assert_error(driver, fmu.exitInitializationMode,
                 words="fmi2ExitInitializationMode is not allowed in the state instantiated")
    fmu.enterInitializationMode()
    driver.set("noise_amplitude", -1.0)
    assert_error(driver, fmu.exitInitializationMode, words="noise_amplitude must be finite")
    driver.set("noise_amplitude", 0.0)
    driver.set("x0", np.array([1.0, math.nan, 0.0, 0.0]))
    assert_error(driver, fmu.exitInitializationMode, words="parameter x0[2] = nan is not finite")
    driver.set("x0", np.array(PENDULUM_X0))
    fmu.exitInitializationMode()
    assert np.array_equal(driver.get("x", (4,)), np.array(PENDULUM_X0))
    fmu.freeInstance()


def test_native_step_sizes_a_design_cannot_take_are_refused(tuned_design, tmp_path):
    with pytest.raises(BuildError, match="--native-step 0.5"):
        build_native_fmus(tuned_design, tmp_path, steps=[0.5], kinds=["observer"])


def test_a_kind_without_a_native_fmu_is_refused_by_name(tuned_design, tmp_path):
    with pytest.raises(BuildError, match="no native FMU of kind sampled: native FMUs are built "
                                         f"for {', '.join(ALL)}$"):
        build_native_fmus(tuned_design, tmp_path, kinds=["observer", "sampled"])
    assert not any(tmp_path.iterdir())


# -- build_fmu.py --native, the harness, fmpy's compile of sources/ -------------------------------
@pytest.fixture(scope="module")
def cli_folders(tmp_path_factory) -> Path:
    """``python build_fmu.py examples/pendulum.toml --out DIR --native``: DIR holds the
    pythonfmu FMUs, DIR/native the native ones."""
    out = tmp_path_factory.mktemp("cli")
    assert cli_main([str(fmu_fixtures.EXAMPLES / "pendulum.toml"), "--out", str(out),
                     "--native"]) == 0
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", ["pendulum_nominal", "pendulum_perturbed", "pendulum_noisy"])
def test_paper_scenarios_give_the_same_results_with_either_folder(cli_folders, name, tmp_path):
    """The bundled scenario, full length, through the harness with the pythonfmu FMUs and with
    the native ones (plant included): every recorded estimate and the plant's state agree to
    1e-12 relative per signal (max |difference| / max |pythonfmu value|)."""
    results = []
    for folder in (cli_folders, cli_folders / "native"):
        spec = load_scenario(name, folder, tmp_path / "blocks").with_seed(3)
        results.append(run_system(resolve_system(spec), progress=False))
    python, native = results
    assert native.values.shape == python.values.shape
    for signal in ("plant.x", "observer.x_hat", "linear.x_hat", "kalman.x_hat"):
        assert relative(native.vector(signal), python.vector(signal)) <= RTOL, signal


@pytest.mark.slow
def test_fmpy_compiles_the_sources_into_a_working_binary(native_fmus, native_host, open_pair,
                                                         tmp_path):
    """The shipped binary removed, fmpy's build_platform_binary (CMake, the modelDescription's
    SourceFiles; libm added, which its CMake project does not link) compiles sources/ into a
    library that runs as the shipped one, in fmpy and in the C host with an empty
    environment."""
    if shutil.which("cmake") is None:
        pytest.skip("fmpy's build_platform_binary needs cmake")
    from fmpy.build import build_platform_binary

    folder = tmp_path / "compiled"
    with zipfile.ZipFile(native_fmus["observer"]) as archive:
        archive.extractall(folder)
    (binary,) = (folder / "binaries" / "linux64").iterdir()
    binary.unlink()
    build_platform_binary(str(folder.resolve()),
                          cmake_options={"CMAKE_C_STANDARD_LIBRARIES:STRING": "-lm"})
    assert binary.exists()
    compiled = FmuDriver(native_fmus["observer"], str(folder), "compiled")
    compiled.start()
    python, _ = open_pair("observer")
    signals = inputs("observer", 200, seed=9)
    assert relative(run(compiled, "observer", signals, 5e-5),
                    run(python, "observer", signals, 5e-5)) <= RTOL
    compiled.fmu.freeInstance()
    python, _ = open_pair("observer")
    assert relative(*host_and_fmpy_rows(native_host, folder, python, signals, tmp_path)) <= RTOL


# -- a native host with an empty environment -------------------------------------------------------
def host_and_fmpy_rows(host: Path, folder: Path, python: FmuDriver,
                       signals: dict[str, np.ndarray], tmp_path: Path,
                       dt: float = 5e-5) -> tuple[np.ndarray, np.ndarray]:
    """The outputs of the extracted FMU in ``folder`` run by the C host with an empty
    environment (a row after initialisation and after each step) and those of the started
    pythonfmu FMU ``python`` under fmpy with the same inputs."""
    names = [label for name, values in signals.items()
             for label in fmu_fixtures.names(name, values.shape[1:])]
    steps = len(next(iter(signals.values()))) - 1
    times = dt * np.arange(steps + 1)
    write_inputs(tmp_path / "in.csv", names, times, np.hstack(list(signals.values())))
    done = run_host(host, folder, tmp_path / "in.csv", tmp_path / "out.csv", dt)
    assert done.returncode == 0, done.stderr
    columns, rows = read_outputs(tmp_path / "out.csv")
    variables = [v for v in python.description.modelVariables if v.causality == "output"]
    assert columns == [v.name for v in variables]
    assert np.array_equal(rows[:, 0], times)
    refs = [v.valueReference for v in variables]
    expected = [python.fmu.getReal(refs)]
    for k in range(steps):
        for name, values in signals.items():
            python.set(name, values[k])
        python.fmu.doStep(times[k], dt)
        expected.append(python.fmu.getReal(refs))
    return rows[:, 1:], np.array(expected)


@pytest.mark.parametrize("kind", ["observer", "plant"])
def test_c_host_with_an_empty_environment_gives_the_pythonfmu_results(
        native_host, native_fmus, open_pair, kind, tmp_path):
    """tests/native_host.c (no Python in its process, ``env -i``) runs the native FMU from a
    CSV of inputs; its outputs equal the pythonfmu FMU's under fmpy (plant: with its noise)."""
    folder = tmp_path / "fmu"
    with zipfile.ZipFile(native_fmus[kind]) as archive:
        archive.extractall(folder)
    python, _ = open_pair(kind)
    rows, expected = host_and_fmpy_rows(native_host, folder, python, inputs(kind, 201, seed=10),
                                        tmp_path)
    assert relative(rows, expected) <= RTOL


@pytest.mark.parametrize(("options", "words"), [
    (["--native", "--native-step", "0"], "--native-step 0.0: a communication step size must be"),
    (["--native", "--native-step", "inf"], "--native-step inf"),
    (["--native-step", "1e-3"], "add --native"),
    (["--native", "--design-only"], "drop --design-only"),
])
def test_native_options_are_checked_before_any_work(options, words, tmp_path, capsys):
    """Exit 2 with one paragraph naming the option; nothing written."""
    spec = fmu_fixtures.EXAMPLES / "pendulum.toml"
    assert cli_main([str(spec), "--out", str(tmp_path / "out"), *options]) == 2
    error = capsys.readouterr().err
    assert error.startswith("error: ") and words in error and "Traceback" not in error
    assert not (tmp_path / "out").exists()


def test_fmpys_simulate_fmu_runs_the_native_plant_as_the_pythonfmu_one(pendulum_fmus,
                                                                        native_fmus):
    """fmpy's own master (its DefaultExperiment step, steps formed as t_k+1 - t_k, so
    5.000000000000001e-05 among them) gives the pythonfmu plant's results."""
    from fmpy import simulate_fmu

    results = [simulate_fmu(str(folder["plant"]), stop_time=0.02, output_interval=5e-5,
                            start_values={"u[1]": 0.5, "q[1]": -0.1})
               for folder in (native_fmus, pendulum_fmus)]
    native, python = (np.column_stack([r[name] for name in r.dtype.names]) for r in results)
    assert native.shape == python.shape == (401, 7)
    assert relative(native, python) <= RTOL


@pytest.mark.slow
def test_another_design_complex_spectrum_no_perturbation_input(chain_design, tmp_path):
    """The triple integrator (k = 1, complex eigenvalues of the injection flow, no E, no
    disturbance model): native observer, Luenberger observer and plant against the pythonfmu
    ones at three step sizes and with the euler schemes (3e-4)."""
    from fhobs.build import build_fmus

    kinds = ("observer", "luenberger", "plant")
    pairs = {"pythonfmu": build_fmus(chain_design, tmp_path / "py", kinds=kinds, x0=[1, -1, 2]),
             "native": build_native_fmus(chain_design, tmp_path / "native", kinds=kinds,
                                         x0=[1, -1, 2])}
    for kind in kinds:
        for dt, scheme in [*((dt, 0) for dt in STEPS), (3e-4, 1)]:
            runs = []
            for label, built in pairs.items():
                driver = FmuDriver(built[kind], extract(str(built[kind])), label)
                variables = driver.description.modelVariables
                ins = [v.valueReference for v in variables if v.causality == "input"]
                outs = [v.valueReference for v in variables if v.causality == "output"]
                driver.fmu.setInteger([driver.vr["scheme"]], [scheme])
                driver.start()
                values = random_walk(11, 150, len(ins), 0.2)
                rows = []
                for k, row in enumerate(values):
                    driver.fmu.setReal(ins, row.tolist())
                    driver.fmu.doStep(k * dt, dt)
                    rows.append(driver.fmu.getReal(outs))
                driver.fmu.freeInstance()
                runs.append(np.array(rows))
            assert relative(runs[1], runs[0]) <= RTOL, (kind, dt, scheme)


@pytest.mark.parametrize("kind", KINDS)
def test_variable_steps_are_declared_and_the_default_experiment_is_the_pythonfmu_ones(
        pendulum_fmus, native_fmus, kind):
    """canHandleVariableCommunicationStepSize; the default experiment (or its absence) is the
    pythonfmu FMU's, so a host that derives its step from it runs both alike."""
    native, python = (read_model_description(str(p[kind])) for p in (native_fmus, pendulum_fmus))
    assert native.coSimulation.canHandleVariableCommunicationStepSize is True
    experiments = [d.defaultExperiment for d in (native, python)]
    assert [None if e is None else (e.startTime, e.stopTime, e.stepSize, e.tolerance)
            for e in experiments] == [None if e is None else (e.startTime, e.stopTime,
                                                               e.stepSize, e.tolerance)
                                      for e in experiments[::-1]]
