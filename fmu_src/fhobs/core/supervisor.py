"""The supervised observer: Kalman-level in noise, homogeneous-level in transients (numpy only).

Two estimators run on the same (y, u) every step: the filtering homogeneous observer of
Theorem 2 (:class:`fhobs.core.runtime.FilteringObserver`) and a steady-state Kalman filter of the
same extended model (:class:`fhobs.core.kalman_filter.KalmanObserver`, its state z one to one
with the homogeneous observer's: x_hat, then q_hat and its derivatives). A test on the Kalman
filter's innovations decides which of the two estimates is output.

Statistic. At each filter sample t_j the innovation ``nu_j = y_j - C z_j|j-1`` has, when the
Kalman filter's model explains the data (white measurement noise of covariance R, process
noise of its intensity), zero mean and the steady-state covariance ``S = C P C^T + R`` (P the
a-priori covariance of the record); the normalised innovation squared
``e_j = nu_j^T S^-1 nu_j`` then has mean k (the number of outputs) and is white. The statistic
is its exponentially weighted mean, ``s_j = min((1 - a) s_j-1 + a e_j, ceiling)`` with
``a = 1 / window`` (the ceiling, above ``upper``, leaves every switch to H as it is and
shortens the memory of a transient's innovations, many decades above k, from dozens of
windows to about one); without the ceiling it has
mean k, variance ``2 k a / (2 - a)`` for Gaussian innovations, approximately
``a / (2 - a)`` times a chi-square of ``k (2 - a) / a`` degrees of freedom. The design
(:func:`fhobs.design.supervised.design_supervised`) sets the band ``(lower, upper)`` so that
the statistic leaves it with probability ``false_alarm`` per sample under that model, and the
narrower return band ``(lower_return, upper_return)``. The same mean of the homogeneous
observer's normalised output residual ``y_j - C z_H`` (z_H its estimate at the step's start,
given the data before y_j; ``homogeneous_statistic``) decides the handover.

Rule. The mode is K (output: the Kalman estimate) or H (output: the homogeneous estimate);
the observer starts in H. After each communication step:

- in K: switch to H when ``s < lower`` or ``s > upper``;
- in H: switch to K once ``lower_return < s < upper_return`` has held for ``dwell_time``
  without a break (so H lasts at least ``dwell_time``, and a statistic that only passes
  through the return band, falling from a transient's values to a noise-free zero, does not
  switch); at that switch the Kalman filter's state is set to the homogeneous estimate (the
  handover), so the output is continuous across it, when the homogeneous observer's own
  statistic is below ``upper_return`` (its output predictions are then as consistent with the
  noise as the Kalman filter's must be to return); otherwise the Kalman filter keeps its
  state: its innovations are consistent while the homogeneous observer is still in its
  transient (a homogeneous design tuned for noise can settle later than the Kalman filter),
  and handing that estimate over would restart the Kalman filter from a worse one (on the cart
  pole of ``bench/bench_supervisor.py``: noisy RMS 1.6 times the Kalman filter's with the
  handover at every return, 1.0 with this condition).

The homogeneous observer is never reset. ``s > upper``: the innovations are larger than the
Kalman filter's model explains (a transient, an unknown input it tracks too slowly), the
homogeneous observer converges in finite time and rejects them. ``s < lower``: the measurements
are much cleaner than the ``[noise]`` table says (noise-free data), the Kalman filter's gain is
then too low for them and its error is its disturbance-tracking error, while the homogeneous
observer's reaches its round-off floor.

Stability. Write e_H, e_K for the two estimators' errors and e for the output's.

1. e_H is the error of Theorem 2: the homogeneous observer is run as if alone (it is never
   reset or fed back), so its bounds (finite-time convergence without noise and disturbance,
   input-to-state stability with respect to them) hold unchanged.
2. Between two handovers e_K evolves by the Kalman filter's error map
   ``e+ = Phi (I - M C) e + (noise and disturbance terms)``, Schur stable (the record's
   certificate), so it is bounded by ``c r^j |e_K(t_h)| + gamma_K (noise, disturbance)`` j
   samples after the last handover t_h (or the start), with ``r < 1`` the map's spectral
   radius (up to any margin) and ``e_K(t_h) = e_H(t_h)`` (or ``e_K(0)``).
3. The dwell time bounds the number of H -> K switches, hence of handovers, on any interval
   of length T by ``1 + T / dwell_time``, and the hysteresis (return band strictly inside the
   leave band) makes a switch need the statistic to cross the gap between the bands: the
   output does not chatter. Every K period continues an e_K of point 2, so |e| is at most
   ``max(sup |e_H|, c max(sup |e_H|, |e_K(0)|) + gamma_K)``: bounded by the larger of the two
   estimators' bounds.
4. Without noise and disturbance e_H reaches its floor (round-off) in finite time and e_K
   decays exponentially after its last handover (or from its start), so e tends to round-off
   in both modes (the statistic then falls below ``lower`` and the output stays on H).

A communication step dt must be a whole number n of Kalman samples Ts (the kalman FMU's rule,
within ``SAMPLE_SLACK`` Ts): each of its n cycles adds one innovation to the statistic and the
mode is decided once per step. Invalid y, u or dt raise ValueError with the state unchanged.

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import math

import numpy as np

from .certificate import CERTIFICATE_MARGIN, DEFAULT_TOLERANCE, certify_filtering, certify_kalman
from .errors import CertificateError
from .gains import KalmanGains, SupervisedGains
from .kalman_filter import SAMPLE_SLACK, KalmanObserver
from .runtime import DEFAULT_H, SCHEMES, FilteringObserver
from .validation import all_finite, as_finite_vector, check_step_size

MODE_KALMAN = 0
"""Mode K: the output is the Kalman filter's estimate."""
MODE_HOMOGENEOUS = 1
"""Mode H: the output is the homogeneous observer's estimate."""
DWELL_SLACK = 1e-9
"""Relative slack of the dwell-time comparison (time accumulated in steps of dt)."""


def innovation_covariance(kalman: KalmanGains) -> np.ndarray:
    """The steady-state covariance ``S = C P C^T + R`` of the Kalman filter's innovation.

    Examples
    --------
    >>> from fhobs.core.gains import PlantModel
    >>> plant = PlantModel(np.zeros((1, 1)), np.ones((1, 1)), np.ones((1, 1)))
    >>> kalman = KalmanGains(plant, 0, 1.0, np.ones(1), 1.0, np.array([[0.6]]), 1.5 * np.eye(1))
    >>> innovation_covariance(kalman).tolist()
    [[2.5]]
    """
    C = kalman.model_matrices[2]
    S = C @ kalman.covariance @ C.T + np.diag(kalman.measurement_std**2)
    return 0.5 * (S + S.T)


def threshold_problems(supervised: SupervisedGains) -> list[str]:
    """What is out of range in the supervisor's own fields (empty if nothing): the Kalman
    filter of the homogeneous model, the window, the ordered bands around the statistic's mean
    k and the ceiling above them, the dwell time and the false-alarm probability.

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> record = NS(plant=NS(k=2), model=NS(disturbance_order=1),
    ...             kalman=NS(disturbance_order=1), window=200.0, lower=1.4, lower_return=1.7,
    ...             upper_return=2.3, upper=2.7, ceiling=5.4, dwell_time=0.02,
    ...             false_alarm=1e-9)
    >>> threshold_problems(record)
    []
    >>> threshold_problems(NS(**{**vars(record), "upper": 2.2}))
    ['upper = 2.2 must exceed upper_return = 2.3 (the hysteresis)']
    """
    k = supervised.plant.k
    problems = []
    if supervised.kalman.disturbance_order != supervised.model.disturbance_order:
        problems.append(f"kalman.disturbance_order = {supervised.kalman.disturbance_order} must "
                        f"equal the homogeneous model's {supervised.model.disturbance_order} "
                        "(the handover maps one state onto the other)")
    values = {name: float(getattr(supervised, name)) for name in
              ("window", "lower", "lower_return", "upper_return", "upper", "ceiling",
               "dwell_time", "false_alarm")}
    bad = [name for name, value in values.items() if not math.isfinite(value)]
    problems += [f"{name} = {values[name]!r} must be finite" for name in bad]
    if bad:
        return problems
    if values["window"] < 1.0:
        problems.append(f"window = {values['window']!r} must be at least 1 sample")
    if values["lower"] < 0.0:
        problems.append(f"lower = {values['lower']!r} must be >= 0")
    for name, below, reason in (("lower_return", "lower", "(the hysteresis)"),
                                ("upper_return", "lower_return", ""),
                                ("upper", "upper_return", "(the hysteresis)"),
                                ("ceiling", "upper", "")):
        if not values[name] > values[below]:
            problems.append(f"{name} = {values[name]!r} must exceed {below} = "
                            f"{values[below]!r} {reason}".rstrip())
    if not values["lower_return"] < k < values["upper_return"]:
        problems.append(f"the return band ({values['lower_return']!r}, "
                        f"{values['upper_return']!r}) must hold the statistic's mean k = {k}")
    if not values["dwell_time"] > 0.0:
        problems.append(f"dwell_time = {values['dwell_time']!r} must be > 0 s")
    if not 0.0 < values["false_alarm"] < 1.0:
        problems.append(f"false_alarm = {values['false_alarm']!r} must be in (0, 1)")
    return problems


def certify_supervised(
    supervised: SupervisedGains, tolerance: float = DEFAULT_TOLERANCE,
    margin: float = CERTIFICATE_MARGIN,
) -> dict[str, float]:
    """The supervised observer's certificate: its thresholds in range
    (:func:`threshold_problems`), the innovation covariance S positive definite, then the
    filtering record's (:func:`fhobs.core.certificate.certify_filtering`) and the Kalman
    record's (:func:`fhobs.core.certificate.certify_kalman`) certificates.

    Returns
    -------
    dict
        Both parts' figures and ``innovation_covariance_positive``
        (``lambda_min(S) / lambda_max(S)``).

    Raises
    ------
    CertificateError
        Naming every field out of range, or the part's failed checks.

    Examples
    --------
    >>> from fhobs.design.supervised import supervised_for_spec
    >>> from fhobs.design.spec import load_spec
    >>> from fhobs.paper import PENDULUM_SPEC
    >>> record = supervised_for_spec(load_spec(PENDULUM_SPEC))
    >>> figures = certify_supervised(record)
    >>> figures["schur_kalman"] < 1 and figures["lmi_filtering"] < 0
    True
    """
    problems = threshold_problems(supervised)
    if problems:
        raise CertificateError("the supervised observer's thresholds are out of range: "
                               + "; ".join(problems))
    eigenvalues = np.linalg.eigvalsh(innovation_covariance(supervised.kalman))
    positive = float(eigenvalues[0] / eigenvalues[-1]) if eigenvalues[-1] > 0 else -1.0
    if not positive > 1e-14:
        raise CertificateError(f"the Kalman filter's innovation covariance S = C P C^T + R is "
                               f"not positive definite (lambda_min / lambda_max = {positive:.3e})")
    figures = certify_filtering(supervised.filtering, tolerance, margin)
    figures |= certify_kalman(supervised.kalman, tolerance, margin)
    return figures | {"innovation_covariance_positive": positive}


def sample_count(dt: float, sample_time: float) -> int:
    """The number n of Kalman samples in a communication step dt = n Ts.

    Raises
    ------
    ValueError
        If dt is not a whole multiple of Ts (within ``SAMPLE_SLACK`` Ts).

    Examples
    --------
    >>> sample_count(3e-3, 1e-3), sample_count(1e-3 * (1 + 1e-12), 1e-3)
    (3, 1)
    """
    n = round(dt / sample_time)
    if n < 1 or abs(dt - n * sample_time) > SAMPLE_SLACK * sample_time:
        raise ValueError(f"the step size {dt!r} is not a whole multiple of the Kalman sample "
                         f"time Ts = {sample_time!r}; state left unchanged")
    return n


class SupervisedObserver:
    """The homogeneous observer and the Kalman filter, one of them output (module docstring).

    Parameters
    ----------
    supervised : SupervisedGains
        The record (:func:`fhobs.design.supervised.design_supervised`).
    h, scheme : float, str
        The homogeneous observer's internal step and scheme
        (:class:`fhobs.core.runtime.FilteringObserver`).
    z0 : array_like or None
        Initial model state of both estimators (``n_model`` entries; zeros if None).
    kernel : bool
        Step both estimators in the compiled kernel when it is available.

    Examples
    --------
    >>> from fhobs.design.supervised import supervised_for_spec
    >>> from fhobs.design.spec import load_spec
    >>> from fhobs.paper import PENDULUM_SPEC
    >>> record = supervised_for_spec(load_spec(PENDULUM_SPEC))
    >>> obs = SupervisedObserver(record)
    >>> obs.step(y=[0.1, 0.0], u=[0.0], dt=record.kalman.sample_time)
    >>> obs.mode == MODE_HOMOGENEOUS, obs.x_hat.shape
    (True, (4,))
    """

    def __init__(self, supervised: SupervisedGains, h: float = DEFAULT_H,
                 scheme: str = SCHEMES[0], z0: np.ndarray | None = None,
                 kernel: bool = True) -> None:
        problems = threshold_problems(supervised)
        if problems:
            raise ValueError("supervised observer: " + "; ".join(problems))
        self.supervised = supervised
        self.homogeneous = FilteringObserver(supervised.filtering, h=h, scheme=scheme, z0=z0,
                                             kernel=kernel)
        self.kalman = KalmanObserver(supervised.kalman, z0=self.homogeneous.z, kernel=kernel)
        self.sample_time = self.kalman.sample_time
        self._n, self._k, self._m = supervised.plant.n, supervised.plant.k, supervised.plant.m
        self._C = supervised.kalman.model_matrices[2]
        self._S_inv = np.linalg.inv(innovation_covariance(supervised.kalman))
        self._weight = 1.0 / float(supervised.window)
        self._statistics = np.full(2, float(self._k))
        self._mode = MODE_HOMOGENEOUS
        self._time_consistent = 0.0

    # -- outputs --------------------------------------------------------------------------
    @property
    def z(self) -> np.ndarray:
        """The output's model state (copy): the estimate of the current mode."""
        return (self.kalman if self._mode == MODE_KALMAN else self.homogeneous).z

    @property
    def x_hat(self) -> np.ndarray:
        """Estimate of the plant's state (the first n entries of :attr:`z`)."""
        return self.z[:self._n]

    @property
    def q_hat(self) -> np.ndarray:
        """Disturbance-model estimates (q, then its derivatives; empty for order 0)."""
        return self.z[self._n:]

    @property
    def mode(self) -> int:
        """:data:`MODE_KALMAN` or :data:`MODE_HOMOGENEOUS`."""
        return self._mode

    @property
    def statistic(self) -> float:
        """The statistic: the exponentially weighted mean of the Kalman filter's normalised
        innovation squared."""
        return float(self._statistics[0])

    @property
    def homogeneous_statistic(self) -> float:
        """The same mean of the homogeneous observer's normalised output residual squared
        (the handover's condition)."""
        return float(self._statistics[1])

    @property
    def compiled(self) -> bool:
        """Whether both estimators step in the compiled kernel."""
        return self.homogeneous.compiled and self.kalman.compiled

    # -- stepping -------------------------------------------------------------------------
    def step(self, y: np.ndarray, u: np.ndarray, dt: float) -> None:
        """Advance by dt = n Ts with y and u held, then decide the mode (module docstring).

        Raises
        ------
        ValueError
            On invalid y, u or dt (not a whole multiple of Ts), or a non-finite result of
            either estimator; the state is then left unchanged.
        """
        self.advance(as_finite_vector(y, self._k, "y"), as_finite_vector(u, self._m, "u"),
                     check_step_size(dt))

    def advance(self, y: np.ndarray, u: np.ndarray, dt: float) -> None:
        """:meth:`step` without checking y, u and the sign of dt; a dt that is not a whole
        multiple of Ts and a non-finite result still raise ValueError, the state unchanged."""
        n_cycles = sample_count(dt, self.sample_time)
        before = self.homogeneous.get_state(), self.kalman.get_state()
        residual = y - self._C @ self.homogeneous.z
        nis_homogeneous = float(residual @ self._S_inv @ residual)
        statistics = self._statistics.copy()
        try:
            self.homogeneous.advance(y, u, dt)
            for _ in range(n_cycles):
                innovation = y - self._C @ self.kalman.z
                nis = (float(innovation @ self._S_inv @ innovation), nis_homogeneous)
                statistics = np.minimum(statistics + self._weight * (nis - statistics),
                                        self.supervised.ceiling)
                self.kalman.advance(y, u, self.sample_time)
            if not all_finite(statistics):
                raise ValueError("the innovation statistics are not finite")
        except ValueError:
            self.homogeneous.set_state(before[0])
            self.kalman.set_state(before[1])
            raise
        self._statistics = statistics
        self._decide(dt)

    def _decide(self, dt: float) -> None:
        """The mode after a step of dt, with the handover at H -> K."""
        record = self.supervised
        kalman, homogeneous = self._statistics
        if self._mode == MODE_KALMAN:
            if not record.lower <= kalman <= record.upper:
                self._mode, self._time_consistent = MODE_HOMOGENEOUS, 0.0
            return
        if not record.lower_return < kalman < record.upper_return:
            self._time_consistent = 0.0
            return
        self._time_consistent += dt
        if self._time_consistent >= record.dwell_time * (1.0 - DWELL_SLACK):
            if homogeneous < record.upper_return:
                self.kalman.set_state(np.append(self.homogeneous.z, 0.0))
            self._mode = MODE_KALMAN

    # -- state ----------------------------------------------------------------------------
    def get_state(self) -> np.ndarray:
        """The full internal state (a copy): the homogeneous observer's, the Kalman filter's,
        then the two statistics, the mode and the time the statistic has been inside the return
        band in H."""
        return np.concatenate((self.homogeneous.get_state(), self.kalman.get_state(),
                               self._statistics, [float(self._mode), self._time_consistent]))

    def set_state(self, arr: np.ndarray) -> None:
        """Restore a state from :meth:`get_state` exactly.

        Raises
        ------
        ValueError
            If ``arr`` is not such a state (size, finite entries, a negative statistic or
            time, a mode other than 0 or 1); the state is then left unchanged.
        """
        sizes = (self.homogeneous.get_state().size, self.kalman.get_state().size)
        arr = as_finite_vector(arr, sum(sizes) + 4, "supervised observer state")
        statistics, (mode, time_consistent) = arr[-4:-2].copy(), arr[-2:].tolist()
        if min(*statistics, time_consistent) < 0.0 or mode not in (MODE_KALMAN, MODE_HOMOGENEOUS):
            raise ValueError(f"supervised observer state: the statistics {statistics.tolist()} "
                             f"and the time in band {time_consistent!r} must be >= 0 and the "
                             f"mode 0 or 1, got {mode!r}")
        homogeneous_before = self.homogeneous.get_state()
        self.homogeneous.set_state(arr[:sizes[0]])
        try:
            self.kalman.set_state(arr[sizes[0]:sizes[0] + sizes[1]])
        except ValueError:
            self.homogeneous.set_state(homogeneous_before)
            raise
        self._statistics, self._mode, self._time_consistent = statistics, int(mode), time_consistent

    def diagnostics(self) -> dict[str, float | np.ndarray]:
        """``z`` (the output's), ``mode``, ``statistic``, ``homogeneous_statistic``,
        ``time_consistent``, both estimators' z (``z_homogeneous``, ``z_kalman``) and the
        homogeneous observer's psi, xi and sigma."""
        homogeneous = self.homogeneous.diagnostics()
        return {"z": self.z, "mode": float(self._mode), "statistic": self.statistic,
                "homogeneous_statistic": self.homogeneous_statistic,
                "time_consistent": self._time_consistent, "z_homogeneous": homogeneous["z"],
                "z_kalman": self.kalman.z, "psi": homogeneous["psi"], "xi": homogeneous["xi"],
                "sigma": homogeneous["sigma"]}
