"""The harness's loops in C, compiled on first use with the system C compiler: the master's step
(``step_loop.c``) and the in-process reference loop (``reference_loop.c``).

:func:`step_library` and :func:`reference_library` return the loaded library, or None when it
cannot be had (no ``cc`` or ``gcc``, not Linux, a failed compilation,
``FHOBS_HARNESS_PYTHON_LOOP`` set): the master then makes the same calls from Python (and
gathers the inputs with the same sums, so both loops give the same results bit for bit), the
reference loop steps its models from Python. The libraries are cached in the user's cache
directory (``$XDG_CACHE_HOME/fhobs`` or ``~/.cache/fhobs``; a private temporary directory if that
is not writable) under a name derived from the source, and loaded with ``ctypes.PyDLL`` so that
the GIL stays held during a call (as for the master's own ctypes calls).
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
from collections.abc import Callable
from pathlib import Path

from fhobs.core.kernel import HEADER as KERNEL_HEADER
from fhobs.core.kernel import StepperHandle, cached_library

SOURCE = Path(__file__).resolve().parent / "step_loop.c"
REFERENCE_SOURCE = SOURCE.with_name("reference_loop.c")
FLAGS = ("-shared", "-fPIC", "-O2", "-ffp-contract=off")
DISABLE_ENV = "FHOBS_HARNESS_PYTHON_LOOP"
CALLS = ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal")


class Gather(ctypes.Structure):
    """``Gather`` of step_loop.c: the connections as rows of (output index, gain, offset,
    noise index) entries, a bias per input and the noise draws of a chunk of steps."""

    _fields_ = [
        ("n_inputs", ctypes.c_int),
        ("row_start", ctypes.c_void_p),
        ("cols", ctypes.c_void_p),
        ("gains", ctypes.c_void_p),
        ("offsets", ctypes.c_void_p),
        ("bias", ctypes.c_void_p),
        ("noise_index", ctypes.c_void_p),
        ("noise", ctypes.c_void_p),
        ("n_noise", ctypes.c_int),
        ("noise_from", ctypes.c_long),
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
    return cached_library(SOURCE, "harness_step", FLAGS, (), _opener("harness_run"))


class ReferenceLoop(ctypes.Structure):
    """``ReferenceLoop`` of reference_loop.c: sizes, matrices, eta and q, the models."""

    _fields_ = [
        ("n_steps", ctypes.c_long),
        ("n", ctypes.c_int),
        ("k", ctypes.c_int),
        ("m", ctypes.c_int),
        ("r", ctypes.c_int),
        ("feedback_state", ctypes.c_int),
        ("C", ctypes.c_void_p),
        ("K", ctypes.c_void_p),
        ("eta", ctypes.c_void_p),
        ("q", ctypes.c_void_p),
        ("plant", ctypes.POINTER(StepperHandle)),
        ("observer", ctypes.POINTER(StepperHandle)),
        ("others", ctypes.POINTER(StepperHandle)),
        ("n_others", ctypes.c_int),
    ]


class ReferenceRecord(ctypes.Structure):
    """``ReferenceRecord`` of reference_loop.c: where the loop writes the trajectories."""

    _fields_ = [(name, ctypes.c_void_p) for name in ("x", "observer", "others", "y", "u")]


@functools.cache
def reference_library() -> ctypes.CDLL | None:
    """The compiled reference_loop.c (``reference_run``), or None (see the module docstring)."""
    if os.environ.get(DISABLE_ENV) or sys.platform != "linux":
        return None
    flags = (*FLAGS, f"-I{KERNEL_HEADER.parent}")
    return cached_library(REFERENCE_SOURCE, "harness_reference", flags, (),
                          _opener("reference_run"), depends=(KERNEL_HEADER,))


def _opener(function: str) -> Callable[[Path], ctypes.CDLL | None]:
    """The loader of a library whose entry point is ``function`` (returning int)."""

    def load(path: Path) -> ctypes.CDLL | None:
        try:
            lib = ctypes.PyDLL(str(path))
            entry = getattr(lib, function)
        except (OSError, AttributeError):
            return None
        entry.restype = ctypes.c_int
        entry.argtypes = None
        return lib

    return load
