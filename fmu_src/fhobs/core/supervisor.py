"""The supervised observer: Kalman-level in noise, homogeneous-level in transients (numpy only).

Two estimators run on the same (y, u) every step: the filtering homogeneous observer of
Theorem 2 (:class:`fhobs.core.runtime.FilteringObserver`) and a steady-state Kalman filter of the
same extended model (:class:`fhobs.core.kalman_filter.KalmanObserver`, its state z one to one
with the homogeneous observer's: x_hat, then q_hat and its derivatives). A test on the Kalman
filter's innovations decides which of the two estimates is output.

Statistic. At each filter sample t_j the innovation ``nu_j = y_j - C z_j|j-1`` has, when the
Kalman filter's model explains the data (white measurement noise of covariance R, process
noise of its intensity), zero mean and the covariance ``S_j = C P_j C^T + R`` (P_j the
filter's a-priori covariance: the record's steady-state P, or that of the time-varying
recursion after a handover, below); the normalised innovation squared
``e_j = nu_j^T S_j^-1 nu_j`` then has mean k (the number of outputs) and is white. The
statistic is its exponentially weighted mean, ``s_j = min((1 - a) s_j-1 + a e_j, ceiling)``
with ``a = 1 / window`` (the ceiling, above ``upper``, leaves every switch to H as it is and
shortens the memory of a transient's innovations, many decades above k, from dozens of
windows to about one); without the ceiling it has
mean k, variance ``2 k a / (2 - a)`` for Gaussian innovations, approximately
``a / (2 - a)`` times a chi-square of ``k (2 - a) / a`` degrees of freedom. The design
(:func:`fhobs.design.supervised.design_supervised`) sets the band ``(lower, upper)`` so that
the statistic leaves it with probability ``false_alarm`` per sample under that model, and the
narrower return band ``(lower_return, upper_return)``. The same mean of the homogeneous
observer's normalised output residual ``y_j - C z_H`` (z_H its estimate at the step's start,
given the data before y_j), normalised by ``S_H = C P_H C^T + R`` with P_H the record's
``handover_covariance`` (the homogeneous estimate's error covariance under the ``[noise]``
table), is the homogeneous statistic: of mean k once the homogeneous observer has converged
to its noise floor, many times k in its transient.

Rule. The mode is K (output: the Kalman estimate) or H (output: the homogeneous estimate);
the observer starts in H. After each communication step:

- in K: switch to H when ``s > upper``, or when ``s < lower`` and the homogeneous observer's
  own statistic is lower still (data cleaner than the ``[noise]`` table: the homogeneous
  estimate is output only if it explains them better; a homogeneous design tuned for noise
  that has not converged yet does not take over: cart_pole of ``bench/bench_supervisor.py``,
  noise-free max 0.88 with ``s < lower`` alone, 0.10 = the Kalman filter's with this rule);
- in H: switch to K once, for ``dwell_time`` without a break, the Kalman filter's statistic
  has been inside the return band ``(lower_return, upper_return)`` or the homogeneous one
  inside the leave band ``[lower, upper]`` (the homogeneous observer has converged: its
  residuals are as consistent with the noise as the Kalman filter's must be to stay in K).
  H lasts at least ``dwell_time``, and a statistic that only passes through its band, falling
  from a transient's values to a noise-free zero, does not switch. At that switch:

  - a Kalman filter whose own statistic is in the return band keeps its state (its estimate is
    consistent with the data; handing it the homogeneous estimate would discard its smaller
    covariance, and while the homogeneous observer is still in its transient, a worse
    estimate);
  - otherwise the homogeneous estimate is handed over: the Kalman filter's state becomes z_H,
    its covariance P_H and its statistic the homogeneous one (the statistic of the estimate it
    now holds), and it runs the time-varying recursion: at each sample the measurement update
    with ``K_j = P_j C^T S_j^-1``, ``P <- (I - K_j C) P_j``, then the prediction
    ``P_j+1 = Phi P Phi^T + Q_d`` (Q_d the Kalman record's ``process_covariance``), until
    ``max |P - P_ss| <= RECURSION_TOLERANCE max |P_ss|`` (P_ss the steady-state covariance;
    at most ``RECURSION_CYCLES`` cycles), then the steady-state gain M again. The filter
    thereby weighs the handed-over estimate by its actual uncertainty: large gains at first
    (the data correct the homogeneous estimate's noise), decreasing to M. The fixed-gain
    filter instead kept that noise for seconds when tuned for a slowly varying q (the stiff
    DC motor of ``bench/bench_real_plants.py``: 7.5 times the tuned Kalman filter's noisy
    error with a fixed-gain handover, 0.9 times with this one).

The handover thus happens as soon as the homogeneous observer has converged after a
transient (the dwell time after the switch to H), not when the Kalman filter has followed on
its own, which for a filter tuned for a slowly varying q takes about 0.5 s after a load step
on that motor.

The homogeneous observer is never reset. ``s > upper``: the innovations are larger than the
Kalman filter's model explains (a transient, an unknown input it tracks too slowly), the
homogeneous observer converges in finite time and rejects them. ``s < lower``: the measurements
are much cleaner than the ``[noise]`` table says (noise-free data), the Kalman filter's gain is
then too low for them and its error is its disturbance-tracking error, while the homogeneous
observer's reaches its round-off floor (and its statistic, below ``lower``, hands nothing
over).

Stability. Write e_H, e_K for the two estimators' errors and e for the output's.

1. e_H is the error of Theorem 2: the homogeneous observer is run as if alone (it is never
   reset or fed back), so its bounds (finite-time convergence without noise and disturbance,
   input-to-state stability with respect to them) hold unchanged.
2. Between two handovers e_K evolves by the Kalman filter's error map
   ``e+ = Phi (I - K_j C) e + (noise and disturbance terms)``, with K_j the time-varying gain
   for at most ``RECURSION_CYCLES`` samples after a handover and M afterwards. The steady-state
   map ``Phi (I - M C)`` is Schur stable (the record's certificate). The time-varying maps are
   too, as a sequence: the Riccati recursion converges to the stabilising solution P_ss from
   any positive semi-definite start (the model is detectable and stabilisable by the noise,
   what makes the record's P_ss exist), and from P_H >= P_ss (the design floors it) it stays
   at or above P_ss (the Riccati map is monotone), hence K_j -> M and the products of the
   maps converge to powers of the stable one; moreover ``V_j = e^T P_j^-1 e`` does not
   increase along the noise-free error map (the update gives
   ``e^T P^-1 P+ P^-1 e <= e^T P^-1 e`` with ``P+ = (I - K_j C) P <= P``, the prediction
   ``P_j+1 >= Phi P+ Phi^T``), and ``P_ss <= P_j`` with P_j bounded (it converges) bounds V_j
   by |e|^2 from both sides. So e_K is bounded by
   ``c r^j |e_K(t_h)| + gamma_K (noise, disturbance)`` j samples after the last handover t_h
   (or the start), with ``r < 1`` and c depending on the condition of the P_j against P_ss,
   and ``e_K(t_h) = e_H(t_h)`` (or ``e_K(0)``).
3. The dwell time bounds the number of H -> K switches, hence of handovers, on any interval
   of length T by ``1 + T / dwell_time``, and the hysteresis (a return needs a statistic in its
   band for the dwell time, a switch to H the Kalman filter's outside the wider leave band)
   makes the output not chatter. Every K period continues an e_K of point 2, so |e| is at most
   ``max(sup |e_H|, c max(sup |e_H|, |e_K(0)|) + gamma_K)``: bounded by the larger of the two
   estimators' bounds.
4. Without noise and disturbance e_H reaches its floor (round-off) in finite time and e_K
   decays exponentially after its last handover (or from its start), so e tends to round-off
   in both modes (the statistics then fall below ``lower`` and the output stays on H).

A communication step dt must be a whole number n of Kalman samples Ts (the kalman FMU's rule,
within ``SAMPLE_SLACK`` Ts): each of its n cycles adds one innovation to the statistic and the
mode is decided once per step. Invalid y, u or dt raise ValueError with the state unchanged.

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import numpy as np

from .certificate import covariance_problems, innovation_covariance, threshold_problems
from .gains import SupervisedGains
from .kalman_filter import MAX_CYCLES, SAMPLE_SLACK, KalmanObserver
from .linalg import zoh_blocks
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
RECURSION_TOLERANCE = 1e-9
"""The time-varying recursion ends once ``max |P - P_ss| <= RECURSION_TOLERANCE max |P_ss|``."""
RECURSION_CYCLES = 1_000_000
"""The time-varying recursion ends after at most this many cycles (then the steady-state gain,
whatever P is)."""


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
    >>> from fhobs.design.observer import design_for_spec
    >>> from fhobs.design.spec import load_spec
    >>> from fhobs.paper import PENDULUM_SPEC
    >>> record = design_for_spec(load_spec(PENDULUM_SPEC)).supervised
    >>> obs = SupervisedObserver(record)
    >>> obs.step(y=[0.1, 0.0], u=[0.0], dt=record.kalman.sample_time)
    >>> obs.mode == MODE_HOMOGENEOUS, obs.x_hat.shape
    (True, (4,))
    """

    def __init__(self, supervised: SupervisedGains, h: float = DEFAULT_H,
                 scheme: str = SCHEMES[0], z0: np.ndarray | None = None,
                 kernel: bool = True) -> None:
        problems = threshold_problems(supervised) + covariance_problems(supervised)
        if problems:
            raise ValueError("supervised observer: " + "; ".join(problems))
        self.supervised = supervised
        self.homogeneous = FilteringObserver(supervised.filtering, h=h, scheme=scheme, z0=z0,
                                             kernel=kernel)
        self.kalman = KalmanObserver(supervised.kalman, z0=self.homogeneous.z, kernel=kernel)
        self.sample_time = self.kalman.sample_time
        self._n, self._k, self._m = supervised.plant.n, supervised.plant.k, supervised.plant.m
        A, B, self._C = supervised.kalman.model_matrices
        self._Phi, self._Gamma = zoh_blocks(A, [B], self.sample_time)
        self._R = np.diag(supervised.kalman.measurement_std**2)
        self._S_inv = np.linalg.inv(innovation_covariance(supervised.kalman))
        self._S_homogeneous_inv = np.linalg.inv(
            self._C @ supervised.handover_covariance @ self._C.T + self._R)
        self._weight = 1.0 / float(supervised.window)
        self._statistics = np.full(2, float(self._k))
        self._mode = MODE_HOMOGENEOUS
        self._time_consistent = 0.0
        self._P = supervised.kalman.covariance.copy()
        self._cycles_left = 0

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
    def covariance(self) -> np.ndarray:
        """The Kalman filter's a-priori covariance P (copy): the steady-state one, or that of
        the time-varying recursion after a handover while :attr:`recursion` is on."""
        return self._P.copy()

    @property
    def recursion(self) -> bool:
        """Whether the Kalman filter runs the time-varying recursion (after a handover)."""
        return self._cycles_left > 0

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
        nis_homogeneous = float(residual @ self._S_homogeneous_inv @ residual)
        statistics = self._statistics.copy()
        P, cycles_left = self._P, self._cycles_left
        try:
            self.homogeneous.advance(y, u, dt)
            for _ in range(n_cycles):
                innovation = y - self._C @ self.kalman.z
                if cycles_left:
                    nis, P, cycles_left = self._recursion_cycle(innovation, u, P, cycles_left)
                else:
                    nis = float(innovation @ self._S_inv @ innovation)
                    self.kalman.advance(y, u, self.sample_time)
                statistics = np.minimum(statistics + self._weight
                                        * ((nis, nis_homogeneous) - statistics),
                                        self.supervised.ceiling)
            if not (all_finite(statistics) and all_finite(P.ravel())):
                raise ValueError("the innovation statistics or the Kalman filter's covariance "
                                 "are not finite")
        except ValueError:
            self.homogeneous.set_state(before[0])
            self.kalman.set_state(before[1])
            raise
        self._statistics, self._P, self._cycles_left = statistics, P, cycles_left
        self._decide(dt)

    def _recursion_cycle(self, innovation: np.ndarray, u: np.ndarray, P: np.ndarray,
                         cycles_left: int) -> tuple[float, np.ndarray, int]:
        """One cycle of the time-varying Kalman filter from the a-priori covariance P: the
        normalised innovation squared under ``S = C P C^T + R``, the Kalman filter's state
        updated with ``K = P C^T S^-1`` and predicted, the next P (module docstring), and the
        cycles left (0 once P is within ``RECURSION_TOLERANCE`` of the steady state)."""
        C, steady = self._C, self.supervised.kalman.covariance
        CP = C @ P
        S = CP @ C.T + self._R
        gain = np.linalg.solve(S, CP).T
        nis = float(innovation @ np.linalg.solve(S, innovation))
        z = self._Phi @ (self.kalman.z + gain @ innovation) + self._Gamma @ u
        P = self._Phi @ (P - gain @ CP) @ self._Phi.T + self.supervised.kalman.process_covariance
        P = 0.5 * (P + P.T)
        if not all_finite(z):
            raise ValueError("the Kalman step diverged (non-finite state); state left unchanged")
        self.kalman.set_state(np.append(z, 0.0))
        converged = np.abs(P - steady).max() <= RECURSION_TOLERANCE * np.abs(steady).max()
        return nis, P, 0 if converged else cycles_left - 1

    def _decide(self, dt: float) -> None:
        """The mode after a step of dt, with the handover at H -> K."""
        record = self.supervised
        kalman, homogeneous = self._statistics
        if self._mode == MODE_KALMAN:
            if kalman > record.upper or (kalman < record.lower and homogeneous < kalman):
                self._mode, self._time_consistent = MODE_HOMOGENEOUS, 0.0
            return
        kalman_consistent = record.lower_return < kalman < record.upper_return
        if not (kalman_consistent or record.lower <= homogeneous <= record.upper):
            self._time_consistent = 0.0
            return
        self._time_consistent += dt
        if self._time_consistent >= record.dwell_time * (1.0 - DWELL_SLACK):
            if not kalman_consistent:
                self.kalman.set_state(np.append(self.homogeneous.z, 0.0))
                self._P = record.handover_covariance.copy()
                self._cycles_left = RECURSION_CYCLES
                self._statistics[0] = homogeneous
            self._mode = MODE_KALMAN

    # -- state ----------------------------------------------------------------------------
    def get_state(self) -> np.ndarray:
        """The full internal state (a copy): the statistic and the mode (the outputs that are
        state, first), the homogeneous observer's statistic and the time the statistic has
        been inside the return band in H, then the homogeneous observer's state, the Kalman
        filter's, its covariance P (row by row) and the cycles left of the time-varying
        recursion (0: the steady-state gain)."""
        head = (self._statistics[0], float(self._mode), self._statistics[1],
                self._time_consistent)
        return np.concatenate((head, self.homogeneous.get_state(), self.kalman.get_state(),
                               self._P.ravel(), [float(self._cycles_left)]))

    def set_state(self, arr: np.ndarray) -> None:
        """Restore a state from :meth:`get_state` exactly.

        Raises
        ------
        ValueError
            If ``arr`` is not such a state (size, finite entries, a negative statistic or
            time, a mode other than 0 or 1, cycles left not a whole number in
            ``[0, RECURSION_CYCLES]``); the state is then left unchanged.
        """
        size = self._P.shape[0]
        sizes = (self.homogeneous.get_state().size, self.kalman.get_state().size, size * size)
        arr = as_finite_vector(arr, HEAD_SIZE + sum(sizes) + 1, "supervised observer state")
        kalman_statistic, mode, homogeneous_statistic, time_consistent = arr[:HEAD_SIZE].tolist()
        statistics = np.array([kalman_statistic, homogeneous_statistic])
        if min(*statistics, time_consistent) < 0.0 or mode not in (MODE_KALMAN, MODE_HOMOGENEOUS):
            raise ValueError(f"supervised observer state: the statistics {statistics.tolist()} "
                             f"and the time in band {time_consistent!r} must be >= 0 and the "
                             f"mode 0 or 1, got {mode!r}")
        cycles_left = float(arr[-1])
        if not (cycles_left.is_integer() and 0 <= cycles_left <= RECURSION_CYCLES):
            raise ValueError(f"supervised observer state: the cycles left of the recursion "
                             f"{cycles_left!r} must be a whole number in [0, {RECURSION_CYCLES}]")
        ends = np.cumsum((HEAD_SIZE, *sizes))
        homogeneous_before = self.homogeneous.get_state()
        self.homogeneous.set_state(arr[ends[0]:ends[1]])
        try:
            self.kalman.set_state(arr[ends[1]:ends[2]])
        except ValueError:
            self.homogeneous.set_state(homogeneous_before)
            raise
        self._statistics, self._mode, self._time_consistent = statistics, int(mode), time_consistent
        self._P, self._cycles_left = arr[ends[2]:ends[3]].reshape(size, size), int(cycles_left)

    def diagnostics(self) -> dict[str, float | np.ndarray]:
        """``z`` (the output's), ``mode``, ``statistic``, ``homogeneous_statistic``,
        ``time_consistent``, ``recursion`` (1.0 while the time-varying recursion runs) and
        ``covariance`` (the Kalman filter's P), both estimators' z (``z_homogeneous``,
        ``z_kalman``) and the homogeneous observer's psi, xi and sigma."""
        homogeneous = self.homogeneous.diagnostics()
        return {"z": self.z, "mode": float(self._mode), "statistic": self.statistic,
                "homogeneous_statistic": self.homogeneous_statistic,
                "time_consistent": self._time_consistent, "recursion": float(self.recursion),
                "covariance": self.covariance, "z_homogeneous": homogeneous["z"],
                "z_kalman": self.kalman.z, "psi": homogeneous["psi"], "xi": homogeneous["xi"],
                "sigma": homogeneous["sigma"]}
