"""Steady-state discrete Kalman filter (numpy only): the noise-optimal linear baseline.

The filter runs on the extended model of :mod:`fhobs.core.disturbance` (order
``kalman.disturbance_order``) sampled with the exact zero-order hold at the filter's
sample time Ts: ``Phi = expm(Ts A_model)``, ``Gamma = int_0^Ts expm(t A_model) dt B_model``.
One cycle with the measurement y_k and the input u_k of the sample t_k:

    update:   z_k|k    = z_k|k-1 + M (y_k - C_model z_k|k-1)
    predict:  z_k+1|k  = Phi z_k|k + Gamma u_k

with the steady-state gain M of :class:`fhobs.core.gains.KalmanGains`. The state kept (and ``z``,
``x_hat``) is the one-step prediction ``z_k+1|k``: after a communication step from t_k the
estimate is that of t_k+1 from the measurements up to y_k, the information the Jacobi
co-simulation gives every observer. Both equations are precomputed as one matrix
``z+ = [Phi (I - M C), Phi M, Gamma] (z, y, u)``.

Communication steps of any size. The filter samples at the instants ``t0 + j Ts`` (t0: where
it started). A communication step ``[t, t + dt)`` runs one cycle for every sample instant that
falls inside it, with the y and u held over the step (a zero-order-hold sensor sampled at Ts),
and none when no instant falls inside: between samples the estimate is held. After the step
the state is the prediction for the next sample instant, so for ``dt = n Ts`` (the design's
case) a step runs exactly n cycles and its estimate is that of ``t + dt``. The state carries,
besides z, the ``offset`` from the current time to the next sample instant (in ``[0, Ts)``);
a sample instant within ``SAMPLE_SLACK`` Ts of a step's end belongs to the next step, so a
host that accumulates time in floating point (and ends a step a few ulps before or after a
sample instant) runs the same cycles as one that steps exactly.

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import math

import numpy as np

from . import kernel as compiled
from .gains import KalmanGains
from .linalg import zoh_blocks
from .validation import all_finite, as_finite_vector, check_step_size, floating_point_failure

SAMPLE_SLACK = 1e-6
"""A sample instant closer than this fraction of Ts to a step's end belongs to the next step."""

MAX_CYCLES = 1_000_000
"""A communication step of more filter cycles than this is rejected (a mistake, not a request)."""


def samples_in_step(offset: float, dt: float, sample_time: float) -> tuple[int, float]:
    """The filter cycles of a communication step and the offset of the next sample after it.

    Parameters
    ----------
    offset : float
        Time from the step's start to the next sample instant, in ``[0, Ts)``.
    dt : float
        The communication step (positive).
    sample_time : float
        The filter's sample time Ts.

    Returns
    -------
    n : int
        The number of sample instants ``offset + i Ts`` (i >= 0) before
        ``dt - SAMPLE_SLACK Ts``, and at least 1 when ``offset`` is 0: the sample at the step's
        start is in the step, however short the step (steps shorter than the slack would
        otherwise defer it for ever).
    offset : float
        Time from the step's end to the next sample instant (``offset + n Ts - dt``, at least 0).

    Raises
    ------
    ValueError
        If the step holds more than ``MAX_CYCLES`` sample instants.

    Examples
    --------
    >>> samples_in_step(0.0, 3e-3, 1e-3)
    (3, 0.0)
    >>> samples_in_step(0.0, 0.5e-3, 1e-3), samples_in_step(0.5e-3, 0.5e-3, 1e-3)
    ((1, 0.0005), (0, 0.0))
    >>> samples_in_step(0.0, 1e-10, 1e-3)
    (1, 0.0009999999)
    """
    n = max(math.ceil((dt - offset) / sample_time - SAMPLE_SLACK), 0 if offset > 0.0 else 1)
    if n > MAX_CYCLES:
        raise ValueError(f"the step size {dt!r} holds {n} samples of Ts = {sample_time!r}, more "
                         f"than {MAX_CYCLES}; state left unchanged")
    return n, max((offset + n * sample_time) - dt, 0.0)


class KalmanObserver:
    """Steady-state discrete Kalman filter with the observers' interface (module docstring).

    Parameters
    ----------
    kalman : KalmanGains
        The filter's record (a design's ``kalman``), on its plant.
    z0 : array_like or None
        Initial prediction: the plant's n states, or the model's N (zeros if None; with n
        entries the disturbance states start at zero).
    kernel : bool
        Run the cycles in the compiled kernel when it is available (:mod:`fhobs.core.kernel`);
        False: numpy only.

    Examples
    --------
    A double integrator at rest at x = (1, 0), the filter started at zero:

    >>> from fhobs.design.observer import design_for_spec
    >>> from fhobs.design.spec import spec_from_dict
    >>> spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]],
    ...                        "E": [[0], [1]], "observer": {"rho": 2.0},
    ...                        "noise": {"measurement_std": [0.01], "sample_time": 0.01,
    ...                                  "process_intensity": 1.0}})
    >>> kalman = design_for_spec(spec).kalman  # the Kalman filter of the [noise] table
    >>> obs = KalmanObserver(kalman)
    >>> for _ in range(500):
    ...     obs.step(y=[1.0], u=[0.0], dt=kalman.sample_time)
    >>> bool(np.allclose(obs.x_hat, [1.0, 0.0], atol=1e-9))
    True
    """

    def __init__(self, kalman: KalmanGains, z0: np.ndarray | None = None,
                 kernel: bool = True) -> None:
        plant = kalman.plant
        self.kalman = kalman
        self.sample_time = check_step_size(kalman.sample_time)
        A, B, C = kalman.model_matrices
        size = A.shape[0]
        if kalman.gain.shape != (size, plant.k):
            raise ValueError(f"Kalman gain has shape {kalman.gain.shape}, expected "
                             f"({size}, {plant.k}) for disturbance order "
                             f"{kalman.disturbance_order}")
        self._k, self._m, self._n = plant.k, plant.m, plant.n
        Phi, Gamma = zoh_blocks(A, [B], self.sample_time)
        self._cycle = np.hstack((Phi - Phi @ kalman.gain @ C, Phi @ kalman.gain, Gamma))
        self._z = np.zeros(size)
        self._offset = 0.0
        if z0 is not None:
            z0 = np.asarray(z0, dtype=float).reshape(-1)
            if z0.size == self._n:  # the plant's states; the disturbance states start at zero
                z0 = np.concatenate((z0, self._z[self._n:]))
            self._z = as_finite_vector(z0, size, "z0")
        library = compiled.library() if kernel else None
        self._stepper = None if library is None else compiled.Stepper(
            library.fhobs_kalman_step, (size,), (self._k, self._m), self._kernel_plan)

    @property
    def z(self) -> np.ndarray:
        """The filter's model state (copy): x_hat, then the disturbance-model estimates."""
        return self._z.copy()

    @property
    def x_hat(self) -> np.ndarray:
        """Estimate of the plant's state (copy of the first n entries of z)."""
        return self._z[:self._n].copy()

    @property
    def q_hat(self) -> np.ndarray:
        """Disturbance-model estimates (q, then its derivatives; empty for order 0)."""
        return self._z[self._n:].copy()

    def step(self, y: np.ndarray, u: np.ndarray, dt: float) -> None:
        """Advance by dt with y and u held: one cycle per sample instant inside the step
        (module docstring).

        Raises
        ------
        ValueError
            On invalid y, u or dt, a step of more than ``MAX_CYCLES`` samples, or a non-finite
            result; the state is then left unchanged.
        """
        self.advance(as_finite_vector(y, self._k, "y"), as_finite_vector(u, self._m, "u"),
                     check_step_size(dt))

    def advance(self, y: np.ndarray, u: np.ndarray, dt: float) -> None:
        """:meth:`step` without checking y, u (finite, of k and m entries) and the sign of dt;
        too many samples and a non-finite result still raise ValueError."""
        n_cycles, offset = samples_in_step(self._offset, dt, self.sample_time)
        if n_cycles:
            self._z = self._cycles(n_cycles, y, u)
        self._offset = offset

    def _cycles(self, n_cycles: int, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        """z after n_cycles filter cycles with y and u held (ValueError if not finite)."""
        stepper = self._stepper
        if stepper is not None:
            if stepper.run(float(n_cycles), self._z, self._z, y, u) != compiled.OK:
                raise ValueError("the Kalman step diverged (non-finite state); state left "
                                 "unchanged")
            return stepper.state[0]
        z, tail = self._z, np.concatenate((y, u))
        try:
            for _ in range(n_cycles):
                z = self._cycle.dot(np.concatenate((z, tail)))
        except ArithmeticError as err:
            raise floating_point_failure("Kalman", err) from err
        if not all_finite(z):
            raise ValueError("the Kalman step diverged (non-finite state); state left unchanged")
        return z

    @property
    def compiled(self) -> bool:
        """Whether the cycles run in the compiled kernel (:mod:`fhobs.core.kernel`)."""
        return self._stepper is not None

    def _kernel_plan(self, cycles: float) -> None:
        """Register the kernel's plan of ``cycles`` filter cycles (its key in the stepper)."""
        work = np.zeros(compiled.kalman_work_size(self._z.size, self._k))
        plan = compiled.LinearPlan(n=self._z.size, k=self._k, m=self._m, cycles=int(cycles),
                                   M=compiled.pointer(self._cycle), work=compiled.pointer(work))
        self._stepper.add_plan(cycles, plan, self._cycle, work)

    def get_state(self) -> np.ndarray:
        """The full internal state (a copy): the prediction z, then the offset to the next
        sample instant."""
        return np.append(self._z, self._offset)

    def set_state(self, arr: np.ndarray) -> None:
        """Restore a state from :meth:`get_state` exactly.

        Raises
        ------
        ValueError
            If ``arr`` is not such a state (size, finite entries, offset in ``[0, Ts)``).
        """
        arr = as_finite_vector(arr, self._z.size + 1, "Kalman state")
        offset = float(arr[-1])
        if not 0.0 <= offset < self.sample_time:
            raise ValueError(f"Kalman state: the offset to the next sample {offset!r} is not in "
                             f"[0, Ts = {self.sample_time!r})")
        self._z, self._offset = arr[:-1].copy(), offset

    def diagnostics(self) -> dict[str, float | np.ndarray]:
        """``z``, ``q_hat``, the sample time and the offset to the next sample instant."""
        return {"z": self.z, "q_hat": self.q_hat, "sample_time": self.sample_time,
                "offset": self._offset}
