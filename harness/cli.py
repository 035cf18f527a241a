"""Command line: ``python -m harness {run,paper,plant,list,export-ssp,sweep,linearize} ...``.

- ``run SCENARIO --out DIR``: co-simulate one system description (a file, or the name of a
  bundled scenario such as ``pendulum_nominal``); writes ``results.csv``, ``summary.json`` and
  the plots into DIR. ``--seeds N`` runs N seeds and averages the figures.
- ``paper --out DIR``: the main job. For each design (``--design both``, the default: our design
  of examples/pendulum.toml, label ``ours``, and the paper's published gains, label ``paper``)
  builds the pendulum FMUs (build_fmu.py's machinery; the Kalman filter baseline, kalman.fmu,
  from the spec's ``[noise]`` table for both) into ``DIR/<label>/fmus`` (pythonfmu) and
  ``DIR/<label>/fmus/native``, runs the three paper scenarios with the native FMUs (the same
  results, ten times faster; ``--pythonfmu``: with the pythonfmu ones; the noisy scenario over 5
  seeds, on the sweep engine in the design's process; homogeneous, Luenberger and Kalman
  estimates side by side) into
  ``DIR/<label>/<scenario>/``, the two designs in parallel processes, prints one table of the
  summary figures and writes it with its legend to ``DIR/summary.md``.
- ``plant SPEC --out DIR``: your own plant: designs its observer (the design's defaults where
  the spec is silent), builds its FMUs into ``DIR/fmus`` and runs the default scenario of
  :mod:`harness.own_plant` (x(0) = state_scale, observers at zero, u = K x on the true state,
  three settling times; the spec's ``[disturbance]`` fed to the plant's q, its ``[mismatch]``
  or ``--mismatch`` perturbing the plant FMU's A and B); results (x and q errors over the
  transient and the steady window) and plots (errors, states, q against its estimates) in DIR.
  ``--tolerance T``: the relative tolerance every FMU gets in ``fmi2SetupExperiment`` (default
  1e-10 with a ``[plant_model]``, whose FMUs integrate with their own solver, none otherwise).
  ``--export-ssp FILE``: the run's system (a ``[plant_model]``'s FMUs as they are, with the
  start values and bindings the run sets, the run's seed) also written as an SSP
  (:func:`harness.ssp.export_ssp`: connections lowered to blocks), before the run, which then
  goes on; with ``--native`` no FMU of it needs Python, else refused (exit 2, before anything
  is built) unless ``--allow-python``.
- ``list``: the bundled scenarios.
- ``export-ssp SCENARIO --out FILE.ssp``: the system as an SSP file (gains as FMUs); refused
  (exit 2, each FMU named) when FMUs of it need Python (pythonfmu FMUs, the ``signal`` block),
  unless ``--allow-python``.
- ``sweep SWEEP.toml --out DIR``: the points of a sweep file (design axes, spec entries, start
  values, seeds, steps; a grid or seeded random samples) on dask, one table of their figures
  (:mod:`harness.sweep`); exit 1 when points failed, one line per failure reason, the engine's
  tracebacks in ``DIR/engine.log`` (:mod:`harness.engine_log`).
- ``linearize MODEL --input U --output Y [--unknown-input Q] --out SPEC.toml``: a plant FMU
  (Model Exchange) or SSP linearised at its start values (``--set``, ``--at``) into a plant
  spec (:mod:`harness.linearize`, :mod:`harness.spec_writer`).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from fhobs.cli import check_output_folder, program_name
from fhobs.core.gains import ObserverDesign
from fhobs.design.spec import PlantSpec
from fhobs.errors import FhobsError, SpecError
from fhobs.paper import PENDULUM_SPEC

from harness.master import CoSimResult, MasterError, run_system
from harness.own_plant import (
    RUNS_PER_SETTLING_TIME,
    STEP,
    own_plant_system,
    plant_table,
    run_own_plant,
    transient_end,
)
from harness.results import (
    DIVERGED,
    divergence_note,
    summary,
    table_label,
    write_csv,
    write_summary,
)
from harness.sweep import CONNECT_TIMEOUT, MAX_SEEDS
from harness.system import (
    DescriptionError,
    SystemSpec,
    build_blocks,
    check_timing,
    evaluation_outside,
    load_system,
    resolve_system,
    run_tolerance,
)
from harness.writing import (
    NOTHING_WRITTEN,
    Interrupted,
    complete_written,
    completed,
    rows_written,
    write_text,
)

SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"
PAPER_SCENARIO_FILES = {"nominal": "pendulum_nominal", "perturbed": "pendulum_perturbed",
                        "perturbed_noisy": "pendulum_noisy"}
"""The bundled scenario of each of the paper's scenarios (keys of fhobs.paper.PAPER_SCENARIOS)."""
PAPER_SEEDS = {"pendulum_noisy": 5}
MAX_SEED = 2**31 - 1
"""The largest seed: the seeds are 32-bit FMI Integers (the plant's and the noise block's
``seed``), and numpy's seeds are non-negative."""
PAPER_CSV_EVERY = 20
"""The main job writes every 20th point (1 ms at the paper's step) of its 60,000-step runs."""


def scenario_path(name: str) -> Path:
    """A file path, or a bundled scenario's name (``pendulum_nominal``)."""
    path = Path(name)
    if path.suffix == ".toml" or path.exists():
        return path
    bundled = SCENARIO_DIR / f"{name}.toml"
    if not bundled.exists():
        have = sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))
        raise DescriptionError(f"no scenario file {name!r} and no bundled scenario (have {have})")
    return bundled


def parse_value(text: str) -> Any:
    """``--set`` values: JSON (numbers, true/false, lists) or a plain number."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number, boolean or list") from None


def parse_assignment(text: str) -> tuple[str, Any]:
    """``fmu.var=VALUE`` -> ``("fmu.var", value)``."""
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    return name.strip(), parse_value(value.strip())


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=program_name("python -m harness"),
        description="Co-simulate FMUs with fmpy: the paper's scenarios, your own plant, any "
                    "system description.")
    sub = parser.add_subparsers(dest="command", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--fmu-dir", type=Path, help="value of ${fmu_dir} in FMU paths")
    common.add_argument("--block-cache", type=Path, help="where harness blocks are built")
    common.add_argument("--csv-every", type=int, default=None, metavar="K",
                        help="write every K-th communication point to results.csv (figures "
                             f"use every point; default 1, paper: {PAPER_CSV_EVERY})")
    run = sub.add_parser("run", parents=[common], help="run one scenario")
    run.add_argument("scenario", help="system description file or bundled scenario name")
    run.add_argument("--out", type=Path, required=True, help="results folder")
    run.add_argument("--stop-time", type=float, help="override the stop time")
    run.add_argument("--step", type=float, help="override the communication step")
    seeds = run.add_mutually_exclusive_group()
    seeds.add_argument("--seed", type=int, help="set the scenario's seed variable")
    seeds.add_argument("--seeds", type=int, help="run seeds 0..N-1 and average the figures")
    run.add_argument(
        "--set",
        dest="overrides",
        action="append",
        type=parse_assignment,
        default=[],
        metavar="FMU.VAR=VALUE",
        help="start-value override (repeat)",
    )
    run.add_argument("--jobs", type=int, default=2, help="parallel processes for --seeds")
    run.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    paper = sub.add_parser("paper", parents=[common], help="build the FMUs, run the paper")
    paper.add_argument("--out", type=Path, default=Path("results"), help="results folder")
    paper.add_argument(
        "--design",
        choices=("both", "spec", "paper"),
        default="both",
        help="spec: our design of --spec (label ours); paper: the published gains; both",
    )
    paper.add_argument(
        "--spec", type=Path, default=PENDULUM_SPEC,
        help="plant spec (--design spec); its [noise] table gives both designs' Kalman filter"
    )
    paper.add_argument("--stop-time", type=float, help="override the stop time")
    paper.add_argument("--jobs", type=int, default=2,
                       help="parallel processes: one per design")
    paper.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    paper.add_argument("--pythonfmu", action="store_true",
                       help="run the scenarios with the pythonfmu FMUs (fmus/) rather than the "
                            "native ones (fmus/native; the same results)")
    plant = sub.add_parser(
        "plant", parents=[common],
        help="design and build the FMUs of your own plant spec and run its default scenario",
    )
    plant.add_argument("spec", type=Path, help="plant spec TOML file")
    plant.add_argument("--out", type=Path, required=True, help="results folder (FMUs in fmus/)")
    plant.add_argument("--stop-time", type=float,
                       help=f"run length (default {RUNS_PER_SETTLING_TIME:g} settling times)")
    plant.add_argument("--step", type=float,
                       help=f"communication step (default the [noise] sample time, else {STEP:g})")
    plant.add_argument("--seed", type=int, default=0, help="measurement noise seed")
    plant.add_argument("--tolerance", type=float,
                       help="the relative tolerance every FMU gets in fmi2SetupExperiment "
                            "(default: 1e-10 with a [plant_model], whose FMUs integrate with "
                            "their own solver; none otherwise, the generated FMUs need none)")
    plant.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    plant.add_argument("--tune-noise", action="store_true",
                       help="design for the spec's [noise] and [disturbance] tables "
                            "(build_fmu.py --tune-noise) and show the measured figures beside "
                            "the predicted ones")
    plant.add_argument("--native", action="store_true",
                       help="also build native FMUs for the step (fmus/native) and run them")
    plant.add_argument("--mismatch", type=float, metavar="SIZE",
                       help="perturb the plant FMU's A and B by this relative size (0.1 = "
                            "10 %%; the spec's [mismatch] distribution, default gaussian); the "
                            "observers keep the nominal model")
    plant.add_argument("--mismatch-seed", type=int, metavar="N",
                       help="seed of the mismatch (default: the [mismatch] table's, else 0)")
    plant.add_argument("--export-ssp", type=Path, metavar="FILE",
                       help="also write the run's system as an SSP file (before the run)")
    plant.add_argument("--allow-python", action="store_true",
                       help="--export-ssp without --native: export the pythonfmu FMUs")
    sub.add_parser("list", help="list the bundled scenarios")
    ssp = sub.add_parser("export-ssp", parents=[common], help="export a scenario as SSP")
    ssp.add_argument("scenario")
    ssp.add_argument("--out", type=Path, required=True, help="the .ssp file")
    ssp.add_argument("--native-blocks", action=argparse.BooleanOptionalAction, default=None,
                     help="native harness blocks, so no FMU of the SSP needs Python (default: "
                          "when the --fmu-dir FMUs are native)")
    ssp.add_argument("--allow-python", action="store_true",
                     help="export even when FMUs of the SSP need Python (pythonfmu FMUs, the "
                          "signal block); without it such an export is refused, each FMU named")
    sweep = sub.add_parser("sweep", help="run a sweep file's points on dask (harness/sweep.py)")
    sweep.add_argument("sweep", help="sweep file or bundled sweep name (harness/sweeps/)")
    sweep.add_argument("--out", type=Path, required=True,
                       help="results folder (a re-run skips the points done there)")
    sweep.add_argument("--scheduler", help="address of a running dask scheduler "
                                           "(tcp://HOST:PORT); default: a local cluster")
    sweep.add_argument("--workers", type=int, help="local cluster's worker processes "
                                                   "(default: the core count)")
    sweep.add_argument("--connect-timeout", type=float, default=CONNECT_TIMEOUT,
                       metavar="SECONDS", help="seconds the --scheduler has to answer "
                                               f"(default {CONNECT_TIMEOUT:g})")
    sweep.add_argument("--retry-failed", action="store_true", help="rerun the failed points")
    sweep.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    sweep.add_argument("--no-progress", action="store_true", help="no progress bar")
    lin = sub.add_parser("linearize", help="linearise a plant FMU or SSP into a plant spec "
                                           "(harness/linearize.py)")
    lin.add_argument("model", type=Path, help="the plant: an FMI 2.0 FMU with Model Exchange, "
                                              "or an SSP of such FMUs")
    lin.add_argument("--input", nargs="+", required=True, metavar="NAME",
                     help="the inputs u (B's columns)")
    lin.add_argument("--output", nargs="+", required=True, metavar="NAME",
                     help="the measured outputs y (C's rows)")
    lin.add_argument("--unknown-input", nargs="+", default=[], metavar="NAME",
                     help="the unknown inputs q (E's columns)")
    lin.add_argument("--system", help="the SSP's (sub)system whose connectors are the ports "
                                      "(e.g. DC-Motor.SuT; default the top system)")
    lin.add_argument("--at", type=float, help="simulate to this time first (inputs held)")
    lin.add_argument("--set", dest="overrides", action="append", type=parse_assignment,
                     default=[], metavar="VAR=VALUE",
                     help="start value (SSP: component.var=VALUE; repeat)")
    lin.add_argument("--out", type=Path, required=True, help="the spec TOML file to write")
    return parser


def load_scenario(name: str, fmu_dir: Path | None, block_cache: Path | None) -> SystemSpec:
    """Load a scenario with an optional ``${fmu_dir}`` and build its harness blocks."""
    variables = {} if fmu_dir is None else {"fmu_dir": str(Path(fmu_dir).resolve())}
    return build_blocks(load_system(scenario_path(name), variables), block_cache)


def _run_one(spec: SystemSpec, stop_time: float | None) -> CoSimResult:
    return run_system(resolve_system(spec), stop_time)


def run_seeds(
    spec: SystemSpec, seeds: list[int], stop_time: float | None, jobs: int
) -> list[CoSimResult]:
    """Run ``spec`` once per seed, in up to ``jobs`` processes."""
    specs = [spec.with_seed(s) for s in seeds]
    if jobs <= 1 or len(specs) == 1:
        return [_run_one(s, stop_time) for s in specs]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        return list(pool.map(_run_one, specs, [stop_time] * len(specs)))


def mean_summary(each: list[dict[str, Any]], spec: SystemSpec, seeds: list[int] | None,
                 stop_time: float, **run: Any) -> dict[str, Any]:
    """summary.json of one or several seeded runs, each run's figures as
    :func:`harness.results.summary` gives them: the figures averaged over the seeds, an
    estimator flagged ``diverged`` if it diverged with any seed."""
    out = {
        **run,
        "scenario": spec.name,
        "step": spec.step,
        "stop_time": stop_time,
        "steps": each[0]["steps"],
        "wall_time_s": float(np.mean([s["wall_time_s"] for s in each])),
    }
    for name in spec.evaluation.errors:
        out[name] = {k: float(np.mean([s[name][k] for s in each])) for k in each[0][name]
                     if k != DIVERGED}
        if any(s[name].get(DIVERGED) for s in each):
            out[name][DIVERGED] = True
    if seeds is not None:
        out["seeds"] = seeds
        out["per_seed"] = [{name: s[name] for name in spec.evaluation.errors} for s in each]
    return out


def run_scenario(
    spec: SystemSpec,
    out: Path,
    stop_time: float | None = None,
    seeds: list[int] | None = None,
    jobs: int = 2,
    plots: bool = True,
    csv_every: int = 1,
    label: str = "",
    seed_rows: Callable[[], list[dict[str, Any]]] | None = None,
) -> dict[str, Any]:
    """Run, write results.csv (first seed), summary.json and plots into ``out``; the plots'
    title is ``label`` (the design, in the main job), the system's name and the seed plotted.

    The seeds run in up to ``jobs`` processes, or, with ``seed_rows``, on the sweep engine:
    ``seed_rows()`` gives their rows (:func:`harness.sweep.run_in_process`), the figures of
    summary.json, and the first seed runs here once more for results.csv and the plots.

    A run that fails part-way still writes results.csv with the rows recorded up to the
    failure and a summary.json marked ``"incomplete": true`` with the error, then raises the
    :class:`~harness.master.MasterError`. Each file is written whole
    (:mod:`harness.writing`), and a signal while they are written ends the command after the
    last of them (:func:`harness.writing.completed`).
    """
    make_output_folder(out)
    if stop_time is not None:
        note_clipped_evaluation(spec, stop_time)
    try:
        if seed_rows is not None:
            results = [_run_one(spec.with_seed(seeds[0]), stop_time)]
            each = [row_summary(row, spec) for row in seed_rows()]
        else:
            results = (run_seeds(spec, seeds, stop_time, jobs) if seeds is not None
                       else [_run_one(spec, stop_time)])
            each = [summary(r, spec.evaluation) for r in results]
    except MasterError as err:
        if err.partial is not None:
            write_incomplete(err, spec, out, csv_every)
        raise
    with completed(complete_written(out)):
        write_csv(results[0], out / "results.csv", csv_every)
        data = mean_summary(each, spec, seeds, float(results[0].time[-1]))
        if plots:
            from harness.plotting import plot_results

            title = " ".join(filter(None, (label, spec.name)))
            if seeds is not None:
                title += f" (seed {seeds[0]}; the figures average {len(seeds)} seeds)"
            data["plots"] = [str(p) for p in plot_results(results[0], spec, out, title)]
        write_summary(data, out / "summary.json")
    return data


def row_summary(row: dict[str, Any], spec: SystemSpec) -> dict[str, Any]:
    """A sweep point's row (:func:`harness.sweep.run_point`) as the run's summary
    (:func:`harness.results.summary`): ``steps``, ``wall_time_s`` (its co-simulation) and the
    figures per error signal of ``spec``; MasterError with the reason of a failed point.

    Examples
    --------
    >>> from harness.system import Evaluation
    >>> spec = SystemSpec("s", {}, (), 0.1, 1.0,
    ...                   evaluation=Evaluation(errors={"linear": ("p.x", "l.x_hat")}))
    >>> row_summary({"status": "ok", "steps": 10, "cosim_s": 0.5, "seed": 2,
    ...              "linear.error_at_1": 3.0}, spec)
    {'steps': 10, 'wall_time_s': 0.5, 'linear': {'error_at_1': 3.0}}
    """
    if row["status"] != "ok":
        raise MasterError(f"{spec.name}, seed {row.get('seed')}: {row.get('reason')}")
    figures = {name: {column.partition(".")[2]: value for column, value in row.items()
                      if column.startswith(f"{name}.")} for name in spec.evaluation.errors}
    return {"steps": row["steps"], "wall_time_s": row["cosim_s"], **figures}


def make_output_folder(out: Path) -> None:
    """Create the results folder ``out`` (with its parents), or raise an OSError that says it
    is the output folder that cannot be created.

    Examples
    --------
    >>> make_output_folder(Path("/proc/x"))
    Traceback (most recent call last):
    ...
    FileNotFoundError: cannot create the output folder --out /proc/x: No such file or directory
    """
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        reason = err.strerror or str(err)
        raise type(err)(f"cannot create the output folder --out {out}: {reason}") from None


def note_clipped_evaluation(spec: SystemSpec, stop_time: float) -> None:
    """Print a note naming the ``[evaluation]`` entries that ``--stop-time`` puts beyond the
    run: they have no figures in summary.json."""
    outside = evaluation_outside(spec.evaluation, spec.start_time, stop_time)
    if outside:
        print(f"note: --stop-time {stop_time:g} ends {spec.name} before its [evaluation] "
              f"{', '.join(outside)}: no figures for them", flush=True)


def write_incomplete(err: MasterError, spec: SystemSpec, out: Path, every: int = 1) -> None:
    """results.csv of the rows recorded before a failure or an interruption (every
    ``every``-th and the last, as for a complete run) and a summary.json marked incomplete,
    with the reason (``"interrupted"`` or ``"failed"``); both written whatever signal
    arrives meanwhile (:func:`harness.writing.completed`)."""
    with completed(rows_written(float(err.partial.time[-1]), out)):
        write_csv(err.partial, out / "results.csv", every)
        data = summary(err.partial, spec.evaluation, scenario=spec.name, step=spec.step)
        reason = "interrupted" if err.interrupted is not None else "failed"
        data |= {"incomplete": True, "reason": reason, "error": str(err),
                 "stop_time": float(err.partial.time[-1])}
        write_summary(data, out / "summary.json")


def csv_every(args: argparse.Namespace, default: int) -> int:
    """``--csv-every``, or the command's default; DescriptionError unless it is >= 1."""
    every = default if args.csv_every is None else args.csv_every
    if every < 1:
        raise DescriptionError(f"--csv-every = {every} must be >= 1")
    return every


def check_seed(seed: int | None, option: str = "--seed") -> None:
    """DescriptionError unless the value ``seed`` of the command-line option ``option`` is
    None or in ``0..MAX_SEED``.

    Examples
    --------
    >>> check_seed(2**31 - 1)
    >>> check_seed(-1)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    harness.system.DescriptionError: --seed = -1 must be an integer in 0..2147483647 (...)
    """
    if seed is not None and not 0 <= seed <= MAX_SEED:
        raise DescriptionError(f"{option} = {seed} must be an integer in 0..{MAX_SEED} (a seed "
                               "is a non-negative 32-bit FMI Integer)")


def _cmd_run(args: argparse.Namespace) -> int:
    check_seed(args.seed)
    for option in ("seeds", "jobs"):
        if getattr(args, option) is not None and getattr(args, option) < 1:
            raise DescriptionError(f"--{option} = {getattr(args, option)} must be >= 1")
    if args.seeds is not None and args.seeds > MAX_SEEDS:
        raise DescriptionError(f"--seeds = {args.seeds}: at most {MAX_SEEDS} seeds (each is a "
                               "run; the figures are their mean)")
    check_output_folder(args.out)
    spec = load_scenario(args.scenario, args.fmu_dir, args.block_cache)
    if args.step is not None:
        spec = replace(spec, step=args.step)
    stop_time = spec.stop_time if args.stop_time is None else args.stop_time
    check_timing(spec.step, spec.start_time, stop_time, "--step/--stop-time (or the file's [run])")
    spec = spec.with_start(dict(args.overrides))
    seeds = None
    if args.seed is not None:
        seeds = [args.seed]
    if args.seeds is not None:
        seeds = list(range(args.seeds))
    data = run_scenario(spec, args.out, args.stop_time, seeds, args.jobs, not args.no_plots,
                        csv_every(args, 1))
    print(format_table({spec.name: data}))
    print(f"results in {args.out}")
    return 0


def build_paper_fmus(out: Path, design: str = "paper", spec: Path = PENDULUM_SPEC,
                     kernel: bool | None = None, native: bool = False) -> Path:
    """Build the pendulum FMUs (and design.json) into ``out`` with build_fmu.py's machinery.

    Parameters
    ----------
    out
        Folder for observer.fmu, luenberger.fmu, plant.fmu, kalman.fmu and design.json.
    design
        ``"paper"``: the paper's published gains (``examples/pendulum-paper.json``, certified),
        which reproduce its figures; ``"spec"``: our own design of ``spec``, as
        ``python build_fmu.py SPEC`` makes it.
    spec
        The plant spec for ``design="spec"``; for ``design="paper"`` its ``[noise]`` table
        gives the Kalman filter.
    kernel
        Ship the compiled step kernel in the FMUs (:func:`fhobs.build.build_fmus`; default:
        when it can be compiled); False: the FMUs run the numpy runtime alone.
    native
        Also build the native FMUs into ``out/native`` (:mod:`fhobs.native`).

    Returns
    -------
    Path
        The folder of the FMUs to run: ``out``, or ``out/native`` with ``native``.
    """
    from fhobs.build import build_fmus
    from fhobs.design.kalman import with_kalman
    from fhobs.design.observer import paper_gains
    from fhobs.design.spec import load_spec

    if design not in DESIGN_LABELS:
        raise ValueError(f"design must be one of {sorted(DESIGN_LABELS)}, not {design!r}")
    if design == "spec":
        _, observers = design_spec_file(spec)
    else:
        observers = paper_gains()
        noise = load_spec(spec).noise
        if noise is not None:
            observers = with_kalman(observers, noise)
    out.mkdir(parents=True, exist_ok=True)
    observers.save_json(out / "design.json")
    build_fmus(observers, out, kernel=kernel)
    if not native:
        return out
    from fhobs.native.build import build_native_fmus

    build_native_fmus(observers, out / "native")
    return out / "native"


DESIGN_LABELS = {"spec": "ours", "paper": "paper"}


def design_spec_file(path: Path, tune_noise: bool = False) -> tuple[PlantSpec, ObserverDesign]:
    """The spec of ``path`` and its design, as build_fmu.py makes it (the design limits
    checked first, by the design; what the design achieved printed, and a poor design beside
    the Kalman filter said, :func:`fhobs.design.tuning.poor_design_lines`); with ``tune_noise``
    as ``build_fmu.py --tune-noise`` (:func:`fhobs.design.tuning.design_for_noise_spec`).

    Returns
    -------
    tuple of PlantSpec and ObserverDesign
    """
    from fhobs.cli import design_summary
    from fhobs.design.observer import design_for_spec
    from fhobs.design.spec import load_spec
    from fhobs.design.tuning import design_for_noise_spec, poor_design_lines

    spec = load_spec(path)
    lines: list[str] = []
    if tune_noise:
        tuned = design_for_noise_spec(spec, "--tune-noise")
        design, lines = tuned.design, tuned.summary()
    else:
        design = design_for_spec(spec)
    for line in design_summary(design) + lines + poor_design_lines(spec, design):
        print(line)
    return spec, design


def predicted_line(predicted: dict[str, Any], data: dict[str, Any]) -> str:
    """The noise tuning's predictions (design.json's ``noise_tuning``) beside
    what the run measured over its steady window (the homogeneous observer's and the Kalman
    filter's RMS of ``||x - x_hat||``).

    Examples
    --------
    >>> line = predicted_line({"window": [2.0, 6.0], "predicted_noisy_rms": 1e-3,
    ...                        "kalman_predicted_noisy_rms": 5e-4},
    ...                       {"homogeneous": {"x_rms_steady": 1.1e-3},
    ...                        "kalman": {"x_rms_steady": 5.2e-4}})
    >>> line.split(": ")[1]
    'homogeneous 1.000e-03 / 1.100e-03, kalman 5.000e-04 / 5.200e-04'
    """
    a, b = predicted["window"]
    measured = {label: data.get(label, {}).get("x_rms_steady") for label in ("homogeneous",
                                                                              "kalman")}
    shown = {label: "-" if value is None else f"{value:.3e}" for label, value in measured.items()}
    return (f"noisy RMS predicted over [{a:g}, {b:g}] s / measured (steady window): homogeneous "
            f"{predicted['predicted_noisy_rms']:.3e} / {shown['homogeneous']}, kalman "
            f"{predicted['kalman_predicted_noisy_rms']:.3e} / {shown['kalman']}")


def _check_kalman_fmu(fmu_dir: Path, spec: Path) -> None:
    """The paper scenarios run the Kalman filter baseline: DescriptionError without it."""
    if not (fmu_dir / "kalman.fmu").exists():
        raise DescriptionError(
            f"{spec} has no [noise] table: the paper scenarios run the Kalman filter baseline "
            "(kalman.fmu) beside the observers; add [noise] (see examples/pendulum.toml)"
        )


def _cmd_paper(args: argparse.Namespace) -> int:
    check_output_folder(args.out)
    designs = ("spec", "paper") if args.design == "both" else (args.design,)
    if args.jobs > 1 and len(designs) > 1:
        with ProcessPoolExecutor(max_workers=min(args.jobs, len(designs))) as pool:
            parts = list(pool.map(_paper_design, designs, [args] * len(designs)))
    else:
        parts = [_paper_design(design, args) for design in designs]
    table = {key: data for part in parts for key, (data, _) in part.items()}
    folders = {key: folder for part in parts for key, (_, folder) in part.items()}
    print(format_table(table))
    for key, data in table.items():
        print(f"{key}: {folders[key]} (plots: {', '.join(data.get('plots', []))})")
    print(f"table: {write_paper_summary(args.out, table, folders)}")
    return 0


def _paper_design(design: str, args: argparse.Namespace) -> dict[str, tuple[dict[str, Any], Path]]:
    """One design of the main job: build its FMUs (pythonfmu, and native unless
    ``--pythonfmu``), run the paper's scenarios with them (the seeds on the sweep engine,
    :func:`paper_seed_rows`); ``{"<label> <scenario>": (summary, folder)}``."""
    label = DESIGN_LABELS[design]
    fmu_dir = build_paper_fmus(args.out / label / "fmus", design, args.spec,
                               native=not args.pythonfmu)
    _check_kalman_fmu(fmu_dir, args.spec)
    part = {}
    for name in PAPER_SCENARIO_FILES.values():
        spec = load_scenario(name, fmu_dir, args.block_cache)
        n = PAPER_SEEDS.get(name)
        seeds = list(range(n)) if n else None
        print(f"running {label} {name}" + (f" ({n} seeds)" if n else ""), flush=True)
        folder = args.out / label / name
        rows = None if seeds is None else partial(paper_seed_rows, name, design, seeds, args,
                                                  fmu_dir)
        part[f"{label} {name}"] = (
            run_scenario(spec, folder, args.stop_time, seeds, plots=not args.no_plots,
                         csv_every=csv_every(args, PAPER_CSV_EVERY), label=f"{label} design:",
                         seed_rows=rows),
            folder)
    return part


def paper_seed_rows(name: str, design: str, seeds: list[int], args: argparse.Namespace,
                    fmu_dir: Path) -> list[dict[str, Any]]:
    """The main job's seeded runs of the scenario ``name`` through the sweep engine, in this
    process (:func:`harness.sweep.run_in_process`), on the FMUs it built into ``fmu_dir``: a
    sweep of the seeds, of base ``name``, the main job's spec, design, FMU flavour and stop
    time (as the bundled sweep ``pendulum_noisy_seeds``); its rows in seed order."""
    from harness.sweep import fmu_bundle, run_in_process, sweep_from_table

    table: dict[str, Any] = {
        "name": f"{DESIGN_LABELS[design]} {name}", "base": name,
        "spec": str(Path(args.spec).resolve()), "design": design,
        "fmus": "pythonfmu" if args.pythonfmu else "native", "grid": {"seed": seeds}}
    if args.stop_time is not None:
        table["stop_time"] = args.stop_time
    sweep = sweep_from_table(table, args.out / DESIGN_LABELS[design] / name)
    observers = ObserverDesign.load_json(args.out / DESIGN_LABELS[design] / "fmus" / "design.json")
    return run_in_process(sweep, fmu_bundle(sweep, observers, fmu_dir))


PAPER_LEGEND = """\
Rows: scenario (design and paper scenario) and estimator: `homogeneous` = observer.fmu (the
filtering homogeneous observer), `linear` = luenberger.fmu (the Luenberger observer with the
design's linear gain), `kalman` = kalman.fmu (the steady-state Kalman filter of the spec's
`[noise]` table). Columns, with e(t) = ||x(t) - x_hat(t)|| (Euclidean norm over the four
states): `error_at_1_5` = e(1.5 s), the paper's comparison instant; `max_error_1_3` and
`rms_error_1_3` = max and RMS of e over the window [1, 3] s (after the transient). The noisy
scenario's figures are means over its seeds (each seed in its folder's summary.json);
`steps` = communication steps per run, `wall_s` = seconds per run."""
"""The main job's summary.md: what its rows and columns mean."""


def write_paper_summary(out: Path, table: dict[str, dict[str, Any]],
                        folders: dict[str, Path]) -> Path:
    """Write the main job's table, what its rows and columns mean and where each run's files
    are to ``out/summary.md``; return its path."""
    lines = ["# Main job: the paper's scenarios", "", "```", format_table(table), "```", "",
             PAPER_LEGEND, "", "Runs (results.csv, summary.json, plots):", ""]
    lines += [f"- {key}: `{folders[key].relative_to(out)}/`" for key in table]
    return write_text(out / "summary.md", "\n".join(lines) + "\n")


def plant_mismatch(spec: PlantSpec, size: float | None, seed: int | None) -> PlantSpec:
    """The spec with ``--mismatch SIZE`` / ``--mismatch-seed N`` applied to its ``[mismatch]``
    table (SpecError for a bad value, or a seed without a size anywhere).

    Examples
    --------
    >>> from fhobs.design.spec import plant_spec
    >>> plant_mismatch(plant_spec([[0.0]], [[1.0]], [[1.0]]), 0.1, 7).mismatch
    MismatchSpec(size=0.1, distribution='gaussian', seed=7)
    """
    from fhobs.design.spec import mismatch_spec

    if size is None and seed is None:
        return spec
    table = spec.mismatch
    if size is None and table is None:
        raise SpecError("--mismatch-seed needs --mismatch SIZE or a [mismatch] table in "
                        f"{spec.source}")
    mismatch = mismatch_spec(
        table.size if size is None else size,
        "gaussian" if table is None else table.distribution,
        (0 if table is None else table.seed) if seed is None else seed,
        "--mismatch/--mismatch-seed")
    return replace(spec, mismatch=mismatch)


def _cmd_plant(args: argparse.Namespace) -> int:
    from fhobs.build import build_fmus
    from fhobs.design.spec import load_spec

    check_seed(args.seed)
    if args.tolerance is not None:
        run_tolerance(args.tolerance, "--tolerance")
    check_output_folder(args.out)
    export = plant_export(args)
    plant_mismatch(load_spec(args.spec), args.mismatch, args.mismatch_seed)  # before designing
    spec, design = design_spec_file(args.spec, tune_noise=args.tune_noise)
    spec = plant_mismatch(spec, args.mismatch, args.mismatch_seed)
    noise = 0.0
    if spec.noise is not None:
        noise = float(np.sqrt(3.0) * np.max(spec.noise.measurement_std))
    step = args.step or (spec.noise.sample_time if spec.noise is not None else STEP)
    stop_time = args.stop_time or RUNS_PER_SETTLING_TIME * spec.settling_time
    stop_time = step * round(stop_time / step)
    check_timing(step, 0.0, stop_time, "--step/--stop-time")
    if spec.plant_model is not None:
        return _plant_model_run(args, spec, design, step, stop_time, export)
    options = {"x0": spec.state_scale, "noise_amplitude": noise, "h": step,
               "names": spec.names, "plant_name": spec.name}
    fmus = build_fmus(design, args.out / "fmus", T0=spec.settling_time, **options)
    if args.native:
        from fhobs.native.build import build_native_fmus

        native = build_native_fmus(design, args.out / "fmus" / "native", steps=(step,),
                                   T0=spec.settling_time, **options)
        if spec.mismatch is not None:  # its A and B are compiled in: the pythonfmu plant runs
            native.pop("plant")
        fmus |= native
    settled = transient_end(design, spec.settling_time, step, stop_time)
    plant, about = None, {}
    if spec.mismatch is not None:
        plant = spec.mismatch.perturb(design.plant.A, design.plant.B)
        about["mismatch"] = {**vars(spec.mismatch), "A": plant[0].tolist(),
                             "B": plant[1].tolist()}
    if spec.disturbance is not None:
        about["disturbance"] = {**vars(spec.disturbance), "size": spec.disturbance.size.tolist()}
    predicted = design.noise_tuning
    if predicted is not None:
        about["predicted"] = predicted
    system = own_plant_system(design, fmus, spec.state_scale, stop_time, step, noise,
                              disturbance=spec.disturbance, plant_matrices=plant,
                              settled=settled)
    system = replace(build_blocks(system, args.block_cache), tolerance=args.tolerance)
    if export is not None:
        export(system.with_seed(args.seed) if noise else system)
    data = run_own_plant(system, args.out, settled=settled,
                         channels=0 if design.plant.E is None else design.plant.E.shape[1],
                         seed=args.seed if noise else None, plots=not args.no_plots,
                         csv_every=csv_every(args, 1), about=about, names=spec.names,
                         title=spec.name)
    print(plant_table(data))
    steady = f"steady [{settled:g}, {stop_time:g}] s" if settled < stop_time else "no steady window"
    print(f"windows: transient [0, {settled:g}] s, {steady}; {data['steps']} steps, "
          f"{data['wall_time_s']:.2f} s")
    if predicted is not None:
        print(predicted_line(predicted, data))
    if not args.no_plots:
        print(f"plots: {', '.join(data['plots'])}")
    print(f"results in {args.out}, FMUs in {args.out / 'fmus'}")
    return 0


def plant_export(args: argparse.Namespace) -> Callable[[SystemSpec], None] | None:
    """What ``harness plant --export-ssp FILE`` does with the run's system (write the SSP and
    print its path), None without the option; DescriptionError for an export that would need
    Python and is not allowed, before anything is built."""
    if args.export_ssp is None:
        return None
    if args.export_ssp.is_dir():
        raise IsADirectoryError(f"--export-ssp {args.export_ssp}: is a folder, expected the "
                                ".ssp file to write")
    if not (args.native or args.allow_python):
        raise DescriptionError(
            f"--export-ssp {args.export_ssp}: without --native the estimators are pythonfmu "
            "FMUs, which need Python 3.11 with numpy in the host that runs the SSP; pass "
            "--native (no FMU of the SSP needs Python) or --allow-python to export them anyway")

    def export(system: SystemSpec) -> None:
        from harness.ssp import export_ssp

        written = export_ssp(system, args.export_ssp, args.block_cache,
                             allow_python=args.allow_python)
        print(f"ssp: {written}")

    return export


def _plant_model_run(args: argparse.Namespace, spec: Any, design: Any, step: float,
                     stop_time: float, export: Callable[[SystemSpec], None] | None) -> int:
    """``harness plant`` against the spec's ``[plant_model]`` (:mod:`harness.plant_model`)."""
    from harness.plant_model import MODEL_TOLERANCE, run_plant_model, state_table

    settled = transient_end(design, spec.settling_time, step, stop_time)
    data = run_plant_model(spec, design, args.out, step=step, stop_time=stop_time,
                           settled=settled, seed=args.seed, plots=not args.no_plots,
                           csv_every=csv_every(args, 1), native=args.native,
                           block_cache=args.block_cache, export=export,
                           tolerance=MODEL_TOLERANCE if args.tolerance is None else args.tolerance)
    model = data["plant_model"]
    print(f"model: {model['path']}" + (f", system {model['system']}" if model["system"] else "")
          + f"; {model['initial_error']}")
    print(plant_table(data))
    print(state_table(data))
    print(f"{data['steps']} steps, {data['wall_time_s']:.2f} s")
    if not args.no_plots:
        print(f"plots: {', '.join(data['plots'])}")
    print(f"results in {args.out}, FMUs in {args.out / 'fmus'}")
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    paths = sorted(SCENARIO_DIR.glob("*.toml"))
    width = max(len(path.stem) for path in paths)
    for path in paths:
        print(f"{path.stem:<{width}}  {scenario_summary(path)}")
    return 0


def scenario_summary(path: Path) -> str:
    """The first sentence of a scenario file's leading comment (up to its first ':' or '.')."""
    lines = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("# ").strip())
    text = " ".join(lines)
    ends = [i for i in (text.find(": "), text.find(". ")) if i >= 0]
    return text[:min(ends)] if ends else text


def _cmd_export(args: argparse.Namespace) -> int:
    from harness.ssp import export_ssp

    if args.out.is_dir():
        raise IsADirectoryError(f"--out {args.out}: is a folder, expected the .ssp file to write")
    check_output_folder(args.out.parent)
    spec = load_scenario(args.scenario, args.fmu_dir, args.block_cache)
    print(export_ssp(spec, args.out, args.block_cache, native_blocks=args.native_blocks,
                     allow_python=args.allow_python))
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from harness.sweep import (
        check_connect_timeout,
        check_workers,
        format_report,
        load_sweep,
        run_sweep,
    )

    check_workers(args.workers)
    check_connect_timeout(args.connect_timeout)
    sweep = load_sweep(args.sweep)
    check_output_folder(args.out)
    report = run_sweep(sweep, args.out, args.scheduler, args.workers, args.retry_failed,
                       not args.no_progress, not args.no_plots,
                       connect_timeout=args.connect_timeout)
    print(format_report(report, sweep, args.out))
    return 1 if report.failed else 0


def _cmd_linearize(args: argparse.Namespace) -> int:
    from harness.linearize import linearize
    from harness.spec_writer import summary_lines, write_spec

    if args.out.is_dir():
        raise IsADirectoryError(f"--out {args.out}: is a folder, expected the spec file to write")
    check_output_folder(args.out.parent)
    lin = linearize(args.model, args.input, args.output, args.unknown_input, system=args.system,
                    at=args.at, start=dict(args.overrides))
    print("\n".join(summary_lines(lin)))
    print(f"spec: {write_spec(lin, args.out)}")
    return 0


def format_table(summaries: dict[str, dict[str, Any]]) -> str:
    """Plain-text table: one row per (scenario, error signal), one column per figure; a
    diverged estimator's row marked and named in a note under the table."""
    rows = []
    for scenario, data in summaries.items():
        for name, figures in data.items():
            if isinstance(figures, dict):
                rows.append((scenario, name, figures, data["steps"], data["wall_time_s"]))
    keys = list(dict.fromkeys(k for r in rows for k in r[2] if k != DIVERGED))
    head = ["scenario", "observer", *keys, "steps", "wall_s"]
    lines = [head] + [
        [s, table_label(n, f), *(f"{f[k]:.3e}" if k in f else "-" for k in keys), str(st),
         f"{w:.2f}"]
        for s, n, f, st, w in rows
    ]
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    note = divergence_note([f"{s} {n}" for s, n, f, _, _ in rows if f.get(DIVERGED)])
    return "\n".join(
        ["  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)) for line in lines]
        + ([note] if note else [])
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code: 0, 1 for a sweep with failed points (one line per
    failure reason, :func:`harness.sweep.failure_lines`), or 2 with a one-paragraph message on
    stderr.

    Exit 2 for an invalid system description or option, an unusable ``--out``, an FMU that
    refuses its start values or fails during the run (its own log messages quoted; what was
    recorded before a failure is written, marked incomplete), and as a last resort for any
    other failure: never a traceback. SIGINT and SIGTERM end the command with one line on
    stderr and exit 130 and 143; during a run, after the chunk of steps in progress, with the
    rows recorded so far written as for a failure (summary.json's ``reason``:
    ``"interrupted"``); while results are written, after the last of them. The line says
    which of the three a run left: nothing, the complete results, or the rows so far with
    summary.json marked incomplete.
    """
    args = _parser().parse_args(argv)
    commands = {"run": _cmd_run, "paper": _cmd_paper, "plant": _cmd_plant, "list": _cmd_list,
                "export-ssp": _cmd_export, "sweep": _cmd_sweep, "linearize": _cmd_linearize}
    try:
        with terminate_as_interrupt():
            return commands[args.command](args)
    except MasterError as err:
        if err.interrupted is not None:
            return _interrupted(err.interrupted, written_before(err, args.out))
        print(f"error: {err}", file=sys.stderr)
        if err.partial is not None:
            print(f"error: {rows_written(float(err.partial.time[-1]), args.out)}",
                  file=sys.stderr)
        return 2
    except (FhobsError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except Interrupted as err:
        return _interrupted(err.signum, err.written)
    except KeyboardInterrupt:
        return _interrupted(signal.SIGINT, NOTHING_WRITTEN)
    except Exception as err:  # noqa: BLE001 - last resort: a message, never a traceback
        print(f"error: {args.command} failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 2


@contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM raises :class:`Interrupted` (as SIGINT raises KeyboardInterrupt) inside the
    block, so that the command ends with its message and exit code rather than being killed;
    the previous handler is back on exit. During a run, the master defers both signals to the
    end of its chunk of steps (:func:`harness.master.deferred_signals`)."""
    def raise_interrupted(signum: int, frame: object) -> None:
        raise Interrupted(signum)

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, raise_interrupted)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def written_before(err: MasterError, out: Path) -> str:
    """What a run that ``err`` ended wrote: its rows so far and an incomplete summary.json,
    or nothing when it ended before its first row."""
    if err.partial is None:
        return NOTHING_WRITTEN
    return rows_written(float(err.partial.time[-1]), out)


def _interrupted(signum: int, written: str) -> int:
    """Print the one line of an interrupted command, ``written`` saying what it wrote of the
    run in progress (nothing, the complete results, or the rows so far with an incomplete
    summary.json); its exit code, 128 + the signal's number (130 for SIGINT, 143 for
    SIGTERM)."""
    name = signal.Signals(signum).name
    print(f"interrupted by {name}: {written}", file=sys.stderr, flush=True)
    return 128 + int(signum)
