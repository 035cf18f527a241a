"""prescribed_time.fmu (Theorem 1) through fmpy, its prescribed-time property, its scenario.

The in-process :class:`PrescribedTimeObserver` is the reference implementation of the FMU; the
prescribed-time property is checked against the plant (a scipy ZOH of the pendulum, independent
of :mod:`fhobs.core.plant`) and against a fine-step scipy integration of the continuous-time
error dynamics of Theorem 1. Caller mistakes follow tests/fmu/test_fault_injection.py.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys

import numpy as np
import pytest
import scipy.linalg
from fhobs.core.runtime import SCHEMES, PrescribedTimeObserver
from fhobs.paper import K_PAPER, X0_PAPER
from fmpy import extract, read_model_description
from fmpy.validation import validate_fmu
from fmu_fixtures import EXAMPLES, FmuDriver, assert_error, names
from reference_math import zoh
from scipy.integrate import solve_ivp

from harness.cli import PAPER_SCENARIO_FILES, SCENARIO_DIR
from harness.system import load_system

X0 = X0_PAPER
K = K_PAPER
DT = 1e-3

needs_wrapper = pytest.mark.skipif(
    sys.platform != "linux" or shutil.which("cc") is None,
    reason="fmi2Error answers need the status wrapper (linux64, built with cc)",
)


def xi0_of(gains, T0: float) -> float:
    """xi0 with ``T0 = xi0^(-nu) / (-nu rho)``, rho the prescribed-time record's, solved here
    by hand."""
    return (-gains.model.nu * gains.prescribed_time.rho * T0) ** (-1.0 / gains.model.nu)


def closed_loop(gains, dt: float, t_end: float, T0: float = 1.0, scheme: str = SCHEMES[0],
                h: float = 5e-5):
    """The nominal pendulum (q = 0) under u = K x, the observer on its y and u from zero.

    Returns the inputs ``y`` (steps x k), ``u`` (steps x m), the observer's model state after
    each step and at the start (``z``, steps+1 x N), its xi, and the plant state ``x``.
    """
    Phi, Gamma = zoh(gains.plant.A, gains.plant.B, dt)
    obs = PrescribedTimeObserver(gains.prescribed_time, h=h, scheme=scheme, xi0=xi0_of(gains, T0))
    steps = int(round(t_end / dt))
    x = X0.copy()
    ys, us, zs, xis, xs = [], [], [obs.z], [obs.diagnostics()["xi"]], [x]
    for _ in range(steps):
        y, u = gains.plant.C @ x, K @ x
        obs.step(y, u, dt)
        x = Phi @ x + Gamma @ u
        ys.append(y), us.append(u), zs.append(obs.z), xis.append(obs.diagnostics()["xi"])
        xs.append(x)
    return np.array(ys), np.array(us), np.array(zs), np.array(xis), np.array(xs)


@pytest.fixture(scope="module")
def pt_fmu(pendulum_fmus):
    """prescribed_time.fmu of the pendulum design (default start values: T0 = 1 s), from
    ``pendulum_fmus`` (its options are the plant's and h, the default)."""
    path = pendulum_fmus["prescribed_time"]
    return path, extract(str(path))


@pytest.fixture
def open_pt(pt_fmu):
    """Factory of prescribed_time.fmu instances, freed after the test."""
    opened = []

    def factory(name: str = "instance") -> FmuDriver:
        opened.append(FmuDriver(*pt_fmu, name))
        return opened[-1]

    yield factory
    for driver in opened:
        driver.fmu.freeInstance()


def run_fmu(driver, gains, ys, us, dt=DT):
    """Step the FMU on the (y, u) sequence; the model state (x_hat, q_hat) and xi per step."""
    N = gains.model.n_model
    n = gains.plant.n
    z = [np.concatenate([driver.get("x_hat", (n,)), driver.get("q_hat", (N - n,))])]
    xi = [driver.get("xi", ())]
    for k, (y, u) in enumerate(zip(ys, us, strict=True)):
        driver.set("y", y)
        driver.set("u", u)
        driver.fmu.doStep(k * dt, dt)
        z.append(np.concatenate([driver.get("x_hat", (gains.plant.n,)),
                                 driver.get("q_hat", (N - gains.plant.n,))]))
        xi.append(driver.get("xi", ()))
    return np.array(z), np.array(xi, dtype=float)


def test_model_description_is_valid_and_declares_no_feedthrough(pt_fmu, tuned_design):
    """fmpy's validation passes; the variables are the contract's; no output depends on an
    input (the harness's algebraic-loop check relies on it)."""
    path, _ = pt_fmu
    assert validate_fmu(str(path)) == []
    description = read_model_description(str(path))
    causality = {v.name: v.causality for v in description.modelVariables}
    g = tuned_design
    outputs = ["xi", *names("x_hat", (g.plant.n,)), *names("q_hat", (g.model.n_model - g.plant.n,))]
    assert sorted(n for n, c in causality.items() if c == "output") == sorted(outputs)
    assert sorted(n for n, c in causality.items() if c == "input") == sorted(
        names("y", (g.plant.k,)) + names("u", (g.plant.m,)))
    for name, value in (("L0", g.model.L0), ("G_d", g.model.G_d),
                        ("L_pt", g.prescribed_time.L_pt), ("P_pt", g.prescribed_time.P_pt)):
        assert all(causality[n] == "parameter" for n in names(name, value.shape))
    assert {"nu", "rho", "T0", "h", "input_bound", "z0[1]", "A[1,1]"} <= set(causality)
    assert all(unknown.dependencies == [] for unknown in description.outputs)


# -- (a) the FMU is the runtime -----------------------------------------------------------------
@pytest.mark.parametrize(("scheme", "T0", "h"), [("split", 1.0, 5e-5), ("euler", 0.8, 2.5e-4)])
def test_fmu_equals_the_runtime_on_the_same_inputs(open_pt, tuned_design, scheme, T0, h):
    """Through T0 and beyond (the capped gain): x_hat, q_hat and xi of the FMU are the
    runtime's to 1e-12 relative, under both schemes; the FMU's first xi is the xi0 of its T0
    parameter."""
    ys, us, zs, xis, _ = closed_loop(tuned_design, DT, 1.2, T0=T0, scheme=scheme, h=h)
    driver = open_pt()
    start = {} if T0 == 1.0 else {"T0": T0}
    driver.fmu.setupExperiment(startTime=0.0)
    for name, value in (start | {"h": h}).items():
        driver.set(name, value)
    driver.fmu.setInteger([driver.vr["scheme"]], [SCHEMES.index(scheme)])
    driver.fmu.enterInitializationMode()
    driver.fmu.exitInitializationMode()
    z_fmu, xi_fmu = run_fmu(driver, tuned_design, ys, us)
    assert xi_fmu[0] == pytest.approx(xi0_of(tuned_design, T0), rel=1e-14)
    if scheme == "split":  # xi integrated exactly: 0 from T0 on
        assert xis[-1] == 0.0 and xi_fmu[-1] == 0.0
    scale = np.abs(zs).max(axis=0)
    np.testing.assert_allclose(z_fmu, zs, rtol=1e-12, atol=1e-12 * scale.max())
    np.testing.assert_allclose(xi_fmu, xis, rtol=1e-12, atol=0.0)


def test_first_xi_is_the_xi0_of_an_edited_rho(open_pt, tuned_design):
    """rho edited (halved: Theorem 1's LMI holds for a smaller rho): the FMU's first xi is the
    xi0 of its T0 with the edited rho, the prescribed-time record's."""
    pt = tuned_design.prescribed_time
    edited = dataclasses.replace(tuned_design, prescribed_time=dataclasses.replace(
        pt, rho=pt.rho / 2))
    driver = open_pt()
    driver.fmu.setupExperiment(startTime=0.0)
    driver.set("rho", pt.rho / 2)
    driver.fmu.enterInitializationMode()
    driver.fmu.exitInitializationMode()
    assert driver.get("xi", ()) == pytest.approx(xi0_of(edited, 1.0), rel=1e-14)
    assert xi0_of(edited, 1.0) != pytest.approx(xi0_of(tuned_design, 1.0), rel=1e-3)


# -- (b) the prescribed-time property -------------------------------------------------------------
def test_error_vanishes_at_T0_not_before(tuned_design):
    """From e0 = |x0| = 3.6 (observer at zero): at T0/2 the error is still above 1e-3 e0
    (measured 1.6e-2 e0), from T0 on below 1e-10 e0 (measured 2e-14 e0 at T0 + 5 dt)."""
    T0 = 1.0
    _, _, zs, xis, xs = closed_loop(tuned_design, DT, 1.2 * T0, T0=T0)
    error = np.linalg.norm(zs[:, :tuned_design.plant.n] - xs, axis=1)
    e0, at = error[0], lambda t: int(round(t / DT))
    assert e0 == pytest.approx(np.linalg.norm(X0))
    assert error[at(T0 / 2)] > 1e-3 * e0
    assert error[at(T0) + 5] < 1e-10 * e0
    assert error[at(T0):].max() < 1e-10 * e0
    assert np.abs(zs[at(T0):, tuned_design.plant.n:]).max() < 1e-9  # q_hat of q = 0
    assert xis[at(T0) - 1] > 0.0 and xis[at(T0) + 1] == 0.0  # 0 within a step of T0


def theorem1_error(gains, T0: float, times: list[float]) -> np.ndarray:
    """Fine-step scipy solution of Theorem 1's error dynamics of the model (q = 0, so the
    model's state is (x, 0)), e(0) = -(x0, 0): ``de/dt = (A_m + (L0 + |xi|^(nu-1)
    expm(ln|xi| (G_d - nu I)) L_pt) C_m) e``, ``dxi/dt = -rho |xi|^(1+nu)``."""
    N, n, nu = gains.model.n_model, gains.plant.n, gains.model.nu
    # q constant: dq/dt = 0
    A_m = np.block([[gains.plant.A, gains.plant.E], [np.zeros((N - n, N))]])
    C_m = np.hstack([gains.plant.C, np.zeros((gains.plant.k, N - n))])
    G = gains.model.G_d - nu * np.eye(N)
    # expm(s G) = V exp(s w) V^-1 (G is diagonalisable: checked against scipy's expm)
    w, V = np.linalg.eig(G)
    V_inv_L = np.linalg.solve(V, gains.prescribed_time.L_pt)
    np.testing.assert_allclose((V * np.exp(-2.0 * w)) @ V_inv_L,
                               scipy.linalg.expm(-2.0 * G) @ gains.prescribed_time.L_pt,
                               rtol=1e-10, atol=1e-12)

    def rate(_t, s):
        e, xi = s[:N], s[N]
        gain = xi ** (nu - 1.0) * ((V * np.exp(np.log(xi) * w)) @ V_inv_L).real
        return np.append((A_m + (gains.model.L0 + gain) @ C_m) @ e,
                         -gains.prescribed_time.rho * xi ** (1.0 + nu))

    start = np.append(-np.append(X0, np.zeros(N - n)), xi0_of(gains, T0))
    sol = solve_ivp(rate, (0.0, times[-1]), start, method="DOP853", t_eval=times,
                    rtol=1e-10, atol=1e-14)
    assert sol.success
    return sol.y[:N].T


def test_sampled_error_follows_the_continuous_theorem1_dynamics(tuned_design):
    """The split scheme freezes the gain over each step, so it follows the continuous error
    dynamics to first order in dt: up to 3 T0/4 the relative difference is below 250 dt
    (measured 24 dt at T0/4, 90 dt at T0/2, 170 dt at 3 T0/4) and shrinks by 4 +- 1 when dt
    does (measured 3.95..4.12)."""
    T0, times = 1.0, [0.25, 0.5, 0.75]
    reference = theorem1_error(tuned_design, T0, times)
    differences = {}
    for dt in (2e-4, 5e-5):
        _, _, zs, _, xs = closed_loop(tuned_design, dt, times[-1], T0=T0)
        q_states = tuned_design.model.n_model - tuned_design.plant.n
        model_x = np.hstack([xs, np.zeros((len(xs), q_states))])
        rows = [int(round(t / dt)) for t in times]
        error = zs[rows] - model_x[rows]
        differences[dt] = (np.linalg.norm(error - reference, axis=1)
                           / np.linalg.norm(reference, axis=1))
        assert np.all(differences[dt] < 250 * dt), (dt, differences[dt])
    ratio = differences[2e-4] / differences[5e-5]
    assert np.all((ratio > 3.0) & (ratio < 5.0)), ratio


# -- (c) the bundled scenario -------------------------------------------------------------------
def test_scenario_is_the_nominal_loop_with_the_prescribed_time_observer():
    """Perturbation off, prescribed_time on plant.y and on u = K x_hat of the filtering
    observer like the other observers, its error evaluated at T0/2, T0 and after; not one of
    the paper's scenarios."""
    spec = load_system(SCENARIO_DIR / "pendulum_prescribed_time.toml")
    assert "perturbation" not in spec.fmus and spec.fmus["plant"].start["q[1]"] == 0.0
    assert spec.fmus["prescribed_time"].path.name == "prescribed_time.fmu"
    T0 = spec.fmus["prescribed_time"].start["T0"]
    into = {c.target: c for c in spec.connections}
    assert into["prescribed_time.y"].source == "plant.y"
    assert into["prescribed_time.u"].source == "observer.x_hat"
    for observer in ("prescribed_time", "linear", "kalman", "observer"):
        np.testing.assert_array_equal(into[f"{observer}.u"].gain, K)
    assert spec.evaluation.errors["prescribed_time"] == ("plant.x", "prescribed_time.x_hat")
    assert T0 / 2 in spec.evaluation.at and max(spec.evaluation.at) >= T0
    assert "pendulum_prescribed_time" not in PAPER_SCENARIO_FILES.values()


@pytest.mark.slow
def test_scenario_runs_with_the_fmus_of_build_fmu(tmp_path, capsys):
    """``build_fmu.py examples/pendulum.toml`` then ``python -m harness run
    pendulum_prescribed_time``: the summary has the prescribed-time error, tiny from T0 on
    (measured 2.4e-12 at T0, 5.0e-13 at 1.5 s; 5.2e-2 at T0/2)."""
    from fhobs.cli import main as build_main

    from harness.cli import main as harness_main

    assert build_main([str(EXAMPLES / "pendulum.toml"), "--out", str(tmp_path / "fmus")]) == 0
    assert (tmp_path / "fmus" / "prescribed_time.fmu").is_file()
    assert harness_main(["run", "pendulum_prescribed_time", "--fmu-dir", str(tmp_path / "fmus"),
                         "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    capsys.readouterr()
    figures = json.loads((tmp_path / "out" / "summary.json").read_text())["prescribed_time"]
    e0 = np.linalg.norm(X0)
    assert figures["error_at_0_5"] > 1e-3 * e0
    assert figures["error_at_1"] < 1e-10 * e0
    assert figures["error_at_1_5"] < 1e-10 * e0
    assert figures["max_error_1_3"] < 1e-10 * e0


# -- (d) caller mistakes ------------------------------------------------------------------------
def steps(driver, count: int, first: int = 0) -> np.ndarray:
    """``count`` steps with fixed inputs from step ``first``; x_hat and xi after them."""
    for k in range(first, first + count):
        driver.set("y", np.array([0.3, -0.2]))
        driver.set("u", np.array([0.1]))
        driver.fmu.doStep(k * DT, DT)
    return np.append(driver.get("x_hat", (4,)), driver.get("xi", ()))


@needs_wrapper
def test_mistakes_are_errors_the_instance_stays_usable(open_pt):
    """Unknown value reference, non-finite input, a parameter written in step mode: fmi2Error
    with the reason, the state untouched, the run then equal to a clean run."""
    clean = open_pt("clean")
    clean.start()
    reference = steps(clean, 5)
    driver = open_pt()
    driver.start()
    assert_error(driver, driver.fmu.getReal, [99999], words="value reference 99999 is not a")
    steps(driver, 2)
    before = np.append(driver.get("x_hat", (4,)), driver.get("xi", ()))
    driver.set("y", np.array([np.inf, 0.0]))
    assert_error(driver, driver.fmu.doStep, 2 * DT, DT, words="input y[1] = inf is not finite")
    np.testing.assert_array_equal(np.append(driver.get("x_hat", (4,)), driver.get("xi", ())),
                                  before)
    vr = driver.vr["L_pt[1,1]"]
    assert_error(driver, driver.fmu.setReal, [vr], [0.0], words="L_pt[1,1] (value reference")
    np.testing.assert_array_equal(steps(driver, 3, first=2), reference)


@needs_wrapper
def test_fmu_state_replays_the_run(open_pt):
    driver = open_pt()
    driver.start()
    steps(driver, 3)
    state = driver.fmu.getFMUstate()
    after = steps(driver, 4, first=3)
    driver.fmu.setFMUstate(state)
    driver.fmu.freeFMUstate(state)
    np.testing.assert_array_equal(steps(driver, 4, first=3), after)


@needs_wrapper
def test_edited_L_pt_that_breaks_theorem1_fails_initialisation(open_pt, tuned_design):
    """L_pt -> -L_pt makes A0 + L_pt C + rho (G_d - nu I) non-Hurwitz (checked here with numpy),
    so no P_pt can satisfy Theorem 1's LMI: exitInitializationMode answers fmi2Error naming the
    check, doStep is refused; corrected, the instance initialises."""
    g = tuned_design
    N, n = g.model.n_model, g.plant.n
    A_m = np.block([[g.plant.A, g.plant.E], [np.zeros((N - n, N))]])
    C_m = np.hstack([g.plant.C, np.zeros((g.plant.k, N - n))])
    H = (A_m + (g.model.L0 - g.prescribed_time.L_pt) @ C_m
         + g.prescribed_time.rho * (g.model.G_d - g.model.nu * np.eye(N)))
    assert np.linalg.eigvals(H).real.max() > 0.0
    driver = open_pt()
    driver.fmu.setupExperiment(startTime=0.0)
    driver.set("L_pt", -g.prescribed_time.L_pt)
    driver.fmu.enterInitializationMode()
    assert_error(driver, driver.fmu.exitInitializationMode, words="lmi_pt")
    assert "hurwitz_pt" in driver.messages[-1][1]
    assert_error(driver, driver.fmu.doStep, 0.0, DT,
                 words="fmi2DoStep is not allowed in the state initialisation mode")
    driver.set("L_pt", g.prescribed_time.L_pt)
    driver.fmu.exitInitializationMode()
    steps(driver, 1)


@needs_wrapper
@pytest.mark.parametrize(
    ("edit", "words"),
    [
        ({"T0": 0.0}, "prescribed time T0 = 0.0 is not a positive finite number"),
        ({"T0": 1e-300}, "T0 = 1e-300 s gives xi0"),
        ({"rho": -1.0}, "rho = -1.0 must be > 0"),
        ({"nu": 0.1}, "nu = 0.1 is outside [-1/(n_tilde+1), 0)"),
        ({"G_d[1,1]": 5.0}, "homogenisation_residual"),
        ({"P_pt[1,1]": -1.0}, "P_pt_positive"),
    ],
)
def test_edited_parameters_outside_theorem1_fail_initialisation(open_pt, edit, words):
    driver = open_pt()
    driver.fmu.setupExperiment(startTime=0.0)
    for name, value in edit.items():
        driver.fmu.setReal([driver.vr[name]], [value])
    driver.fmu.enterInitializationMode()
    assert_error(driver, driver.fmu.exitInitializationMode, words=words)
