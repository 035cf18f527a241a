"""kalman.fmu (the steady-state Kalman filter baseline) through fmpy against the numpy runtime
(:class:`fhobs.core.kalman_filter.KalmanObserver`), its rejections of caller mistakes, and the
build's refusal of a design without a Kalman filter."""

from __future__ import annotations

import numpy as np
import pytest
from fhobs.build import build_fmus
from fhobs.core.kalman_filter import KalmanObserver
from fmpy import extract
from fmu_fixtures import FmuDriver, assert_error, random_walk


@pytest.fixture(scope="module")
def kalman_fmu(pendulum_fmus):
    """kalman.fmu of the pendulum design, from ``pendulum_fmus`` (its options are the plant's
    and h, the default: the Kalman FMU's start values are the default ones)."""
    path = pendulum_fmus["kalman"]
    return path, extract(str(path))


@pytest.fixture
def open_kalman(kalman_fmu):
    opened = []

    def factory(name="instance"):
        driver = FmuDriver(kalman_fmu[0], kalman_fmu[1], name)
        opened.append(driver)
        return driver

    yield factory
    for driver in opened:
        driver.fmu.freeInstance()


def run_fmu(driver, g, ys, us, dt):
    rows = []
    for k, (y, u) in enumerate(zip(ys, us, strict=True)):
        driver.set("y", y)
        driver.set("u", u)
        driver.fmu.doStep(k * dt, dt)
        rows.append(np.concatenate([driver.get("x_hat", (g.plant.n,)), driver.get("q_hat", (1,))]))
    return np.array(rows)


@pytest.mark.parametrize("cycles", [1, 4])
def test_fmu_equals_runtime(open_kalman, kalman_design, cycles):
    g = kalman_design
    dt = cycles * g.kalman.sample_time
    ys, us = random_walk(3, 100, g.plant.k, 0.05), random_walk(4, 100, g.plant.m, 0.1)
    driver = open_kalman()
    driver.start()
    rows = run_fmu(driver, g, ys, us, dt)
    obs = KalmanObserver(g.kalman)
    expected = []
    for y, u in zip(ys, us, strict=True):
        obs.step(y, u, dt)
        expected.append(obs.z)
    np.testing.assert_allclose(rows, np.array(expected), rtol=0, atol=1e-12)


def test_fmu_takes_any_step_as_the_runtime(open_kalman, kalman_design):
    """Steps of 0.4 Ts with the time accumulated in floating point, a short last step, then
    variable steps: the FMU runs the runtime's cycles (one per sample instant inside a step)."""
    g = kalman_design
    ts = g.kalman.sample_time
    variable = ts * np.random.default_rng(8).uniform(0.1, 3.3, 40)
    steps = [0.4 * ts] * 40 + [3e-13] + variable.tolist()
    ys, us = random_walk(3, len(steps), g.plant.k, 0.05), random_walk(4, len(steps), g.plant.m, 0.1)
    driver = open_kalman()
    driver.start()
    obs = KalmanObserver(g.kalman)
    t = 0.0
    for dt, y, u in zip(steps, ys, us, strict=True):
        driver.set("y", y)
        driver.set("u", u)
        driver.fmu.doStep(t, dt)
        t += dt
        obs.step(y, u, dt)
        got = np.concatenate([driver.get("x_hat", (g.plant.n,)), driver.get("q_hat", (1,))])
        np.testing.assert_allclose(got, obs.z, rtol=0, atol=1e-12)


def test_fmu_rejects_an_unstable_edited_gain(open_kalman, kalman_design):
    driver = open_kalman()
    driver.fmu.setupExperiment(startTime=0.0)
    driver.set("kalman_gain", -kalman_design.kalman.gain)
    driver.fmu.enterInitializationMode()
    assert_error(driver, driver.fmu.exitInitializationMode, words="schur_kalman")


def test_build_without_kalman_design_is_refused(tuned_design, tmp_path):
    with pytest.raises(ValueError, match="Kalman"):
        build_fmus(tuned_design, tmp_path, kinds=("kalman",))


def test_native_fmu_takes_any_step_as_the_runtime(kalman_design, native_fmus, tmp_path):
    """The native kalman.fmu (the shared build) under the same host-like steps: the runtime's
    cycles, and its FMU state carries the offset to the next sample."""
    g = kalman_design
    path = native_fmus["kalman"]
    ts = g.kalman.sample_time
    variable = ts * np.random.default_rng(9).uniform(0.1, 3.3, 40)
    steps = [0.4 * ts] * 40 + [3e-13] + variable.tolist()
    ys, us = random_walk(5, len(steps), g.plant.k, 0.05), random_walk(6, len(steps), g.plant.m, 0.1)
    driver = FmuDriver(path, extract(str(path), str(tmp_path / "kalman")), "native")
    try:
        driver.start()
        obs = KalmanObserver(g.kalman)
        times = np.concatenate(([0.0], np.cumsum(steps)))
        for i, (dt, y, u) in enumerate(zip(steps, ys, us, strict=True)):
            driver.set("y", y)
            driver.set("u", u)
            if i == 20:
                state, saved = driver.fmu.getFMUstate(), obs.get_state()
            driver.fmu.doStep(times[i], dt)
            obs.step(y, u, dt)
            got = np.concatenate([driver.get("x_hat", (g.plant.n,)), driver.get("q_hat", (1,))])
            np.testing.assert_allclose(got, obs.z, rtol=0, atol=1e-12)
        driver.fmu.setFMUstate(state)
        obs.set_state(saved)
        for i in range(20, 30):
            driver.set("y", ys[i])
            driver.set("u", us[i])
            driver.fmu.doStep(times[i], steps[i])
            obs.step(ys[i], us[i], steps[i])
        got = np.concatenate([driver.get("x_hat", (g.plant.n,)), driver.get("q_hat", (1,))])
        np.testing.assert_allclose(got, obs.z, rtol=0, atol=1e-12)
    finally:
        driver.fmu.freeInstance()
