"""The master's step in C (``step_loop.c``), compiled on first use with the system C compiler.

:func:`step_library` returns the loaded library, or None when it cannot be had (no ``cc`` or
``gcc``, not Linux, a failed compilation, ``FHOBS_HARNESS_PYTHON_LOOP`` set): the master then
makes the same calls from Python. The library is cached in the user's cache directory
(``$XDG_CACHE_HOME/fhobs`` or ``~/.cache/fhobs``; a private temporary directory if that is not
writable) under a name derived from the source, and loaded with ``ctypes.PyDLL`` so that the GIL
stays held during a step (as for the master's own ctypes calls).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from fhobs.kernel import cache_dir

SOURCE = Path(__file__).resolve().parent / "step_loop.c"
DISABLE_ENV = "FHOBS_HARNESS_PYTHON_LOOP"
CALLS = ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal")


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
    """The compiled step_loop.c (``harness_step``), or None (see the module docstring)."""
    if os.environ.get(DISABLE_ENV) or sys.platform != "linux" or not SOURCE.exists():
        return None
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        return None
    source = SOURCE.read_bytes()
    tag = hashlib.sha256(source + compiler.encode() + platform.machine().encode()).hexdigest()
    name = f"harness_step_{tag[:16]}.so"
    private = None  # a temporary directory, removed once the library is loaded
    try:
        library = cache_dir() / name
        if not library.exists():
            _compile(compiler, library)
    except (OSError, subprocess.SubprocessError):
        private = tempfile.mkdtemp(prefix="fhobs_harness_")
        library = Path(private) / name
        try:
            _compile(compiler, library)
        except (OSError, subprocess.SubprocessError):
            shutil.rmtree(private, ignore_errors=True)
            return None
    try:
        lib = ctypes.PyDLL(str(library))
        step = lib.harness_step
    except (OSError, AttributeError):
        return None
    finally:
        if private is not None:
            shutil.rmtree(private, ignore_errors=True)
    step.restype = ctypes.c_int
    step.argtypes = None
    return lib


def _compile(compiler: str, library: Path) -> None:
    """Compile step_loop.c into ``library`` (written under another name, then renamed, so that
    concurrent processes never load a partial file)."""
    fd, partial = tempfile.mkstemp(suffix=".so", dir=library.parent)
    os.close(fd)
    try:
        subprocess.run(
            [compiler, "-shared", "-fPIC", "-O2", "-o", partial, str(SOURCE)],
            check=True, capture_output=True, timeout=60,
        )
        os.replace(partial, library)
    finally:
        if os.path.exists(partial):
            os.unlink(partial)
