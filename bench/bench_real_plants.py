"""Stiff plants of examples/stiff/: the homogeneous observer against the tuned Kalman filter
after a load step, through the native FMUs.

Usage::

    python bench/bench_real_plants.py [--plants NAME ...] [--seeds N] [--pythonfmu]
                                      [--out FILE]

For each spec of ``examples/stiff/`` the design of its defaults
(:func:`fhobs.design.observer.design_for_spec`; a plant whose design fails is reported with
the design's message), its native FMUs (:func:`fhobs.native.build.build_native_fmus`; with
``--pythonfmu`` also the pythonfmu ones, noise-free run only) and the closed loop of
``harness plant`` (:func:`harness.own_plant.own_plant_system`): the plant from
``x(0) = state_scale``, the estimators at zero, LQR feedback on the true state (so the data do
not depend on the estimators), the spec's load step, communication step = the ``[noise]``
sample time, until ``RUN_SETTLING_TIMES`` settling times after the load step. Runs:
noise-free, and with measurement noise of std 1e-3 (the spec's; uniform) for seeds 0..N-1.

Estimators, all on the same run's (y, u):

- ``homogeneous``: observer.fmu (the filtering observer of the design);
- ``kalman (tuned)``: the steady-state Kalman filter of the same extended model (the spec's
  ``[noise]`` disturbance order, the observer's), its process intensity the oracle of the run:
  a grid ``|q_step|^2 10^j`` 1/s, j = -8..6, then quarter decades around the best, the one of
  least steady error on this very run (replayed in process, :class:`KalmanObserver`);
- ``supervised``: :class:`fhobs.core.supervisor.SupervisedObserver` of the design with the
  spec's ``[noise]`` table and the tuned intensity, replayed in process (it has no FMU).

The kalman.fmu built with the spec's intensity runs in the loop too: its trajectory against the
in-process replay at that intensity (``replay check``) shows that the replay is the FMU.

Figures: ``steady``, the RMS over the window ``[t_load + T_w, t_end]`` (``T_w`` the larger of
the requested and predicted settling times) of ``|(x - x_hat) / state_scale|``; ``ratio``, it
over the tuned Kalman filter's; ``q 1 %``, the time after the load step from which
``|q_hat - q|`` stays within 1 % of the step (inf: never). Targets: ratio <= 1.0 noise-free,
<= 1.2 noisy; the homogeneous observer's q 1 % before the tuned Kalman filter's.
Every noise draw is seeded (the plant FMU's noise is a function of its seed and the step).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.supervisor import SupervisedObserver
from fhobs.design.feedback import state_feedback
from fhobs.design.kalman import design_kalman
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import PlantSpec, load_spec
from fhobs.design.supervised import design_supervised
from fhobs.errors import FhobsError, KalmanDesignError
from fhobs.paper import EXAMPLES

from harness.master import run_system
from harness.own_plant import own_plant_system
from harness.reference import replay
from harness.system import build_blocks, resolve_system

STIFF = EXAMPLES / "stiff"
RUN_SETTLING_TIMES = 3.0
"""The run ends this many requested settling times after the load step."""
GRID_DECADES = range(-8, 7)
"""The coarse grid of the Kalman filter's intensity, decades of ``|q_step|^2`` 1/s."""
REFINE = (-0.75, -0.5, -0.25, 0.25, 0.5, 0.75)
"""The fine grid around the coarse grid's best, in decades."""
Q_BAND = 0.01
"""The load estimate has settled once ``|q_hat - q|`` stays within this fraction of the step."""
TARGETS = {"noise-free": 1.0, "noisy": 1.2}


def stiff_specs(names: list[str] | None = None) -> dict[str, Path]:
    """The specs of ``examples/stiff/`` by name (sorted), or those of ``names``.

    Examples
    --------
    >>> sorted(stiff_specs())[:2]
    ['aircraft_longitudinal', 'dc_motor']
    """
    paths = {path.stem: path for path in sorted(STIFF.glob("*.toml"))}
    return paths if not names else {name: paths[name] for name in names}


def decades(values: np.ndarray) -> float:
    """``log10(max / min)`` of the positive entries of ``values``.

    Examples
    --------
    >>> decades(np.array([0.0, 2e-3, 20.0]))
    4.0
    """
    positive = np.abs(values[np.abs(values) > 0])
    return float(np.log10(positive.max() / positive.min()))


def time_constant_decades(A: np.ndarray) -> float:
    """The spread of the plant's time constants ``1 / |Re lambda|`` (modes off the imaginary
    axis), in decades."""
    rates = -np.linalg.eigvals(A).real
    return decades(rates[rates > 1e-12 * np.max(np.abs(rates))])


@dataclasses.dataclass(frozen=True)
class Run:
    """One closed-loop run: the samples at ``t_k`` and what the FMUs estimated."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    q: np.ndarray
    fmu_z: dict[str, np.ndarray]  # label -> [x_hat, q_hat] rows


@dataclasses.dataclass(frozen=True)
class Case:
    """What the figures of a plant's runs need: its spec, design, windows and FMUs."""

    spec: PlantSpec
    design: object
    step: float
    stop: float
    window: tuple[float, float]
    fmus: dict[str, Path]

    @property
    def load_start(self) -> float:
        return float(self.spec.disturbance.start)

    @property
    def load_size(self) -> float:
        return float(self.spec.disturbance.size[0])


def make_case(spec: PlantSpec, design, folder: Path, pythonfmu: bool) -> Case:
    """The run's step, stop time and steady window, and the FMUs built into ``folder``
    (``native``, and ``pythonfmu`` when asked)."""
    from fhobs.build import build_fmus
    from fhobs.native.build import build_native_fmus

    step = spec.noise.sample_time
    start, requested = float(spec.disturbance.start), spec.settling_time
    predicted = (design.settling_tuning or {}).get("settling_time_predicted", requested)
    stop = step * round((start + RUN_SETTLING_TIMES * requested) / step)
    settle = max(requested, float(predicted))
    window = (start + settle, stop) if np.isfinite(settle) else (stop, stop)
    options = {"x0": spec.state_scale, "h": step}
    fmus = {"native": build_native_fmus(design, folder / "native", steps=(step,),
                                        kinds=("plant", "observer", "kalman"), **options)}
    if pythonfmu:
        fmus["pythonfmu"] = build_fmus(design, folder / "pythonfmu",
                                       kinds=("plant", "observer", "kalman"), **options)
    return Case(spec, design, step, stop, window, fmus)


def run_fmus(case: Case, build: str, noise_std: float, seed: int) -> Run:
    """The closed loop of :func:`harness.own_plant.own_plant_system` with the FMUs of
    ``build``, uniform measurement noise of std ``noise_std``, the noise seed ``seed``."""
    design = case.design
    system = own_plant_system(design, case.fmus[build], case.spec.state_scale, case.stop,
                              case.step, float(np.sqrt(3.0) * noise_std),
                              disturbance=case.spec.disturbance)
    system = dataclasses.replace(system, record=system.record + ("plant.y",))
    result = run_system(resolve_system(build_blocks(system).with_seed(seed)))
    K = state_feedback(design.plant.A, design.plant.B)
    x = result.vector("plant.x")
    fmu_z = {label: np.hstack([result.vector(f"{kind}.x_hat"), result.vector(f"{kind}.q_hat")])
             for kind, label in (("observer", "homogeneous"), ("kalman", "kalman (spec)"))}
    return Run(result.time, x, result.vector("plant.y"), x @ K.T,
               result.vector("disturbance.y"), fmu_z)


def replayed(observer, run: Run) -> np.ndarray:
    """An estimator's state z (x_hat, then q_hat) at every t_k, run open loop on the run's
    (y, u) (:func:`harness.reference.replay`)."""
    class Full:
        """The observer, its whole estimate z read as ``x_hat``."""

        x_hat = property(lambda self: observer.z)

        def step(self, y, u, dt):
            observer.step(y, u, dt)

    return replay(Full(), SimpleNamespace(t=run.t, y=run.y[:-1], u=run.u[:-1]))


def steady_error(case: Case, run: Run, z: np.ndarray) -> float:
    """RMS over the steady window of ``|(x - x_hat) / state_scale|``."""
    a, b = case.window
    mask = (run.t >= a - 1e-9) & (run.t <= b + 1e-9)
    if not mask.any():
        return float("nan")
    n = case.spec.A.shape[0]
    e = (run.x[mask] - z[mask, :n]) / case.spec.state_scale
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def q_settling(case: Case, run: Run, z: np.ndarray) -> float:
    """Time after the load step from which ``|q_hat - q|`` stays within :data:`Q_BAND` of the
    step (inf if it is outside at the end)."""
    n = case.spec.A.shape[0]
    after = run.t >= case.load_start - 1e-9
    outside = np.abs(z[after, n] - run.q[after, 0]) > Q_BAND * abs(case.load_size)
    if outside[-1]:
        return float("inf")
    last = np.flatnonzero(outside)
    t = run.t[after]
    return float(t[last[-1] + 1] - case.load_start) if last.size else 0.0


def kalman(case: Case, intensity: float):
    """The Kalman filter record of the design's extended model at ``intensity``."""
    noise = case.spec.noise
    return design_kalman(case.design.plant, noise.disturbance_order, noise.measurement_std,
                         intensity, noise.sample_time, tuning="bench oracle")


def tuned_kalman(case: Case, run: Run) -> tuple[float, np.ndarray]:
    """The intensity of least steady error on ``run`` (module docstring) and its estimates."""
    base = case.load_size**2
    tried: dict[float, tuple[float, np.ndarray]] = {}

    def trial(intensity: float) -> None:
        try:
            z = replayed(KalmanObserver(kalman(case, intensity)), run)
        except KalmanDesignError:
            return
        tried[intensity] = (steady_error(case, run, z), z)

    for j in GRID_DECADES:
        trial(base * 10.0**j)
    best = min(tried, key=lambda p: tried[p][0])
    for d in REFINE:
        trial(best * 10.0**d)
    best = min(tried, key=lambda p: tried[p][0])
    return best, tried[best][1]


def evaluate(case: Case, run: Run) -> dict[str, dict[str, float]]:
    """The figures of every estimator on one run (module docstring)."""
    intensity, z_kalman = tuned_kalman(case, run)
    noise = dataclasses.replace(case.spec.noise, process_intensity=intensity)
    estimates = {"homogeneous": run.fmu_z["homogeneous"], "kalman (tuned)": z_kalman,
                 "supervised": replayed(SupervisedObserver(design_supervised(case.design, noise),
                                                           h=case.step), run)}
    reference = steady_error(case, run, z_kalman)
    out = {label: {"steady": steady_error(case, run, z), "q_1pct": q_settling(case, run, z)}
           for label, z in estimates.items()}
    for figures in out.values():
        figures["ratio"] = figures["steady"] / reference
    out["kalman (tuned)"]["intensity"] = intensity
    spec_z = replayed(KalmanObserver(case.design.kalman), run)
    out["replay check"] = {"max_rel": float(np.max(np.abs(spec_z - run.fmu_z["kalman (spec)"]))
                                            / max(np.max(np.abs(spec_z)), 1e-300))}
    return out


def mean_figures(each: list[dict[str, dict[str, float]]]) -> dict[str, dict[str, float]]:
    """The figures averaged over seeds (the ratio of the mean steady errors)."""
    out = {label: {key: float(np.mean([e[label][key] for e in each])) for key in each[0][label]}
           for label in each[0]}
    reference = out["kalman (tuned)"]["steady"]
    for label in ("homogeneous", "kalman (tuned)", "supervised"):
        out[label]["ratio"] = out[label]["steady"] / reference
    return out


def design_row(name: str, spec: PlantSpec, design) -> str:
    """The design table's row: settling times, gains and the plant's stiffness."""
    tuning = design.settling_tuning or {}
    predicted = float(tuning.get("settling_time_predicted", float("nan")))
    return (f"| {name} | {spec.settling_time:g} | {predicted:.3g} | {tuning.get('met')} | "
            f"{design.filtering.rho:.3g} | "
            f"{np.linalg.norm(design.filtering.L, 2):.3g} | "
            f"{np.linalg.norm(design.model.L0, 2):.3g} | {time_constant_decades(spec.A):.1f} | "
            f"{decades(spec.state_scale):.1f} |")


def figure_rows(name: str, case_label: str, figures: dict[str, dict[str, float]]) -> list[str]:
    """The results table's rows of one plant and one case."""
    rows = []
    for label in ("homogeneous", "kalman (tuned)", "supervised"):
        f = figures[label]
        extra = f" (W = {f['intensity']:.3g})" if "intensity" in f else ""
        rows.append(f"| {name} | {case_label} | {label}{extra} | {f['steady']:.3e} | "
                    f"{f['ratio']:.3g} | {f['q_1pct']:.3g} |")
    return rows


def bench_plant(name: str, path: Path, seeds: int, pythonfmu: bool,
                folder: Path) -> dict[str, object]:
    """Every figure of one plant (or the design's failure)."""
    spec = load_spec(path)
    started = time.perf_counter()
    try:
        design = design_for_spec(spec)
    except (FhobsError, ValueError, np.linalg.LinAlgError) as err:  # reported as it is
        return {"error": f"{type(err).__name__}: {err}"}
    case = make_case(spec, design, folder / name, pythonfmu)
    std = float(spec.noise.measurement_std[0])
    out: dict[str, object] = {"design_row": design_row(name, spec, design),
                              "window": case.window}
    out["noise-free"] = evaluate(case, run_fmus(case, "native", 0.0, 0))
    out["noisy"] = mean_figures([evaluate(case, run_fmus(case, "native", std, seed))
                                 for seed in range(seeds)])
    if pythonfmu:
        python_run = run_fmus(case, "pythonfmu", 0.0, 0)
        native_run = run_fmus(case, "native", 0.0, 0)
        out["pythonfmu vs native"] = float(np.max(np.abs(
            python_run.fmu_z["homogeneous"] - native_run.fmu_z["homogeneous"])))
    out["seconds"] = time.perf_counter() - started
    return out


def report(results: dict[str, dict[str, object]], seeds: int) -> str:
    """The markdown tables of the results."""
    lines = ["| plant | requested T_s (s) | predicted T_s (s) | met | rho | abs(L) | abs(L0) | "
             "time constants (decades) | state sizes (decades) |",
             "|---|---|---|---|---|---|---|---|---|"]
    lines += [r["design_row"] for r in results.values() if "design_row" in r]
    failed = [f"- {name}: design failed: {r['error']}" for name, r in results.items()
              if "error" in r]
    lines += ["", *failed, "",
              f"Steady window [t_load + T_w, t_end]; noisy: std 1e-3 of y, means of seeds "
              f"0..{seeds - 1}; ratio to the tuned Kalman filter (targets: noise-free <= "
              f"{TARGETS['noise-free']}, noisy <= {TARGETS['noisy']}); q 1 %: s after the load "
              "step.", "",
              "| plant | case | estimator | steady RMS (state_scale) | ratio | q 1 % (s) |",
              "|---|---|---|---|---|---|"]
    for name, r in results.items():
        for case_label in TARGETS:
            if case_label in r:
                lines += figure_rows(name, case_label, r[case_label])
    lines += ["", "| plant | window (s) | kalman.fmu vs replay (rel., noise-free / noisy) | "
              "pythonfmu vs native (max abs) | seconds |", "|---|---|---|---|---|"]
    for name, r in results.items():
        if "window" in r:
            a, b = r["window"]
            check = "/".join(f"{r[c]['replay check']['max_rel']:.1e}" for c in TARGETS)
            both = r.get("pythonfmu vs native")
            lines.append(f"| {name} | [{a:g}, {b:g}] | {check} | "
                         f"{'-' if both is None else f'{both:.1e}'} | {r['seconds']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--plants", nargs="*", help="names of examples/stiff/ specs")
    parser.add_argument("--seeds", type=int, default=5, help="noisy runs: seeds 0..N-1")
    parser.add_argument("--pythonfmu", action="store_true",
                        help="also build the pythonfmu FMUs and compare their noise-free run")
    parser.add_argument("--out", type=Path, help="write the figures as JSON")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        results = {name: bench_plant(name, path, args.seeds, args.pythonfmu, Path(folder))
                   for name, path in stiff_specs(args.plants).items()}
    print(report(results, args.seeds))
    if args.out:
        args.out.write_text(json.dumps(results, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
