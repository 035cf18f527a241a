"""Cost per doStep of the observer FMUs under variable communication steps, both builds.

Usage::

    python bench/bench_variable_steps.py [--steps 2000]

The pendulum's filtering and prescribed-time observers (examples/pendulum.toml), pythonfmu
and native, through fmpy's ``FMU2Slave`` (setReal of y and u, doStep, getReal of the
outputs), with the step sequences a host may send: fixed 1e-4; 1e-4 / 3e-4 in turn; seeded
random sizes among {5e-5, 1e-4, 2e-4, 3e-4, 5e-4, 1e-3}; and a new size at every step
(distinct, log-uniform in [5e-5, 1e-3]), where each step pays for its size's plan (and the
first size of each of the 36 bins of sizes for the bin's tau scan). Prints a markdown table of
microseconds per step.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_native import references, started  # the script's folder is on sys.path
from fhobs.build import build_fmus
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import load_spec
from fhobs.native.build import build_native_fmus
from fhobs.paper import PENDULUM_SPEC

KINDS = ("observer", "prescribed_time")
SIZES = (5e-5, 1e-4, 2e-4, 3e-4, 5e-4, 1e-3)


def patterns(steps: int) -> dict[str, np.ndarray]:
    """The step sequences (seeded)."""
    rng = np.random.default_rng(0)
    return {"fixed 1e-4": np.full(steps, 1e-4),
            "1e-4 / 3e-4": np.tile([1e-4, 3e-4], steps // 2),
            "random of 6 sizes": rng.choice(SIZES, steps),
            "new size every step": np.exp(rng.uniform(np.log(5e-5), np.log(1e-3), steps))}


def time_steps(path: Path, steps: np.ndarray) -> float:
    """Microseconds per (setReal y, u + doStep + getReal outputs) of a fresh instance."""
    fmu, md = started(path)
    inputs, outputs = references(md, "input"), references(md, "output")
    rows = (0.1 + np.cumsum(np.random.default_rng(1).normal(
        scale=0.01, size=(steps.size, len(inputs))), axis=0)).tolist()
    t = 0.0
    start = time.perf_counter()
    for row, dt in zip(rows, steps.tolist(), strict=True):
        fmu.setReal(inputs, row)
        fmu.doStep(t, dt)
        fmu.getReal(outputs)
        t += dt
    elapsed = time.perf_counter() - start
    fmu.terminate()
    fmu.freeInstance()
    return 1e6 * elapsed / steps.size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    args = parser.parse_args()
    design = design_for_spec(dataclasses.replace(load_spec(PENDULUM_SPEC), noise=None))
    with tempfile.TemporaryDirectory(prefix="bench_variable_steps_") as tmp:
        builds = {"pythonfmu": build_fmus(design, Path(tmp) / "python", kinds=KINDS),
                  "native": build_native_fmus(design, Path(tmp) / "native", kinds=KINDS)}
        sequences = patterns(args.steps)
        print("| FMU | build | " + " | ".join(sequences) + " |")
        print("|---|---|" + "---:|" * len(sequences))
        for kind in KINDS:
            for build, fmus in builds.items():
                cells = [f"{time_steps(fmus[kind], steps):.0f}" for steps in sequences.values()]
                print(f"| {kind} | {build} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
