"""Cost of one doStep through fmpy: native FMUs against the pythonfmu FMUs.

Usage: ``python bench/bench_native.py [--steps N] [--dt DT]``. Builds the pendulum FMUs (our
design of examples/pendulum.toml, with its Kalman filter) both ways in a temporary directory,
then times per communication step, for every kind, ``doStep`` alone and the whole exchange
(setReal of the inputs + doStep + getReal of the outputs) through fmpy's ``FMU2Slave``, and
``fmi2DoStep`` called through ctypes without fmpy's wrapper (as the harness's master calls
it), with seeded random-walk inputs. Prints a table in microseconds per step and the build times,
then, for every native kind, the time of the first ``fmi2DoStep`` at a step size the instance has
not seen (its plan computed in C: the ZOH matrices, and for the filtering observer the tau scan
of the gain level's floor and ceiling) against a step at a size already planned.
"""

from __future__ import annotations

import argparse
import ctypes
import tempfile
import time
from pathlib import Path

import numpy as np
from fhobs.build import build_fmus
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import load_spec
from fhobs.native.build import build_native_fmus
from fhobs.paper import PENDULUM_SPEC
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.model_description import ModelDescription

KINDS = ("observer", "luenberger", "kalman", "plant")


def started(path: Path, name: str = "bench") -> tuple[FMU2Slave, ModelDescription]:
    """An instance `name` of the FMU at `path` through fmpy's ``FMU2Slave``, initialised at
    time 0, and the FMU's model description."""
    md = read_model_description(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu, md


def references(md: ModelDescription, causality: str) -> list[int]:
    """The value references of the FMU's variables of a causality, in their order."""
    return [v.valueReference for v in md.modelVariables if v.causality == causality]


def time_kind(path: Path, steps: int, dt: float) -> tuple[float, float, float]:
    """Seconds per doStep alone through fmpy, per (setReal inputs + doStep + getReal outputs)
    through fmpy, and per doStep called through ctypes without fmpy's wrapper (as the harness
    calls it)."""
    fmu, md = started(path)
    inputs, outputs = references(md, "input"), references(md, "output")
    values = 0.1 + np.cumsum(np.random.default_rng(0).normal(scale=0.01,
                                                              size=(steps, len(inputs))), axis=0)
    fmu.setReal(inputs, values[0].tolist())
    initial = fmu.getFMUstate()  # each timing starts here (the open-loop plant diverges)
    start = time.perf_counter()
    for k in range(steps):
        fmu.doStep(k * dt, dt)
    alone = (time.perf_counter() - start) / steps
    rows = values.tolist()
    fmu.setFMUstate(initial)
    start = time.perf_counter()
    for k, row in enumerate(rows):
        fmu.setReal(inputs, row)
        fmu.doStep(k * dt, dt)
        fmu.getReal(outputs)
    exchange = (time.perf_counter() - start) / steps
    do_step = fmu.dll.fmi2DoStep
    do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int]
    do_step.restype = ctypes.c_int
    component = fmu.component
    fmu.setFMUstate(initial)
    fmu.setReal(inputs, values[0].tolist())
    start = time.perf_counter()
    for k in range(steps):
        do_step(component, k * dt, dt, 1)
    raw = (time.perf_counter() - start) / steps
    fmu.freeFMUstate(initial)
    fmu.terminate()
    fmu.freeInstance()
    return alone, exchange, raw


FIRST_STEP_SIZES = tuple(float(dt) for dt in np.geomspace(1.1e-5, 2.3e-3, 12))
"""New step sizes (each planned at its first doStep) for :func:`time_first_steps`."""


def time_first_steps(path: Path) -> tuple[float, float, float]:
    """Seconds of the first doStep at each of :data:`FIRST_STEP_SIZES` (median and largest,
    the plan included) and of a doStep at a step size already planned (median of 2000), called
    through ctypes as the harness calls it."""
    fmu, _ = started(path, "first")
    do_step = fmu.dll.fmi2DoStep
    do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int]
    do_step.restype = ctypes.c_int
    first, t = [], 0.0
    for dt in FIRST_STEP_SIZES:
        start = time.perf_counter()
        assert do_step(fmu.component, t, dt, 1) == 0
        first.append(time.perf_counter() - start)
        t += dt
    steady = []
    for _ in range(2000):
        start = time.perf_counter()
        do_step(fmu.component, t, FIRST_STEP_SIZES[-1], 1)
        steady.append(time.perf_counter() - start)
        t += FIRST_STEP_SIZES[-1]
    fmu.terminate()
    fmu.freeInstance()
    return float(np.median(first)), max(first), float(np.median(steady))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--dt", type=float, default=1e-3, help="communication step")
    args = parser.parse_args()
    gains = design_for_spec(load_spec(PENDULUM_SPEC))
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        python = build_fmus(gains, Path(tmp) / "pythonfmu", kinds=KINDS)
        built_python = time.perf_counter() - start
        start = time.perf_counter()
        native = build_native_fmus(gains, Path(tmp) / "native", kinds=KINDS)
        built_native = time.perf_counter() - start
        print(f"build: pythonfmu {built_python:.1f} s, native {built_native:.1f} s "
              "(the native build builds the pythonfmu FMUs for their interface)")
        print(f"\nus per communication step of {args.dt:g} s through fmpy ({args.steps} steps)")
        print("| FMU | doStep pythonfmu | doStep native | set + doStep + get pythonfmu | "
              "set + doStep + get native | raw doStep pythonfmu | raw doStep native |")
        print("|---|---|---|---|---|---|---|")
        for kind in KINDS:
            a = time_kind(python[kind], args.steps, args.dt)
            b = time_kind(native[kind], args.steps, args.dt)
            print(f"| {kind} | " + " | ".join(f"{x * 1e6:.2f}" for pair in zip(a, b, strict=True)
                                             for x in pair) + " |", flush=True)
        print(f"\nnative fmi2DoStep through ctypes: the first step at each of "
              f"{len(FIRST_STEP_SIZES)} new step sizes (plan computed in C) and a steady step")
        print("| FMU | first step, median (ms) | first step, largest (ms) | steady step (us) |")
        print("|---|---|---|---|")
        for kind in ("observer", "luenberger", "plant"):
            median, largest, steady = time_first_steps(native[kind])
            print(f"| {kind} | {median * 1e3:.3f} | {largest * 1e3:.3f} | {steady * 1e6:.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
