"""The utility blocks' pythonfmu slaves (FMI 2.0 co-simulation): sources, a gain and a sum.

- :class:`SineSource`: ``y[i] = amplitude[i] * sin(omega[i] * t + phase[i]) + offset[i]``.
  After ``doStep(t, h)`` the outputs are the signal at ``t + h``; after ``setupExperiment(t0)``
  they are the signal at ``t0``. So under the Jacobi convention the value read at ``t_k`` is
  exactly the signal at ``t_k``.
- :class:`ConstantSource`: ``y[i] = value[i]`` (tunable parameters).
- :class:`MatrixGain`: ``y = K u`` (direct feedthrough, no state), inputs ``u[1..m]``, outputs
  ``y[1..p]``, parameters ``K[i,j]`` (row-major). The outputs are evaluated from the current
  inputs whenever they are read. A co-simulation master that only exchanges values at
  communication points therefore sees this block as one communication step of delay on the
  path through it; the harness applies connection gains itself (no delay) and uses this block
  only where an external engine needs the gain as an FMU (SSP export).
- :class:`Sum`: ``y = u[1,:] + ... + u[m,:]``, the sum of ``m`` input vectors of ``n`` entries
  (inputs ``u[k,i]``, term k, entry i), evaluated whenever read, as the gain.

The model descriptions declare the direct feedthrough of the gain and the sum: each output
depends on the inputs it is computed from (``<Unknown dependencies>``; K is tunable, so no
entry of it is assumed zero), which lets a master find algebraic loops through the block.
The outputs are ``initial="calculated"`` (no start value) and listed as ``<InitialUnknowns>``
depending on the inputs and parameters they are computed from (:meth:`Block.knowns_of`):
every block computes its outputs in initialisation mode too, so a master that propagates the
values at the start time through the blocks in the order of these dependencies (OMSimulator)
gets each block's output from its inputs of the start time, not a start value of 0.

The dimensions are constructor arguments; :mod:`harness.blocks.build` bakes them into a
uniquely named copy of this module (pythonfmu shares ``sys.modules`` between FMUs), which is
why the module imports nothing from the harness.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real

SINE_PARAMETERS = ("amplitude", "omega", "phase", "offset")


def declare_structure(root: Element, inputs_of: Callable[[int, list[str]], list[str]],
                      knowns_of: Callable[[int, list[str]], list[str]]) -> Element:
    """Complete the ``<ModelStructure>`` of a block's modelDescription ``root`` (pythonfmu's,
    which lists the outputs only): each output's dependencies on the inputs
    (``inputs_of(i, inputs)``, output ``i`` 0-based, ``inputs`` the names of the block's
    inputs) and its ``<InitialUnknowns>`` entry with its dependencies on the inputs and
    parameters (``knowns_of(i, inputs)``), as FMI 2.0 asks of outputs ``initial="calculated"``.

    Parameters
    ----------
    root
        The modelDescription, changed in place.
    inputs_of, knowns_of
        Output ``i``'s inputs, and its inputs and parameters, by name.

    Returns
    -------
    Element
        ``root``.

    Examples
    --------
    >>> from xml.etree.ElementTree import fromstring
    >>> root = fromstring(
    ...     '<m><ModelVariables><ScalarVariable name="k" causality="parameter"/>'
    ...     '<ScalarVariable name="u" causality="input"/><ScalarVariable name="y" '
    ...     'causality="output"/></ModelVariables><ModelStructure><Outputs>'
    ...     '<Unknown index="3"/></Outputs></ModelStructure></m>')
    >>> root = declare_structure(root, lambda i, u: u, lambda i, u: ["k", *u])
    >>> [(u.get("index"), u.get("dependencies")) for u in root.iterfind("ModelStructure/*/")]
    [('3', '2'), ('3', '1 2')]
    """
    variables = list(root.find("ModelVariables"))
    index = {v.get("name"): position for position, v in enumerate(variables, start=1)}
    inputs = [v.get("name") for v in variables if v.get("causality") == "input"]
    structure = root.find("ModelStructure")
    initial = SubElement(structure, "InitialUnknowns")
    for i, unknown in enumerate(structure.iterfind("Outputs/Unknown")):
        for element, names in ((unknown, inputs_of(i, inputs)),
                               (SubElement(initial, "Unknown", index=unknown.get("index")),
                                knowns_of(i, inputs))):
            element.set("dependencies", " ".join(str(k) for k in sorted(index[n] for n in names)))
    return root


def added(terms: Iterable[float]) -> float:
    """The terms added one by one from 0.0 in their order, as the native blocks add them (not
    ``sum``, which compensates the rounding from Python 3.12 on).

    Examples
    --------
    >>> added([1e16, 1.0, -1e16])
    0.0
    """
    total = 0.0
    for term in terms:
        total += term
    return total


class Block(Fmi2Slave):
    """What the blocks share: Real variables backed by list entries, outputs ``y[i]``, and in
    the model description the outputs' dependencies on the inputs (:meth:`inputs_of`) and, as
    initial unknowns, on the inputs and parameters (:meth:`knowns_of`)."""

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

    def _register_parameters(self, name: str, store: list[float], labels: list[str]) -> None:
        """Register ``store[j]`` as the tunable parameter ``name[labels[j]]``."""
        for j, label in enumerate(labels):
            self._register_element(f"{name}[{label}]", store, j, Fmi2Causality.parameter,
                                   Fmi2Variability.tunable)

    def _register_inputs(self, store: list[float], labels: list[str]) -> None:
        """Register ``store[j]`` as the input ``u[labels[j]]``."""
        for j, label in enumerate(labels):
            self._register_element(f"u[{label}]", store, j, Fmi2Causality.input,
                                   Fmi2Variability.continuous)

    def _register_outputs(self, n_outputs: int) -> None:
        """Register the outputs ``y[1..n_outputs]``, read from :meth:`value`."""
        for i in range(n_outputs):
            self.register_variable(
                Real(
                    f"y[{i + 1}]",
                    causality=Fmi2Causality.output,
                    variability=Fmi2Variability.continuous,
                    initial=Fmi2Initial.calculated,
                    getter=lambda i=i: self.value(i),
                )
            )

    def value(self, i: int) -> float:
        """Output ``i`` (0-based)."""
        raise NotImplementedError

    def inputs_of(self, i: int, inputs: list[str]) -> list[str]:
        """The names among ``inputs`` that output ``i`` (0-based) is computed from: all."""
        return inputs

    def parameters_of(self, i: int) -> list[str]:
        """The names of the parameters that output ``i`` (0-based) is computed from."""
        raise NotImplementedError

    def knowns_of(self, i: int, inputs: list[str]) -> list[str]:
        """The inputs (among ``inputs``) and parameters that output ``i`` (0-based) is
        computed from at initialisation."""
        return [*self.inputs_of(i, inputs), *self.parameters_of(i)]

    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's model description with the outputs' dependencies and initial unknowns
        declared (:func:`declare_structure`; pythonfmu 0.7.0 writes neither)."""
        root = super().to_xml(model_options if model_options is not None else {})
        return declare_structure(root, self.inputs_of, self.knowns_of)

    def do_step(self, current_time: float, step_size: float) -> bool:
        return True


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
            self._register_parameters(name, self.params[name],
                                      [str(i + 1) for i in range(n_outputs)])
        self._register_outputs(n_outputs)

    def value(self, i: int) -> float:
        """Output ``i`` (0-based) at the block's current time."""
        p = self.params
        return (
            p["amplitude"][i] * math.sin(p["omega"][i] * self.time + p["phase"][i]) + p["offset"][i]
        )

    def parameters_of(self, i: int) -> list[str]:
        """``amplitude[i+1]``, ``omega[i+1]``, ``phase[i+1]``, ``offset[i+1]``."""
        return [f"{name}[{i + 1}]" for name in SINE_PARAMETERS]

    def setup_experiment(self, start_time: float, stop_time, tolerance) -> None:
        self.time = float(start_time)

    def do_step(self, current_time: float, step_size: float) -> bool:
        self.time = current_time + step_size
        return True


class ConstantSource(Block):
    """``y[i] = value[i]``, parameters ``value[i]`` (tunable)."""

    description = "Constant source: y[i] = value[i]"

    def __init__(self, n_outputs: int = 1, **kwargs) -> None:
        super().__init__(**kwargs)
        self.values = [0.0] * n_outputs
        self._register_parameters("value", self.values, [str(i + 1) for i in range(n_outputs)])
        self._register_outputs(n_outputs)

    def value(self, i: int) -> float:
        """Output ``i`` (0-based): its parameter."""
        return self.values[i]

    def parameters_of(self, i: int) -> list[str]:
        """``value[i+1]``."""
        return [f"value[{i + 1}]"]


class MatrixGain(Block):
    """``y = K u`` with ``K`` of shape ``(n_outputs, n_inputs)``, parameters ``K[i,j]``."""

    description = "Static matrix gain y = K u"

    def __init__(self, n_outputs: int = 1, n_inputs: int = 1, **kwargs) -> None:
        super().__init__(**kwargs)
        self.gain = [[0.0] * n_inputs for _ in range(n_outputs)]
        self.inputs = [0.0] * n_inputs
        for i in range(n_outputs):
            self._register_parameters("K", self.gain[i],
                                      [f"{i + 1},{j + 1}" for j in range(n_inputs)])
        self._register_inputs(self.inputs, [str(j + 1) for j in range(n_inputs)])
        self._register_outputs(n_outputs)

    def value(self, i: int) -> float:
        """Output ``i`` (0-based): row i of K times the current inputs."""
        return added(k * u for k, u in zip(self.gain[i], self.inputs, strict=True))

    def parameters_of(self, i: int) -> list[str]:
        """Row ``i + 1`` of K."""
        return [f"K[{i + 1},{j + 1}]" for j in range(len(self.inputs))]


class Sum(Block):
    """``y = u[1,:] + ... + u[n_terms,:]``, inputs ``u[k,i]`` (term k, entry i)."""

    description = "Sum of input vectors y = u[1,:] + ... + u[m,:]"

    def __init__(self, n_outputs: int = 1, n_terms: int = 2, **kwargs) -> None:
        super().__init__(**kwargs)
        self.n_outputs = n_outputs
        self.inputs = [0.0] * (n_terms * n_outputs)
        self._register_inputs(self.inputs, [f"{k + 1},{i + 1}" for k in range(n_terms)
                                            for i in range(n_outputs)])
        self._register_outputs(n_outputs)

    def value(self, i: int) -> float:
        """Output ``i`` (0-based): entry i of every term, added in the terms' order."""
        return added(self.inputs[i::self.n_outputs])

    def inputs_of(self, i: int, inputs: list[str]) -> list[str]:
        """Entry ``i`` of every term."""
        return inputs[i::self.n_outputs]

    def parameters_of(self, i: int) -> list[str]:
        """None: the sum has no parameters."""
        return []
