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
from xml.etree.ElementTree import Element

import numpy as np
from pythonfmu import (
    Boolean,
    Fmi2Causality,
    Fmi2Initial,
    Fmi2Slave,
    Fmi2Variability,
    Integer,
    Real,
    String,
)
from pythonfmu.enums import Fmi2Status

from ..core.gains import ObserverGains
from ..core.runtime import SCHEMES

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
_WRAPPER_ACCESS_TYPE = ctypes.CFUNCTYPE(
    ctypes.c_int, ctypes.c_int, ctypes.POINTER(ctypes.c_uint), ctypes.c_size_t
)
_WRAPPER_STATE_TYPE = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_size_t)

ACCESS_FUNCTIONS = (
    ("fmi2GetReal", Real), ("fmi2SetReal", Real), ("fmi2GetInteger", Integer),
    ("fmi2SetInteger", Integer), ("fmi2GetBoolean", Boolean), ("fmi2SetBoolean", Boolean),
    ("fmi2GetString", String), ("fmi2SetString", String),
)
"""The get/set functions by the code the wrapper passes (``FHOBS_GET_REAL`` ...), with the
variable type each one serves."""

INSTANTIATED, INITIALISATION, STEP_MODE, TERMINATED = (
    "instantiated", "initialisation mode", "step mode", "terminated",
)
MODES = (INSTANTIATED, INITIALISATION, STEP_MODE, TERMINATED)
"""The FMI 2.0 co-simulation states a slave tracks (``fmi2Reset`` creates a new slave)."""

STATE_FORMAT = 2
"""Version of the FMU state layout of :meth:`FhobsSlave._get_fmu_state`."""
STATE_KEYS = {"format", "fmu", "mode", "arrays", "integers", "model"}
"""The entries of a state (:meth:`FhobsSlave._get_fmu_state`)."""

ZOH_CONDITION_LIMIT = 1e9
"""Largest ``step ||A||_1`` for which the exact ZOH ``expm(step A)`` is computed: its condition
number is at least ``step ||A||``, so at this limit its relative error can already reach
eps * 1e9 = 2e-7 (entries like 1e300 give finite numbers that mean nothing)."""

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


def number(value: float) -> str:
    """A number as a message shows it: ``repr`` of a Python float (never ``np.float64(...)``)."""
    return repr(float(value))


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
    return (f"{what}: step * ||A||_1 = {scale:.3g} exceeds {ZOH_CONDITION_LIMIT:.0e}, beyond "
            f"which expm(step * A) has no correct digit (step = {number(step)}); "
            "check the entries of A")


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


def _array_problem(value: Any, shape: tuple[int, ...], name: str, finite: bool = True) -> str:
    """Why ``value`` (from a parsed state) is not an array of numbers of ``shape`` ('' if it
    is); with ``finite``, also if an entry is NaN or infinite."""
    try:
        array = np.asarray(value)
    except ValueError:  # ragged nesting
        return f"{name} is not an array of numbers"
    if array.dtype.kind not in "fi":
        return f"{name} is not an array of numbers"
    if array.shape != shape:
        return f"{name} has shape {array.shape}, expected {shape}"
    if finite and not np.isfinite(array).all():
        return f"{name} has non-finite entries"
    return ""


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
                description="status of the last call the slave answered (0 ok, 3 error)",
            )
        )
        self._declare()
        self.add_array(
            "input_bound", float(self.config["input_bound"]), "parameter",
            "inputs of larger magnitude are rejected as absurd",
        )
        self._pack_arrays()
        self._set_mode(INSTANTIATED)
        self.via_wrapper = self._register_with_wrapper()
        self.model: SlaveModel = self._make_model()
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
        # buffer positions of lists of value references checked for reading / for writing now
        self._index_cache: dict[tuple[int, ...], np.ndarray | slice] = {}
        self._write_cache: dict[tuple[int, ...], np.ndarray | slice] = {}
        size = max(self._position, default=-1) + 1
        # 1 where fmi2SetReal may write now (kept up to date by _set_mode; read by the wrapper)
        self._writable = np.zeros(size, dtype=np.uint8)
        self._input_vrs = [vr for name in self._kinds["input"] for vr in self._vrs(name)]
        self._parameter_vrs = [vr for name in self._kinds["parameter"] for vr in self._vrs(name)]
        self._writable[self._input_vrs] = 1
        self._accepted_step = math.nan  # the step size whose checks passed last (none yet)
        self._certified: tuple | None = None  # the parameters of the last initialisation

    def _vrs(self, name: str) -> range:
        """Value references of the elements of array variable ``name``."""
        return range(self._first_vr[name], self._first_vr[name] + self._arrays[name].size)

    def _set_mode(self, mode: str) -> None:
        """Enter FMI state ``mode``: Real parameters are writable before step mode only."""
        self._mode = mode
        self._writable[self._parameter_vrs] = mode in (INSTANTIATED, INITIALISATION)
        self._write_cache.clear()

    def _register_with_wrapper(self) -> bool:
        """Let the status wrapper serve ``fmi2GetReal`` / ``fmi2SetReal`` from the flat buffer
        without entering Python (reads of Real variables; writes where ``self._writable`` says
        so), call :meth:`do_step` through a ctypes callback rather than pythonfmu's C++ layer,
        and ask :meth:`_access_for_wrapper` / :meth:`_state_bytes_for_wrapper` before handing
        any other get/set or a state's bytes to pythonfmu (see ``status_wrapper.c``); True if
        it took them.

        Called from the constructor, which runs inside the wrapper's ``fmi2Instantiate`` (or
        ``fmi2Reset``): the wrapper library, already loaded by the importer, is looked up
        without loading it (``RTLD_NOLOAD``), given the buffer's address, the buffer position
        of every Real value reference and the callback, and released. Without the wrapper, or
        when the slave is not being created through it, nothing happens and every call goes
        through pythonfmu. ``self._values`` and ``self._writable`` are never rebound or resized
        after this (the wrapper keeps their addresses).
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
            positions = np.full(self._writable.size, -1, dtype=np.longlong)
            positions[list(self._position)] = list(self._position.values())
            # kept alive with the instance (the wrapper calls them until fmi2FreeInstance/Reset)
            self._wrapper_callbacks = (
                _WRAPPER_STEP_TYPE(self._step_for_wrapper),
                _WRAPPER_ACCESS_TYPE(self._access_for_wrapper),
                _WRAPPER_STATE_TYPE(self._state_bytes_for_wrapper),
            )
            register.restype = ctypes.c_int
            register.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
                                 ctypes.c_void_p, ctypes.c_size_t, _WRAPPER_STEP_TYPE,
                                 _WRAPPER_ACCESS_TYPE, _WRAPPER_STATE_TYPE]
            return bool(register(self._values.ctypes.data, self._values.size,
                                 positions.ctypes.data, self._writable.ctypes.data,
                                 positions.size, *self._wrapper_callbacks))
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

    def _access_for_wrapper(self, function: int, vrs: Any, count: int) -> int:
        """The wrapper's question before it hands a get/set call to pythonfmu (a ctypes
        callback: never raises): 1 if the call may go ahead, else 0 with the reason logged and
        ``status`` error. ``function`` indexes :data:`ACCESS_FUNCTIONS`."""
        self.status = STATUS_OK
        try:
            name, _ = ACCESS_FUNCTIONS[function]
            problem = self._access_problem(name, vrs[:count])
        except BaseException as err:  # noqa: BLE001 (a callback must answer)
            problem = f"the call could not be checked ({type(err).__name__}: {err})"
        if problem:
            self._fail(problem)
            return 0
        return 1

    def _access_problem(self, function: str, vrs: Sequence[int]) -> str:
        """Why ``function`` (``fmi2GetReal``, ``fmi2SetInteger``...) may not be applied to the
        value references ``vrs`` now ('' if it may): unknown reference, another type, or a
        write to an output, to ``status`` or to a parameter after initialisation."""
        kind = dict(ACCESS_FUNCTIONS)[function]
        for vr in vrs:
            var = self.vars.get(vr)
            if var is None:
                return (f"{function}: value reference {vr} is not a variable of this FMU "
                        f"(its value references are 0..{len(self.vars) - 1})")
            label = f"{var.name} (value reference {vr})"
            if not isinstance(var, kind):
                return (f"{function}: {label} is of type {type(var).__name__}, "
                        f"not {kind.__name__}")
            if not function.startswith("fmi2Set"):
                continue
            if var.causality == Fmi2Causality.output:
                return f"{function}: {label} is an output: the FMU computes it, it cannot be set"
            if var.causality == Fmi2Causality.local:
                return f"{function}: {label} is a local variable: it cannot be set"
            if var.causality == Fmi2Causality.parameter and self._mode not in (
                INSTANTIATED, INITIALISATION
            ):
                return (f"{function}: {label} is a fixed parameter: it can be set only before "
                        f"fmi2ExitInitializationMode (the instance is in {self._mode}; "
                        "fmi2Reset returns to the start values)")
        return ""

    def _checked_access(self, function: str, vrs: Sequence[int]) -> None:
        """Refuse a get/set call that :meth:`_access_problem` rejects (ValueError, which
        pythonfmu answers with fmi2Fatal: only reached without the wrapper)."""
        problem = self._access_problem(function, vrs)
        if problem:
            self._fail(problem)
            raise ValueError(problem)

    def _state_bytes_for_wrapper(self, data: int, size: int) -> int:
        """The wrapper's question before it hands bytes to pythonfmu's
        fmi2DeSerializeFMUstate (a ctypes callback: never raises): 1 if they are a state this
        FMU can restore, else 0 with the reason logged and ``status`` error."""
        self.status = STATUS_OK
        try:
            problem = self._state_bytes_problem(ctypes.string_at(data, size) if size else b"")
        except BaseException as err:  # noqa: BLE001 (a callback must answer)
            problem = f"the state could not be checked ({type(err).__name__}: {err})"
        if problem:
            self._fail(f"fmi2DeSerializeFMUstate rejected the bytes: {problem}")
            return 0
        return 1

    def _state_bytes_problem(self, data: bytes) -> str:
        """Why ``data`` is not a serialized state of this FMU ('' if it is)."""
        try:
            state = self._fmu_state_from_bytes(data)
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
            return f"they are not a serialized FMU state of this FMU ({err})"
        return self._state_problem(state)

    def get_real(self, vrs: list[int]) -> list[float]:
        """Values of the Real variables ``vrs`` (one read of the flat buffer)."""
        index = self._index_cache.get(tuple(vrs))
        if index is None:
            self._checked_access("fmi2GetReal", vrs)
            index = self._index(self._index_cache, vrs)
        return self._values[index].tolist()

    def set_real(self, vrs: list[int], values: list[float]) -> None:
        """Set the Real variables ``vrs`` (one write into the flat buffer)."""
        index = self._write_cache.get(tuple(vrs))
        if index is None:
            self._checked_access("fmi2SetReal", vrs)
            index = self._index(self._write_cache, vrs)
        self._values[index] = values

    def get_integer(self, vrs: list[int]) -> list[int]:
        self._checked_access("fmi2GetInteger", vrs)
        return super().get_integer(vrs)

    def set_integer(self, vrs: list[int], values: list[int]) -> None:
        self._checked_access("fmi2SetInteger", vrs)
        super().set_integer(vrs, values)

    def get_boolean(self, vrs: list[int]) -> list[bool]:
        self._checked_access("fmi2GetBoolean", vrs)
        return super().get_boolean(vrs)

    def set_boolean(self, vrs: list[int], values: list[bool]) -> None:
        self._checked_access("fmi2SetBoolean", vrs)
        super().set_boolean(vrs, values)

    def get_string(self, vrs: list[int]) -> list[str]:
        self._checked_access("fmi2GetString", vrs)
        return super().get_string(vrs)

    def set_string(self, vrs: list[int], values: list[str]) -> None:
        self._checked_access("fmi2SetString", vrs)
        super().set_string(vrs, values)

    def _index(self, cache: dict, vrs: list[int]) -> np.ndarray | slice:
        """Buffer positions of the Real variables ``vrs``, which the caller has checked, kept
        in ``cache`` (per list of references; a slice when they are consecutive, as a
        master's inputs and outputs usually are)."""
        if len(cache) >= INDEX_CACHE_SIZE:
            cache.clear()
        positions = np.array([self._position[vr] for vr in vrs], dtype=np.intp)
        index = cache[tuple(vrs)] = _as_slice(positions)
        return index

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

    def choice(self, name: str, choices: Sequence[str]) -> str:
        """The entry of ``choices`` that the Integer parameter ``name`` selects; ValueError if
        the index is out of range."""
        index = self.integer(name)
        if not 0 <= index < len(choices):
            raise ValueError(f"{name} = {index} is not in 0..{len(choices) - 1} ({choices})")
        return choices[index]

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

    def _refuse(self, message: str) -> None:
        """Answer a call made out of sequence or with unusable parameters: log ``message``,
        record the error for the wrapper, which returns fmi2Error; without the wrapper raise
        ValueError (pythonfmu: fmi2Fatal)."""
        self._fail(message)
        if not self._status_via_wrapper:
            raise ValueError(message)

    def enter_initialization_mode(self) -> None:
        """Enter initialisation mode: once, right after instantiation or fmi2Reset."""
        self.status = STATUS_OK
        if self._mode != INSTANTIATED:
            self._refuse(f"fmi2EnterInitializationMode called in {self._mode}: an instance is "
                         "initialised once (fmi2Reset first to start again)")
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
        if self._mode != INITIALISATION:
            self._refuse(f"fmi2ExitInitializationMode called in {self._mode}: it must follow "
                         "fmi2EnterInitializationMode")
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
        self._set_mode(STEP_MODE)

    def terminate(self) -> None:
        """End the run: no doStep afterwards (fmi2Reset to start again)."""
        self.status = STATUS_OK
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
        if self._mode != STEP_MODE:
            if self._mode == TERMINATED:
                reason = "the instance was terminated (fmi2Terminate); fmi2Reset to start again"
            else:
                reason = (f"the instance is in {self._mode}; doStep needs a successful "
                          "initialisation")
            return self._fail(f"doStep at t = {number(current_time)} refused: {reason}")
        # One comparison accepts a valid call: math.hypot of the inputs is within 1 ulp of
        # their Euclidean norm (Python >= 3.10), which bounds each |input|, so a hypot strictly
        # below the bound bounds them all; it is NaN or inf when an input is not finite, which
        # fails the comparison. Anything else (also |input| = bound) gets the exact checks.
        if not (step_size == self._accepted_step
                and _hypot(*self._inputs.tolist()) < self._bound.item()):
            problem = self._step_size_problem(step_size) or self._input_problem()
            if problem:
                return self._fail(f"doStep at t = {number(current_time)} rejected: {problem}")
            self._accepted_step = step_size
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
            return self._fail(f"doStep at t = {number(current_time)} rejected: {err}")
        self._outputs[...] = outputs
        return True

    def _check_all_parameters(self) -> None:
        """Raise ValueError naming the first problem of the current parameters: a non-finite
        element, ``input_bound <= 0``, or what the slave's own checks reject."""
        self._check_finite_parameters()
        bound = float(self._bound)
        if not bound > 0.0:
            raise ValueError(f"parameter input_bound = {number(bound)} must be > 0")
        self._check_parameters()

    def _check_finite_parameters(self) -> None:
        """Raise ValueError naming the first parameter element that is not finite."""
        for name in self._kinds["parameter"]:
            for label, value in self._elements(name):
                if not math.isfinite(value):
                    raise ValueError(f"parameter {label} = {number(value)} is not finite")

    def _fail(self, message: str) -> bool:
        """Log ``message`` with status error, record the status, and return False."""
        self.status = STATUS_ERROR
        self.log(message, Fmi2Status.error)
        return False

    def _step_size_problem(self, step_size: float) -> str:
        """Describe what is wrong with the communication step size ('' when nothing is)."""
        if not (math.isfinite(step_size) and step_size > 0.0):
            return f"communication step size {number(step_size)} is not a positive finite number"
        return self._step_problem(step_size)

    def _input_problem(self) -> str:
        """Describe what is wrong with the inputs ('' when nothing is)."""
        bound = float(self._bound)
        for name in self._kinds["input"]:
            for label, value in self._elements(name):
                if not math.isfinite(value):
                    return f"input {label} = {number(value)} is not finite"
                if abs(value) > bound:
                    return f"input {label} = {number(value)} exceeds input_bound = {number(bound)}"
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
        """Everything needed to continue bit for bit: variables, FMI state, model state; with
        the layout's version and the FMU's identity (its class name, unique per build)."""
        return {
            "format": STATE_FORMAT,
            "fmu": type(self).__name__,
            "mode": self._mode,
            "arrays": {name: value.tolist() for name, value in self._arrays.items()},
            "integers": dict(self._integers),
            "model": self.model.get_state().tolist(),
        }

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> Any:
        """Parse a serialized state (JSON, as pythonfmu writes it; checked by the caller)."""
        return json.loads(state.decode("utf-8"))

    def _state_problem(self, state: Any) -> str:
        """Why ``state`` is not a complete, consistent state of this FMU ('' if it is):
        layout version, FMU identity, FMI state, and every variable's presence, shape and
        finiteness (inputs may hold any number: doStep checks them)."""
        if not isinstance(state, dict) or set(state) != STATE_KEYS:
            return "not an FMU state of this FMU (unexpected layout)"
        if state["format"] != STATE_FORMAT:
            return f"state format {state['format']!r} is not {STATE_FORMAT}"
        if state["fmu"] != type(self).__name__:
            return f"it is a state of {state['fmu']!r}, not of this FMU ({type(self).__name__})"
        if state["mode"] not in MODES:
            return f"unknown FMI state {state['mode']!r}"
        arrays, integers = state["arrays"], state["integers"]
        if not isinstance(arrays, dict) or set(arrays) != set(self._arrays):
            return "its variables are not this FMU's"
        for name, current in self._arrays.items():
            problem = _array_problem(arrays[name], current.shape, name,
                                     finite=name not in self._kinds["input"])
            if problem:
                return problem
        if not isinstance(integers, dict) or set(integers) != set(self._integers):
            return "its Integer variables are not this FMU's"
        for name, value in integers.items():
            if type(value) is not int:
                return f"Integer variable {name} = {value!r} is not an integer"
        return _array_problem(state["model"], (self.model.get_state().size,), "model state")

    def _set_fmu_state(self, state: dict[str, Any]) -> None:
        """Restore a state from :meth:`_get_fmu_state` (possibly of another instance), or
        refuse it whole (:meth:`_refuse`) without changing anything.

        The state is checked completely first (:meth:`_state_problem`); then its parameters
        are tried: for a state of an initialised instance they must pass the initialisation
        checks (unless they are the parameters this instance was initialised with), and the
        model built from them must accept the model state and give finite outputs. Only then
        is anything of the instance replaced.
        """
        self.status = STATUS_OK
        problem = self._state_problem(state)
        if not problem:
            saved_values, saved_integers = self._values.copy(), dict(self._integers)
            self._values[...] = np.concatenate([
                np.ravel(np.asarray(state["arrays"][name], dtype=float))
                for name in (*self._kinds["input"], *self._output_names,
                             *self._kinds["parameter"])
            ])
            self._integers.update(state["integers"])
            model, problem = self._model_for_state(state)
            if problem:
                self._values[...] = saved_values
                self._integers.clear()
                self._integers.update(saved_integers)
        if problem:
            self._refuse(f"fmi2SetFMUstate rejected the state: {problem}")
            return
        self.model = model
        self._start_model = None
        self._accepted_step = math.nan
        if state["mode"] in (STEP_MODE, TERMINATED):
            self._certified = self._parameters()
        self._set_mode(state["mode"])

    def _model_for_state(self, state: dict[str, Any]) -> tuple[SlaveModel | None, str]:
        """The model of the parameters just written, set to the state's model state, or the
        reason why there is none."""
        try:
            if state["mode"] in (STEP_MODE, TERMINATED) and self._parameters() != self._certified:
                self._check_all_parameters()
            model = self._make_model()
            model.set_state(np.array(state["model"], dtype=float))
            current, self.model = self.model, model
            try:
                self._finite_outputs()
            finally:
                self.model = current
        except ValueError as err:
            return None, f"its parameters or model state are not usable: {err}"
        return model, ""

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

    def _step_problem(self, step_size: float) -> str:
        """Why the model cannot take a communication step of ``step_size`` (positive and
        finite) with the current parameters ('' if it can); checked once per new size."""
        return ""

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
    parameters are by default those of :mod:`fhobs.core.runtime` (internal step ``h`` and
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
        return self.choice("scheme", SCHEMES)

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

    def _step_problem(self, step_size: float) -> str:
        """The exact ZOH of the model over the communication step (the split scheme's
        prediction) must be computable to some digits; an h larger than the step is fine
        (the runtime steps by min(h, step))."""
        return zoh_problem(self.edited_design().model[0], step_size, "the observer's model")

    @abstractmethod
    def _declare_gains(self) -> None:
        """Register the observer's gain parameters."""

    @abstractmethod
    def _check_gains(self) -> None:
        """Raise ValueError (CertificateError) if the edited design is not certified."""
