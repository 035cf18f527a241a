"""The disturbance model (extended-state observer): the extended matrices, and exact estimation
of a constant perturbation, which the model describes exactly."""

import tomllib

import numpy as np
import pytest
from fhobs.core.disturbance import extended_model, model_perturbation_matrix
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver
from fhobs.design.feedback import state_feedback
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import spec_from_dict
from fhobs.paper import EXAMPLES, K_PAPER, X0_PAPER


def test_extended_model_blocks():
    rng = np.random.default_rng(7)
    A, B = rng.standard_normal((3, 3)), rng.standard_normal((3, 1))
    C, E = rng.standard_normal((2, 3)), rng.standard_normal((3, 2))
    A_m, B_m, C_m = extended_model(A, B, C, E, order=2)
    expected = np.zeros((7, 7))
    expected[:3, :3], expected[:3, 3:5], expected[3:5, 5:7] = A, E, np.eye(2)
    np.testing.assert_array_equal(A_m, expected)
    np.testing.assert_array_equal(B_m, np.vstack([B, np.zeros((4, 1))]))
    np.testing.assert_array_equal(C_m, np.hstack([C, np.zeros((2, 4))]))
    assert extended_model(A, B, C, None, order=0) == (A, B, C)
    # the model's unknown input q'' drives the last block: A_m^2 E_model lands in E's columns
    E_model = model_perturbation_matrix(3, 2, 2)
    np.testing.assert_array_equal((A_m @ A_m @ E_model)[:3], E)


def test_constant_perturbation_is_estimated_to_round_off(tuned_design):
    """q = 0.3 constant in the paper's closed loop (noise-free): the model is exact, so x_hat and
    q_hat converge to round-off, like the nominal case."""
    g, dt, q = tuned_design, 5e-5, np.array([0.3])
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, g.plant.E, x0=X0_PAPER)
    obs = FilteringObserver(g.filtering, h=dt)
    for _ in range(int(round(1.5 / dt))):
        y, u = plant.y, K_PAPER @ obs.x_hat
        plant.step(u, q, dt)
        obs.step(y, u, dt)
    assert np.linalg.norm(obs.x_hat - plant.x) <= 1e-9
    assert abs(obs.z[4] - q[0]) <= 1e-9


@pytest.mark.parametrize("order", [1, 2, 3])
def test_disturbance_models_of_every_order_design_on_the_pendulum(order):
    """Orders 1..3 (HOSM nu of the extended model, rho = gamma = 6) are certified, and the
    designed observer tracks the pendulum driven by a q of degree order - 1 (noise-free, LQR
    feedback on the true state): the error falls below 1e-6 of max |x| within 4 s (the plant
    holds q over each step, a staircase that the model's polynomial matches up to O(dt))."""
    data = tomllib.loads((EXAMPLES / "pendulum.toml").read_text())
    data = {k: v for k, v in data.items() if k in ("A", "B", "C", "E")}
    data["observer"] = {"disturbance_order": order, "rho": 6.0, "gamma": 6.0}
    g = design_for_spec(spec_from_dict(data, f"pendulum, order {order}"))
    assert g.model.n_model == 4 + order
    assert g.filtering.certificate["checks"]["lmi_filtering"] < 0
    dt, coefficients = 1e-3, [0.3, -0.2, 0.1][:order]
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, g.plant.E, x0=X0_PAPER)
    obs = FilteringObserver(g.filtering, h=dt)
    K = state_feedback(g.plant.A, g.plant.B)
    size = 0.0
    for step in range(int(round(4.0 / dt))):
        t = step * dt
        q = np.array([sum(c * t**j for j, c in enumerate(coefficients))])
        y, u = plant.y, K @ plant.x
        size = max(size, np.linalg.norm(plant.x))
        plant.step(u, q, dt)
        obs.step(y, u, dt)
    assert np.linalg.norm(obs.x_hat - plant.x) <= 1e-6 * size
