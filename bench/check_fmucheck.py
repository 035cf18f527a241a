"""The native FMUs in the FMU Compliance Checker, against the pythonfmu FMUs under fmpy.

Usage: ``python bench/check_fmucheck.py --fmucheck PATH --out DIR [--steps N] [--dt DT]
[--pythonfmu]``.

Builds the pendulum FMUs of ``examples/pendulum.toml`` (our design, with its Kalman filter)
into ``DIR`` (pythonfmu FMUs in ``DIR/pythonfmu``, native FMUs in ``DIR/native``), then for
every kind (observer, luenberger, kalman, plant):

1. writes a seeded random-walk input signal (``y`` and ``u`` for the observers, ``u`` and
   ``q`` for the plant) as ``DIR/<kind>_inputs.csv``, one row per communication step;
2. runs the FMU Compliance Checker on the native FMU with it (model description check and
   co-simulation, ``-n 0``: an output row at every step), log in ``DIR/<kind>_fmucheck.log``,
   results in ``DIR/<kind>_fmucheck.csv``;
3. runs the pythonfmu FMU through fmpy's ``FMU2Slave`` on the same input values, with the
   checker's calling sequence;

4. with ``--pythonfmu``: runs the checker on the pythonfmu FMU too, in an empty environment
   (no ``LD_PRELOAD``, ``PYTHONHOME`` or ``PATH``: its status wrapper loads the Python that
   built it), log and results in ``DIR/<kind>_pythonfmu_fmucheck.*``;

and prints a table: the warnings and errors the checker reports (its own and those the FMU
logged), and the largest difference between the two runs, max |native - pythonfmu| / max
|pythonfmu| over time, for the worst output (then every output); with ``--pythonfmu`` the same
for the pythonfmu FMU in the checker against fmpy. The checker's messages are printed under
the tables.

Input convention: before each ``fmi2DoStep(t_k, h)`` the checker sets the inputs to the CSV
interpolated linearly at ``t_k``. With one CSV row per step, that is the row of ``t_k``
itself, held over the step; the fmpy run sets the same row before the same step, so both
FMUs see identical piecewise-constant inputs. The checker also sets the inputs of ``t_0``
right after ``fmi2Instantiate``, before ``fmi2SetupExperiment``, as the fmpy run does.
Without ``-h`` the checker steps by stopTime / 500 (1/500 s, as the FMUs declare no stop
time), which the native FMUs refuse (``fmi2Error``, their log naming the built step sizes)
unless built for it; hence the explicit ``-s`` and ``-h`` here.

Building the checker (linux64, offline, about 40 s): take the FMU Compliance Checker sources
(github.com/modelica-tools/FMUComplianceChecker) and unpack FMI Library 2.0.3
(github.com/modelon-community/fmi-library, tag ``2.0.3``) into its ``FMIL/`` folder. In the
checker's ``CMakeLists.txt``, replace the ``GIT_REPOSITORY`` and ``GIT_TAG`` lines of
``ExternalProject_Add(fmil ...)`` by ``DOWNLOAD_COMMAND ""`` so that the unpacked copy is
used. Configure with CMake 3.x (CMake 4 rejects FMI Library 2.0.3's
``LOCATION`` target property reads; Debian's ``/usr/bin/cmake`` is 3.x where a pip-installed
CMake 4 comes first on ``PATH``) and gcc, then build and install::

    mkdir build && cd build
    cmake .. -DCMAKE_BUILD_TYPE=Release -DFMUCHK_INSTALL_PREFIX=$PWD/../install
    make -j2 && make install

The binary is ``install/fmuCheck.linux64``; pass it as ``--fmucheck``.
"""

from __future__ import annotations

import argparse
import re
import subprocess
from pathlib import Path

import numpy as np
from fhobs.build import build_fmus
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import load_spec
from fhobs.native.build import build_native_fmus
from fhobs.paper import PENDULUM_SPEC
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

KINDS = ("observer", "luenberger", "kalman", "plant")
SUMMARY = re.compile(r"FMU reported:\s*(\d+) warning\(s\) and error\(s\)\s*Checker reported:"
                     r"\s*(\d+) Warning\(s\)\s*(\d+) Error\(s\)")
FATAL = re.compile(r"(\d+) Fatal error\(s\)")
MESSAGE = re.compile(r"^\s*\[(WARNING|ERROR|FATAL|FMU)\]")


def variables(path: Path, causality: str) -> list[str]:
    """Names of the variables of ``causality`` of an FMU, in XML order."""
    md = read_model_description(str(path))
    return [v.name for v in md.modelVariables if v.causality == causality]


def input_signal(count: int, steps: int, seed: int) -> np.ndarray:
    """Seeded random walk around 0.1, ``steps + 1`` rows (one per step boundary) of ``count``."""
    rng = np.random.default_rng(seed)
    return 0.1 + np.cumsum(rng.normal(scale=0.01, size=(steps + 1, count)), axis=0)


def write_inputs(path: Path, names: list[str], times: np.ndarray, values: np.ndarray) -> None:
    """Write the checker's input CSV: quoted header ``"time","y[1]",...``, exact decimals."""
    lines = [",".join(f'"{name}"' for name in ("time", *names))]
    lines += [",".join(repr(float(x)) for x in (t, *row)) for t, row in zip(times, values,
                                                                            strict=True)]
    path.write_text("\n".join(lines) + "\n")


def run_fmucheck(fmucheck: Path, fmu: Path, inputs: Path, stem: Path, stop: float,
                 dt: float, env: dict[str, str] | None = None
                 ) -> tuple[dict[str, np.ndarray], tuple[int, ...], list[str]]:
    """Run the checker on ``fmu`` (in the environment ``env``, this process's by default);
    return its output columns by name, (FMU-reported, checker warnings, checker errors,
    checker fatal errors) and its warning/error/fatal log lines and the FMU's own log
    messages."""
    log, out = stem.with_suffix(".log"), stem.with_suffix(".csv")
    log.unlink(missing_ok=True)
    out.unlink(missing_ok=True)
    done = subprocess.run([str(fmucheck), "-s", repr(stop), "-h", repr(dt), "-n", "0", "-l", "3",
                           "-i", str(inputs), "-o", str(out), "-e", str(log), str(fmu)],
                          check=False, capture_output=True, text=True, env=env)
    if not log.exists():
        log.write_text(f"the checker wrote no log (exit code {done.returncode})\n{done.stderr}")
    text = log.read_text()
    found = SUMMARY.search(text)
    counts = tuple(int(g) for g in found.groups()) if found else (-1, -1, -1)
    fatal = FATAL.search(text)
    counts += (int(fatal.group(1)) if fatal else 0,)
    messages = [line for line in text.splitlines() if MESSAGE.match(line)]
    lines = out.read_text().splitlines() if out.exists() else ['"time"']
    names = [name.strip('"') for name in lines[0].split(",")]
    table = np.array([[float(x) for x in row.split(",")] for row in lines[1:]])
    columns = {name: table[:, j] if table.size else np.empty(0) for j, name in enumerate(names)}
    return columns, counts, messages


def run_fmpy(fmu: Path, input_names: list[str], output_names: list[str], values: np.ndarray,
             dt: float) -> np.ndarray:
    """Outputs ``output_names`` of ``fmu`` under fmpy at every step boundary (one column
    each), with the checker's calling sequence: set the inputs ``input_names`` (one column of
    ``values`` each), setup, initialise, then (set inputs of t_k, doStep(t_k, dt)) per step."""
    md = read_model_description(str(fmu))
    references = {v.name: v.valueReference for v in md.modelVariables}
    inputs = [references[name] for name in input_names]
    outputs = [references[name] for name in output_names]
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="check")
    slave.instantiate()
    slave.setReal(inputs, values[0].tolist())
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    rows = [slave.getReal(outputs)]
    for k, row in enumerate(values[:-1]):
        slave.setReal(inputs, row.tolist())
        slave.doStep(k * dt, dt)
        rows.append(slave.getReal(outputs))
    slave.terminate()
    slave.freeInstance()
    return np.array(rows)


def relative_differences(native: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per column, max |native - reference| / max |reference| (absolute where the reference
    is identically zero); NaN for every column when the shapes differ."""
    if native.shape != reference.shape:
        return np.full(reference.shape[1], np.nan)
    scale = np.abs(reference).max(axis=0)
    return np.abs(native - reference).max(axis=0) / np.where(scale > 0, scale, 1.0)


def check_kind(kind: str, native: Path, python: Path, args: argparse.Namespace) -> dict:
    """Run one kind both ways and return its row of results."""
    names = variables(native, "input")
    outputs = variables(native, "output")
    times = np.arange(args.steps + 1) * args.dt
    values = input_signal(len(names), args.steps, args.seed)
    inputs = args.out / f"{kind}_inputs.csv"
    write_inputs(inputs, names, times, values)
    columns, counts, messages = run_fmucheck(args.fmucheck, native, inputs,
                                           args.out / f"{kind}_fmucheck", args.steps * args.dt,
                                           args.dt)
    reference = run_fmpy(python, names, outputs, values, args.dt)
    row = {"kind": kind, "counts": counts, "messages": messages, "outputs": outputs,
           "relative": relative_differences(output_table(columns, outputs), reference),
           "rows": len(output_table(columns, outputs))}
    if args.pythonfmu:
        columns, counts, messages = run_fmucheck(args.fmucheck, python, inputs,
                                                 args.out / f"{kind}_pythonfmu_fmucheck",
                                                 args.steps * args.dt, args.dt, env={})
        checked = output_table(columns, outputs)
        row["pythonfmu"] = {"kind": kind, "counts": counts, "messages": messages,
                            "outputs": outputs, "rows": len(checked),
                            "relative": relative_differences(checked, reference)}
    return row


def output_table(columns: dict[str, np.ndarray], outputs: list[str]) -> np.ndarray:
    """The checker's ``outputs`` columns side by side (no rows if one is missing)."""
    if all(name in columns for name in outputs):
        return np.column_stack([columns[name] for name in outputs])
    return np.empty((0, len(outputs)))


def print_report(results: list[dict], args: argparse.Namespace,
                 title: str = "the native FMUs") -> None:
    """The summary table, the per-output table and the checker's messages."""
    print(f"\nFMU Compliance Checker on {title}, {args.steps} steps of {args.dt:g} s, "
          f"against the pythonfmu FMUs under fmpy (same inputs, seed {args.seed})")
    print("| FMU | checker warnings | checker errors | fatal | FMU-reported | output rows | "
          "max rel. difference | worst output |")
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        fmu_reported, warnings, errors, fatal = r["counts"]
        worst = int(np.nanargmax(r["relative"])) if np.isfinite(r["relative"]).any() else 0
        print(f"| {r['kind']} | {warnings} | {errors} | {fatal} | {fmu_reported} | {r['rows']} | "
              f"{r['relative'].max():.2e} | {r['outputs'][worst]} |")
    print("\n| FMU | output | max rel. difference |\n|---|---|---|")
    for r in results:
        for name, value in zip(r["outputs"], r["relative"], strict=True):
            print(f"| {r['kind']} | {name} | {value:.2e} |")
    print("\nchecker messages (warnings, errors, fatal; the FMU's own as [FMU]):")
    for r in results:
        for line in r["messages"] or ["(none)"]:
            print(f"  {r['kind']}: {line.strip()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmucheck", type=Path, required=True,
                        help="the FMU Compliance Checker binary (fmuCheck.linux64)")
    parser.add_argument("--out", type=Path, required=True, help="directory for FMUs and runs")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--dt", type=float, default=1e-3,
                        help="communication step (the native FMUs are built for it)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the input signals")
    parser.add_argument("--pythonfmu", action="store_true",
                        help="also run the checker on the pythonfmu FMUs, environment empty")
    args = parser.parse_args()
    if not args.fmucheck.is_file():
        parser.error(f"--fmucheck {args.fmucheck}: no such file (build the checker first, "
                     "see the docstring of this script)")
    args.out.mkdir(parents=True, exist_ok=True)
    gains = design_for_spec(load_spec(PENDULUM_SPEC))
    python = build_fmus(gains, args.out / "pythonfmu", kinds=KINDS)
    native = build_native_fmus(gains, args.out / "native", kinds=KINDS, steps=[args.dt])
    results = [check_kind(kind, native[kind], python[kind], args) for kind in KINDS]
    print_report(results, args)
    if args.pythonfmu:
        print_report([r["pythonfmu"] for r in results], args,
                     "the pythonfmu FMUs (empty environment: env -i)")


if __name__ == "__main__":
    main()
