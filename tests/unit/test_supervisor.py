"""The supervised observer: its Kalman part against python-control, its thresholds against a
Monte Carlo of the statistic, its handover covariance against the homogeneous observer's error
on noise, its output against the homogeneous observer and a time-varying Kalman filter written
out here, each run alone, and the switching rule's claims (no false alarm on data the Kalman
filter's model explains, dwell and handover, noise-free convergence to round-off)."""

from __future__ import annotations

import dataclasses
import json

import control
import numpy as np
import pytest
import scipy.linalg as sl
from fhobs.core.certificate import certify_supervised
from fhobs.core.errors import CertificateError
from fhobs.core.gains import SupervisedGains
from fhobs.core.runtime import FilteringObserver
from fhobs.core.supervisor import (
    MODE_HOMOGENEOUS,
    MODE_KALMAN,
    RECURSION_CYCLES,
    SupervisedObserver,
)
from fhobs.design.kalman import van_loan
from fhobs.design.observer import design_for_spec
from fhobs.design.supervised import covariance_floor, design_supervised, statistic_band
from fhobs.errors import SpecError
from reference_math import zoh
from scipy.signal import lfilter

from harness.reference import simulate

NOISY_SEEDS = range(5)


@pytest.fixture(scope="module")
def design(pendulum_spec):
    """examples/pendulum.toml's design with the Kalman filter of its [noise] table."""
    return design_for_spec(pendulum_spec)


@pytest.fixture(scope="module")
def record(design, pendulum_spec) -> SupervisedGains:
    return design_supervised(design, pendulum_spec.noise)


def run(record, ys, us, dt):
    """The supervised observer on (y, u) held over steps dt: at every t_k its output z, mode,
    both statistics, whether the time-varying recursion runs and both estimators' z."""
    obs = SupervisedObserver(record)
    rows = {"z": [], "mode": [], "statistic": [], "homogeneous_statistic": [],
            "recursion": [], "kalman": [], "homogeneous": []}
    for step in range(len(ys) + 1):
        rows["z"].append(obs.z)
        rows["mode"].append(obs.mode)
        rows["statistic"].append(obs.statistic)
        rows["homogeneous_statistic"].append(obs.homogeneous_statistic)
        rows["recursion"].append(obs.recursion)
        rows["kalman"].append(obs.kalman.z)
        rows["homogeneous"].append(obs.homogeneous.z)
        if step < len(ys):
            obs.step(ys[step], us[step], dt)
    return {name: np.array(value) for name, value in rows.items()}


def process_covariance(record):
    """Q_d of the record's Kalman filter written out with scipy (Van Loan): the white noise of
    the table's intensity on dq/dt (disturbance order 1)."""
    A, _, _ = record.kalman.model_matrices
    size = A.shape[0]
    noise = np.zeros((size, size))
    noise[-1, -1] = record.kalman.process_intensity
    F = sl.expm(record.kalman.sample_time * np.block([[-A, noise], [np.zeros_like(A), A.T]]))
    return F[size:, size:].T @ F[:size, size:]


def riccati(record, P):
    """The a-priori covariance one sample after P (the Riccati recursion in its textbook
    form) and the measurement-update gain at P."""
    A, B, C = record.kalman.model_matrices
    Phi, _ = zoh(A, B, record.kalman.sample_time)
    R = np.diag(record.kalman.measurement_std**2)
    S = C @ P @ C.T + R
    gain = P @ C.T @ np.linalg.inv(S)
    following = (Phi @ P @ Phi.T - Phi @ P @ C.T @ np.linalg.inv(S) @ C @ P @ Phi.T
                 + process_covariance(record))
    return following, gain, S


def time_varying_filter(record, z, ys, us, statistic):
    """A Kalman filter written out here from a handover (state z, covariance the record's
    handover_covariance, statistic its value): the time-varying gain until P is within 1e-9
    of the steady-state covariance, then the record's fixed gain M; its z (from the handover
    on) and statistic after every sample, and the sample at which the recursion ended."""
    A, B, C = record.kalman.model_matrices
    Phi, Gamma = zoh(A, B, record.kalman.sample_time)
    steady = record.kalman.covariance
    P, ended = record.handover_covariance, None
    rows, statistics = [z], []
    for j, (y, u) in enumerate(zip(ys, us, strict=True)):
        innovation = y - C @ z
        if ended is None:
            following, gain, S = riccati(record, P)
        else:
            following, gain, S = P, record.kalman.gain, C @ steady @ C.T + np.diag(
                record.kalman.measurement_std**2)
        nis = innovation @ np.linalg.inv(S) @ innovation
        statistic = min(statistic + (nis - statistic) / record.window, record.ceiling)
        z = Phi @ (z + gain @ innovation) + Gamma @ u
        if ended is None and np.abs(following - steady).max() <= 1e-9 * np.abs(steady).max():
            ended = j + 1
        P = following
        rows.append(z)
        statistics.append(statistic)
    return np.array(rows), np.array(statistics), ended


def noisy_run(design, record, seed):
    """The paper's noisy perturbed loop of a seed and the supervised observer replayed on its
    (y, u)."""
    result = simulate(design, "perturbed_noisy", seed=seed)
    return result, run(record, result.y, result.u, result.t[1])


def rms(values):
    return float(np.sqrt(np.mean(values**2)))


# -- design ------------------------------------------------------------------------------------
def test_kalman_part_is_the_dlqe_filter_of_the_homogeneous_model(record, pendulum_spec):
    A, _, C = record.filtering.model_matrices
    G = np.zeros((A.shape[0], 1))
    G[-1, 0] = 1.0  # the white noise drives dq/dt (disturbance order 1)
    noise = pendulum_spec.noise
    Phi, Qd = van_loan(A, noise.process_intensity * G @ G.T, noise.sample_time)
    R = np.diag(noise.measurement_std**2)
    L, P, _ = control.dlqe(Phi, np.eye(A.shape[0]), C, Qd, R)
    kalman = record.kalman
    assert kalman.disturbance_order == record.model.disturbance_order == 1
    np.testing.assert_allclose(Phi @ kalman.gain, L, rtol=1e-8, atol=1e-12 * np.abs(L).max())
    np.testing.assert_allclose(kalman.covariance, P, rtol=1e-8, atol=1e-12 * np.abs(P).max())
    assert record.lower < record.lower_return < 2 < record.upper_return < record.upper


def test_statistic_band_matches_a_monte_carlo_of_the_statistic():
    """Gaussian innovations: the normalised innovation squared is chi-square with k degrees
    of freedom; its exponential mean leaves each side of the band about as often as asked."""
    k, window, probability = 2, 50.0, 0.02
    rng = np.random.default_rng(7)
    nis = np.sum(rng.standard_normal((2_000_000, k))**2, axis=1)
    a = 1.0 / window
    statistic = lfilter([a], [1.0, a - 1.0], nis, zi=[(1.0 - a) * k])[0][10_000:]
    lower, upper = statistic_band(k, window, probability)
    for fraction in (np.mean(statistic < lower), np.mean(statistic > upper)):
        assert 0.6 * probability / 2 < fraction < 1.5 * probability / 2


def test_process_covariance_is_van_loans(record):
    """The Kalman record's Q_d (the recursion's) is the process noise's covariance over one
    sample, written out here with scipy."""
    expected = process_covariance(record)
    np.testing.assert_allclose(record.kalman.process_covariance, expected, rtol=1e-9,
                               atol=1e-12 * np.abs(expected).max())


def test_handover_covariance_is_the_homogeneous_error_floored_by_the_kalman_one(record):
    """The homogeneous observer alone on the table's noise (plant at rest; a seed the design
    does not use), floored by the Kalman filter's steady state P, is the handover covariance
    within sampling error in every direction (the error is correlated over hundreds of
    samples: two seeds' estimates of 20000 samples differ by up to 40 % in some direction,
    measured), the handover covariance is at least P, and the floor leaves a direction."""
    Ts, k = record.kalman.sample_time, record.plant.k
    observer = FilteringObserver(record.filtering, h=Ts)
    half_width = np.sqrt(3.0) * record.kalman.measurement_std
    ys = half_width * np.random.default_rng(42).uniform(-1.0, 1.0, (25_000, k))
    errors = []
    for j, y in enumerate(ys):
        observer.step(y, np.zeros(record.plant.m), Ts)
        if j >= 5_000:
            errors.append(observer.z)
    sample = np.cov(np.array(errors).T, bias=True)
    steady, handover = record.kalman.covariance, record.handover_covariance
    np.testing.assert_array_equal(handover, handover.T)
    assert np.linalg.eigvalsh(handover - steady)[0] >= -1e-12 * np.abs(handover).max()
    root = np.linalg.cholesky(covariance_floor(sample, steady))
    ratios = np.linalg.eigvalsh(np.linalg.solve(root, np.linalg.solve(root, handover).T))
    assert 0.6 < ratios[0] and ratios[-1] < 1.6
    assert np.linalg.eigvalsh(sample - steady)[-1] > 0


def test_covariance_floor_raises_the_directions_below_the_floor():
    """Random covariances (seeded): the result is at least both; where the covariance exceeds
    the floor it is kept, where it is below it the result is the floor; a state of zero
    variance in both (bordered on here, scales 1e-6 to 1e6 apart) keeps a zero row and the
    others are floored as without it."""
    rng = np.random.default_rng(4)
    scales = np.diag([1e-6, 1.0, 1e3, 1e6])
    for _ in range(20):
        root = scales @ rng.normal(size=(4, 4))
        floor = root @ root.T + 0.1 * scales**2
        assert np.allclose(covariance_floor(4.0 * floor, floor), 4.0 * floor, rtol=1e-9, atol=0)
        assert np.allclose(covariance_floor(0.25 * floor, floor), floor, rtol=1e-9, atol=0)
        other = scales @ rng.normal(size=(4, 4))
        covariance = other @ other.T
        raised = covariance_floor(covariance, floor)
        for below in (covariance, floor):
            difference = np.linalg.inv(scales) @ (raised - below) @ np.linalg.inv(scales)
            assert np.linalg.eigvalsh(difference)[0] >= -1e-9 * np.abs(difference).max()
        bordered = covariance_floor(*(np.pad(m, ((0, 1), (0, 1))) for m in (covariance, floor)))
        assert not np.any(bordered[4]) and not np.any(bordered[:, 4])
        np.testing.assert_allclose(bordered[:4, :4], raised, rtol=1e-9, atol=0)


def test_record_round_trips_and_certificate_names_the_field(record):
    back = SupervisedGains.from_dict(json.loads(json.dumps(record.to_dict())),
                                     plant=record.plant, model=record.model)
    assert back.kalman.plant is record.plant and back.filtering.model is record.model
    np.testing.assert_array_equal(back.kalman.gain, record.kalman.gain)
    np.testing.assert_array_equal(back.handover_covariance, record.handover_covariance)
    np.testing.assert_array_equal(back.kalman.process_covariance,
                                  record.kalman.process_covariance)
    assert certify_supervised(back) == record.certificate["checks"]
    indefinite = record.handover_covariance - 2 * np.abs(record.handover_covariance).max() * \
        np.eye(record.handover_covariance.shape[0])
    for change, words in (({"upper": record.upper_return}, "upper = "),
                          ({"lower_return": 2.5}, "mean k"),
                          ({"dwell_time": 0.0}, "dwell_time"), ({"window": 0.5}, "window"),
                          ({"ceiling": record.upper}, "ceiling"),
                          ({"handover_covariance": indefinite},
                           "handover_covariance must be positive definite"),
                          ({"handover_covariance": np.eye(2)}, "handover_covariance must be a"),
                          ({"kalman": dataclasses.replace(record.kalman,
                                                          process_covariance=None)},
                           "process_covariance"),
                          ({"kalman": dataclasses.replace(record.kalman, gain=-record.kalman.gain)},
                           "schur_kalman")):
        with pytest.raises(CertificateError, match=words):
            certify_supervised(dataclasses.replace(record, **change))


def test_design_refuses_a_false_alarm_rate_out_of_range_and_a_spec_without_noise(
        design, pendulum_spec):
    from fhobs.design.observer import design_for_spec

    for bad, words in (({"false_alarm": 0.5}, "false_alarm = 0.5"), ({"window": 0.0}, "window")):
        with pytest.raises(SpecError, match=words):
            design_supervised(design, pendulum_spec.noise, **bad)
    assert design_for_spec(dataclasses.replace(pendulum_spec, noise=None)).supervised is None


# -- the paper's scenarios ---------------------------------------------------------------------
@pytest.mark.slow
def test_noise_free_output_is_the_homogeneous_observer_and_reaches_round_off(design, record):
    """No noise, no disturbance: the homogeneous part is the observer run alone (never reset);
    once the transient is over the statistic stays below the band and the output is that
    observer, which reaches round-off."""
    result = simulate(design, "nominal")
    out = run(record, result.y, result.u, result.t[1])
    alone = FilteringObserver(design.filtering)
    rows = []
    for y, u in zip(result.y, result.u, strict=True):
        rows.append(alone.z)
        alone.step(y, u, result.t[1])
    rows.append(alone.z)
    np.testing.assert_allclose(out["homogeneous"], np.array(rows), rtol=0, atol=1e-12)
    settled = result.window(1.0, 3.0)
    assert np.all(out["mode"][settled] == MODE_HOMOGENEOUS)
    np.testing.assert_array_equal(out["z"][settled], out["homogeneous"][settled])
    error = np.linalg.norm(result.x - out["z"][:, :4], axis=1)
    assert error[result.window(2.5, 3.0)].max() < 1e-9 * error[0]
    assert out["statistic"][-1] < record.lower


@pytest.mark.slow
def test_perturbed_noise_free_rejects_the_disturbance(design, record):
    result = simulate(design, "perturbed")
    out = run(record, result.y, result.u, result.t[1])
    window = result.window(1.0, 3.0)
    error = np.linalg.norm(result.x - out["z"][:, :4], axis=1)[window]
    kalman = result.error_kalman[window]
    assert error.max() <= 1e-6 and kalman.max() >= 100 * error.max()
    np.testing.assert_allclose(error, result.error[window], rtol=1e-9, atol=1e-15)


@pytest.mark.slow
def test_noisy_rms_is_within_5_percent_of_the_kalman_filter(design, record):
    """The target: the mean over the seeds 0..4 of the RMS over [1, 3] s."""
    noisy = [noisy_run(design, record, seed) for seed in NOISY_SEEDS]
    kalman, homogeneous = (np.mean([rms(getattr(r, name)[r.window(1.0, 3.0)])
                                    for r, _ in noisy]) for name in ("error_kalman", "error"))
    ours = np.mean([rms(np.linalg.norm(r.x - out["z"][:, :4], axis=1)[r.window(1.0, 3.0)])
                    for r, out in noisy])
    assert ours <= 1.05 * kalman and ours < homogeneous


@pytest.mark.slow
def test_kalman_mode_is_the_filter_written_out_from_the_handover(design, record):
    """After its one switch to K (the transient over: a handover) the output and the statistic
    are those of a time-varying Kalman filter written out here with scipy, started at the
    handover from the homogeneous estimate and the handover covariance, back on the fixed gain
    at the same sample; the noisy RMS over [1, 3] s is within 5 % of the Kalman filter run
    alone (seed 0)."""
    result, out = noisy_run(design, record, 0)
    window = result.window(1.0, 3.0)
    ours = rms(np.linalg.norm(result.x - out["z"][:, :4], axis=1)[window])
    assert ours <= 1.05 * rms(result.error_kalman[window])
    switches = np.flatnonzero(np.diff(out["mode"]))
    assert len(switches) == 1 and out["mode"][-1] == MODE_KALMAN
    start = switches[0] + 1
    np.testing.assert_allclose(out["z"][start], out["homogeneous"][start], rtol=0, atol=0)
    assert out["recursion"][start] and out["statistic"][start] == \
        out["homogeneous_statistic"][start]
    expected, statistics, ended = time_varying_filter(
        record, out["homogeneous"][start], result.y[start:], result.u[start:],
        out["statistic"][start])
    np.testing.assert_allclose(out["z"][start:], expected, rtol=0,
                               atol=1e-9 * np.abs(expected).max())
    # the statistic squares innovations at the noise level (1e-3) taken from estimates of
    # size 2 over ~2e4 samples: eps 2e3 2e4 ~ 1e-8 relative between two BLAS kernels
    np.testing.assert_allclose(out["statistic"][start + 1:], statistics, rtol=1e-8)
    assert ended is not None and abs(np.argmin(out["recursion"][start:]) - ended) <= 1
    assert not out["recursion"][-1]


@pytest.mark.slow
def test_recursion_is_the_riccati_recursion_back_to_the_steady_state(record):
    """A handover forced through the state (mode K, z = 0, the handover covariance, the cycles
    left at their bound), then the table's noise at rest: the covariance after every sample is
    the Riccati recursion written out here, the recursion ends where it is within 1e-9 of the
    steady-state covariance, which is scipy's solution of the Riccati equation, and the filter
    is then the fixed-gain one."""
    Ts, k, m = record.kalman.sample_time, record.plant.k, record.plant.m
    obs = SupervisedObserver(record)
    state = obs.get_state()
    size = record.handover_covariance.size
    state[1] = MODE_KALMAN
    state[-1 - size:-1] = record.handover_covariance.ravel()
    state[-1] = RECURSION_CYCLES
    obs.set_state(state)
    amplitude = float(np.sqrt(3.0) * record.kalman.measurement_std[0])
    ys = np.random.default_rng(9).uniform(-amplitude, amplitude, (40_000, k))
    P, ended = record.handover_covariance, None
    for j, y in enumerate(ys):
        obs.step(y, np.zeros(m), Ts)
        if ended is not None:
            break
        P = riccati(record, P)[0]
        np.testing.assert_allclose(obs.covariance, P, rtol=0, atol=1e-9 * np.abs(P).max())
        if not obs.recursion:
            ended = j
    steady = record.kalman.covariance
    assert ended is not None and np.abs(P - steady).max() <= 2e-9 * np.abs(steady).max()
    A, B, C = record.kalman.model_matrices
    dare = sl.solve_discrete_are(zoh(A, B, Ts)[0].T, C.T, process_covariance(record),
                                 np.diag(record.kalman.measurement_std**2))
    np.testing.assert_allclose(steady, dare, rtol=0, atol=1e-8 * np.abs(dare).max())
    z = obs.kalman.z
    Phi = zoh(A, B, Ts)[0]
    for y in ys[-200:]:
        obs.step(y, np.zeros(m), Ts)
        z = Phi @ (z + record.kalman.gain @ (y - C @ z))
    np.testing.assert_allclose(obs.kalman.z, z, rtol=0, atol=1e-12 * np.abs(z).max())


# -- the switching rule ------------------------------------------------------------------------
def at_rest(record, seed, amplitude, n_steps):
    """The pendulum at rest (x = 0, u = 0) measured with uniform noise of the ``amplitude`` of
    each step (a number or one per step): data the Kalman filter's model explains for the
    [noise] table's amplitude."""
    rng = np.random.default_rng(seed)
    half_width = np.broadcast_to(np.asarray(amplitude, dtype=float), (n_steps,))[:, None]
    ys = half_width * rng.uniform(-1.0, 1.0, (n_steps, record.plant.k))
    return run(record, ys, np.zeros((n_steps, record.plant.m)), record.kalman.sample_time)


@pytest.mark.slow
def test_no_false_alarm_on_data_the_kalman_model_explains(record):
    """4 seeds of 1 s (80000 samples): at the documented 1e-9 per sample, 8e-5 false alarms
    are expected; the output goes to K after the dwell and stays there."""
    amplitude = float(np.sqrt(3.0) * record.kalman.measurement_std[0])
    for seed in range(4):
        out = at_rest(record, seed, amplitude, 20_000)
        switches = np.flatnonzero(np.diff(out["mode"]))
        assert len(switches) == 1 and out["mode"][-1] == MODE_KALMAN
        assert switches[0] * record.kalman.sample_time < 5 * record.dwell_time


def test_dwell_and_hysteresis_bound_the_switches(record):
    """Noise 1.6 times the table's in bursts of random lengths (50 to 1000 samples, seeded)
    between stretches of the table's noise: every H period lasts the dwell time, the switches
    to K are at most 1 + T / dwell_time, and each returns to a Kalman filter whose statistic
    is back in the return band once a burst is over, which keeps its state (no handover: the
    recursion does not start)."""
    Ts = record.kalman.sample_time
    rng = np.random.default_rng(5)
    lengths = rng.integers(50, 1000, 60)
    nominal = float(np.sqrt(3.0) * record.kalman.measurement_std[0])
    amplitude = np.concatenate([np.full(n, nominal * (1.6 if i % 2 else 1.0))
                                for i, n in enumerate(lengths)])
    out = at_rest(record, 11, amplitude, amplitude.size)
    mode = out["mode"]
    to_kalman = np.flatnonzero((mode[1:] == MODE_KALMAN) & (mode[:-1] == MODE_HOMOGENEOUS)) + 1
    to_homogeneous = np.flatnonzero((mode[1:] == MODE_HOMOGENEOUS)
                                    & (mode[:-1] == MODE_KALMAN)) + 1
    assert len(to_kalman) >= 3 and len(to_homogeneous) >= 3
    assert len(to_kalman) <= 1 + len(mode) * Ts / record.dwell_time
    for step in to_kalman:
        entered = max([0, *to_homogeneous[to_homogeneous < step]])
        assert (step - entered) * Ts >= record.dwell_time * (1 - 1e-9)
        np.testing.assert_array_equal(out["z"][step], out["kalman"][step])
        assert record.lower_return < out["statistic"][step] < record.upper_return
    assert not np.any(out["recursion"])


def test_no_handover_while_the_homogeneous_observer_is_in_its_transient(record):
    """The Kalman filter at the truth, the homogeneous observer 0.05 rad off: the Kalman
    innovations are consistent, the output returns to K after the dwell and the Kalman filter
    keeps its own estimate (the homogeneous one, still off, is not handed over)."""
    Ts, k = record.kalman.sample_time, record.plant.k
    rng = np.random.default_rng(2)
    amplitude = float(np.sqrt(3.0) * record.kalman.measurement_std[0])
    obs = SupervisedObserver(record)
    state = obs.homogeneous.get_state()
    state[0] = 0.05
    obs.homogeneous.set_state(state)
    steps = int(round(2 * record.dwell_time / Ts))
    for y in rng.uniform(-amplitude, amplitude, (steps, k)):
        obs.step(y, np.zeros(record.plant.m), Ts)
    assert obs.mode == MODE_KALMAN and obs.homogeneous_statistic > record.upper_return
    assert np.abs(obs.x_hat).max() < 10 * amplitude
    assert abs(obs.homogeneous.z[0] - obs.z[0]) > 10 * amplitude


# -- interface ---------------------------------------------------------------------------------
def test_state_round_trip_replays_and_bad_steps_leave_the_state(record):
    rng = np.random.default_rng(3)
    Ts = record.kalman.sample_time
    ys, us = rng.normal(0, 1e-3, (600, 2)), rng.normal(0, 1e-2, (600, 1))
    obs = SupervisedObserver(record)
    for y, u in zip(ys[:300], us[:300], strict=True):
        obs.step(y, u, 2 * Ts)
    state = obs.get_state()
    first = [obs.step(y, u, Ts) or obs.get_state() for y, u in zip(ys[300:], us[300:],
                                                                   strict=True)]
    obs.set_state(state)
    again = [obs.step(y, u, Ts) or obs.get_state() for y, u in zip(ys[300:], us[300:],
                                                                   strict=True)]
    np.testing.assert_array_equal(np.array(first), np.array(again))
    before = obs.get_state()
    for bad, words in (((ys[0], us[0], 1.5 * Ts), "multiple"), (([np.nan, 0.0], us[0], Ts), "y"),
                       ((ys[0], us[0], -Ts), "step size")):
        with pytest.raises(ValueError, match=words):
            obs.step(*bad)
        np.testing.assert_array_equal(obs.get_state(), before)
    with pytest.raises(ValueError, match="mode"):
        obs.set_state(np.concatenate((before[:1], [0.5], before[2:])))
    with pytest.raises(ValueError, match="cycles left"):
        obs.set_state(np.concatenate((before[:-1], [0.5])))
    np.testing.assert_array_equal(obs.get_state(), before)
    diagnostics = obs.diagnostics()
    assert diagnostics["mode"] in (MODE_KALMAN, MODE_HOMOGENEOUS)
    np.testing.assert_array_equal(diagnostics["z"], obs.z)
    assert sl.norm(obs.x_hat - obs.z[:record.plant.n]) == 0
