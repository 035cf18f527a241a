"""Fixed-step Jacobi co-simulation master over fmpy's ``FMU2Slave``.

Call sequence (the one fmpy's ``simulate_fmu`` uses for setting up, and libcosim's fixed-step
algorithm for stepping)::

    for each FMU: instantiate, setupExperiment(tolerance, t0, t_end), set start values,
                  enterInitializationMode, exitInitializationMode
    outputs(t0) <- getReal
    for k = 0 .. N-1, t_k = t0 + k h (never accumulated):
        inputs  <- M outputs(t_k)        (connections and their gains, row sums)
        for each FMU: setReal(inputs)    (Jacobi: all inputs from the outputs at t_k)
        for each FMU: doStep(t_k, h)
        for each FMU: getReal(outputs)   -> outputs(t_{k+1}), recorded
    for each FMU: terminate, freeInstance

The tolerance is the system's ``[run] tolerance`` (:attr:`harness.system.SystemSpec.tolerance`;
none by default: ``toleranceDefined`` false), for FMUs that integrate internally over a
communication step (a modelling tool's Co-Simulation export: its solver's relative tolerance).

Variables are looked up once (:func:`harness.system.resolve_system`), each FMU file is
extracted once per process (:func:`harness.fmu_files.unzipped`); the step loop calls the
FMUs' C functions directly through ctypes on preallocated buffers that alias one numpy vector
of outputs and one of inputs, so a step costs three C calls per FMU plus the gather and one row
copy; with a C compiler at hand a chunk of steps is made by one ctypes call of a small C
function (:mod:`harness.native`), else from Python. Every FMI status is checked: warnings pass,
anything worse raises :class:`MasterError` naming the FMU, the call, the time and the FMU's own
log messages (every FMU is instantiated with logging on). A failure during the run keeps what
was recorded up to it: the error carries the partial :class:`CoSimResult` (``partial``).

A connection may subtract an offset from its sources and add a bias to its targets
(``to = gain @ (from - offset) + bias``), and add measurement noise to its sources: the
master adds a Gaussian draw to the value it passes on (no block, no step of delay). The draws
are the noise block's (:mod:`harness.blocks.signal_source`: the product's portable generator,
``default_rng([noise_seed, k // 1024])`` uniforms and their Box-Muller Gaussians): the step from
t_k adds draw k of a noise block of p outputs seeded ``noise_seed``, times the standard
deviations, p the noisy sources in the order of the recorded signals
(:attr:`Master.noise_sources`); every connection from one source gets the same draw. So a
``noise`` block with that seed and those sizes (:func:`harness.ssp.lower_gains`) reads out at
t_k exactly what the master adds over the step from t_k. Derived
signals (``[[derived]]`` of :mod:`harness.system`) are computed from the recorded rows after
the run and recorded after the FMUs' signals.

SIGINT and SIGTERM during a run (in the main thread) are deferred: they are noted, never
raised inside an FMU's code, and the run stops after the chunk of steps in progress with a
:class:`MasterError` whose ``interrupted`` is the signal, its ``partial`` every row recorded.
"""

from __future__ import annotations

import ctypes
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from fhobs.errors import FhobsError
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.fmi2 import calloc as _calloc
from fmpy.fmi2 import free as _free

from harness.blocks.signal_source import Draws, gaussian
from harness.fmi3 import Fmi3Slave
from harness.fmu_files import unzipped
from harness.native import CALLS as NATIVE_CALLS
from harness.native import Gather, StepFmu, step_library
from harness.system import ResolvedFmu, ResolvedSystem, check_timing, vector_names

FMI2_WARNING = 1
STATUS_LABELS = ("ok", "warning", "discard", "error", "fatal", "pending")
PROGRESS_CHUNK = 500
LOG_LINES = 3
"""How many of the FMU's last log messages a MasterError quotes."""


class MasterError(FhobsError, RuntimeError):
    """An FMU answered a call with a status worse than warning (or raised in fmpy's wrapper).

    Attributes
    ----------
    slave : str or None
        The FMU's instance name.
    step : int or None
        Index k of the failed step (the one from t_k), None before the first step.
    partial : CoSimResult or None
        The rows recorded before the failure (t_0 .. t_k), when it happened during the run.
    interrupted : int or None
        The signal (``signal.SIGINT``, ``signal.SIGTERM``) that stopped the run, None for a
        failure.
    """

    def __init__(
        self,
        message: str,
        slave: str | None = None,
        step: int | None = None,
        partial: CoSimResult | None = None,
        interrupted: int | None = None,
    ) -> None:
        super().__init__(message)
        self.slave, self.step, self.partial = slave, step, partial
        self.interrupted = interrupted

    def __reduce__(self):  # noqa: ANN204 - keeps the attributes across process pools
        return (type(self), (str(self), self.slave, self.step, self.partial, self.interrupted))


DEFERRED_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals a run defers to the end of its chunk of steps."""


@contextmanager
def deferred_signals() -> Iterator[list[int]]:
    """Note SIGINT and SIGTERM in the yielded list instead of acting on them; the previous
    handlers are back on exit. Outside the main thread (where Python cannot set handlers)
    nothing is deferred and the list stays empty.

    Examples
    --------
    >>> import os
    >>> with deferred_signals() as received:
    ...     os.kill(os.getpid(), signal.SIGINT)
    ...     time.sleep(0.01)
    >>> received == [signal.SIGINT]
    True
    """
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def note(signum: int, frame: object) -> None:
        received.append(signum)

    previous = {signum: signal.signal(signum, note) for signum in DEFERRED_SIGNALS}
    try:
        yield received
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _recording(steps: int, signals: int, name: str) -> np.ndarray:
    """The (steps + 1) x signals array of recorded rows, or a MasterError saying why a run of
    that length cannot be recorded."""
    try:
        return np.empty((steps + 1, signals))
    except (MemoryError, ValueError):
        size = (steps + 1) * max(signals, 1) * 8
        raise MasterError(
            f"system {name!r}: a run of {steps} steps recording {signals} signals needs "
            f"{size / 2**30:.3g} GiB of memory, more than there is; shorten the run, enlarge "
            "the step or record fewer signals"
        ) from None


@dataclass(frozen=True)
class CoSimResult:
    """Recorded outputs: ``values[i, j]`` is signal ``names[j]`` at ``time[i]``."""

    time: np.ndarray
    names: tuple[str, ...]
    values: np.ndarray
    steps: int
    wall_time_s: float

    def signal(self, name: str) -> np.ndarray:
        """Column of the scalar signal ``"fmu.var"``."""
        return self.values[:, self.names.index(name)]

    def vector(self, name: str) -> np.ndarray:
        """Columns (time x elements) of the scalar or vector signal ``"fmu.var"``."""
        fmu, _, var = name.partition(".")
        recorded = {n.partition(".")[2]: n for n in self.names if n.startswith(fmu + ".")}
        cols = [self.names.index(recorded[v]) for v in vector_names(recorded, var)]
        if not cols:
            raise KeyError(f"signal {name!r} was not recorded (have {list(self.names)})")
        return self.values[:, cols]


@dataclass
class _Slave:
    """One instantiated FMU with its raw C entry points and buffers."""

    name: str
    fmu: FMU2Slave
    in_vr: ctypes.Array
    in_buf: ctypes.Array
    out_vr: ctypes.Array
    out_buf: ctypes.Array
    callbacks: fmi2CallbackFunctions
    calls: tuple[ctypes._CFuncPtr, ...] = ()
    """fmi2SetReal, fmi2DoStep, fmi2GetReal as :func:`_raw` entry points."""

    @property
    def comp(self) -> ctypes.c_void_p:
        """The component pointer as a ctypes object."""
        return ctypes.c_void_p(self.fmu.component)

    @property
    def in_n(self) -> ctypes.c_size_t:
        return ctypes.c_size_t(len(self.in_vr))

    @property
    def out_n(self) -> ctypes.c_size_t:
        return ctypes.c_size_t(len(self.out_vr))


def _status(status: int, slave: str, call: str, t: float, step: int | None = None) -> None:
    if status > FMI2_WARNING:
        label = STATUS_LABELS[status] if 0 <= status < len(STATUS_LABELS) else "illegal"
        raise MasterError(
            f"{slave}: {call} at t = {t!r} returned {status} ({label})", slave, step
        )


def _raw(slave: _Slave, function: str) -> ctypes._CFuncPtr:
    """``function`` of the slave's library as a bare entry point: argtypes unset (the caller
    passes ctypes objects only, so nothing is converted), ``int`` status, and the GIL kept
    during the call (``PyDLL``), which spares a Python-based FMU's own ``PyGILState_Ensure``
    from re-acquiring it. An exception left set by the FMU is raised after the call."""
    dll = slave.fmu.dll
    entry = ctypes.PyDLL(dll._name, handle=dll._handle)[function]
    entry.restype = ctypes.c_int
    return entry


def _vrs(values: list[int]) -> ctypes.Array:
    return (ctypes.c_uint * len(values))(*values)


def _alias(arr: np.ndarray, start: int, count: int) -> ctypes.Array:
    """A ctypes double array sharing memory with ``arr[start:start+count]``."""
    return (ctypes.c_double * count).from_address(arr.ctypes.data + 8 * start)


class Connections:
    """The connection matrix as rows of (output index, gain, offset, noise index) entries:
    input i is the sum of ``gain * (outputs[j] - offset + draw)`` over its row's entries, left
    to right, plus its bias; the same sums in the master's Python loop (:meth:`gather`) and
    in its C loop (:attr:`struct`, ``Gather`` of step_loop.c), so that both give the same
    inputs bit for bit.

    Parameters
    ----------
    matrix : np.ndarray
        (inputs x outputs) gains; zero entries are no connection.
    offsets : np.ndarray, optional
        (inputs x outputs) the offset subtracted from output j on its way to input i.
    bias : np.ndarray, optional
        Added to each input.
    noise : np.ndarray, optional
        (inputs x outputs) booleans: whether the entry adds output j's draw.
    std : np.ndarray, optional
        Per output, the standard deviation of its draws (> 0 where an entry adds it).

    Examples
    --------
    >>> c = Connections(np.array([[0.0, 2.0], [1.0, -1.0]]))
    >>> inputs = np.zeros(2)
    >>> c.gather(np.array([3.0, 4.0]), inputs)
    >>> inputs.tolist()
    [8.0, -1.0]
    >>> c = Connections(np.array([[2.0, 0.0]]), offsets=np.array([[1.0, 0.0]]),
    ...                 bias=np.array([0.5]))
    >>> c.gather(np.array([3.0, 4.0]), inputs[:1])
    >>> float(inputs[0])
    4.5
    """

    def __init__(self, matrix: np.ndarray, offsets: np.ndarray | None = None,
                 bias: np.ndarray | None = None, noise: np.ndarray | None = None,
                 std: np.ndarray | None = None) -> None:
        offsets = np.zeros_like(matrix) if offsets is None else offsets
        noise = np.zeros(matrix.shape, dtype=bool) if noise is None else noise
        self.std = np.zeros(matrix.shape[1]) if std is None else np.asarray(std, dtype=float)
        self.noisy = np.flatnonzero(noise.any(axis=0))
        column = {int(j): n for n, j in enumerate(self.noisy)}
        rows = [np.flatnonzero(row) for row in matrix]
        self.entries = [[(int(j), float(matrix[i, j]), float(offsets[i, j]),
                          column[int(j)] if noise[i, j] else -1) for j in cols]
                        for i, cols in enumerate(rows)]
        self.bias = [0.0] * len(rows) if bias is None else [float(b) for b in bias]
        flat = [entry for row in self.entries for entry in row]
        self._row_start = np.cumsum([0] + [len(cols) for cols in rows]).astype(np.intc)
        self._cols = np.array([e[0] for e in flat] or [0], dtype=np.intc)
        self._gains = np.array([e[1] for e in flat] or [0.0])
        self._offsets = np.array([e[2] for e in flat] or [0.0])
        self._noise_index = np.array([e[3] for e in flat] or [-1], dtype=np.intc)
        self._bias = np.array(self.bias or [0.0])
        self._draws = np.zeros((1, max(self.noisy.size, 1)))
        self._source: Draws | None = None
        self.struct = Gather(len(rows), self._row_start.ctypes.data, self._cols.ctypes.data,
                             self._gains.ctypes.data, self._offsets.ctypes.data,
                             self._bias.ctypes.data, self._noise_index.ctypes.data,
                             self._draws.ctypes.data, int(self.noisy.size), 0)

    def draw(self, seed: int, k_from: int, k_to: int) -> np.ndarray:
        """The draws of steps ``k_from .. k_to - 1`` (one row per step, one column per noisy
        output: the noise block's Gaussian numbers of ``seed`` times the standard deviations),
        kept for :meth:`gather` and the C loop."""
        p = self.noisy.size
        if self._source is None or self._source.seed != seed:
            self._source = Draws(seed, p)
        rows = [self._source.row(k) for k in range(k_from, k_to)] if p else []
        normal = np.array([[gaussian(row[c], row[p + c]) for c in range(p)] for row in rows])
        draws = normal.reshape(k_to - k_from, p) * self.std[self.noisy]
        if self.noisy.size:
            self._draws = np.ascontiguousarray(draws)
            self.struct.noise = self._draws.ctypes.data
        self.struct.noise_from = k_from
        return draws

    def gather(self, outputs: np.ndarray, inputs: np.ndarray,
               draws: np.ndarray | None = None) -> None:
        """Write the inputs of the outputs ``outputs`` into ``inputs``; ``draws`` the noise
        draws of this step (a row of :meth:`draw`)."""
        values = outputs.tolist()
        noise = draws.tolist() if draws is not None else []
        for i, row in enumerate(self.entries):
            total = 0.0
            for j, gain, offset, index in row:
                value = values[j] - offset
                if index >= 0:
                    value += noise[index]
                total += gain * value
            inputs[i] = total + self.bias[i]


class Master:
    """Co-simulate a :class:`~harness.system.ResolvedSystem` (see the module docstring)."""

    def __init__(self, system: ResolvedSystem, first_inputs: str = "outputs") -> None:
        """Prepare the exchange for ``system``.

        Parameters
        ----------
        system
            The resolved system.
        first_inputs
            ``"outputs"``: the first step's inputs come from the outputs at ``t0`` (the
            convention, as libcosim does). ``"zero"``: connected inputs are 0 during the first
            step, which is what ``fmpy.ssp.simulation.simulate_ssp`` does; only for comparing
            with it.
        """
        if first_inputs not in ("outputs", "zero"):
            raise ValueError(f"first_inputs must be 'outputs' or 'zero', not {first_inputs!r}")
        self.system = system
        self.first_inputs = first_inputs
        self.names = tuple(
            s for f in system.fmus for s in system.recorded if s.partition(".")[0] == f
        )
        index = {s: j for j, s in enumerate(self.names)}
        inputs = [(f, v) for c in system.connections for f, v in c.targets]
        inputs.sort(key=lambda fv: list(system.fmus).index(fv[0]))
        in_index = {f"{f}.{v.name}": i for i, (f, v) in enumerate(inputs)}
        self.inputs = tuple(f"{f}.{v.name}" for f, v in inputs)
        self.matrix = np.zeros((len(inputs), len(self.names)))
        offsets = np.zeros_like(self.matrix)
        noise = np.zeros(self.matrix.shape, dtype=bool)
        bias, std = np.zeros(len(inputs)), np.zeros(len(self.names))
        for conn in system.connections:
            rows = [in_index[f"{f}.{v.name}"] for f, v in conn.targets]
            cols = [index[f"{f}.{v.name}"] for f, v in conn.sources]
            self.matrix[np.ix_(rows, cols)] += conn.gain
            offsets[np.ix_(rows, cols)] = conn.offset
            bias[rows] = conn.bias
            if conn.noise is not None:
                noise[np.ix_(rows, cols)] = conn.noise > 0.0
                std[cols] = np.maximum(std[cols], conn.noise)
        self.connections = Connections(self.matrix, offsets, bias, noise, std)
        self.derived = tuple(name for d in system.derived for name in d.names)

    @property
    def noise_sources(self) -> dict[str, float]:
        """The noisy sources in the order of the draws' columns, with their standard
        deviations: column c of draw k is the Gaussian number c of a noise block of
        ``len(noise_sources)`` outputs seeded ``noise_seed`` (module docstring)."""
        noisy = self.connections.noisy
        return {self.names[j]: float(self.connections.std[j]) for j in noisy}

    def run(self, stop_time: float | None = None, progress: bool | None = None) -> CoSimResult:
        """Run from the system's start time to ``stop_time`` (default: the system's).

        Parameters
        ----------
        stop_time
            End of the run; the number of steps is ``round((stop_time - t0) / h)``.
        progress
            Show a tqdm bar (it appears after one second); None: only on a terminal.

        Returns
        -------
        CoSimResult
            Rows at ``t_k = t0 + k h`` for ``k = 0 .. steps``.
        """
        spec = self.system.spec
        t0, h = spec.start_time, spec.step
        t_end = spec.stop_time if stop_time is None else stop_time
        steps = check_timing(h, t0, t_end, f"system {spec.name!r}")
        values = _recording(steps, len(self.names), spec.name)
        started = time.perf_counter()
        self._logs: dict[str, deque[str]] = {}
        done = -1  # the last step whose row is recorded (-1: not even t0's)
        try:
            with deferred_signals() as received, self._slaves(t0, t_end) as slaves:
                outputs = np.zeros(len(self.names))
                inputs = np.zeros(len(self.inputs))
                self._bind(slaves, outputs, inputs)
                self._read_outputs(slaves, t0)
                values[0] = outputs
                done = 0
                show = sys.stderr.isatty() if progress is None else progress
                buffers = (values, outputs, inputs)
                for k0 in self._chunks(steps, show):
                    if received:
                        break
                    k1 = min(k0 + PROGRESS_CHUNK, steps)
                    draws = self.connections.draw(spec.noise_seed, k0, k1)
                    if k0 == 0 and self.first_inputs == "zero":
                        unconnected = Connections(np.zeros_like(self.matrix))
                        self._steps(slaves, 0, 1, t0, h, *buffers, unconnected, draws)
                        k0 = 1
                    self._steps(slaves, k0, k1, t0, h, *buffers, self.connections, draws)
                    done = k1
        except MasterError as err:
            raise self._explained(err, values, t0, h, time.perf_counter() - started) from None
        if received:
            err = self._interrupted(received[0], done)
            raise self._explained(err, values, t0, h, time.perf_counter() - started)
        wall = time.perf_counter() - started
        return CoSimResult(t0 + h * np.arange(steps + 1), self.names + self.derived,
                           self._with_derived(values), steps, wall)

    def _with_derived(self, values: np.ndarray) -> np.ndarray:
        """``values`` (rows of the recorded signals) with the derived signals' columns."""
        if not self.derived:
            return values
        columns = [values]
        for d in self.system.derived:
            cols = [self.names.index(f"{f}.{v.name}") for f, v in d.sources]
            columns.append((values[:, cols] - d.offset) @ d.gain.T + d.bias)
        return np.hstack(columns)

    def _interrupted(self, signum: int, done: int) -> MasterError:
        """The MasterError of a run stopped by ``signum`` after step ``done`` (-1: before the
        first row was recorded)."""
        name = signal.Signals(signum).name
        spec = self.system.spec
        if done < 0:
            return MasterError(f"interrupted by {name} before the first step", None, None,
                               None, signum)
        t = spec.start_time + done * spec.step
        return MasterError(f"interrupted by {name} at t = {t!r}", None, done, None, signum)

    def _explained(
        self, err: MasterError, values: np.ndarray, t0: float, h: float, wall: float
    ) -> MasterError:
        """``err`` with the FMU's last log messages (not for an interruption) and the rows
        recorded before it."""
        message = str(err)
        if err.interrupted is None:
            logged = list(self._logs.get(err.slave or "", ()))
            message += ("; the FMU says: " + " | ".join(logged) if logged
                        else "; the FMU logged nothing")
        partial = None
        if err.step is not None:
            k = err.step
            partial = CoSimResult(t0 + h * np.arange(k + 1), self.names + self.derived,
                                  self._with_derived(values[: k + 1].copy()), k, wall)
        return MasterError(message, err.slave, err.step, partial, err.interrupted)

    @staticmethod
    def _chunks(steps: int, show: bool) -> Iterator[int]:
        from tqdm import tqdm

        with tqdm(total=steps, unit="step", delay=1.0, disable=not show) as bar:
            for k0 in range(0, steps, PROGRESS_CHUNK):
                yield k0
                bar.update(min(PROGRESS_CHUNK, steps - k0))

    def _steps(
        self,
        slaves: list[_Slave],
        k_from: int,
        k_to: int,
        t0: float,
        h: float,
        values: np.ndarray,
        outputs: np.ndarray,
        inputs: np.ndarray,
        connections: Connections,
        draws: np.ndarray,
    ) -> None:
        """Steps ``k_from .. k_to - 1`` with inputs gathered by ``connections`` (``draws``
        the noise draws of the chunk, from :meth:`Connections.draw`): the hot loop.

        When :func:`harness.native.step_library` is available, one call of its ``harness_run``
        makes the steps (gather, the nine FMI calls of each step, the recorded row); else the
        C functions are called from Python through :func:`_raw` entry points (GIL kept, no
        argtypes) with every argument already a ctypes object, only the time changing from
        step to step, written into one ``c_double``.
        """
        native = step_library()
        if native is not None:
            self._native_steps(native, slaves, k_from, k_to, t0, h, values, outputs, inputs,
                               connections)
            return
        first = connections.struct.noise_from
        t_c = ctypes.c_double(0.0)
        h_c = ctypes.c_double(h)
        no_set_prior = ctypes.c_int(1)
        setters = [
            (s.calls[0], s.comp, s.in_vr, s.in_n, s.in_buf, s.name) for s in slaves if len(s.in_vr)
        ]
        steppers = [(s.calls[1], s.comp, s.name) for s in slaves]
        getters = [
            (s.calls[2], s.comp, s.out_vr, s.out_n, s.out_buf, s.name)
            for s in slaves
            if len(s.out_vr)
        ]
        gather = connections.gather
        for k in range(k_from, k_to):
            t = t0 + k * h
            t_c.value = t
            gather(outputs, inputs, draws[k - first])
            for set_real, comp, vr, n, buf, name in setters:
                if status := set_real(comp, vr, n, buf):
                    _status(status, name, "fmi2SetReal", t, k)
            for do_step, comp, name in steppers:
                if status := do_step(comp, t_c, h_c, no_set_prior):
                    _status(status, name, "fmi2DoStep", t, k)
            for get_real, comp, vr, n, buf, name in getters:
                if status := get_real(comp, vr, n, buf):
                    _status(status, name, "fmi2GetReal", t + h, k)
            values[k + 1] = outputs

    @staticmethod
    def _native_steps(
        native: ctypes.CDLL,
        slaves: list[_Slave],
        k_from: int,
        k_to: int,
        t0: float,
        h: float,
        values: np.ndarray,
        outputs: np.ndarray,
        inputs: np.ndarray,
        connections: Connections,
    ) -> None:
        """:meth:`_steps` by one call of ``harness_run`` (``step_loop.c``): the same gathers
        and calls, in the same order, on the same buffers."""
        fmus = (StepFmu * len(slaves))()
        for f, s in zip(fmus, slaves, strict=True):
            f.component = s.fmu.component
            f.set_real, f.do_step, f.get_real = (
                ctypes.cast(call, ctypes.c_void_p).value for call in s.calls
            )
            f.in_vr, f.in_n = ctypes.addressof(s.in_vr), len(s.in_vr)
            f.out_vr, f.out_n = ctypes.addressof(s.out_vr), len(s.out_vr)
            f.in_buf, f.out_buf = ctypes.addressof(s.in_buf), ctypes.addressof(s.out_buf)
        assert values.flags.c_contiguous and values.shape[1] == outputs.size
        failed = (ctypes.c_int * 2)()
        failed_step = ctypes.c_long(0)
        status = native.harness_run(
            fmus, ctypes.c_int(len(slaves)), ctypes.byref(connections.struct),
            ctypes.c_void_p(outputs.ctypes.data), ctypes.c_void_p(inputs.ctypes.data),
            ctypes.c_int(outputs.size), ctypes.c_void_p(values.ctypes.data),
            ctypes.c_long(k_from), ctypes.c_long(k_to), ctypes.c_double(t0), ctypes.c_double(h),
            failed, ctypes.byref(failed_step))
        if status:
            k = failed_step.value
            t = t0 + k * h
            call = NATIVE_CALLS[failed[1]]
            _status(status, slaves[failed[0]].name, call, t + h if failed[1] == 2 else t, k)

    @staticmethod
    def _read_outputs(slaves: list[_Slave], t: float) -> None:
        for s in slaves:
            if len(s.out_vr):
                _status(
                    s.fmu.dll.fmi2GetReal(s.fmu.component, s.out_vr, len(s.out_vr), s.out_buf),
                    s.name,
                    "fmi2GetReal",
                    t,
                )

    def _bind(self, slaves: list[_Slave], outputs: np.ndarray, inputs: np.ndarray) -> None:
        """Point every slave's buffers at its slices of ``outputs`` and ``inputs``."""
        for s in slaves:
            out = [j for j, n in enumerate(self.names) if n.partition(".")[0] == s.name]
            inp = [i for i, n in enumerate(self.inputs) if n.partition(".")[0] == s.name]
            if out:
                s.out_buf = _alias(outputs, out[0], len(out))
            if inp:
                s.in_buf = _alias(inputs, inp[0], len(inp))

    @contextmanager
    def _slaves(self, t0: float, t_end: float) -> Iterator[list[_Slave]]:
        """Instantiated and initialised slaves; terminated and freed on exit."""
        slaves: list[_Slave] = []
        try:
            for name, rf in self.system.fmus.items():
                slaves.append(self._instantiate(name, rf, t0, t_end))
            for s in slaves:
                _checked(s.name, "fmi2EnterInitializationMode", t0, s.fmu.enterInitializationMode)
            for s in slaves:
                _checked(s.name, "fmi2ExitInitializationMode", t0, s.fmu.exitInitializationMode)
            yield slaves
            for s in slaves:
                s.fmu.terminate()
        finally:
            for s in slaves:
                s.fmu.freeInstance()

    def _instantiate(self, name: str, rf: ResolvedFmu, t0: float, t_end: float) -> _Slave:
        md = rf.description
        unzip_dir = unzipped(rf.spec.path)
        if md.fmiVersion == "3.0":  # its arrays' elements as scalars (harness.fmi3)
            log = self._logs.setdefault(name, deque(maxlen=LOG_LINES))
            fmu, callbacks = Fmi3Slave(md, unzip_dir, name, t0, t_end, log.append), None
        else:
            fmu = FMU2Slave(
                guid=md.guid,
                unzipDirectory=unzip_dir,
                instanceName=name,
                modelIdentifier=md.coSimulation.modelIdentifier,
            )
            callbacks = self._callbacks(name)
        try:
            if callbacks is None:
                _checked(name, "fmi3InstantiateCoSimulation", t0, fmu.instantiate)
            else:
                _checked(name, "fmi2Instantiate", t0, fmu.instantiate, callbacks=callbacks,
                         loggingOn=True)
                _checked(name, "fmi2SetupExperiment", t0, fmu.setupExperiment,
                         tolerance=self.system.spec.tolerance, startTime=t0, stopTime=t_end)
            _checked(name, "setting the start values", t0, _set_start_values, fmu, rf)
        except Exception:
            if getattr(fmu, "component", None):
                fmu.freeInstance()
            raise
        out_vr = [
            rf.variables[n.partition(".")[2]].valueReference
            for n in self.names
            if n.partition(".")[0] == name
        ]
        in_vr = [
            rf.variables[n.partition(".")[2]].valueReference
            for n in self.inputs
            if n.partition(".")[0] == name
        ]
        empty = (ctypes.c_double * 0)()
        slave = _Slave(name, fmu, _vrs(in_vr), empty, _vrs(out_vr), empty, callbacks)
        slave.calls = tuple(_raw(slave, call) for call in NATIVE_CALLS)
        return slave

    def _callbacks(self, name: str) -> fmi2CallbackFunctions:
        """FMI callbacks whose logger keeps the FMU's messages in ``self._logs[name]``."""
        log = self._logs.setdefault(name, deque(maxlen=LOG_LINES))

        def logger(env, instance, status, category, message) -> None:  # noqa: ANN001
            log.append(message.decode("utf-8", "replace") if message else "")

        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(logger)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(_calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(_free)
        return callbacks


def _checked(slave: str, call: str, t: float, function, *args, **kwargs) -> None:  # noqa: ANN001
    """Call one of fmpy's checked wrappers; its exception becomes a MasterError."""
    try:
        function(*args, **kwargs)
    except MasterError:
        raise
    except Exception as err:  # noqa: BLE001 - fmpy raises plain Exception and FMICallException
        status = getattr(err, "status", None)
        if isinstance(status, int):
            label = STATUS_LABELS[status] if 0 <= status < len(STATUS_LABELS) else "illegal"
            what = f"returned {status} ({label})"
        else:
            what = f"failed ({err})"
        raise MasterError(f"{slave}: {call} at t = {t!r} {what}", slave) from err


def _set_start_values(fmu: FMU2Slave, rf: ResolvedFmu) -> None:
    """Set the system's start values (fmpy raises on a status worse than warning)."""
    for var, value in rf.spec.start.items():
        v = rf.variables[var]
        if v.type == "Real":
            fmu.setReal([v.valueReference], [float(value)])
        elif v.type == "Boolean":
            fmu.setBoolean([v.valueReference], [bool(value)])
        else:
            fmu.setInteger([v.valueReference], [int(value)])


def run_system(
    system: ResolvedSystem,
    stop_time: float | None = None,
    progress: bool | None = None,
    first_inputs: str = "outputs",
) -> CoSimResult:
    """Shorthand for ``Master(system, first_inputs).run(stop_time, progress)``.

    Examples
    --------
    With the pendulum's FMUs built into ``build/pendulum`` (see :func:`resolve_system`):

    >>> from harness.cli import SCENARIO_DIR
    >>> from harness.system import load_system, resolve_system
    >>> spec = load_system(SCENARIO_DIR / "pendulum_nominal.toml", {"fmu_dir": "build/pendulum"})
    >>> result = run_system(resolve_system(spec), stop_time=0.1)  # doctest: +SKIP
    >>> result.steps, result.vector("observer.x_hat").shape  # doctest: +SKIP
    (2000, (2001, 4))
    """
    return Master(system, first_inputs).run(stop_time, progress)
