"""Declarative system description (TOML): FMUs, start values, connections, run settings.

A description is loaded with :func:`load_system` into a :class:`SystemSpec` (plain data, paths
resolved, nothing built), its harness blocks are built with :func:`build_blocks`, and it is
checked against the FMUs' model descriptions with :func:`resolve_system`, which
returns a :class:`ResolvedSystem`: every variable looked up once, every connection as a pair of
scalar variable lists with its gain matrix. All problems raise :class:`DescriptionError` with a
message naming the FMU, the variable and what was expected.

File format (all keys except ``fmus`` optional)::

    extends = "pendulum_nominal.toml"     # optional: start from that file (relative to this
                                          # one) and change it: tables merge key by key,
                                          # [[connections]] are appended (an input they connect
                                          # loses the start value the base gave it), other
                                          # values replace
    name = "pendulum_perturbed"
    [variables]                      # ${NAME} placeholders in FMU paths; overridable by callers
    fmu_dir = "../../build/pendulum"
    [run]
    step = 5e-5
    stop_time = 3.0
    seed = "plant.noise_seed"        # the start value that --seed sets
    noise_seed = 0                   # the seed of the master's connection noise (--seed too)
    tolerance = 1e-10                # optional: the relative tolerance every FMU gets in
                                     # fmi2SetupExperiment (an exported model's internal
                                     # solver); none by default (toleranceDefined false)
    record = ["plant.x", "observer.x_hat"]   # extra signals; connected outputs are always kept
    [fmus.plant]
    path = "${fmu_dir}/plant.fmu"    # relative to this file
    start = { x0 = [2, 2, 1, 2], noise_amplitude = 0.0 }   # list -> x0[1..4]; matrix -> K[i,j]
    [fmus.q]
    block = "sine"                   # a harness block (harness.blocks), built on demand
    outputs = 1                      # block dimensions: outputs (sine); outputs, inputs (gain)
    start = { amplitude = [0.1], omega = [5.0] }
    [[connections]]
    from = "observer.x_hat"          # a vector name expands to x_hat[1..n], or one scalar;
                                     # a list of signals is their concatenation; outputs or
                                     # local Real variables (a model's states)
    to = "plant.u"
    gain = [[2, -35, 1.5, -3]]       # optional: to = gain @ from, applied by the master
    offset = [0, 0, 0, 0]            # optional, per source: to = gain @ (from - offset) + bias
    bias = [0.5]                     # optional, per target
    noise = [0.01]                   # optional, per source: the std of a Gaussian draw the
                                     # master adds to the source before the gain (no block, no
                                     # delay); one draw per source and communication step,
                                     # shared by every connection from that source: the
                                     # noise block's portable generator (harness.blocks.
                                     # signal_source), draw k of a block seeded noise_seed
                                     # (module docstring of harness.master), so an exported
                                     # SSP's noise block draws the same numbers
    [[derived]]                      # a signal the master computes from recorded ones, no FMU:
    from = ["a.i", "b.phi"]          # the same keys as a connection but noise; recorded as
    to = "deviation.x"               # deviation.x[1..2] (its element, "deviation", is no FMU)
    offset = [0.0, 1.5]              # and usable as an [evaluation.errors] reference
    [evaluation]                     # summary.json figures, see harness.results
    at = [1.5]
    windows = [[1.0, 3.0]]
    converged = [1e-3]               # optional: time_to_1e-3, the time the error settles
    peak = true                      # optional: peak, the error's peak over its start
    floor = 1.0                      # optional: floor, the error over the last 1 s
    [evaluation.errors]
    homogeneous = ["plant.x", "observer.x_hat"]   # error = ||first - second||
    [plots]                          # optional: the paper-style figure of harness.figures
    figure = "perturbed"             # its scenario key (title: the paper's Figure 2)
    [plots.signals]                  # harness.reference.SimulationResult field -> signal
    x = "plant.x"                    # likewise z, z_lin, psi, xi, sigma

A value written as the string ``"${paper.NAME}"`` (anywhere but in FMU paths) is the paper's
number of that name from :mod:`fhobs.paper` (``PAPER_VALUES``): ``paper.K``, ``paper.x0``,
``paper.step``, and ``paper.SCENARIO.q_amplitude`` / ``q_frequency`` / ``noise_amplitude``
for the scenarios ``nominal``, ``perturbed``, ``perturbed_noisy``; the bundled scenarios take
the paper's set-up from there.

Inputs must each be connected exactly once or given a start value (a constant input). Start
values go to parameters, inputs and locals with ``initial`` exact or approx, never outputs.
Connections carry Real signals only. Algebraic loops: under the Jacobi exchange no loop passes
through ``doStep``, and connection gains are applied in one exchange, so a loop can only arise
through FMUs that *declare* direct feedthrough (``<Outputs><Unknown dependencies=...>`` naming an
input). A cycle made only of declared feedthrough and connections is rejected, because its value
would depend on the exchange scheme. The fhobs FMUs declare that their outputs depend on no
input (``dependencies=""``) and the gain block that each output depends on every input; an
FMU that declares nothing (pythonfmu writes no dependencies) is not assumed to feed through.
"""

from __future__ import annotations

import re
import string
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from fhobs.design.spec import unknown_key_text
from fhobs.errors import FhobsError
from fhobs.paper import H_PAPER, K_PAPER, PAPER_SCENARIOS, X0_PAPER
from fmpy.model_description import ModelDescription, ScalarVariable

from harness.blocks import BLOCK_KINDS, block_fmu
from harness.blocks.build import native_by_default
from harness.fmi3 import element_variables
from harness.fmu_files import description

StartValue = float | int | bool
PAPER_VALUES: dict[str, Any] = {
    "paper.K": K_PAPER.tolist(), "paper.x0": X0_PAPER.tolist(), "paper.step": H_PAPER,
    **{f"paper.{name}.{field}": getattr(scenario, field)
       for name, scenario in PAPER_SCENARIOS.items()
       for field in ("q_amplitude", "q_frequency", "noise_amplitude")},
}
"""The paper's set-up by name, for ``"${paper.NAME}"`` values (module docstring)."""
_PAPER_VALUE = re.compile(r"\$\{(paper\.[A-Za-z0-9_.]+)\}")
TOP_KEYS = ("extends", "name", "variables", "run", "fmus", "connections", "derived",
            "evaluation", "plots")
RUN_KEYS = ("step", "stop_time", "start_time", "seed", "noise_seed", "tolerance", "record")
CONNECTION_KEYS = ("from", "to", "gain", "offset", "bias", "noise")
READABLE = ("output", "local")
"""The causalities a connection, a record or an error may read (Real variables)."""
EVALUATION_KEYS = ("at", "windows", "converged", "peak", "floor", "errors")
MAX_STEPS = 10**9
"""The most communication steps of one run (every step is a recorded row)."""
PLOTS_KEYS = ("figure", "signals")


class DescriptionError(FhobsError, ValueError):
    """An invalid system description (message names the offending item)."""


@dataclass(frozen=True)
class FmuSpec:
    """One FMU of the system: its file (None for a harness block not built yet, see
    :func:`build_blocks`) and its start values (scalar variable names)."""

    name: str
    path: Path | None
    start: dict[str, StartValue] = field(default_factory=dict)
    block: tuple[str, tuple[int, ...]] | None = None
    shapes: dict[str, tuple[int, ...]] = field(default_factory=dict)


@dataclass(frozen=True)
class ConnectionSpec:
    """``to = gain @ (from - offset + noise) + bias`` between vector or scalar signals
    ``"fmu.variable"``; ``source`` one signal or a tuple of them (concatenated); ``offset``
    and ``noise`` (standard deviations) per source scalar, ``bias`` per target scalar."""

    source: str | tuple[str, ...]
    target: str
    gain: np.ndarray | None = None
    offset: np.ndarray | None = None
    bias: np.ndarray | None = None
    noise: np.ndarray | None = None

    @property
    def sources(self) -> tuple[str, ...]:
        """The source signals as a tuple."""
        return (self.source,) if isinstance(self.source, str) else tuple(self.source)

    def __str__(self) -> str:
        return f"{' + '.join(self.sources)} -> {self.target}"


@dataclass(frozen=True)
class Evaluation:
    """What the summary figures are made of (:mod:`harness.results`): instants, windows, the
    relative tolerances of the settling times (``converged``), whether to give the peak, the
    length of the final stretch of the floor (s, or None), and the named error signals
    (reference, estimate)."""

    at: tuple[float, ...] = ()
    windows: tuple[tuple[float, float], ...] = ()
    converged: tuple[float, ...] = ()
    peak: bool = False
    floor: float | None = None
    errors: dict[str, tuple[str, str]] = field(default_factory=dict)


@dataclass(frozen=True)
class FigureSpec:
    """A paper-style figure: harness.figures scenario key and the signals of its fields."""

    scenario: str
    signals: dict[str, str]


@dataclass(frozen=True)
class SystemSpec:
    """A loaded system description (see the module docstring for the file format)."""

    name: str
    fmus: dict[str, FmuSpec]
    connections: tuple[ConnectionSpec, ...]
    step: float
    stop_time: float
    start_time: float = 0.0
    record: tuple[str, ...] = ()
    seed: str | None = None
    evaluation: Evaluation = field(default_factory=Evaluation)
    figure: FigureSpec | None = None
    source: Path | None = None
    derived: tuple[ConnectionSpec, ...] = ()
    noise_seed: int = 0
    tolerance: float | None = None

    def with_start(self, overrides: dict[str, StartValue]) -> SystemSpec:
        """Copy with start values ``{"fmu.variable": value}`` overriding the file's."""
        fmus = dict(self.fmus)
        for key, value in overrides.items():
            fmu, var = split_signal(key)
            if fmu not in fmus:
                raise DescriptionError(
                    f"start value {key!r}: unknown FMU {fmu!r} (have {sorted(fmus)})"
                )
            spec = fmus[fmu]
            start = {**spec.start, **expand_start(var, value)}
            shapes = {**spec.shapes, **start_shape(var, value)}
            fmus[fmu] = replace(spec, start=start, shapes=shapes)
        return replace(self, fmus=fmus)

    def with_seed(self, seed: int) -> SystemSpec:
        """Copy with the start value named by ``run.seed`` and the master's noise seed
        (``noise_seed``) set to ``seed``."""
        noisy = any(c.noise is not None for c in self.connections)
        if self.seed is None and not noisy:
            raise DescriptionError(
                f"system {self.name!r} names no seed variable ([run] seed = ...) and has no "
                "noisy connection"
            )
        spec = self if self.seed is None else self.with_start({self.seed: int(seed)})
        return replace(spec, noise_seed=int(seed))


def split_signal(signal: str) -> tuple[str, str]:
    """``"fmu.var[1]"`` -> ``("fmu", "var[1]")``."""
    fmu, sep, var = signal.partition(".")
    if not sep or not fmu or not var:
        raise DescriptionError(f"signal {signal!r} is not of the form 'fmu.variable'")
    return fmu, var


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def real_number(value: Any, where: str) -> float:
    """``value`` as a float, or DescriptionError naming ``where`` if it is not a finite number."""
    if not _is_number(value) or not np.isfinite(value):
        raise DescriptionError(f"{where} = {value!r} is not a finite number")
    return float(value)


def number_matrix(value: Any, where: str) -> np.ndarray:
    """A vector (list of numbers) or a matrix (list of equal-length rows) of finite numbers.

    Raises
    ------
    DescriptionError
        Naming ``where`` and the first entry that is not a finite number, or the ragged shape.
    """
    if isinstance(value, list) and value and all(isinstance(r, list) for r in value):
        if any(not r or len(r) != len(value[0]) for r in value):
            raise DescriptionError(f"{where} = {value!r}: rows are empty or of unequal length")
        for i, row in enumerate(value, start=1):
            for j, v in enumerate(row, start=1):
                real_number(v, f"{where}[{i},{j}]")
    elif isinstance(value, list) and value:
        for i, v in enumerate(value, start=1):
            real_number(v, f"{where}[{i}]")
    else:
        raise DescriptionError(
            f"{where} = {value!r} is not a non-empty list of numbers or of equal-length rows"
        )
    return np.array(value, dtype=float)


def start_shape(name: str, value: Any) -> dict[str, tuple[int, ...]]:
    """``{name: shape}`` for a vector or matrix start value, ``{}`` for a scalar."""
    return {name: np.shape(value)} if isinstance(value, list) else {}


def expand_start(name: str, value: Any) -> dict[str, StartValue]:
    """Scalar start values from a scalar, a vector (``x[i]``) or a matrix (``K[i,j]``)."""
    if isinstance(value, list):
        arr = number_matrix(value, f"start value {name}")
        if arr.ndim == 1:
            return {f"{name}[{i + 1}]": float(v) for i, v in enumerate(arr)}
        if arr.ndim == 2:
            return {
                f"{name}[{i + 1},{j + 1}]": float(arr[i, j])
                for i in range(arr.shape[0])
                for j in range(arr.shape[1])
            }
        raise DescriptionError(f"start value {name!r}: only scalars, vectors and matrices")
    if not isinstance(value, bool | int | float):
        raise DescriptionError(f"start value {name!r}: {value!r} is not a number or boolean")
    return {name: value}


def load_system(path: str | Path, variables: dict[str, str] | None = None) -> SystemSpec:
    """Load a system description TOML file.

    Parameters
    ----------
    path
        The TOML file; relative FMU paths are relative to its directory.
    variables
        Values for ``${NAME}`` placeholders in FMU paths, overriding ``[variables]``.

    Returns
    -------
    SystemSpec

    Examples
    --------
    >>> from harness.cli import SCENARIO_DIR
    >>> spec = load_system(SCENARIO_DIR / "pendulum_perturbed.toml", {"fmu_dir": "/opt/fmus"})
    >>> spec.name, sorted(spec.fmus), spec.step
    ('pendulum_perturbed', ['kalman', 'linear', 'observer', 'perturbation', 'plant'], 5e-05)
    >>> str(spec.fmus["plant"].path), spec.fmus["perturbation"].block
    ('/opt/fmus/plant.fmu', ('sine', (1,)))
    """
    path = Path(path)
    where = str(path)
    data = _with_paper_values(_read_description(path, ()), where)
    _reject_unknown(data, TOP_KEYS, where)
    subst = {**_strings(data, "variables", where), **(variables or {})}
    run = _table(data, "run", where)
    _reject_unknown(run, RUN_KEYS, f"{where}: [run]")
    fmu_tables = _table(data, "fmus", where)
    fmus = {
        name: _fmu_spec(name, _table(fmu_tables, name, f"{where}: [fmus]"), path.parent, subst)
        for name in fmu_tables
    }
    if not fmus:
        raise DescriptionError(f"{path}: no [fmus.NAME] tables")
    connections = data.get("connections", [])
    if not isinstance(connections, list) or not all(isinstance(c, dict) for c in connections):
        raise DescriptionError(f"{where}: connections must be [[connections]] tables")
    step, start_time, stop_time = (
        real_number(run.get(key, default), f"{where}: run.{key}")
        for key, default in (("step", 1e-3), ("start_time", 0.0), ("stop_time", 1.0))
    )
    check_timing(step, start_time, stop_time, f"{where}: [run]")
    evaluation = parse_evaluation(_table(data, "evaluation", where), f"{where}: [evaluation]")
    outside = evaluation_outside(evaluation, start_time, stop_time)
    if outside:
        raise DescriptionError(
            f"{where}: [evaluation] {outside[0]} lies outside the run [{start_time:g}, "
            f"{stop_time:g}] s of [run]: it would have no figures; change it or run.stop_time"
        )
    seed = run.get("seed")
    if seed is not None and not isinstance(seed, str):
        raise DescriptionError(f"{where}: run.seed = {seed!r} must name a variable ('fmu.var')")
    noise_seed = run.get("noise_seed", 0)
    if isinstance(noise_seed, bool) or not isinstance(noise_seed, int) or noise_seed < 0:
        raise DescriptionError(f"{where}: run.noise_seed = {noise_seed!r} must be an integer "
                               ">= 0")
    tolerance = run.get("tolerance")
    if tolerance is not None:
        tolerance = run_tolerance(tolerance, f"{where}: run.tolerance")
    derived = _list(data, "derived", where)
    if not all(isinstance(d, dict) for d in derived):
        raise DescriptionError(f"{where}: derived must be [[derived]] tables")
    return SystemSpec(
        name=_string(data.get("name", path.stem), f"{where}: name"),
        fmus=fmus,
        connections=tuple(_connection_spec(c, f"{where}: connection {i}")
                          for i, c in enumerate(connections, start=1)),
        step=step,
        stop_time=stop_time,
        start_time=start_time,
        record=tuple(_string(r, f"{where}: run.record") for r in _list(run, "record", where)),
        seed=seed,
        evaluation=evaluation,
        figure=_figure_spec(_table(data, "plots", where), f"{where}: [plots]"),
        source=path,
        derived=tuple(_connection_spec(d, f"{where}: derived {i}", derived=True)
                      for i, d in enumerate(derived, start=1)),
        noise_seed=noise_seed,
        tolerance=tolerance,
    )


def _read_description(path: Path, extending: tuple[Path, ...]) -> dict[str, Any]:
    """The TOML data of ``path``, merged onto the description it ``extends`` (recursively);
    ``extending`` are the files that extend this one (a cycle is an error)."""
    extended = f" (extended by {extending[-1]})" if extending else ""
    if path.is_dir():
        raise DescriptionError(f"system description {path} is a folder, not a file{extended}: "
                               "give a .toml system description or a bundled scenario's name")
    if not path.is_file():
        raise DescriptionError(f"system description {path} does not exist{extended}")
    try:
        with path.open("rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as err:
        raise DescriptionError(f"{path}: invalid TOML: {err}") from None
    except UnicodeDecodeError as err:
        raise DescriptionError(
            f"system description {path}{extended} is not a text file: byte {err.start} "
            f"(0x{err.object[err.start]:02x}) is not UTF-8 text; a system description is a "
            "TOML text file"
        ) from None
    base = data.pop("extends", None)
    if base is None:
        return data
    if not isinstance(base, str):
        raise DescriptionError(f"{path}: extends = {base!r} must name a description file")
    base_path = (path.parent / base).resolve()
    if base_path in (*extending, path.resolve()):
        raise DescriptionError(f"{path}: extends {base} which extends it again (a cycle)")
    base_data = _read_description(base_path, (*extending, path.resolve()))
    return _merged(_without_connected_starts(base_data, data, str(path)), data, str(path))


def _with_paper_values(value: Any, where: str) -> Any:
    """``value`` with every string ``"${paper.NAME}"`` in it replaced by ``PAPER_VALUES``."""
    if isinstance(value, dict):
        return {key: _with_paper_values(item, where) for key, item in value.items()}
    if isinstance(value, list):
        return [_with_paper_values(item, where) for item in value]
    match = _PAPER_VALUE.fullmatch(value) if isinstance(value, str) else None
    if match is None:
        return value
    if match.group(1) not in PAPER_VALUES:
        raise DescriptionError(f"{where}: {value} is not one of the paper's values "
                               f"({', '.join(sorted(PAPER_VALUES))})")
    return PAPER_VALUES[match.group(1)]


def _without_connected_starts(base: dict[str, Any], changes: dict[str, Any],
                              where: str) -> dict[str, Any]:
    """``base`` without the start values of the inputs that ``changes`` connects: a constant
    input of the base becomes a connected one (within one file, both stay an error)."""
    fmus = dict(_table(base, "fmus", where))
    for entry in _list(changes, "connections", where):
        target = entry.get("to") if isinstance(entry, dict) else None
        if not isinstance(target, str) or "." not in target:
            continue  # reported when the connection is read
        fmu, var = split_signal(target)
        table = fmus.get(fmu)
        if isinstance(table, dict) and isinstance(table.get("start"), dict):
            fmus[fmu] = {**table, "start": {key: value for key, value in table["start"].items()
                                            if not _same_input(key, var)}}
    return {**base, "fmus": fmus}


def _same_input(a: str, b: str) -> bool:
    """Whether two names of a description (``q``, ``q[1]``) denote a common scalar."""
    return a == b or a.startswith(b + "[") or b.startswith(a + "[")


def _merged(base: dict[str, Any], changes: dict[str, Any], where: str) -> dict[str, Any]:
    """``base`` changed by ``changes``: tables merged key by key, connections appended, any
    other value replaced."""
    merged = dict(base)
    for key, value in changes.items():
        if key == "connections":
            merged[key] = [*_list(base, key, where), *_list(changes, key, where)]
        elif isinstance(value, dict) and isinstance(base.get(key), dict):
            merged[key] = _merged(base[key], value, where)
        else:
            merged[key] = value
    return merged


def build_blocks(spec: SystemSpec, block_cache: Path | None = None,
                 native: bool | None = None) -> SystemSpec:
    """Copy of ``spec`` whose harness blocks have their FMU files (built on first use).

    Parameters
    ----------
    spec : SystemSpec
        A loaded description.
    block_cache : Path or None
        Where the blocks are built (default: :func:`harness.blocks.default_cache_dir`).
    native : bool or None
        Native blocks (compiled C, :mod:`harness.blocks.native`: every kind has one) (True),
        pythonfmu blocks (False), or (None) native ones when none of the system's own FMUs is a
        pythonfmu FMU (:func:`harness.blocks.build.native_by_default`): a system of native
        FMUs then needs no Python in any FMU.

    Returns
    -------
    SystemSpec
        Every FMU with a path.

    Examples
    --------
    >>> import tempfile
    >>> from harness.cli import SCENARIO_DIR
    >>> spec = load_system(SCENARIO_DIR / "pendulum_perturbed.toml")
    >>> with tempfile.TemporaryDirectory() as cache:
    ...     built = build_blocks(spec, Path(cache), native=False)
    ...     print(spec.fmus["perturbation"].path, built.fmus["perturbation"].path.suffix)
    None .fmu
    """
    if native is None:
        native = native_by_default(fs.path for fs in spec.fmus.values()
                                   if fs.block is None and fs.path is not None)
    fmus = {name: fs if fs.block is None or fs.path is not None
            else replace(fs, path=block_fmu(*fs.block, block_cache, native=native))
            for name, fs in spec.fmus.items()}
    return replace(spec, fmus=fmus)


def run_tolerance(value: Any, where: str) -> float:
    """``value`` as a run's tolerance (the relative tolerance of ``fmi2SetupExperiment``): a
    number in (0, 1); DescriptionError naming ``where`` otherwise.

    Examples
    --------
    >>> run_tolerance(1e-10, "run.tolerance")
    1e-10
    >>> run_tolerance(0, "run.tolerance")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    harness.system.DescriptionError: run.tolerance = 0 must be a number in (0, 1): ...
    """
    if not _is_number(value) or not 0.0 < value < 1.0:
        raise DescriptionError(f"{where} = {value!r} must be a number in (0, 1): the relative "
                               "tolerance of the FMUs' solvers")
    return float(value)


def check_timing(step: float, start_time: float, stop_time: float, where: str) -> int:
    """The number of steps of a run; DescriptionError unless it is a positive integer.

    Parameters
    ----------
    step, start_time, stop_time
        The communication step h, t0 and t_end.
    where
        Named in the message (the file, or the command-line options).

    Returns
    -------
    int
        ``N = (t_end - t0) / h`` (to 1e-9 relative).

    Raises
    ------
    DescriptionError
        If h <= 0, t_end <= t0, t_end - t0 is not a whole number of steps or more than
        ``MAX_STEPS`` of them.

    Examples
    --------
    >>> check_timing(0.1, 0.0, 1.0, "run")
    10
    """
    for name, value in (("step", step), ("start_time", start_time), ("stop_time", stop_time)):
        if not np.isfinite(value):
            raise DescriptionError(f"{where}: {name} = {value!r} is not finite")
    if step <= 0.0:
        raise DescriptionError(f"{where}: step = {step!r} must be > 0")
    if stop_time <= start_time:
        raise DescriptionError(
            f"{where}: stop_time = {stop_time!r} must be after start_time = {start_time!r}"
        )
    count = (stop_time - start_time) / step
    if count > MAX_STEPS:
        raise DescriptionError(
            f"{where}: stop_time - start_time = {stop_time - start_time:g} s at step = "
            f"{step:g} s is {count:.3g} steps, more than a run can record (at most "
            f"{MAX_STEPS:.0e}); shorten the run or enlarge the step"
        )
    steps = int(round(count))
    if steps < 1 or abs(start_time + steps * step - stop_time) > 1e-9 * max(1.0, abs(stop_time)):
        raise DescriptionError(
            f"{where}: step = {step!r} does not divide stop_time - start_time = "
            f"{stop_time - start_time!r} into a whole number of steps"
        )
    return steps


def evaluation_outside(evaluation: Evaluation, start_time: float, stop_time: float) -> list[str]:
    """The ``[evaluation]`` instants, windows and floor stretch that do not lie within
    ``[start_time, stop_time]`` (to 1e-9 relative), as they are written in the file.

    Parameters
    ----------
    evaluation
        The instants (``at``) and windows of the figures.
    start_time, stop_time
        The run's t0 and t_end.

    Returns
    -------
    list of str
        ``"at = 10"``, ``"window [1, 3]"``, ...; empty if every entry lies within the run.

    Examples
    --------
    >>> ev = Evaluation(at=(1.5, 10.0), windows=((1.0, 3.0),))
    >>> evaluation_outside(ev, 0.0, 3.0)
    ['at = 10']
    >>> evaluation_outside(ev, 0.0, 0.05)
    ['at = 1.5', 'at = 10', 'window [1, 3]']
    >>> evaluation_outside(Evaluation(floor=2.0), 0.0, 1.5)
    ['floor = 2']
    """
    tol = 1e-9 * max(1.0, abs(start_time), abs(stop_time))

    def inside(t: float) -> bool:
        return start_time - tol <= t <= stop_time + tol

    floor = evaluation.floor
    return ([f"at = {t:g}" for t in evaluation.at if not inside(t)]
            + [f"window [{a:g}, {b:g}]" for a, b in evaluation.windows
               if not (inside(a) and inside(b))]
            + ([f"floor = {floor:g}"] if floor is not None and not inside(stop_time - floor)
               else []))


def _reject_unknown(table: dict[str, Any], allowed: tuple[str, ...], where: str) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise DescriptionError(f"{where}: {unknown_key_text(unknown[0], allowed, quote=True)}")


def _table(data: dict[str, Any], key: str, where: str) -> dict[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise DescriptionError(f"{where}: {key} must be a table, got {value!r}")
    return value


def _list(data: dict[str, Any], key: str, where: str) -> list[Any]:
    value = data.get(key, [])
    if not isinstance(value, list):
        raise DescriptionError(f"{where}: {key} must be a list, got {value!r}")
    return value


def _string(value: Any, where: str) -> str:
    if not isinstance(value, str):
        raise DescriptionError(f"{where} = {value!r} must be a string")
    return value


def _strings(data: dict[str, Any], key: str, where: str) -> dict[str, str]:
    return {k: _string(v, f"{where}: {key}.{k}") for k, v in _table(data, key, where).items()}


def parse_evaluation(ev: dict[str, Any], where: str) -> Evaluation:
    """An ``[evaluation]`` table (module docstring) as an :class:`Evaluation`.

    Raises
    ------
    DescriptionError
        Naming ``where`` and the entry: an unknown key, a value of the wrong kind, a window
        that is not ``[start, end]`` with start < end, a tolerance or a floor length <= 0.

    Examples
    --------
    >>> parse_evaluation({"converged": [1e-3], "floor": 1}, "[evaluation]")
    Evaluation(at=(), windows=(), converged=(0.001,), peak=False, floor=1.0, errors={})
    >>> parse_evaluation({"peak": 1}, "[evaluation]")
    Traceback (most recent call last):
    ...
    harness.system.DescriptionError: [evaluation]: peak = 1 must be true or false
    """
    _reject_unknown(ev, EVALUATION_KEYS, where)
    at = tuple(real_number(t, f"{where} at") for t in _list(ev, "at", where))
    windows = []
    for w in _list(ev, "windows", where):
        if not (isinstance(w, list) and len(w) == 2):
            raise DescriptionError(f"{where}: window {w!r} is not a pair [start, end]")
        a, b = (real_number(t, f"{where}: window {w!r}") for t in w)
        if not a < b:
            raise DescriptionError(f"{where}: window {w!r} must have start < end")
        windows.append((a, b))
    errors = {}
    for name, pair in _table(ev, "errors", where).items():
        pair_ok = isinstance(pair, list) and len(pair) == 2
        if not (pair_ok and all(isinstance(x, str) for x in pair)):
            raise DescriptionError(
                f"{where}: errors.{name} = {pair!r} is not a pair of signals [reference, estimate]"
            )
        errors[name] = (pair[0], pair[1])
    converged = tuple(_positive(t, f"{where}: converged") for t in _list(ev, "converged", where))
    peak = ev.get("peak", False)
    if not isinstance(peak, bool):
        raise DescriptionError(f"{where}: peak = {peak!r} must be true or false")
    floor = None if "floor" not in ev else _positive(ev["floor"], f"{where}: floor")
    return Evaluation(at=at, windows=tuple(windows), converged=converged, peak=peak,
                      floor=floor, errors=errors)


def _positive(value: Any, where: str) -> float:
    """``value`` as a float, or DescriptionError unless it is a finite number > 0."""
    number = real_number(value, where)
    if not number > 0.0:
        raise DescriptionError(f"{where} = {value!r} must be > 0")
    return number


def override_evaluation(evaluation: Evaluation, table: dict[str, Any], where: str) -> Evaluation:
    """``evaluation`` with each entry that the ``[evaluation]`` table ``table`` gives replaced
    by the table's (:func:`parse_evaluation`); the others kept.

    Examples
    --------
    >>> ev = Evaluation(at=(1.5,), windows=((1.0, 3.0),))
    >>> override_evaluation(ev, {"converged": [1e-3], "at": []}, "sweep")
    Evaluation(at=(), windows=((1.0, 3.0),), converged=(0.001,), peak=False, floor=None, errors={})
    """
    given = parse_evaluation(table, where)
    return replace(evaluation, **{key: getattr(given, key) for key in table})


def _figure_spec(entry: dict[str, Any], where: str) -> FigureSpec | None:
    _reject_unknown(entry, PLOTS_KEYS, where)
    if "figure" not in entry:
        return None
    return FigureSpec(
        _string(entry["figure"], f"{where} figure"), _strings(entry, "signals", where)
    )


def _fmu_spec(name: str, entry: dict[str, Any], base: Path, subst: dict[str, str]) -> FmuSpec:
    where = f"FMU {name!r}"
    start: dict[str, StartValue] = {}
    shapes: dict[str, tuple[int, ...]] = {}
    for var, value in _table(entry, "start", where).items():
        start.update(expand_start(var, value))
        shapes.update(start_shape(var, value))
    if "block" in entry:
        kind = entry["block"]
        if kind not in BLOCK_KINDS:
            raise DescriptionError(
                f"FMU {name!r}: unknown block {kind!r} (have {sorted(BLOCK_KINDS)})"
            )
        keys = tuple(d.removeprefix("n_") for d in BLOCK_KINDS[kind].dimensions)
        _reject_unknown(entry, ("block", "start", *keys), where)
        dims = tuple(_dimension(entry, key, where) for key in keys)
        return FmuSpec(name, None, start, (kind, dims), shapes)
    _reject_unknown(entry, ("path", "start"), where)
    if "path" not in entry:
        raise DescriptionError(f"FMU {name!r}: needs 'path' or 'block'")
    try:
        raw = string.Template(_string(entry["path"], f"{where}: path")).substitute(subst)
    except KeyError as err:
        raise DescriptionError(
            f"FMU {name!r}: path {entry['path']!r} uses undefined {err}"
        ) from None
    return FmuSpec(name, (base / raw).resolve(), start, shapes=shapes)


def _dimension(entry: dict[str, Any], key: str, where: str) -> int:
    value = entry.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise DescriptionError(f"{where}: {key} = {value!r} must be a positive integer")
    return value


def _connection_spec(entry: dict[str, Any], where: str, derived: bool = False) -> ConnectionSpec:
    _reject_unknown(entry, CONNECTION_KEYS[:-1] if derived else CONNECTION_KEYS, where)
    try:
        source, target = entry["from"], entry["to"]
    except KeyError as err:
        raise DescriptionError(f"{where} {entry!r} lacks {err}") from None
    if isinstance(source, list) and source:
        source = tuple(_string(s, f"{where}: from") for s in source)
    else:
        source = _string(source, f"{where}: from")
    target = _string(target, f"{where}: to")
    arrays = {}
    for key in ("gain", "offset", "bias", "noise"):
        if entry.get(key) is not None:
            value = number_matrix(entry[key], f"{where} (-> {target}): {key}")
            if key != "gain" and value.ndim != 1:
                raise DescriptionError(f"{where} (-> {target}): {key} must be a list of "
                                       "numbers, one per scalar")
            arrays[key] = np.atleast_2d(value) if key == "gain" else value
    if "noise" in arrays and np.any(arrays["noise"] < 0.0):
        raise DescriptionError(f"{where} (-> {target}): noise = {entry['noise']!r} must be "
                               "standard deviations >= 0")
    return ConnectionSpec(source, target, **arrays)


# ---------------------------------------------------------------- resolution against the FMUs


@dataclass(frozen=True)
class ResolvedFmu:
    """An FMU with its model description and its variables by name."""

    spec: FmuSpec
    description: ModelDescription
    variables: dict[str, ScalarVariable]


@dataclass(frozen=True)
class ResolvedConnection:
    """Scalar sources and targets of one connection, its gain, offset, bias and noise,
    ``targets = gain @ (sources - offset + noise) + bias`` (``noise``: the standard deviations
    per source, None for a connection without noise)."""

    sources: tuple[tuple[str, ScalarVariable], ...]
    targets: tuple[tuple[str, ScalarVariable], ...]
    gain: np.ndarray
    offset: np.ndarray
    bias: np.ndarray
    noise: np.ndarray | None = None


@dataclass(frozen=True)
class ResolvedDerived:
    """A derived signal (``[[derived]]``): ``names = gain @ (sources - offset) + bias``, its
    scalar names ``"element.var[i]"``."""

    sources: tuple[tuple[str, ScalarVariable], ...]
    names: tuple[str, ...]
    gain: np.ndarray
    offset: np.ndarray
    bias: np.ndarray


@dataclass(frozen=True)
class ResolvedSystem:
    """A system checked against its FMUs: everything the master needs, looked up once."""

    spec: SystemSpec
    fmus: dict[str, ResolvedFmu]
    connections: tuple[ResolvedConnection, ...]
    recorded: tuple[str, ...]  # scalar "fmu.var" outputs recorded, connected ones included
    derived: tuple[ResolvedDerived, ...] = ()


_INDEXED = re.compile(r"^(?P<base>.+)\[(?P<idx>[0-9, ]+)\]$")


def vector_names(variables: dict[str, ScalarVariable], name: str) -> list[str]:
    """``name`` itself if it is a variable, else its elements ``name[1]``, ``name[2]``, ...

    Elements are ordered by their indices (row-major for matrices), not by file order.
    """
    if name in variables:
        return [name]
    elements = []
    for var in variables:
        m = _INDEXED.match(var)
        if m and m["base"] == name:
            elements.append((tuple(int(i) for i in m["idx"].split(",")), var))
    return [var for _, var in sorted(elements)]


def resolve_system(spec: SystemSpec) -> ResolvedSystem:
    """Check ``spec`` against the FMUs' model descriptions and look every variable up (harness
    blocks not built yet are built into the default cache, see :func:`build_blocks`).

    Raises
    ------
    DescriptionError
        Unknown FMU file or variable, wrong causality or type, size mismatch, an input
        connected twice or neither connected nor given a start value, an algebraic loop.

    Examples
    --------
    With the pendulum's FMUs built into ``build/pendulum`` (``python build_fmu.py
    examples/pendulum.toml --out build/pendulum``):

    >>> from harness.cli import SCENARIO_DIR
    >>> spec = load_system(SCENARIO_DIR / "pendulum_nominal.toml", {"fmu_dir": "build/pendulum"})
    >>> system = resolve_system(spec)  # doctest: +SKIP
    >>> sorted(system.fmus), [v.name for _, v in system.connections[0].sources]  # doctest: +SKIP
    (['kalman', 'linear', 'observer', 'plant'], ['y[1]', 'y[2]'])

    A missing FMU is reported by name:

    >>> resolve_system(load_system(SCENARIO_DIR / "pendulum_nominal.toml",
    ...                            {"fmu_dir": "/nonexistent"}))
    Traceback (most recent call last):
    ...
    harness.system.DescriptionError: FMU 'plant': file /nonexistent/plant.fmu does not exist
    """
    spec = build_blocks(spec)
    fmus = {name: _resolve_fmu(fs) for name, fs in spec.fmus.items()}
    connections = tuple(_resolve_connection(c, fmus) for c in spec.connections)
    _check_inputs(fmus, connections)
    _check_algebraic_loops(fmus, connections)
    _check_noise(connections)
    derived = tuple(_resolve_derived(d, fmus) for d in spec.derived)
    recorded: list[str] = []
    for conn in (*connections, *derived):
        recorded += [f"{f}.{v.name}" for f, v in conn.sources]
    figure = () if spec.figure is None else tuple(spec.figure.signals.values())
    errors = tuple(s for pair in spec.evaluation.errors.values() for s in pair)
    elements = {split_signal(d.target)[0] for d in spec.derived}
    for signal in spec.record + errors + figure:
        if split_signal(signal)[0] not in elements:
            recorded += [f"{f}.{v.name}" for f, v in _signals(signal, fmus, READABLE)]
    return ResolvedSystem(spec, fmus, connections, tuple(dict.fromkeys(recorded)), derived)


def _resolve_fmu(fs: FmuSpec) -> ResolvedFmu:
    if not fs.path.is_file():
        raise DescriptionError(f"FMU {fs.name!r}: file {fs.path} does not exist")
    try:
        md = description(fs.path)
    except Exception as err:  # noqa: BLE001 - any parse failure is reported the same way
        raise DescriptionError(f"FMU {fs.name!r}: cannot read {fs.path}: {err}") from err
    if md.fmiVersion not in ("2.0", "3.0") or md.coSimulation is None:
        raise DescriptionError(f"FMU {fs.name!r}: {fs.path} is not an FMI 2.0 or 3.0 "
                               "co-simulation FMU")
    variables = ({v.name: v for v in md.modelVariables} if md.fmiVersion == "2.0"
                 else element_variables(md))
    for var, value in fs.start.items():
        _check_start(fs.name, variables, var, value)
    for var, shape in fs.shapes.items():
        _check_start_shape(fs.name, variables, var, shape)
    return ResolvedFmu(fs, md, variables)


def _check_start(
    fmu: str, variables: dict[str, ScalarVariable], name: str, value: StartValue
) -> None:
    v = _variable(fmu, variables, name)
    settable = v.causality in ("parameter", "input") or (
        v.causality == "local" and v.initial in ("exact", "approx")
    )
    if v.variability == "constant" or not settable:
        raise DescriptionError(
            f"{fmu}.{name}: cannot be given a start value (causality "
            f"{v.causality}, variability {v.variability}, initial {v.initial})"
        )
    if v.type == "Real" and isinstance(value, bool):
        raise DescriptionError(f"{fmu}.{name}: Real variable given boolean {value!r}")
    if v.type in ("Integer", "Enumeration") and float(value) != int(value):
        raise DescriptionError(f"{fmu}.{name}: {v.type} variable given non-integer {value!r}")
    if v.type not in ("Real", "Integer", "Enumeration", "Boolean"):
        raise DescriptionError(f"{fmu}.{name}: start values of type {v.type} are not supported")


def _check_start_shape(
    fmu: str, variables: dict[str, ScalarVariable], name: str, shape: tuple[int, ...]
) -> None:
    """A vector or matrix start value must cover the FMU's array variable exactly."""
    elements = [v for v in vector_names(variables, name) if v != name]
    indices = [tuple(int(i) for i in _INDEXED.match(v)["idx"].split(",")) for v in elements]
    have = tuple(max(d) for d in zip(*indices, strict=True)) if indices else ()
    if have != shape:
        what = f"{'x'.join(map(str, have))} ({name}[...])" if have else "no array of that name"
        raise DescriptionError(
            f"{fmu}.{name}: start value of shape {'x'.join(map(str, shape))}, but the FMU has "
            f"{what}"
        )


def _variable(fmu: str, variables: dict[str, ScalarVariable], name: str) -> ScalarVariable:
    if name not in variables:
        near = [v for v in variables if v.split("[")[0] == name.split("[")[0]][:6]
        hint = f"; similar: {near}" if near else f"; has {list(variables)[:12]}"
        raise DescriptionError(f"FMU {fmu!r} has no variable {name!r}{hint}")
    return variables[name]


def _signals(
    signal: str, fmus: dict[str, ResolvedFmu], causality: tuple[str, ...]
) -> list[tuple[str, ScalarVariable]]:
    """Scalar variables of a vector or scalar signal, checked for causality (one of
    ``causality``) and type Real."""
    fmu, name = split_signal(signal)
    if fmu not in fmus:
        raise DescriptionError(f"signal {signal!r}: unknown FMU {fmu!r} (have {sorted(fmus)})")
    variables = fmus[fmu].variables
    names = vector_names(variables, name) or [_variable(fmu, variables, name).name]
    out = []
    for n in names:
        v = variables[n]
        if v.causality not in causality:
            raise DescriptionError(
                f"{fmu}.{n}: causality is {v.causality}, a connection needs "
                f"{' or '.join(causality)} here"
            )
        if v.type != "Real":
            raise DescriptionError(f"{fmu}.{n}: type {v.type}; connections carry Real signals only")
        out.append((fmu, v))
    return out


def _resolve_connection(c: ConnectionSpec, fmus: dict[str, ResolvedFmu]) -> ResolvedConnection:
    sources = [s for signal in c.sources for s in _signals(signal, fmus, READABLE)]
    targets = _signals(c.target, fmus, ("input",))
    gain, offset, bias = _affine(c, len(sources), len(targets))
    noise = None if c.noise is None else _sized(c, "noise", c.noise, len(sources), "sources")
    return ResolvedConnection(tuple(sources), tuple(targets), gain, offset, bias, noise)


def _resolve_derived(c: ConnectionSpec, fmus: dict[str, ResolvedFmu]) -> ResolvedDerived:
    element, var = split_signal(c.target)
    if element in fmus:
        raise DescriptionError(f"derived {c}: {element!r} is an FMU of the system; a derived "
                               "signal needs an element name of its own")
    sources = [s for signal in c.sources for s in _signals(signal, fmus, READABLE)]
    rows = len(sources) if c.gain is None else c.gain.shape[0]
    gain, offset, bias = _affine(c, len(sources), rows)
    names = tuple(f"{element}.{var}[{i + 1}]" for i in range(rows))
    return ResolvedDerived(tuple(sources), names, gain, offset, bias)


def _affine(c: ConnectionSpec, n_sources: int,
            n_targets: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gain, offset and bias of ``c`` checked against its sizes (defaults: I, 0, 0)."""
    gain = np.eye(n_targets) if c.gain is None else c.gain
    if gain.shape != (n_targets, n_sources):
        what = "gain shape " + str(gain.shape) if c.gain is not None else "sizes differ:"
        raise DescriptionError(
            f"connection {c}: {what} for {n_sources} sources and {n_targets} targets"
        )
    if not np.all(np.isfinite(gain)):
        raise DescriptionError(f"connection {c}: gain is not finite")
    offset = (np.zeros(n_sources) if c.offset is None
              else _sized(c, "offset", c.offset, n_sources, "sources"))
    bias = (np.zeros(n_targets) if c.bias is None
            else _sized(c, "bias", c.bias, n_targets, "targets"))
    return gain, offset, bias


def _sized(c: ConnectionSpec, key: str, value: np.ndarray, size: int, what: str) -> np.ndarray:
    if value.shape != (size,):
        raise DescriptionError(f"connection {c}: {key} has {value.size} entries for {size} "
                               f"{what}")
    return value


def _check_noise(connections: tuple[ResolvedConnection, ...]) -> None:
    """A source's noise is one draw per step for every connection that reads it: its standard
    deviation must be the same in each."""
    std: dict[str, float] = {}
    for conn in connections:
        if conn.noise is None:
            continue
        for (fmu, v), sigma in zip(conn.sources, conn.noise, strict=True):
            key = f"{fmu}.{v.name}"
            if std.setdefault(key, float(sigma)) != float(sigma):
                raise DescriptionError(f"{key}: connections add noise of standard deviation "
                                       f"{std[key]!r} and {float(sigma)!r}; one source has "
                                       "one noise draw per step, give both the same")


def _check_inputs(
    fmus: dict[str, ResolvedFmu], connections: tuple[ResolvedConnection, ...]
) -> None:
    connected: set[str] = set()
    for conn in connections:
        for fmu, v in conn.targets:
            key = f"{fmu}.{v.name}"
            if key in connected:
                raise DescriptionError(f"input {key} is connected more than once")
            if v.name in fmus[fmu].spec.start:
                raise DescriptionError(f"input {key} is connected and also given a start value")
            connected.add(key)
    for name, rf in fmus.items():
        for v in rf.variables.values():
            key = f"{name}.{v.name}"
            if v.causality == "input" and key not in connected and v.name not in rf.spec.start:
                raise DescriptionError(
                    f"input {key} is unconnected: connect it or give it a start "
                    f"value (a constant input)"
                )


def _check_algebraic_loops(
    fmus: dict[str, ResolvedFmu], connections: tuple[ResolvedConnection, ...]
) -> None:
    """Reject cycles made of connections and *declared* direct feedthrough."""
    edges: dict[str, set[str]] = {}
    for conn in connections:
        for (sf, sv), row in zip(conn.targets, conn.gain, strict=True):
            for (of, ov), g in zip(conn.sources, row, strict=True):
                if g != 0.0:
                    edges.setdefault(f"{of}.{ov.name}", set()).add(f"{sf}.{sv.name}")
    for name, rf in fmus.items():
        for unknown in rf.description.outputs:
            for dep in unknown.dependencies or []:
                if dep.causality == "input":
                    edges.setdefault(f"{name}.{dep.name}", set()).add(
                        f"{name}.{unknown.variable.name}"
                    )
    cycle = _find_cycle(edges)
    if cycle:
        raise DescriptionError(
            "algebraic loop through declared direct feedthrough: " + " -> ".join(cycle)
        )


def _find_cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """A cycle of the directed graph ``edges`` as a closed list of nodes, or None."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(edges):
        if node not in state and (found := visit(node)):
            return found
    return None
