"""FMI plumbing shared by the observer, Luenberger and plant slaves.

A slave declares array-valued parameters, inputs and outputs; this base class turns each
array into consecutive, row-major scalar variables (``A[1,1]``, ``A[1,2]``, ..., ``y[1]``),
re-checks the parameters at ``exitInitializationMode``, validates the inputs of every
``doStep``, keeps the model's state at its last valid value when a call is rejected, and
captures the complete state (parameters, inputs, the numpy model's internal state) for
``fmi2GetFMUstate`` / ``fmi2SerializeFMUstate``.

Speed. All Real variables live in one flat float buffer (each array variable is a view of its
slice; the inputs first, then the outputs, then the parameters), so ``fmi2GetReal`` /
``fmi2SetReal`` are one fancy-indexing operation on it (the index array of a list of value
references is cached). With the status wrapper (linux64), the slave hands the wrapper the
buffer's address, the buffer position of each value reference and a ctypes callback of
``do_step`` when it is created: ``fmi2GetReal`` / ``fmi2SetReal`` of Real variables then never
enter Python, and ``fmi2DoStep`` skips pythonfmu's C++ layer (see ``status_wrapper.c`` and
:meth:`FhobsSlave._register_with_wrapper`). A valid ``doStep`` costs little more than the
model's own step: one comparison accepts the inputs (their ``math.hypot`` against
``input_bound``), the model steps on views of the input variables (no copies) through its
``advance``, which does not check them again, the state before the step is kept as a shallow
copy of the model's attributes, and the outputs are read as one list of floats (in the order
the model gives them, which is the order of the output arrays in the buffer: no reordering),
accepted by one sum and written into the buffer in one assignment. Element labels are only
formatted, and the exact checks only made, to describe a rejected call.

Rejected calls. Python code inside a pythonfmu 0.7.0 FMU cannot itself return ``fmi2Error``:
an exception is answered with ``fmi2Fatal`` and ``do_step`` returning False with
``fmi2Discard``. The slave therefore records the status of its last call in the Integer
variable ``status`` (value reference 0, ``3`` = error) and logs the reason; the small C
wrapper that :mod:`fhobs.build` places in front of pythonfmu's binary (linux64) reads it
after ``fmi2DoStep`` and ``fmi2ExitInitializationMode`` and returns ``fmi2Error``. Without
that wrapper (win64), a rejected step returns ``fmi2Discard`` and a rejected
initialisation ``fmi2Fatal``.

Only numpy, the standard library, pythonfmu and numpy-only fhobs modules are imported here.
"""

from __future__ import annotations

import _ctypes
import ctypes
import dataclasses
import json
import math
import os
import sys
from abc import abstractmethod
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

from ..gains import ObserverGains
from ..runtime import SCHEMES

DESIGN_FILE = "design.json"
CONFIG_FILE = "fmu_config.json"
STATUS_VALUE_REFERENCE = 0
STATUS_OK = int(Fmi2Status.ok)
STATUS_ERROR = int(Fmi2Status.error)

_KINDS: dict[str, dict[str, Any]] = {
    "parameter": {"causality": Fmi2Causality.parameter, "variability": Fmi2Variability.fixed},
    "input": {"causality": Fmi2Causality.input, "variability": Fmi2Variability.continuous},
    "output": {
        "causality": Fmi2Causality.output,
        "variability": Fmi2Variability.continuous,
        "initial": Fmi2Initial.exact,
    },
}


_INF = math.inf
_hypot = math.hypot

WRAPPER_STEP_OK, WRAPPER_STEP_OK_LOGGED, WRAPPER_STEP_REJECTED, WRAPPER_STEP_RAISED = 1, 2, 3, 4
"""Answers of :meth:`FhobsSlave._step_for_wrapper` (``FHOBS_STEP_*`` in status_wrapper.c)."""
_WRAPPER_STEP_TYPE = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_double, ctypes.c_double)

INDEX_CACHE_SIZE = 64
"""Cached index arrays of lists of value references (cleared when it holds this many)."""


def _as_slice(index: np.ndarray) -> np.ndarray | slice:
    """Buffer positions ``index`` as a slice when they are consecutive (indexing with it is a
    view, cheaper than fancy indexing), else unchanged."""
    if index.size and np.array_equal(index, np.arange(index[0], index[0] + index.size)):
        return slice(int(index[0]), int(index[0]) + index.size)
    return index


class SlaveModel(Protocol):
    """What the base class needs from a runtime object (observer or plant).

    Its ``advance`` (its ``step`` without the argument checks, which the slave has made) must
    replace the arrays that hold the state, never write into them, and leave them as they were
    when it raises (as :mod:`fhobs.runtime` and :mod:`fhobs.plant` do):
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


def element_names(name: str, shape: tuple[int, ...]) -> list[str]:
    """FMI names of the elements of an array, row-major, 1-based (``A[1,1]``, ``A[1,2]``...).

    Parameters
    ----------
    name : str
        Base name of the array.
    shape : tuple of int
        ``()`` for a scalar (the name is returned unchanged), ``(n,)`` or ``(n, m)``.

    Returns
    -------
    list of str
    """
    if not shape:
        return [name]
    return [f"{name}[{','.join(str(i + 1) for i in idx)}]" for idx in np.ndindex(*shape)]


class FhobsSlave(Fmi2Slave):
    """Common base of the fhobs slaves (abstract: subclasses define the model).

    Subclasses implement :meth:`_declare`, :meth:`_check_parameters`, :meth:`_make_model`
    and :meth:`_model_outputs`, and override :meth:`_model_step_arguments` if the model's
    ``advance`` does not take the input arrays in declaration order and :meth:`_output_layout` if
    the model's outputs do not come in declaration order. The design record and the
    build options are read from the instance's own ``resources`` folder, never from module
    globals, so that two FMUs sharing Python modules in one process stay independent.
    """

    author = "fhobs"
    license = "MIT"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        resources = Path(self.resources)
        self.design = ObserverGains.load_json(resources / DESIGN_FILE)
        self.config: dict[str, Any] = json.loads((resources / CONFIG_FILE).read_text())
        self._status_via_wrapper = bool(self.config["status_wrapper"]) and sys.platform == "linux"
        self._arrays: dict[str, np.ndarray] = {}
        self._first_vr: dict[str, int] = {}
        self._integers: dict[str, int] = {}
        self._kinds: dict[str, list[str]] = {kind: [] for kind in _KINDS}
        self.status = STATUS_OK
        self.register_variable(
            Integer(
                "status",
                causality=Fmi2Causality.local,
                variability=Fmi2Variability.discrete,
                initial=Fmi2Initial.exact,
                description="status of the last doStep/exitInitializationMode (0 ok, 3 error)",
            )
        )
        self._declare()
        self.add_array(
            "input_bound", float(self.config["input_bound"]), "parameter",
            "inputs of larger magnitude are rejected as absurd",
        )
        self._pack_arrays()
        self.via_wrapper = self._register_with_wrapper()
        self._ready = False
        self.model: SlaveModel = self._make_model()
        # the start model and the parameters it was built from, until initialisation uses it
        self._start_model: tuple[SlaveModel, tuple] | None = (self.model, self._parameters())
        self._publish()

    # -- declaration helpers -------------------------------------------------------------
    def add_array(self, name: str, value: Any, kind: str, description: str) -> None:
        """Register a float array (or scalar) as consecutive row-major scalar variables.

        Parameters
        ----------
        name : str
            Base name (``A``, ``y``, ``nu``...).
        value : array_like
            Start value; its shape fixes the variables.
        kind : {"parameter", "input", "output"}
        description : str
        """
        array = np.array(value, dtype=float)
        self._arrays[name] = array
        self._first_vr[name] = len(self.vars)
        self._kinds[kind].append(name)
        labels = element_names(name, array.shape)
        for index, label in zip(np.ndindex(*array.shape), labels, strict=True):
            self.register_variable(
                Real(
                    label,
                    description=description,
                    getter=lambda n=name, i=index: float(self._arrays[n][i]),
                    setter=lambda v, n=name, i=index: self._arrays[n].__setitem__(i, v),
                    **_KINDS[kind],
                )
            )

    def _pack_arrays(self) -> None:
        """Move every array variable into one flat buffer (each array becomes a view of it):
        the inputs in declaration order, the outputs in the order of :meth:`_output_layout`,
        then the parameters. Precompute the value-reference -> buffer-position map, the views
        of all inputs and of all outputs, and the model step's arguments."""
        self._output_names = self._output_layout()
        if sorted(self._output_names) != sorted(self._kinds["output"]):
            raise ValueError(f"output layout {self._output_names} is not a permutation of the "
                             f"outputs {self._kinds['output']}")
        self._values = np.zeros(sum(a.size for a in self._arrays.values()))
        self._position: dict[int, int] = {}
        start = 0
        for name in (*self._kinds["input"], *self._output_names, *self._kinds["parameter"]):
            array = self._arrays[name]
            view = self._values[start:start + array.size].reshape(array.shape)
            view[...] = array
            self._arrays[name] = view
            first = self._first_vr[name]
            self._position.update({first + i: start + i for i in range(array.size)})
            start += array.size
        n_inputs = sum(self._arrays[name].size for name in self._kinds["input"])
        n_outputs = sum(self._arrays[name].size for name in self._kinds["output"])
        self._inputs = self._values[:n_inputs]
        self._outputs = self._values[n_inputs:n_inputs + n_outputs]
        self._bound = self._arrays["input_bound"]
        self._step_arguments = self._model_step_arguments()
        self._index_cache: dict[tuple[int, ...], np.ndarray | slice] = {}

    def _register_with_wrapper(self) -> bool:
        """Let the status wrapper serve ``fmi2GetReal`` / ``fmi2SetReal`` from the flat buffer
        without entering Python and call :meth:`do_step` through a ctypes callback rather than
        pythonfmu's C++ layer (see ``status_wrapper.c``); True if it took them.

        Called from the constructor, which runs inside the wrapper's ``fmi2Instantiate`` (or
        ``fmi2Reset``): the wrapper library, already loaded by the importer, is looked up
        without loading it (``RTLD_NOLOAD``), given the buffer's address, the buffer position
        of every Real value reference and the callback, and released. Without the wrapper, or
        when the slave is not being created through it, nothing happens and every call goes
        through pythonfmu. ``self._values`` is never rebound or resized after this (the
        wrapper keeps its address).
        """
        if not (self._status_via_wrapper and hasattr(os, "RTLD_NOLOAD")):
            return False
        binary = Path(self.resources).parent / "binaries" / "linux64" / f"{type(self).__name__}.so"
        try:
            library = ctypes.CDLL(str(binary), mode=os.RTLD_NOLOAD | os.RTLD_LOCAL)
        except OSError:
            return False
        try:
            register = getattr(library, "fhobs_register", None)
            if register is None:
                return False
            positions = np.full(max(self._position, default=-1) + 1, -1, dtype=np.longlong)
            positions[list(self._position)] = list(self._position.values())
            # kept alive with the instance (the wrapper calls it until fmi2FreeInstance/Reset)
            self._wrapper_step = _WRAPPER_STEP_TYPE(self._step_for_wrapper)
            register.restype = ctypes.c_int
            register.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
                                 ctypes.c_size_t, _WRAPPER_STEP_TYPE]
            return bool(register(self._values.ctypes.data, self._values.size,
                                 positions.ctypes.data, positions.size, self._wrapper_step))
        finally:
            _ctypes.dlclose(library._handle)  # balance the RTLD_NOLOAD reference

    def _step_for_wrapper(self, current_time: float, step_size: float) -> int:
        """:meth:`do_step` for the wrapper's ``fmi2DoStep`` (a ctypes callback must not raise):
        its answer as one of the ``WRAPPER_STEP_*`` codes. An exception is kept and raised
        again by the ``do_step`` that the wrapper then calls through pythonfmu, which answers
        it with ``fmi2Fatal`` and logs it as for any exception."""
        try:
            ok = self.do_step(current_time, step_size)
        except BaseException as err:  # handed over to pythonfmu
            pending = err

            def raise_again(current_time: float, step_size: float) -> bool:
                del self.do_step  # back to the method
                raise pending

            self.do_step = raise_again
            return WRAPPER_STEP_RAISED
        if not ok:
            return WRAPPER_STEP_REJECTED
        return WRAPPER_STEP_OK_LOGGED if self.log_queue else WRAPPER_STEP_OK

    def _index(self, vrs: list[int]) -> np.ndarray | slice:
        """Buffer positions of the Real variables ``vrs`` (cached per list of references; a
        slice when they are consecutive, as a master's inputs and outputs usually are).

        Raises
        ------
        TypeError
            If a value reference is not that of a Real variable (as pythonfmu does).
        """
        key = tuple(vrs)
        index = self._index_cache.get(key)
        if index is None:
            missing = [vr for vr in key if vr not in self._position]
            if missing:
                raise TypeError(f"Variable with valueReference={missing[0]} is not of type Real!")
            if len(self._index_cache) >= INDEX_CACHE_SIZE:
                self._index_cache.clear()
            positions = np.array([self._position[vr] for vr in key], dtype=np.intp)
            index = self._index_cache[key] = _as_slice(positions)
        return index

    def get_real(self, vrs: list[int]) -> list[float]:
        """Values of the Real variables ``vrs`` (one read of the flat buffer)."""
        return self._values[self._index(vrs)].tolist()

    def set_real(self, vrs: list[int], values: list[float]) -> None:
        """Set the Real variables ``vrs`` (one write into the flat buffer)."""
        self._values[self._index(vrs)] = values

    def add_integer(self, name: str, value: int, description: str) -> None:
        """Register an Integer parameter."""
        self._integers[name] = int(value)
        self.register_variable(
            Integer(
                name,
                description=description,
                getter=lambda n=name: self._integers[n],
                setter=lambda v, n=name: self._integers.__setitem__(n, int(v)),
                **_KINDS["parameter"],
            )
        )

    def array(self, name: str) -> np.ndarray:
        """Current value of an array variable (a copy)."""
        return self._arrays[name].copy()

    def _elements(self, name: str) -> Iterator[tuple[str, float]]:
        """(FMI name, value) of each element of an array variable, row-major."""
        values = self._arrays[name]
        return zip(element_names(name, values.shape), values.flat, strict=True)

    def integer(self, name: str) -> int:
        """Current value of an Integer parameter."""
        return self._integers[name]

    def edited_design(self) -> ObserverGains:
        """The design record with every design field replaced by its current parameter value."""
        changes: dict[str, Any] = {}
        for field in dataclasses.fields(ObserverGains):
            if field.name in self._kinds["parameter"]:
                value = self.array(field.name)
                changes[field.name] = float(value) if value.ndim == 0 else value
        return dataclasses.replace(self.design, **changes)

    # -- FMI lifecycle -------------------------------------------------------------------
    def _parameters(self) -> tuple:
        """The exact current values of every parameter (what :meth:`_make_model` reads)."""
        arrays = tuple(self._arrays[name].tobytes() for name in self._kinds["parameter"])
        return arrays, tuple(self._integers.items())

    def exit_initialization_mode(self) -> None:
        """Re-check the (possibly edited) parameters and build the model from them.

        The model built by the constructor is used if it is still the slave's model (no FMU
        state was set since) and every parameter still has the value it was built from: it
        is then the model :meth:`_make_model` would build (whose construction can cost tens of
        milliseconds). It is used at most once.
        """
        self.status = STATUS_OK
        self._ready = False
        start, self._start_model = self._start_model, None
        try:
            self._check_finite_parameters()
            self._check_parameters()
            if start is None or start[0] is not self.model or start[1] != self._parameters():
                self.model = self._make_model()
        except ValueError as err:
            self._fail(f"initialisation rejected the parameters: {err}")
            if not self._status_via_wrapper:
                raise
            return
        self._ready = True
        self._publish()

    def do_step(self, current_time: float, step_size: float) -> bool:
        """Advance by ``step_size`` with the inputs held; reject invalid calls, state kept.

        The path of a valid step is kept short (it runs once per FMU and communication step):
        the inputs are checked as one list; the model steps on views of the input variables
        (:class:`SlaveModel`: it neither keeps nor writes them); the state before the step is
        kept as a shallow copy of the model's attributes rather than through ``get_state``: a
        runtime step never writes into its state arrays, it replaces them (and leaves them as
        they were when it raises), so those references are the complete state before the step.
        They are put back if the new outputs are not finite; the output variables are only
        written once the outputs are accepted.
        """
        self.status = STATUS_OK
        if not self._ready:
            return self._fail("doStep called without a successful initialisation")
        # One comparison accepts a valid call: math.hypot of the inputs is within 1 ulp of
        # their Euclidean norm (Python >= 3.10), which bounds each |input|, so a hypot strictly
        # below the bound bounds them all; it is NaN or inf when an input is not finite, which
        # fails the comparison. Anything else (also |input| = bound) gets the exact checks.
        if not (0.0 < step_size < _INF and _hypot(*self._inputs.tolist()) < self._bound.item()):
            problem = self._input_problem(step_size)
            if problem:
                return self._fail(f"doStep at t = {current_time!r} rejected: {problem}")
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
            return self._fail(f"doStep at t = {current_time!r} rejected: {err}")
        self._outputs[...] = outputs
        return True

    def _check_finite_parameters(self) -> None:
        """Raise ValueError naming the first parameter element that is not finite."""
        for name in self._kinds["parameter"]:
            for label, value in self._elements(name):
                if not np.isfinite(value):
                    raise ValueError(f"parameter {label} = {value!r} is not finite")

    def _fail(self, message: str) -> bool:
        """Log ``message`` with status error, record the status, and return False."""
        self.status = STATUS_ERROR
        self.log(message, Fmi2Status.error)
        return False

    def _input_problem(self, step_size: float) -> str:
        """Describe what is wrong with the step size or the inputs ('' when nothing is)."""
        if not (np.isfinite(step_size) and step_size > 0.0):
            return f"communication step size {step_size!r} is not a positive finite number"
        bound = float(self._arrays["input_bound"])
        for name in self._kinds["input"]:
            for label, value in self._elements(name):
                if not np.isfinite(value):
                    return f"input {label} = {value!r} is not finite"
                if abs(value) > bound:
                    return f"input {label} = {value!r} exceeds input_bound = {bound!r}"
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

    # -- FMU state -----------------------------------------------------------------------
    def _get_fmu_state(self) -> dict[str, Any]:
        """Everything needed to continue bit for bit: variables, readiness, model state."""
        return {
            "arrays": {name: value.tolist() for name, value in self._arrays.items()},
            "integers": dict(self._integers),
            "ready": self._ready,
            "model": self.model.get_state().tolist(),
        }

    def _set_fmu_state(self, state: dict[str, Any]) -> None:
        """Restore a state from :meth:`_get_fmu_state` (possibly of another instance)."""
        for name, value in state["arrays"].items():
            self._arrays[name][...] = value
        self._integers.update(state["integers"])
        self.model = self._make_model()
        self.model.set_state(np.array(state["model"], dtype=float))
        self._ready = bool(state["ready"])
        self.status = STATUS_OK

    # -- what a slave defines ------------------------------------------------------------
    @abstractmethod
    def _declare(self) -> None:
        """Register the slave's parameters, inputs and outputs (start values from the design)."""

    @abstractmethod
    def _check_parameters(self) -> None:
        """Raise ValueError, naming the check and the amount, if the parameters are unusable."""

    @abstractmethod
    def _make_model(self) -> SlaveModel:
        """Build the runtime object from the current parameter values."""

    def _model_step_arguments(self) -> tuple[np.ndarray | None, ...]:
        """The arguments of the model's ``advance`` before the step size: by default the input
        variables (views of the buffer, read during the step) in declaration order."""
        return tuple(self._arrays[name] for name in self._kinds["input"])

    def _output_layout(self) -> list[str]:
        """Names of the output arrays in the order in which :meth:`_model_outputs` gives their
        elements (and the buffer holds them); by default the declaration order."""
        return list(self._kinds["output"])

    @abstractmethod
    def _model_outputs(self) -> Sequence[float]:
        """The model's current outputs as floats, flat, in the order of :meth:`_output_layout`
        (called after every step: kept cheap)."""


def positive_parameter(slave: FhobsSlave, name: str, what: str) -> float:
    """The scalar parameter ``name`` of ``slave``; ValueError naming ``what`` unless it is a
    positive finite number."""
    value = float(slave.array(name))
    if not (np.isfinite(value) and value > 0.0):
        raise ValueError(f"{what} = {value!r} is not a positive finite number")
    return value


class ObserverSlave(FhobsSlave):
    """Base of the observer slaves: plant matrices, z0, timing, inputs y, u, output x_hat.

    Subclasses add their gains with :meth:`_declare_gains` and may add outputs. The timing
    parameters are by default those of :mod:`fhobs.runtime` (internal step ``h`` and
    ``scheme``); a sampled-data observer replaces them (:meth:`_declare_timing`,
    :meth:`_check_timing`).
    """

    def _declare(self) -> None:
        design, config = self.design, self.config
        self.add_array("A", design.A, "parameter", "plant state matrix (n x n)")
        self.add_array("B", design.B, "parameter", "plant input matrix (n x m)")
        self.add_array("C", design.C, "parameter", "plant output matrix (k x n)")
        self._declare_gains()
        self.add_array("z0", config["z0"], "parameter", "initial state estimate")
        self._declare_timing()
        self.add_array("y", np.zeros(design.k), "input", "measured plant output")
        self.add_array("u", np.zeros(design.m), "input", "plant input")
        self.add_array("x_hat", np.zeros(design.n), "output", "state estimate z")

    def scheme_name(self) -> str:
        """Name of the selected integration scheme; ValueError if the index is unknown."""
        index = self.integer("scheme")
        if not 0 <= index < len(SCHEMES):
            raise ValueError(f"scheme = {index} is not in 0..{len(SCHEMES) - 1} ({SCHEMES})")
        return SCHEMES[index]

    def _declare_timing(self) -> None:
        """Register the internal step ``h`` and the integration ``scheme``."""
        self.add_array("h", self.config["h"], "parameter", "internal integration step (s)")
        self.add_integer(
            "scheme",
            SCHEMES.index(self.config["scheme"]),
            "integration scheme: " + ", ".join(f"{i} = {s}" for i, s in enumerate(SCHEMES)),
        )

    def _check_timing(self) -> None:
        """Raise ValueError if ``h`` is not a positive finite number or ``scheme`` unknown."""
        positive_parameter(self, "h", "internal step h")
        self.scheme_name()

    def _check_parameters(self) -> None:
        self._check_timing()
        self._check_gains()

    @abstractmethod
    def _declare_gains(self) -> None:
        """Register the observer's gain parameters."""

    @abstractmethod
    def _check_gains(self) -> None:
        """Raise ValueError (CertificateError) if the edited design is not certified."""
