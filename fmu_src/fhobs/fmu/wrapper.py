"""The slave's side of the status wrapper (``status_wrapper.c``, linux64).

With the wrapper, the slave hands it the flat buffer's address, the buffer position of each
value reference and ctypes callbacks when it is created: ``fmi2GetReal`` / ``fmi2SetReal`` of
Real variables then never enter Python, ``fmi2DoStep`` skips pythonfmu's C++ layer, and the
wrapper asks the slave before it hands any other get/set call or a state's bytes to pythonfmu,
answering a refusal with ``fmi2Error``.
"""

from __future__ import annotations

import _ctypes
import ctypes
import os
from pathlib import Path
from typing import Any

import numpy as np

from .access import ACCESS_FUNCTIONS
from .modes import STATUS_OK

WRAPPER_STEP_OK, WRAPPER_STEP_OK_LOGGED, WRAPPER_STEP_REJECTED, WRAPPER_STEP_RAISED = 1, 2, 3, 4
"""Answers of :meth:`FhobsSlave._step_for_wrapper` (``FHOBS_STEP_*`` in status_wrapper.c)."""
_WRAPPER_STEP_TYPE = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_double, ctypes.c_double)
_WRAPPER_ACCESS_TYPE = ctypes.CFUNCTYPE(
    ctypes.c_int, ctypes.c_int, ctypes.POINTER(ctypes.c_uint), ctypes.c_size_t
)
_WRAPPER_STATE_TYPE = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_size_t)


class WrapperCalls:
    """Registration with the wrapper and its callbacks (a mixin of
    :class:`fhobs.fmu.slave_base.FhobsSlave`)."""

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
        through pythonfmu. ``self._values``, ``self._writable``, ``self._mode_code`` (the index
        of the FMI state, which the wrapper reads to refuse calls out of sequence) and
        ``self._clock`` (the last successful time, its fmi2GetRealStatus) are never rebound or
        resized
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
                                 ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
                                 ctypes.c_void_p, _WRAPPER_STEP_TYPE, _WRAPPER_ACCESS_TYPE,
                                 _WRAPPER_STATE_TYPE]
            return bool(register(self._values.ctypes.data, self._values.size,
                                 positions.ctypes.data, self._writable.ctypes.data,
                                 positions.size, self._mode_code.ctypes.data,
                                 self._clock.ctypes.data, *self._wrapper_callbacks))
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
