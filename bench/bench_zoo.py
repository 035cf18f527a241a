"""The zoo bench: every example plant with the default design, noise-free closed loop.

Usage::

    python bench/bench_zoo.py [--plants pendulum,maglev] [--stop-time 10] [--jobs 2] [--fmu]

For every zoo plant (:func:`harness.zoo.zoo_spec_paths`) the default design
(:func:`harness.zoo.load_zoo_spec`; a design failure is a row of the table) runs in the
closed loop of :func:`harness.zoo.closed_loop` (``u = K x`` on the true state, x(0) =
state_scale, observers at zero, no noise, no perturbation) for each communication step dt in (1e-4,
1e-3) and internal step h in (5e-5, dt). Columns: time from which the relative error |x - x_hat| /
max|x| stays <= 1e-3, peak |x - x_hat| / |x(0) - x_hat(0)|, floor (max relative error over the last
second) of the filtering observer (split scheme), and the Luenberger baseline's floor. ``MISS``
marks a floor > 1e-9 and a time to 1e-3 > 5 s (targets of the zoo).

With ``--fmu`` the same loop runs through the FMUs: each plant's observer.fmu, luenberger.fmu and
plant.fmu are built (:func:`fhobs.build.build_fmus`, into a temporary folder) and co-simulated by
the harness master, the feedback ``u = K x`` being a connection gain from ``plant.x``.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from fhobs.core.gains import ObserverGains
from fhobs.design.observer import design_for_spec

from harness.reference import SimulationResult
from harness.zoo import (
    closed_loop,
    convergence_figures,
    load_zoo_spec,
    state_feedback,
    zoo_spec_paths,
)

STEPS = ((1e-4, 5e-5), (1e-4, 1e-4), (1e-3, 5e-5), (1e-3, 1e-3))
"""(dt, h) of the four runs per plant."""
FLOOR_TARGET = 1e-9
TIME_TARGET = 5.0


def cosimulate(gains: ObserverGains, fmu_dir: Path, dt: float, h: float,
               stop_time: float, x0: np.ndarray) -> SimulationResult:
    """The closed loop of :func:`harness.zoo.closed_loop` through the FMUs of
    ``fmu_dir``, co-simulated by the harness master with communication step dt."""
    from harness.master import run_system
    from harness.system import ConnectionSpec, FmuSpec, SystemSpec, expand_start, resolve_system

    K = state_feedback(gains.A, gains.B)
    start = expand_start("h", h)
    plant_start = expand_start("x0", [float(v) for v in x0])
    if gains.E is not None:
        plant_start |= expand_start("q", [0.0] * gains.E.shape[1])
    fmus = {"plant": FmuSpec("plant", fmu_dir / "plant.fmu", plant_start),
            "observer": FmuSpec("observer", fmu_dir / "observer.fmu", dict(start)),
            "linear": FmuSpec("linear", fmu_dir / "luenberger.fmu", dict(start))}
    connections = [ConnectionSpec("plant.y", f"{obs}.y") for obs in ("observer", "linear")]
    connections += [ConnectionSpec("plant.x", f"{to}.u", K)
                    for to in ("plant", "observer", "linear")]
    spec = SystemSpec(name="zoo", fmus=fmus, connections=tuple(connections), step=dt,
                      stop_time=stop_time,
                      record=("plant.x", "observer.x_hat", "linear.x_hat"))
    res = run_system(resolve_system(spec), progress=False)
    empty = np.zeros(res.time.size)
    return SimulationResult(t=res.time, x=res.vector("plant.x"), z=res.vector("observer.x_hat"),
                            z_lin=res.vector("linear.x_hat"), psi=empty, xi=empty, sigma=empty)


def run_plant(name: str, stop_time: float, fmu: bool = False) -> list[str]:
    """The table rows of one plant (one per (dt, h), or one row saying why the design failed)."""
    spec = load_zoo_spec(zoo_spec_paths()[name])
    try:
        gains = design_for_spec(spec)
    except (ValueError, RuntimeError) as err:  # LMIError, CertificateError, homogenisation
        return [f"| {name} | design failed: {str(err).splitlines()[0]} |"]
    if fmu:
        with tempfile.TemporaryDirectory() as tmp:
            from fhobs.build import build_fmus

            build_fmus(gains, Path(tmp), x0=spec.state_scale)
            return _rows(name, gains, stop_time,
                         lambda dt, h: cosimulate(gains, Path(tmp), dt, h, stop_time,
                                                  spec.state_scale))
    return _rows(name, gains, stop_time,
                 lambda dt, h: closed_loop(gains, dt, h, stop_time, x0=spec.state_scale))


def _rows(name: str, gains: ObserverGains, stop_time: float, run) -> list[str]:
    """One row per (dt, h) of :data:`STEPS`, ``run(dt, h)`` giving the closed-loop result."""
    head = (f"| {name} | {gains.n} | {gains.k} | {gains.n_tilde} | {gains.rho:.3g} / "
            f"{gains.gamma:.3g} / {gains.nu:.3g}")
    rows = []
    for dt, h in STEPS:
        try:
            with np.errstate(all="ignore"):
                result = run(dt, h)
        except (ValueError, RuntimeError) as err:  # the runtime's or the master's refusal
            rows.append(f"{head} | {dt:g} | {h:g} | failed: {str(err).splitlines()[0]} |")
            continue
        fig, lin = convergence_figures(result), convergence_figures(result, "z_lin")
        rows.append(f"{head} | {dt:g} | {h:g} | {_time(fig['time'])} | {fig['peak']:.3g} | "
                    f"{_floor(fig['floor'])} | {lin['floor']:.1e} |")
    return rows


def _time(t: float) -> str:
    """Time to 1e-3, marked when above the target."""
    text = "never" if math.isinf(t) else f"{t:.2f}"
    return text + (" MISS" if t > TIME_TARGET else "")


def _floor(value: float) -> str:
    """Noise-free floor, marked when above the target (NaN included)."""
    return f"{value:.1e}" + ("" if value <= FLOOR_TARGET else " MISS")


def main(argv: list[str] | None = None) -> int:
    """Print the zoo table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", default=None, help="comma-separated names (default: all)")
    parser.add_argument("--stop-time", type=float, default=10.0)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--fmu", action="store_true", help="run through the FMUs")
    args = parser.parse_args(argv)
    known = list(zoo_spec_paths())
    names = known if args.plants is None else args.plants.split(",")
    unknown = sorted(set(names) - set(known))
    if unknown or not args.stop_time > 1.0:
        print(f"error: unknown plants {unknown} (known: {', '.join(known)})" if unknown else
              f"error: --stop-time must be > 1 s (the floor is the last second), got "
              f"{args.stop_time}", file=sys.stderr)
        return 2
    print(f"noise-free closed loop u = K x, x(0) = state_scale, {args.stop_time:g} s, "
          f"split scheme, {'through the FMUs' if args.fmu else 'in process'}")
    print("| plant | n | k | n~ | rho / gamma / nu | dt | h | t(1e-3) s | peak | floor | "
          "Luenberger floor |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for rows in pool.map(run_plant, names, [args.stop_time] * len(names),
                             [args.fmu] * len(names)):
            print("\n".join(rows), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
