"""Design of the steady-state discrete Kalman filter baseline (scipy; the filter itself runs in
:mod:`fhobs.core.kalman_filter`, numpy only).

Model. The plant dx/dt = A x + B u + E q, y = C x + eta, with q modelled as in
:mod:`fhobs.core.disturbance`: for order r >= 1, ``q^(r) = w`` (the extended model, w entering the
last q block), for r = 0 ``q = w`` itself (through E). w is continuous white noise of intensity W
(``process_intensity``, power spectral density per component of q), eta is white with standard
deviation ``measurement_std`` per output (uniform noise of amplitude a: std a / sqrt(3)).

Discretisation. Exact for the sample time Ts: ``Phi = expm(Ts A)`` and the process-noise
covariance ``Qd = int_0^Ts expm(t A) G W G^T expm(t A)^T dt`` by Van Loan's method (one
exponential of ``[[-A, G W G^T], [0, A^T]] Ts``); ``R = diag(measurement_std^2)``.

Gain. The a-priori covariance P solves the discrete algebraic Riccati equation
``P = Phi P Phi^T - Phi P C^T (C P C^T + R)^-1 C P Phi^T + Qd`` (scipy.linalg.solve_discrete_are);
the measurement-update gain is ``M = P C^T (C P C^T + R)^-1`` (python-control's ``dlqe`` returns
the predictor gain ``Phi M``; a test checks both).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from .core.disturbance import extended_model, model_perturbation_matrix
from .core.gains import KalmanGains, ObserverGains
from .errors import KalmanDesignError
from .spec import NoiseSpec

RICCATI_TOLERANCE = 1e-8
"""Largest accepted relative residual of the Riccati equation (and negative eigenvalue of P)."""


def riccati_residual(Phi: np.ndarray, C: np.ndarray, Qd: np.ndarray, R: np.ndarray,
                     P: np.ndarray) -> float:
    """Relative residual of the filter's discrete Riccati equation at P (module docstring),
    max |residual| / max(max |P|, max |Qd|).

    Examples
    --------
    >>> one = np.eye(1)
    >>> riccati_residual(one, one, one, one, np.array([[(1 + 5 ** 0.5) / 2]])) < 1e-15
    True
    """
    gain = Phi @ P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    residual = Phi @ P @ Phi.T - gain @ C @ P @ Phi.T + Qd - P
    scale = max(float(np.abs(P).max()), float(np.abs(Qd).max()), 1e-300)
    return float(np.abs(residual).max()) / scale


def noise_input_matrix(E: np.ndarray, n: int, order: int) -> np.ndarray:
    """Where the white noise w enters the filter's model: E for order 0, else the last q block.

    Examples
    --------
    >>> noise_input_matrix(np.array([[0.0], [1.0]]), 2, 1).ravel().tolist()
    [0.0, 0.0, 1.0]
    """
    if order == 0:
        return np.asarray(E, dtype=float)
    return model_perturbation_matrix(n, E.shape[1], order)


def van_loan(A: np.ndarray, GWGt: np.ndarray, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Phi, Qd)`` of dx/dt = A x + G w, w white of intensity W, sampled exactly at Ts.

    Parameters
    ----------
    A : numpy.ndarray
        (N, N) state matrix.
    GWGt : numpy.ndarray
        (N, N) ``G W G^T``.
    Ts : float
        Sample time.

    Returns
    -------
    tuple of numpy.ndarray
        ``Phi = expm(Ts A)`` and ``Qd = int_0^Ts expm(t A) G W G^T expm(t A)^T dt``
        (symmetrised).

    Examples
    --------
    >>> Phi, Qd = van_loan(np.zeros((1, 1)), np.eye(1), 0.5)
    >>> float(Qd[0, 0])
    0.5
    """
    size = A.shape[0]
    block = np.zeros((2 * size, 2 * size))
    block[:size, :size] = -A
    block[:size, size:] = GWGt
    block[size:, size:] = A.T
    F = expm(block * Ts)
    Phi = F[size:, size:].T
    Qd = Phi @ F[:size, size:]
    return Phi, 0.5 * (Qd + Qd.T)


def design_kalman(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    E: np.ndarray | None,
    order: int,
    measurement_std: np.ndarray,
    process_intensity: float,
    sample_time: float,
    tuning: str = "",
) -> KalmanGains:
    """Steady-state discrete Kalman filter of the plant with a disturbance model of ``order``.

    Parameters
    ----------
    A, B, C : numpy.ndarray
        Plant matrices (n x n, n x m, k x n).
    E : numpy.ndarray or None
        Perturbation input matrix (n x p); required (the process noise enters through it).
    order : int
        Disturbance-model order r in 0..3 (:func:`fhobs.core.disturbance.extended_model`).
    measurement_std : array_like
        (k,) standard deviation of the measurement noise per output (> 0).
    process_intensity : float
        Intensity W > 0 of the white noise driving ``q^(r)``.
    sample_time : float
        The filter's sample time Ts > 0.
    tuning : str
        How the intensity was chosen, kept in the record.

    Returns
    -------
    KalmanGains

    Raises
    ------
    KalmanDesignError
        On E missing, a non-positive std, intensity or sample time, or a Riccati equation
        without a stabilising solution or whose computed solution fails
        ``RICCATI_TOLERANCE`` (an intensity too far from the noise for double precision).

    Examples
    --------
    >>> A = np.array([[0.0, 1.0], [0.0, 0.0]]); B = E = np.array([[0.0], [1.0]])
    >>> kf = design_kalman(A, B, np.array([[1.0, 0.0]]), E, 1, [1e-3], 1.0, 1e-3)
    >>> kf.gain.shape
    (3, 1)
    """
    if E is None:
        raise KalmanDesignError("the Kalman filter needs E: the process noise enters through it")
    std = np.asarray(measurement_std, dtype=float).reshape(-1)
    if std.shape != (C.shape[0],) or not np.all(std > 0) or not np.all(np.isfinite(std)):
        raise KalmanDesignError(f"measurement_std must be {C.shape[0]} positive finite numbers, "
                         f"got {std.tolist()}")
    for name, value in (("process_intensity", process_intensity), ("sample_time", sample_time)):
        if not (np.isfinite(value) and value > 0):
            raise KalmanDesignError(f"{name} = {value!r} must be a positive finite number")
    A_model, _, C_model = extended_model(A, B, C, E, order)
    G = noise_input_matrix(E, A.shape[0], order)
    Phi, Qd = van_loan(A_model, process_intensity * G @ G.T, sample_time)
    R = np.diag(std**2)
    try:
        P = solve_discrete_are(Phi.T, C_model.T, Qd, R)
    except (ValueError, np.linalg.LinAlgError) as err:
        raise KalmanDesignError(f"the Kalman filter's Riccati equation has no stabilising solution "
                         f"(order {order}, W = {process_intensity:g}, Ts = {sample_time:g}): "
                         f"{err}") from err
    P = 0.5 * (P + P.T)
    gain = np.linalg.solve(C_model @ P @ C_model.T + R, C_model @ P).T
    residual = riccati_residual(Phi, C_model, Qd, R, P)
    smallest = float(np.linalg.eigvalsh(P)[0]) / max(float(np.abs(P).max()), 1e-300)
    if not (residual <= RICCATI_TOLERANCE and smallest >= -RICCATI_TOLERANCE):
        raise KalmanDesignError(
            f"the Kalman filter's Riccati solution is inaccurate (order {order}, "
            f"W = {process_intensity:g}, Ts = {sample_time:g}): relative residual "
            f"{residual:.2e}, smallest eigenvalue of P / max |P| = {smallest:.2e} (required "
            f"<= {RICCATI_TOLERANCE:g} and >= -{RICCATI_TOLERANCE:g}); the intensity is too "
            "far from the measurement noise for double precision")
    return KalmanGains(order, float(sample_time), std, float(process_intensity), gain, P, tuning)


def with_kalman(gains: ObserverGains, noise: NoiseSpec,
                tuning: str = "process_intensity from the spec's [noise] table") -> ObserverGains:
    """``gains`` with the Kalman filter of a spec's ``[noise]`` table attached.

    Parameters
    ----------
    gains : ObserverGains
        A design (its A, B, C, E are used).
    noise : fhobs.spec.NoiseSpec
        The validated ``[noise]`` table.
    tuning : str
        How its process intensity was chosen (kept in the record).

    Returns
    -------
    ObserverGains
        A copy with ``kalman`` set.

    Examples
    --------
    >>> from fhobs.design import design_for_spec
    >>> from fhobs.spec import spec_from_dict
    >>> spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]],
    ...                        "E": [[0], [1]], "observer": {"rho": 2.0},
    ...                        "noise": {"measurement_std": [0.01], "sample_time": 0.01,
    ...                                  "process_intensity": 1.0}})
    >>> gains = with_kalman(design_for_spec(spec), spec.noise)
    >>> gains.kalman.gain.shape, gains.kalman.sample_time
    ((2, 1), 0.01)
    """
    kalman = design_kalman(gains.A, gains.B, gains.C, gains.E, noise.disturbance_order,
                           noise.measurement_std, noise.process_intensity, noise.sample_time,
                           tuning)
    return dataclasses.replace(gains, kalman=kalman)
