"""A third-party plant FMU, written here independently of fhobs, and the harness driving it.

The plant is the paper's pendulum, but with its own variable names (``torque``, ``disturbance``,
``angles[1..2]``, ``state[1..4]``, ``initial_state[1..4]``) and its own discretisation code
(exact ZOH by the matrix exponential of the augmented matrix, computed with scipy at the first
step). The system description maps those names; the tests check the master against a plain
numpy loop of the same closed loop.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from harness.master import run_system
from harness.system import build_blocks, load_system, resolve_system

A = np.array([[0, 0, 1, 0], [0, 0, 0, 1],
              [0, 152.0057, -12.2542, -0.5005], [0, 264.3080, -12.1117, -0.8702]])
B = np.array([[0], [0], [50.6372], [50.0484]])
C = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
K = np.array([[2.0, -35.0, 1.5, -3.0]])

PLANT_SOURCE = '''
import numpy as np
import scipy.linalg
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

A = np.array({A})
B = np.array({B})
C = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])


class VendorPendulum(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.x = np.zeros(4)
        self.x_init = [0.0] * 4
        self.torque = 0.0
        self.disturbance = 0.0
        self.cache = {{}}
        for i in range(4):
            self.register_variable(Real(
                f"initial_state[{{i + 1}}]", causality=Fmi2Causality.parameter,
                variability=Fmi2Variability.fixed, getter=lambda i=i: self.x_init[i],
                setter=lambda v, i=i: self.x_init.__setitem__(i, v)))
        self.register_variable(Real("torque", causality=Fmi2Causality.input))
        self.register_variable(Real("disturbance", causality=Fmi2Causality.input))
        for i in range(2):
            self.register_variable(Real(f"angles[{{i + 1}}]", causality=Fmi2Causality.output,
                                        getter=lambda i=i: float(C[i] @ self.x)))
        for i in range(4):
            self.register_variable(Real(f"state[{{i + 1}}]", causality=Fmi2Causality.output,
                                        getter=lambda i=i: float(self.x[i])))

    def exit_initialization_mode(self):
        self.x = np.array(self.x_init, dtype=float)

    def do_step(self, current_time, step_size):
        if step_size not in self.cache:
            aug = np.zeros((6, 6))
            aug[:4, :4] = A
            aug[:4, 4:5] = B
            aug[:4, 5:6] = B
            self.cache[step_size] = scipy.linalg.expm(aug * step_size)[:4]
        phi = self.cache[step_size]
        self.x = phi @ np.concatenate([self.x, [self.torque, self.disturbance]])
        return True
'''


def build_vendor_plant(directory: Path) -> Path:
    """Build the third-party plant FMU into ``directory`` and return its path."""
    from pythonfmu import FmuBuilder

    script = directory / "vendor_pendulum_plant.py"
    script.write_text(textwrap.dedent(PLANT_SOURCE.format(A=A.tolist(), B=B.tolist())))
    return Path(FmuBuilder.build_FMU(script, dest=directory, needsExecutionTool="false"))


SYSTEM = '''
name = "vendor_state_feedback"
[run]
step = 0.001
stop_time = 0.5
record = ["plant.angles"]
[fmus.plant]
path = "{plant}"
start = {{ initial_state = [0.2, -0.1, 0.3, 0.0] }}
[fmus.wave]
block = "sine"
outputs = 1
start = {{ amplitude = [0.1], omega = [5.0], phase = [0.3] }}
[[connections]]
from = "plant.state"
to = "plant.torque"
gain = [[2, -35, 1.5, -3]]
[[connections]]
from = "wave.y[1]"
to = "plant.disturbance"
'''


def zoh(h: float) -> np.ndarray:
    """Exact ZOH transition [Ad, Bd, Ed] of the pendulum with E = B."""
    aug = np.zeros((6, 6))
    aug[:4, :4], aug[:4, 4:5], aug[:4, 5:6] = A, B, B
    return scipy.linalg.expm(aug * h)[:4]


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
    phi = zoh(h)
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
