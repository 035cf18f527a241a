"""Noise against rejection: the trade-off fronts of the Kalman filter, the homogeneous observer
and the supervised estimator.

Usage::

    python bench/bench_tradeoff_front.py [--seeds N] [--zoo NAME] [--workers W]
        [--picture FILE] [--out FILE]

Every estimator variant runs open loop on the same recorded (y, u) of its plant
(:func:`harness.reference.replay`, the runs of ``bench/bench_supervisor.py``), so the data do
not depend on the variant. Per variant: the rejection, the noise-free max of ||x - x_hat||
over the window, against the noise, the RMS of ||x - x_hat|| over the window with noise (mean
of the seeds 0..N-1).

- ``pendulum``: examples/pendulum.toml, its [noise] table, the paper's loop closed through the
  default homogeneous observer (:func:`harness.reference.simulate`, dt = Ts = 5e-5 s) with the
  matched perturbation 0.1 sin 5t: scenario ``perturbed`` (noise-free) and
  ``perturbed_noisy``; window [1, 3] s.
- a zoo plant with a step disturbance (``--zoo``: ``dc_motor`` or ``cart_pole``), the case and
  the tuned design of ``bench/bench_supervisor.py``'s zoo (:func:`bench_supervisor.zoo_run`:
  LQR on the true state, the step at T/4, Ts = 1e-3 s); window [T, 3T].

The variants (families):

- ``kalman``: the Kalman filters (:func:`fhobs.design.kalman.design_kalman`) of disturbance
  orders 1..3 over the process intensities of a decade grid (:data:`INTENSITIES`), and the
  plant's default one (the pendulum's [noise] table, the zoo's tuned filter);
- ``homogeneous``: the default design (the pendulum's spec, the zoo's tuned design) and its
  variants of rho and gamma (both :data:`RHO_FACTORS` times the default's) and filter_scale
  (:data:`FILTER_SCALES`), each :func:`fhobs.design.observer.design_for_spec` of the plant's
  spec with the default's ``[observer]`` keys and these overrides;
- ``supervised``: :func:`fhobs.design.supervised.design_supervised` of the default homogeneous
  design with each Kalman filter of its disturbance order (the default one included).

Prints markdown tables (each family's Pareto front, the default variants, the share of each
front that another family's points dominate, the designs that failed), writes the picture
(one panel per plant, log-log: noise on x, rejection on y, each family's front as a line)
and ``--out`` as JSON. Every noise draw is seeded; the variants run on ``--workers``
processes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from bench_noise_default import tune, zoo_case  # the script's folder is on sys.path
from bench_supervisor import errors, rms, supervised_run, zoo_run
from fhobs.core.gains import ObserverDesign
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.runtime import FilteringObserver
from fhobs.design.kalman import design_kalman
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import NoiseSpec, load_spec
from fhobs.design.supervised import design_supervised
from fhobs.errors import FhobsError
from fhobs.paper import H_PAPER, PENDULUM_SPEC

from harness.figures import new_figure
from harness.reference import replay, simulate
from harness.sweep_plots import pareto_front
from harness.zoo import zoo_spec_paths

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = {"kalman": ("Kalman filter", "tab:blue", "o"),
            "homogeneous": ("homogeneous observer", "tab:red", "s"),
            "supervised": ("supervised estimator", "tab:green", "^")}
"""Each family's name, colour and marker in the picture."""
KALMAN_ORDERS = (1, 2, 3)
INTENSITIES = {"pendulum": 10.0 ** np.arange(-6, 9), "zoo": 10.0 ** np.arange(-10, 9)}
"""Process intensities of the Kalman filters: a decade grid per plant (the pendulum's spans
the one of ``bench/bench_noise_tradeoff.py``)."""
RHO_FACTORS = (2.0 / 3.0, 1.0, 1.5)
FILTER_SCALES = (1.0, 1.5, 2.0, 3.0)
ZOO_PLANTS = ("dc_motor", "cart_pole")
UNITS = {"dc_motor": "rad, rad/s, A", "cart_pole": "m, m/s, rad, rad/s"}
"""The units of the zoo plants' states (their spec files)."""


@dataclasses.dataclass(frozen=True)
class Variant:
    """One estimator: its family, label and record (``KalmanGains``, ``FilteringGains`` or
    ``SupervisedGains``); ``default``: the plant's default of the family."""

    family: str
    label: str
    record: Any
    default: bool = False


@dataclasses.dataclass(frozen=True)
class Bench:
    """A plant's recorded runs and variants.

    Attributes
    ----------
    name : str
        The plant.
    free, noisy : Any
        The noise-free run and the noisy runs (seeds 0..N-1): ``t``, ``x``, ``y``, ``u``.
    window : tuple of float
        ``(t0, t1)`` of the figures (s).
    h : float
        The homogeneous observers' internal step (s).
    variants : tuple of Variant
        The estimators measured.
    failed : tuple of (str, str)
        The variants whose design failed: label, reason.
    units : str
        The units of the state's entries (axis titles).
    title : str
        The scenario (the panel's title).
    """

    name: str
    free: Any
    noisy: tuple[Any, ...]
    window: tuple[float, float]
    h: float
    variants: tuple[Variant, ...]
    failed: tuple[tuple[str, str], ...]
    units: str
    title: str


@dataclasses.dataclass(frozen=True)
class Point:
    """A variant's figures: noisy RMS and noise-free max of ||x - x_hat|| over the window."""

    family: str
    label: str
    noise: float
    rejection: float
    default: bool


def kalman_variants(design: ObserverDesign, noise: NoiseSpec,
                    intensities: np.ndarray) -> tuple[list[Variant], list[tuple[str, str]]]:
    """The default Kalman filter (``design.kalman``) and those of :data:`KALMAN_ORDERS` over
    ``intensities`` (the default's order and intensity once); the failed designs with their
    reasons."""
    variants = [Variant("kalman", kalman_label(design.kalman.disturbance_order,
                                               design.kalman.process_intensity),
                        design.kalman, default=True)]
    failed = []
    for order in KALMAN_ORDERS:
        for intensity in intensities:
            label = kalman_label(order, intensity)
            if label == variants[0].label:
                continue
            try:
                record = design_kalman(design.plant, order, noise.measurement_std,
                                       float(intensity), noise.sample_time, "decade grid")
            except FhobsError as exc:
                failed.append((label, str(exc)))
                continue
            variants.append(Variant("kalman", label, record))
    return variants, failed


def kalman_label(order: int, intensity: float) -> str:
    """'r=1 W=1e-03' of a Kalman filter."""
    return f"r={order} W={intensity:.3g}"


def supervised_variants(design: ObserverDesign, noise: NoiseSpec,
                        kalman: list[Variant]) -> list[Variant]:
    """The supervised estimator of ``design`` with each Kalman filter of its order."""
    order = design.model.disturbance_order
    return [Variant("supervised", f"H + KF {v.label}",
                    design_supervised(dataclasses.replace(design, kalman=v.record),
                                      dataclasses.replace(
                                          noise, process_intensity=v.record.process_intensity,
                                          disturbance_order=order)),
                    v.default)
            for v in kalman if v.record.disturbance_order == order]


def homogeneous_variants(design: ObserverDesign, base: dict[str, float],
                         redesign: Callable[[dict[str, float]], ObserverDesign]
                         ) -> tuple[list[Variant], list[tuple[str, str]]]:
    """The default homogeneous design (``design``, of the ``[observer]`` keys ``base``) and
    ``redesign(overrides)`` of its rho and gamma times each of :data:`RHO_FACTORS` (their
    ratio kept: the xi equation's condition rho > gamma / 2 holds for every factor) and each of
    :data:`FILTER_SCALES`; the failed designs with their reasons."""
    variants, failed = [], []
    for factor in RHO_FACTORS:
        for scale in sorted({*FILTER_SCALES, base["filter_scale"]}):
            overrides = {"rho": factor * base["rho"], "gamma": factor * base["gamma"],
                         "filter_scale": scale}
            label = (f"rho={overrides['rho']:.3g} gamma={overrides['gamma']:.3g} "
                     f"fs={scale:.3g}")
            if factor == 1.0 and scale == base["filter_scale"]:
                variants.append(Variant("homogeneous", label, design.filtering, default=True))
                continue
            try:
                variants.append(Variant("homogeneous", label, redesign(overrides).filtering))
            except FhobsError as exc:
                failed.append((label, str(exc)))
    return variants, failed


def all_variants(design: ObserverDesign, noise: NoiseSpec, intensities: np.ndarray,
                 base: dict[str, float], redesign: Callable[[dict[str, float]], ObserverDesign]
                 ) -> tuple[tuple[Variant, ...], tuple[tuple[str, str], ...]]:
    """The three families of a plant's default ``design`` (module docstring)."""
    kalman, kalman_failed = kalman_variants(design, noise, intensities)
    homogeneous, homogeneous_failed = homogeneous_variants(design, base, redesign)
    supervised = supervised_variants(design, noise, kalman)
    return (tuple(kalman + homogeneous + supervised),
            tuple(kalman_failed + homogeneous_failed))


def pendulum_bench(seeds: int) -> Bench:
    """The pendulum's runs and variants (module docstring)."""
    spec = load_spec(PENDULUM_SPEC)
    design = design_for_spec(spec)
    variants, failed = all_variants(
        design, spec.noise, INTENSITIES["pendulum"],
        {"rho": spec.rho, "gamma": spec.gamma, "filter_scale": spec.filter_scale},
        lambda overrides: design_for_spec(load_spec(PENDULUM_SPEC, overrides)))
    return Bench("pendulum", simulate(design, "perturbed"),
                 tuple(simulate(design, "perturbed_noisy", seed=seed) for seed in range(seeds)),
                 (1.0, 3.0), H_PAPER, variants, failed, "rad, rad/s",
                 "pendulum: matched perturbation 0.1 sin 5t, the paper's loop")


def zoo_bench(name: str, seeds: int) -> Bench:
    """A zoo plant's runs and variants (module docstring): its tuned design is the default."""
    path = zoo_spec_paths()[name]
    case = zoo_case(name, path)
    tuned = tune(case, seed=0)
    design = tuned.design
    noise = NoiseSpec(np.full(case.C.shape[0], case.std), case.sample_time,
                      tuned.kalman_intensity, 1)
    keys = {"disturbance_order": 1, "settling_time": case.settling_time, **tuned.parameters}
    variants, failed = all_variants(
        design, noise, INTENSITIES["zoo"], tuned.parameters,
        lambda overrides: design_for_spec(load_spec(path, keys | overrides)))
    T = case.settling_time
    return Bench(name, zoo_run(case, design, None),
                 tuple(zoo_run(case, design, seed) for seed in range(seeds)),
                 (T, 3.0 * T), case.sample_time, variants, failed, UNITS[name],
                 f"{name}: step disturbance at {case.disturbance['start']:g} s, LQR loop")



def estimates(variant: Variant, run: Any, h: float) -> np.ndarray:
    """The variant's x_hat at every sample of the run."""
    if variant.family == "supervised":
        return supervised_run(variant.record, run)[0]
    observer = (KalmanObserver(variant.record) if variant.family == "kalman"
                else FilteringObserver(variant.record, h=h))
    return replay(observer, run)


def measure(bench: Bench, variant: Variant) -> Point:
    """The variant's noisy RMS (mean of the seeds) and noise-free max over the window."""
    t0, t1 = bench.window

    def window_errors(run: Any) -> np.ndarray:
        inside = (run.t >= t0 - 1e-9) & (run.t <= t1 + 1e-9)
        return errors(run.x, estimates(variant, run, bench.h), inside)

    return Point(variant.family, variant.label,
                 float(np.mean([rms(window_errors(run)) for run in bench.noisy])),
                 float(window_errors(bench.free).max()), variant.default)


BENCHES: dict[str, Bench] = {}
"""The benches of this run, set before the worker processes fork (they inherit them)."""


def measure_task(task: tuple[str, int]) -> tuple[str, int, Point]:
    """:func:`measure` of the variant ``task = (bench name, index)`` of :data:`BENCHES`."""
    name, index = task
    return name, index, measure(BENCHES[name], BENCHES[name].variants[index])


def measure_all(benches: list[Bench], workers: int) -> dict[str, list[Point]]:
    """Every variant's point, per bench in the variants' order; the supervised variants (the
    longest) first on ``workers`` forked processes."""
    BENCHES.update({bench.name: bench for bench in benches})
    tasks = sorted(((b.name, i) for b in benches for i in range(len(b.variants))),
                   key=lambda task: BENCHES[task[0]].variants[task[1]].family != "supervised")
    if workers > 1:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            done = list(pool.imap_unordered(measure_task, tasks))
    else:
        done = [measure_task(task) for task in tasks]
    points: dict[str, list[Point]] = {b.name: [None] * len(b.variants) for b in benches}
    for name, index, point in done:
        points[name][index] = point
    return points


def front_of(points: list[Point]) -> list[Point]:
    """The points that no other point beats in both figures, by increasing noise
    (:func:`harness.sweep_plots.pareto_front` of noise and rejection).

    Examples
    --------
    >>> p = [Point("f", str(i), n, r, False) for i, (n, r) in enumerate([(1, 3), (2, 1),
    ...      (2, 2), (3, 1)])]
    >>> [q.label for q in front_of(p)]
    ['0', '1']
    """
    return pareto_front(points, lambda p: (p.noise, p.rejection))


def dominated(front: list[Point], others: list[Point]) -> int:
    """How many points of ``front`` some point of ``others`` beats or equals in both figures."""
    return sum(any(o.noise <= p.noise and o.rejection <= p.rejection for o in others)
               for p in front)


def by_family(points: list[Point]) -> dict[str, list[Point]]:
    return {family: [p for p in points if p.family == family] for family in FAMILIES}


def tables(bench: Bench, points: list[Point]) -> str:
    """The markdown tables of a bench (module docstring)."""
    families = by_family(points)
    fronts = {family: front_of(ps) for family, ps in families.items()}
    t0, t1 = bench.window
    lines = [f"### {bench.name}: window [{t0:g}, {t1:g}] s, {len(bench.noisy)} noisy seeds, "
             f"{len(points)} variants", "",
             "| family | variant | noisy RMS | noise-free max |", "|---|---|---|---|"]
    for family, front in fronts.items():
        lines += [f"| {family} | {p.label}{' (default)' * p.default} | {p.noise:.3e} | "
                  f"{p.rejection:.3e} |" for p in front]
    lines += ["", "Default variants:", "", "| family | variant | noisy RMS | noise-free max |",
              "|---|---|---|---|"]
    lines += [f"| {p.family} | {p.label} | {p.noise:.3e} | {p.rejection:.3e} |"
              for p in points if p.default]
    lines += ["", "Front points dominated (another family's point at most as noisy and at most "
              "as large without noise):", "", "| front of | by | dominated |", "|---|---|---|"]
    for family, front in fronts.items():
        for other, ps in families.items():
            if other != family:
                lines.append(f"| {family} | {other} | {dominated(front, ps)}/{len(front)} |")
    if bench.failed:
        lines += ["", "Designs that failed:", ""]
        lines += [f"- {label}: {reason[:160]}" for label, reason in bench.failed]
    return "\n".join(lines)


def plot(benches: list[Bench], points: dict[str, list[Point]], path: Path) -> Path:
    """One log-log panel per bench: every point of each family, its front as a line, the
    default variants enlarged; the legend below the panels."""
    fig, axes = new_figure(1, len(benches), (6.5 * len(benches), 5.8), layout="constrained")
    for ax, bench in zip(axes[0], benches, strict=True):
        t0, t1 = bench.window
        for family, ps in by_family(points[bench.name]).items():
            name, colour, marker = FAMILIES[family]
            ax.loglog([p.noise for p in ps], [p.rejection for p in ps], marker, color=colour,
                      ms=4, alpha=0.45, ls="none", label=f"{name}: variants")
            front = front_of(ps)
            ax.loglog([p.noise for p in front], [p.rejection for p in front], "-",
                      marker=marker, color=colour, lw=1.4, ms=5, label=f"{name}: Pareto front")
            ax.loglog([p.noise for p in ps if p.default], [p.rejection for p in ps if p.default],
                      marker, color=colour, ms=11, mec="k", mew=1.2, ls="none",
                      label=f"{name}: default")
        ax.set_title(f"{bench.title}; noise: mean of {len(bench.noisy)} seeds", fontsize=10)
        ax.set_xlabel(f"noisy RMS of ||x - x_hat|| over [{t0:g}, {t1:g}] s ({bench.units})")
        ax.set_ylabel(f"noise-free max of ||x - x_hat|| over [{t0:g}, {t1:g}] s "
                      f"({bench.units})")
        ax.grid(True, which="major", alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=3, fontsize=8)
    fig.savefig(path, dpi=110)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--zoo", choices=ZOO_PLANTS, default="dc_motor")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--picture", type=Path, default=ROOT / "docs" / "tradeoff_front.png")
    parser.add_argument("--out", type=Path, default=Path("results") / "tradeoff_front.json")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    benches = [pendulum_bench(args.seeds), zoo_bench(args.zoo, args.seeds)]
    print(f"designs and runs: {time.perf_counter() - start:.0f} s; "
          f"{sum(len(b.variants) for b in benches)} variants", flush=True)
    points = measure_all(benches, args.workers)
    for bench in benches:
        print(tables(bench, points[bench.name]))
        print()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({name: [dataclasses.asdict(p) for p in ps]
                                    for name, ps in points.items()}, indent=1))
    print(f"picture: {plot(benches, points, args.picture)}; {args.out}; "
          f"total {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
