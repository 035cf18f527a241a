"""The Kalman filter's communication steps of any size: one cycle per sample instant inside a
step, the estimate held between samples. The runtime is compared with the filter's equations
written out here on sample instants counted in exact rational arithmetic (``fractions``), so
the runtime's floating-point offset bookkeeping is checked against an independent count."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from fhobs.core.disturbance import extended_model
from fhobs.core.kalman_filter import SAMPLE_SLACK, KalmanObserver, samples_in_step
from fmu_fixtures import random_walk
from reference_math import zoh


def exact_reference(gains, steps, ys, us):
    """z after each step: the filter's update and exact-ZOH prediction, run once for every
    sample instant j Ts with t_k <= j Ts < t_k+1 (rational times; a sample within
    SAMPLE_SLACK Ts of the step's end counts in the next step, as the documented convention)."""
    kf = gains.kalman
    A, B, C = extended_model(gains.plant.A, gains.plant.B, gains.plant.C, gains.plant.E,
                             kf.disturbance_order)
    Phi, Gamma = zoh(A, B, kf.sample_time)
    ts = Fraction(kf.sample_time)
    slack = Fraction(SAMPLE_SLACK) * ts
    z, t, j, rows = np.zeros(A.shape[0]), Fraction(0), 0, []
    for dt, y, u in zip(steps, ys, us, strict=True):
        end = t + Fraction(dt)
        while j * ts < end - slack:
            z = Phi @ (z + kf.gain @ (y - C @ z)) + Gamma @ u
            j += 1
        t = end
        rows.append(z)
    return np.array(rows)


def run(gains, steps, ys, us, kernel=True):
    obs = KalmanObserver(gains.kalman, kernel=kernel)
    rows = []
    for dt, y, u in zip(steps, ys, us, strict=True):
        obs.step(y, u, dt)
        rows.append(obs.z)
    return np.array(rows)


def host_steps(ts: float, pattern: str) -> list[float]:
    """Communication steps as a host forms them (the times accumulated in floating point)."""
    rng = np.random.default_rng(11)
    if pattern == "accumulated":  # t += 0.4 Ts to 300 Ts, the last step cut to the stop time
        times, t = [0.0], 0.0
        while t + 0.4 * ts < 300 * ts:
            t += 0.4 * ts
            times.append(t)
        times.append(300 * ts)
        return np.diff(times).tolist()
    if pattern == "variable":
        return (ts * rng.uniform(0.05, 3.7, 400)).tolist()
    if pattern == "never_seen":  # 0.7 Ts, then 2.3 Ts
        return [0.7 * ts] * 150 + [2.3 * ts] * 100
    raise ValueError(pattern)


@pytest.mark.parametrize("pattern", ["accumulated", "variable", "never_seen"])
def test_any_step_runs_the_samples_inside_it(kalman_design, pattern):
    g = kalman_design
    steps = host_steps(g.kalman.sample_time, pattern)
    ys, us = random_walk(3, len(steps), g.plant.k, 0.05), random_walk(4, len(steps), g.plant.m, 0.1)
    expected = exact_reference(g, steps, ys, us)
    for kernel in (True, False):
        got = run(g, steps, ys, us, kernel)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_short_last_step_holds_the_estimate(kalman_design):
    """A host's last step of 3e-13 s, no sample instant inside: the estimate is held."""
    g = kalman_design
    obs = KalmanObserver(g.kalman)
    ts = g.kalman.sample_time
    for _ in range(10):
        obs.step(np.array([0.1, 0.2]), np.array([0.3]), ts * (1 - 1e-12))
    before = obs.z
    obs.step(np.array([5.0, 5.0]), np.array([5.0]), 3e-13)
    np.testing.assert_array_equal(obs.z, before)
    obs.step(np.array([0.1, 0.2]), np.array([0.3]), 0.5 * ts)  # the next sample is at its start
    assert not np.array_equal(obs.z, before)


def test_samples_in_step_counts_against_exact_arithmetic():
    rng = np.random.default_rng(5)
    ts = 1e-3
    offset, t = 0.0, Fraction(0)
    samples = 0
    for dt in ts * rng.uniform(0.01, 5.0, 2000):
        n, offset = samples_in_step(offset, float(dt), ts)
        samples += n
        t += Fraction(float(dt))
        exact = int(np.ceil(float(t / Fraction(ts)) - SAMPLE_SLACK))
        assert samples == exact
        assert 0.0 <= offset < ts


def test_too_many_samples_rejected_state_kept(kalman_design):
    obs = KalmanObserver(kalman_design.kalman)
    before = obs.get_state()
    with pytest.raises(ValueError, match="more than"):
        obs.step(np.array([0.1, 0.2]), np.array([0.3]), 1e7 * kalman_design.kalman.sample_time)
    np.testing.assert_array_equal(obs.get_state(), before)


def test_state_carries_the_offset(kalman_design):
    g = kalman_design
    ts = g.kalman.sample_time
    obs = KalmanObserver(g.kalman)
    obs.step(np.array([0.1, 0.2]), np.array([0.3]), 0.3 * ts)
    state = obs.get_state()
    assert state.size == obs.z.size + 1 and state[-1] == pytest.approx(0.7 * ts)
    first = [obs.step(np.array([0.1, 0.2]), np.array([0.3]), 0.45 * ts) or obs.z
             for _ in range(5)]
    obs.set_state(state)
    again = [obs.step(np.array([0.1, 0.2]), np.array([0.3]), 0.45 * ts) or obs.z
             for _ in range(5)]
    np.testing.assert_array_equal(np.array(first), np.array(again))
    for offset in (-1e-9, ts, np.nan):
        with pytest.raises(ValueError, match="Kalman state"):
            obs.set_state(np.append(obs.z, offset))
    np.testing.assert_array_equal(obs.get_state(), np.append(again[-1], obs.get_state()[-1]))
