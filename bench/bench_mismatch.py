"""Model mismatch: the estimators' steady error when the plant's A and B differ from the model.

Usage::

    python bench/bench_mismatch.py [--plants maglev,dc_motor] [--sizes 0.05,0.1,0.2]
                                   [--draws 10] [--order 1] [--jobs 1] [--json FILE]

For every plant of ``examples/zoo/`` (the zoo's defaults, :func:`harness.zoo.load_zoo_spec`)
four estimators keep the nominal model while the plant runs with A and B perturbed entry by entry,
``M_ij (1 + s w_ij)``, w ~ N(0, 1) (:meth:`fhobs.design.spec.MismatchSpec.perturb`, seeds
0..draws-1: the same draws scaled to each size s):

- ``fho r=0``: the filtering observer of the default design (no disturbance model);
- ``fho r=R, E=B``: the filtering observer with a disturbance model of order R (``--order``,
  default 1) that lumps the mismatch into an unknown input entering where u does (E = B): the
  mismatch's effect ``dA x + dB u`` is estimated as far as it acts through the input channels.
  E = I (every state) would make the model unobservable with fewer outputs than states (the
  extended pair needs rank [[A, I], [C, 0]] = 2n), so it is not an option; E = B needs
  ``(A, B, C)`` without an invariant zero at s = 0 and at least as many outputs as inputs,
  else the column reads ``n/a``;
- ``luenberger``: the default design's Luenberger observer;
- ``kalman r=R, E=B``: the steady-state Kalman filter of the same disturbance model, sampled at
  the communication step, tuned for a measurement std of 1e-4 of each output's scale
  (``sum_j |C_ij| state_scale_j``) and a process intensity ``(0.1 a)^2 w^(2R-1)`` (a lumped
  input of 10 % of the excitation's amplitude a at its frequency w).

The closed loop (in process, the numpy/kernel runtime that the FMUs run; dt = h = 1e-3): the
plant and the estimators start at ``state_scale`` (disturbance states at zero: no initial error,
so that the figure is the mismatch's effect, not what remains of a slow or peaking transient);
``u = K_p x + v(t)``, K_p the LQR of the perturbed plant (the loop is a test rig that stays
stable; the estimators see u and y), and ``v_j(t) = a sin(w t + 2 pi j / m)`` a persistent
excitation with ``w = 2 pi / settling_time`` and ``a`` such that the nominal loop's steady
oscillation has the size of ``state_scale`` (its largest ``sum_j |G_ij(jw)| a / state_scale_i``
is 1). Without excitation u = K_p x drives x, and the mismatch's effect, to zero. No
measurement noise. The run lasts three settling times; the figure is the RMS over the steady
window ``[T_s, t_end]`` (``T_s``: :func:`harness.own_plant.transient_end`, the larger of both
designs') of the scaled error ``||(x - x_hat) / state_scale||``. The table gives its median and
90th percentile over the draws per plant and size, then over all plants' draws.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from fhobs.core.gains import ObserverDesign
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver, LuenbergerObserver
from fhobs.design.feedback import state_feedback
from fhobs.design.kalman import with_kalman
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import MismatchSpec, NoiseSpec, PlantSpec, plant_spec
from fhobs.paper import EXAMPLES

from harness.own_plant import RUNS_PER_SETTLING_TIME, transient_end
from harness.zoo import load_zoo_spec

DT = 1e-3
SIZES = (0.05, 0.1, 0.2)
DRAWS = 10
ESTIMATORS = ("fho r=0", "fho r={order}, E=B", "luenberger", "kalman r={order}, E=B")
MEASUREMENT_STD = 1e-4
"""The Kalman filter's measurement std, relative to each output's scale."""
LUMPED_SIZE = 0.1
"""The Kalman filter's process intensity: a lumped input of this fraction of the excitation."""


def zoo_paths() -> dict[str, Path]:
    """The zoo's specs (``examples/zoo/*.toml``) by name.

    Examples
    --------
    >>> sorted(zoo_paths())[:2]
    ['aircraft_pitch', 'cart_pole']
    """
    return {path.stem: path for path in sorted((EXAMPLES / "zoo").glob("*.toml"))}


def excitation(A: np.ndarray, B: np.ndarray, scale: np.ndarray,
               settling_time: float) -> tuple[float, float]:
    """``(a, w)`` of the excitation ``v_j = a sin(w t + 2 pi j / m)`` (module docstring).

    Examples
    --------
    >>> a, w = excitation(np.array([[-1.0]]), np.array([[1.0]]), np.ones(1), 2 * np.pi)
    >>> round(w, 6), bool(a > 1.0)
    (1.0, True)
    """
    w = 2.0 * math.pi / settling_time
    K = state_feedback(A, B)
    G = np.linalg.solve(1j * w * np.eye(A.shape[0]) - (A + B @ K), B)
    return float(1.0 / np.max(np.abs(G).sum(axis=1) / scale)), w


def designs(spec: PlantSpec, order: int, amplitude: float,
            w: float) -> tuple[ObserverDesign, ObserverDesign | None, ObserverDesign | None, str]:
    """The default design, the E = B disturbance-model design, the latter with its Kalman
    filter (None where they do not exist) and why they do not."""
    nominal = design_for_spec(spec)
    try:
        lumped_spec = plant_spec(spec.A, spec.B, spec.C, E=spec.B, disturbance_order=order,
                                 settling_time=spec.settling_time, state_scale=spec.state_scale,
                                 source=f"{spec.source} with E = B")
        lumped = design_for_spec(lumped_spec)
    except (ValueError, RuntimeError) as err:  # SpecError, LMIError, CertificateError
        return nominal, None, None, f"no E = B design: {type(err).__name__}: {_short(err)}"
    y_scale = np.abs(spec.C) @ spec.state_scale
    noise = NoiseSpec(MEASUREMENT_STD * y_scale, DT,
                      (LUMPED_SIZE * amplitude) ** 2 * w ** (2 * order - 1), order)
    try:
        kalman = with_kalman(lumped, noise, "bench_mismatch: lumped input of 10 % of the "
                                            "excitation at its frequency")
    except (ValueError, RuntimeError) as err:  # KalmanDesignError
        return nominal, lumped, None, f"no Kalman filter: {type(err).__name__}: {_short(err)}"
    return nominal, lumped, kalman, ""


def _short(err: Exception) -> str:
    text = str(err)
    return text if len(text) <= 200 else text[:197] + "..."


def run_draw(spec: PlantSpec, gains: tuple[ObserverDesign | None, ...],
             mismatch: MismatchSpec, amplitude: float, w: float, stop: float,
             settled: float) -> list[float]:
    """The steady-window RMS scaled error of each estimator (NaN where it does not exist) in
    one closed-loop run with the perturbed plant; ``gains``: the default design, the E = B
    design and the latter with its Kalman filter (:func:`designs`)."""
    nominal, lumped, kalman = gains
    A_p, B_p = mismatch.perturb(spec.A, spec.B)
    K_p = state_feedback(A_p, B_p)
    m, scale = spec.B.shape[1], spec.state_scale
    plant = LTIPlant(A_p, B_p, spec.C, x0=scale)
    estimators = [FilteringObserver(nominal.filtering, h=DT, z0=scale), None,
                  LuenbergerObserver(nominal.luenberger, h=DT, z0=scale), None]
    if lumped is not None:
        z0 = np.concatenate((scale, np.zeros(lumped.model.n_model - lumped.plant.n)))
        estimators[1] = FilteringObserver(lumped.filtering, h=DT, z0=z0)
    if kalman is not None:
        estimators[3] = KalmanObserver(kalman.kalman, z0=scale)
    steps = round(stop / DT)
    phases = 2.0 * math.pi * np.arange(m) / m
    squares = np.zeros(len(estimators))
    count = 0
    for k in range(steps + 1):
        t = k * DT
        if t >= settled - 1e-9:
            count += 1
            for i, estimator in enumerate(estimators):
                if estimator is not None:
                    squares[i] += np.sum(((plant.x - estimator.x_hat) / scale) ** 2)
        if k == steps:
            break
        y, u = plant.y, K_p @ plant.x + amplitude * np.sin(w * t + phases)
        plant.step(u, None, DT)
        for estimator in estimators:
            if estimator is not None:
                estimator.step(y, u, DT)
    return [math.sqrt(s / count) if e is not None else math.nan
            for s, e in zip(squares, estimators, strict=True)]


def run_plant(name: str, sizes: tuple[float, ...], draws: int, order: int) -> dict:
    """Every draw of every size for one zoo plant: ``{"name", "note", "errors": {size: [[per
    estimator] per draw]}}``."""
    spec = load_zoo_spec(zoo_paths()[name])
    amplitude, w = excitation(spec.A, spec.B, spec.state_scale, spec.settling_time)
    *gains, note = designs(spec, order, amplitude, w)
    stop = RUNS_PER_SETTLING_TIME * spec.settling_time
    settled = max(transient_end(g, spec.settling_time, DT, stop)
                  for g in gains[:2] if g is not None)
    errors = {size: [run_draw(spec, tuple(gains), MismatchSpec(size, "gaussian", seed),
                              amplitude, w, stop, settled) for seed in range(draws)]
              for size in sizes}
    return {"name": name, "note": note, "errors": errors, "settled": settled, "stop": stop}


def cell(values: np.ndarray) -> str:
    """``median / p90`` of the finite values, ``n/a`` if there are none.

    Examples
    --------
    >>> cell(np.array([1e-3, 2e-3, 3e-3]))
    '2.0e-03 / 2.8e-03'
    >>> cell(np.array([np.nan]))
    'n/a'
    """
    values = values[np.isfinite(values)]
    if not values.size:
        return "n/a"
    return f"{np.median(values):.1e} / {np.percentile(values, 90):.1e}"


def markdown(rows: list[dict], sizes: tuple[float, ...], order: int) -> str:
    """The markdown table: per plant and size, then all plants per size."""
    names = [e.format(order=order) for e in ESTIMATORS]
    lines = ["| plant | mismatch | " + " | ".join(names) + " |",
             "|---|---|" + "---|" * len(names)]
    for row in rows:
        for size in sizes:
            data = np.array(row["errors"][size])
            cells = [cell(data[:, i]) for i in range(len(names))]
            lines.append(f"| {row['name']} | {size:.0%} | " + " | ".join(cells) + " |")
    for size in sizes:
        data = np.vstack([np.array(row["errors"][size]) for row in rows])
        cells = [cell(data[:, i]) for i in range(len(names))]
        lines.append(f"| **all plants** | {size:.0%} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--plants", help="comma-separated zoo plants (default: all)")
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)),
                        help="relative mismatch sizes")
    parser.add_argument("--draws", type=int, default=DRAWS, help="draws per size")
    parser.add_argument("--order", type=int, default=1, help="the lumped model's order R")
    parser.add_argument("--jobs", type=int, default=1, help="parallel processes (plants)")
    parser.add_argument("--json", type=Path, help="also write every figure to this file")
    args = parser.parse_args(argv)
    names = args.plants.split(",") if args.plants else list(zoo_paths())
    sizes = tuple(float(s) for s in args.sizes.split(","))
    unknown = sorted(set(names) - set(zoo_paths()))
    if unknown:
        print(f"error: unknown plants {unknown} (have {sorted(zoo_paths())})", file=sys.stderr)
        return 2
    jobs = [(name, sizes, args.draws, args.order) for name in names]
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(run_plant, *zip(*jobs, strict=True)))
    else:
        rows = []
        for job in jobs:
            rows.append(run_plant(*job))
            print(f"done {job[0]}", file=sys.stderr, flush=True)
    print(f"steady-window RMS of ||(x - x_hat) / state_scale||, median / 90th percentile over "
          f"{args.draws} draws (gaussian, seeds 0..{args.draws - 1})\n")
    print(markdown(rows, sizes, args.order))
    for row in rows:
        if row["note"]:
            print(f"\n{row['name']}: {row['note']}")
    if args.json:
        args.json.write_text(json.dumps(
            [{**row, "errors": {str(k): v for k, v in row["errors"].items()}} for row in rows],
            indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
