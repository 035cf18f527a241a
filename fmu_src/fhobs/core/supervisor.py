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
- in H: switch to K once the Kalman filter's statistic s or the homogeneous observer's own
  has been inside the return band ``(lower_return, upper_return)`` for ``dwell_time`` without
  a break (so H lasts at least ``dwell_time``, and a statistic that only passes through the
  return band, falling from a transient's values to a noise-free zero, does not switch); the
  homogeneous one counts too because a Kalman filter tuned for a slowly varying q follows a
  load step only slowly, and its own statistic would hold the output on H until it had (the
  stiff DC motor of ``bench/bench_real_plants.py``: 19 times the tuned Kalman filter's noisy
  error with the Kalman statistic alone); at that switch the Kalman filter's state is set to
  the homogeneous estimate (the handover), so the output is continuous across it, when the
  Kalman filter's own statistic is outside the return band (its estimate is not consistent
  with the data) and the homogeneous observer's is below ``upper_return`` (its output
  predictions are as consistent with the noise as the Kalman filter's must be to return). A
  Kalman filter whose innovations are consistent keeps its state: handing it the homogeneous
  estimate would hand it that estimate's noise, which a filter tuned for a slowly varying q
  then keeps for seconds (the stiff motor: load error 4.5e-3 N m against 5.8e-5). Otherwise,
  too, the Kalman filter keeps its state: its innovations are consistent while the homogeneous observer is still in its
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

import numpy as np

from .certificate import innovation_covariance, threshold_problems
from .gains import SupervisedGains
from .kalman_filter import MAX_CYCLES, SAMPLE_SLACK, KalmanObserver
from .runtime import DEFAULT_H, SCHEMES, FilteringObserver
from .validation import all_finite, as_finite_vector, check_step_size

MODE_KALMAN = 0
"""Mode K: the output is the Kalman filter's estimate."""
MODE_HOMOGENEOUS = 1
"""Mode H: the output is the homogeneous observer's estimate."""
DWELL_SLACK = 1e-9
"""Relative slack of the dwell-time comparison (time accumulated in steps of dt)."""
HEAD_SIZE = 4
"""The supervisor's own entries at the start of the state: statistic, mode, homogeneous
statistic, time in the return band."""


def sample_count(dt: float, sample_time: float) -> int:
    """The number n of Kalman samples in a communication step dt = n Ts.

    Raises
    ------
    ValueError
        If dt is not a whole multiple of Ts (within ``SAMPLE_SLACK`` Ts) or holds more than
        ``MAX_CYCLES`` samples.

    Examples
    --------
    >>> sample_count(3e-3, 1e-3), sample_count(1e-3 * (1 + 1e-12), 1e-3)
    (3, 1)
    """
    n = round(dt / sample_time)
    if n < 1 or abs(dt - n * sample_time) > SAMPLE_SLACK * sample_time:
        raise ValueError(f"the step size {dt!r} is not a whole multiple of the Kalman sample "
                         f"time Ts = {sample_time!r}; state left unchanged")
    if n > MAX_CYCLES:
        raise ValueError(f"the step size {dt!r} holds {n} samples of Ts = {sample_time!r}, "
                         f"more than {MAX_CYCLES}; state left unchanged")
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
        if not (record.lower_return < kalman < record.upper_return
                or record.lower_return < homogeneous < record.upper_return):
            self._time_consistent = 0.0
            return
        self._time_consistent += dt
        if self._time_consistent >= record.dwell_time * (1.0 - DWELL_SLACK):
            if (homogeneous < record.upper_return
                    and not record.lower_return < kalman < record.upper_return):
                self.kalman.set_state(np.append(self.homogeneous.z, 0.0))
            self._mode = MODE_KALMAN

    # -- state ----------------------------------------------------------------------------
    def get_state(self) -> np.ndarray:
        """The full internal state (a copy): the statistic and the mode (the outputs that are
        state, first), the homogeneous observer's statistic and the time the statistic has
        been inside the return band in H, then the homogeneous observer's state and the Kalman
        filter's."""
        head = (self._statistics[0], float(self._mode), self._statistics[1],
                self._time_consistent)
        return np.concatenate((head, self.homogeneous.get_state(), self.kalman.get_state()))

    def set_state(self, arr: np.ndarray) -> None:
        """Restore a state from :meth:`get_state` exactly.

        Raises
        ------
        ValueError
            If ``arr`` is not such a state (size, finite entries, a negative statistic or
            time, a mode other than 0 or 1); the state is then left unchanged.
        """
        sizes = (self.homogeneous.get_state().size, self.kalman.get_state().size)
        arr = as_finite_vector(arr, HEAD_SIZE + sum(sizes), "supervised observer state")
        kalman_statistic, mode, homogeneous_statistic, time_consistent = arr[:HEAD_SIZE].tolist()
        statistics = np.array([kalman_statistic, homogeneous_statistic])
        if min(*statistics, time_consistent) < 0.0 or mode not in (MODE_KALMAN, MODE_HOMOGENEOUS):
            raise ValueError(f"supervised observer state: the statistics {statistics.tolist()} "
                             f"and the time in band {time_consistent!r} must be >= 0 and the "
                             f"mode 0 or 1, got {mode!r}")
        parts = arr[HEAD_SIZE:HEAD_SIZE + sizes[0]], arr[HEAD_SIZE + sizes[0]:]
        homogeneous_before = self.homogeneous.get_state()
        self.homogeneous.set_state(parts[0])
        try:
            self.kalman.set_state(parts[1])
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
