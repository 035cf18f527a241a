"""The utility blocks' pythonfmu slaves (FMI 2.0 co-simulation): a signal source and a gain.

- :class:`SineSource`: ``y[i] = amplitude[i] * sin(omega[i] * t + phase[i]) + offset[i]``.
  After ``doStep(t, h)`` the outputs are the signal at ``t + h``; after ``setupExperiment(t0)``
  they are the signal at ``t0``. So under the Jacobi convention the value read at ``t_k`` is
  exactly the signal at ``t_k``.
- :class:`MatrixGain`: ``y = K u`` (direct feedthrough, no state), inputs ``u[1..m]``, outputs
  ``y[1..p]``, parameters ``K[i,j]`` (row-major). The outputs are evaluated from the current
  inputs whenever they are read. A co-simulation master that only exchanges values at
  communication points therefore sees this block as one communication step of delay on the
  path through it; the harness applies connection gains itself (no delay) and uses this block
  only where an external engine needs the gain as an FMU (SSP export). The model description
  declares the direct feedthrough: each output depends on every input (``<Unknown
  dependencies>``; K is tunable, so no entry is assumed zero), which lets a master find
  algebraic loops through the block.

The dimensions are constructor arguments; :mod:`harness.blocks.build` bakes them into a
uniquely named copy of this module (pythonfmu shares ``sys.modules`` between FMUs), which is
why the module imports nothing from the harness.
"""

from __future__ import annotations

import math
from xml.etree.ElementTree import Element

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real

SINE_PARAMETERS = ("amplitude", "omega", "phase", "offset")


class Block(Fmi2Slave):
    """What the blocks share: Real variables backed by list entries, outputs ``y[i]``."""

    author = "fhobs harness"

    def _register_element(
        self, name: str, store: list[float], index: int, causality, variability
    ) -> None:
        """Register ``store[index]`` as the Real variable ``name``."""

        def setter(v: float) -> None:
            store[index] = float(v)

        self.register_variable(
            Real(
                name,
                causality=causality,
                variability=variability,
                getter=lambda: store[index],
                setter=setter,
            )
        )

    def _register_outputs(self, n_outputs: int) -> None:
        """Register the outputs ``y[1..n_outputs]``, read from :meth:`value`."""
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

    def value(self, i: int) -> float:
        """Output ``i`` (0-based)."""
        raise NotImplementedError


class SineSource(Block):
    """Vector of independent sinusoids; parameters ``amplitude, omega, phase, offset [i]``."""

    description = (
        "Sinusoidal signal source: y[i] = amplitude[i] sin(omega[i] t + phase[i]) + offset[i]"
    )

    def __init__(self, n_outputs: int = 1, **kwargs) -> None:
        super().__init__(**kwargs)
        self.n_outputs = n_outputs
        self.time = 0.0
        self.params = {name: [0.0] * n_outputs for name in SINE_PARAMETERS}
        for name in SINE_PARAMETERS:
            for i in range(n_outputs):
                self._register_element(f"{name}[{i + 1}]", self.params[name], i,
                                       Fmi2Causality.parameter, Fmi2Variability.tunable)
        self._register_outputs(n_outputs)

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


class MatrixGain(Block):
    """``y = K u`` with ``K`` of shape ``(n_outputs, n_inputs)``, parameters ``K[i,j]``."""

    description = "Static matrix gain y = K u"

    def __init__(self, n_outputs: int = 1, n_inputs: int = 1, **kwargs) -> None:
        super().__init__(**kwargs)
        self.gain = [[0.0] * n_inputs for _ in range(n_outputs)]
        self.inputs = [0.0] * n_inputs
        for i in range(n_outputs):
            for j in range(n_inputs):
                self._register_element(f"K[{i + 1},{j + 1}]", self.gain[i], j,
                                       Fmi2Causality.parameter, Fmi2Variability.tunable)
        for j in range(n_inputs):
            self._register_element(f"u[{j + 1}]", self.inputs, j,
                                   Fmi2Causality.input, Fmi2Variability.continuous)
        self._register_outputs(n_outputs)

    def value(self, i: int) -> float:
        """Output ``i`` (0-based): row i of K times the current inputs."""
        return sum(k * u for k, u in zip(self.gain[i], self.inputs, strict=True))

    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's model description with each output's dependence on every input declared
        (pythonfmu 0.7.0 writes no dependencies)."""
        root = super().to_xml(model_options if model_options is not None else {})
        variables = list(root.find("ModelVariables"))
        inputs = " ".join(str(index) for index, v in enumerate(variables, start=1)
                          if v.get("causality") == "input")
        for unknown in root.iterfind("ModelStructure/Outputs/Unknown"):
            unknown.set("dependencies", inputs)
        return root

    def do_step(self, current_time: float, step_size: float) -> bool:
        return True
