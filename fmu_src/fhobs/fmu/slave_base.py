"""FMI plumbing shared by the observer, prescribed-time, Luenberger, Kalman and plant slaves:
the lifecycle.

A slave declares array-valued parameters, inputs and outputs (:mod:`.variables`); this base
class re-checks the parameters at ``exitInitializationMode``, validates the inputs of every
``doStep``, keeps the model's state at its last valid value when a call is rejected, and
follows the FMI call sequence (:mod:`.modes`). The other concerns are mixins in their own
modules: the access rules of get/set calls (:mod:`.access`), the status wrapper's callbacks
(:mod:`.wrapper`) and FMU states (:mod:`.fmu_state`).

Speed. A valid ``doStep`` costs little more than the model's own step: one comparison accepts
the inputs (their ``math.hypot`` against ``input_bound``), the model steps on views of the input
variables (no copies) through its ``advance``, which does not check them again, the state before
the step is kept as a shallow copy of the model's attributes, and the outputs are read as one
list of floats (in the order the model gives them, which is the order of the output arrays in
the buffer: no reordering), accepted by one sum and written into the buffer in one assignment.
Element labels are only formatted, and the exact checks only made, to describe a rejected call.

Rejected calls. Python code inside a pythonfmu 0.7.0 FMU cannot itself return ``fmi2Error``:
an exception is answered with ``fmi2Fatal`` and ``do_step`` returning False with
``fmi2Discard``. The slave therefore records the status of its last call in the Integer
variable ``status`` (value reference 0, ``3`` = error) and logs the reason; the small C
wrapper that :mod:`fhobs.build` places in front of pythonfmu's binary (linux64) reads it
after ``fmi2DoStep``, ``fmi2Enter/ExitInitializationMode``, ``fmi2Terminate`` and
``fmi2SetFMUstate`` and returns ``fmi2Error``. Without that wrapper (win64), a rejected step
returns ``fmi2Discard`` and every other refusal ``fmi2Fatal``.

Caller mistakes. pythonfmu 0.7.0 answers an exception with ``fmi2Fatal`` and releases the
slave's Python objects, after which further calls can crash the host; so with the wrapper no
caller mistake reaches that path: the wrapper asks the slave (:meth:`FhobsSlave._access_problem`,
:meth:`FhobsSlave._state_bytes_problem`) before handing a get/set or a state's bytes to
pythonfmu, and answers a refusal with ``fmi2Error``. The rules:

- call sequence: fmi2EnterInitializationMode once after instantiation (or fmi2Reset),
  fmi2ExitInitializationMode once after it, fmi2DoStep only between a successful
  initialisation and fmi2Terminate;
- parameters are fixed: they can be set until fmi2ExitInitializationMode, which checks them,
  and never afterwards (fmi2Reset returns to the start values); outputs and ``status`` are
  never set; unknown value references and references of another type are refused;
- an FMU state (in memory or serialized) is checked completely before any of it is used:
  format version, the FMU it was made by, every variable's shape, finiteness, and for a state
  of an initialised instance its parameters pass the initialisation checks again.

Only numpy, the standard library, pythonfmu and :mod:`fhobs.core` are imported here.
"""

from __future__ import annotations

import json
import math
import sys
from abc import abstractmethod
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol
from xml.etree.ElementTree import Element

import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer
from pythonfmu.enums import Fmi2Status

from ..core.gains import ObserverDesign
from ..core.runtime import SCHEMES
from .access import AccessRules
from .call_rules import (
    TIME_TOLERANCE,
    ZOH_CONDITION_LIMIT,
    ZOH_MESSAGE,
    call_problem,
    coarse_step_problem,
    number_text,
    time_problem,
)
from .fmu_state import FmuStates
from .kinds import Kind, edited_record
from .modes import (
    INITIALISATION,
    INSTANTIATED,
    MODES,
    STATUS_ERROR,
    STATUS_OK,
    STATUS_WARNING,
    STEP_MODE,
    TERMINATED,
)
from .variables import CAUSALITIES, Variables, element_names
from .wrapper import WrapperCalls

DESIGN_FILE = "design.json"
CONFIG_FILE = "fmu_config.json"

_hypot = math.hypot
SIZE_CHECKS = 64
"""The checks of this many step sizes are remembered per model (:meth:`FhobsSlave._size_problem`);
then they are forgotten at once."""

class SlaveModel(Protocol):
    """What the base class needs from a runtime object (observer or plant).

    Its ``advance`` (its ``step`` without the argument checks, which the slave has made) must
    replace the arrays that hold the state, never write into them, and leave them as they were
    when it raises (as :mod:`fhobs.core.runtime` and :mod:`fhobs.core.plant` do):
    :meth:`FhobsSlave.do_step` keeps the state before a step as the references in the model's
    ``__dict__``. Its array arguments are views of the slave's input variables: ``advance`` may
    read them during the call only, never write into them or keep references to them (the
    runtime's ``advance(y, u, dt)`` and the plant's ``advance(u, q, dt)`` do not).
    """

    def advance(self, *arguments: np.ndarray | float | None) -> None:
        """Advance by the last argument (the step size) with the array arguments held; the
        arguments are finite and of the right sizes, the step size positive."""

    def get_state(self) -> np.ndarray:
        """Return the complete internal state as a flat float array (a copy)."""

    def set_state(self, state: np.ndarray) -> None:
        """Restore a state returned by :meth:`get_state`."""


def zoh_problem(A: np.ndarray, step: float, what: str) -> str:
    """Why the exact ZOH of ``A`` over ``step`` cannot be trusted ('' when it can).

    Examples
    --------
    >>> zoh_problem(np.array([[0.0, 1.0], [-1.0, 0.0]]), 1e-3, "the plant")
    ''
    >>> zoh_problem(np.array([[-1e300]]), 1e-3, "the plant")[:40]
    'the plant: step * ||A||_1 = 1e+297 excee'
    """
    scale = step * float(np.linalg.norm(A, 1))
    if scale <= ZOH_CONDITION_LIMIT:
        return ""
    return ZOH_MESSAGE % (what, scale, number_text(step))


class FhobsSlave(Variables, AccessRules, WrapperCalls, FmuStates, Fmi2Slave):
    """Common base of the fhobs slaves (abstract: subclasses define the model).

    Subclasses name their :attr:`kind` (whose declaration gives the variables, in
    value-reference order, the output layout, where each output comes from and the runtime
    model, :meth:`_make_model`) and implement :meth:`_check_parameters`. The record the kind
    runs (of the design in ``design.json``) and the build options are read from the
    instance's own ``resources`` folder, never from module globals, so that two FMUs sharing
    Python modules in one process stay independent.
    """

    author = "fhobs"
    license = "MIT"
    kind: Kind
    """The slave's FMU kind (:mod:`fhobs.fmu.kinds`): its variables and output layout."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "kind" in cls.__dict__:
            cls.description = cls.kind.description  # pythonfmu reads the class attribute

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        resources = Path(self.resources)
        self.record: Any = self.kind.runs(ObserverDesign.load_json(resources / DESIGN_FILE))
        self.config: dict[str, Any] = json.loads((resources / CONFIG_FILE).read_text())
        self._status_via_wrapper = bool(self.config["status_wrapper"]) and sys.platform == "linux"
        self._arrays: dict[str, np.ndarray] = {}
        self._first_vr: dict[str, int] = {}
        self._integers: dict[str, int] = {}
        self._causal: dict[str, list[str]] = {causality: [] for causality in CAUSALITIES}
        self._design_fields: dict[str, str] = {}  # design parameter -> its field of the record
        self.status = STATUS_OK
        self._declare()
        self._pack_arrays()
        self._output_reads = output_reads(self.kind, self._arrays)
        self._mode_code = np.zeros(1, dtype=np.intc)  # the mode's index, read by the wrapper
        self._set_mode(INSTANTIATED)
        self._start_time = self._time = 0.0
        self._time_slack = 0.0  # the next doStep's time passes the fast path within this
        self._clock = np.zeros(1)  # the last successful time, read by the wrapper
        self.via_wrapper = self._register_with_wrapper()
        self.model: SlaveModel = self._make_model()
        self._size_checks: tuple[SlaveModel | None, dict[float, str]] = (None, {})
        # the start model and the parameters it was built from, until initialisation uses it
        self._start_model: tuple[SlaveModel, tuple] | None = (self.model, self._parameters())
        self._publish()

    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's model description with the outputs' dependencies declared: every output
        is the model's state (or a function of it) after the last step, so none depends
        directly on an input (``dependencies=""``: no algebraic loop through this FMU)."""
        root = super().to_xml(model_options if model_options is not None else {})
        for unknown in root.iterfind("ModelStructure/Outputs/Unknown"):
            unknown.set("dependencies", "")
        return root

    def _set_mode(self, mode: str) -> None:
        """Enter FMI state ``mode``: Real parameters are writable before step mode only."""
        self._mode = mode
        self._mode_code[0] = MODES.index(mode)
        self._writable[self._parameter_vrs] = mode in (INSTANTIATED, INITIALISATION)
        self._write_cache.clear()

    def edited_record(self) -> Any:
        """The record the kind runs with every design parameter replaced by its current
        value."""
        values = {}
        for name, field in self._design_fields.items():
            value = self.array(name)
            values[field] = float(value) if value.ndim == 0 else value
        return edited_record(self.record, values)

    def _declare(self) -> None:
        """Register the variables of :attr:`kind` present for its record, in its order (their
        value references), with their start values from the record and the build options."""
        causality = {"input": "input", "output": "output", "design": "parameter",
                     "setting": "parameter"}
        for variable, start in self.kind.starts(self.record, self.config):
            if variable.role == "local":
                self.register_variable(Integer(
                    variable.name, causality=Fmi2Causality.local,
                    variability=Fmi2Variability.discrete, initial=Fmi2Initial.exact,
                    description=variable.description))
            elif variable.integer:
                self.add_integer(variable.name, start, variable.description)
            else:
                self.add_array(variable.name, start, causality[variable.role],
                               variable.description)
                if variable.role == "design":
                    self._design_fields[variable.name] = variable.field

    # -- FMI lifecycle -------------------------------------------------------------------
    def _parameters(self) -> tuple:
        """The exact current values of every parameter (what :meth:`_make_model` reads)."""
        arrays = tuple(self._arrays[name].tobytes() for name in self._causal["parameter"])
        return arrays, tuple(self._integers.items())

    def _refuse(self, message: str) -> None:
        """Answer a call made out of sequence or with unusable parameters: log ``message``,
        record the error for the wrapper, which returns fmi2Error; without the wrapper raise
        ValueError (pythonfmu: fmi2Fatal)."""
        self._fail(message)
        if not self._status_via_wrapper:
            raise ValueError(message)

    def setup_experiment(self, start_time: float, stop_time: float | None = None,
                         tolerance: float | None = None) -> None:
        """Record the start time: the first doStep's currentCommunicationPoint."""
        self.status = STATUS_OK
        problem = call_problem("fmi2SetupExperiment", self._mode)
        if problem:
            self._refuse(problem)
            return
        if not math.isfinite(start_time):
            self._refuse(f"fmi2SetupExperiment: startTime {number_text(start_time)} is not finite")
            return
        self._start_time = self._clock[0] = float(start_time)

    def enter_initialization_mode(self) -> None:
        """Enter initialisation mode: once, right after instantiation or fmi2Reset."""
        self.status = STATUS_OK
        problem = call_problem("fmi2EnterInitializationMode", self._mode)
        if problem:
            self._refuse(problem)
            return
        self._set_mode(INITIALISATION)

    def exit_initialization_mode(self) -> None:
        """Re-check the (possibly edited) parameters and build the model from them.

        On success the instance is in step mode and its parameters are fixed; a rejection
        leaves it in initialisation mode (the parameters can be corrected and the call
        repeated). The model built by the constructor is used if it is still the slave's
        model (no FMU state was set since) and every parameter still has the value it was
        built from: it is then the model :meth:`_make_model` would build (whose construction
        can cost tens of milliseconds). It is used at most once.
        """
        self.status = STATUS_OK
        problem = call_problem("fmi2ExitInitializationMode", self._mode)
        if problem:
            self._refuse(problem)
            return
        start, self._start_model = self._start_model, None
        try:
            self._check_all_parameters()
            if start is None or start[0] is not self.model or start[1] != self._parameters():
                self.model = self._make_model()
            self._publish()
        except ValueError as err:
            self._refuse(f"initialisation rejected the parameters: {err}")
            return
        self._certified = self._parameters()
        self._accepted_step = math.nan
        self._time = self._clock[0] = self._start_time
        self._set_mode(STEP_MODE)

    def terminate(self) -> None:
        """End the run: no doStep afterwards (fmi2Reset to start again)."""
        self.status = STATUS_OK
        problem = call_problem("fmi2Terminate", self._mode)
        if problem:
            self._refuse(problem)
            return
        self._set_mode(TERMINATED)

    def do_step(self, current_time: float, step_size: float) -> bool:
        """Advance by ``step_size`` with the inputs held; reject invalid calls, state kept.

        The path of a valid step is kept short (it runs once per FMU and communication step):
        the step size is the one accepted last (its checks are made once per new size), the
        inputs are checked as one list; the model steps on views of the input variables
        (:class:`SlaveModel`: it neither keeps nor writes them); the state before the step is
        kept as a shallow copy of the model's attributes rather than through ``get_state``: a
        runtime step never writes into its state arrays, it replaces them (and leaves them as
        they were when it raises), so those references are the complete state before the step.
        They are put back if the new outputs are not finite; the output variables are only
        written once the outputs are accepted.
        """
        self.status = STATUS_OK
        warning = ""
        if self._mode != STEP_MODE:
            return self._fail(call_problem("fmi2DoStep", self._mode))
        # One comparison accepts a valid call: math.hypot of the inputs is within 1 ulp of
        # their Euclidean norm (Python >= 3.10), which bounds each |input|, so a hypot strictly
        # below the bound bounds them all; it is NaN or inf when an input is not finite, which
        # fails the comparison. Anything else (also |input| = bound) gets the exact checks.
        if not (step_size == self._accepted_step
                and abs(current_time - self._time) <= self._time_slack
                and _hypot(*self._inputs.tolist()) < self._bound.item()):
            problem = (time_problem(current_time, self._time, step_size)
                       or self._size_problem(step_size)
                       or ("" if _hypot(*self._inputs.tolist()) < self._bound.item()
                           else self._input_problem()))
            if problem:
                return self._fail(f"doStep at t = {number_text(current_time)} rejected: {problem}")
            self._accepted_step = step_size
            warning = self._coarse_step_warning(step_size)
        model = self.model
        attributes = model.__dict__
        saved = attributes.copy()
        try:
            model.advance(*self._step_arguments, step_size)
            outputs = self._model_outputs()
            total = sum(outputs)  # NaN or inf if an output is; inf also on overflow
            if total - total != 0.0:
                self._finite_outputs(outputs)  # raises, naming them (unless the sum overflowed)
        except ValueError as err:
            attributes.clear()
            attributes.update(saved)
            return self._fail(f"doStep at t = {number_text(current_time)} rejected: {err}")
        self._outputs[...] = outputs
        self._time = self._clock[0] = current_time + step_size
        self._time_slack = TIME_TOLERANCE * max(abs(self._time), step_size)
        if warning:
            self._warned_coarse_step = True
            self.status = STATUS_WARNING
            self.log(warning, Fmi2Status.warning)
        return True

    _warned_coarse_step = False
    """Whether the instance has warned of a step longer than its max_communication_step."""

    def _coarse_step_warning(self, step_size: float) -> str:
        """The warning of a step longer than the observer's ``max_communication_step``
        (:func:`~fhobs.fmu.call_rules.coarse_step_problem`), given by the step (then fmi2Warning)
        if it succeeds; '' once the instance has warned, and for kinds without the parameter."""
        if self._warned_coarse_step or "max_communication_step" not in self._arrays:
            return ""
        return coarse_step_problem(step_size, self._arrays["max_communication_step"].item())

    def _check_all_parameters(self) -> None:
        """Raise ValueError naming the first problem of the current parameters: a non-finite
        element, ``input_bound <= 0``, or what the slave's own checks reject."""
        self._check_finite_parameters()
        bound = float(self._bound)
        if not bound > 0.0:
            raise ValueError(f"parameter input_bound = {number_text(bound)} must be > 0")
        self._check_parameters()

    def _check_finite_parameters(self) -> None:
        """Raise ValueError naming the first parameter element that is not finite."""
        for name in self._causal["parameter"]:
            for label, value in self._elements(name):
                if not math.isfinite(value):
                    raise ValueError(f"parameter {label} = {number_text(value)} is not finite")

    def _fail(self, message: str) -> bool:
        """Log ``message`` with status error, record the status, and return False."""
        self.status = STATUS_ERROR
        self.log(message, Fmi2Status.error)
        return False

    def _size_problem(self, step_size: float) -> str:
        """:meth:`_step_size_problem`, remembered per step size while the model is the same
        (its parameters are fixed then; ``SIZE_CHECKS`` sizes), so a host that changes the
        size at every step pays for the check of each size once."""
        model, problems = self._size_checks
        if model is not self.model:
            problems = {}
            self._size_checks = (self.model, problems)
        problem = problems.get(step_size)
        if problem is None:
            if len(problems) >= SIZE_CHECKS:
                problems.clear()
            problem = problems[step_size] = self._step_size_problem(step_size)
        return problem

    def _step_size_problem(self, step_size: float) -> str:
        """Describe what is wrong with the communication step size ('' when nothing is)."""
        if not (math.isfinite(step_size) and step_size > 0.0):
            return (f"communication step size {number_text(step_size)} is not a positive finite "
                    "number")
        return self._step_problem(step_size)

    def _input_problem(self) -> str:
        """Describe what is wrong with the inputs ('' when nothing is)."""
        bound = float(self._bound)
        for name in self._causal["input"]:
            for label, value in self._elements(name):
                if not math.isfinite(value):
                    return f"input {label} = {number_text(value)} is not finite"
                if abs(value) > bound:
                    return (f"input {label} = {number_text(value)} exceeds input_bound = "
                            f"{number_text(bound)}")
        return ""

    def _finite_outputs(self, outputs: Sequence[float] | None = None) -> Sequence[float]:
        """The model's outputs (flat, in the order of :meth:`_output_layout`; ``outputs`` if
        given, else computed); ValueError if one is not finite."""
        if outputs is None:
            outputs = self._model_outputs()
        if not all(map(math.isfinite, outputs)):
            labels = [label for name in self._output_names
                      for label in element_names(name, self._arrays[name].shape)]
            bad = {label: value for label, value in zip(labels, outputs, strict=True)
                   if not math.isfinite(value)}
            raise ValueError(f"the model produced non-finite outputs {bad}")
        return outputs

    def _publish(self) -> None:
        """Copy the model's outputs to the output variables."""
        self._outputs[...] = self._finite_outputs()

    # -- what a slave defines ------------------------------------------------------------
    @abstractmethod
    def _check_parameters(self) -> None:
        """Raise ValueError, naming the check and the amount, if the parameters are unusable."""

    def _make_model(self) -> SlaveModel:
        """Build the runtime object from the current parameter values: the kind's runtime
        model (:attr:`~fhobs.fmu.kinds.Kind.model`) of the edited record with the current
        setting parameters."""
        return self.kind.model(self.edited_record(), self.setting)

    def setting(self, name: str) -> Any:
        """The current value of the setting parameter ``name`` as the kind's runtime model
        takes it (:data:`~fhobs.fmu.kinds.Setting`): an array, an Integer, a choice's name
        (ValueError if its index is unknown)."""
        variable = self.kind.variable(name)
        if variable.choices:
            return self.choice(name, variable.choices)
        return self.integer(name) if variable.integer else self.array(name)

    def _step_problem(self, step_size: float) -> str:
        """Why the model cannot take a communication step of ``step_size`` (positive and
        finite) with the current parameters ('' if it can); checked once per new size."""
        return ""

    def _model_step_arguments(self) -> tuple[np.ndarray | None, ...]:
        """The arguments of the model's ``advance`` before the step size: the input variables
        of :attr:`kind` in declaration order (views of the buffer, read during the step; None
        for an input absent for this design, such as the plant's q without E)."""
        return tuple(self._arrays.get(variable.name) for variable in self.kind.variables
                     if variable.role == "input")

    def _output_layout(self) -> list[str]:
        """Names of the output arrays in the order in which :meth:`_model_outputs` gives their
        elements (and the buffer holds them): :attr:`Kind.outputs` of those present."""
        return [name for name in self.kind.outputs if name in self._arrays]

    def _model_outputs(self) -> list[float]:
        """The model's current outputs as floats, flat, in the order of :meth:`_output_layout`,
        from where the declaration says (:meth:`~fhobs.fmu.kinds.Kind.output_sources`): the
        model state's first elements (every kind has some: ``x_hat``, the plant's ``x``), the
        model's attributes (called after every step: one state read, one slice per run of
        state outputs)."""
        model = self.model
        values: list[float] = []
        state = model.get_state()
        for attribute, start, stop in self._output_reads:
            if attribute:
                values += np.ravel(getattr(model, attribute)).tolist()
            else:
                values += state[start:stop].tolist()
        return values


def output_reads(kind: Kind, arrays: Mapping[str, np.ndarray]) -> list[tuple[str, int, int]]:
    """The reads that give the outputs of ``kind`` present in ``arrays``:
    ``(attribute, start, stop)``, a slice of the model's state where ``attribute`` is '' (runs
    of state outputs merged into one slice), else the model's attribute.

    Examples
    --------
    >>> from fhobs.fmu.kinds import KINDS
    >>> arrays = {name: np.zeros(size) for name, size in
    ...           [("x_hat", 4), ("psi", 2), ("xi", 1), ("sigma", 1)]}
    >>> output_reads(KINDS["observer"], arrays)
    [('', 0, 7), ('sigma', 0, 1)]
    """
    sizes = {name: arrays[name].size for name in kind.outputs if name in arrays}
    reads: list[tuple[str, int, int]] = []
    for _, source, offset, size in kind.output_sources(sizes):
        if source == "state" and reads and not reads[-1][0] and reads[-1][2] == offset:
            reads[-1] = ("", reads[-1][1], offset + size)
        else:
            reads.append(("" if source == "state" else source, offset, offset + size))
    return reads


def positive_parameter(slave: FhobsSlave, name: str, what: str) -> float:
    """The scalar parameter ``name`` of ``slave``; ValueError naming ``what`` unless it is a
    positive finite number."""
    value = float(slave.array(name))
    if not (np.isfinite(value) and value > 0.0):
        raise ValueError(f"{what} = {value!r} is not a positive finite number")
    return value


class ObserverSlave(FhobsSlave):
    """The observer slave: the timing checks, the certificate of the edited record, the ZOH
    check of a step size; as it is, the slave of every estimator kind without checks of its
    own (:attr:`~fhobs.fmu.kinds.Kind.slave_module`), subclassed by the others.

    The timing parameters are by default those of :mod:`fhobs.core.runtime` (internal step
    ``h`` and ``scheme``); a sampled-data observer replaces their check
    (:meth:`_check_timing`).
    """

    _matrix_of_model: tuple[SlaveModel | None, np.ndarray | None] = (None, None)
    """The model and the state matrix :meth:`_model_matrix` formed for it."""

    def scheme_name(self) -> str:
        """Name of the selected integration scheme; ValueError if the index is unknown."""
        return self.choice("scheme", SCHEMES)

    def _check_timing(self) -> None:
        """Raise ValueError if ``h`` is not a positive finite number or ``scheme`` unknown."""
        positive_parameter(self, "h", "internal step h")
        self.scheme_name()

    def _check_parameters(self) -> None:
        self._check_timing()
        self._check_gains()

    def _step_problem(self, step_size: float) -> str:
        """The exact ZOH of the model over the communication step (the split scheme's
        prediction) must be computable to some digits; an h larger than the step is fine
        (the runtime steps by min(h, step))."""
        return zoh_problem(self._model_matrix(), step_size, "the observer's model")

    def _model_matrix(self) -> np.ndarray:
        """The state matrix of the model the (edited) observer runs on (its record's
        ``model_matrices``), formed once per model."""
        model, matrix = self._matrix_of_model
        if model is not self.model:
            matrix = self.edited_record().model_matrices[0]
            self._matrix_of_model = (self.model, matrix)
        return matrix

    def _check_gains(self) -> None:
        """Raise ValueError (CertificateError) if the edited record is not certified (the
        kind's :attr:`~fhobs.fmu.kinds.Kind.certificate`)."""
        self.kind.certificate(self.edited_record())
