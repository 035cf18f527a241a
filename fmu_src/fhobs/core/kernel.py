"""The compiled step kernel (``kernel.c``) of the runtime, through ctypes.

The numpy runtime (:mod:`fhobs.core.runtime`, :mod:`fhobs.core.plant`,
:mod:`fhobs.core.kalman_filter`) is the reference implementation; when this kernel is available, the
models make their common step in C instead: the plant's ZOH step (the noise stays numpy's), the
split step and the explicit Euler substeps of the Luenberger and the filtering observers, the
split step of the prescribed-time observer, the Kalman filter's cycles. The numpy side prepares
everything (matrices, eigen-decompositions, gain-level floor and ceiling) once per design and
step size, in a *plan*, and the kernel only does the per-step arithmetic, to about 1e-15
relative of the numpy step (the matrix-vector sums may be added in another order than numpy's
BLAS).

Where the library comes from (:func:`library`), in this order:

- ``kernel_linux64.so`` next to this file: inside an FMU, where :mod:`fhobs.build` compiled it
  when the FMU was built (linux64 only);
- otherwise, on Linux with ``cc`` or ``gcc``, ``kernel.c`` compiled on first use into the user's
  cache directory (``$XDG_CACHE_HOME/fhobs`` or ``~/.cache/fhobs``, a private temporary
  directory if that is not writable), under a name derived from the source;
- none (the numpy runtime alone): on another platform, without a compiler, when compiling or
  loading fails, when the environment variable ``FHOBS_NO_KERNEL`` is set (non-empty), or when
  a model is made with ``kernel=False``.

State. The kernel never writes a model's state in place: :class:`Stepper` keeps two buffers,
the state arrays of the model are views of one of them, and a step writes the other one, which
then becomes the state. A model thus *replaces* its state arrays in every step, as the numpy
runtime does, so a caller that keeps references to them (the FMU slaves' rollback) and
``get_state``/``set_state`` work unchanged.

This module is numpy-only (plus the standard library): it runs inside the FMUs.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

import numpy as np

from .cache_files import cache_unusable, check_private, is_elf, trusted

SOURCE = Path(__file__).resolve().with_name("kernel.c")
HEADER = SOURCE.with_name("kernel.h")
"""The kernel's declarations (plans, scratch sizes, shared helpers), included by kernel.c."""
SHIPPED = Path(__file__).resolve().with_name("kernel_linux64.so")
"""The library inside an FMU (compiled by :mod:`fhobs.build`)."""
DISABLE_ENV = "FHOBS_NO_KERNEL"
COMPILE_FLAGS = ("-O2", "-shared", "-fPIC", "-ffp-contract=off")
"""No contraction into fused multiply-adds: each product is rounded, as in numpy."""
LIBRARY_FLAGS = (*COMPILE_FLAGS, "-DFHOBS_EXPORT")
"""The kernel compiled alone for ctypes: its step functions exported (kernel.h's FHOBS_HIDDEN
hides them inside a native FMU)."""
OK, NONFINITE = 0, 2
"""Return codes of the kernel's step functions (``kernel.c``)."""
PLAN_CACHE_SIZE = 16
"""Plans are cached per step size; the cache is cleared when it holds this many."""

_DOUBLE_P = ctypes.POINTER(ctypes.c_double)
T = TypeVar("T")


class PlantPlan(ctypes.Structure):
    """``PlantPlan`` of kernel.c."""

    _fields_ = [("n", ctypes.c_int), ("m", ctypes.c_int), ("r", ctypes.c_int),
                ("Phi", _DOUBLE_P), ("Gamma_B", _DOUBLE_P), ("Gamma_E", _DOUBLE_P)]


class LinearPlan(ctypes.Structure):
    """``LinearPlan`` of kernel.c."""

    _fields_ = [("n", ctypes.c_int), ("k", ctypes.c_int), ("m", ctypes.c_int),
                ("cycles", ctypes.c_int), ("M", _DOUBLE_P), ("work", _DOUBLE_P)]


class FilterPlan(ctypes.Structure):
    """``FilterPlan`` of kernel.c (complex arrays as interleaved doubles)."""

    _fields_ = [("n", ctypes.c_int), ("k", ctypes.c_int), ("m", ctypes.c_int),
                ("real_lam", ctypes.c_int),
                ("nu", ctypes.c_double), ("gamma", ctypes.c_double), ("p", ctypes.c_double),
                ("dt", ctypes.c_double), ("floor_level", ctypes.c_double),
                ("ceiling", ctypes.c_double), ("mismatch", ctypes.c_double),
                ("tiny", ctypes.c_double), ("series", ctypes.c_double),
                ("C", _DOUBLE_P), ("M", _DOUBLE_P), ("F", _DOUBLE_P),
                ("V_inv", _DOUBLE_P), ("V_k", _DOUBLE_P), ("WL", _DOUBLE_P), ("V_g", _DOUBLE_P),
                ("g", _DOUBLE_P), ("lam", _DOUBLE_P), ("factors", _DOUBLE_P),
                ("last_tau", _DOUBLE_P), ("work", _DOUBLE_P), ("cwork", _DOUBLE_P)]


class EulerPlan(ctypes.Structure):
    """``EulerPlan`` of kernel.c (complex arrays as interleaved doubles)."""

    _fields_ = [("n", ctypes.c_int), ("k", ctypes.c_int), ("m", ctypes.c_int),
                ("n_sub", ctypes.c_int), ("homogeneous", ctypes.c_int), ("real_g", ctypes.c_int),
                ("hs", ctypes.c_double), ("nu", ctypes.c_double), ("gamma", ctypes.c_double),
                ("p", ctypes.c_double), ("guard", ctypes.c_double),
                ("A", _DOUBLE_P), ("B", _DOUBLE_P), ("C", _DOUBLE_P), ("L_inj", _DOUBLE_P),
                ("L_tilde", _DOUBLE_P), ("V_d", _DOUBLE_P), ("inverse_L", _DOUBLE_P),
                ("g", _DOUBLE_P), ("work", _DOUBLE_P), ("cwork", _DOUBLE_P)]


def kalman_work_size(n: int, k: int) -> int:
    """Scratch doubles of the Kalman filter's ``LinearPlan`` (``FHOBS_KALMAN_WORK``)."""
    return 2 * n


def filter_work_size(n: int, k: int) -> tuple[int, int]:
    """Scratch doubles and complex numbers of a ``FilterPlan`` (``FHOBS_FILTER_WORK``,
    ``FHOBS_FILTER_CWORK``).

    Examples
    --------
    >>> filter_work_size(5, 2)
    (15, 17)
    """
    return 2 * n + 2 * k + 1, n + 6 * k


def euler_work_size(n: int, k: int) -> tuple[int, int]:
    """Scratch doubles and complex numbers of an ``EulerPlan`` (``FHOBS_EULER_WORK``,
    ``FHOBS_EULER_CWORK``): two substep states of n + k + 1 and the rates."""
    return 7 * n + 4 * k + 2, n


class PrescribedPlan(ctypes.Structure):
    """``PrescribedPlan`` of kernel.c (complex arrays as interleaved doubles)."""

    _fields_ = [("n", ctypes.c_int), ("k", ctypes.c_int), ("m", ctypes.c_int),
                ("real_lam", ctypes.c_int),
                ("nu", ctypes.c_double), ("rho", ctypes.c_double), ("dt", ctypes.c_double),
                ("floor_level", ctypes.c_double), ("ceiling", ctypes.c_double),
                ("tiny", ctypes.c_double), ("series", ctypes.c_double),
                ("C", _DOUBLE_P), ("M", _DOUBLE_P), ("F", _DOUBLE_P),
                ("Q_inv", _DOUBLE_P), ("Q_V", _DOUBLE_P), ("lam", _DOUBLE_P),
                ("V_g", _DOUBLE_P), ("g", _DOUBLE_P), ("inverse_L", _DOUBLE_P),
                ("factors", _DOUBLE_P), ("last_tau", _DOUBLE_P), ("work", _DOUBLE_P)]


def prescribed_work_size(n: int, k: int) -> int:
    """Scratch doubles of a ``PrescribedPlan`` (``FHOBS_PRESCRIBED_WORK`` of kernel.c).

    Examples
    --------
    >>> prescribed_work_size(2, 1)
    10
    """
    return 4 * k + 3 * n


def library() -> ctypes.PyDLL | None:
    """The loaded kernel, or None when the numpy runtime must do without (module docstring).

    Examples
    --------
    >>> lib = library()
    >>> lib is None or hasattr(lib, "fhobs_filter_step")
    True
    """
    if os.environ.get(DISABLE_ENV):
        return None
    return _load()


@functools.cache
def _load() -> ctypes.PyDLL | None:
    """Load the shipped library, else compile the source into the cache (once per process)."""
    if sys.platform != "linux":
        return None
    if SHIPPED.exists():
        return _open(SHIPPED)
    return cached_library(SOURCE, "fhobs_kernel", LIBRARY_FLAGS, ("-lm",), _open,
                          depends=(HEADER,))


def cached_library(source: Path, prefix: str, flags: tuple[str, ...], libs: tuple[str, ...],
                   open_library: Callable[[Path], T | None],
                   depends: tuple[Path, ...] = ()) -> T | None:
    """``open_library`` of ``source`` compiled by :func:`cached_build`; None without a
    compiler or when the compilation fails.

    Examples
    --------
    >>> lib = cached_library(SOURCE, "fhobs_kernel", LIBRARY_FLAGS, ("-lm",), _open)
    >>> lib is None or hasattr(lib, "fhobs_plant_step")
    True
    """
    try:
        path = cached_build(source, prefix, flags, libs, depends)
    except (OSError, subprocess.SubprocessError):
        return None
    return None if path is None else open_library(path)


def cached_build(source: Path, prefix: str, flags: tuple[str, ...], libs: tuple[str, ...] = (),
                 depends: tuple[Path, ...] = ()) -> Path | None:
    """``source`` compiled with ``cc`` (or ``gcc``) into :func:`cache_dir`, under a name that
    hashes the source (and the headers ``depends``), the flags, the compiler and the machine,
    so that it is compiled once per machine; into a private temporary folder when the cache
    cannot be written. None without a compiler.

    Raises
    ------
    OSError, subprocess.SubprocessError
        If the compiler fails.

    Examples
    --------
    >>> path = cached_build(SOURCE, "fhobs_kernel", LIBRARY_FLAGS, ("-lm",))
    >>> path is None or path.suffix == ".so"
    True
    """
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None or not source.exists():
        return None
    tag = hashlib.sha256(b"".join(path.read_bytes() for path in (source, *depends))
                         + " ".join(flags).encode()
                         + compiler.encode() + platform.machine().encode()).hexdigest()
    name = f"{prefix}_{tag[:16]}.so"
    try:
        path = cache_dir() / name
    except OSError:
        path = None
    if path is not None and trusted(path, is_elf):
        return path
    if path is not None:
        try:
            compile_source(source, path, compiler, flags, libs)
            return path
        except (OSError, subprocess.SubprocessError) as err:
            failure = err  # the cache's fault only if a private folder does better
    private = Path(tempfile.mkdtemp(prefix=f"{prefix}_"))  # kept: the library is in use
    compile_source(source, private / name, compiler, flags, libs)
    if path is not None:
        cache_unusable(path.parent, _reason(failure))
    return private / name


def _reason(err: BaseException) -> str:
    """A compiler's or the file system's complaint in one line."""
    detail = getattr(err, "stderr", None) or err
    if isinstance(detail, bytes):
        detail = detail.decode(errors="replace")
    return " ".join(str(detail).split())


def _open(path: Path) -> ctypes.PyDLL | None:
    """Load the library (GIL held during calls: they are short) and type its functions."""
    try:
        lib = ctypes.PyDLL(str(path))
        for name in ("fhobs_plant_step", "fhobs_luenberger_step", "fhobs_kalman_step",
                     "fhobs_filter_step", "fhobs_euler_step", "fhobs_prescribed_step"):
            function = getattr(lib, name)
            function.restype = ctypes.c_int
            function.argtypes = None  # called with ctypes objects only: nothing to convert
    except (OSError, AttributeError):
        return None
    return lib


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/fhobs`` (default ``~/.cache/fhobs``), created private to the user: where
    compiled helpers (this kernel, the harness's step loop) are kept.

    Raises
    ------
    OSError
        If the folder cannot be used (a file in its place, not writable, not private to the
        user: :func:`fhobs.core.cache_files.check_private`); logged once
        (:func:`fhobs.core.cache_files.cache_unusable`), the caller does without the cache.
    """
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    path = Path(base) / "fhobs"
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        check_private(path)
        if not os.access(path, os.W_OK | os.X_OK):
            raise PermissionError(f"{path} is not writable")
    except OSError as err:
        cache_unusable(path, err)
        raise
    return path


def compile_source(source: Path | tuple[Path, ...], target: Path, compiler: str,
                   flags: tuple[str, ...], libs: tuple[str, ...] = ()) -> None:
    """Compile a C ``source`` (or several, linked together) into the shared library ``target``
    (written under another name, then renamed, so that concurrent processes never load a
    partial file).

    Raises
    ------
    OSError, subprocess.SubprocessError
        If the compiler fails or cannot be run.

    Examples
    --------
    >>> compile_source(SOURCE, Path("build/kernel.so"), "cc", COMPILE_FLAGS)  # doctest: +SKIP
    """
    sources = (source,) if isinstance(source, Path) else source
    with replaced_atomically(target) as partial:
        subprocess.run([compiler, *flags, "-o", str(partial), *map(str, sources), *libs],
                       check=True, capture_output=True, timeout=120)


@contextlib.contextmanager
def replaced_atomically(target: Path) -> Iterator[Path]:
    """A new path beside ``target`` for the block to write (hidden, ending in ``.tmp``: no
    reader of ``*.json``, ``*.csv`` or ``*.pickle`` takes it); renamed over ``target`` when the
    block ends, removed if it raises: concurrent processes never see a partial file.

    Examples
    --------
    >>> folder = Path(tempfile.mkdtemp())
    >>> with replaced_atomically(folder / "a.txt") as partial:
    ...     _ = partial.write_text("whole")
    >>> (folder / "a.txt").read_text(), [p.name for p in folder.iterdir()]
    ('whole', ['a.txt'])
    """
    handle, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(handle)
    partial = Path(name)
    try:
        yield partial
        os.replace(partial, target)
    finally:
        partial.unlink(missing_ok=True)


def pointer(array: np.ndarray) -> ctypes._Pointer:
    """A ``double *`` to a C-contiguous float64 or complex128 array (kept alive by the caller).

    Examples
    --------
    >>> values = np.array([1.0, 2.0])
    >>> pointer(values)[1]
    2.0
    """
    assert array.flags.c_contiguous and array.dtype in (np.float64, np.complex128)
    return ctypes.cast(array.ctypes.data, _DOUBLE_P)


class Call(ctypes.Structure):
    """``Call`` of kernel.c: the one argument of a step function (plan, state read, state
    written, inputs)."""

    _fields_ = [("plan", ctypes.c_void_p), ("src", ctypes.c_void_p), ("dst", ctypes.c_void_p),
                ("inputs", ctypes.c_void_p)]


class StepperHandle(ctypes.Structure):
    """``StepperHandle`` of kernel.h: a model's stepper as a loop in C drives it (step function,
    its two calls, the two state buffers, the input buffer, the state's size)."""

    _fields_ = [("step", ctypes.c_void_p), ("calls", ctypes.c_void_p * 2),
                ("buffers", ctypes.c_void_p * 2), ("inputs", ctypes.c_void_p),
                ("size", ctypes.c_int)]


class Stepper:
    """Two state buffers, an input buffer and the per-step-size plans of one model.

    Parameters
    ----------
    function : ctypes function
        The kernel's step function ``f(call)``.
    sizes : tuple of int
        Sizes of the model's state arrays, stored one after the other in each buffer.
    inputs : tuple of int
        Sizes of the two inputs held over a step, one after the other in the input buffer.
    make_plan : callable
        ``make_plan(dt)`` prepares the plan of a step size at its first use and registers it
        with :meth:`add_plan` (it may raise ValueError: the step is then refused).

    Attributes
    ----------
    state : tuple of np.ndarray
        The state arrays written by the last successful :meth:`run` (views of a buffer).

    Examples
    --------
    As :class:`fhobs.core.plant.LTIPlant` uses it (``make_plan`` registers a ``PlantPlan``)::

        stepper = Stepper(library().fhobs_plant_step, (n,), (m, r), make_plan)
        if stepper.run(dt, x, x, u, q) == OK:
            x = stepper.state[0]
    """

    def __init__(self, function, sizes: tuple[int, ...], inputs: tuple[int, int],
                 make_plan) -> None:
        self._function = function
        self._make_plan = make_plan
        self._buffers = [np.zeros(sum(sizes)), np.zeros(sum(sizes))]
        self._views = [_split(buffer, sizes) for buffer in self._buffers]
        self._input_buffer = np.zeros(max(sum(inputs), 1))
        self._in_a, self._in_b = _split(self._input_buffer, inputs)
        self._first = [views[0] for views in self._views]
        self._last = [views[-1] for views in self._views]
        self._calls: dict[float, tuple[ctypes.c_void_p, ctypes.c_void_p]] = {}
        self._kept: dict[float, tuple] = {}
        self.state = self._views[0]

    def add_plan(self, dt: float, plan: ctypes.Structure, *arrays: np.ndarray) -> None:
        """Register the plan of step size dt (``arrays``: what its pointers point into, kept
        alive with it)."""
        if len(self._calls) >= PLAN_CACHE_SIZE:
            self._calls.clear()
            self._kept.clear()
        ends = [buffer.ctypes.data for buffer in self._buffers]
        inputs = self._input_buffer.ctypes.data
        structs = [Call(ctypes.addressof(plan), ends[side], ends[1 - side], inputs)
                   for side in (0, 1)]
        self._kept[dt] = (plan, arrays, structs)
        self._calls[dt] = tuple(ctypes.c_void_p(ctypes.addressof(c)) for c in structs)

    def plan(self, dt: float) -> tuple[ctypes.Structure, tuple[np.ndarray, ...]]:
        """The plan of step size dt and the arrays its pointers point into, made at its first
        use as :meth:`run` makes it (ValueError if the model refuses the step size)."""
        if dt not in self._kept:
            self._make_plan(dt)
        plan, arrays, _ = self._kept[dt]
        return plan, arrays

    def handle(self, dt: float, *state: np.ndarray) -> StepperHandle:
        """The stepper for a loop in C that makes its steps of size dt (``StepperHandle``): the
        plan of dt made as :meth:`run` makes it (ValueError if the model refuses the step
        size), the arrays of ``state`` copied into buffer 0, where the loop's first step reads
        them. Valid while this stepper lives and plans no other step size. The loop's steps
        write both buffers: the model's own state arrays must not be views of them (the
        models' ``kernel_handle`` detaches them first).

        Examples
        --------
        A plant's stepper, for a loop in C that steps the plant from its state x::

            handle = stepper.handle(dt, x)      # x in buffers[0]: the first step is side 0
        """
        self.plan(dt)
        for view, array in zip(self._views[0], state, strict=True):
            view[...] = array
        calls = [call.value for call in self._calls[dt]]
        buffers = [buffer.ctypes.data for buffer in self._buffers]
        return StepperHandle(ctypes.cast(self._function, ctypes.c_void_p).value, tuple(calls),
                             tuple(buffers), self._input_buffer.ctypes.data,
                             self._buffers[0].size)

    def run(self, dt: float, first: np.ndarray, last: np.ndarray, a: np.ndarray,
            b: np.ndarray) -> int:
        """Step the state whose arrays are ``first`` ... ``last`` (the same for a one-array
        state) by dt with the inputs ``a``, ``b`` held; the kernel's return code, the new
        state in :attr:`state` when it is ``OK``.

        The state is read from the buffer whose views ``first`` and ``last`` are, and the other
        buffer is written: the arrays of the state before the step are never written by it. A
        state held elsewhere (after ``set_state``, or a rollback to it) is first copied into
        buffer 0 (then not the state: its arrays stay as they are).
        """
        calls = self._calls.get(dt)
        if calls is None:
            self._make_plan(dt)
            calls = self._calls[dt]
        self._in_a[...] = a
        self._in_b[...] = b
        if first is self._first[0] and last is self._last[0]:
            side = 0
        elif first is self._first[1] and last is self._last[1]:
            side = 1
        else:
            side = 0
            for view, array in zip(self._views[0], (first, last), strict=False):
                view[...] = array
        code = self._function(calls[side])
        if code == OK:
            self.state = self._views[1 - side]
        return code


def _split(buffer: np.ndarray, sizes: tuple[int, ...]) -> tuple[np.ndarray, ...]:
    """Consecutive views of ``buffer`` of the given sizes."""
    bounds = np.cumsum((0,) + tuple(sizes)).tolist()
    return tuple(buffer[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True))
