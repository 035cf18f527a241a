"""Design of the steady-state discrete Kalman filter baseline (scipy; the filter itself runs in
:mod:`fhobs.core.kalman_filter`, numpy only).

Model. The plant dx/dt = A x + B u + E q, y = C x + eta, with q modelled as in
:mod:`fhobs.core.disturbance`: for order r >= 1, ``q^(r) = w`` (the extended model, w entering the
last q block), for r = 0 ``q = w`` itself (through E). w is continuous white noise of intensity W
(``process_intensity``, power spectral density per component of q), eta is white with standard
deviation ``measurement_std`` per output (uniform noise of amplitude a: std a / sqrt(3)).

Discretisation. Exact for the sample time Ts: ``Phi = expm(Ts A)`` and the process-noise
covariance ``Qd = int_0^Ts expm(t A) G W G^T expm(t A)^T dt`` by Van Loan's method (one
exponential of ``[[-A, G W G^T], [0, A^T]] Ts``), kept in the record as
``process_covariance`` (the supervised observer's time-varying recursion needs it);
``R = diag(measurement_std^2)``.

Gain. The a-priori covariance P solves the discrete algebraic Riccati equation
``P = Phi P Phi^T - Phi P C^T (C P C^T + R)^-1 C P Phi^T + Qd`` (scipy.linalg.solve_discrete_are);
the measurement-update gain is ``M = P C^T (C P C^T + R)^-1`` (python-control's ``dlqe`` returns
the predictor gain ``Phi M``; a test checks both).

Stability. The steady-state filter ``z+ = Phi (I - M C) z + ...`` must be asymptotically stable
(spectral radius of ``Phi (I - M C)`` below ``1 - RADIUS_MARGIN``; the kalman FMU refuses a
filter with radius >= 1 at initialisation). It is not when the process noise reaches no mode of
the model on or near the unit circle: the ball and beam with q on the ball and no disturbance
model (order 0) has noise on the ball only, so the filter never corrects the beam angle, a
double integrator (radius 1), and with a disturbance model the Riccati equation has no
stabilising solution at all. Then a small process noise of intensity ``REGULARISATION`` times
the largest intensity that the noise puts on one state (``max diag(W G G^T)``) is added on every
state of the filter's model (``G W G^T + W_reg I``), multiplied by ``REGULARISATION_GROWTH``
until the filter is stable (up to the noise's own intensity); the record's ``tuning`` says so and
names the states the table's noise does not reach. A filter that is stable as specified is left
exactly as specified.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from ..core.certificate import certify_kalman
from ..core.disturbance import (
    describe_direction,
    model_perturbation_matrix,
    model_state_names,
)
from ..core.gains import KalmanGains, ObserverDesign, PlantModel
from ..core.linalg import spectral_radius
from ..errors import KalmanDesignError
from .homogenisation import unobservable_directions
from .spec import NoiseSpec

RICCATI_TOLERANCE = 1e-8
"""Largest accepted relative residual of the Riccati equation (and negative eigenvalue of P)."""
RADIUS_MARGIN = 1e-6
"""A filter whose spectral radius is within this of 1 counts as not asymptotically stable (at
Ts = 1e-3 s such a mode would take more than 1000 s to decay by e)."""
REGULARISATION = 1e-6
"""Intensity of the process noise added on every state of a filter that is not stable as
specified, relative to the largest intensity that the specified noise puts on one state."""
REGULARISATION_GROWTH = 10.0
"""Factor between the regularisation intensities tried (from REGULARISATION up to 1)."""


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
    plant: PlantModel,
    order: int,
    measurement_std: np.ndarray,
    process_intensity: float,
    sample_time: float,
    tuning: str = "",
) -> KalmanGains:
    """Steady-state discrete Kalman filter of the plant with a disturbance model of ``order``.

    Parameters
    ----------
    plant : PlantModel
        The plant; its E (n x p) is required (the process noise enters through it).
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
        On ``plant``, its ``certificate`` holding the figures of
        :func:`fhobs.core.certificate.certify_kalman`.

    Raises
    ------
    KalmanDesignError
        On E missing, a non-positive std, intensity or sample time, or a Riccati equation
        without a stabilising solution or whose computed solution fails
        ``RICCATI_TOLERANCE`` (an intensity too far from the noise for double precision),
        when the specified noise reaches every state; a filter that the specified noise leaves
        unstable because it reaches some states only is regularised (module docstring), or
        this error names the states it does not reach.

    Examples
    --------
    >>> A = np.array([[0.0, 1.0], [0.0, 0.0]]); B = E = np.array([[0.0], [1.0]])
    >>> plant = PlantModel(A, B, np.array([[1.0, 0.0]]), E)
    >>> kf = design_kalman(plant, 1, [1e-3], 1.0, 1e-3)
    >>> kf.gain.shape
    (3, 1)
    """
    A, C, E = plant.A, plant.C, plant.E
    if E is None:
        raise KalmanDesignError("the Kalman filter needs E: the process noise enters through it")
    std = np.asarray(measurement_std, dtype=float).reshape(-1)
    if std.shape != (C.shape[0],) or not np.all(std > 0) or not np.all(np.isfinite(std)):
        raise KalmanDesignError(f"measurement_std must be {C.shape[0]} positive finite numbers, "
                         f"got {std.tolist()}")
    for name, value in (("process_intensity", process_intensity), ("sample_time", sample_time)):
        if not (np.isfinite(value) and value > 0):
            raise KalmanDesignError(f"{name} = {value!r} must be a positive finite number")
    A_model, _, C_model = plant.extended_model(order)
    G = noise_input_matrix(E, A.shape[0], order)
    noise = process_intensity * G @ G.T
    R = np.diag(std**2)
    label = f"order {order}, W = {process_intensity:g}, Ts = {sample_time:g}"
    try:
        P, gain, radius = steady_state_filter(A_model, C_model, noise, R, sample_time, label)
        failure = None if radius < 1.0 - RADIUS_MARGIN else KalmanDesignError(
            f"the Kalman filter ({label}) is not asymptotically stable: spectral radius of "
            f"Phi (I - M C) = {radius:.9g} (required < 1 - {RADIUS_MARGIN:g})")
    except KalmanDesignError as err:
        failure = err
    if failure is not None:
        P, gain, noise, note = _regularised_filter(A_model, C_model, G, noise, R, sample_time,
                                                   order, E.shape[1], A.shape[0], label, failure)
        tuning = f"{tuning}; {note}" if tuning else note
    kalman = KalmanGains(plant, order, float(sample_time), std, float(process_intensity), gain,
                         P, tuning, process_covariance=van_loan(A_model, noise, sample_time)[1])
    return dataclasses.replace(kalman, certificate={"checks": certify_kalman(kalman)})


def steady_state_filter(
    A_model: np.ndarray, C_model: np.ndarray, noise: np.ndarray, R: np.ndarray,
    sample_time: float, label: str = "",
) -> tuple[np.ndarray, np.ndarray, float]:
    """The steady-state filter of a model with continuous process noise ``noise = G W G^T``.

    Parameters
    ----------
    A_model, C_model : numpy.ndarray
        The filter's model (N x N, k x N).
    noise : numpy.ndarray
        N x N intensity of the continuous process noise on the model's states.
    R : numpy.ndarray
        k x k covariance of the measurement noise.
    sample_time : float
        Ts.
    label : str
        What the error messages name (order, intensity, sample time).

    Returns
    -------
    P : numpy.ndarray
        A-priori covariance (symmetrised).
    gain : numpy.ndarray
        Measurement-update gain M (N x k).
    radius : float
        Spectral radius of ``Phi (I - M C)``.

    Raises
    ------
    KalmanDesignError
        If the Riccati equation has no stabilising solution or its computed solution fails
        ``RICCATI_TOLERANCE``.

    Examples
    --------
    A measured integrator with unit noises, sampled at 1 s:

    >>> P, gain, radius = steady_state_filter(np.zeros((1, 1)), np.eye(1), np.eye(1),
    ...                                       np.eye(1), 1.0)
    >>> round(float(P[0, 0]), 6), round(radius, 6)
    (1.618034, 0.381966)
    """
    Phi, Qd = van_loan(A_model, noise, sample_time)
    try:
        P = solve_discrete_are(Phi.T, C_model.T, Qd, R)
    except (ValueError, np.linalg.LinAlgError) as err:
        raise KalmanDesignError(f"the Kalman filter's Riccati equation has no stabilising solution "
                                f"({label}): {err}") from err
    P = 0.5 * (P + P.T)
    gain = np.linalg.solve(C_model @ P @ C_model.T + R, C_model @ P).T
    residual = riccati_residual(Phi, C_model, Qd, R, P)
    smallest = float(np.linalg.eigvalsh(P)[0]) / max(float(np.abs(P).max()), 1e-300)
    if not (residual <= RICCATI_TOLERANCE and smallest >= -RICCATI_TOLERANCE):
        raise KalmanDesignError(
            f"the Kalman filter's Riccati solution is inaccurate ({label}): relative residual "
            f"{residual:.2e}, smallest eigenvalue of P / max |P| = {smallest:.2e} (required "
            f"<= {RICCATI_TOLERANCE:g} and >= -{RICCATI_TOLERANCE:g}); the intensity is too "
            "far from the measurement noise for double precision")
    radius = spectral_radius(Phi - Phi @ gain @ C_model)
    return P, gain, radius


def _regularised_filter(
    A_model: np.ndarray, C_model: np.ndarray, G: np.ndarray, noise: np.ndarray, R: np.ndarray,
    sample_time: float, order: int, p: int, n: int, label: str, failure: KalmanDesignError,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """The filter with a small process noise on every state (module docstring), the process
    noise's intensity with it (N x N) and the note that says so; ``failure`` (the
    unregularised filter's problem) is raised when the noise reaches every state
    (regularising cannot be the cure) or no regularisation up to the noise's own intensity
    gives a stable filter."""
    names = model_state_names(n, p, order)
    unreached = unobservable_directions(A_model.T, G.T).T  # the uncontrollable directions
    if not unreached.size:
        raise failure
    missed = ", ".join(describe_direction(v, names) for v in unreached)
    largest = float(np.max(np.diag(noise)))
    fraction = REGULARISATION
    while fraction <= 1.0:
        extra = fraction * largest
        regularised = noise + extra * np.eye(A_model.shape[0])
        try:
            P, gain, radius = steady_state_filter(A_model, C_model, regularised, R, sample_time,
                                                  label)
        except KalmanDesignError:
            radius = np.inf
        if radius < 1.0 - RADIUS_MARGIN:
            note = (f"process noise of intensity {extra:.3g} ({fraction:g} of the largest the "
                    f"[noise] table puts on a state) added on every state: the table's noise "
                    f"does not reach {missed}, and without it the filter is not asymptotically "
                    f"stable; spectral radius of Phi (I - M C) = {radius:.9g}")
            return P, gain, regularised, note
        fraction *= REGULARISATION_GROWTH
    raise KalmanDesignError(
        f"the Kalman filter ({label}) is not asymptotically stable: the [noise] table's process "
        f"noise does not reach {missed}, and a process noise on every state of up to the "
        f"table's own intensity does not stabilise it ({failure})")


def with_kalman(design: ObserverDesign, noise: NoiseSpec,
                tuning: str = "process_intensity from the spec's [noise] table") -> ObserverDesign:
    """``design`` with the Kalman filter of a spec's ``[noise]`` table attached.

    Parameters
    ----------
    design : ObserverDesign
        A design (the filter runs on its plant).
    noise : fhobs.design.spec.NoiseSpec
        The validated ``[noise]`` table.
    tuning : str
        How its process intensity was chosen (kept in the record).

    Returns
    -------
    ObserverDesign
        A copy with ``kalman`` set.

    Examples
    --------
    >>> from fhobs.design.observer import design_for_spec
    >>> from fhobs.design.spec import spec_from_dict
    >>> plant = {"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]], "E": [[0], [1]],
    ...          "observer": {"rho": 2.0}}
    >>> noise = spec_from_dict(plant | {"noise": {"measurement_std": [0.01],
    ...                                           "sample_time": 0.01,
    ...                                           "process_intensity": 1.0}}).noise
    >>> design = with_kalman(design_for_spec(spec_from_dict(plant)), noise)
    >>> design.kalman.gain.shape, design.kalman.sample_time
    ((2, 1), 0.01)
    """
    kalman = design_kalman(design.plant, noise.disturbance_order, noise.measurement_std,
                           noise.process_intensity, noise.sample_time, tuning)
    return dataclasses.replace(design, kalman=kalman)
