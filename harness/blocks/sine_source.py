"""Signal source block: ``y[i] = amplitude[i] * sin(omega[i] * t + phase[i]) + offset[i]``.

A pythonfmu slave (FMI 2.0 co-simulation). After ``doStep(t, h)`` the outputs are the signal at
``t + h``; after ``setupExperiment(t0)`` they are the signal at ``t0``. So under the Jacobi
convention the value read at ``t_k`` is exactly the signal at ``t_k``.

The number of outputs is a constructor argument; :mod:`harness.blocks.build` bakes it into a
uniquely named copy of this module (see PythonFMU#228 on shared ``sys.modules``).
"""

from __future__ import annotations

import math

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real

PARAMETERS = ("amplitude", "omega", "phase", "offset")


class SineSource(Fmi2Slave):
    """Vector of independent sinusoids; parameters ``amplitude, omega, phase, offset [i]``."""

    author = "fhobs harness"
    description = (
        "Sinusoidal signal source: y[i] = amplitude[i] sin(omega[i] t + phase[i]) + offset[i]"
    )

    def __init__(self, n_outputs: int = 1, **kwargs) -> None:
        super().__init__(**kwargs)
        self.n_outputs = n_outputs
        self.time = 0.0
        self.params = {name: [0.0] * n_outputs for name in PARAMETERS}
        for name in PARAMETERS:
            for i in range(n_outputs):
                self._register_parameter(name, i)
        for i in range(n_outputs):
            self.register_variable(
                Real(
                    f"y[{i + 1}]",
                    causality=Fmi2Causality.output,
                    variability=Fmi2Variability.continuous,
                    initial=Fmi2Initial.exact,
                    getter=lambda i=i: self.value(i),
                )
            )

    def _register_parameter(self, name: str, i: int) -> None:
        values = self.params[name]

        def setter(v: float) -> None:
            values[i] = float(v)

        self.register_variable(
            Real(
                f"{name}[{i + 1}]",
                causality=Fmi2Causality.parameter,
                variability=Fmi2Variability.tunable,
                getter=lambda: values[i],
                setter=setter,
            )
        )

    def value(self, i: int) -> float:
        """Output ``i`` (0-based) at the block's current time."""
        p = self.params
        return (
            p["amplitude"][i] * math.sin(p["omega"][i] * self.time + p["phase"][i]) + p["offset"][i]
        )

    def setup_experiment(self, start_time: float, stop_time, tolerance) -> None:
        self.time = float(start_time)

    def do_step(self, current_time: float, step_size: float) -> bool:
        self.time = current_time + step_size
        return True
