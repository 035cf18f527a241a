"""The stiff plants of examples/stiff/: each designs with the defaults and meets its settling
time; on the DC motor, after the load step, the homogeneous observer's noise-free steady error is
not above the tuned Kalman filter's and its load estimate reaches 1 % first.

The closed loop is run in process (the plant's exact ZOH step, LQR feedback on the true state,
the spec's load step); the Kalman filter of the same extended model is tuned on that run (the
intensity of least steady error, as bench/bench_real_plants.py does) and its gain checked
against an independent Van Loan discretisation and scipy's discrete Riccati solver.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from fhobs.core.disturbance import extended_model
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver
from fhobs.design.feedback import state_feedback
from fhobs.design.kalman import design_kalman
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import load_spec
from fhobs.paper import EXAMPLES

STIFF = EXAMPLES / "stiff"
EXPECTED_FAILURES = {
    "aircraft_longitudinal": "5 s is not reachable within a peaking of 1e3 (the phugoid's "
                             "states seen through the pitch angle): the design takes the "
                             "fastest within the limit, about 10 s, and says the request is "
                             "not met",
}
Q_BAND = 0.01
ROUND_OFF = 1e-9
"""Steady errors (state_scale units) below this are both at round-off."""


def spec_params():
    return [pytest.param(path.stem, marks=[pytest.mark.xfail(
                reason=EXPECTED_FAILURES[path.stem], strict=True)]
            if path.stem in EXPECTED_FAILURES else [])
            for path in sorted(STIFF.glob("*.toml"))]


@pytest.fixture(scope="module")
def dc_motor():
    spec = load_spec(STIFF / "dc_motor.toml")
    return spec, design_for_spec(spec)


@pytest.mark.slow
@pytest.mark.parametrize("name", spec_params())
def test_stiff_example_designs_with_defaults(name):
    spec = load_spec(STIFF / f"{name}.toml")
    design = design_for_spec(spec)
    tuning = design.settling_tuning
    assert spec.rho is None and tuning is not None
    assert tuning["met"], tuning
    assert tuning["settling_time_predicted"] <= spec.settling_time
    # the fast stable modes are kept by the model: the homogenised part is smaller than it
    assert np.trace(design.model.slow_projector) < design.model.G_d.shape[0] - 0.5


@pytest.mark.slow
def test_unreachable_settling_time_is_reported_not_forced():
    """The aircraft's 5 s would take a peaking above 1e3: the design keeps to the limit, with
    a finite predicted settling time, and its settling_tuning says the request is not met."""
    spec = load_spec(STIFF / "aircraft_longitudinal.toml")
    tuning = design_for_spec(spec).settling_tuning
    assert not tuning["met"]
    assert tuning["peaking"] <= tuning["peaking_limit"]
    assert spec.settling_time < tuning["settling_time_predicted"] < np.inf


def closed_loop(spec, design):
    """The run after the load step: t, x, y, u, q at t_k (feedback u = K x, noise-free)."""
    dt = spec.noise.sample_time
    start, size = spec.disturbance.start, spec.disturbance.size
    n_steps = int(round((start + 3.0 * spec.settling_time) / dt))
    plant = LTIPlant(spec.A, spec.B, spec.C, spec.E, x0=spec.state_scale)
    K = state_feedback(spec.A, spec.B)
    t = np.arange(n_steps + 1) * dt
    q = np.where(t[:, None] >= start - 1e-12, size[None, :], 0.0)
    x, y, u = (np.empty((n_steps + 1, dim)) for dim in (spec.A.shape[0], 1, spec.B.shape[1]))
    for k in range(n_steps + 1):
        x[k], y[k], u[k] = plant.x, plant.y, K @ plant.x
        if k < n_steps:
            plant.step(u[k], q[k], dt)
    return t, x, y, u, q


def estimates(observer, y, u, dt):
    """z (x_hat, then q_hat) at every t_k of an estimator run on (y, u)."""
    z = np.empty((len(y), observer.z.size))
    for k in range(len(y)):
        z[k] = observer.z
        observer.step(y[k], u[k], dt)
    return z


def steady_error(spec, t, x, z, window):
    mask = (t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)
    e = (x[mask] - z[mask, :x.shape[1]]) / spec.state_scale
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def q_settling(spec, t, q, z):
    n = spec.A.shape[0]
    after = t >= spec.disturbance.start - 1e-9
    outside = np.abs(z[after, n] - q[after, 0]) > Q_BAND * abs(spec.disturbance.size[0])
    if outside[-1]:
        return np.inf
    last = np.flatnonzero(outside)
    return float(t[after][last[-1] + 1] - spec.disturbance.start) if last.size else 0.0


def reference_gain(spec, intensity):
    """The steady-state Kalman gain by an independent route: Van Loan's discretisation with
    scipy's expm and scipy's discrete Riccati solver."""
    A, _, C = extended_model(spec.A, spec.B, spec.C, spec.E, 1)
    N, Ts = A.shape[0], spec.noise.sample_time
    G = np.zeros((N, 1))
    G[-1, 0] = 1.0  # the white noise drives dq/dt
    M = scipy.linalg.expm(np.block([[-A, intensity * G @ G.T], [np.zeros((N, N)), A.T]]) * Ts)
    Phi = M[N:, N:].T
    Qd = Phi @ M[:N, N:]
    R = np.diag(spec.noise.measurement_std**2)
    P = scipy.linalg.solve_discrete_are(Phi.T, C.T, 0.5 * (Qd + Qd.T), R)
    return P @ C.T @ np.linalg.inv(C @ P @ C.T + R)


@pytest.mark.slow
def test_dc_motor_after_load_step_against_tuned_kalman(dc_motor):
    spec, design = dc_motor
    dt = spec.noise.sample_time
    t, x, y, u, q = closed_loop(spec, design)
    settle = max(spec.settling_time, design.settling_tuning["settling_time_predicted"])
    window = (spec.disturbance.start + settle, t[-1])
    z_h = estimates(FilteringObserver(design.filtering, h=dt), y, u, dt)

    tried = {}
    for j in range(-8, 7):
        intensity = spec.disturbance.size[0] ** 2 * 10.0**j
        record = design_kalman(design.plant, 1, spec.noise.measurement_std, intensity, dt)
        z = estimates(KalmanObserver(record), y, u, dt)
        tried[intensity] = (steady_error(spec, t, x, z, window), q_settling(spec, t, q, z), record)
    best = min(tried, key=lambda p: tried[p][0])
    error_k, q_time_k, record = tried[best]
    np.testing.assert_allclose(record.gain, reference_gain(spec, best), rtol=1e-6,
                               atol=1e-9 * np.max(np.abs(record.gain)))

    error_h = steady_error(spec, t, x, z_h, window)
    q_time_h = q_settling(spec, t, q, z_h)
    assert error_h <= max(error_k, ROUND_OFF), (error_h, error_k)
    assert q_time_h < q_time_k, (q_time_h, q_time_k, best)
