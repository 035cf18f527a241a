"""Sweeps and Monte Carlo runs of the harness on dask.distributed.

``python -m harness sweep SWEEP.toml --out DIR [--scheduler ADDRESS] [--workers N]`` runs one
co-simulation per point of a sweep file and writes one table of their figures. A sweep file::

    # what this sweep is for (its first sentence is its summary)
    base = "pendulum_noisy"        # a scenario (bundled name or system description file)
                                   # or a plant spec (a TOML file with A, B, C)
    spec = "examples/pendulum.toml"   # scenario bases: the plant spec designed (default: the
                                      # pendulum's); a plant-spec base is its own spec
    design = "spec"                # "spec" (default), "paper" (the published pendulum gains)
                                   # or "defaults" (the spec's plant with the design's
                                   # defaults: no L_lin, no [noise], of its [observer] table
                                   # only state_scale and settling_time; harness.zoo)
    fmus = "native"                # "native" (default) or "pythonfmu"
    stop_time = 1.5                # default: the scenario's (a plant: 3 settling times)
    step = 5e-5                    # default: the scenario's (a plant: [noise] sample time or 1e-3)

    [grid]                         # every combination of the values (or several [[grid]])
    rho = [3.0, 6.0]               # an [observer] key of the spec: nu, rho, gamma, objective,
                                   # filter_scale, disturbance_order, settling_time, state_scale
    "spec.noise.process_intensity" = [1e-3, 1e-2]   # any spec entry: spec.<key>[.<key>]
    "set.plant.x0" = [[1, 0, 0, 0], [2, 2, 1, 2]]   # a start value, as `run --set FMU.VAR=V`
    seed = [0, 1, 2, 3, 4]         # the scenario's noise seed ([run] seed)
    # step, stop_time and base are axes too

    [random]                       # seeded random samples (combined with every grid point)
    samples = 16
    seed = 1                       # the generator's seed: the same file gives the same points
    [random.axes]
    rho = {uniform = [2.0, 8.0]}   # uniform, loguniform (both bounds > 0), integers (both
    seed = {integers = [0, 999]}   # bounds included), choice (a list of values)

    [evaluation]                   # optional: the figures (as a system description's
    at = [0.1]                     # [evaluation], harness.results); each key given replaces
    windows = [[0.1, 0.2]]         # the base's, the others are kept
    converged = [1e-3]             # time_to_1e-3: when the relative error settles below 1e-3
    peak = true                    # peak: the error's peak over its initial size
    floor = 1.0                    # floor: the relative error's max over the last 1 s

    [pareto]                       # optional: the Pareto picture of two bases
    perturbation = "pendulum_perturbed"   # its max error (first window) on the x-axis
    noisy = "pendulum_noisy"              # its RMS error (first window, mean over seeds)
    [pareto.estimators]            # optional: the estimators shown, each with the axes its
    kalman = ["spec.noise.process_intensity"]   # designs vary over; its points come from the
    homogeneous = ["rho"]          # points that set no other axis (base and seed aside)

Each distinct design (the content hash of the point's spec) is designed and its FMUs built
once per sweep, by one worker (:func:`build_bundle`, a task the points of that design depend
on; :func:`fhobs.native.build.build_native_fmus` or :func:`fhobs.build.build_fmus`, into that
worker's temporary folder); the design and the FMU files' bytes travel to the workers that run
its points, which write them into their own temporary folders (no disk is shared). Each point
then co-simulates the scenario (:func:`harness.master.run_system`) and returns its row: its
parameters, the figures of :func:`harness.results.error_figures` per estimator
(``<estimator>.<figure>``), wall time, status and, when it failed, the reason. The points run
on dask (:func:`run_sweep`), or one after the other in the calling process
(:func:`run_in_process`: the same tasks, the same rows, no cluster). A scenario base
runs the FMUs named in it; a plant-spec base runs :func:`harness.own_plant.own_plant_system`
(as ``harness plant``).

Every finished row is written at once to ``DIR/points/<key>.json`` (the key is a hash of the
point and of the files it depends on); a re-run of the same command skips the points that
have a row (``--retry-failed`` reruns the failed ones). At the end ``DIR/sweep.parquet`` and
``DIR/sweep.csv`` hold one row per point (:func:`read_table` reads either back as a pandas
DataFrame), and ``DIR/plots/`` each figure against each swept axis and, with ``[pareto]``, the
Pareto picture (:mod:`harness.sweep_plots`).
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import itertools
import json
import math
import os
import shutil
import socket
import sys
import tempfile
import time
import tomllib
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from harness.system import DescriptionError, SystemSpec, check_timing
from harness.writing import atomic_path, completed, write_text

SWEEP_DIR = Path(__file__).resolve().parent / "sweeps"
"""The bundled sweep files."""
TOP_KEYS = ("name", "base", "spec", "design", "fmus", "stop_time", "step", "grid", "random",
            "evaluation", "pareto")
RANDOM_KEYS = ("samples", "seed", "axes")
EVALUATION_KEYS = ("at", "windows", "converged", "peak", "floor")
PARETO_KEYS = ("perturbation", "noisy", "estimators")
DESIGNS = ("spec", "paper", "defaults")
FLAVOURS = ("native", "pythonfmu")
RUN_AXES = ("base", "seed", "step", "stop_time")
"""Axes that are not spec entries or start values."""
DISTRIBUTIONS = ("uniform", "loguniform", "integers", "choice")
STATUS_OK, STATUS_FAILED = "ok", "failed"
MAX_POINTS = 100_000
"""The most points a sweep file may have (each is a co-simulation and a row)."""
MAX_SEEDS = 1000
"""The most distinct seeds of a sweep (and of ``harness run --seeds``)."""
MAX_SEED = 2**31 - 1
"""The largest seed: the plant FMU's ``noise_seed`` is an FMI Integer (int32)."""
WORKERS_PER_CORE = 4
"""``--workers`` is at most this many times the core count (one thread each)."""
CONNECT_TIMEOUT = 30.0
"""Seconds a ``--scheduler`` has to accept the connection and answer (``--connect-timeout``)."""
MAX_CONNECT_TIMEOUT = 3600.0
"""The longest ``--connect-timeout``."""


class SweepError(DescriptionError):
    """An invalid sweep file or sweep option (the message names the field and the reason)."""


# -- the sweep file ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Base:
    """What a point runs: a scenario with the spec it designs, or a plant spec alone.

    Attributes
    ----------
    name : str
        As the sweep file names it.
    kind : str
        ``"scenario"`` or ``"plant"``.
    spec_data : dict
        The plant spec's parsed TOML (the design's source).
    system : SystemSpec or None
        The scenario, loaded with FMU paths under :data:`FMU_PLACEHOLDER` (``scenario`` only).
    files : dict
        ``{path: bytes}`` of the FMUs the scenario names outside ``${fmu_dir}``.
    digest : str
        Hash of the files the base was read from (a point's key depends on it).
    """

    name: str
    kind: str
    spec_data: dict[str, Any]
    system: SystemSpec | None = None
    files: dict[str, bytes] = field(default_factory=dict)
    digest: str = ""


FMU_PLACEHOLDER = "/fhobs-sweep-fmu-dir"
"""``${fmu_dir}`` of a scenario loaded on the client; each worker puts its own folder there."""


@dataclass(frozen=True)
class Point:
    """One point of a sweep: its position, parameters (axis -> value) and key (hash)."""

    index: int
    params: dict[str, Any]
    key: str


@dataclass(frozen=True)
class Sweep:
    """A loaded sweep file (see the module docstring).

    Attributes
    ----------
    path : Path
        The sweep file.
    name : str
        Its ``name`` (default: the file's stem).
    bases : dict
        ``{name: Base}`` of every base the points use.
    points : list of Point
        In the order of the grid (then of the random samples); no two with the same key.
    axes : tuple of str
        The swept axes, sorted.
    settings : dict
        ``base``, ``design``, ``fmus``, ``stop_time``, ``step``, ``evaluation``: what every point
        shares unless an axis sets it.
    pareto : dict
        ``{"perturbation": base, "noisy": base}`` and, when the file selects them,
        ``"estimators": {estimator: [axis, ...]}``; or empty.
    """

    path: Path
    name: str
    bases: dict[str, Base]
    points: list[Point]
    axes: tuple[str, ...]
    settings: dict[str, Any]
    pareto: dict[str, Any]


def sweep_path(name: str | Path) -> Path:
    """A sweep file's path: a file, or a bundled sweep's name.

    Examples
    --------
    >>> sweep_path("pendulum_noisy_seeds").name
    'pendulum_noisy_seeds.toml'
    """
    path = Path(name)
    if path.is_file():
        return path
    if path.exists():
        raise SweepError(f"{name}: not a regular file (a sweep file is a TOML file; folders, "
                         "FIFOs and devices are refused)")
    bundled = SWEEP_DIR / f"{name}.toml"
    if path.suffix != ".toml" and bundled.is_file():
        return bundled
    have = sorted(p.stem for p in SWEEP_DIR.glob("*.toml"))
    raise SweepError(f"{name}: no such sweep file, and no bundled sweep of that name "
                     f"(bundled: {', '.join(have)})")


def load_sweep(path: str | Path) -> Sweep:
    """Read and check a sweep file, and enumerate its points.

    Parameters
    ----------
    path : str or Path
        The sweep file, or a bundled sweep's name (:data:`SWEEP_DIR`).

    Returns
    -------
    Sweep

    Raises
    ------
    SweepError
        One paragraph naming the field and the reason: not TOML, an unknown key or axis, an
        empty grid or axis, a file that does not exist, a bad distribution, a spec value the
        design refuses, a step that does not divide the run.

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")
    >>> len(sweep.points), sweep.axes
    (6, ('base', 'seed'))
    """
    path = sweep_path(path)
    return sweep_from_table(_read_toml(path), path)


def sweep_from_table(data: dict[str, Any], path: Path) -> Sweep:
    """A sweep from the parsed TOML of a sweep file (:func:`load_sweep`): ``path`` names it
    in messages and gives its default name and the folder relative files are looked up in
    first.

    Examples
    --------
    >>> sweep = sweep_from_table({"base": "pendulum_noisy", "grid": {"seed": [0, 1]}},
    ...                          Path("seeds.toml"))
    >>> sweep.name, [p.params for p in sweep.points]
    ('seeds', [{'seed': 0}, {'seed': 1}])
    """
    where = str(path)
    _reject_unknown(data, TOP_KEYS, where)
    settings = _settings(data, where)
    combos = _combinations(data, where)
    axes = tuple(sorted({axis for combo in combos for axis in combo}))
    for axis in axes:
        _check_axis(axis, where)
    bases = {}
    for name in {c.get("base", settings["base"]) for c in combos}:
        if name is None:
            raise SweepError(f"{where}: base is missing (a scenario name such as "
                             "'pendulum_nominal', or a plant spec file)")
        bases[name] = _load_base(str(name), settings, path)
    pareto = _pareto(data, bases, axes, where)
    points = _points(combos, bases, settings, where)
    return Sweep(path, _string(data.get("name", path.stem), f"{where}: name"), bases, points,
                 axes, settings, pareto)


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise SweepError(f"{path}: cannot read the sweep file ({err})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SweepError(f"{path}: not valid TOML ({err})") from None


def _reject_unknown(table: dict[str, Any], allowed: tuple[str, ...], where: str) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise SweepError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(allowed)})")


def _string(value: Any, where: str) -> str:
    if not isinstance(value, str):
        raise SweepError(f"{where} = {value!r} must be a string")
    return value


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SweepError(f"{where} = {value!r} must be a finite number")
    return float(value)


def _settings(data: dict[str, Any], where: str) -> dict[str, Any]:
    """The values every point shares unless an axis sets them."""
    design = data.get("design", "spec")
    flavour = data.get("fmus", "native")
    if design not in DESIGNS:
        raise SweepError(f"{where}: design = {design!r} must be one of {', '.join(DESIGNS)}")
    if flavour not in FLAVOURS:
        raise SweepError(f"{where}: fmus = {flavour!r} must be one of {', '.join(FLAVOURS)}")
    settings = {"base": data.get("base"), "design": design, "fmus": flavour,
                "spec": data.get("spec"), "evaluation": _evaluation(data, where)}
    for key in ("stop_time", "step"):
        settings[key] = None if key not in data else _number(data[key], f"{where}: {key}")
    if settings["spec"] is not None:
        _string(settings["spec"], f"{where}: spec")
    return settings


def _evaluation(data: dict[str, Any], where: str) -> dict[str, Any] | None:
    """The ``[evaluation]`` override as plain data: the keys it gives, checked as a system
    description's (:func:`harness.system.parse_evaluation`); the error signals are the base's."""
    from harness.system import parse_evaluation

    if "evaluation" not in data:
        return None
    table = data["evaluation"]
    if not isinstance(table, dict):
        raise SweepError(f"{where}: evaluation must be a table (at, windows, converged, peak, "
                         "floor)")
    _reject_unknown(table, EVALUATION_KEYS, f"{where}: [evaluation]")
    try:
        parsed = parse_evaluation(table, f"{where}: [evaluation]")
    except DescriptionError as err:
        raise SweepError(str(err)) from None
    return {key: _plain(getattr(parsed, key)) for key in table}


def _flatten(table: dict[str, Any], leaf: Any, prefix: str = "") -> dict[str, Any]:
    """Dotted keys of nested tables (``set.plant.x0``), down to the values ``leaf`` accepts."""
    out = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and not leaf(value):
            out |= _flatten(value, leaf, name + ".")
        else:
            out[name] = value
    return out


def _combinations(data: dict[str, Any], where: str) -> list[dict[str, Any]]:
    """The axis values of every point: each grid's product, times the random samples."""
    if "grid" not in data and "random" not in data:
        raise SweepError(f"{where}: no [grid] and no [random] table: nothing to sweep "
                         "(add e.g. [grid] seed = [0, 1, 2])")
    grids = data.get("grid", [])
    grids = [grids] if isinstance(grids, dict) else grids
    if not isinstance(grids, list) or not all(isinstance(g, dict) for g in grids):
        raise SweepError(f"{where}: grid must be a [grid] table or [[grid]] tables")
    combos: list[dict[str, Any]] = []
    for i, grid in enumerate(grids, start=1):
        combos += _grid_points(grid, f"{where}: grid" + (f" {i}" if len(grids) > 1 else ""))
        check_size(len(combos), f"{where}: [grid]")
    if "random" in data:
        samples = _random_points(data["random"], f"{where}: [random]")
        check_size(len(combos or [{}]) * len(samples), f"{where}: [grid] times [random]")
        combos = [c | s for c in (combos or [{}]) for s in samples]
    seeds = {json.dumps(c["seed"]) for c in combos if "seed" in c}
    if len(seeds) > MAX_SEEDS:
        raise SweepError(f"{where}: axis 'seed' has {len(seeds)} values, more than a sweep may "
                         f"have (at most {MAX_SEEDS})")
    return combos


def _grid_points(grid: dict[str, Any], where: str) -> list[dict[str, Any]]:
    axes = _flatten(grid, lambda value: False)
    if not axes:
        raise SweepError(f"{where}: empty grid (give each axis a list of values, e.g. "
                         "seed = [0, 1, 2])")
    for axis, values in axes.items():
        if not isinstance(values, list):
            raise SweepError(f"{where}: axis {axis!r} = {values!r} must be a list of values")
        if not values:
            raise SweepError(f"{where}: axis {axis!r} is empty (the grid would have no point)")
    names = sorted(axes)
    check_size(math.prod(len(axes[n]) for n in names), where)
    return [dict(zip(names, values, strict=True))
            for values in itertools.product(*(axes[n] for n in names))]


def check_size(points: int, where: str) -> None:
    """SweepError when ``points`` exceeds :data:`MAX_POINTS`.

    Examples
    --------
    >>> check_size(10**9, "sweep.toml: grid")
    Traceback (most recent call last):
    ...
    harness.sweep.SweepError: sweep.toml: grid has 1e+09 points, more than a sweep may have \
(at most 100000); split it into several sweeps
    """
    if points > MAX_POINTS:
        raise SweepError(f"{where} has {points:.3g} points, more than a sweep may have (at "
                         f"most {MAX_POINTS}); split it into several sweeps")


def _random_points(table: Any, where: str) -> list[dict[str, Any]]:
    """``samples`` draws of every axis of ``[random.axes]``, in sorted axis order, seeded."""
    if not isinstance(table, dict):
        raise SweepError(f"{where} must be a table (samples, seed, axes)")
    _reject_unknown(table, RANDOM_KEYS, where)
    samples = table.get("samples")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise SweepError(f"{where}: samples = {samples!r} must be an integer >= 1")
    check_size(samples, f"{where}: samples")
    seed = table.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SweepError(f"{where}: seed = {seed!r} must be an integer >= 0")
    axes = table.get("axes", {})
    if not isinstance(axes, dict):
        raise SweepError(f"{where}: axes must be a table of distributions")
    axes = _flatten(axes, lambda value: set(value) <= set(DISTRIBUTIONS))
    if not axes:
        raise SweepError(f"{where}: no [random.axes] (e.g. rho = {{uniform = [2.0, 8.0]}})")
    rng = np.random.default_rng(seed)
    draws = {axis: _draw(rng, axes[axis], samples, f"{where}: axes.{axis}")
             for axis in sorted(axes)}
    return [{axis: draws[axis][i] for axis in draws} for i in range(samples)]


def _draw(rng: np.random.Generator, dist: Any, samples: int, where: str) -> list[Any]:
    """``samples`` values of one distribution ``{uniform|loguniform|integers|choice = ...}``."""
    if not isinstance(dist, dict) or len(dist) != 1 or next(iter(dist)) not in DISTRIBUTIONS:
        raise SweepError(f"{where} = {dist!r} must be one distribution: "
                         f"{{NAME = ARGS}} with NAME one of {', '.join(DISTRIBUTIONS)}")
    (name, args), = dist.items()
    if name == "choice":
        if not isinstance(args, list) or not args:
            raise SweepError(f"{where}: choice needs a non-empty list of values")
        return [args[i] for i in rng.integers(0, len(args), samples)]
    if not (isinstance(args, list) and len(args) == 2):
        raise SweepError(f"{where}: {name} needs [low, high], got {args!r}")
    low, high = (_number(v, f"{where}.{name}") for v in args)
    if not low < high or (name == "loguniform" and low <= 0.0):
        raise SweepError(f"{where}: {name} bounds {args!r} must have low < high"
                         + (" and low > 0" if name == "loguniform" else ""))
    if name == "integers":
        if low != int(low) or high != int(high):
            raise SweepError(f"{where}: integers bounds {args!r} must be whole numbers")
        return [int(v) for v in rng.integers(int(low), int(high) + 1, samples)]
    if name == "loguniform":
        return [float(v) for v in np.exp(rng.uniform(np.log(low), np.log(high), samples))]
    return [float(v) for v in rng.uniform(low, high, samples)]


def spec_axis(axis: str) -> tuple[str, ...] | None:
    """The spec path an axis sets, or None: ``rho`` and ``spec.observer.rho`` ->
    ``("observer", "rho")``, ``spec.E`` -> ``("E",)``.

    Examples
    --------
    >>> spec_axis("rho"), spec_axis("spec.noise.process_intensity"), spec_axis("seed")
    (('observer', 'rho'), ('noise', 'process_intensity'), None)
    """
    from fhobs.design.spec import OBSERVER_KEYS

    if axis in OBSERVER_KEYS:
        return ("observer", axis)
    if axis.startswith("spec."):
        return tuple(axis.split(".")[1:])
    return None


def _check_axis(axis: str, where: str) -> None:
    """SweepError unless ``axis`` is a run axis, a known spec entry or ``set.FMU.VAR``."""
    from fhobs.design.spec import NOISE_KEYS, OBSERVER_KEYS
    from fhobs.design.spec import TOP_KEYS as SPEC_KEYS

    path = spec_axis(axis)
    if axis in RUN_AXES:
        return
    if axis.startswith("set."):
        if len(axis.split(".", 2)) < 3:
            raise SweepError(f"{where}: axis {axis!r} must be set.FMU.VARIABLE (a start value, "
                             "as `run --set FMU.VAR=VALUE`)")
        return
    tables = {"observer": OBSERVER_KEYS, "noise": NOISE_KEYS}
    if path is not None and path and path[0] in SPEC_KEYS and (
            (len(path) == 1 and path[0] not in tables)
            or (len(path) == 2 and path[0] in tables and path[1] in tables[path[0]])):
        return
    raise SweepError(
        f"{where}: unknown axis {axis!r}; an axis is one of {', '.join(RUN_AXES)}, an "
        f"[observer] key ({', '.join(OBSERVER_KEYS)}), spec.KEY for a spec entry (spec.A, "
        f"spec.observer.rho, spec.noise.process_intensity; keys: "
        f"{', '.join(SPEC_KEYS)}) or set.FMU.VARIABLE for a start value")


def _resolve_file(name: str, sweep_file: Path, what: str) -> Path:
    """A path of the sweep file: relative to its folder, else to the working directory, else
    to the bundled examples (``zoo/dc_motor.toml``: :data:`fhobs.paper.EXAMPLES`)."""
    from fhobs.paper import EXAMPLES

    for path in (sweep_file.parent / name, Path(name), EXAMPLES / name):
        if path.is_file():
            return path.resolve()
    raise SweepError(f"{sweep_file}: {what} {name!r}: no such file (looked in "
                     f"{sweep_file.parent}, in the working directory {Path.cwd()} and in the "
                     f"bundled examples {EXAMPLES})")


def _load_base(name: str, settings: dict[str, Any], sweep_file: Path) -> Base:
    """Read a base: a bundled scenario, a system description or a plant spec file."""
    from fhobs.paper import PENDULUM_SPEC

    from harness.cli import SCENARIO_DIR

    where = f"{sweep_file}: base {name!r}"
    bundled = SCENARIO_DIR / f"{name}.toml"
    path = bundled if bundled.is_file() and not name.endswith(".toml") else \
        _resolve_file(name, sweep_file, "base")
    data = _read_toml(path)
    if "A" in data:
        if settings["design"] == "paper":
            raise SweepError(f"{where}: design = 'paper' (the pendulum's published gains) needs "
                             "a scenario base, not a plant spec")
        return Base(name, "plant", data, digest=_digest(path.read_bytes()))
    if "fmus" not in data and "extends" not in data:
        raise SweepError(f"{where}: {path} is neither a plant spec (no A, B, C) nor a system "
                         "description (no [fmus] tables)")
    spec_file = PENDULUM_SPEC if settings["spec"] is None else \
        _resolve_file(settings["spec"], sweep_file, "spec")
    return _scenario_base(name, path, spec_file, where)


def _scenario_base(name: str, path: Path, spec_file: Path, where: str) -> Base:
    """A scenario loaded with its FMUs under :data:`FMU_PLACEHOLDER`; FMUs it names elsewhere
    are read into ``files`` (they travel with the points)."""
    from harness.system import load_system

    try:
        system = load_system(path, {"fmu_dir": FMU_PLACEHOLDER})
    except DescriptionError as err:
        raise SweepError(f"{where}: {err}") from None
    files, sources = {}, [path.read_bytes(), spec_file.read_bytes()]
    for fs in system.fmus.values():
        if fs.path is not None and not str(fs.path).startswith(FMU_PLACEHOLDER):
            if not Path(fs.path).is_file():
                raise SweepError(f"{where}: FMU {fs.name!r}: {fs.path} does not exist")
            files[str(fs.path)] = Path(fs.path).read_bytes()
            sources.append(files[str(fs.path)])
    extends = system.source
    while extends is not None:  # the files it extends count in the digest too
        parent = tomllib.loads(extends.read_text()).get("extends")
        extends = None if parent is None else (extends.parent / parent)
        if extends is not None:
            sources.append(extends.read_bytes())
    spec_data = _read_toml(spec_file)
    return Base(name, "scenario", spec_data, system, files, _digest(*sources))


def _digest(*parts: bytes) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(hashlib.sha256(part).digest())
    return h.hexdigest()[:16]


def _pareto(data: dict[str, Any], bases: dict[str, Base], axes: tuple[str, ...],
            where: str) -> dict[str, Any]:
    table = data.get("pareto", {})
    if not isinstance(table, dict):
        raise SweepError(f"{where}: pareto must be a table (perturbation, noisy)")
    _reject_unknown(table, PARETO_KEYS, f"{where}: [pareto]")
    if table and not {"perturbation", "noisy"} <= set(table):
        raise SweepError(f"{where}: [pareto] needs both perturbation and noisy (base names)")
    for key in ("perturbation", "noisy"):
        if key in table and table[key] not in bases:
            raise SweepError(f"{where}: pareto.{key} = {table[key]!r} is not a base of the "
                             f"sweep (bases: {', '.join(sorted(bases))})")
    out = dict(table)
    if "estimators" in table:
        out["estimators"] = _pareto_estimators(table["estimators"], axes,
                                               f"{where}: pareto.estimators")
    return out


def _pareto_estimators(table: Any, axes: tuple[str, ...], where: str) -> dict[str, list[str]]:
    """``[pareto.estimators]``: ``{estimator: [axis, ...]}``, each axis a swept one."""
    if not isinstance(table, dict) or not table:
        raise SweepError(f"{where} must be a table of estimator = [axis, ...] (e.g. kalman = "
                         "[\"spec.noise.process_intensity\"])")
    swept = [a for a in axes if a not in ("base", "seed")]
    for estimator, names in table.items():
        if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
            raise SweepError(f"{where}.{estimator} = {names!r} must be a list of axis names")
        for name in names:
            if name not in swept:
                raise SweepError(f"{where}.{estimator}: {name!r} is not a swept axis (axes: "
                                 f"{', '.join(swept) or 'none but base and seed'})")
    return {estimator: list(names) for estimator, names in table.items()}


def _points(combos: list[dict[str, Any]], bases: dict[str, Base], settings: dict[str, Any],
            where: str) -> list[Point]:
    """The points with their keys (duplicates dropped), each checked on the client: its FMU
    start values name FMUs of its base, its spec is valid, its step divides its run."""
    points, seen, checked = [], set(), set()
    for combo in combos:
        params = {axis: _plain(combo[axis]) for axis in sorted(combo)}
        base = bases[params.get("base", settings["base"])]
        job = make_job(base, params, settings)
        key = point_key(job)
        if key in seen:
            continue
        seen.add(key)
        label = f"{where}: point {len(points)} ({_describe(params)})"
        _check_point(job, label, checked)
        points.append(Point(len(points), params, key))
    return points


def _plain(value: Any) -> Any:
    """JSON-compatible plain values (numpy scalars and tuples become floats and lists)."""
    return json.loads(json.dumps(value, default=float))


def _describe(params: dict[str, Any]) -> str:
    return ", ".join(f"{k} = {json.dumps(v)}" for k, v in params.items()) or "no axis"


def _check_point(job: dict[str, Any], label: str, checked: set[str]) -> None:
    from fhobs.design.spec import spec_from_dict
    from fhobs.errors import SpecError

    digest = design_key(job)
    if digest not in checked:
        checked.add(digest)
        if job["design"] == "paper" and any(
                path[0] != "noise" for path in spec_changes(job["params"])):
            raise SweepError(f"{label}: design = 'paper' takes the published gains: only "
                             "spec.noise.* axes apply to it")
        try:
            spec_from_dict(design_spec_data(job), source=f"the spec of base {job['base']!r}")
        except SpecError as err:
            raise SweepError(f"{label}: {err}") from None
    check_seed(job["seed"], label)
    fmus = fmu_variables(job)
    for axis, value in job["params"].items():
        if axis.startswith("set."):
            _check_start(axis, value, fmus, job, label)
    step, stop = job["step"], job["stop_time"]
    system = job["system"]
    if system is not None:
        step = system.step if step is None else step
        stop = system.stop_time if stop is None else stop
    if step is not None and stop is not None:
        start = system.start_time if system is not None else 0.0
        try:
            check_timing(step, start, stop, "step/stop_time")
        except DescriptionError as err:
            raise SweepError(f"{label}: {err}") from None


def check_seed(seed: Any, where: str) -> None:
    """SweepError unless ``seed`` is None or a whole number in 0..:data:`MAX_SEED`.

    Examples
    --------
    >>> check_seed(-1, "sweep.toml: point 0 (seed = -1)")
    Traceback (most recent call last):
    ...
    harness.sweep.SweepError: sweep.toml: point 0 (seed = -1): axis 'seed' = -1 must be a whole \
number from 0 to 2147483647 (the plant FMU's noise_seed, an FMI Integer)
    """
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)
                             or not 0 <= seed <= MAX_SEED):
        raise SweepError(f"{where}: axis 'seed' = {seed!r} must be a whole number from 0 to "
                         f"{MAX_SEED} (the plant FMU's noise_seed, an FMI Integer)")


def fmu_variables(job: dict[str, Any]) -> dict[str, tuple[str, ...] | None]:
    """The FMUs of a point's system with the names of their variables: a kind's FMU (built
    for the point) its declared variables (:data:`fhobs.fmu.kinds.KINDS`), an FMU file its
    model description's scalar variables, a harness block None (not known before it is built).

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")
    >>> fmus = fmu_variables(make_job(sweep.bases["pendulum_noisy"], {}, sweep.settings))
    >>> sorted(fmus), "x0" in fmus["plant"]
    (['kalman', 'linear', 'observer', 'perturbation', 'plant'], True)
    """
    from fhobs.fmu.kinds import KINDS

    from harness.fmu_files import description

    if job["system"] is None:
        return {name: tuple(v.name for v in kind.variables) for name, kind in KINDS.items()}
    out: dict[str, tuple[str, ...] | None] = {}
    for name, fs in job["system"].fmus.items():
        if fs.path is None:
            out[name] = None
        elif str(fs.path).startswith(FMU_PLACEHOLDER):
            out[name] = tuple(v.name for v in KINDS[Path(fs.path).stem].variables)
        else:
            out[name] = tuple(v.name for v in description(fs.path).modelVariables)
    return out


def _check_start(axis: str, value: Any, fmus: dict[str, tuple[str, ...] | None],
                 job: dict[str, Any], label: str) -> None:
    """SweepError unless ``set.FMU.VAR = value`` names an FMU of the point's system and, where
    its variables are known before the run, a variable of it with as many elements as the
    value (the plant FMU's ``x0``: the spec's n)."""
    from harness.system import expand_start

    _, fmu, var = axis.split(".", 2)
    where = f"{label}: axis {axis!r} = {json.dumps(value)}"
    if fmu not in fmus:
        raise SweepError(f"{label}: axis {axis!r}: no FMU {fmu!r} in base {job['base']!r} "
                         f"(FMUs: {', '.join(sorted(fmus))})")
    try:
        names = expand_start(var, value)
    except DescriptionError as err:
        raise SweepError(f"{where}: {err}") from None
    known = fmus[fmu]
    if known is None:
        return
    kind = job["system"] is None or str(job["system"].fmus[fmu].path).startswith(
        FMU_PLACEHOLDER)
    have = set(known) if kind else {n.partition("[")[0] for n in known}
    if var not in have:
        raise SweepError(f"{where}: FMU {fmu!r} has no variable {var!r} (its variables: "
                         f"{', '.join(dict.fromkeys(n.partition('[')[0] for n in known))})")
    size = len(names) if isinstance(value, list) else 0
    expected = _expected_size(job, fmu, var) if kind else sum(
        n.partition("[")[0] == var and "[" in n for n in known)
    if expected is not None and size != expected:
        what = f"{expected} values" if expected else "a number"
        raise SweepError(f"{where}: {fmu}.{var} takes {what}, not "
                         f"{size or 'a number'}{' values' if size else ''}")


def _expected_size(job: dict[str, Any], fmu: str, var: str) -> int | None:
    """The number of elements of a kind's array variable known from the spec alone: the
    plant's ``x0`` (n); None for the others."""
    kind = fmu if job["system"] is None else Path(job["system"].fmus[fmu].path).stem
    if (kind, var) == ("plant", "x0"):
        return len(design_spec_data(job)["A"])
    return None


# -- a point's job: what travels to a worker ---------------------------------------------------
def make_job(base: Base, params: dict[str, Any], settings: dict[str, Any]) -> dict[str, Any]:
    """The data a worker needs to run one point (plain data, pickled to the worker).

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")
    >>> job = make_job(sweep.bases["pendulum_noisy"], {"seed": 3}, sweep.settings)
    >>> job["kind"], job["fmus"], job["seed"]
    ('scenario', 'native', 3)
    """
    return {
        "base": base.name, "kind": base.kind, "spec_data": base.spec_data,
        "system": base.system, "files": base.files, "digest": base.digest,
        "design": settings["design"], "fmus": settings["fmus"],
        "evaluation": settings["evaluation"], "params": params,
        "seed": params.get("seed"),
        "step": params.get("step", settings["step"]),
        "stop_time": params.get("stop_time", settings["stop_time"]),
    }


def point_key(job: dict[str, Any]) -> str:
    """Hash of everything a point's row depends on (its base's files, settings, parameters).

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")
    >>> len(sweep.points[0].key)
    16
    """
    data = {k: job[k] for k in ("base", "kind", "digest", "design", "fmus", "evaluation",
                                "params", "step", "stop_time")}
    return _digest(json.dumps(data, sort_keys=True, default=str).encode())


def spec_changes(params: dict[str, Any]) -> dict[tuple[str, ...], Any]:
    """The spec entries a point's parameters set: ``{path: value}``.

    Examples
    --------
    >>> spec_changes({"rho": 3.0, "seed": 1, "spec.noise.process_intensity": 1e-3})
    {('observer', 'rho'): 3.0, ('noise', 'process_intensity'): 0.001}
    """
    return {path: value for axis, value in params.items()
            if (path := spec_axis(axis)) is not None}


def design_spec_data(job: dict[str, Any]) -> dict[str, Any]:
    """The plant spec of a point: its base's spec (with the design's defaults for the design
    ``defaults``, :func:`harness.zoo.default_spec_data`) with the point's spec entries set.

    Examples
    --------
    >>> job = {"spec_data": {"A": [[0]], "observer": {"rho": 2.0}}, "params": {"nu": -0.2}}
    >>> design_spec_data(job)
    {'A': [[0]], 'observer': {'rho': 2.0, 'nu': -0.2}}
    """
    from harness.zoo import default_spec_data

    data = json.loads(json.dumps(job["spec_data"]))
    if job.get("design") == "defaults":
        data = default_spec_data(data)
    for path, value in spec_changes(job["params"]).items():
        table = data
        for key in path[:-1]:
            table = table.setdefault(key, {})
        table[path[-1]] = value
    return data


def design_key(job: dict[str, Any]) -> str:
    """The content hash of a point's design (its spec and the design kind): points that
    differ only by seed, step or start values share it.

    Examples
    --------
    >>> job = {"spec_data": {"A": [[0]]}, "design": "spec", "params": {"seed": 1}}
    >>> design_key(job) == design_key(job | {"params": {"seed": 2}})
    True
    """
    text = json.dumps({"spec": design_spec_data(job), "design": job["design"]}, sort_keys=True)
    return _digest(text.encode())


# -- the worker side --------------------------------------------------------------------------
_DESIGNS: dict[str, Any] = {}
"""Designs of this process by design key: ``(PlantSpec, ObserverDesign)``."""
_FMU_DIRS: dict[str, dict[str, Path]] = {}
"""FMUs built in this process, by design key, flavour and options."""
_WORKDIR: list[Path] = []
"""This process's temporary folder (removed at exit)."""


def _workdir() -> Path:
    if not _WORKDIR:
        path = Path(tempfile.mkdtemp(prefix="fhobs_sweep_"))
        atexit.register(shutil.rmtree, path, ignore_errors=True)
        _WORKDIR.append(path)
    return _WORKDIR[0]


def point_design(job: dict[str, Any]) -> tuple[Any, Any, str]:
    """The point's spec and design, designed once per process for equal specs.

    Returns
    -------
    tuple
        ``(PlantSpec, ObserverDesign, design key)``.

    Examples
    --------
    >>> job = {"base": "b", "spec_data": {"A": [[0, 1], [0, 0]], "B": [[0], [1]],
    ...        "C": [[1, 0]], "observer": {"rho": 2.0}}, "design": "spec", "params": {}}
    >>> spec, design, key = point_design(job)
    >>> design.filtering.rho, point_design(job)[1] is design
    (2.0, True)
    """
    from fhobs.design.kalman import with_kalman
    from fhobs.design.observer import design_for_spec, paper_gains
    from fhobs.design.spec import spec_from_dict

    key = design_key(job)
    if key not in _DESIGNS:
        spec = spec_from_dict(design_spec_data(job), source=f"spec of base {job['base']!r}")
        if job["design"] == "paper":
            design = paper_gains()
            design = design if spec.noise is None else with_kalman(design, spec.noise)
        else:
            design = design_for_spec(spec)  # the design limits checked first
        _DESIGNS[key] = (spec, design)
    return (*_DESIGNS[key], key)


def point_fmus(design: Any, key: str, flavour: str, options: dict[str, Any]) -> dict[str, Path]:
    """The FMUs of a design, built once per process into its temporary folder.

    Parameters
    ----------
    design : ObserverDesign
        The design.
    key : str
        Its design key.
    flavour : str
        ``"native"`` (:func:`fhobs.native.build.build_native_fmus`: any communication step)
        or ``"pythonfmu"`` (:func:`fhobs.build.build_fmus`).
    options : dict
        Keyword arguments of the build: ``kinds`` and start values (``x0``,
        ``noise_amplitude``, ``h``; ``T0`` for the prescribed-time observer).

    Returns
    -------
    dict of str to Path
        ``{kind: path}``.

    Examples
    --------
    >>> spec, design, key = point_design(job)                     # doctest: +SKIP
    >>> sorted(point_fmus(design, key, "native", {}))              # doctest: +SKIP
    ['kalman', 'luenberger', 'observer', 'plant']
    """
    tag = fmu_tag(key, flavour, options)
    if tag not in _FMU_DIRS:
        out = _workdir() / "fmus" / tag
        _FMU_DIRS[tag] = _build(design, out, flavour, dict(options))
    return _FMU_DIRS[tag]


def fmu_tag(key: str, flavour: str, options: dict[str, Any]) -> str:
    """The hash FMUs are cached by: design key, flavour and build options.

    Examples
    --------
    >>> fmu_tag("abc", "native", {}) == fmu_tag("abc", "native", {"kinds": None})
    False
    """
    return _digest(json.dumps([key, flavour, options], sort_keys=True, default=float).encode())


def _build(design: Any, out: Path, flavour: str, options: dict[str, Any]) -> dict[str, Path]:
    """Build the FMUs, native ones with the ``native`` flavour (the Kalman filter's and the
    supervised estimator's only when the design has them)."""
    from fhobs.build import build_fmus
    from fhobs.fmu.kinds import KINDS
    from fhobs.native.build import build_native_fmus

    kinds = options.pop("kinds", None)
    if kinds is not None:  # a kind whose record the design lacks (no [noise] table) is not built
        kinds = [kind for kind in kinds if KINDS[kind].built_when(design)]
    build = build_native_fmus if flavour == "native" else build_fmus
    return build(design, out, kinds=kinds, **options)


def scenario_kinds(job: dict[str, Any]) -> list[str]:
    """The FMU kinds a scenario base's system runs (its FMUs in the built folder).

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")
    >>> scenario_kinds(make_job(sweep.bases["pendulum_noisy"], {}, sweep.settings))
    ['kalman', 'luenberger', 'observer', 'plant']
    """
    return sorted(Path(fs.path).stem for fs in job["system"].fmus.values()
                  if fs.path is not None and str(fs.path).startswith(FMU_PLACEHOLDER))


def build_options(job: dict[str, Any], spec: Any) -> dict[str, Any]:
    """The keyword arguments of a point's FMU build: the kinds its system runs and, for a
    plant-spec base, the start values ``harness plant`` builds with (every kind that runs on
    its measurement noise, :attr:`fhobs.fmu.kinds.Kind.noise_free`; :func:`_build` leaves out
    those whose record the design lacks).

    Examples
    --------
    >>> from fhobs.design.spec import spec_from_dict
    >>> spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]]})
    >>> build_options({"kind": "plant", "step": 1e-3}, spec)["kinds"]
    ['observer', 'prescribed_time', 'luenberger', 'kalman', 'supervised', 'plant']
    """
    from fhobs.fmu.kinds import KINDS

    if job["kind"] != "plant":
        return {"kinds": scenario_kinds(job)}
    noise, step = _plant_noise(spec), _plant_step(job, spec)
    options: dict[str, Any] = {
        "x0": [float(v) for v in spec.state_scale], "noise_amplitude": noise, "h": step,
        "kinds": [k for k in KINDS if not (noise and KINDS[k].noise_free)],
    }
    if noise == 0.0:
        options["T0"] = float(spec.settling_time)
    return options


def _plant_noise(spec: Any) -> float:
    """The plant FMU's uniform noise amplitude for the spec's ``[noise]`` table."""
    return 0.0 if spec.noise is None else float(np.sqrt(3.0) * np.max(spec.noise.measurement_std))


def _plant_step(job: dict[str, Any], spec: Any) -> float:
    from harness.own_plant import STEP

    return job["step"] or (spec.noise.sample_time if spec.noise is not None else STEP)


def point_build(job: dict[str, Any]) -> tuple[Any, Any, dict[str, Path]]:
    """The point's spec, design and FMUs (each made once per process).

    Returns
    -------
    tuple
        ``(PlantSpec, ObserverDesign, {kind: path})``.

    Examples
    --------
    >>> spec, design, fmus = point_build(job)      # doctest: +SKIP
    >>> sorted(fmus)                              # doctest: +SKIP
    ['kalman', 'luenberger', 'observer', 'plant']
    """
    spec, design, key = point_design(job)
    return spec, design, point_fmus(design, key, job["fmus"], build_options(job, spec))


def build_bundle(job: dict[str, Any]) -> dict[str, Any]:
    """Design and build a point's FMUs; the design and the FMU files' bytes, for the workers
    that run the points of the same design (:func:`run_point`): one build per sweep.

    Returns
    -------
    dict
        ``design_key``, ``design`` (ObserverDesign), ``tag`` (:func:`fmu_tag`), ``files``
        (``{kind: (path relative to the FMU folder, bytes)}``) and ``build_s`` (the time of
        the design and the build, s).

    Examples
    --------
    >>> bundle = build_bundle(job)                 # doctest: +SKIP
    >>> run_point(other_job_of_the_same_design, bundle)["status"]  # doctest: +SKIP
    'ok'
    """
    clock = time.perf_counter()
    spec, design, fmus = point_build(job)
    key = design_key(job)
    tag = fmu_tag(key, job["fmus"], build_options(job, spec))
    root = _workdir() / "fmus" / tag
    files = {kind: (str(path.relative_to(root)), path.read_bytes()) for kind, path in fmus.items()}
    return {"design_key": key, "design": design, "tag": tag, "files": files,
            "build_s": time.perf_counter() - clock}


def fmu_bundle(sweep: Sweep, design: Any, fmu_dir: Path) -> dict[str, dict[str, Any]]:
    """The bundles of FMUs built already, for :func:`run_in_process`: ``design``, the design
    of every point of ``sweep`` (a sweep of one design and a scenario base), its FMUs those of
    ``fmu_dir`` (``<kind>.fmu``, of the sweep's flavour) that the scenario runs.

    Returns
    -------
    dict
        ``{build group: bundle}`` (as :func:`build_bundle` makes them, ``build_s`` 0).

    Examples
    --------
    >>> bundles = fmu_bundle(sweep, design, Path("results/ours/fmus/native"))  # doctest: +SKIP
    >>> rows = run_in_process(sweep, bundles)                                 # doctest: +SKIP
    """
    bundles = {}
    for _, job, group in point_jobs(sweep, sweep.points):
        if group not in bundles:
            kinds = scenario_kinds(job)
            files = {kind: (f"{kind}.fmu", (fmu_dir / f"{kind}.fmu").read_bytes())
                     for kind in kinds}
            key = design_key(job)
            bundles[group] = {"design_key": key, "design": design, "files": files,
                              "tag": fmu_tag(key, job["fmus"], build_options(job, None)),
                              "build_s": 0.0}
    return bundles


def install_bundle(job: dict[str, Any], bundle: dict[str, Any]) -> None:
    """Take a bundle of :func:`build_bundle` into this process's caches (its FMUs written
    into this worker's temporary folder), so that the point neither designs nor builds."""
    from fhobs.design.spec import spec_from_dict

    if bundle["design_key"] not in _DESIGNS:
        spec = spec_from_dict(design_spec_data(job), source=f"spec of base {job['base']!r}")
        _DESIGNS[bundle["design_key"]] = (spec, bundle["design"])
    if bundle["tag"] not in _FMU_DIRS:
        root = _workdir() / "fmus" / bundle["tag"]
        paths = {}
        for kind, (relative, data) in bundle["files"].items():
            paths[kind] = root / relative
            paths[kind].parent.mkdir(parents=True, exist_ok=True)
            paths[kind].write_bytes(data)
        _FMU_DIRS[bundle["tag"]] = paths


def point_system(job: dict[str, Any]) -> tuple[SystemSpec, float | None]:
    """The runnable system of a point (designed, FMUs built) and its stop time.

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")                        # doctest: +SKIP
    >>> job = make_job(sweep.bases["pendulum_noisy"], {"seed": 2}, sweep.settings)  # doctest: +SKIP
    >>> point_system(job)[0].fmus["plant"].start["noise_seed"]           # doctest: +SKIP
    2
    """
    from harness.own_plant import RUNS_PER_SETTLING_TIME, own_plant_system
    from harness.system import build_blocks, override_evaluation

    spec, design, fmus = point_build(job)
    if job["kind"] == "plant":
        step = _plant_step(job, spec)
        stop = job["stop_time"] or RUNS_PER_SETTLING_TIME * spec.settling_time
        stop = step * round(stop / step)
        system = own_plant_system(design, fmus, spec.state_scale, stop, step, _plant_noise(spec))
    else:
        system = job["system"]
        step = system.step if job["step"] is None else job["step"]
        system = replace(system, step=step, fmus=_placed(system, fmus, job["files"]))
        stop = job["stop_time"]
        system = build_blocks(system)  # the user's block cache, as every command
    sets = {axis[4:]: value for axis, value in job["params"].items() if axis.startswith("set.")}
    if sets:
        system = system.with_start(sets)
    if job["seed"] is not None:
        system = system.with_seed(job["seed"])
    if job["evaluation"] is not None:
        system = replace(system, evaluation=override_evaluation(
            system.evaluation, job["evaluation"], "[evaluation]"))
    return system, stop


def _placed(system: SystemSpec, fmus: dict[str, Path],
            files: dict[str, bytes]) -> dict[str, Any]:
    """The scenario's FMUs with paths in this worker: ``${fmu_dir}`` -> the built FMUs, other
    FMU files written from the bytes that came with the point."""
    out = {}
    for name, fs in system.fmus.items():
        path = fs.path
        if path is not None and str(path).startswith(FMU_PLACEHOLDER):
            stem = Path(path).stem
            if stem not in fmus:
                raise DescriptionError(f"FMU {name!r}: {Path(path).name} is not built for this "
                                       f"design (built: {', '.join(sorted(fmus))})")
            path = fmus[stem]
        elif path is not None:
            target = _workdir() / "files" / _digest(files[str(path)]) / Path(path).name
            if not target.exists():
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(files[str(path)])
            path = target
        out[name] = replace(fs, path=path)
    return out


def run_point(job: dict[str, Any], bundle: dict[str, Any] | None = None) -> dict[str, Any]:
    """Design, build and co-simulate one point; its row (a failure is a row too).

    Parameters
    ----------
    job : dict
        From :func:`make_job`.
    bundle : dict, optional
        The point's design and FMUs from :func:`build_bundle` (default: designed and built
        here, once per process).

    Returns
    -------
    dict
        The point's parameters, ``status`` (``ok`` or ``failed``), ``reason``, ``note`` (the
        ``[evaluation]`` entries beyond its run, :func:`clipped_note`, or ''), the figures
        ``<estimator>.<figure>``, ``wall_time_s`` (the whole point), ``cosim_s`` (its run),
        ``build_s`` (its design and FMU build, shared with the points of the same design),
        ``started_at``/``finished_at`` (Unix time), ``worker`` and ``pid``.

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")                      # doctest: +SKIP
    >>> job = make_job(sweep.bases["pendulum_perturbed"], {}, sweep.settings)  # doctest: +SKIP
    >>> run_point(job)["status"]                                      # doctest: +SKIP
    'ok'
    """
    from harness.master import MasterError, run_system
    from harness.results import error_figures
    from harness.system import evaluation_outside, resolve_system

    started, clock = time.time(), time.perf_counter()
    row: dict[str, Any] = {"status": STATUS_OK, "reason": "", "note": "", "cosim_s": math.nan}
    try:
        with np.errstate(all="ignore"):
            if bundle is not None:
                row["build_s"] = bundle["build_s"]
                install_bundle(job, bundle)
            system, stop = point_system(job)
            end = system.stop_time if stop is None else stop
            outside = evaluation_outside(system.evaluation, system.start_time, end)
            row["note"] = clipped_note(end, outside) if outside else ""
            result = run_system(resolve_system(system), stop, progress=False)
        row["cosim_s"] = result.wall_time_s
        row["steps"] = result.steps
        for estimator, figures in error_figures(result, system.evaluation).items():
            row |= {f"{estimator}.{name}": value for name, value in figures.items()}
    except Exception as err:  # noqa: BLE001 - a failed point is a row, the sweep goes on
        if isinstance(err, MasterError) and err.interrupted is not None:
            raise  # SIGINT or SIGTERM in this process (run_in_process): the caller stops
        row |= {"status": STATUS_FAILED, "reason": one_paragraph(err)}
    row |= {"wall_time_s": time.perf_counter() - clock, "started_at": started,
            "finished_at": time.time(), "worker": _worker_name(), "pid": os.getpid()}
    return row


def one_paragraph(err: BaseException) -> str:
    """``Type: message`` on one line.

    Examples
    --------
    >>> one_paragraph(ValueError("bad\\nvalue"))
    'ValueError: bad value'
    """
    text = " ".join(str(err).split())
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def _worker_name() -> str:
    """The dask worker's address, or host and process id outside a worker (a process that has
    not imported distributed is none: the in-process runs do not pay for its import)."""
    distributed = sys.modules.get("distributed")
    if distributed is not None:
        with contextlib.suppress(ValueError):
            return str(distributed.get_worker().address)
    return f"{socket.gethostname()}:{os.getpid()}"


# -- the engine -------------------------------------------------------------------------------
@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None,
                connect_timeout: float = CONNECT_TIMEOUT) -> Iterator[Any]:
    """A dask.distributed client: of the cluster at ``scheduler`` (which must answer within
    ``connect_timeout`` seconds, :func:`check_scheduler`), or of an embedded LocalCluster of
    ``workers`` worker processes (default: the core count), one thread each.

    Examples
    --------
    >>> with dask_client(workers=1) as client:                       # doctest: +SKIP
    ...     client.submit(sum, [1, 2]).result()
    3
    """
    import logging

    from distributed import Client, LocalCluster

    if scheduler is not None:
        check_scheduler(scheduler, connect_timeout)
        try:
            client = Client(scheduler, timeout=f"{connect_timeout}s")
        except (OSError, TimeoutError) as err:
            raise SweepError(f"--scheduler {scheduler}: cannot connect ({err}); start one with "
                             "`dask scheduler` and workers with `dask worker ADDRESS`") from None
        with client:
            yield client
        return
    n = workers or os.cpu_count() or 1
    with _without_fmu_paths(), LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
            silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client


@contextlib.contextmanager
def _without_fmu_paths() -> Iterator[None]:
    """``sys.path`` without FMU resource folders while the local workers start: spawned
    processes inherit it, and the slave modules of pythonfmu FMUs this process ran would
    shadow those that the workers' builds import."""
    saved = list(sys.path)
    sys.path[:] = [entry for entry in saved if Path(entry).name != "resources"]
    try:
        yield
    finally:
        sys.path[:] = saved


def read_rows(points_dir: Path) -> dict[str, dict[str, Any]]:
    """The rows already written (``points/<key>.json``), by key.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> write_row(folder, {"key": "abc", "status": "ok"}).name
    'abc.json'
    >>> read_rows(folder)
    {'abc': {'key': 'abc', 'status': 'ok'}}
    """
    rows = {}
    for path in points_dir.glob("*.json"):
        with contextlib.suppress(OSError, ValueError):
            rows[path.stem] = json.loads(path.read_text())
    return rows


def write_row(points_dir: Path, row: dict[str, Any]) -> Path:
    """Write one point's row whole (:func:`harness.writing.write_text`); see
    :func:`read_rows`."""
    return write_text(points_dir / f"{row['key']}.json", json.dumps(row, default=float))


@dataclass
class SweepReport:
    """What a sweep did: ``rows`` in point order, how many ran now, skipped (done before) and
    failed, the table and plot files, the elapsed time of the run (s)."""

    rows: list[dict[str, Any]]
    ran: int
    skipped: int
    failed: int
    files: list[Path]
    elapsed_s: float
    engine_log: Path | None = None
    """The engine's log (:mod:`harness.engine_log`) when it wrote one."""


def run_sweep(sweep: Sweep, out: Path, scheduler: str | None = None, workers: int | None = None,
              retry_failed: bool = False, progress: bool = True,
              plots: bool = True, client: Any = None,
              connect_timeout: float = CONNECT_TIMEOUT) -> SweepReport:
    """Run the points of ``sweep`` that have no row in ``out`` yet, then write the table.

    Parameters
    ----------
    sweep : Sweep
        From :func:`load_sweep`.
    out : Path
        The results folder: ``points/``, ``sweep.parquet``, ``sweep.csv``, ``plots/``.
    scheduler : str, optional
        Address of a running dask scheduler (``tcp://HOST:PORT``); default: an embedded
        LocalCluster.
    workers : int, optional
        Worker processes of the LocalCluster (default: the core count).
    retry_failed : bool
        Rerun the points whose row says failed.
    progress : bool
        Show a tqdm progress bar.
    plots : bool
        Draw the PNGs.
    client : distributed.Client, optional
        A client to use (``scheduler`` and ``workers`` are then ignored).
    connect_timeout : float
        Seconds ``scheduler`` has to answer (:func:`check_scheduler`).

    Returns
    -------
    SweepReport

    Examples
    --------
    >>> report = run_sweep(load_sweep("pendulum_noisy_seeds"), Path("out/seeds"))  # doctest: +SKIP
    >>> report.failed                                                             # doctest: +SKIP
    0
    """
    from fhobs.extras import require
    from tqdm import tqdm

    for module in ("distributed", "pyarrow"):
        require(module, "sweep")
    from harness.engine_log import ENGINE_LOG, EngineLog, engine_log

    started = time.perf_counter()
    points_dir = out / "points"
    points_dir.mkdir(parents=True, exist_ok=True)
    done = read_rows(points_dir)
    todo = [p for p in sweep.points if p.key not in done
            or (retry_failed and done[p.key].get("status") != STATUS_OK)]
    log = out / ENGINE_LOG
    if todo:
        with contextlib.ExitStack() as stack:
            stack.enter_context(engine_log(log))
            if client is None:
                client = stack.enter_context(dask_client(scheduler, workers, connect_timeout))
                if scheduler is None:
                    client.register_plugin(EngineLog(log))
            bar = stack.enter_context(tqdm(total=len(todo), desc=f"sweep {sweep.name}",
                                           unit="point", disable=not progress))
            for point, row in _submit(client, sweep, todo):
                write_row(points_dir, _full_row(sweep, point, row))
                bar.update(1)
    rows = _ordered_rows(sweep, read_rows(points_dir))
    files = write_table(rows, out)
    if plots:
        from harness.sweep_plots import plot_sweep

        files += plot_sweep(rows, sweep, out / "plots")
    failed = sum(r["status"] != STATUS_OK for r in rows)
    return SweepReport(rows, len(todo), len(sweep.points) - len(todo), failed, files,
                       time.perf_counter() - started, log if log.is_file() else None)


def _submit(client: Any, sweep: Sweep, todo: list[Point]) -> Iterator[tuple[Point, dict]]:
    """Submit the points; yield ``(point, row)`` as each finishes (a task the cluster gave up
    on, after the workers running it died, yields a failed row)."""
    from distributed import as_completed

    futures, builds = {}, {}
    token = uuid.uuid4().hex[:8]
    for point, job, group in point_jobs(sweep, todo):
        if group not in builds:
            builds[group] = client.submit(build_bundle, job, key=f"fhobs-build-{group}-{token}",
                                          pure=False)
        future = client.submit(run_point, job, builds[group], key=f"fhobs-sweep-{point.key}",
                               pure=False)
        futures[future.key] = (future, point)
    for future in as_completed([f for f, _ in futures.values()]):
        point = futures[future.key][1]
        try:
            row = future.result()
        except Exception as err:  # noqa: BLE001 - e.g. KilledWorker: the point failed
            row = {"status": STATUS_FAILED, "reason": one_paragraph(err)}
        future.release()
        yield point, row


def point_jobs(sweep: Sweep, points: list[Point]) -> Iterator[tuple[Point, dict, str]]:
    """Each point with its job (:func:`make_job`) and build group (:func:`build_group`).

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")
    >>> [(p.index, job["seed"]) for p, job, _ in point_jobs(sweep, sweep.points[:2])]
    [(0, None), (1, 0)]
    """
    for point in points:
        job = make_job(sweep.bases[point.params.get("base", sweep.settings["base"])],
                       point.params, sweep.settings)
        yield point, job, build_group(job)


def run_in_process(sweep: Sweep, bundles: dict[str, dict[str, Any]] | None = None
                   ) -> list[dict[str, Any]]:
    """Every point of ``sweep`` run in this process, one after the other, with no cluster and
    no file written: the engine's tasks (:func:`build_bundle` once per design and FMU build,
    unless ``bundles`` has it; :func:`run_point` per point) and rows (as in the table of
    :func:`run_sweep`), for a few short points where starting a cluster costs more than
    running them.

    Parameters
    ----------
    sweep : Sweep
        From :func:`load_sweep` or :func:`sweep_from_table`.
    bundles : dict, optional
        ``{build group: bundle}`` of designs built already (:func:`fmu_bundle`).

    Returns
    -------
    list of dict
        The rows, in point order.

    Examples
    --------
    >>> rows = run_in_process(load_sweep("pendulum_noisy_seeds"))    # doctest: +SKIP
    >>> [(r["base"], r["seed"], r["status"]) for r in rows][:2]       # doctest: +SKIP
    [('pendulum_perturbed', None, 'ok'), ('pendulum_noisy', 0, 'ok')]
    """
    built = dict(bundles or {})
    rows = []
    for point, job, group in point_jobs(sweep, sweep.points):
        if group not in built:
            built[group] = build_bundle(job)
        rows.append(_full_row(sweep, point, run_point(job, built[group])))
    return rows


def build_group(job: dict[str, Any]) -> str:
    """The points that share one design and FMU build (:func:`build_bundle`) share this hash:
    the design key, the FMU flavour and what is built: a scenario base's FMU kinds (two
    scenarios of the same FMUs share the build), a plant base's step.

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")
    >>> jobs = [make_job(sweep.bases[p.params["base"]], p.params, sweep.settings)
    ...         for p in sweep.points]
    >>> len({build_group(job) for job in jobs})
    1
    """
    built = (["plant", job["base"], job["step"]] if job["kind"] == "plant"
             else scenario_kinds(job))
    data = [design_key(job), job["fmus"], built]
    return _digest(json.dumps(data, default=str).encode())


def _full_row(sweep: Sweep, point: Point, row: dict[str, Any]) -> dict[str, Any]:
    """A worker's row with the point's identity and parameters first."""
    params = {axis: point.params.get(axis) for axis in sweep.axes}
    return {"point": point.index, "key": point.key, "sweep": sweep.name, **params, **row}


def _ordered_rows(sweep: Sweep, rows: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows of this sweep's points, in point order (rows of other points are ignored)."""
    return [rows[p.key] | {"point": p.index} for p in sweep.points if p.key in rows]


def write_table(rows: list[dict[str, Any]], out: Path) -> list[Path]:
    """``sweep.parquet`` and ``sweep.csv``: one row per point, one column per key (lists as
    JSON text, a figure a point lacks as null). Both are written to temporary names and
    renamed over the previous ones when both are complete (a failure leaves the previous
    table, :func:`harness.writing.atomic_path`); a signal meanwhile ends the command after
    both (:func:`harness.writing.completed`).

    Examples
    --------
    >>> import tempfile
    >>> files = write_table([{"point": 0, "rho": 3.0, "x0": [1, 0]}], Path(tempfile.mkdtemp()))
    >>> [f.name for f in files]
    ['sweep.parquet', 'sweep.csv']
    """
    import pyarrow as pa
    import pyarrow.csv as pa_csv
    import pyarrow.parquet as pq

    columns = list(dict.fromkeys(k for row in rows for k in row))
    data = {c: [_cell(row.get(c)) for row in rows] for c in columns}
    table = pa.table({c: _column(values) for c, values in data.items()}) if rows else \
        pa.table({"point": pa.array([], pa.int64())})
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "sweep.parquet", out / "sweep.csv"]
    with completed(f"the sweep table was written to {out} (points/ holds each point's row)"), \
            contextlib.ExitStack() as renames:  # both renamed once both are written
        for path, write in zip(paths, (pq.write_table, pa_csv.write_csv), strict=True):
            write(table, str(renames.enter_context(atomic_path(path))))
    return paths


def read_table(path: str | Path) -> Any:
    """A sweep's table as a pandas DataFrame: ``DIR/sweep.parquet`` (or ``sweep.csv``, or the
    folder ``DIR``), one row per point; lists are JSON text, a figure a point lacks is NaN
    (a number column) or None.

    Examples
    --------
    >>> import tempfile
    >>> out = Path(tempfile.mkdtemp())
    >>> _ = write_table([{"point": 0, "rho": 3.0, "kalman.peak": 1.5},
    ...                  {"point": 1, "rho": 4.0}], out)
    >>> frame = read_table(out)
    >>> frame["rho"].tolist(), frame["kalman.peak"].isna().tolist()
    ([3.0, 4.0], [False, True])
    """
    from fhobs.extras import require

    require("pandas", "sweep")
    path = Path(path)
    if path.is_dir():
        path = path / "sweep.parquet"
    if path.suffix == ".csv":
        import pyarrow.csv as pa_csv

        return pa_csv.read_csv(str(path)).to_pandas()
    import pyarrow.parquet as pq

    return pq.read_table(str(path)).to_pandas()


def _cell(value: Any) -> Any:
    return json.dumps(value) if isinstance(value, list | dict) else value


def _column(values: list[Any]) -> Any:
    """One column: numbers as float64 (int64 when all are integers), else text."""
    import pyarrow as pa

    present = [v for v in values if v is not None]
    if all(isinstance(v, bool) for v in present) and present:
        return pa.array(values, pa.bool_())
    if all(isinstance(v, int) and not isinstance(v, bool) for v in present) and present:
        return pa.array(values, pa.int64())
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in present):
        return pa.array([None if v is None else float(v) for v in values], pa.float64())
    return pa.array([None if v is None else str(v) for v in values], pa.string())


# -- plots ------------------------------------------------------------------------------------
def figure_columns(rows: list[dict[str, Any]]) -> dict[str, list[str]]:
    """``{figure: [estimator, ...]}`` of the ``<estimator>.<figure>`` columns.

    Examples
    --------
    >>> figure_columns([{"homogeneous.rms_error_1_3": 1e-3, "linear.rms_error_1_3": 2e-3}])
    {'rms_error_1_3': ['homogeneous', 'linear']}
    """
    from harness.results import FIGURE_PREFIXES

    out: dict[str, list[str]] = {}
    for column in dict.fromkeys(k for row in rows for k in row):
        estimator, dot, figure = column.partition(".")
        if dot and figure.startswith(FIGURE_PREFIXES):
            out.setdefault(figure, []).append(estimator)
    return out


class ParetoPoint(NamedTuple):
    """One design of one estimator in the Pareto picture: ``x`` its max error in the
    perturbation base, ``y`` its RMS error in the noisy base (mean over the seeds), ``label``
    and ``params`` its design's axis values (``{axis: value}``), ``y_min`` and ``y_max`` the
    least and largest RMS over the seeds (``y`` when not given)."""

    x: float
    y: float
    label: str
    params: dict[str, Any]
    y_min: float = math.nan
    y_max: float = math.nan

    def spread(self) -> tuple[float, float]:
        """``(y_min, y_max)``, each ``y`` when not given.

        Examples
        --------
        >>> ParetoPoint(1.0, 2.0, "a", {}).spread(), ParetoPoint(1.0, 2.0, "a", {}, 1.5).spread()
        ((2.0, 2.0), (1.5, 2.0))
        """
        return (self.y if math.isnan(self.y_min) else self.y_min,
                self.y if math.isnan(self.y_max) else self.y_max)


def pareto_points(rows: list[dict[str, Any]], sweep: Sweep) -> dict[str, list[ParetoPoint]]:
    """Per estimator, a :class:`ParetoPoint` per design: the rows of the two bases of
    ``[pareto]`` paired on every axis but base and seed, the noisy RMS averaged over the seeds.
    With ``[pareto.estimators]`` only the estimators it names, each paired on its own axes
    over the rows that set no other axis (base and seed aside).

    Returns
    -------
    dict
        ``{estimator: [ParetoPoint, ...]}``; empty when the figures are missing.

    Examples
    --------
    >>> sweep = load_sweep("pendulum_noisy_seeds")
    >>> rows = [{"base": "pendulum_perturbed", "kalman.max_error_1_3": 1e-3},
    ...         {"base": "pendulum_noisy", "seed": 0, "kalman.rms_error_1_3": 2e-3},
    ...         {"base": "pendulum_noisy", "seed": 1, "kalman.rms_error_1_3": 4e-3}]
    >>> pareto_points(rows, sweep)
    {'kalman': [ParetoPoint(x=0.001, y=0.003, label='no axis', params={}, y_min=0.002, \
y_max=0.004)]}
    """
    figures = pareto_figures(rows, sweep)
    if figures is None:
        return {}
    xfig, yfig = figures
    others = [a for a in sweep.axes if a not in ("base", "seed")]
    selected = sweep.pareto.get("estimators") or dict.fromkeys(
        figure_columns(rows).get(xfig, []), others)
    base = sweep.settings["base"]
    out: dict[str, list[ParetoPoint]] = {}
    for estimator, axes in selected.items():
        groups: dict[str, tuple[dict, dict[str, list[dict]]]] = {}
        for r in rows:
            if any(r.get(a) is not None for a in others if a not in axes):
                continue  # a design of another estimator
            params = {a: r.get(a) for a in axes}
            group = groups.setdefault(_describe(params), (params, {}))[1]
            group.setdefault(r.get("base") or base, []).append(r)
        for label, (params, by_base) in groups.items():
            pert = by_base.get(sweep.pareto["perturbation"])
            noisy = by_base.get(sweep.pareto["noisy"])
            if not pert or not noisy:
                continue
            xs = [r.get(f"{estimator}.{xfig}") for r in pert]
            ys = [r.get(f"{estimator}.{yfig}") for r in noisy]
            if None in xs or None in ys:
                continue
            out.setdefault(estimator, []).append(ParetoPoint(
                float(np.mean(xs)), float(np.mean(ys)), label, params, float(min(ys)),
                float(max(ys))))
    return out


def pareto_figures(rows: list[dict[str, Any]], sweep: Sweep) -> tuple[str, str] | None:
    """The Pareto picture's figures: the first max error of the perturbation base's rows and
    the first RMS error of the noisy base's; None when one is missing.

    Examples
    --------
    >>> pareto_figures([{"base": "pendulum_perturbed", "kalman.max_error_1_3": 1.0},
    ...                 {"base": "pendulum_noisy", "kalman.rms_error_1_3": 1.0}],
    ...                load_sweep("pendulum_noisy_seeds"))
    ('max_error_1_3', 'rms_error_1_3')
    """
    xfig = _first(rows, sweep.pareto["perturbation"], "max_error_")
    yfig = _first(rows, sweep.pareto["noisy"], "rms_error_")
    return None if xfig is None or yfig is None else (xfig, yfig)


def _first(rows: list[dict[str, Any]], base: str, prefix: str) -> str | None:
    """The first figure of ``prefix`` in the rows of ``base``."""
    for row in rows:
        if row.get("base", base) in (base, None):
            for column in row:
                figure = column.partition(".")[2]
                if figure.startswith(prefix):
                    return figure
    return None


def format_report(report: SweepReport, sweep: Sweep, out: Path) -> str:
    """The command's closing lines: counts, one line per failure reason
    (:func:`failure_lines`) and per note (:func:`note_lines`), files, the engine's log.

    Examples
    --------
    >>> rep = SweepReport([{"point": 0, "status": "ok"}], 1, 0, 0, [], 1.0)
    >>> print(format_report(rep, load_sweep("pendulum_noisy_seeds"), Path("out")))
    sweep pendulum_noisy_seeds: 6 points, 1 run now, 0 done before, 0 failed, 1.0 s
    table: out/sweep.parquet, out/sweep.csv
    """
    lines = [f"sweep {sweep.name}: {len(sweep.points)} points, {report.ran} run now, "
             f"{report.skipped} done before, {report.failed} failed, {report.elapsed_s:.1f} s"]
    lines += failure_lines(report.rows) + note_lines(report.rows)
    lines.append(f"table: {out / 'sweep.parquet'}, {out / 'sweep.csv'}")
    pngs = [str(p) for p in report.files if p.suffix == ".png"]
    if pngs:
        lines.append(f"plots: {', '.join(pngs)}")
    if report.engine_log is not None:
        lines.append(f"engine log (tracebacks): {report.engine_log}")
    return "\n".join(lines)


def failure_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One line per distinct reason of the failed rows: how many points, the first of them
    (rows in point order), the reason.

    Examples
    --------
    >>> rows = [{"point": 0, "status": "ok"},
    ...         {"point": 1, "status": "failed", "reason": "SpecError: rho"},
    ...         {"point": 2, "status": "failed", "reason": "MasterError: bogus"},
    ...         {"point": 3, "status": "failed", "reason": "SpecError: rho"}]
    >>> print("\\n".join(failure_lines(rows)))
      2 points failed (first: point 1): SpecError: rho
      1 point failed (first: point 2): MasterError: bogus
    """
    points: dict[str, list[int]] = {}
    for row in rows:
        if row.get("status") != STATUS_OK:
            points.setdefault(row.get("reason") or "no reason given", []).append(row["point"])
    return [f"  {len(each)} point{'s' if len(each) > 1 else ''} failed (first: point "
            f"{each[0]}): {reason}" for reason, each in points.items()]


def note_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One line per distinct note of the finished rows (an ``[evaluation]`` entry beyond a
    point's run, :func:`clipped_note`): how many points, the first of them, the note.

    Examples
    --------
    >>> rows = [{"point": 0, "status": "ok", "note": "stop_time 0.05 ends ..."},
    ...         {"point": 1, "status": "ok", "note": ""},
    ...         {"point": 2, "status": "ok", "note": "stop_time 0.05 ends ..."}]
    >>> note_lines(rows)
    ['  note: 2 points (first: point 0): stop_time 0.05 ends ...']
    """
    points: dict[str, list[int]] = {}
    for row in rows:
        if row.get("status") == STATUS_OK and row.get("note"):
            points.setdefault(row["note"], []).append(row["point"])
    return [f"  note: {len(each)} point{'s' if len(each) > 1 else ''} (first: point "
            f"{each[0]}): {note}" for note, each in points.items()]


def clipped_note(stop: float, outside: list[str]) -> str:
    """A point's note when its run ends before entries of its ``[evaluation]``
    (:func:`harness.system.evaluation_outside`), as ``harness run --stop-time`` says it.

    Examples
    --------
    >>> clipped_note(0.05, ["at = 0.1", "window [0.1, 0.2]"])
    'stop_time 0.05 ends the run before its [evaluation] at = 0.1, window [0.1, 0.2]: no \
figures for them'
    """
    return (f"stop_time {stop:g} ends the run before its [evaluation] {', '.join(outside)}: "
            "no figures for them")


def check_workers(workers: int | None) -> None:
    """SweepError unless ``--workers`` is None or from 1 to :data:`WORKERS_PER_CORE` times the
    core count.

    Examples
    --------
    >>> check_workers(0)
    Traceback (most recent call last):
    ...
    harness.sweep.SweepError: --workers = 0 must be >= 1
    >>> check_workers(10**6)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    harness.sweep.SweepError: --workers = 1000000: at most ... (4 per core of this machine's ...)
    """
    if workers is not None and workers < 1:
        raise SweepError(f"--workers = {workers} must be >= 1")
    cores = os.cpu_count() or 1
    if workers is not None and workers > WORKERS_PER_CORE * cores:
        raise SweepError(f"--workers = {workers}: at most {WORKERS_PER_CORE * cores} "
                         f"({WORKERS_PER_CORE} per core of this machine's {cores}; each worker "
                         "is a process running one point at a time)")


def check_connect_timeout(seconds: float) -> None:
    """SweepError unless ``--connect-timeout`` is > 0 and at most :data:`MAX_CONNECT_TIMEOUT`.

    Examples
    --------
    >>> check_connect_timeout(float("nan"))
    Traceback (most recent call last):
    ...
    harness.sweep.SweepError: --connect-timeout = nan must be > 0 and at most 3600 s
    """
    if not 0.0 < seconds <= MAX_CONNECT_TIMEOUT:
        raise SweepError(f"--connect-timeout = {seconds:g} must be > 0 and at most "
                         f"{MAX_CONNECT_TIMEOUT:g} s")


def check_scheduler(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """SweepError unless a dask scheduler answers at ``address`` within ``timeout`` seconds:
    a ``tcp://HOST:PORT`` (or ``HOST:PORT``) address, connected to and asked its identity.

    Examples
    --------
    >>> check_scheduler("http://localhost:8786")
    Traceback (most recent call last):
    ...
    harness.sweep.SweepError: --scheduler http://localhost:8786: not a dask scheduler's address: \
give tcp://HOST:PORT (the address `dask scheduler` prints)
    """
    import asyncio

    scheme, sep, rest = address.partition("://")
    host, _, port = (rest if sep else address).rpartition(":")
    if (sep and scheme != "tcp") or not host or not port.isdigit():
        tls = " (TLS needs certificates this command does not take)" if scheme == "tls" else ""
        raise SweepError(f"--scheduler {address}: not a dask scheduler's address{tls}: give "
                         "tcp://HOST:PORT (the address `dask scheduler` prints)")
    try:
        asyncio.run(_identity(f"tcp://{host}:{port}", timeout))
    except (OSError, TimeoutError, ValueError, KeyError) as err:
        raise SweepError(
            f"--scheduler {address}: no dask scheduler answered within {timeout:g} s "
            f"({type(err).__name__}{': ' if str(err) else ''}{err}); start one with `dask "
            "scheduler` and workers with `dask worker ADDRESS`, or give a longer "
            "--connect-timeout") from None


async def _identity(address: str, timeout: float) -> dict[str, Any]:
    """The scheduler's answer to ``identity`` (a dict with its ``type``), each step of the
    exchange bounded by ``timeout`` seconds in all."""
    import asyncio

    from distributed.comm import connect

    async def exchange() -> dict[str, Any]:
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity", "reply": True})
            answer = await comm.read()
        finally:
            comm.abort()
        if not isinstance(answer, dict) or answer.get("type") != "Scheduler":
            raise ValueError(f"the server answered {str(answer)[:80]!r}, not as a scheduler")
        return answer

    return await asyncio.wait_for(exchange(), timeout)


__all__ = ["Base", "ParetoPoint", "Point", "Sweep", "SweepError", "SweepReport",
           "check_connect_timeout", "check_scheduler", "dask_client", "failure_lines",
           "fmu_bundle", "load_sweep", "make_job", "pareto_figures", "pareto_points",
           "point_jobs", "point_key", "read_table", "run_in_process", "run_point", "run_sweep",
           "sweep_from_table", "write_table"]
