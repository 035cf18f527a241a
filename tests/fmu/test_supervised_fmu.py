"""supervised.fmu in both builds against the numpy runtime (fhobs.core.supervisor): the
paper's closed loop (u = K x_hat, the sinusoidal perturbation through E) run three times, the
plant in process and the estimator either SupervisedObserver in process, the pythonfmu FMU or
the native FMU, noise-free and with seeded measurement noise (a handover and the Kalman
filter's time-varying recursion after it); the step sizes the Kalman filter refuses; FMU
states taken before a handover; edited parameters re-certified."""

from __future__ import annotations

import numpy as np
import pytest
from fhobs.build import build_fmus
from fhobs.core.plant import LTIPlant
from fhobs.core.supervisor import MODE_HOMOGENEOUS, MODE_KALMAN, SupervisedObserver
from fhobs.native.build import build_native_fmus
from fhobs.paper import K_PAPER, PAPER_SCENARIOS
from fmpy import extract

from tests.fmu_fixtures import FmuDriver, assert_error, forged, serialized

SCENARIO = PAPER_SCENARIOS["perturbed_noisy"]
SAMPLES_PER_STEP = 4
STEPS = 6000
AGREEMENT = 1e-12
"""Largest difference between two runs of a signal, relative to the signal's largest size."""
ROUNDOFF_FLOOR_AGREEMENT = 1e-9
"""The same for the native q_hat and statistic of a noise-free run: once the filtering
observer's error is at its round-off floor its gain level is large and amplifies the 1e-12
differences between the native step plans (computed in C) and the numpy runtime's (the native
observer.fmu alone shows the same q_hat difference on this loop: 1.5e-10 measured), and the
statistic is then a mean of innovations at round-off level."""


@pytest.fixture(scope="module")
def design(pendulum_spec):
    """examples/pendulum.toml's design: its [noise] table gives the supervised record."""
    from fhobs.design.observer import design_for_spec

    return design_for_spec(pendulum_spec)


@pytest.fixture(scope="module")
def fmus(design, tmp_path_factory):
    """supervised.fmu of both builds: {build: (path, extracted folder)}."""
    built = {"pythonfmu": build_fmus(design, tmp_path_factory.mktemp("py"),
                                     kinds=["supervised"])["supervised"],
             "native": build_native_fmus(design, tmp_path_factory.mktemp("native"),
                                         kinds=["supervised"])["supervised"]}
    return {build: (path, extract(str(path))) for build, path in built.items()}


@pytest.fixture
def open_supervised(fmus):
    """Factory of started supervised FMU instances of a build, freed after the test."""
    opened = []

    def factory(build: str, parameters: dict | None = None) -> FmuDriver:
        driver = FmuDriver(*fmus[build], instance_name=f"supervised_{len(opened)}")
        opened.append(driver)
        if parameters is not False:
            driver.start(parameters)
        return driver

    yield factory
    for driver in opened:
        driver.fmu.freeInstance()


class _InProcess:
    """SupervisedObserver behind the drivers' interface."""

    def __init__(self, record) -> None:
        self.model = SupervisedObserver(record)
        self.recursion: list[bool] = []  # after every step: the time-varying recursion on

    def step(self, y, u, t, dt):  # noqa: ANN001, ARG002
        self.model.step(y, u, dt)
        self.recursion.append(self.model.recursion)

    def outputs(self, n, q):  # noqa: ANN001
        return (self.model.x_hat, self.model.q_hat, self.model.mode, self.model.statistic)


class _Fmu:
    """A started FMU instance behind the same interface."""

    def __init__(self, driver: FmuDriver) -> None:
        self.driver = driver

    def step(self, y, u, t, dt):  # noqa: ANN001
        self.driver.set("y", y)
        self.driver.set("u", u)
        self.driver.fmu.doStep(t, dt)

    def outputs(self, n, q):  # noqa: ANN001
        get = self.driver.get
        return get("x_hat", (n,)), get("q_hat", (q,)), get("mode", ())[()], \
            get("statistic", ())[()]


def closed_loop(estimator, design, seed: int, noise: float) -> dict[str, np.ndarray]:
    """The paper's loop with ``estimator``: the plant from a seeded x0, y_k with uniform noise
    of amplitude ``noise``, u_k = K x_hat_k, q_k = a sin(w t_k) held; every t_k's outputs."""
    plant_model, record = design.plant, design.supervised
    n, q_size = plant_model.n, record.model.n_model - plant_model.n
    dt = SAMPLES_PER_STEP * record.kalman.sample_time
    x0 = np.random.default_rng(seed).uniform(-0.5, 0.5, n)
    plant = LTIPlant(plant_model.A, plant_model.B, plant_model.C, E=plant_model.E, x0=x0,
                     noise_amplitude=noise, seed=seed)
    rows = {"x_hat": [], "q_hat": [], "mode": [], "statistic": [], "x": [], "y": [], "u": []}
    for k in range(STEPS):
        t = k * dt
        x_hat, q_hat, mode, statistic = estimator.outputs(n, q_size)
        y, u = plant.y, K_PAPER @ x_hat
        for name, value in zip(rows, (x_hat, q_hat, mode, statistic, plant.x, y, u),
                               strict=True):
            rows[name].append(np.array(value, dtype=float))
        estimator.step(y, u, t, dt)
        plant.step(u, [SCENARIO.q_amplitude * np.sin(SCENARIO.q_frequency * t)], dt)
    return {name: np.array(value) for name, value in rows.items()}


def assert_agree(run, reference, what, loose=()):  # noqa: ANN001
    """Every signal of ``run`` within AGREEMENT of the reference's largest size (those named in
    ``loose`` within ROUNDOFF_FLOOR_AGREEMENT)."""
    for name, values in reference.items():
        scale = max(float(np.max(np.abs(values))), np.finfo(float).tiny)
        gap = float(np.max(np.abs(run[name] - values)))
        bound = ROUNDOFF_FLOOR_AGREEMENT if name in loose else AGREEMENT
        assert gap <= bound * scale, (what, name, gap / scale)


@pytest.mark.parametrize("noise, seed", [(0.0, 1), (SCENARIO.noise_amplitude, 2),
                                         (SCENARIO.noise_amplitude, 3)])
@pytest.mark.slow
def test_both_builds_run_the_numpy_runtime(design, open_supervised, noise, seed):
    """The closed loop through the pythonfmu and the native FMU agrees with SupervisedObserver
    to 1e-12 of each signal's size (ROUNDOFF_FLOOR_AGREEMENT for two native signals without
    noise); with noise the output switches to the Kalman estimate at least once and the
    time-varying recursion runs after a handover and ends (the statistic, the mode logic, the
    handover and the recursion are all exercised); the estimate converges."""
    in_process = _InProcess(design.supervised)
    reference = closed_loop(in_process, design, seed, noise)
    for build in ("pythonfmu", "native"):
        loose = ("q_hat", "statistic") if build == "native" and not noise else ()
        assert_agree(closed_loop(_Fmu(open_supervised(build)), design, seed, noise), reference,
                     build, loose)
    modes = reference["mode"]
    assert modes[0] == MODE_HOMOGENEOUS
    if noise:
        assert np.any(modes == MODE_KALMAN) and np.count_nonzero(np.diff(modes)) >= 1
        assert any(in_process.recursion) and not in_process.recursion[-1]
    else:  # noise-free: the statistic ends below `lower`, the output on the homogeneous estimate
        assert reference["statistic"][-1] < design.supervised.lower
        assert modes[-1] == MODE_HOMOGENEOUS
    error = np.abs(reference["x_hat"][-100:] - reference["x"][-100:]).max()
    assert error < 0.05 * np.abs(reference["x"]).max()


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
def test_a_step_that_is_not_a_multiple_of_Ts_is_an_error(design, open_supervised, build):
    """fmi2Error naming the rule, the state (outputs, then the next valid step) unchanged."""
    Ts = design.supervised.kalman.sample_time
    driver, twin = open_supervised(build), open_supervised(build)
    for fmu in (driver, twin):
        fmu.set("y", [0.1, -0.2])
        fmu.fmu.doStep(0.0, 3 * Ts)
    before = driver.get("x_hat", (4,))
    assert_error(driver, driver.fmu.doStep, 3 * Ts, 1.5 * Ts, words="whole multiple")
    np.testing.assert_array_equal(driver.get("x_hat", (4,)), before)
    for fmu in (driver, twin):
        fmu.fmu.doStep(3 * Ts, 2 * Ts)
    np.testing.assert_array_equal(driver.get("x_hat", (4,)), twin.get("x_hat", (4,)))


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
def test_fmu_state_round_trip(design, open_supervised, build):
    """A state taken in mode H shortly before the switch to K (and its handover), set again,
    also serialized and into a second instance, replays the same outputs bit for bit."""
    in_process = _InProcess(design.supervised)
    recorded = closed_loop(in_process, design, 2, SCENARIO.noise_amplitude)
    first_kalman = int(np.argmax(recorded["mode"] == MODE_KALMAN))
    assert first_kalman > 0 and in_process.recursion[first_kalman - 1]  # a handover
    dt = SAMPLES_PER_STEP * design.supervised.kalman.sample_time
    driver = _Fmu(open_supervised(build))
    fmu = driver.driver.fmu
    start = first_kalman - 100
    for k in range(start):
        driver.step(recorded["y"][k], recorded["u"][k], k * dt, dt)
    state = fmu.getFMUstate()
    serialized = fmu.serializeFMUstate(state)

    def replay(target: _Fmu) -> np.ndarray:
        rows = []
        for k in range(start, first_kalman + 300):
            target.step(recorded["y"][k], recorded["u"][k], k * dt, dt)
            rows.append(np.hstack(target.outputs(4, 1)))
        return np.array(rows)

    first = replay(driver)
    fmu.setFMUstate(state)
    np.testing.assert_array_equal(replay(driver), first)
    other = _Fmu(open_supervised(build))
    other.driver.fmu.setFMUstate(other.driver.fmu.deSerializeFMUstate(serialized))
    np.testing.assert_array_equal(replay(other), first)
    assert MODE_KALMAN in first[:, 5] and MODE_HOMOGENEOUS in first[:, 5]
    fmu.freeFMUstate(state)


def test_edited_parameters_are_certified_again(design, open_supervised):
    """pythonfmu: exitInitializationMode refuses an `upper` inside the return band (the
    hysteresis) with fmi2Error; a band edited within range is accepted and run."""
    record = design.supervised
    driver = open_supervised("pythonfmu", parameters=False)
    driver.fmu.setupExperiment(startTime=0.0)
    driver.set("upper", record.upper_return)
    driver.fmu.enterInitializationMode()
    assert_error(driver, driver.fmu.exitInitializationMode, words="upper = ")
    driver.set("upper", 1.5 * record.upper)
    driver.fmu.exitInitializationMode()
    driver.fmu.doStep(0.0, record.kalman.sample_time)


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
@pytest.mark.parametrize("field, value, words", [
    (1, 0.5, "mode"), (1, 7.0, "mode"), (0, -1.0, "statistic"), (3, -1e-3, "time in"),
    (-1, 1e9, "cycles left")])
def test_a_forged_state_is_refused(open_supervised, build, field, value, words):
    """A serialized state with one count, mode or time forged and its checksum recomputed (a
    checksum proves nothing): fmi2DeSerializeFMUstate or fmi2SetFMUstate refuses it with
    fmi2Error naming the field; the instance steps on. Head: statistic, mode, (kept), time in
    the return band; the last entry: the Kalman recursion's cycles left."""
    driver = open_supervised(build)
    Ts = 5e-5
    for k in range(4):
        driver.fmu.doStep(k * 2 * Ts, 2 * Ts)
    data = serialized(driver)

    def edit(model: list[float]) -> None:
        model[field] = value

    bad = forged(driver, build, data, edit)
    if build == "native":
        assert_error(driver, driver.fmu.deSerializeFMUstate, bad, words=words)
    else:  # the pythonfmu FMU checks a restored state where it is set
        state = driver.fmu.deSerializeFMUstate(bad)
        assert_error(driver, driver.fmu.setFMUstate, state, words=words)
    driver.fmu.doStep(8 * Ts, 2 * Ts)
    assert np.all(np.isfinite(driver.get("x_hat", (4,))))
