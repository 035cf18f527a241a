"""Predicted settling time and peaking of a designed filtering observer.

The estimation error of the observer does not depend on the plant's motion (the plant's
inputs are known to the observer and the model is exact), so it can be simulated alone: a plant
at rest (x = 0, u = 0, y = 0) and an observer started at ``z0 = -e0``, whose state z is then
the error. :func:`error_response` runs that with the runtime's split scheme, which is the
observer that the FMU runs, at a communication step fine enough for the settling time.

This module is numpy-only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.gains import FilteringGains
from ..core.linalg import expm
from ..core.runtime import FilteringObserver

SETTLED = 1e-3
"""An error has settled when it stays below this fraction of its initial size."""
CONVERGED = 1e-12
"""A simulated error below this fraction of its initial size ends its run early (the
observer's error then stays at round-off)."""
STEPS_PER_SETTLING_TIME = 500
"""Communication steps of the prediction per requested settling time (the settling time is
known to 0.2 % of the request; 2000 steps change the zoo's and the stiff examples' predictions
by at most 10 % and none of the rho choices, at four times the cost)."""
HORIZON = 3.0
"""The prediction runs for this many requested settling times."""


@dataclass(frozen=True)
class ErrorResponse:
    """Worst case over the initial errors of :func:`error_response`.

    Attributes
    ----------
    settling_time : float
        Time (s) after which every error stays below ``SETTLED`` times its initial size
        (inf if some error does not within the horizon).
    peaking : float
        Largest ``|e(t)| / |e(0)|``.
    final : float
        Largest ``|e| / |e(0)|`` at the end of the horizon (0 for runs that reached round-off
        before it): how far an error that has not settled still is.
    """

    settling_time: float
    peaking: float
    final: float = 0.0


def initial_errors(state_scale: np.ndarray) -> list[np.ndarray]:
    """The initial errors of the prediction: ``state_scale`` times all ones, and times
    alternating signs (an error whose components do not all point one way).

    Examples
    --------
    >>> [e.tolist() for e in initial_errors(np.array([1.0, 2.0]))]
    [[1.0, 2.0], [1.0, -2.0]]
    """
    signs = np.where(np.arange(state_scale.size) % 2 == 0, 1.0, -1.0)
    return [state_scale.copy(), state_scale * signs]


def error_response(filtering: FilteringGains, state_scale: np.ndarray,
                   settling_time: float) -> ErrorResponse:
    """Simulate the error from each of :func:`initial_errors` for ``HORIZON`` settling times;
    errors are measured in units of ``state_scale`` (``|e / state_scale|``), so that states of
    very different sizes count alike.

    Parameters
    ----------
    filtering : FilteringGains
        The filtering observer.
    state_scale : numpy.ndarray
        Typical size of each plant state (n entries).
    settling_time : float
        The requested settling time (s): sets the step ``settling_time /
        STEPS_PER_SETTLING_TIME`` and the horizon.

    Returns
    -------
    ErrorResponse

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> response = error_response(paper_gains().filtering, np.ones(4), settling_time=2.0)
    >>> bool(response.settling_time < 2.0), bool(response.peaking >= 1.0)
    (True, True)
    """
    dt = settling_time / STEPS_PER_SETTLING_TIME
    steps = int(round(HORIZON * STEPS_PER_SETTLING_TIME))
    plant = filtering.plant
    y, u = np.zeros(plant.k), np.zeros(plant.m)
    worst_time, worst_peak, worst_final = 0.0, 1.0, 0.0
    observer = FilteringObserver(filtering, h=dt)  # one observer: its plan of dt made once
    start = observer.get_state()
    for e0 in initial_errors(state_scale):
        state = start.copy()
        state[:plant.n] = -e0
        observer.set_state(state)
        size = math.sqrt(plant.n)  # |e0| in units of state_scale
        last_above, error = 0, 1.0
        for step in range(1, steps + 1):
            try:
                observer.advance(y, u, dt)
            except ValueError:
                return ErrorResponse(np.inf, np.inf, np.inf)
            error = float(np.linalg.norm(observer.x_hat / state_scale)) / size
            worst_peak = max(worst_peak, error)
            if error > SETTLED:
                last_above = step
            elif error < CONVERGED:
                error = 0.0
                break
        worst_time = max(worst_time, math.inf if last_above == steps else last_above * dt)
        worst_final = max(worst_final, error)
    return ErrorResponse(worst_time, worst_peak, worst_final)


HELD_STEPS = (10, 20, 50, 100, 200, 500)
"""Communication steps H = settling_time / N tried by :func:`communication_step_bracket`,
coarsest first (N = ``STEPS_PER_SETTLING_TIME``, the fine prediction's, last)."""
HELD_SLOWDOWN = 2.0
"""Held inputs are tolerated while the settling time stays within this factor of the fine
step's."""
BRACKET_RATIO = 1.1
"""The bisection between a tolerated and a refused step ends when they are this close."""


def held_input_response(filtering: FilteringGains, state_scale: np.ndarray,
                        settling_time: float, step: float, K: np.ndarray) -> ErrorResponse:
    """The estimation error of the runtime as a co-simulation master runs it: the plant (exact
    ZOH) in closed loop with ``u = K x_hat``, the observer fed ``y`` and ``u`` of each step's
    start, held over the communication step ``step``; from each of :func:`initial_errors` as
    the plant's initial state with the observer at 0, for ``HORIZON`` settling times.

    Unlike :func:`error_response` (a plant at rest, whose held output is exact), the plant moves
    within a step while the observer sees its output of the step's start.

    Parameters
    ----------
    filtering : FilteringGains
        The filtering observer (run at its own internal step, ``h = DEFAULT_H``).
    state_scale : numpy.ndarray
        Typical size of each plant state (n entries); the unit of the error.
    settling_time : float
        The horizon's unit (s).
    step : float
        The communication step H (s).
    K : numpy.ndarray
        The state feedback (m x n) closing the loop on the estimate.

    Returns
    -------
    ErrorResponse
        Infinite figures if the runtime refuses the step or the error grows beyond 1e6.

    Examples
    --------
    >>> from fhobs.design.feedback import state_feedback
    >>> from fhobs.design.observer import paper_gains
    >>> gains = paper_gains().filtering
    >>> K = state_feedback(gains.plant.A, gains.plant.B)
    >>> response = held_input_response(gains, np.ones(4), 2.0, 1e-3, K)
    >>> bool(response.settling_time < 2.0)
    True
    """
    plant = filtering.plant
    steps = int(math.ceil(HORIZON * settling_time / step))
    Phi, Gamma = _zoh(plant.A, plant.B, step)
    observer = FilteringObserver(filtering)
    start = observer.get_state()
    worst_time, worst_peak, worst_final = 0.0, 1.0, 0.0
    size = math.sqrt(plant.n)
    for e0 in initial_errors(state_scale):
        observer.set_state(start.copy())
        x = e0.copy()
        last_above, error = 0, 1.0
        for k in range(1, steps + 1):
            u = K @ observer.x_hat
            try:
                observer.advance(plant.C @ x, u, step)
            except ValueError:
                return ErrorResponse(np.inf, np.inf, np.inf)
            x = Phi @ x + Gamma @ u
            error = float(np.linalg.norm((observer.x_hat - x) / state_scale)) / size
            if not error < 1e6:
                return ErrorResponse(np.inf, np.inf, np.inf)
            worst_peak = max(worst_peak, error)
            if error > SETTLED:
                last_above = k  # no early end at round-off: a held loop may grow from there
        worst_time = max(worst_time, math.inf if last_above == steps else last_above * step)
        worst_final = max(worst_final, error)
    return ErrorResponse(worst_time, worst_peak, worst_final)


def communication_step_bracket(filtering: FilteringGains, state_scale: np.ndarray,
                               settling_time: float, K: np.ndarray) -> tuple[float, float]:
    """The longest communication step with held inputs the design tolerates, as ``(held,
    refused)``: at ``held`` the closed loop's error (:func:`held_input_response`) settles
    within ``HELD_SLOWDOWN`` times the settling time at the fine step ``settling_time /
    STEPS_PER_SETTLING_TIME`` (where that does not settle within the horizon, its error at
    the horizon's end is within that factor of the fine step's); at ``refused`` (at most
    ``BRACKET_RATIO`` times ``held``, or inf when the coarsest step of ``HELD_STEPS`` is
    tolerated) it does not.

    Examples
    --------
    >>> from fhobs.design.feedback import state_feedback
    >>> from fhobs.design.observer import paper_gains
    >>> gains = paper_gains().filtering
    >>> K = state_feedback(gains.plant.A, gains.plant.B)
    >>> held, refused = communication_step_bracket(gains, np.ones(4), 2.0, K)
    >>> bool(held < refused <= BRACKET_RATIO * held)
    True
    """
    fine = held_input_response(filtering, state_scale, settling_time,
                               settling_time / STEPS_PER_SETTLING_TIME, K)

    def tolerated(step: float) -> bool:
        held = held_input_response(filtering, state_scale, settling_time, step, K)
        if math.isfinite(fine.settling_time):
            return held.settling_time <= HELD_SLOWDOWN * fine.settling_time
        return held.final <= HELD_SLOWDOWN * fine.final  # not settled in the horizon: how far

    refused = math.inf
    for n_steps in HELD_STEPS:
        held = settling_time / n_steps
        if n_steps == STEPS_PER_SETTLING_TIME or tolerated(held):
            break
        refused = held
    while math.isfinite(refused) and refused / held > BRACKET_RATIO:
        middle = math.sqrt(held * refused)
        held, refused = (middle, refused) if tolerated(middle) else (held, middle)
    return held, refused


def _zoh(A: np.ndarray, B: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The plant's exact ZOH step (Phi, Gamma) of size ``step``."""
    n, m = B.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n], block[:n, n:] = A * step, B * step
    exp = expm(block)
    return exp[:n, :n], exp[:n, n:]
