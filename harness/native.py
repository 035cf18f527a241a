"""The master's step in C (``step_loop.c``), compiled on first use with the system C compiler.

:func:`step_library` returns the loaded library, or None when it cannot be had (no ``cc`` or
``gcc``, not Linux, a failed compilation, ``FHOBS_HARNESS_PYTHON_LOOP`` set): the master then
makes the same calls from Python (and gathers the inputs with the same sums, so both loops give
the same results bit for bit). The library is cached in the user's cache directory
(``$XDG_CACHE_HOME/fhobs`` or ``~/.cache/fhobs``; a private temporary directory if that is not
writable) under a name derived from the source, and loaded with ``ctypes.PyDLL`` so that the GIL
stays held during a step (as for the master's own ctypes calls).
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
from pathlib import Path

from fhobs.core.kernel import cached_library

SOURCE = Path(__file__).resolve().parent / "step_loop.c"
DISABLE_ENV = "FHOBS_HARNESS_PYTHON_LOOP"
CALLS = ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal")


class Gather(ctypes.Structure):
    """``Gather`` of step_loop.c: the connections as rows of (output index, gain) entries."""

    _fields_ = [
        ("n_inputs", ctypes.c_int),
        ("row_start", ctypes.c_void_p),
        ("cols", ctypes.c_void_p),
        ("gains", ctypes.c_void_p),
    ]


class StepFmu(ctypes.Structure):
    """``StepFmu`` of step_loop.c: one FMU's component, entry points and buffers."""

    _fields_ = [
        ("component", ctypes.c_void_p),
        ("set_real", ctypes.c_void_p),
        ("do_step", ctypes.c_void_p),
        ("get_real", ctypes.c_void_p),
        ("in_vr", ctypes.c_void_p),
        ("in_n", ctypes.c_size_t),
        ("in_buf", ctypes.c_void_p),
        ("out_vr", ctypes.c_void_p),
        ("out_n", ctypes.c_size_t),
        ("out_buf", ctypes.c_void_p),
    ]


@functools.cache
def step_library() -> ctypes.CDLL | None:
    """The compiled step_loop.c (``harness_run``), or None (see the module docstring)."""
    if os.environ.get(DISABLE_ENV) or sys.platform != "linux":
        return None
    flags = ("-shared", "-fPIC", "-O2", "-ffp-contract=off")
    return cached_library(SOURCE, "harness_step", flags, (), _open)


def _open(path: Path) -> ctypes.CDLL | None:
    """Load the library and type ``harness_run``."""
    try:
        lib = ctypes.PyDLL(str(path))
        step = lib.harness_run
    except (OSError, AttributeError):
        return None
    step.restype = ctypes.c_int
    step.argtypes = None
    return lib
