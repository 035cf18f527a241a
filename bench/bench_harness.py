"""Benchmark: the nominal pendulum scenario to t = 1.5 (30,000 steps, plant + two observers)
through the harness, beside the in-process reference loop (fhobs.reference), as a ratio.

Targets (issue 5): harness <= 1.0 s and <= 1.5 x the in-process loop.

It also splits the cost: per FMU, the three calls the master makes per step (fmi2SetReal,
fmi2DoStep, fmi2GetReal, straight through ctypes) are timed in isolation at fixed inputs; the
same arithmetic without FMI (the runtime objects' ``advance``) is timed replaying the nominal
run's inputs in a tight loop, its sum over the three models being the cost of the arithmetic
alone, which no master over these FMUs can go below; and the harness is run once more with
every model's ``advance`` a no-op, the cost of the FMI calls, the slaves and the master alone.

Usage: ``python bench/bench_harness.py [--fmu-dir DIR] [--repeat N] [--json FILE]``
(builds the FMUs into a temporary folder unless --fmu-dir is given).
"""

from __future__ import annotations

import argparse
import ctypes
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from fhobs.gains import ObserverGains
from fhobs.plant import LTIPlant
from fhobs.reference import H_PAPER, K_PAPER, X0_PAPER, simulate
from fhobs.runtime import FilteringObserver, LuenbergerObserver
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from harness.cli import build_paper_fmus, load_scenario
from harness.master import run_system
from harness.system import resolve_system

T_END = 1.5
CALLS = 3000


def best_of(repeat: int, fn) -> float:
    """Smallest wall time of ``repeat`` calls of ``fn`` (seconds)."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


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
        start = time.perf_counter()
        for _ in range(CALLS):
            call()
        costs[name] = (time.perf_counter() - start) / CALLS * 1e6
    slave.terminate()
    slave.freeInstance()
    return costs


def model_step_costs(gains: ObserverGains, repeat: int) -> dict[str, float]:
    """Microseconds per ``advance`` (the step the FMUs make, their inputs checked by the slave)
    of each runtime object, replaying the inputs of the in-process nominal run to T_END in a
    tight loop (best of ``repeat``): the trajectory the harness computes, at the most favourable
    cost. Their sum is what the model arithmetic alone costs per step, a lower bound for any
    master over these FMUs."""
    result = simulate(gains, "nominal", t_end=T_END)
    ys, us = list(result.x[:-1] @ gains.C.T), list(result.z[:-1] @ K_PAPER.T)
    E = gains.B if gains.E is None else gains.E
    q = np.zeros(E.shape[1])
    models = {
        "plant": lambda: (LTIPlant(gains.A, gains.B, gains.C, E, x0=X0_PAPER),
                          lambda m, y, u: m.advance(u, q, H_PAPER)),
        "observer": lambda: (FilteringObserver(gains, h=H_PAPER),
                             lambda m, y, u: m.advance(y, u, H_PAPER)),
        "linear": lambda: (LuenbergerObserver(gains, h=H_PAPER),
                           lambda m, y, u: m.advance(y, u, H_PAPER)),
    }
    costs = {}
    for name, make in models.items():
        best = math.inf
        for _ in range(repeat):
            model, advance = make()
            start = time.perf_counter()
            for y, u in zip(ys, us, strict=True):
                advance(model, y, u)
            best = min(best, time.perf_counter() - start)
        costs[name] = best / len(ys) * 1e6
    return costs


def harness_without_models(system, repeat: int) -> float:
    """Wall time of the harness run with every FMU model's ``advance`` made a no-op (best of
    ``repeat``): what the FMI calls, the slaves and the master cost without any arithmetic.

    The FMUs' Python runs in this interpreter, from the vendored ``fhobs_<hash>`` packages
    they import; their runtime and plant classes are patched there and restored."""
    run_system(system, T_END, progress=False)  # loads the FMUs' packages
    classes = [getattr(module, name) for key, module in list(sys.modules.items())
               if key.startswith("fhobs_") and key.endswith((".runtime", ".plant"))
               for name in ("FilteringObserver", "LuenbergerObserver", "LTIPlant")
               if hasattr(module, name)]
    originals = [cls.advance for cls in classes]
    try:
        for cls in classes:
            cls.advance = lambda self, *args: None
        return best_of(repeat, lambda: run_system(system, T_END, progress=False))
    finally:
        for cls, advance in zip(classes, originals, strict=True):
            cls.advance = advance


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fmu-dir", type=Path)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        fmu_dir = args.fmu_dir or build_paper_fmus(Path(tmp))
        gains = ObserverGains.load_json(fmu_dir / "design.json")
        system = resolve_system(load_scenario("pendulum_nominal", fmu_dir, Path(tmp) / "b"))
        steps = int(round(T_END / system.spec.step))
        harness_s = best_of(args.repeat, lambda: run_system(system, T_END, progress=False))
        reference_s = best_of(args.repeat, lambda: simulate(gains, "nominal", t_end=T_END))
        no_models_s = harness_without_models(system, args.repeat)
        fmu_costs = {
            "plant": fmu_call_costs(
                fmu_dir / "plant.fmu",
                {"u[1]": 0.0, "q[1]": 0.0},
                [f"y[{i}]" for i in (1, 2)] + [f"x[{i}]" for i in range(1, 5)],
            ),
            "observer": fmu_call_costs(
                fmu_dir / "observer.fmu",
                {"y[1]": 2.0, "y[2]": 2.0, "u[1]": 0.0},
                [f"x_hat[{i}]" for i in range(1, 5)],
            ),
            "linear": fmu_call_costs(
                fmu_dir / "luenberger.fmu",
                {"y[1]": 2.0, "y[2]": 2.0, "u[1]": 0.0},
                [f"x_hat[{i}]" for i in range(1, 5)],
            ),
        }
    runtime_costs = model_step_costs(gains, args.repeat)
    model_us = sum(runtime_costs.values())
    fmu_us = sum(sum(c.values()) for c in fmu_costs.values())
    report = {
        "steps": steps,
        "harness_s": harness_s,
        "reference_s": reference_s,
        "ratio": harness_s / reference_s,
        "harness_us_per_step": harness_s / steps * 1e6,
        "reference_us_per_step": reference_s / steps * 1e6,
        "fmu_calls_us_per_step": fmu_us,
        "runtime_step_us": runtime_costs,
        "fmu_call_us": fmu_costs,
        "model_steps_us_per_step": model_us,
        "model_steps_s": model_us * steps * 1e-6,
        "overhead_us_per_step": harness_s / steps * 1e6 - model_us,
        "harness_without_models_s": no_models_s,
        "targets": {
            "harness_s<=1.0": harness_s <= 1.0,
            "ratio<=1.5": harness_s / reference_s <= 1.5,
        },
    }
    print(f"nominal to t = {T_END} ({steps} steps), best of {args.repeat}:")
    print(f"  harness   {harness_s:7.3f} s  ({report['harness_us_per_step']:.1f} us/step)")
    print(f"  reference {reference_s:7.3f} s  ({report['reference_us_per_step']:.1f} us/step)")
    print(f"  ratio     {report['ratio']:7.2f}   targets: {report['targets']}")
    print("  per step, us: FMU calls (set/doStep/get, fixed inputs) | model advance "
          "(in process, the nominal run's inputs replayed)")
    for name, costs in fmu_costs.items():
        calls = " ".join(f"{k}={v:.1f}" for k, v in costs.items())
        print(f"    {name:9s} {calls}  | model advance {runtime_costs[name]:.1f}")
    print(f"  model steps alone: {model_us:.1f} us/step = {report['model_steps_s']:.2f} s for "
          f"{steps} steps (a lower bound for any master over these FMUs)")
    print(f"  harness minus model steps (FMI calls, slaves, master): "
          f"{report['overhead_us_per_step']:.1f} us/step")
    print(f"  harness with no-op model steps: {no_models_s:.2f} s "
          f"({no_models_s / steps * 1e6:.1f} us/step: FMI calls, slaves and master alone)")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return report


if __name__ == "__main__":
    main()
