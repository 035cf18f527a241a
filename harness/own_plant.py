"""The default scenario of a user's own plant: its FMUs in a closed loop the harness can run.

``python -m harness plant SPEC --out DIR`` designs the observer of a plant spec (the design's
defaults where the spec is silent), builds its FMUs into ``DIR/fmus`` (the prescribed-time
observer with T0 = the spec's settling time; it runs only without noise, which its unbounded
gain towards T0 would amplify up to the runtime's round-off limit) and runs
:func:`own_plant_system`: the plant starts at the spec's ``state_scale`` (an initial error of the
size the design was asked to remove in ``settling_time``), every observer at zero, the input is
a stabilising state feedback ``u = K x`` on the true state (LQR with Q = I, R = I of the plant
as simulated; the observers' errors do not act on the plant, and an unstable plant stays
bounded), with the spec's measurement noise when it has a ``[noise]`` table, for three settling
times.

Two spec tables change the plant, never the design (:mod:`fhobs.design.spec`):

- ``[disturbance]``: the unknown input q (a step, ramp, sine or seeded random walk from a start
  time) is a ``signal`` block of :mod:`harness.blocks` connected to the plant's input ``q``
  (it enters through E); the estimators with a disturbance model (the filtering and
  prescribed-time observers with ``disturbance_order >= 1``, the Kalman filter with its
  ``[noise] disturbance_order >= 1``) report ``q_hat``, whose first r entries estimate q.
- ``[mismatch]`` (or ``--mismatch``): the plant FMU's A and B are perturbed
  (:meth:`fhobs.design.spec.MismatchSpec.perturb`) as start values of its parameters; the observers
  keep the design's nominal model, and ``K`` is the LQR of the perturbed plant.

The figures (:func:`plant_figures`) separate the transient ``[0, T_s]`` from the steady window
``[T_s, t_end]``, ``T_s`` the design's settling time (:func:`transient_end`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from fhobs.core.gains import ObserverDesign, SupervisedGains
from fhobs.core.supervisor import sample_count
from fhobs.design.feedback import state_feedback
from fhobs.design.signals import SignalNames
from fhobs.design.spec import DISTURBANCE_SHAPES, DisturbanceSpec
from fhobs.fmu.kinds import KINDS, LABELS, kinds_where

from harness.master import CoSimResult, MasterError, run_system
from harness.results import (
    DIVERGED,
    divergence,
    divergence_note,
    error_figures,
    flagged,
    table_label,
    window_mask,
    write_csv,
    write_summary,
)
from harness.system import (
    ConnectionSpec,
    Evaluation,
    FmuSpec,
    SystemSpec,
    expand_start,
    resolve_system,
)
from harness.writing import complete_written, completed, rows_written

RUNS_PER_SETTLING_TIME = 3.0
"""The default stop time, in requested settling times."""
STEP = 1e-3
"""The default communication step (s)."""
DISTURBANCE_BLOCK = "disturbance"
"""The name of the q signal block in the system."""
FIGURES = ("x_max_transient", "x_rms_transient", "x_max_steady", "x_rms_steady",
           "q_max_transient", "q_rms_transient", "q_max_steady", "q_rms_steady")
"""The plant command's figures per estimator (:func:`plant_figures`), the table's columns."""


def whole_samples(step: float, supervised: SupervisedGains) -> bool:
    """Whether the communication ``step`` is a whole number of the supervised observer's
    Kalman samples (:func:`fhobs.core.supervisor.sample_count`), as its FMU requires.

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> record = NS(kalman=NS(sample_time=5e-5))
    >>> whole_samples(1e-3, record), whole_samples(1.5e-4, record), whole_samples(1e-4, record)
    (True, True, True)
    >>> whole_samples(7.5e-5, record)
    False
    """
    try:
        sample_count(step, supervised.kalman.sample_time)
    except ValueError:
        return False
    return True


def q_hat_kinds(design: ObserverDesign) -> set[str]:
    """The FMU kinds whose FMU has the output ``q_hat`` (a disturbance model).

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> q_hat_kinds(paper_gains())
    set()
    """
    kinds = (KINDS[name] for name in kinds_where(variable="q_hat"))
    return {kind.name for kind in kinds if kind.built_when(design)
            and int(np.prod(kind.variable("q_hat").shape(kind.runs(design))))}


def transient_end(design: ObserverDesign, settling_time: float, step: float,
                  stop_time: float) -> float:
    """``T_s``: the end of the transient window, the larger of the requested settling time
    (the prescribed-time observer converges at it) and the design's predicted one (the
    filtering observer's), rounded up to a communication point and at most ``stop_time``.

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> transient_end(paper_gains(), 1.0, 1e-3, 3.0)  # the paper's gains predict nothing
    1.0
    """
    tuning = design.settling_tuning or {}
    end = max(float(settling_time), float(tuning.get("settling_time_predicted", 0.0)))
    return float(min(step * np.ceil(end / step - 1e-9), stop_time))


def signal_start(disturbance: DisturbanceSpec) -> dict[str, float | int]:
    """Start values of the ``signal`` block (:mod:`harness.blocks.signal_source`) that draws
    ``disturbance``.

    Examples
    --------
    >>> from fhobs.design.spec import DisturbanceSpec
    >>> signal_start(DisturbanceSpec("sine", np.array([0.5]), 1.0, 2.0))
    {'size[1]': 0.5, 'shape': 2, 'start': 1.0, 'frequency': 2.0, 'seed': 0}
    """
    return {**expand_start("size", [float(v) for v in disturbance.size]),
            "shape": DISTURBANCE_SHAPES.index(disturbance.shape),
            "start": float(disturbance.start),
            "frequency": float(disturbance.frequency or 0.0), "seed": int(disturbance.seed)}


def estimator_kinds(design: ObserverDesign, fmus: dict[str, object], step: float,
                    noisy: bool) -> dict[str, str]:
    """``{kind: label}`` of the estimators that run: those in ``fmus`` built for the design
    and the noise (:meth:`fhobs.fmu.kinds.Kind.built_when`: not the prescribed-time observer
    with noise, its gain grows without bound towards T0: noise, amplified), but the
    supervised one unless ``step`` is a whole number of its Kalman samples.

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> estimator_kinds(paper_gains(), {"plant": 0, "observer": 0, "prescribed_time": 0},
    ...                 1e-3, True)
    {'observer': 'homogeneous'}
    """
    observers = {kind: label for kind, label in LABELS.items()
                 if KINDS[kind].built_when(design, noisy)}
    if design.supervised is not None and not whole_samples(step, design.supervised):
        observers.pop("supervised")
    return {kind: label for kind, label in observers.items() if kind in fmus}


def own_plant_system(design: ObserverDesign, fmus: dict[str, object], x0: np.ndarray,
                     stop_time: float, step: float = STEP,
                     noise_amplitude: float = 0.0, *,
                     disturbance: DisturbanceSpec | None = None,
                     plant_matrices: tuple[np.ndarray, np.ndarray] | None = None,
                     settled: float | None = None) -> SystemSpec:
    """The default closed loop of a plant's FMUs (module docstring).

    Parameters
    ----------
    design : ObserverDesign
        The design the FMUs were built from.
    fmus : dict
        ``{kind: path}`` from :func:`fhobs.build.build_fmus` (``plant``, ``observer``,
        ``luenberger`` and, with a ``[noise]`` table, ``kalman`` and ``supervised``; the
        supervised one is left out of the loop when ``step`` is not a whole number of its
        Kalman samples).
    x0 : numpy.ndarray
        The plant's initial state.
    stop_time, step : float
        Run length and communication step (s).
    noise_amplitude : float
        Uniform measurement noise of the plant FMU.
    disturbance : DisturbanceSpec, optional
        The q fed to the plant (a ``signal`` block named :data:`DISTURBANCE_BLOCK`); q = 0
        without it.
    plant_matrices : tuple of numpy.ndarray, optional
        The plant FMU's ``(A, B)`` when they differ from the design's (a model mismatch).
    settled : float, optional
        ``T_s`` (:func:`transient_end`): the evaluation's windows are ``[0, T_s]`` and
        ``[T_s, stop_time]``; default: the last half of the run.

    Returns
    -------
    SystemSpec
        Runnable with :func:`run_own_plant` (or :func:`harness.cli.run_scenario`).

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> from fhobs.design.spec import DisturbanceSpec
    >>> fmus = {kind: f"{kind}.fmu" for kind in ("plant", "observer", "luenberger")}
    >>> step = DisturbanceSpec("step", np.array([0.1]), start=0.5)
    >>> system = own_plant_system(paper_gains(), fmus, np.ones(4), 3.0, 1e-3,
    ...                           disturbance=step, settled=1.0)
    >>> sorted(system.fmus), system.fmus["disturbance"].block
    (['disturbance', 'luenberger', 'observer', 'plant'], ('signal', (1,)))
    >>> system.evaluation.windows
    ((0.0, 1.0), (1.0, 3.0))
    """
    E = design.plant.E
    A, B = (design.plant.A, design.plant.B) if plant_matrices is None else plant_matrices
    K = state_feedback(np.asarray(A, dtype=float), np.asarray(B, dtype=float))
    plant_start = expand_start("x0", [float(v) for v in x0])
    plant_start["noise_amplitude"] = float(noise_amplitude)
    if plant_matrices is not None:
        plant_start |= expand_start("A", np.asarray(A, dtype=float).tolist())
        plant_start |= expand_start("B", np.asarray(B, dtype=float).tolist())
    present = estimator_kinds(design, fmus, step, noise_amplitude > 0.0)
    specs = {"plant": FmuSpec("plant", fmus["plant"], plant_start)}
    specs |= {kind: FmuSpec(kind, fmus[kind]) for kind in present}
    connections = [ConnectionSpec("plant.x", "plant.u", K)]
    if E is not None and disturbance is not None:
        specs[DISTURBANCE_BLOCK] = FmuSpec(DISTURBANCE_BLOCK, None, signal_start(disturbance),
                                           block=("signal", (E.shape[1],)))
        connections.append(ConnectionSpec(f"{DISTURBANCE_BLOCK}.y", "plant.q"))
    elif E is not None:
        plant_start |= expand_start("q", [0.0] * E.shape[1])
    for kind in present:
        connections += [ConnectionSpec("plant.y", f"{kind}.y"),
                        ConnectionSpec("plant.x", f"{kind}.u", K)]
    with_q = q_hat_kinds(design)
    record = ("plant.x", *(f"{kind}.x_hat" for kind in present),
              *(f"{kind}.q_hat" for kind in present if kind in with_q))
    windows = ((stop_time / 2, stop_time),)
    if settled is not None:
        windows = ((0.0, settled),) + (((settled, stop_time),) if settled < stop_time else ())
    return SystemSpec(
        name="own_plant", fmus=specs, connections=tuple(connections), step=step,
        stop_time=stop_time, seed="plant.noise_seed", record=record,
        evaluation=Evaluation(
            windows=windows,
            errors={label: ("plant.x", f"{kind}.x_hat") for kind, label in present.items()},
        ),
    )


def q_signals(result: CoSimResult, system: SystemSpec,
              channels: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The q the plant got and each estimator's estimate of it (the first ``channels``
    entries of its ``q_hat``), sampled at the result's times.

    Returns
    -------
    tuple
        ``q`` (time x channels; zeros without a disturbance block) and ``{label: q_hat}``
        for the estimators that have ``q_hat``.
    """
    q = (result.vector(f"{DISTURBANCE_BLOCK}.y") if DISTURBANCE_BLOCK in system.fmus
         else np.zeros((result.time.size, channels)))
    estimates = {}
    for label, (_, estimate) in system.evaluation.errors.items():
        kind = estimate.partition(".")[0]
        if any(name.startswith(f"{kind}.q_hat[") for name in result.names):
            estimates[label] = result.vector(f"{kind}.q_hat")[:, :channels]
    return q, estimates


def plant_figures(result: CoSimResult, system: SystemSpec, settled: float,
                  channels: int) -> dict[str, dict[str, float]]:
    """The plant command's figures per estimator (:data:`FIGURES`).

    ``x_*`` are of ``||x - x_hat||``, ``q_*`` of ``||q - q_hat[:r]||`` (only for estimators
    with ``q_hat``); ``max``/``rms`` over the transient ``[0, settled]`` and the steady window
    ``[settled, t_end]`` (absent when the run ends before ``settled``).

    Parameters
    ----------
    result : CoSimResult
        A run of :func:`own_plant_system`.
    system : SystemSpec
        That system.
    settled : float
        ``T_s`` (:func:`transient_end`).
    channels : int
        The number r of q channels (columns of E; 0 without E).

    Returns
    -------
    dict
        ``{label: {figure: value}}``.

    Examples
    --------
    >>> from harness.system import Evaluation, SystemSpec
    >>> t = np.linspace(0.0, 2.0, 5)
    >>> x = np.column_stack([np.exp(-t), np.zeros(5)])
    >>> names = ("plant.x[1]", "obs.x_hat[1]", "obs.q_hat[1]", "obs.q_hat[2]")
    >>> result = CoSimResult(t, names, np.column_stack([x, np.ones(5), np.zeros(5)]), 4, 0.0)
    >>> system = SystemSpec("s", {}, (), 0.5, 2.0,
    ...     evaluation=Evaluation(errors={"obs": ("plant.x", "obs.x_hat")}))
    >>> figures = plant_figures(result, system, 1.0, 1)["obs"]
    >>> round(figures["x_max_steady"], 4), figures["q_rms_steady"]
    (0.3679, 1.0)
    """
    q, q_hats = q_signals(result, system, channels)
    windows = {"transient": (result.time[0], settled), "steady": (settled, result.time[-1])}
    figures: dict[str, dict[str, float]] = {}
    for label, (reference, estimate) in system.evaluation.errors.items():
        errors = {"x": np.linalg.norm(result.vector(reference) - result.vector(estimate), axis=1)}
        if label in q_hats:
            errors["q"] = np.linalg.norm(q - q_hats[label], axis=1)
        out = {}
        for window, (a, b) in windows.items():
            mask = window_mask(result.time, a, b)
            if not a < b or not mask.any() or result.time[-1] + 1e-12 < b:
                continue
            for signal, e in errors.items():
                out[f"{signal}_max_{window}"] = float(np.max(e[mask]))
                out[f"{signal}_rms_{window}"] = float(np.sqrt(np.mean(e[mask] ** 2)))
        figures[label] = {key: out[key] for key in FIGURES if key in out}
    return figures


def run_own_plant(system: SystemSpec, out: Path, *, settled: float, channels: int,
                  seed: int | None = None, plots: bool = True, csv_every: int = 1,
                  about: dict[str, Any] | None = None,
                  state_names: list[str] | None = None, names: SignalNames | None = None,
                  title: str | None = None) -> dict[str, Any]:
    """Run the plant command's system and write ``results.csv``, ``summary.json`` and the plots
    (``errors.png``: x and q errors, ``states.png``, ``disturbance.png`` with q) into ``out``.

    A run that fails part-way writes the rows recorded up to the failure and a summary marked
    ``"incomplete": true``, then raises the :class:`~harness.master.MasterError`. Each file is
    written whole, and a signal while they are written ends the command after the last of
    them (:mod:`harness.writing`).

    Parameters
    ----------
    system : SystemSpec
        From :func:`own_plant_system` (blocks built or not).
    out : Path
        The results folder (created).
    settled : float
        ``T_s``, the end of the transient window.
    channels : int
        q channels (columns of E; 0 without E).
    seed : int, optional
        The measurement noise seed (noisy runs).
    plots : bool
        Write the PNGs.
    csv_every : int
        Write every ``csv_every``-th point to results.csv.
    about : dict, optional
        Extra summary items (the disturbance, the mismatch).
    state_names : list of str, optional
        The states' names and units (``states.png``'s panels); default from ``names``.
    names : SignalNames, optional
        The plant's signals (a spec's ``spec.names``): the plots' axes carry their names and
        units; default ``plant.x[i]``, ``q[i]``.
    title : str, optional
        The plant's name (``spec.name``), heading the plots; default the system's name.

    Returns
    -------
    dict
        The summary (as written to summary.json): per estimator label the evaluation's
        figures (:mod:`harness.results`), :data:`FIGURES` and ``x_rms_states``, the RMS
        error of each state over the steady window.
    """
    out.mkdir(parents=True, exist_ok=True)
    spec = system if seed is None else system.with_seed(seed)
    head = {"scenario": spec.name, "step": spec.step, "transient_end": settled,
            **(about or {})}
    try:
        result = run_system(resolve_system(spec))
    except MasterError as err:
        if err.partial is not None:
            with completed(rows_written(float(err.partial.time[-1]), out)):
                write_csv(err.partial, out / "results.csv")
                data = _summary(err.partial, spec, settled, channels, head)
                write_summary(data | {"incomplete": True, "error": str(err)},
                              out / "summary.json")
        raise
    with completed(complete_written(out)):
        write_csv(result, out / "results.csv", csv_every)
        data = _summary(result, spec, settled, channels, head)
        if seed is not None:
            data["seeds"] = [seed]
        if plots:
            data["plots"] = [str(p) for p in _plots(result, spec, settled, channels, out,
                                                    state_names, names, title)]
        write_summary(data, out / "summary.json")
    return data


def _summary(result: CoSimResult, system: SystemSpec, settled: float, channels: int,
             head: dict[str, Any]) -> dict[str, Any]:
    data = {**head, "stop_time": float(result.time[-1]), "steps": result.steps,
            "wall_time_s": result.wall_time_s}
    generic = flagged(error_figures(result, system.evaluation),
                      divergence(result, system.evaluation))
    steady = window_mask(result.time, min(settled, result.time[-1] / 2), result.time[-1])
    for label, figures in plant_figures(result, system, settled, channels).items():
        reference, estimate = system.evaluation.errors[label]
        e = (result.vector(reference) - result.vector(estimate))[steady]
        data[label] = generic[label] | figures | {
            "x_rms_states": np.sqrt(np.mean(e ** 2, axis=0)).tolist()}
    return data


def _plots(result: CoSimResult, system: SystemSpec, settled: float, channels: int,
           out: Path, state_names: list[str] | None = None, names: SignalNames | None = None,
           title: str | None = None) -> list[Path]:
    from harness.plotting import plot_disturbance, plot_plant_errors, plot_state_estimates

    q, q_hats = q_signals(result, system, channels)
    errors = system.evaluation.errors
    diverged = {label for label, flag in divergence(result, system.evaluation).items() if flag}
    title = title or system.name
    labels = {group: [names.label(group, i) for i in range(len(getattr(names, group)))]
              for group in ("states", "unknown_inputs")} if names is not None else {}
    paths = [plot_plant_errors(result, errors, q, q_hats, settled, out / "errors.png",
                               diverged, names=names, title=title),
             plot_state_estimates(result, next(iter(errors.values()))[0],
                                  {label: est for label, (_, est) in errors.items()},
                                  out / "states.png", title, diverged,
                                  state_names or labels.get("states"))]
    if channels and (q_hats or DISTURBANCE_BLOCK in system.fmus):
        paths.append(plot_disturbance(result.time, q, q_hats, settled,
                                      out / "disturbance.png", diverged,
                                      names=labels.get("unknown_inputs"), title=title))
    return paths


def plant_table(data: dict[str, Any]) -> str:
    """The plant command's table: one row per estimator, the columns :data:`FIGURES` ("-" where
    an estimator has no such figure: no q_hat, or no steady window); a diverged estimator's
    row marked and named in a note under the table.

    Examples
    --------
    >>> print(plant_table({"steps": 3, "homogeneous": {"x_max_steady": 1e-9},
    ...                    "linear": {"x_max_steady": 2e40, "diverged": True}}))
    ... # doctest: +NORMALIZE_WHITESPACE
    estimator          x_max_transient  x_rms_transient  x_max_steady  x_rms_steady
      q_max_transient  q_rms_transient  q_max_steady  q_rms_steady
    homogeneous        -                -                1.000e-09     -             -
      -                -             -
    linear (diverged)  -                -                2.000e+40     -             -
      -                -             -
    note: linear diverged: its error grew beyond 1e+06 times its initial error
    """
    labels = [label for label, figures in data.items() if isinstance(figures, dict)
              and label in LABELS.values()]
    lines = [["estimator", *FIGURES]] + [
        [table_label(label, data[label]),
         *(f"{data[label][k]:.3e}" if k in data[label] else "-" for k in FIGURES)]
        for label in labels]
    widths = [max(len(line[i]) for line in lines) for i in range(len(lines[0]))]
    note = divergence_note([label for label in labels if data[label].get(DIVERGED)])
    return "\n".join(["  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)).rstrip()
                      for line in lines] + ([note] if note else []))
