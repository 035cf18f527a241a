"""An estimator's error on the noise tuning's loop, computed apart from fhobs.design.tuning:
the plant's ZOH by scipy's expm, its LQR gain by scipy's Riccati solver, the step disturbance
and the documented noise (numpy's ``default_rng([seed, draw])``, uniform of the given std),
the estimator of the product's runtime."""

from __future__ import annotations

import numpy as np
import scipy.linalg
from fhobs.core.gains import FilteringGains, KalmanGains
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.runtime import FilteringObserver
from reference_math import zoh


def replay_error(record: FilteringGains | KalmanGains, std: float | None, step: float,
                 settling_time: float, size: float = 0.0, start: float = 0.0, seed: int = 0,
                 draw: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(t, ||x - x_hat||)`` over ``[0, 3 settling_time]``: the plant of ``record`` from
    x(0) = 1 under ``u = -B^T X x`` (X the continuous ARE's solution, Q = I, R = I), a step
    q = ``size`` from ``start`` through E, measured with noise of std ``std`` (None: none)."""
    plant = record.plant
    A, B, C, E = plant.A, plant.B, plant.C, plant.E
    n = A.shape[0]
    K = -B.T @ scipy.linalg.solve_continuous_are(A, B, np.eye(n), np.eye(B.shape[1]))
    Phi, Gamma = zoh(A, np.hstack([B, E]), step)
    steps = int(round(3.0 * settling_time / step))
    t = np.arange(steps + 1) * step
    q = np.where(t[:-1, None] >= start - 1e-12, size, 0.0) * np.ones(E.shape[1])
    noise = (np.zeros((steps, C.shape[0])) if std is None else
             np.random.default_rng([seed, draw]).uniform(-1.0, 1.0, (steps, C.shape[0]))
             * np.sqrt(3.0) * std)
    estimator = (KalmanObserver(record) if isinstance(record, KalmanGains)
                 else FilteringObserver(record, h=step))
    x = np.ones(n)
    error = [np.linalg.norm(x - estimator.x_hat)]
    for i in range(steps):
        u = K @ x
        estimator.step(C @ x + noise[i], u, step)
        x = Phi @ x + Gamma @ np.concatenate([u, q[i]])
        error.append(np.linalg.norm(x - estimator.x_hat))
    return t, np.array(error)


def window_rms(t: np.ndarray, error: np.ndarray, a: float, b: float) -> float:
    """RMS of ``error`` over ``a <= t <= b``."""
    inside = (t >= a - 1e-9) & (t <= b + 1e-9)
    return float(np.sqrt(np.mean(error[inside] ** 2)))
