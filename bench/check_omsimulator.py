"""The exported native SSP in OMSimulator 3.0, without Python, against the harness.

Usage: ``python bench/check_omsimulator.py --out DIR (--omsimulator PATH | --oms-src SRC)
[--scenario pendulum_nominal] [--design spec|paper] [--stop-time T] [--timeout S]``.

1. builds the pendulum FMUs of ``examples/pendulum.toml`` (``--design spec``: our design; or
   the paper's published gains) with their native FMUs into ``DIR/fmus`` (as ``python -m
   harness paper --native`` does), loads the scenario on ``DIR/fmus/native`` and exports it as
   ``DIR/<scenario>.ssp`` (:func:`harness.ssp.export_ssp`: gains lowered to gain blocks, every
   FMU native, the harness blocks included; checked here: no FMU of the SSP is a pythonfmu
   FMU);
2. runs ``OMSimulator --resultFile=DIR/oms_result.csv --stopTime=T DIR/<scenario>.ssp`` in an
   empty environment (``env -i``: no PYTHONHOME, no PATH, no LD_LIBRARY_PATH; what the binary
   needs beyond libc must come with it), its log in ``DIR/oms.log``;
3. runs the harness on the scenario (gains applied by the master, as ``harness paper
   --native``) and on the exported system (the gain blocks, as a Jacobi engine runs the SSP),
   and prints OMSimulator's outcome (exit status, rows, the last time it reached, its error
   lines), the scenario's figures (errors at the instants, max and RMS over the windows) for the
   three runs, and the largest differences of the recorded signals at the common instants.

OMSimulator reads an SSP only with OpenModelica's annotation of the top-level system
(``oms:SimulationInformation`` with an ``oms:FixedStepMaster``; the export writes it with the
scenario's step). Its master orders the exchange by the declared dependencies (the gain
blocks' outputs depend on their inputs), so it follows the scenario itself rather than the
lagged Jacobi exchange of fmpy and libcosim; both comparisons are printed. Its CSV holds 15
significant digits.

Building OMSimulator 3.0 (linux64, offline, about 10 minutes on 2 cores, CMake >= 3.5 and a
C/C++ compiler): unpack tag ``v3.0.0`` of github.com/OpenModelica/OMSimulator, and in its
empty ``3rdParty/`` commit ``f807ac3664cf21a86304e56e1b8ebf7b192f26b8`` of
github.com/OpenModelica/OMSimulator-3rdParty (from git mirrors ``OMS.git`` and ``3RD.git``;
``git archive`` stops at the test suite's large reference files when a mirror lacks them, which
the build does not need)::

    mkdir oms && git --git-dir=OMS.git archive v3.0.0 | tar -x -C oms
    git --git-dir=3RD.git archive f807ac3664cf21a86304e56e1b8ebf7b192f26b8 | tar -x -C oms/3rdParty
    export CMAKE_POLICY_VERSION_MINIMUM=3.5     # CMake 4 refuses the 3rd-party projects' minimum
    cmake -S oms -B oms/build -DCMAKE_INSTALL_PREFIX=oms/install -DCMAKE_BUILD_TYPE=Release
    cmake --build oms/build --target install -j2

The binary is ``oms/install/bin/OMSimulator``; pass it as ``--omsimulator``, or pass the
unpacked sources as ``--oms-src`` and this script runs the two CMake steps (unless
``install/bin/OMSimulator`` is there already; log in ``SRC/build.log``).
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.cli import build_paper_fmus, load_scenario  # noqa: E402
from harness.master import CoSimResult, run_system  # noqa: E402
from harness.results import error_figures  # noqa: E402
from harness.ssp import export_ssp, exported_system, is_pythonfmu  # noqa: E402
from harness.system import SystemSpec, resolve_system  # noqa: E402

OMS_BINARY = Path("install/bin/OMSimulator")
"""Where the build puts the binary, relative to the sources."""


def build_omsimulator(src: Path) -> Path:
    """Build and install OMSimulator from its unpacked sources ``src`` (with ``3rdParty/``);
    return the binary. Nothing is built when ``src/install/bin/OMSimulator`` exists.

    Examples
    --------
    >>> build_omsimulator(Path("oms"))  # doctest: +SKIP
    PosixPath('oms/install/bin/OMSimulator')
    """
    binary = src / OMS_BINARY
    if binary.is_file():
        return binary
    if not all((src / part / "CMakeLists.txt").is_file() for part in (".", "3rdParty")):
        raise SystemExit(f"--oms-src {src}: expected OMSimulator's sources with 3rdParty/ "
                         "filled in (see the docstring of this script)")
    env = {**os.environ, "CMAKE_POLICY_VERSION_MINIMUM": "3.5"}
    with open(src / "build.log", "w") as log:
        for command in (["cmake", "-S", str(src), "-B", str(src / "build"),
                         f"-DCMAKE_INSTALL_PREFIX={src.resolve() / 'install'}",
                         "-DCMAKE_BUILD_TYPE=Release"],
                        ["cmake", "--build", str(src / "build"), "--target", "install", "-j2"]):
            print("$", " ".join(command), flush=True)
            if subprocess.run(command, stdout=log, stderr=subprocess.STDOUT, env=env).returncode:
                raise SystemExit(f"building OMSimulator failed: see {src / 'build.log'}")
    return binary


def export_native_ssp(out: Path, scenario: str, design: str) -> tuple[SystemSpec, Path]:
    """Build the FMUs (pythonfmu and native) into ``out/fmus``, load ``scenario`` on the native
    ones and export it as ``out/<scenario>.ssp``; check that every FMU of the SSP is native."""
    native = build_paper_fmus(out / "fmus", design=design, native=True)
    spec = load_scenario(scenario, native, out / "blocks")
    ssp = export_ssp(spec, out / f"{scenario}.ssp", out / "blocks")
    unpacked = out / "ssp_fmus"
    with zipfile.ZipFile(ssp) as archive:
        fmus = [Path(archive.extract(n, unpacked)) for n in archive.namelist()
                if n.endswith(".fmu")]
    python = [fmu.name for fmu in fmus if is_pythonfmu(fmu)]
    if python:
        raise SystemExit(f"the SSP holds pythonfmu FMUs: {python}")
    return spec, ssp


def run_omsimulator(binary: Path, ssp: Path, out: Path, stop_time: float,
                    timeout: float) -> tuple[int, Path, str]:
    """Run ``binary`` on ``ssp`` under ``env -i``; return its exit status (-1: timeout), the
    result CSV and its log (stdout and stderr, also written to ``out/oms.log``)."""
    result = out / "oms_result.csv"
    result.unlink(missing_ok=True)
    temp = out / "oms_temp"
    temp.mkdir(exist_ok=True)
    command = ["env", "-i", str(binary.resolve()), f"--resultFile={result.resolve()}",
               f"--stopTime={stop_time!r}", f"--tempDir={temp.resolve()}", str(ssp.resolve())]
    print("$", " ".join(command), flush=True)
    try:
        run = subprocess.run(command, capture_output=True, text=True, timeout=timeout,
                             cwd=out, check=False)
        status, log = run.returncode, run.stdout + run.stderr
    except subprocess.TimeoutExpired as err:
        status, log = -1, f"timeout after {timeout} s\n{err.stdout or ''}{err.stderr or ''}"
    (out / "oms.log").write_text(log)
    return status, result, log


def read_oms_result(path: Path, names: list[str]) -> CoSimResult | None:
    """The signals ``names`` (``"fmu.var"``) from OMSimulator's CSV (columns named
    ``<model>.<system>.<fmu>.<var>``), one row per time (the last row of a repeated time)."""
    if not path.is_file():
        return None
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header = [h.strip().strip('"') for h in rows[0]]
    columns = {}
    for name in names:
        found = [j for j, h in enumerate(header) if h == name or h.endswith("." + name)]
        if not found:
            return None
        columns[name] = found[0]
    table = np.array([[float(x) for x in row] for row in rows[1:] if row])
    time = table[:, 0]
    last = np.append(time[1:] != time[:-1], True)  # the last row of each time
    values = np.column_stack([table[last, columns[n]] for n in names])
    return CoSimResult(time[last], tuple(names), values, int(last.sum()) - 1, 0.0)


def on_grid(result: CoSimResult, reference: CoSimResult) -> tuple[np.ndarray, np.ndarray]:
    """The signals of ``result`` in both runs at their common instants (within 1e-9 s)."""
    index = np.searchsorted(reference.time, result.time - 1e-9)
    index = np.minimum(index, len(reference.time) - 1)
    match = np.abs(reference.time[index] - result.time) <= 1e-9
    theirs = np.column_stack([reference.signal(n) for n in result.names])
    return result.values[match], theirs[index[match]]


def differences(figures: dict, reference: dict) -> str:
    """Per error signal, the largest relative and absolute difference of its figures."""
    return ", ".join(
        f"{e} {max(abs(figures[e][k] / reference[e][k] - 1) for k in reference[e]):.1e} rel "
        f"{max(abs(figures[e][k] - reference[e][k]) for k in reference[e]):.1e} abs"
        for e in reference)


def print_report(status: int, log: str, oms: CoSimResult | None, runs: dict[str, CoSimResult],
                 spec: SystemSpec) -> None:
    """OMSimulator's outcome, the figures of every run and the differences."""
    errors = [line for line in log.splitlines() if "error" in line.lower()]
    print(f"\nOMSimulator: exit status {status}, "
          + (f"{len(oms.time)} rows, last t = {oms.time[-1]!r}" if oms is not None
             else "no result file with the recorded signals"))
    for line in errors[:20]:
        print(f"  {line}")
    if oms is not None:
        runs = {"OMSimulator": oms, **runs}
    figures = {label: error_figures(r, spec.evaluation) for label, r in runs.items()}
    keys = [(e, k) for e in figures["harness (scenario)"]
            for k in figures["harness (scenario)"][e]]
    print("\n| figure | " + " | ".join(figures) + " |")
    print("|---|" + "---|" * len(figures))
    for e, k in keys:
        cells = " | ".join(f"{f.get(e, {}).get(k, float('nan')):.6e}" for f in figures.values())
        print(f"| {e} {k} | {cells} |")
    if oms is None:
        return
    print("\n| OMSimulator against | figure differences (per error signal) | max abs. signal "
          "difference | common instants |\n|---|---|---|---|")
    for label, run in runs.items():
        if label == "OMSimulator":
            continue
        a, b = on_grid(oms, run)
        print(f"| {label} | {differences(figures['OMSimulator'], figures[label])} | "
              f"{np.max(np.abs(a - b)) if a.size else float('nan'):.2e} | {len(a)} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--omsimulator", type=Path, help="a built OMSimulator 3.0 binary")
    source.add_argument("--oms-src", type=Path,
                        help="OMSimulator v3.0.0 sources with 3rdParty/ (built if needed)")
    parser.add_argument("--out", type=Path, required=True, help="directory for FMUs and runs")
    parser.add_argument("--scenario", default="pendulum_nominal")
    parser.add_argument("--design", choices=("spec", "paper"), default="spec")
    parser.add_argument("--stop-time", type=float, help="default: the scenario's")
    parser.add_argument("--timeout", type=float, default=1800.0, help="OMSimulator's, s")
    args = parser.parse_args()
    binary = args.omsimulator if args.omsimulator else build_omsimulator(args.oms_src)
    if not binary.is_file():
        parser.error(f"--omsimulator {binary}: no such file (build it first, see the "
                     "docstring of this script)")
    args.out.mkdir(parents=True, exist_ok=True)
    spec, ssp = export_native_ssp(args.out, args.scenario, args.design)
    stop_time = args.stop_time if args.stop_time is not None else spec.stop_time
    status, result, log = run_omsimulator(binary, ssp, args.out, stop_time, args.timeout)
    runs = {
        "harness (scenario)": run_system(resolve_system(spec), stop_time=stop_time,
                                         progress=False),
        "harness (exported system)": run_system(
            resolve_system(exported_system(spec, args.out / "blocks")), stop_time=stop_time,
            progress=False),
    }
    names = list(runs["harness (scenario)"].names)
    print_report(status, log, read_oms_result(result, names), runs, spec)


if __name__ == "__main__":
    main()
