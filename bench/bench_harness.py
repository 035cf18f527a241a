"""Benchmark: the nominal pendulum scenario to t = 1.5 (30,000 steps: plant, filtering observer,
Luenberger observer, Kalman filter) through the harness, with the FMUs' compiled step kernel
and without it (numpy runtime), beside the in-process reference loop (harness.reference) and a
bare numpy loop of three linear 4-state updates timed in the same run.

Targets: filtering observer step in process <= 2 us; harness <= 0.5 s and no slower than the
bare numpy loop; with the native FMUs at most 0.15 times the bare numpy loop. The harness runs
the pythonfmu FMUs (with and without their kernel) and the native FMUs
(``build_fmu.py --native``).

It also splits the cost: per FMU, the three calls the master makes per step (fmi2SetReal,
fmi2DoStep, fmi2GetReal, straight through ctypes) are timed in isolation at fixed inputs; the
same arithmetic without FMI (the runtime objects' ``advance``, kernel and numpy) is timed
replaying the nominal run's inputs in a tight loop, its sum over the models being the cost of
the arithmetic alone, which no master over these FMUs can go below; the harness is run once
more with every model's ``advance`` a no-op (the FMI calls, the slaves and the master alone);
and the speed plumbing is switched off one piece at a time (the master's compiled step loop,
the status wrapper's direct get/set and ctypes doStep callback) to measure what each saves.

Usage: ``python bench/bench_harness.py [--repeat N] [--json FILE]`` (builds the FMUs into a
temporary folder).
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from fhobs.core.gains import ObserverDesign
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.linalg import zoh_blocks
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver, LuenbergerObserver
from fhobs.paper import H_PAPER, K_PAPER, X0_PAPER
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from harness import native
from harness.cli import build_paper_fmus, load_scenario
from harness.master import run_system
from harness.reference import simulate
from harness.system import resolve_system

T_END = 1.5
CALLS = 3000


def fmu_call_costs(fmu: Path, inputs: dict[str, float], outputs: list[str]) -> dict[str, float]:
    """Microseconds per fmi2SetReal / fmi2DoStep / fmi2GetReal as the master makes them."""
    md = read_model_description(str(fmu))
    vrs = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(
        guid=md.guid,
        unzipDirectory=extract(str(fmu)),
        instanceName="bench",
        modelIdentifier=md.coSimulation.modelIdentifier,
    )
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    # bare entry points with preconverted arguments and the GIL kept, as harness.master makes
    # the calls (fmpy's own wrappers convert arguments and release the GIL around each call)
    raw = ctypes.PyDLL(slave.dll._name, handle=slave.dll._handle)
    set_real, do_step, get_real = raw.fmi2SetReal, raw.fmi2DoStep, raw.fmi2GetReal
    for entry in (set_real, do_step, get_real):
        entry.restype = ctypes.c_int
    comp = ctypes.c_void_p(slave.component)
    in_vr = (ctypes.c_uint * len(inputs))(*[vrs[n] for n in inputs])
    in_buf = (ctypes.c_double * len(inputs))(*inputs.values())
    in_n = ctypes.c_size_t(len(inputs))
    out_vr = (ctypes.c_uint * len(outputs))(*[vrs[n] for n in outputs])
    out_buf = (ctypes.c_double * len(outputs))()
    out_n = ctypes.c_size_t(len(outputs))
    t, h, no_set_prior = ctypes.c_double(0.0), ctypes.c_double(H_PAPER), ctypes.c_int(1)
    costs = {}
    for name, call in [
        ("fmi2SetReal", lambda: set_real(comp, in_vr, in_n, in_buf)),
        ("fmi2DoStep", lambda: do_step(comp, t, h, no_set_prior)),
        ("fmi2GetReal", lambda: get_real(comp, out_vr, out_n, out_buf)),
    ]:
        call()  # the first step of a size prepares it (ZOH, gain cap): not timed
        start = time.perf_counter()
        for _ in range(CALLS):
            call()
        costs[name] = (time.perf_counter() - start) / CALLS * 1e6
    slave.terminate()
    slave.freeInstance()
    return costs


def model_step_costs(gains: ObserverDesign, repeat: int, kernel: bool) -> dict[str, float]:
    """Microseconds per ``advance`` (the step the FMUs make, their inputs checked by the slave)
    of each runtime object, in the kernel or in numpy, replaying the inputs of the in-process
    nominal run to T_END in a tight loop (best of ``repeat``): the trajectory the harness
    computes, at the most favourable cost. Their sum is what the model arithmetic alone costs
    per step, a lower bound for any master over these FMUs. The first step, which prepares
    the step size (ZOH, the observer's gain cap: tens of ms, once per instance and step
    size), is not timed."""
    result = simulate(gains, "nominal", t_end=T_END)
    ys, us = list(result.x[:-1] @ gains.plant.C.T), list(result.z[:-1] @ K_PAPER.T)
    E = gains.plant.B if gains.plant.E is None else gains.plant.E
    q = np.zeros(E.shape[1])
    models = {
        "plant": lambda: (LTIPlant(gains.plant.A, gains.plant.B, gains.plant.C, E, x0=X0_PAPER,
                                   kernel=kernel),
                          lambda m, y, u: m.advance(u, q, H_PAPER)),
        "observer": lambda: (FilteringObserver(gains.filtering, h=H_PAPER, kernel=kernel),
                             lambda m, y, u: m.advance(y, u, H_PAPER)),
        "linear": lambda: (LuenbergerObserver(gains.luenberger, h=H_PAPER, kernel=kernel),
                           lambda m, y, u: m.advance(y, u, H_PAPER)),
    }
    if gains.kalman is not None:
        models["kalman"] = (lambda: (KalmanObserver(gains.kalman, kernel=kernel),
                                     lambda m, y, u: m.advance(y, u, H_PAPER)))
    costs = {}
    for name, make in models.items():
        best = math.inf
        for _ in range(repeat):
            model, advance = make()
            advance(model, ys[0], us[0])
            start = time.perf_counter()
            for y, u in zip(ys[1:], us[1:], strict=True):
                advance(model, y, u)
            best = min(best, time.perf_counter() - start)
        costs[name] = best / (len(ys) - 1) * 1e6
    return costs


def bare_numpy_loop(gains: ObserverDesign, steps: int) -> None:
    """``steps`` steps of three linear 4-state updates in a plain numpy loop: the plant
    ``x = Ad x + Bd u`` and two observers ``z = Ad z + Bd u + L (C z - y)`` (the Luenberger
    gain's ZOH), u = K z of the first."""
    Ad, Bd, Ld = zoh_blocks(gains.plant.A, [gains.plant.B, gains.luenberger.L_lin], H_PAPER)
    C, K = gains.plant.C, K_PAPER
    x, z1, z2 = X0_PAPER.copy(), np.zeros(4), np.zeros(4)
    for _ in range(steps):
        y, u = C @ x, K @ z1
        x = Ad @ x + Bd @ u
        z1 = Ad @ z1 + Bd @ u + Ld @ (C @ z1 - y)
        z2 = Ad @ z2 + Bd @ u + Ld @ (C @ z2 - y)


def _vendored(suffixes: tuple[str, ...], names: tuple[str, ...]) -> list[type]:
    """Classes of the FMUs' shipped ``fhobs_<kind>_<hash>`` packages loaded in this interpreter (the
    FMUs' Python runs here)."""
    return [getattr(module, name) for key, module in list(sys.modules.items())
            if key.startswith("fhobs_") and key.endswith(suffixes)
            for name in names if hasattr(module, name)]


@contextlib.contextmanager
def _patched(classes: list[type], name: str, replacement) -> Iterator[None]:
    """Replace a method of the classes for the duration of the block."""
    originals = [cls.__dict__[name] for cls in classes]
    try:
        for cls in classes:
            setattr(cls, name, replacement)
        yield
    finally:
        for cls, original in zip(classes, originals, strict=True):
            setattr(cls, name, original)


def no_model_steps() -> contextlib.AbstractContextManager:
    """Every FMU model's ``advance`` a no-op: what the FMI calls, the slaves and the master
    cost without any arithmetic."""
    classes = _vendored((".runtime", ".plant", ".kalman_filter"),
                        ("_Observer", "LTIPlant", "KalmanObserver"))
    return _patched(classes, "advance", lambda self, *args: None)


def no_wrapper_paths() -> contextlib.AbstractContextManager:
    """The slaves do not register with the status wrapper: every fmi2GetReal / fmi2SetReal /
    fmi2DoStep goes through pythonfmu (the wrapper still answers with fmi2Error)."""
    return _patched(_vendored((".fmu.wrapper",), ("WrapperCalls",)), "_register_with_wrapper",
                    lambda self: False)


@contextlib.contextmanager
def python_step_loop() -> Iterator[None]:
    """The master's step loop in Python (no ``harness/step_loop.c``)."""
    saved = os.environ.get(native.DISABLE_ENV)
    os.environ[native.DISABLE_ENV] = "1"
    native.step_library.cache_clear()
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(native.DISABLE_ENV, None)
        else:
            os.environ[native.DISABLE_ENV] = saved
        native.step_library.cache_clear()


def interleaved(runs: dict[str, tuple], repeat: int) -> dict[str, float]:
    """Best wall time of each run ``name -> (function, context factory)``, the runs taking
    turns ``repeat`` times (so that a change of the shared machine's load hits them alike)."""
    best = dict.fromkeys(runs, math.inf)
    for _ in range(repeat):
        for name, (function, context) in runs.items():
            with context():
                start = time.perf_counter()
                function()
                best[name] = min(best[name], time.perf_counter() - start)
    return best


def call_costs(fmu_dir: Path) -> dict[str, dict[str, float]]:
    """:func:`fmu_call_costs` of the plant and the two observers of ``fmu_dir``."""
    x_hat = [f"x_hat[{i}]" for i in range(1, 5)]
    return {
        "plant": fmu_call_costs(fmu_dir / "plant.fmu", {"u[1]": 0.0, "q[1]": 0.0},
                                [f"y[{i}]" for i in (1, 2)] + [f"x[{i}]" for i in range(1, 5)]),
        "observer": fmu_call_costs(fmu_dir / "observer.fmu",
                                   {"y[1]": 2.0, "y[2]": 2.0, "u[1]": 0.0}, x_hat),
        "linear": fmu_call_costs(fmu_dir / "luenberger.fmu",
                                 {"y[1]": 2.0, "y[2]": 2.0, "u[1]": 0.0}, x_hat),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    systems = {}
    with tempfile.TemporaryDirectory() as tmp:
        for kernel in (True, False):
            label = "kernel" if kernel else "numpy"
            fmu_dir = build_paper_fmus(Path(tmp) / label, kernel=kernel)
            systems[label] = resolve_system(
                load_scenario("pendulum_nominal", fmu_dir, Path(tmp) / f"b_{label}"))
            run_system(systems[label], T_END, progress=False)  # loads the FMUs' packages
        native_dir = build_paper_fmus(Path(tmp) / "native", native=True)
        systems["native"] = resolve_system(
            load_scenario("pendulum_nominal", native_dir, Path(tmp) / "b_native"))
        gains = ObserverDesign.load_json(fmu_dir / "design.json")
        steps = int(round(T_END / systems["kernel"].spec.step))
        plain = contextlib.nullcontext

        def harness(label: str):
            return lambda: run_system(systems[label], T_END, progress=False)

        times = interleaved({
            "harness_kernel": (harness("kernel"), plain),
            "harness_numpy": (harness("numpy"), plain),
            "harness_native": (harness("native"), plain),
            "bare_numpy_loop": (lambda: bare_numpy_loop(gains, steps), plain),
            "reference_kernel": (lambda: simulate(gains, "nominal", t_end=T_END), plain),
            "reference_numpy": (lambda: simulate(gains, "nominal", t_end=T_END, kernel=False),
                                plain),
            "python_step_loop": (harness("kernel"), python_step_loop),
            "no_wrapper_paths": (harness("kernel"), no_wrapper_paths),
            "no_model_steps": (harness("kernel"), no_model_steps),
        }, args.repeat)
        fmu_costs = call_costs(Path(tmp) / "kernel")
    runtime_costs = {label: model_step_costs(gains, args.repeat, kernel)
                     for label, kernel in (("kernel", True), ("numpy", False))}
    harness_s = times["harness_kernel"]
    report = {
        "steps": steps,
        "seconds": times,
        "harness_over_bare_loop": harness_s / times["bare_numpy_loop"],
        "native_over_bare_loop": times["harness_native"] / times["bare_numpy_loop"],
        "runtime_step_us": runtime_costs,
        "fmu_call_us": fmu_costs,
        "targets": {
            "observer_step_us<=2": runtime_costs["kernel"]["observer"] <= 2.0,
            "harness_s<=0.5": harness_s <= 0.5,
            "harness_native_s<=0.5": times["harness_native"] <= 0.5,
            "harness<=bare_loop": harness_s <= times["bare_numpy_loop"],
            "native<=0.15_bare_loop": times["harness_native"] <= 0.15 * times["bare_numpy_loop"],
        },
    }
    print(f"nominal to t = {T_END} ({steps} steps, {len(systems['kernel'].fmus)} FMUs), "
          f"best of {args.repeat} (runs interleaved):")
    print("| what | kernel | numpy |")
    print("|---|---|---|")
    print(f"| harness, pythonfmu FMUs, s | {harness_s:.3f} | {times['harness_numpy']:.3f} |")
    print(f"| harness, native FMUs, s | {times['harness_native']:.3f} | |")
    print(f"| in-process reference loop, s | {times['reference_kernel']:.3f} | "
          f"{times['reference_numpy']:.3f} |")
    for name in runtime_costs["kernel"]:
        print(f"| {name} advance in process, us/step | {runtime_costs['kernel'][name]:.2f} | "
              f"{runtime_costs['numpy'][name]:.2f} |")
    print(f"| bare numpy loop (3 linear 4-state updates), s | {times['bare_numpy_loop']:.3f} | |")
    print(f"harness (kernel) / bare numpy loop: {report['harness_over_bare_loop']:.2f}; "
          f"harness (native) / bare numpy loop: {report['native_over_bare_loop']:.3f}; "
          f"targets: {report['targets']}")
    print(f"harness with the kernel and one piece off, s (all on: {harness_s:.3f}):")
    for name in ("python_step_loop", "no_wrapper_paths", "no_model_steps"):
        print(f"  {name:18s} {times[name]:.3f}  ({times[name] / harness_s - 1:+.0%})")
    print("per step, us: FMU calls (kernel FMUs, set/doStep/get, fixed inputs)")
    for name, costs in fmu_costs.items():
        print(f"    {name:9s} " + " ".join(f"{k}={v:.1f}" for k, v in costs.items()))
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return report


if __name__ == "__main__":
    main()
