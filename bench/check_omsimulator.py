"""Exported native SSPs in OMSimulator 3.0, without Python, against the harness.

Usage: ``python bench/check_omsimulator.py --out DIR (--omsimulator PATH | --oms-src SRC)
[--scenario NAME ...] [--plant SPEC ...] [--no-blocks] [--design spec|paper] [--stop-time T]
[--timeout S]``.

The systems checked: every bundled scenario (``harness/scenarios/*.toml``, ``python -m harness
list``; or the ``--scenario`` names), ``harness plant``'s system of each ``--plant`` spec (its
``[disturbance]`` as a native ``signal`` block, its plant's seeded measurement noise; e.g.
``fmu_src/fhobs/examples/stiff/dc_motor.toml``) and, unless ``--no-blocks``, a system of every
source block (signal random walk and step from a start between two steps, Gaussian noise,
constant through a gain block) added by a sum block. For each:

1. builds the FMUs natively (the pendulum FMUs of ``examples/pendulum.toml`` with
   ``--design spec`` or the paper's published gains, as ``python -m harness paper --native``;
   a plant spec's design as ``harness plant --native``) into ``DIR/fmus``, and exports the
   system as ``DIR/<system>/<system>.ssp`` (:func:`harness.ssp.export_ssp` with
   ``allow_python=False``: gains lowered to gain blocks, every FMU native, the harness blocks
   native, refused if any FMU needed Python);
2. runs ``OMSimulator --resultFile=... --stopTime=T <system>.ssp`` in an empty environment
   (``env -i``: no PYTHONHOME, no PATH, no LD_LIBRARY_PATH; what the binary needs beyond libc
   must come with it), its log in ``DIR/<system>/oms.log``;
3. runs the harness on the system (gains applied by the master) and on the exported system
   (the gain blocks, as a Jacobi engine runs the SSP), and prints OMSimulator's outcome (exit
   status, rows, the last time it reached, its last step, its error lines), the figures
   (errors at the instants, max and RMS over the windows, ...) of the three runs and the
   largest differences of the recorded signals at the common instants; then one summary row
   per system.

OMSimulator reads an SSP only with OpenModelica's annotation of the top-level system
(``oms:SimulationInformation`` with an ``oms:FixedStepMaster``; the export writes it with the
scenario's step). Its master orders the exchange by the declared dependencies (the gain and
sum blocks' outputs depend on their inputs), so it follows the system itself rather than the
lagged Jacobi exchange of fmpy and libcosim: the summary compares it with the harness's run of
the system (in the system of blocks, whose sum block's output the harness's Jacobi exchange
reads one step late, with that output formed from its inputs of the same instant:
:func:`without_lag`). Its CSV result holds 12 significant digits (``%.12g``), so the script
asks for its MAT v4 result (doubles, the times exact). A signal's difference is taken relative
to the largest magnitude of the signal (the summary's "signals" column), a figure's relative to
itself or, for an error figure far below its signals, to the scale of the error's reference
signal (the largest norm of the true state, as the harness's settling figures take it); the
check asks 1e-9 of both. OMSimulator writes two rows per step (after the doStep, after the
exchange: the last row of a time is kept). It accumulates its time in floating point
(t += h), so after N steps it is short of ``t0 + N h`` by up to a few 1e-13 s and, given that
stop time, takes an extra step of that length: the native FMUs and blocks accept it (any
positive step), the supervised observer refuses it (it steps whole Kalman samples: an error
in OMSimulator's log), and it is one more draw of the seeded noise. So the script passes
OMSimulator the time its master reaches after N steps (:func:`accumulated_time`, the same sum)
as ``T``: it then stops after exactly the harness's N steps. Should a last step still come
(its length is printed), its row is left out (of two instants within 1e-9 s the first is
kept).

Building OMSimulator 3.0 (linux64, offline, about 10-20 minutes on 2 cores, CMake >= 3.5 and a
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
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.io

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.cli import SCENARIO_DIR, build_paper_fmus, design_spec_file, load_scenario  # noqa: E402
from harness.master import CoSimResult, run_system  # noqa: E402
from harness.own_plant import (  # noqa: E402
    FIGURES,
    RUNS_PER_SETTLING_TIME,
    STEP,
    own_plant_system,
    plant_figures,
    transient_end,
)
from harness.results import error_figures  # noqa: E402
from harness.ssp import export_ssp, exported_system  # noqa: E402
from harness.system import (  # noqa: E402
    ConnectionSpec,
    FmuSpec,
    ResolvedSystem,
    SystemSpec,
    build_blocks,
    resolve_system,
)

OMS_BINARY = Path("install/bin/OMSimulator")
"""Where the build puts the binary, relative to the sources."""
TOLERANCE = 1e-9
"""What the check asks of the signals and the figures (relative, see the module docstring)."""
SAME_INSTANT = 1e-9
"""Two rows of OMSimulator's CSV this close in time (s) are one instant."""


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


# -- the systems -------------------------------------------------------------------------------

def scenario_systems(out: Path, names: list[str], design: str) -> list[SystemSpec]:
    """The scenarios ``names`` on the native pendulum FMUs (built once into ``out/fmus``)."""
    native = build_paper_fmus(out / "fmus", design=design, native=True)
    return [load_scenario(name, native, out / "blocks") for name in names]


def plant_system(out: Path, spec_path: Path, seed: int = 3) -> SystemSpec:
    """``harness plant``'s system of the spec (its default step and stop time, its
    ``[disturbance]``, the measurement noise of its ``[noise]`` table with ``seed``) on the
    native FMUs of its design (built into ``out/fmus/<spec>``)."""
    from fhobs.native.build import build_native_fmus

    spec, design = design_spec_file(spec_path)
    noise = 0.0 if spec.noise is None else float(np.sqrt(3.0) * np.max(spec.noise.measurement_std))
    step = spec.noise.sample_time if spec.noise is not None else 1e-3
    stop_time = step * round(RUNS_PER_SETTLING_TIME * spec.settling_time / step)
    native = build_native_fmus(design, out / "fmus" / spec_path.stem, steps=(step,),
                               T0=spec.settling_time, x0=spec.state_scale,
                               noise_amplitude=noise, h=step)
    settled = transient_end(design, spec.settling_time, step, stop_time)
    system = own_plant_system(design, native, spec.state_scale, stop_time, step, noise,
                              disturbance=spec.disturbance, settled=settled)
    system = replace(system, name=f"plant_{spec_path.stem}")
    return build_blocks(system.with_seed(seed) if noise else system, out / "blocks")


PLANT_TABLES: dict[str, tuple[float, int, dict]] = {}
"""Per ``--plant-spec`` system: its transient's end, its q channels and the harness run's
summary (``harness plant``'s table)."""


def plant_model_system(out: Path, spec_path: Path, seed: int = 3) -> SystemSpec:
    """``harness plant --native``'s run of a ``[plant_model]`` spec (its default step and stop
    time, its ``[disturbance]``, the master's measurement noise of its ``[noise]`` table with
    ``seed``; results in ``out/runs/<spec>``): the run's system as ``--export-ssp`` writes it
    (the user's FMUs as they are, with the run's start values; the native estimators), its
    summary kept in :data:`PLANT_TABLES`."""
    from harness.plant_model import run_plant_model

    spec, design = design_spec_file(spec_path)
    step = spec.noise.sample_time if spec.noise is not None else STEP
    stop_time = step * round(RUNS_PER_SETTLING_TIME * spec.settling_time / step)
    settled = transient_end(design, spec.settling_time, step, stop_time)
    systems: list[SystemSpec] = []
    data = run_plant_model(spec, design, out / "runs" / spec_path.stem, step=step,
                           stop_time=stop_time, settled=settled, seed=seed, plots=False,
                           native=True, block_cache=out / "blocks", export=systems.append)
    system = replace(systems[0], name=f"plant_model_{spec_path.stem}")
    PLANT_TABLES[system.name] = (settled, len(spec.plant_model.unknown_inputs), data)
    return system


SCALED = np.array([[0.5, -2.0], [1.5, 0.25]])
"""The blocks system's gain on the constant."""


def blocks_system(out: Path) -> SystemSpec:
    """Every source block, the constant through a gain block, added by a sum block: a random
    walk and a step from a start between two steps, Gaussian noise, a constant; 2000 steps of
    1 ms (the draws cross a generator block of 1024). The constant reaches the sum through two
    direct-feedthrough blocks in a row, which OMSimulator passes on at the start time too (the
    blocks' outputs are initial unknowns computed from their inputs)."""
    start = 0.2005
    fmus = {
        "walk": FmuSpec("walk", None, {"shape": 3, "seed": 5, "start": start, "size[1]": 0.5,
                                       "size[2]": -1.0}, ("signal", (2,))),
        "step": FmuSpec("step", None, {"shape": 0, "start": start, "size[1]": 1.0,
                                       "size[2]": 2.0}, ("signal", (2,))),
        "noise": FmuSpec("noise", None, {"distribution": 1, "seed": 7, "size[1]": 0.1,
                                         "size[2]": 0.2}, ("noise", (2,))),
        "offset": FmuSpec("offset", None, {"value[1]": 3.0, "value[2]": -4.0},
                          ("constant", (2,))),
        "scaled": FmuSpec("scaled", None, {f"K[{i + 1},{j + 1}]": float(SCALED[i, j])
                                           for i in range(2) for j in range(2)},
                          ("gain", (2, 2))),
        "total": FmuSpec("total", None, {}, ("sum", (2, 4))),
    }
    connections = tuple(ConnectionSpec(f"{source}.y[{i}]", f"total.u[{k + 1},{i}]")
                        for k, source in enumerate(("walk", "step", "noise", "scaled"))
                        for i in (1, 2))
    connections += tuple(ConnectionSpec(f"offset.y[{i}]", f"scaled.u[{i}]") for i in (1, 2))
    system = SystemSpec("blocks", fmus, connections, 1e-3, 2.0,
                        record=("walk.y", "step.y", "noise.y", "offset.y", "scaled.y",
                                "total.y"))
    return build_blocks(system, out / "blocks", native=True)


def without_lag(result: CoSimResult) -> CoSimResult:
    """The blocks system's harness run with ``scaled.y`` and ``total.y`` as the gain and sum
    blocks give them from their inputs of the same instant: ``SCALED offset.y`` and ``walk.y
    + step.y + noise.y + scaled.y``, added in the blocks' order (the harness's Jacobi exchange
    reads each one step late; OMSimulator orders the exchange by the blocks' declared
    dependencies)."""
    offset = result.vector("offset.y")
    scaled = 0.0 + SCALED[:, 0] * offset[:, :1] + SCALED[:, 1] * offset[:, 1:]
    total = (0.0 + result.vector("walk.y") + result.vector("step.y") + result.vector("noise.y")
             + scaled)
    values = result.values.copy()
    for name, signal in (("scaled.y", scaled), ("total.y", total)):
        for i in range(2):
            values[:, result.names.index(f"{name}[{i + 1}]")] = signal[:, i]
    return replace(result, values=values)


REFERENCES = {"blocks": without_lag}
"""The systems whose harness run is compared with OMSimulator's after a change."""


# -- OMSimulator ---------------------------------------------------------------------------------

def run_omsimulator(binary: Path, ssp: Path, out: Path, stop_time: float, timeout: float,
                    tolerance: float | None = None) -> tuple[int, Path, str]:
    """Run ``binary`` on ``ssp`` under ``env -i`` (with ``--tolerance`` when the system has a
    run tolerance: the command line replaces the SSP's); return its exit status (-1:
    timeout), the result file and its log (stdout and stderr, also written to
    ``out/oms.log``)."""
    result = out / "oms_result.mat"
    result.unlink(missing_ok=True)
    temp = out / "oms_temp"
    temp.mkdir(exist_ok=True)
    command = ["env", "-i", str(binary.resolve()), f"--resultFile={result.resolve()}",
               f"--stopTime={stop_time!r}", f"--tempDir={temp.resolve()}",
               *([f"--tolerance={tolerance!r}"] if tolerance is not None else []),
               str(ssp.resolve())]
    print("$", " ".join(command), flush=True)
    try:
        run = subprocess.run(command, capture_output=True, text=True, timeout=timeout,
                             cwd=out, check=False)
        status, log = run.returncode, run.stdout + run.stderr
    except subprocess.TimeoutExpired as err:
        status, log = -1, f"timeout after {timeout} s\n{err.stdout or ''}{err.stderr or ''}"
    (out / "oms.log").write_text(log)
    return status, result, log


def read_oms_result(path: Path, names: list[str]) -> tuple[CoSimResult, float] | None:
    """The signals ``names`` (``"fmu.var"``) from OMSimulator's MAT v4 result (doubles; the
    variables named ``<model>.<system>.<fmu>.<var>``, their values in ``data_2`` by
    ``dataInfo``), one row per instant (the last row of a repeated time, the one after the
    exchange; of two instants within :data:`SAME_INSTANT`, the first), and its last step (s)."""
    if not path.is_file():
        return None
    mat = scipy.io.loadmat(str(path))
    info = mat["dataInfo"]
    count = info.shape[1]
    chars = np.array([list(row.ljust(count, "\0")) for row in mat["name"]])
    header = ["".join(chars[:, j]).rstrip("\0 ") for j in range(count)]
    data = mat["data_2"]
    series = {}
    for name in ["time", *names]:
        found = [j for j, h in enumerate(header) if h == name or h.endswith("." + name)]
        if not found or info[0, found[0]] not in (0, 2):
            return None
        column = info[1, found[0]]
        series[name] = np.sign(column) * data[abs(column) - 1]
    time = series["time"]
    last = np.flatnonzero(np.append(time[1:] != time[:-1], True))  # the last row of a time
    keep = [last[0]]
    for k in last[1:]:
        if time[k] - time[keep[-1]] > SAME_INSTANT:
            keep.append(k)
    last_step = float(time[last[-1]] - time[last[-2]])
    values = np.column_stack([series[n][keep] for n in names])
    return CoSimResult(time[keep], tuple(names), values, len(keep) - 1, 0.0), last_step


def with_derived(result: CoSimResult, system: ResolvedSystem) -> CoSimResult:
    """``result`` with the system's derived signals (``[[derived]]``) computed from its
    columns as the master computes them after a run (OMSimulator has no such signals)."""
    columns = [result.values]
    for d in system.derived:
        cols = [result.names.index(f"{f}.{v.name}") for f, v in d.sources]
        columns.append((result.values[:, cols] - d.offset) @ d.gain.T + d.bias)
    names = result.names + tuple(n for d in system.derived for n in d.names)
    return replace(result, names=names, values=np.hstack(columns))


def plant_table_difference(oms: CoSimResult, harness: CoSimResult, spec: SystemSpec) -> float:
    """For a ``--plant-spec`` system: ``harness plant``'s table (x and q errors per window,
    :func:`harness.own_plant.plant_figures`) of OMSimulator's run, of the harness's run and as
    the harness run's summary wrote it; printed; the largest difference of OMSimulator's from
    the summary's, relative to the figure."""
    settled, channels, data = PLANT_TABLES[spec.name]
    tables = {"OMSimulator": plant_figures(oms, spec, settled, channels),
              "harness (system)": plant_figures(harness, spec, settled, channels)}
    print("\n| estimator | figure | OMSimulator | harness (system) | harness plant summary |"
          "\n|---|---|---|---|---|")
    worst = 0.0
    for label, figures in data.items():
        if not isinstance(figures, dict) or not set(FIGURES) & set(figures):
            continue
        for key in (k for k in FIGURES if k in figures):
            cells = [tables[run][label][key] for run in tables] + [figures[key]]
            print(f"| {label} | {key} | " + " | ".join(f"{c:.9e}" for c in cells) + " |")
            worst = max(worst, abs(cells[0] - cells[2]) / abs(cells[2]) if cells[0] != cells[2]
                        else 0.0)
    return worst


def on_grid(result: CoSimResult, reference: CoSimResult) -> tuple[np.ndarray, np.ndarray]:
    """The signals of ``result`` in both runs at their common instants (within 1e-9 s)."""
    index = np.searchsorted(reference.time, result.time - 1e-9)
    index = np.minimum(index, len(reference.time) - 1)
    match = np.abs(reference.time[index] - result.time) <= 1e-9
    theirs = np.column_stack([reference.signal(n) for n in result.names])
    return result.values[match], theirs[index[match]]


def signal_difference(result: CoSimResult, reference: CoSimResult) -> tuple[float, int]:
    """The largest difference of a recorded signal between the runs at their common instants,
    relative to that signal's largest magnitude in ``reference``; the number of instants."""
    a, b = on_grid(result, reference)
    scale = np.max(np.abs(b), axis=0)
    scale[scale == 0.0] = 1.0
    return float(np.max(np.abs(a - b) / scale)) if a.size else float("nan"), len(a)


def figure_difference(figures: dict, reference: dict, scales: dict[str, float]) -> float:
    """The largest difference of a figure, relative to the figure or (when smaller) to the
    scale of its error's reference signal (:func:`reference_scales`)."""
    worst = 0.0
    for e, values in reference.items():
        for k, value in values.items():
            diff = abs(figures[e][k] - value)
            worst = max(worst, diff / max(abs(value), scales[e]) if diff else 0.0)
    return worst


def reference_scales(result: CoSimResult, spec: SystemSpec) -> dict[str, float]:
    """Per error signal: the largest norm of its reference signal (the true state)."""
    return {e: float(np.max(np.linalg.norm(result.vector(ref), axis=1)))
            for e, (ref, _) in spec.evaluation.errors.items()}


def print_report(status: int, log: str, oms: CoSimResult | None, last_step: float,
                 runs: dict[str, CoSimResult], spec: SystemSpec) -> dict[str, float]:
    """OMSimulator's outcome, the figures of every run and the differences; the comparison
    with the harness's run of the system (its summary row)."""
    errors = [line for line in log.splitlines() if "error" in line.lower()]
    print(f"\nOMSimulator: exit status {status}, "
          + (f"{len(oms.time)} instants, last t = {oms.time[-1]!r}, last step {last_step:.3g} s"
             if oms is not None else "no result file with the recorded signals"))
    for line in errors[:20]:
        print(f"  {line}")
    if oms is not None:
        runs = {"OMSimulator": oms, **runs}
    figures = {label: error_figures(r, spec.evaluation) for label, r in runs.items()}
    keys = [(e, k) for e in figures["harness (system)"] for k in figures["harness (system)"][e]]
    if keys:
        print("\n| figure | " + " | ".join(figures) + " |")
        print("|---|" + "---|" * len(figures))
        for e, k in keys:
            cells = " | ".join(f"{f.get(e, {}).get(k, float('nan')):.9e}" for f in figures.values())
            print(f"| {e} {k} | {cells} |")
    row = {"status": status, "errors": len(errors), "instants": 0 if oms is None else len(oms.time),
           "last_step": last_step, "signals": float("nan"), "figures": float("nan")}
    if oms is None:
        return row
    scales = reference_scales(runs["harness (system)"], spec)
    print("\n| OMSimulator against | largest figure difference | largest signal difference "
          "(relative to the signal) | common instants |\n|---|---|---|---|")
    for label, run in runs.items():
        if label == "OMSimulator":
            continue
        signals, common = signal_difference(oms, run)
        fig = figure_difference(figures["OMSimulator"], figures[label], scales)
        print(f"| {label} | {fig:.2e} | {signals:.2e} | {common} |")
        if label == "harness (system)":
            row |= {"signals": signals, "figures": fig}
    return row


def accumulated_time(start: float, step: float, steps: int) -> float:
    """``start + step + step + ...`` (``steps`` times) in floating point, as OMSimulator's
    master accumulates its time.

    Examples
    --------
    >>> accumulated_time(0.0, 5e-5, 60000)
    2.9999999999996776
    """
    t = start
    for _ in range(steps):
        t += step
    return t


def check(binary: Path, spec: SystemSpec, out: Path, stop_time: float | None,
          timeout: float) -> dict[str, float]:
    """Export ``spec`` (native, no Python), run it in OMSimulator and in the harness, print the
    report; the summary row."""
    folder = out / spec.name
    folder.mkdir(parents=True, exist_ok=True)
    ssp = export_ssp(spec, folder / f"{spec.name}.ssp", out / "blocks", allow_python=False)
    stop = stop_time if stop_time is not None else spec.stop_time
    print(f"\n## {spec.name}: {ssp}, {round((stop - spec.start_time) / spec.step)} steps of "
          f"{spec.step!r} s", flush=True)
    steps = round((stop - spec.start_time) / spec.step)
    status, result, log = run_omsimulator(
        binary, ssp, folder, accumulated_time(spec.start_time, spec.step, steps), timeout,
        spec.tolerance)
    system = resolve_system(spec)
    harness = run_system(system, stop_time=stop, progress=False)
    derived = {name for d in system.derived for name in d.names}
    runs = {
        "harness (system)": REFERENCES.get(spec.name, lambda r: r)(harness),
        "harness (exported system)": run_system(
            resolve_system(exported_system(spec, out / "blocks")), stop_time=stop,
            progress=False),
    }
    read = read_oms_result(result, [n for n in harness.names if n not in derived])
    oms, last_step = read if read is not None else (None, float("nan"))
    oms = oms if oms is None else with_derived(oms, system)
    row = print_report(status, log, oms, last_step, runs, spec)
    if spec.name in PLANT_TABLES:
        table = float("nan") if oms is None else plant_table_difference(oms, harness, spec)
        print(f"\nharness plant's table: OMSimulator's figures within {table:.2e} of the "
              "harness run's (relative to the figure)")
        row["figures"] = max(row["figures"], table)
    return row | {"steps": len(runs["harness (system)"].time) - 1}


def print_summary(rows: dict[str, dict[str, float]]) -> bool:
    """One row per system; whether every system passed."""
    print("\n| system | steps | OMSimulator exit, errors logged | instants | its last step (s) | "
          f"signals | figures | within {TOLERANCE:g} |\n|---|---|---|---|---|---|---|---|")
    passed = True
    for name, r in rows.items():
        ok = (r["status"] == 0 and r["errors"] == 0 and r["instants"] == r["steps"] + 1
              and r["signals"] <= TOLERANCE and r["figures"] <= TOLERANCE)
        passed &= ok
        print(f"| {name} | {r['steps']} | {r['status']}, {r['errors']} | {r['instants']} | "
              f"{r['last_step']:.3g} | {r['signals']:.1e} | {r['figures']:.1e} | "
              f"{'yes' if ok else 'NO'} |")
    return passed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--omsimulator", type=Path, help="a built OMSimulator 3.0 binary")
    source.add_argument("--oms-src", type=Path,
                        help="OMSimulator v3.0.0 sources with 3rdParty/ (built if needed)")
    parser.add_argument("--out", type=Path, required=True, help="directory for FMUs and runs")
    parser.add_argument("--scenario", action="append",
                        help="a bundled scenario (repeatable; default: every one)")
    parser.add_argument("--plant", type=Path, action="append", default=[],
                        help="a plant spec whose `harness plant` system is checked (repeatable)")
    parser.add_argument("--plant-spec", type=Path, action="append", default=[],
                        help="a [plant_model] spec whose `harness plant --native --export-ssp` "
                             "system is checked (repeatable)")
    parser.add_argument("--no-blocks", action="store_true", help="skip the system of blocks")
    parser.add_argument("--design", choices=("spec", "paper"), default="spec")
    parser.add_argument("--stop-time", type=float, help="default: each system's")
    parser.add_argument("--timeout", type=float, default=1800.0, help="OMSimulator's, s")
    args = parser.parse_args()
    binary = args.omsimulator if args.omsimulator else build_omsimulator(args.oms_src)
    if not binary.is_file():
        parser.error(f"--omsimulator {binary}: no such file (build it first, see the "
                     "docstring of this script)")
    args.out.mkdir(parents=True, exist_ok=True)
    every = sorted(path.stem for path in SCENARIO_DIR.glob("*.toml"))
    names = args.scenario or ([] if args.plant_spec else every)
    systems = scenario_systems(args.out, names, args.design) if names else []
    systems += [plant_system(args.out, path) for path in args.plant]
    systems += [plant_model_system(args.out, path) for path in args.plant_spec]
    if not args.no_blocks:
        systems.append(blocks_system(args.out))
    rows = {spec.name: check(binary, spec, args.out, args.stop_time, args.timeout)
            for spec in systems}
    sys.exit(0 if print_summary(rows) else 1)


if __name__ == "__main__":
    main()
