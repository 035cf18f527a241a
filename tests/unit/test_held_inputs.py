"""The longest communication step a design tolerates with its inputs held
(fhobs.design.settling.communication_step_bracket), against a closed loop written out here: the
plant stepped by scipy's matrix exponential, the runtime fed y and u of each step's start, u
from the estimate; at the figure the error settles within twice the fine step's settling time,
at the refused step just above it does not."""

import math

import numpy as np
import pytest
import scipy.linalg
from fhobs.core.runtime import FilteringObserver
from fhobs.design.feedback import state_feedback
from fhobs.design.observer import paper_gains
from fhobs.design.settling import (
    BRACKET_RATIO,
    HELD_SLOWDOWN,
    SETTLED,
    STEPS_PER_SETTLING_TIME,
    communication_step_bracket,
)

SETTLING_TIME = 2.0


def settling_time(gains, K, step: float, x0: np.ndarray, horizon: float) -> float:
    """Last time the relative estimation error of the closed loop is above SETTLED (inf when it
    is at the horizon's end or the runtime refuses the step)."""
    A, B, C = gains.plant.A, gains.plant.B, gains.plant.C
    n, m = B.shape
    block = scipy.linalg.expm(np.block([[A, B], [np.zeros((m, n + m))]]) * step)
    Phi, Gamma = block[:n, :n], block[:n, n:]
    observer = FilteringObserver(gains)
    x, last = x0.copy(), 0.0
    steps = math.ceil(horizon / step)
    for k in range(1, steps + 1):
        u = K @ observer.x_hat
        try:
            observer.step(C @ x, u, step)
        except ValueError:
            return math.inf
        x = Phi @ x + Gamma @ u
        if np.linalg.norm(observer.x_hat - x) > SETTLED * np.linalg.norm(x0):
            last = k * step
    return math.inf if last >= steps * step - step / 2 else last


@pytest.fixture(scope="module")
def case():
    gains = paper_gains().filtering
    K = state_feedback(gains.plant.A, gains.plant.B)
    held, refused = communication_step_bracket(gains, np.ones(4), SETTLING_TIME, K)
    return gains, K, held, refused


def test_the_bracket_is_narrow_and_above_the_fine_step(case):
    _, _, held, refused = case
    assert SETTLING_TIME / STEPS_PER_SETTLING_TIME < held < refused <= BRACKET_RATIO * held


def test_the_closed_loop_settles_at_the_figure_and_not_above_it(case):
    gains, K, held, refused = case
    x0 = np.ones(4)  # the first of the prediction's initial errors
    horizon = 3 * SETTLING_TIME
    fine = settling_time(gains, K, SETTLING_TIME / STEPS_PER_SETTLING_TIME, x0, horizon)
    assert 0 < fine < SETTLING_TIME
    assert settling_time(gains, K, held, x0, horizon) <= HELD_SLOWDOWN * fine
    at_refused = max(settling_time(gains, K, refused, x0 * signs, horizon)
                     for signs in (np.ones(4), np.array([1.0, -1.0, 1.0, -1.0])))
    assert at_refused > HELD_SLOWDOWN * fine
