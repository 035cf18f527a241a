"""The native prescribed_time.fmu against the pythonfmu one under fmpy: the pendulum's nominal
closed loop (u = K x, the observer from zero) with host-like steps (time accumulated in floating
point with a short last step, seeded variable steps), to 1e-12 relative; the prescribed-time
property (the error at T0 and after); FMU states; refusals (T0, non-finite inputs, compiled
parameters, the euler scheme) as fmi2Error with a message, the state kept."""

from __future__ import annotations

import shutil
import sys

import numpy as np
import pytest
from fhobs.paper import K_PAPER, X0_PAPER
from fmpy import extract
from fmpy.fmi1 import FMICallException
from fmu_fixtures import FmuDriver, assert_error
from reference_math import zoh

pytestmark = pytest.mark.skipif(
    sys.platform != "linux" or shutil.which("cc") is None,
    reason="native FMUs are built for linux64 with cc",
)

RTOL = 1e-12
T0 = 1.0
N, N_MODEL = 4, 5


@pytest.fixture(scope="module")
def native_pt(native_fmus):
    """The native prescribed_time.fmu of the design and options of ``pendulum_fmus`` (the
    shared build: the options other than h are the plant's)."""
    return native_fmus["prescribed_time"]


@pytest.fixture
def open_pair(pendulum_fmus, native_pt, tmp_path):
    """Factory ``open_pair(parameters=None, start=True)`` -> (pythonfmu, native) drivers."""
    opened = []

    def factory(parameters: dict | None = None, start: bool = True):
        pair = []
        for label, path in (("pythonfmu", pendulum_fmus["prescribed_time"]),
                            ("native", native_pt)):
            folder = extract(str(path), str(tmp_path / f"{label}_{len(opened)}"))
            driver = FmuDriver(path, folder, label)
            opened.append(driver)
            if start:
                driver.start(parameters)
            pair.append(driver)
        return tuple(pair)

    yield factory
    for driver in opened:
        driver.fmu.freeInstance()


def outputs(driver: FmuDriver) -> np.ndarray:
    """x_hat, q_hat, xi."""
    return np.concatenate([driver.get("x_hat", (N,)), driver.get("q_hat", (1,)),
                           [driver.get("xi", ())[()]]])


def closed_loop(gains, steps: np.ndarray, drivers: tuple[FmuDriver, ...]) -> tuple:
    """The nominal pendulum under u = K x (ZOH per step), each driver stepped with its y and u
    and the host's time ``t += dt``; the plant states and each driver's outputs (rows)."""
    x, t = X0_PAPER.copy(), 0.0
    xs, rows = [], [[] for _ in drivers]
    holds = {}  # the plant's ZOH per step size (a host's steps repeat)
    for dt in steps:
        y, u = gains.plant.C @ x, K_PAPER @ x
        for driver, out in zip(drivers, rows, strict=True):
            driver.set("y", y)
            driver.set("u", u)
            driver.fmu.doStep(t, dt)
            out.append(outputs(driver))
        if dt not in holds:
            holds[dt] = zoh(gains.plant.A, gains.plant.B, dt)
        Phi, Gamma = holds[dt]
        x = Phi @ x + Gamma @ u
        t += dt
        xs.append(x)
    return np.array(xs), [np.array(r) for r in rows]


def accumulated_steps(step: float, stop: float) -> np.ndarray:
    """A host's steps: t += step in floating point, the last one cut to the stop time."""
    steps, t = [], 0.0
    while t < stop:
        steps.append(min(step, stop - t))
        t += steps[-1]
    return np.array(steps)


def assert_rows_agree(native: np.ndarray, python: np.ndarray) -> float:
    error = max(np.linalg.norm(a - b) / np.linalg.norm(b) for a, b in zip(native, python,
                                                                           strict=True))
    assert error <= RTOL, error
    return error


def test_accumulated_time_and_a_short_last_step(open_pair, kalman_design):
    python, native = open_pair()
    steps = accumulated_steps(1e-3, 1.3)
    assert steps[-1] < 1e-9  # the host's round-off step
    xs, (p_rows, n_rows) = closed_loop(kalman_design, steps, (python, native))
    assert_rows_agree(n_rows, p_rows)
    times = np.cumsum(steps)
    after = times >= 1.05 * T0
    error = np.abs(n_rows[after, :N] - xs[after]).max() / np.abs(xs[after]).max()
    assert error < 1e-8, error  # exact from T0 on, up to the sampled observer's cap
    assert n_rows[times >= T0 + 1e-9, -1].max() == 0.0  # xi reaches 0 at T0 and stays


def test_variable_steps(open_pair, kalman_design):
    python, native = open_pair()
    rng = np.random.default_rng(3)
    sizes = np.array([2e-4, 5e-4, 1e-3, 2.5e-3, 7e-4, 3e-3])
    steps = rng.choice(sizes, 600)
    closed = closed_loop(kalman_design, steps, (python, native))[1]
    assert_rows_agree(closed[1], closed[0])


def test_state_get_set_serialize_round_trip(open_pair, kalman_design):
    _, native = open_pair()
    fmu = native.fmu
    steps = np.full(300, 2e-3)
    closed_loop(kalman_design, steps[:100], (native,))
    state = fmu.getFMUstate()
    blob = fmu.serializeFMUstate(state)
    before = outputs(native)
    fmu.doStep(0.2, 2e-3)
    after = outputs(native)
    restored = fmu.deSerializeFMUstate(blob)
    fmu.setFMUstate(restored)
    assert np.array_equal(outputs(native), before)
    fmu.doStep(0.2, 2e-3)
    assert np.array_equal(outputs(native), after)
    fmu.freeFMUstate(state)
    fmu.freeFMUstate(restored)


@pytest.mark.parametrize("value", [0.0, -1.0, np.inf, np.nan, 1e-300])
def test_bad_T0_is_refused_at_initialisation(open_pair, value):
    python, native = open_pair(start=False)
    for driver in (python, native):
        driver.fmu.setupExperiment(startTime=0.0)
        driver.fmu.enterInitializationMode()
        driver.set("T0", value)
    assert_error(native, native.fmu.exitInitializationMode, words="T0")


def test_T0_sets_the_prescribed_time(open_pair, kalman_design):
    python, native = open_pair({"T0": 0.4})
    steps = np.full(300, 2e-3)
    xs, (p_rows, n_rows) = closed_loop(kalman_design, steps, (python, native))
    assert_rows_agree(n_rows, p_rows)
    assert n_rows[0, -1] > 0.0 and n_rows[200:, -1].max() == 0.0


def test_non_finite_inputs_are_refused_with_the_state_kept(open_pair, kalman_design):
    python, native = open_pair()
    closed_loop(kalman_design, np.full(20, 1e-3), (python, native))
    kept = outputs(native)
    native.set("y", [np.nan, 0.0])
    assert_error(native, native.fmu.doStep, 0.02, 1e-3, words="y")
    assert np.array_equal(outputs(native), kept)
    for driver in (python, native):
        driver.set("y", [0.1, 0.2])
        driver.set("u", [0.0])
        driver.fmu.doStep(0.02, 1e-3)
    assert_rows_agree([outputs(native)], [outputs(python)])


def test_compiled_parameters_and_the_euler_scheme(open_pair, kalman_design):
    _, native = open_pair(start=False)
    fmu = native.fmu
    native.set("rho", float(kalman_design.filtering.rho))  # the built value: accepted
    with pytest.raises(FMICallException):
        native.set("rho", float(kalman_design.filtering.rho) * 2.0)
    assert "compiled into the native FMU" in native.messages[-1][1]
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setInteger([native.vr["scheme"]], [1])
    assert_error(native, fmu.exitInitializationMode, words="split scheme only")
