"""The numpy-only plant: exact ZOH step, reproducible noise, state round trip, input checks."""

import numpy as np
import pytest
from fhobs.core.plant import LTIPlant, uniform_noise
from scipy.integrate import solve_ivp

A = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0],
              [0.0, 152.0057, -12.2542, -0.5005], [0.0, 264.3080, -12.1117, -0.8702]])
B = np.array([[0.0], [0.0], [50.6372], [50.0484]])
C = np.eye(2, 4)


@pytest.fixture()
def plant():
    return LTIPlant(A, B, C, B, x0=[2.0, 2.0, 1.0, 2.0], noise_amplitude=1e-3, seed=7)


def test_zoh_step_matches_ode_solution(plant):
    u, q, dt = np.array([0.7]), np.array([-0.2]), 0.01
    x0 = plant.x
    plant.step(u, q, dt)
    sol = solve_ivp(lambda t, x: A @ x + B @ u + B @ q, (0.0, dt), x0,
                    rtol=1e-12, atol=1e-14, method="DOP853")
    assert np.allclose(plant.x, sol.y[:, -1], rtol=1e-10, atol=1e-12)


def test_noise_is_uniform_bounded_and_a_function_of_seed_and_index():
    draws = np.array([uniform_noise(3, k, 1e-3, 2) for k in range(5000)])
    assert np.all(np.abs(draws) <= 1e-3)
    assert abs(draws.mean()) < 3e-5 and abs(draws.std() - 1e-3 / np.sqrt(3)) < 2e-5
    assert np.array_equal(uniform_noise(3, 4321, 1e-3, 2), draws[4321])
    assert not np.array_equal(uniform_noise(4, 4321, 1e-3, 2), draws[4321])
    assert np.array_equal(uniform_noise(3, 10, 0.0, 2), np.zeros(2))


def test_state_round_trip_replays_noise_bit_for_bit(plant):
    for _ in range(3):
        plant.step([0.1], [0.0], 1e-3)
    saved = plant.get_state()
    first = [(plant.step([0.2], [0.05], 1e-3), plant.y)[1] for _ in range(5)]
    plant.set_state(saved)
    again = [(plant.step([0.2], [0.05], 1e-3), plant.y)[1] for _ in range(5)]
    assert np.array_equal(np.array(first), np.array(again))


@pytest.mark.parametrize("u, q, dt", [([np.nan], [0.0], 1e-3), ([1.0, 2.0], [0.0], 1e-3),
                                      ([1.0], [np.inf], 1e-3), ([1.0], [0.0], 0.0),
                                      ([1.0], [0.0], -1e-3)])
def test_invalid_inputs_raise_and_leave_state(plant, u, q, dt):
    saved = plant.get_state()
    with pytest.raises(ValueError):
        plant.step(u, q, dt)
    assert np.array_equal(plant.get_state(), saved)


@pytest.mark.parametrize("numpy_errors", ["ignore", "warn", "raise"])
@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy's own, under "warn"
def test_overflow_raises_value_error_and_leaves_state(numpy_errors):
    """Whatever numpy's floating-point error handling of the caller, an overflowing step
    raises ValueError and keeps the last finite state."""
    plant = LTIPlant(np.eye(2), np.ones((2, 1)), np.eye(2), x0=[1e307, 1e307])
    saved = plant.get_state()
    with np.errstate(all=numpy_errors), pytest.raises(ValueError, match="plant"):
        plant.step([0.0], None, 10.0)
    assert np.array_equal(plant.get_state(), saved)
