"""FMU states: the complete state of a slave (parameters, inputs, the model's internal state)
for ``fmi2GetFMUstate`` / ``fmi2SerializeFMUstate``, checked whole before any of it is used.

A serialized state is the state's JSON object with one last member, ``"checksum"``: the 64-bit
FNV-1a hash (16 hex digits) of every byte before that member. The checksum is verified on the
bytes before they are parsed, so a changed byte anywhere is refused naming the checksum."""

from __future__ import annotations

import json
import math
import re
from typing import TYPE_CHECKING, Any

import numpy as np

from .modes import MODES, STATUS_OK, STEP_MODE, TERMINATED

if TYPE_CHECKING:
    from .slave_base import SlaveModel

STATE_FORMAT = 4
"""Version of the FMU state layout of :meth:`FhobsSlave._get_fmu_state`."""
STATE_KEYS = {"format", "fmu", "mode", "time", "arrays", "integers", "model"}
"""The entries of a state (:meth:`FhobsSlave._get_fmu_state`)."""
_CHECKSUM_TAIL = re.compile(rb', "checksum": "([0-9a-f]{16})"\}\Z')
"""The last member of a serialized state: its checksum."""
_FNV_OFFSET, _FNV_PRIME, _MASK64 = 0xCBF29CE484222325, 0x100000001B3, (1 << 64) - 1
INTEGER_RANGE = (-(2**31), 2**31 - 1)
"""The values of an FMI Integer variable (a C int)."""


def fnv1a64(data: bytes) -> int:
    """The 64-bit FNV-1a hash of ``data``.

    Examples
    --------
    >>> f"{fnv1a64(b''):016x}", f"{fnv1a64(b'a'):016x}"
    ('cbf29ce484222325', 'af63dc4c8601ec8c')
    """
    value = _FNV_OFFSET
    for byte in data:
        value = ((value ^ byte) * _FNV_PRIME) & _MASK64
    return value


def state_to_bytes(state: dict[str, Any]) -> bytes:
    """Serialize a state: its JSON object with the checksum of the bytes before it appended as
    the last member (the module docstring).

    Examples
    --------
    >>> state_to_bytes({"format": 3})
    b'{"format": 3, "checksum": "3dd2e8bf3b826a7e"}'
    >>> state_from_bytes(state_to_bytes({"format": 3}))
    {'format': 3}
    """
    body = json.dumps(state).encode("utf-8")
    if not (body.startswith(b"{") and body.endswith(b"}") and len(body) > 2):
        raise ValueError("an FMU state is a non-empty JSON object")
    head = body[:-1]
    return head + b', "checksum": "%016x"}' % fnv1a64(head)


def checksum_problem(data: bytes) -> str:
    """Why ``data`` does not carry a valid checksum ('' if it does).

    Examples
    --------
    >>> data = state_to_bytes({"format": 3})
    >>> checksum_problem(data)
    ''
    >>> checksum_problem(data.replace(b"3", b"2", 1))
    'its checksum does not match its contents (the bytes were changed after serialization)'
    """
    tail = _CHECKSUM_TAIL.search(data)
    if tail is None:
        return "its checksum is missing or damaged"
    if int(tail.group(1), 16) != fnv1a64(data[:tail.start()]):
        return ("its checksum does not match its contents (the bytes were changed after "
                "serialization)")
    return ""


def state_from_bytes(data: bytes) -> Any:
    """Parse a serialized state (:func:`state_to_bytes`) after checking its checksum.

    Raises
    ------
    ValueError
        If the checksum is missing or does not match (:func:`checksum_problem`), or the bytes
        are not UTF-8 JSON (``UnicodeDecodeError`` and ``json.JSONDecodeError`` are
        ValueErrors).

    Examples
    --------
    >>> state_from_bytes(b'{"format": 2}')
    Traceback (most recent call last):
    ...
    ValueError: its checksum is missing or damaged
    """
    problem = checksum_problem(data)
    if problem:
        raise ValueError(problem)
    head = data[:_CHECKSUM_TAIL.search(data).start()]
    return json.loads((head + b"}").decode("utf-8"))


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


class FmuStates:
    """Get, check and set FMU states (a mixin of :class:`fhobs.fmu.slave_base.FhobsSlave`)."""

    def _state_bytes_problem(self, data: bytes) -> str:
        """Why ``data`` is not a serialized state of this FMU ('' if it is)."""
        problem = checksum_problem(data)
        if problem:
            return f"they are not a serialized FMU state of this FMU ({problem})"
        try:
            state = self._fmu_state_from_bytes(data)
        except (ValueError, RecursionError) as err:
            return f"they are not a serialized FMU state of this FMU ({err})"
        return self._state_problem(state)

    # -- FMU state -----------------------------------------------------------------------
    def _get_fmu_state(self) -> dict[str, Any]:
        """Everything needed to continue bit for bit: variables, FMI state, model state; with
        the layout's version and the FMU's identity (its class name, unique per build)."""
        return {
            "format": STATE_FORMAT,
            "fmu": type(self).__name__,
            "mode": self._mode,
            "time": float(self._clock[0]),
            "arrays": {name: value.tolist() for name, value in self._arrays.items()},
            "integers": dict(self._integers),
            "model": self.model.get_state().tolist(),
        }

    @staticmethod
    def _fmu_state_to_bytes(state: dict[str, Any]) -> bytes:
        """Serialize a state for pythonfmu's fmi2SerializeFMUstate (:func:`state_to_bytes`)."""
        return state_to_bytes(state)

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> Any:
        """Parse a serialized state for pythonfmu's fmi2DeSerializeFMUstate
        (:func:`state_from_bytes`: the checksum first; the rest checked by the caller)."""
        return state_from_bytes(state)

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
        if type(state["time"]) is not float or not math.isfinite(state["time"]):
            return f"its time {state['time']!r} is not a finite number"
        arrays, integers = state["arrays"], state["integers"]
        if not isinstance(arrays, dict) or set(arrays) != set(self._arrays):
            return "its variables are not this FMU's"
        for name, current in self._arrays.items():
            problem = _array_problem(arrays[name], current.shape, name,
                                     finite=name not in self._causal["input"])
            if problem:
                return problem
        if not isinstance(integers, dict) or set(integers) != set(self._integers):
            return "its Integer variables are not this FMU's"
        for name, value in integers.items():
            if type(value) is not int or not INTEGER_RANGE[0] <= value <= INTEGER_RANGE[1]:
                return (f"Integer variable {name} = {value!r} is not an integer in "
                        f"[{INTEGER_RANGE[0]}, {INTEGER_RANGE[1]}]")
        return (_array_problem(state["model"], (self.model.get_state().size,), "model state")
                or self._model_state_problem(np.asarray(state["model"], dtype=float)))

    def _model_state_problem(self, model_state: np.ndarray) -> str:
        """Why the finite ``model_state`` of the right size is not one the model can continue
        from ('' if it is): its whole-number fields and ranges, those the model's own
        ``set_state`` does not check (a kind whose state has such fields overrides this)."""
        return ""

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
                for name in (*self._causal["input"], *self._output_names,
                             *self._causal["parameter"])
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
        self._time = math.nan  # the next doStep's time is taken as it comes
        self._clock[0] = state["time"]
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
