"""The reference loop in C (harness/reference_loop.c) against the same loop stepped from Python:
the same kernel steps in the same order. On the pendulum (n = 4) the same trajectories bit for
bit: numpy sums C x and K z in the order the C loop does. On larger plants numpy's BLAS sums
them in another order: y and u differ in the last bits (measured <= 3.5e-16 relative over
0.3 s), which the filtering observer amplifies as it amplifies any round-off of y (measured
<= 3.9e-13 on z and xi): held to the kernel's 1e-12. Plants of every shape the zoo has (a
disturbance model, MIMO, n = 10), the Kalman filter replayed, the feedback on the state, the
Euler scheme with substeps; a non-finite state refused by both loops."""

from __future__ import annotations

import numpy as np
import pytest
from designs import random_design, zoo_design
from fhobs.design.feedback import state_feedback

from harness import reference
from harness.native import reference_library

pytestmark = pytest.mark.skipif(reference_library() is None,
                                reason="the reference loop is compiled with cc on linux")

FIELDS = ("x", "z", "z_lin", "z_kalman", "psi", "xi", "sigma", "q_hat", "y", "u")
DATA = ("x", "z_lin", "z_kalman", "y", "u")
"""The trajectories that do not pass through the filtering observer's amplification."""


def python_loop(monkeypatch, *args, **kwargs) -> reference.SimulationResult:
    """:func:`reference.simulate` with its loop stepped from Python (the kernel's steps)."""
    with monkeypatch.context() as patch:
        patch.setattr(reference, "reference_library", lambda: None)
        return reference.simulate(*args, **kwargs)


def assert_same(a: reference.SimulationResult, b: reference.SimulationResult,
                exact: bool = True) -> None:
    """Every trajectory of a and b equal (``exact``), else within 1e-14 relative (norm-wise)
    for :data:`DATA` and 1e-12 for the filtering observer's."""
    for name in FIELDS:
        left, right = getattr(a, name), getattr(b, name)
        assert (left is None) == (right is None), name
        if left is None:
            continue
        assert left.shape == right.shape, name
        if exact:
            assert np.array_equal(left, right), name
        else:
            scale = max(np.linalg.norm(right), 1e-300)
            limit = 1e-14 if name in DATA else 1e-12
            assert np.linalg.norm(left - right) <= limit * scale, name


@pytest.mark.parametrize("scenario", ["nominal", "perturbed_noisy"])
def test_paper_loop_with_a_kalman_filter(kalman_design, monkeypatch, scenario):
    c_loop = reference.simulate(kalman_design, scenario, t_end=0.5)
    assert c_loop.z_kalman is not None and c_loop.error[-1] < 0.2 * c_loop.error[0]
    assert_same(c_loop, python_loop(monkeypatch, kalman_design, scenario, t_end=0.5))


@pytest.mark.parametrize("design", [
    lambda: zoo_design("random_mimo10"),
    lambda: zoo_design("quarter_car"),
    lambda: random_design(2, 8, 2, 1),
], ids=["random_mimo10", "quarter_car", "random_8_2_order_1"])
@pytest.mark.parametrize(("scheme", "dt", "h"), [("split", 1e-3, None), ("euler", 2e-3, 5e-4)])
def test_other_plants_feedback_on_the_state(design, monkeypatch, scheme, dt, h):
    design = design()
    plant = design.plant
    kwargs = dict(t_end=0.3, dt=dt, h=h, scheme=scheme, K=state_feedback(plant.A, plant.B),
                  x0=np.linspace(1.0, -1.0, plant.n), feedback="state")
    c_loop = reference.simulate(design, "perturbed_noisy", **kwargs)
    assert np.all(np.isfinite(c_loop.z)) and c_loop.u.shape == (round(0.3 / dt), plant.m)
    assert_same(c_loop, python_loop(monkeypatch, design, "perturbed_noisy", **kwargs),
                exact=plant.n <= 4)


def test_feedback_on_the_estimate_of_a_disturbance_model(monkeypatch):
    """The estimate that closes the loop is the first n entries of the model's state."""
    design = random_design(4, 10, 3, 1)
    plant = design.plant
    kwargs = dict(t_end=0.2, dt=1e-3, K=0.1 * state_feedback(plant.A, plant.B),
                  x0=np.ones(plant.n))
    c_loop = reference.simulate(design, "perturbed", **kwargs)
    assert c_loop.q_hat.shape[1] == 1
    assert_same(c_loop, python_loop(monkeypatch, design, "perturbed", **kwargs), exact=False)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
def test_a_state_that_overflows_is_refused(paper_design, monkeypatch):
    """A feedback of 1e300 overflows the plant in the first steps: ValueError from either
    loop, the C loop naming the plant."""
    K = np.full((1, 4), 1e300)
    with pytest.raises(ValueError, match="plant"):
        reference.simulate(paper_design, "nominal", t_end=0.01, K=K)
    with pytest.raises(ValueError, match="plant"):
        python_loop(monkeypatch, paper_design, "nominal", t_end=0.01, K=K)
