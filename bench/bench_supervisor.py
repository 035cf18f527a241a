"""The supervised observer against the Kalman filter and the homogeneous observer run alone.

Usage::

    python bench/bench_supervisor.py [--plants NAME ...] [--seeds N] [--out FILE]

Every estimator runs open loop on the same recorded (y, u) (:func:`harness.reference.replay`):
the loop is closed through the homogeneous observer (the pendulum) or the true state (the
zoo), so the data do not depend on which estimate is output.

- ``pendulum``: examples/pendulum.toml's design and [noise] table
  (the ``supervised`` record of :func:`fhobs.design.observer.design_for_spec`), the paper's loop
  (:func:`harness.reference.simulate`, dt = Ts = 5e-5 s): noisy RMS of ||x - x_hat|| over
  [1, 3] s, mean of the seeds 0..N-1 (scenario ``perturbed_noisy``); the noise-free
  ``perturbed`` max over [1, 3] s; the ``nominal`` error at 3 s. Targets: noisy RMS <= 1.05x
  the Kalman filter's, perturbed max <= 1e-6 and >= 100x below the Kalman filter's.
- the zoo plants whose disturbance model of order 1 is observable, with the noise and
  disturbance of ``bench/bench_noise_default.py``'s ``zoo_case`` (a matched sine, or a step at
  T/4, noise 3.1 % of the disturbance's output, Ts = 1e-3 s) and its tuning (``tune``:
  :func:`fhobs.design.tuning.design_for_noise`, its own seeded noise draws, seed 0): the
  homogeneous design of order 1 and the Kalman filter of the same model with the tuned
  intensity; LQR feedback on the true state from x(0) = state_scale, settling time T: RMS over
  [T, 3T] (seeds 0..N-1) and the noise-free max over [T, 3T]. Target: noisy RMS <= 1.2x the
  Kalman filter's.

Prints the tables (and the switch counts: mean per noisy run, noise-free), writes ``--out``
as JSON. Every noise draw is seeded.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from bench_noise_default import tune, zoo_case  # the script's folder is on sys.path
from fhobs.core.gains import ObserverDesign
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver
from fhobs.core.supervisor import SupervisedObserver
from fhobs.design.feedback import state_feedback
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import NoiseSpec, load_spec
from fhobs.design.supervised import design_supervised
from fhobs.paper import PENDULUM_SPEC

from harness.reference import replay, simulate
from harness.zoo import zoo_spec_paths

TARGETS = {"pendulum": 1.05, "zoo": 1.2}


def errors(x: np.ndarray, estimates: np.ndarray, window: np.ndarray) -> np.ndarray:
    """||x - x_hat|| over the window."""
    return np.linalg.norm(x - estimates, axis=1)[window]


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def supervised_run(record, run) -> tuple[np.ndarray, int]:
    """The supervised observer replayed on a run's (y, u): its x_hat rows and its switches."""
    obs = SupervisedObserver(record)
    modes = []

    class Recorder:
        """The observer, its mode noted at every step."""

        x_hat = property(lambda self: obs.x_hat)

        def step(self, y, u, dt):
            modes.append(obs.mode)
            obs.step(y, u, dt)

    rows = replay(Recorder(), run)
    modes.append(obs.mode)
    return rows, int(np.count_nonzero(np.diff(modes)))


def pendulum(seeds: int) -> dict:
    """The paper's scenarios on examples/pendulum.toml (module docstring)."""
    spec = load_spec(PENDULUM_SPEC)
    design = design_for_spec(spec)
    record = design_supervised(design, spec.noise)
    out: dict = {"plant": "pendulum", "window": record.window, "dwell_time": record.dwell_time,
                 "band": [record.lower, record.upper],
                 "return_band": [record.lower_return, record.upper_return]}
    noisy = {"supervised": [], "kalman": [], "homogeneous": [], "switches": []}
    for seed in range(seeds):
        run = simulate(design, "perturbed_noisy", seed=seed)
        window = run.window(1.0, 3.0)
        rows, switches = supervised_run(record, run)
        noisy["supervised"].append(rms(errors(run.x, rows, window)))
        noisy["kalman"].append(rms(run.error_kalman[window]))
        noisy["homogeneous"].append(rms(run.error[window]))
        noisy["switches"].append(switches)
    out["noisy_rms"] = {k: float(np.mean(v)) for k, v in noisy.items() if k != "switches"}
    out["noisy_switches"] = float(np.mean(noisy["switches"]))
    run = simulate(design, "perturbed")
    window = run.window(1.0, 3.0)
    rows, out["noise_free_switches"] = supervised_run(record, run)
    out["noise_free_max"] = {"supervised": float(errors(run.x, rows, window).max()),
                             "kalman": float(run.error_kalman[window].max()),
                             "homogeneous": float(run.error[window].max())}
    run = simulate(design, "nominal")
    rows, _ = supervised_run(record, run)
    out["nominal_error_3s"] = float(np.linalg.norm(run.x[-1] - rows[-1]))
    return out


def zoo_run(case, design: ObserverDesign, seed: int | None):
    """The zoo plant's loop (u = K x from x(0) = state_scale, the case's disturbance through E,
    its noise of ``seed``; None: noise-free) over [0, 3T]: t, x and the recorded (y, u)."""
    A, B, C, E = design.plant.A, design.plant.B, design.plant.C, design.plant.E
    dt, T = case.sample_time, case.settling_time
    amplitude = 0.0 if seed is None else float(np.sqrt(3.0) * case.std)
    plant = LTIPlant(A, B, C, E, x0=case.state_scale, noise_amplitude=amplitude,
                     seed=0 if seed is None else seed)
    K = state_feedback(A, B)
    n_steps = int(round(3.0 * T / dt))
    t = np.arange(n_steps + 1) * dt
    q = disturbance(case.disturbance, t)
    x, ys, us = np.empty((n_steps + 1, A.shape[0])), [], []
    for step in range(n_steps + 1):
        x[step] = plant.x
        if step < n_steps:
            u = K @ plant.x
            ys.append(plant.y)
            us.append(u)
            plant.step(u, q[step:step + 1], dt)
    return SimpleNamespace(t=t, x=x, y=np.array(ys), u=np.array(us))


def disturbance(d: dict, t: np.ndarray) -> np.ndarray:
    """q(t) of the case's sine or step."""
    if d["shape"] == "sine":
        return d["size"] * np.sin(2.0 * np.pi * d["frequency"] * t)
    return np.where(t >= d["start"], d["size"], 0.0)


def zoo(name: str, path: Path, seeds: int) -> dict | None:
    """One zoo plant (module docstring); None if its case does not exist."""
    case = zoo_case(name, path)
    if case is None:
        return None
    tuned = tune(case, seed=0)
    design = tuned.design
    steady = zoo_run(case, design, None).t >= case.settling_time - 1e-9
    noise = NoiseSpec(np.full(case.C.shape[0], case.std), case.sample_time,
                      tuned.kalman_intensity, 1)
    record = design_supervised(design, noise)  # design.kalman: the tuned filter of order 1
    intensity = tuned.kalman_intensity
    out: dict = {"plant": name, "disturbance": case.disturbance["shape"], "intensity": intensity}
    figures = {"supervised": [], "kalman": [], "homogeneous": [], "switches": []}
    for seed in [None, *range(seeds)]:
        run = zoo_run(case, design, seed)
        rows, switches = supervised_run(record, run)
        result = {"supervised": errors(run.x, rows, steady),
                  "kalman": errors(run.x, replay(KalmanObserver(record.kalman), run), steady),
                  "homogeneous": errors(run.x, replay(FilteringObserver(
                      design.filtering, h=case.sample_time), run), steady)}
        if seed is None:
            out["noise_free_max"] = {k: float(v.max()) for k, v in result.items()}
            out["noise_free_switches"] = switches
            continue
        for label, values in result.items():
            figures[label].append(rms(values))
        figures["switches"].append(switches)
    out["noisy_rms"] = {k: float(np.mean(v)) for k, v in figures.items() if k != "switches"}
    out["noisy_switches"] = float(np.mean(figures["switches"]))
    return out


def table(rows: list[dict]) -> str:
    head = (f"{'plant':<18} {'q':<5} | {'RMS sup':>9} {'RMS KF':>9} {'RMS hom':>9} "
            f"{'sup/KF':>6} {'hom/KF':>6} | {'max sup':>9} {'max KF':>9} {'KF/sup':>8} | "
            f"{'sw noisy':>8} {'sw free':>7} | target")
    lines = [head, "-" * len(head)]
    for row in rows:
        noisy, free = row["noisy_rms"], row["noise_free_max"]
        ratio = noisy["supervised"] / noisy["kalman"]
        target = TARGETS["pendulum" if row["plant"] == "pendulum" else "zoo"]
        lines.append(
            f"{row['plant']:<18} {row.get('disturbance', 'sine')[:5]:<5} | "
            f"{noisy['supervised']:9.3e} {noisy['kalman']:9.3e} {noisy['homogeneous']:9.3e} "
            f"{ratio:6.3f} {noisy['homogeneous'] / noisy['kalman']:6.3f} | "
            f"{free['supervised']:9.2e} {free['kalman']:9.2e} "
            f"{free['kalman'] / max(free['supervised'], 1e-300):8.2g} | "
            f"{row['noisy_switches']:8.1f} {row['noise_free_switches']:7d} | "
            f"{'met' if ratio <= target else 'not met'} (<= {target})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--plants", nargs="*", default=None,
                        help="pendulum and zoo plant names (default: all)")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("results") / "supervisor.json")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows = []
    if args.plants is None or "pendulum" in args.plants:
        rows.append(pendulum(args.seeds))
        print(f"pendulum: {time.perf_counter() - start:.0f} s", flush=True)
    for name, path in zoo_spec_paths().items():
        if name == "pendulum" or (args.plants is not None and name not in args.plants):
            continue
        row = zoo(name, path, args.seeds)
        if row is not None:
            rows.append(row)
            print(f"{name}: {time.perf_counter() - start:.0f} s", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))
    print(table(rows))
    if rows and rows[0]["plant"] == "pendulum":
        print(f"pendulum: nominal error at 3 s {rows[0]['nominal_error_3s']:.2e}; window "
              f"{rows[0]['window']:g} samples, dwell {rows[0]['dwell_time']:g} s, band "
              f"{rows[0]['band']}, return band {rows[0]['return_band']}")
    print(f"total {time.perf_counter() - start:.0f} s; {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
