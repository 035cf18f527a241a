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
