"""A third-party plant FMU written here independently of fhobs (its own names, its own
discretisation), used by the harness and engine tests: the paper's pendulum as a vendor would
ship it (``torque``, ``disturbance``, ``angles[1..2]``, ``state[1..4]``, ``initial_state``)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

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
