"""Static matrix gain block: ``y = K u`` (direct feedthrough, no state).

A pythonfmu slave (FMI 2.0 co-simulation) with inputs ``u[1..m]``, outputs ``y[1..p]`` and
parameters ``K[i,j]`` (row-major). The outputs are evaluated from the current inputs whenever
they are read. A co-simulation master that only exchanges values at communication points
therefore sees this block as one communication step of delay on the path through it; the
harness applies connection gains itself (no delay) and uses this block only where an external
engine needs the gain as an FMU (SSP export). The model description declares the direct
feedthrough: each output depends on every input (``<Unknown dependencies>``; K is tunable, so
no entry is assumed zero), which lets a master find algebraic loops through the block.
"""

from __future__ import annotations

from xml.etree.ElementTree import Element

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class MatrixGain(Fmi2Slave):
    """``y = K u`` with ``K`` of shape ``(n_outputs, n_inputs)``, parameters ``K[i,j]``."""

    author = "fhobs harness"
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

    def value(self, i: int) -> float:
        """Output ``i`` (0-based): row ``i`` of ``K`` times the current inputs."""
        return sum(k * u for k, u in zip(self.gain[i], self.inputs, strict=True))

    def do_step(self, current_time: float, step_size: float) -> bool:
        return True
