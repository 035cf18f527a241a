"""A third-party plant FMU, written here independently of fhobs, and the harness driving it.

The plant is the paper's pendulum, but with its own variable names (``torque``, ``disturbance``,
``angles[1..2]``, ``state[1..4]``, ``initial_state[1..4]``) and its own discretisation code
(exact ZOH by the matrix exponential of the augmented matrix, computed with scipy at the first
step). The system description maps those names; the tests check the master against a plain
numpy loop of the same closed loop.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from reference_math import zoh
from vendor_plant import SYSTEM, A, B, K, build_vendor_plant

from harness.master import run_system
from harness.system import build_blocks, load_system, resolve_system


@pytest.fixture(scope="module")
def block_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("blocks")


@pytest.fixture(scope="module")
def vendor_system(tmp_path_factory, block_cache):
    d = tmp_path_factory.mktemp("vendor")
    plant = build_vendor_plant(d)
    path = d / "system.toml"
    path.write_text(SYSTEM.format(plant=plant))
    return build_blocks(load_system(path), block_cache)


def test_master_matches_numpy_jacobi_loop(vendor_system):
    """x_{k+1} = Phi [x_k; K x_k; q(t_k)], q = 0.1 sin(5 t + 0.3): the Jacobi convention."""
    result = run_system(resolve_system(vendor_system), progress=False)
    h, steps = 0.001, 500
    phi = np.hstack(zoh(A, np.hstack([B, B]), h))  # [Ad, Bd, Ed] with E = B
    x = np.array([0.2, -0.1, 0.3, 0.0])
    expected = [x]
    for k in range(steps):
        q = 0.1 * np.sin(5.0 * (k * h) + 0.3)
        x = phi @ np.concatenate([x, K @ x, [q]])
        expected.append(x)
    expected = np.array(expected)
    assert result.steps == steps
    np.testing.assert_array_equal(result.time, h * np.arange(steps + 1))
    assert np.max(np.abs(result.vector("plant.state") - expected)) < 1e-12
    np.testing.assert_allclose(result.vector("plant.angles"), expected[:, :2], atol=1e-12)
    assert np.max(np.abs(expected[-1])) > 1e-3  # the check is not trivially zero


def test_start_value_override_and_stop_time(vendor_system):
    system = vendor_system.with_start({"plant.initial_state": [0.0, 0.0, 0.0, 0.0],
                                       "wave.amplitude[1]": 0.0})
    result = run_system(resolve_system(system), stop_time=0.01, progress=False)
    assert result.steps == 10
    assert np.all(result.vector("plant.state") == 0.0)
