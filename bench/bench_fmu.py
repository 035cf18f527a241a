"""Cost of one observer doStep through fmpy against the in-process runtime step.

Usage: ``python bench/bench_fmu.py [--steps N]``. Builds the pendulum FMUs (paper design) in
a temporary directory, then times, per communication step of 1 ms (20 internal steps of
5e-5 s): set y and u + doStep + get x_hat through fmpy's FMU2Slave, and ``obs.step`` of the
numpy runtime. Prints build time, FMU sizes and the per-step costs (microseconds).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_native import started  # the script's folder is on sys.path
from fhobs.build import build_fmus
from fhobs.core.runtime import SCHEMES, FilteringObserver
from fhobs.design.observer import paper_gains

DT, H = 1e-3, 5e-5


def time_fmu(path: Path, ys: np.ndarray, us: np.ndarray) -> float:
    """Seconds per (setReal y,u + doStep + getReal x_hat) through fmpy."""
    fmu, md = started(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    inputs = [vr[f"y[{i + 1}]"] for i in range(ys.shape[1])]
    inputs += [vr[f"u[{i + 1}]"] for i in range(us.shape[1])]
    outputs = [vr[n] for n in vr if n.startswith("x_hat[")]
    start = time.perf_counter()
    for k, (y, u) in enumerate(zip(ys, us, strict=True)):
        fmu.setReal(inputs, [*y, *u])
        fmu.doStep(k * DT, DT)
        fmu.getReal(outputs)
    elapsed = time.perf_counter() - start
    fmu.terminate()
    fmu.freeInstance()
    return elapsed / len(ys)


def time_runtime(gains, ys: np.ndarray, us: np.ndarray) -> float:
    """Seconds per ``FilteringObserver.step`` (+ reading z) in process."""
    obs = FilteringObserver(gains.filtering, h=H, scheme=SCHEMES[0])
    start = time.perf_counter()
    for y, u in zip(ys, us, strict=True):
        obs.step(y, u, DT)
        _ = obs.z
    return (time.perf_counter() - start) / len(ys)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    args = parser.parse_args()
    gains = paper_gains()
    rng = np.random.default_rng(0)
    ys = np.cumsum(rng.normal(scale=0.01, size=(args.steps, gains.plant.k)), axis=0)
    us = np.cumsum(rng.normal(scale=0.01, size=(args.steps, gains.plant.m)), axis=0)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        fmus = build_fmus(gains, Path(tmp))
        build_s = time.perf_counter() - start
        sizes = {kind: path.stat().st_size for kind, path in fmus.items()}
        fmu_s = time_fmu(fmus["observer"], ys, us)
    runtime_s = time_runtime(gains, ys, us)
    print(f"build of 3 FMUs: {build_s:.2f} s; sizes (bytes): {sizes}")
    print(f"observer step of {DT:g} s ({round(DT / H)} internal steps), {args.steps} steps:")
    print(f"  through fmpy (setReal + doStep + getReal): {fmu_s * 1e6:9.1f} us")
    print(f"  in-process runtime step:                    {runtime_s * 1e6:9.1f} us")
    print(f"  overhead: {(fmu_s - runtime_s) * 1e6:.1f} us per step ({fmu_s / runtime_s:.2f}x)")


if __name__ == "__main__":
    main()
