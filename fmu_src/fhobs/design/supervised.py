"""Design of the supervised observer (:mod:`fhobs.core.supervisor`): the Kalman filter of the
homogeneous model and the thresholds of the innovation test.

Kalman filter. The steady-state filter (:func:`fhobs.design.kalman.design_kalman`) of
``plant.extended_model(model.disturbance_order)``, the homogeneous observer's own model, so
that the handover maps z onto z; sample time, measurement std and process intensity from the
spec's ``[noise]`` table. The design's ``kalman`` is reused when it is of that order; otherwise
the table's intensity is used with the homogeneous model's order.

Thresholds. The statistic is the exponentially weighted mean, of weight ``a = 1 / window``,
of the normalised innovation squared; under the Kalman filter's model with Gaussian
innovations it is approximately ``g chi2(dof)``, ``g = a / (2 - a)``, ``dof = k (2 - a) / a``
(mean k and variance ``2 k a / (2 - a)`` matched; exact for ``window = 1``). The leave band
``(lower, upper)`` holds it with probability ``1 - false_alarm`` per sample (``false_alarm / 2``
on each side) and the return band with probability ``1 - RETURN_PROBABILITY``. Uniform noise,
the pendulum's, has lighter tails than the Gaussian, so the false-alarm rate on it is lower
still. ``dwell_time`` defaults to ``DWELL_WINDOWS`` windows of the statistic.

Handover covariance. At a handover the Kalman filter takes the homogeneous estimate with the
error covariance of that estimate (``handover_covariance``), from which it runs the
time-varying recursion back to its steady state (:mod:`fhobs.core.supervisor`). The covariance
is that of the homogeneous observer run on the ``[noise]`` table's measurement noise alone (the
plant at rest, uniform noise of the table's std, seed ``HANDOVER_SEED``, one step of Ts per
sample): the sample covariance of its z over ``HANDOVER_SAMPLES`` samples after
``HANDOVER_TRANSIENT`` samples of its transient, floored by the Kalman filter's steady-state
covariance P (:func:`covariance_floor`: in P's whitened coordinates every eigenvalue below 1
raised to 1), so that the recursion starts at or above its fixed point.

Defaults (measured by ``bench/bench_supervisor.py``): ``WINDOW = 50`` samples (2.5 ms at the
pendulum's Ts = 5e-5 s, 50 ms at the zoo's 1e-3 s; 200 samples kept the zoo's step-disturbed
plants on the homogeneous estimate 0.3 s longer after their transients, twice the Kalman
filter's RMS on the dc motor), ``FALSE_ALARM = 1e-9`` per sample (a false alarm every 1e9
samples at most, about 14 h of the pendulum's 20 kHz filter), a dwell of two windows.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.stats import chi2

from ..core.certificate import certify_supervised
from ..core.gains import FilteringGains, KalmanGains, ObserverDesign, SupervisedGains
from ..core.runtime import FilteringObserver
from ..errors import SpecError
from .kalman import design_kalman
from .spec import NoiseSpec

WINDOW = 50.0
"""Default length of the statistic's exponential window, in Kalman samples."""
FALSE_ALARM = 1e-9
"""Default probability per sample that consistent data leave the band (lower, upper)."""
RETURN_PROBABILITY = 0.05
"""Probability per sample that consistent data are outside the return band."""
CEILING = 2.0
"""The statistic's ceiling, in multiples of ``upper``."""
DWELL_WINDOWS = 2.0
"""Default dwell time in H, in windows of the statistic (``window * Ts`` each)."""
HANDOVER_SAMPLES = 20_000
"""Samples of the homogeneous estimate's sample covariance (the handover covariance)."""
HANDOVER_TRANSIENT = 5_000
"""Samples of the homogeneous observer's transient left out of that covariance."""
HANDOVER_SEED = 0
"""Seed of the measurement noise the handover covariance is estimated on."""
RANGE_TOLERANCE = 1e-14
"""Eigenvalues of the scaled sum below this fraction of its largest are its null space
(:func:`covariance_floor`)."""


def statistic_band(k: int, window: float, probability: float) -> tuple[float, float]:
    """The band that the statistic (k outputs, exponential window of ``window`` samples) leaves
    with ``probability`` per sample when the Kalman filter's model explains the data
    (``probability / 2`` below it, as much above; module docstring).

    Examples
    --------
    With a window of one sample the statistic is the chi-square of k degrees of freedom:

    >>> lower, upper = statistic_band(2, 1.0, 0.1)
    >>> round(lower, 6), round(upper, 6)
    (0.102587, 5.991465)
    """
    a = 1.0 / window
    scale, dof = a / (2.0 - a), k * (2.0 - a) / a
    return (float(scale * chi2.ppf(0.5 * probability, dof)),
            float(scale * chi2.isf(0.5 * probability, dof)))


def handover_covariance(filtering: FilteringGains, kalman: KalmanGains, *,
                        samples: int = HANDOVER_SAMPLES, transient: int = HANDOVER_TRANSIENT,
                        seed: int = HANDOVER_SEED) -> np.ndarray:
    """The error covariance of the homogeneous estimate under the Kalman filter's measurement
    noise, floored by its steady-state covariance (module docstring).

    Parameters
    ----------
    filtering : FilteringGains
        The homogeneous observer, run at the Kalman filter's sample time on noise alone.
    kalman : KalmanGains
        The Kalman filter of the same model: its ``measurement_std`` (uniform noise of that
        std), ``sample_time`` and steady-state ``covariance`` (the floor).
    samples, transient : int
        Samples of the sample covariance, and of the transient before them.
    seed : int
        Seed of the noise.

    Returns
    -------
    numpy.ndarray
        N x N, symmetric, at least ``kalman.covariance`` (positive semi-definite difference).

    Examples
    --------
    >>> from fhobs.design.spec import load_spec
    >>> from fhobs.design.observer import design_for_spec
    >>> from fhobs.paper import PENDULUM_SPEC
    >>> design = design_for_spec(load_spec(PENDULUM_SPEC))
    >>> P_h = handover_covariance(design.filtering, design.kalman, samples=2000, transient=500)
    >>> bool(np.linalg.eigvalsh(P_h - design.kalman.covariance)[0]
    ...      >= -1e-12 * np.abs(P_h).max())
    True
    """
    plant = filtering.plant
    observer = FilteringObserver(filtering, h=kalman.sample_time)
    half_width = np.sqrt(3.0) * kalman.measurement_std
    ys = half_width * np.random.default_rng(seed).uniform(-1.0, 1.0,
                                                          (transient + samples, plant.k))
    u = np.zeros(plant.m)
    estimates = np.empty((samples, filtering.model.n_model))
    for j, y in enumerate(ys):
        observer.advance(y, u, kalman.sample_time)
        if j >= transient:
            estimates[j - transient] = observer.z
    return covariance_floor(estimates.T @ estimates / samples, kalman.covariance)


def covariance_floor(covariance: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """``covariance`` with every direction in which it is below ``floor`` raised to it.

    Both are diagonalised by one congruence: that which makes their sum the identity on its
    range (after a diagonal scaling that makes the sum's diagonal one, as stiff models'
    covariances span many decades), then the eigenvectors of ``covariance`` there. In those
    coordinates the result is the larger of their two diagonals entry by entry, and zero on
    the sum's null space (directions in which both are zero: a state the noise never moves).
    With ``floor`` positive definite this is ``covariance`` with its eigenvalues below 1
    raised to 1 in the coordinates where ``floor`` is the identity. The result is symmetric
    and at least both (positive semi-definite differences).

    Examples
    --------
    >>> covariance_floor(np.diag([4.0, 0.25, 0.0]), np.diag([1.0, 1.0, 0.0])).round(12).tolist()
    [[4.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]
    """
    covariance, floor = 0.5 * (covariance + covariance.T), 0.5 * (floor + floor.T)
    scale = np.sqrt(np.diag(covariance) + np.diag(floor))
    scale[scale == 0.0] = 1.0
    total, vectors = np.linalg.eigh((covariance + floor) / np.outer(scale, scale))
    kept = total > RANGE_TOLERANCE * total[-1]
    root = vectors[:, kept] * np.sqrt(total[kept])  # the sum = root root^T on its range
    inverse = vectors[:, kept].T / np.sqrt(total[kept])[:, None]
    whitened = inverse @ (covariance / np.outer(scale, scale)) @ inverse.T
    values, rotation = np.linalg.eigh(0.5 * (whitened + whitened.T))
    basis = scale[:, None] * (root @ rotation)
    raised = basis @ np.diag(np.maximum(values, 1.0 - values)) @ basis.T
    return 0.5 * (raised + raised.T)


def design_supervised(design: ObserverDesign, noise: NoiseSpec, *, window: float = WINDOW,
                      false_alarm: float = FALSE_ALARM,
                      dwell_time: float | None = None) -> SupervisedGains:
    """The supervised observer of a design and a ``[noise]`` table.

    Parameters
    ----------
    design : ObserverDesign
        The homogeneous design (its ``filtering`` record is run as it is).
    noise : fhobs.design.spec.NoiseSpec
        The validated ``[noise]`` table: sample time, measurement std, process intensity.
    window : float
        Length of the statistic's exponential window in samples (>= 1).
    false_alarm : float
        Probability per sample of leaving the Kalman estimate on consistent data, in
        ``(0, RETURN_PROBABILITY)``.
    dwell_time : float or None
        Least time in H (s); None: ``DWELL_WINDOWS * window * Ts``.

    Returns
    -------
    SupervisedGains
        Certified (:func:`fhobs.core.certificate.certify_supervised`; its figures in
        ``certificate["checks"]``).

    Raises
    ------
    KalmanDesignError
        If the Kalman filter of the homogeneous model cannot be designed.
    SpecError
        If ``window`` is below one sample or ``false_alarm`` outside
        ``(0, RETURN_PROBABILITY)``.
    CertificateError
        If a threshold is out of range (a dwell time <= 0) or a part fails its certificate.

    Examples
    --------
    >>> from fhobs.design.spec import load_spec
    >>> from fhobs.design.observer import design_for_spec
    >>> from fhobs.paper import PENDULUM_SPEC
    >>> spec = load_spec(PENDULUM_SPEC)
    >>> record = design_supervised(design_for_spec(spec), spec.noise)
    >>> record.lower < record.lower_return < 2 < record.upper_return < record.upper
    True
    """
    order = design.model.disturbance_order
    kalman = design.kalman
    if not _kalman_of(kalman, order, noise):
        kalman = design_kalman(
            design.plant, order, noise.measurement_std, noise.process_intensity,
            noise.sample_time, f"the [noise] table's process_intensity at the homogeneous "
                               f"model's disturbance order {order}")
    if not (np.isfinite(window) and window >= 1.0):
        raise SpecError(f"window = {window!r} must be a finite number of at least one sample")
    if not 0.0 < false_alarm < RETURN_PROBABILITY:
        raise SpecError(f"false_alarm = {false_alarm!r} must be in (0, {RETURN_PROBABILITY:g}): "
                        "a probability per sample, below the return band's")
    k = design.plant.k
    lower, upper = statistic_band(k, window, false_alarm)
    lower_return, upper_return = statistic_band(k, window, RETURN_PROBABILITY)
    if dwell_time is None:
        dwell_time = DWELL_WINDOWS * window * kalman.sample_time
    record = SupervisedGains(design.plant, design.model, design.filtering, kalman,
                             float(window), lower, upper, lower_return, upper_return,
                             CEILING * upper, float(dwell_time), float(false_alarm),
                             handover_covariance(design.filtering, kalman))
    return dataclasses.replace(record, certificate={"checks": certify_supervised(record)})


def _kalman_of(kalman: KalmanGains | None, order: int, noise: NoiseSpec) -> bool:
    """Whether ``kalman`` is the Kalman filter of the homogeneous model's ``order`` for the
    ``noise`` table (its sample time, measurement std and process intensity)."""
    return (kalman is not None and kalman.disturbance_order == order
            and kalman.sample_time == noise.sample_time
            and kalman.process_intensity == noise.process_intensity
            and np.array_equal(kalman.measurement_std, noise.measurement_std))


def with_supervised(design: ObserverDesign, noise: NoiseSpec) -> ObserverDesign:
    """``design`` with the supervised observer of the ``[noise]`` table attached (its
    ``supervised`` record, :func:`design_supervised` with the defaults); after
    :func:`fhobs.design.kalman.with_kalman`, whose filter it reuses when it is of the
    homogeneous model's order.

    Raises
    ------
    KalmanDesignError, CertificateError
        As :func:`design_supervised`.

    Examples
    --------
    >>> from fhobs.design.kalman import with_kalman
    >>> from fhobs.design.observer import paper_gains
    >>> from fhobs.design.spec import load_spec
    >>> from fhobs.paper import PENDULUM_SPEC
    >>> noise = load_spec(PENDULUM_SPEC).noise
    >>> design = with_supervised(with_kalman(paper_gains(), noise), noise)
    >>> design.supervised.kalman.disturbance_order == design.model.disturbance_order
    True
    """
    return dataclasses.replace(design, supervised=design_supervised(design, noise))
