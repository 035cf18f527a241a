"""Accuracy table of the observer runtime on the paper's scenarios, and its cost per step.

Usage::

    python bench/bench_runtime.py [--gains paper tuned] [--dt 5e-5 1e-4 1e-3 1e-2]
                                  [--seeds 5] [--jobs 2] [--plots DIR]

For each gain set, communication step dt (internal step h = 5e-5: euler substeps when dt > h,
the split scheme takes one step per dt) and scheme (the paper's explicit Euler and the default
split scheme) it prints the paper's scenario metrics:
norm(x - z) at t = 1.5 (nominal), max over [1, 3] (perturbed), RMS over [1, 3] averaged over the
seeds and the linear/homogeneous ratio (perturbed + noise). The plant is the exact-ZOH plant of
the co-simulation; the all-Euler row (plant also explicit Euler) reproduces the paper's runs.
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from fhobs.core.runtime import (
    SCHEMES,
    FilteringObserver,
    LuenbergerObserver,
    PrescribedTimeObserver,
)
from fhobs.design.observer import design_for_spec, paper_gains
from fhobs.design.spec import load_spec
from fhobs.paper import H_PAPER, PENDULUM_SPEC

from harness.reference import accuracy_metrics, simulate

T_END = {"nominal": 1.5, "perturbed": 3.0, "perturbed_noisy": 3.0}


def load_gains(name: str):
    """The paper's published design or our tuned design of examples/pendulum.toml."""
    if name == "paper":
        return paper_gains()
    return design_for_spec(load_spec(PENDULUM_SPEC))


def run_case(case: tuple) -> tuple:
    """Metrics of one (gains, dt, scheme, plant scheme, scenario, seeds) case."""
    gains_name, dt, scheme, plant_scheme, scenario, seeds = case
    gains = load_gains(gains_name)
    try:
        results = [simulate(gains, scenario, t_end=T_END[scenario], dt=dt, h=H_PAPER,
                            scheme=scheme, seed=seed, plant_scheme=plant_scheme)
                   for seed in seeds]
    except ValueError as err:  # a diverging scheme raises instead of producing NaN
        return case, {"diverged": str(err)}
    return case, accuracy_metrics(results, scenario)


def format_metrics(scenario: str, metrics: dict) -> str:
    """One table cell."""
    if "diverged" in metrics:
        return "diverged"
    if scenario == "nominal":
        return f"{metrics['error_1_5']:.1e} (lin {metrics['error_1_5_lin']:.1e})"
    if scenario == "perturbed":
        return f"{metrics['max_1_3']:.1e} (lin {metrics['max_1_3_lin']:.1e})"
    return f"{metrics['rms_1_3']:.1e}, {metrics['ratio']:.0f}x below lin"


def accuracy_table(gains_names: list[str], dts: list[float], n_seeds: int, jobs: int) -> None:
    """Run every case (in parallel) and print one table per gain set."""
    scenarios = list(T_END)
    cases = [(g, dt, scheme, "zoh", sc, tuple(range(n_seeds)) if sc == "perturbed_noisy" else (0,))
             for g in gains_names for dt in dts for scheme in SCHEMES[::-1] for sc in scenarios]
    cases += [(g, H_PAPER, "euler", "euler", sc,
               tuple(range(n_seeds)) if sc == "perturbed_noisy" else (0,))
              for g in gains_names for sc in scenarios]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        results = dict(pool.map(run_case, cases))
    for g in gains_names:
        print(f"\n### {g} gains (internal step h = {H_PAPER:g}; noise: mean of {n_seeds} seeds)")
        print("| dt | scheme | plant | nominal: err(1.5) | perturbed: max[1,3] | "
              "perturbed+noise: RMS[1,3] |")
        print("|---|---|---|---|---|---|")
        rows = [(dt, s, "zoh") for dt in dts for s in SCHEMES[::-1]] + [(H_PAPER, "euler", "euler")]
        for dt, scheme, plant_scheme in rows:
            cells = []
            for sc in scenarios:
                seeds = tuple(range(n_seeds)) if sc == "perturbed_noisy" else (0,)
                cells.append(format_metrics(sc, results[(g, dt, scheme, plant_scheme, sc, seeds)]))
            print(f"| {dt:g} | {scheme} | {plant_scheme} | " + " | ".join(cells) + " |")


COST_COLUMNS = (("split, kernel", "split", True), ("split, numpy", "split", False),
                ("euler, kernel", "euler", True), ("euler, numpy", "euler", False))
"""Cost table columns: (title, scheme, compiled kernel)."""


def cost_per_step(gains_name: str, steps: int = 20000, repeat: int = 3) -> None:
    """Microseconds per internal step of each observer and scheme, the split step in the
    compiled kernel and in numpy (one substep per call, best of ``repeat`` runs from the same
    start; the first step, which prepares the step size, included)."""
    gains = load_gains(gains_name)
    print(f"\n### cost per internal step ({gains_name} gains, {steps} steps, h = {H_PAPER:g}, "
          f"best of {repeat})")
    print("| observer | " + " | ".join(title for title, _, _ in COST_COLUMNS) + " |")
    print("|---|" + "---|" * len(COST_COLUMNS))
    rng = np.random.default_rng(0)
    y = 1e-3 * rng.uniform(-1.0, 1.0, size=(steps, gains.plant.k))
    u = np.zeros(gains.plant.m)
    for cls, record in ((FilteringObserver, gains.filtering),
                        (PrescribedTimeObserver, gains.prescribed_time),
                        (LuenbergerObserver, gains.luenberger)):
        cells = []
        for _, scheme, kernel in COST_COLUMNS:
            if kernel and cls is PrescribedTimeObserver:  # no kernel step
                cells.append("-")
                continue
            options = {} if cls is PrescribedTimeObserver else {"kernel": kernel}
            times = []
            for _ in range(repeat):
                obs = cls(record, h=H_PAPER, scheme=scheme, **options)
                start = time.perf_counter()
                try:
                    with np.errstate(all="ignore"):  # a diverging cell is reported, not warned
                        for row in y:
                            obs.step(row, u, H_PAPER)
                except ValueError:  # explicit Euler can lose stability at this h
                    break
                times.append(time.perf_counter() - start)
            cells.append(f"{min(times) / steps * 1e6:.1f} us" if times else "diverged")
        print(f"| {cls.__name__} | " + " | ".join(cells) + " |")


def write_plots(gains_name: str, directory: Path) -> None:
    """Figures 1-3 (split scheme, h = 5e-5) as PNG files."""
    from harness.figures import plot_errors

    gains = load_gains(gains_name)
    directory.mkdir(parents=True, exist_ok=True)
    for scenario in T_END:
        result = simulate(gains, scenario, t_end=3.0)
        print("wrote", plot_errors(result, scenario, directory / f"{gains_name}_{scenario}.png"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gains", nargs="+", default=["paper", "tuned"],
                        choices=["paper", "tuned"])
    parser.add_argument("--dt", nargs="+", type=float, default=[5e-5, 1e-4, 1e-3, 1e-2])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--plots", type=Path, default=None, help="also write Figures 1-3 here")
    parser.add_argument("--no-table", action="store_true", help="only the cost per step")
    args = parser.parse_args()
    for g in args.gains:
        cost_per_step(g)
    if not args.no_table:
        accuracy_table(args.gains, args.dt, args.seeds, args.jobs)
    if args.plots is not None:
        for g in args.gains:
            write_plots(g, args.plots)


if __name__ == "__main__":
    main()
