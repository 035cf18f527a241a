"""Results never half-written: a SIGINT or SIGTERM at any moment of ``python -m harness run``
(start-up, instantiation, stepping, writing each file) leaves one of three outcomes, and the
one line on stderr says which: nothing, the complete results, or the rows so far with a
summary.json marked incomplete; never a truncated file, never a temporary file. The sweep's
two tables are written whole and together.

The child process stops at a named moment, says so on stdout and waits for a line on stdin:
the test sends the signal while the child is at that moment, then lets it go on.
"""

from __future__ import annotations

import csv
import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from harness.writing import NOTHING_WRITTEN, atomic_path

ROOT = Path(__file__).resolve().parents[2]
STEP = 0.01
SYSTEM = f"""
name = "blocks"
[run]
step = {STEP}
stop_time = 1000.0
record = ["wave.y", "g.y"]
[fmus.wave]
block = "sine"
outputs = 1
start = {{ amplitude = [1.0], omega = [1.0] }}
[fmus.g]
block = "gain"
outputs = 1
inputs = 1
start = {{ K = [[0.5]] }}
[[connections]]
from = "wave.y"
to = "g.u"
[evaluation]
at = [0.5]
windows = [[0.2, 0.8]]
[evaluation.errors]
half = ["wave.y", "g.y"]
"""
"""Two harness blocks: 100,000 steps in a second or so, every row known: ``sin(t)`` and half
of the previous step's (the master's Jacobi exchange)."""
CHILD = """
import os, sys
from pathlib import Path
from harness import cli, master

moments = sys.argv[1].split(",")

def pause(moment):
    if moments and moments[0] == moment:
        moments.pop(0)
        print(moment, flush=True)
        sys.stdin.readline()

def before(name, function):
    def paused(*args, **kwargs):
        pause(name)
        return function(*args, **kwargs)
    return paused

def after(name, function):
    def paused(*args, **kwargs):
        out = function(*args, **kwargs)
        pause(name)
        return out
    return paused

replace = os.replace
def paused_replace(src, dst):
    pause(Path(dst).name)  # the file is written in full under its temporary name
    return replace(src, dst)

os.replace = paused_replace
cli.load_scenario = before("start-up", cli.load_scenario)
master.Master._bind = after("instantiated", master.Master._bind)
master.Master._steps = after("stepping", master.Master._steps)
sys.exit(cli.main(sys.argv[2:]))
"""
"""``python -m harness`` that stops at each moment of its first argument (in order): the
start-up (loading the scenario), the FMUs instantiated, the first chunk of steps done, and
each file named (written under its temporary name, not yet renamed)."""
MOMENT_TIMEOUT = 120.0
"""Seconds allowed to reach a moment (start-up, building the blocks once)."""


@pytest.fixture(scope="module")
def scenario(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("system") / "system.toml"
    path.write_text(SYSTEM)
    return path


@pytest.fixture(scope="module")
def block_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("blocks")


def wait_for(child: subprocess.Popen, moment: str) -> None:
    """Read the child's stdout until it prints ``moment``."""
    deadline = time.monotonic() + MOMENT_TIMEOUT
    while (remaining := deadline - time.monotonic()) > 0:
        if select.select([child.stdout], [], [], remaining)[0]:
            line = child.stdout.readline()
            assert line, (f"the run ended before {moment}", child.communicate())
            if line.strip() == moment:
                return
    pytest.fail(f"no {moment} within {MOMENT_TIMEOUT} s")


def go_on(child: subprocess.Popen) -> None:
    """Let the child go on (it may have ended on the signal already)."""
    try:
        child.stdin.write("go\n")
        child.stdin.flush()
    except BrokenPipeError:
        pass


def signalled_run(script: str, moments: list[str], signals: list[int],
                  arguments: list[str]) -> subprocess.CompletedProcess:
    """Run ``script`` stopping at ``moments``; send the matching signal at each."""
    command = [sys.executable, "-c", script, ",".join(moments), *arguments]
    child = subprocess.Popen(command, cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        for moment, signum in zip(moments, signals, strict=True):
            wait_for(child, moment)
            child.send_signal(signum)
            go_on(child)
        stdout, stderr = child.communicate(timeout=120)
    except BaseException:
        child.kill()
        child.communicate()
        raise
    return subprocess.CompletedProcess(command, child.returncode, stdout, stderr)


def run_with_signals(scenario: Path, block_cache: Path, out: Path, moments: list[str],
                     signals: list[int], stop_time: float,
                     plots: bool = False) -> subprocess.CompletedProcess:
    arguments = ["run", str(scenario), "--out", str(out), "--block-cache", str(block_cache),
                 "--stop-time", repr(stop_time), *([] if plots else ["--no-plots"])]
    return signalled_run(CHILD, moments, signals, arguments)


def read_results(out: Path) -> tuple[np.ndarray, dict]:
    """results.csv (every row parsed, each of the header's width) and summary.json."""
    with (out / "results.csv").open() as f:
        rows = list(csv.reader(f))
    assert [name.strip('"') for name in rows[0]] == ["time", "wave.y[1]", "g.y[1]"]
    assert all(len(row) == 3 for row in rows[1:])
    table = np.array(rows[1:], dtype=float)
    return table, json.loads((out / "summary.json").read_text())


def outcome(done: subprocess.CompletedProcess, out: Path, signum: int) -> str:
    """Which of the three outcomes ``out`` holds ("nothing", "complete", "incomplete"),
    checked against the files' content and the one line on stderr."""
    assert done.returncode == 128 + signum, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"interrupted by {signal.Signals(signum).name}: ")
    assert "Traceback" not in done.stderr
    leftovers = [p.name for p in out.iterdir() if p.name.startswith(".")] if out.exists() else []
    assert leftovers == [], leftovers
    if not (out / "results.csv").exists() and not (out / "summary.json").exists():
        assert lines[0].endswith(NOTHING_WRITTEN)
        return "nothing"
    table, summary = read_results(out)
    time_column, wave, gain = table.T
    steps = round(summary["stop_time"] / STEP)
    np.testing.assert_allclose(time_column, STEP * np.arange(steps + 1), rtol=0, atol=1e-9)
    np.testing.assert_allclose(wave, np.sin(time_column), rtol=0, atol=1e-12)
    held = np.concatenate(([0.0], wave[:-1]))  # Jacobi: the gain sees the previous step's y
    np.testing.assert_allclose(gain, 0.5 * held, rtol=0, atol=1e-12)
    assert summary["steps"] == steps
    if summary.get("incomplete"):
        assert summary["reason"] == "interrupted"
        assert lines[0].endswith(f"the rows up to t = {summary['stop_time']!r} were written to "
                                 f"{out} (summary.json marked incomplete)")
        return "incomplete"
    assert lines[0].endswith(f"the complete results were written to {out}")
    return "complete"


SIGNALS = {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM}


@pytest.mark.parametrize("name", ["SIGINT", pytest.param("SIGTERM", marks=pytest.mark.slow)])
@pytest.mark.parametrize(
    ("moments", "stop_time", "expected"),
    [(["start-up"], 1000.0, "nothing"),
     pytest.param(["instantiated"], 1000.0, "incomplete", marks=pytest.mark.slow),
     (["stepping"], 1000.0, "incomplete"),
     pytest.param(["stepping", "results.csv"], 1000.0, "incomplete", marks=pytest.mark.slow),
     pytest.param(["stepping", "summary.json"], 1000.0, "incomplete", marks=pytest.mark.slow),
     (["results.csv"], 2.0, "complete"),
     (["summary.json"], 2.0, "complete")],
    ids=["start-up", "instantiated", "stepping", "stepping-then-writing-results",
         "stepping-then-writing-summary", "writing-results", "writing-summary"])
def test_signal_leaves_one_of_three_outcomes(scenario, block_cache, tmp_path, name, moments,
                                             stop_time, expected):
    signum = SIGNALS[name]
    out = tmp_path / "out"
    done = run_with_signals(scenario, block_cache, out, moments, [signum] * len(moments),
                            stop_time)
    assert outcome(done, out, signum) == expected
    if expected == "complete":
        assert json.loads((out / "summary.json").read_text())["stop_time"] == stop_time


def test_signal_while_plotting_completes_the_results(scenario, block_cache, tmp_path):
    """A signal while the first plot is drawn: the plots and summary.json are still written,
    whole, and the summary names every plot."""
    out = tmp_path / "out"
    done = run_with_signals(scenario, block_cache, out, ["errors.png"], [signal.SIGTERM], 2.0,
                            plots=True)
    assert outcome(done, out, signal.SIGTERM) == "complete"
    plots = json.loads((out / "summary.json").read_text())["plots"]
    assert plots and all(Path(p).read_bytes()[1:4] == b"PNG" for p in plots)


def test_interrupted_rerun_leaves_the_previous_results(scenario, block_cache, tmp_path):
    """A second run into the same folder, stopped at start-up, changes none of the first
    run's files."""
    out = tmp_path / "out"
    first = run_with_signals(scenario, block_cache, out, [], [], 2.0)
    assert first.returncode == 0, first.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    done = run_with_signals(scenario, block_cache, out, ["start-up"], [signal.SIGINT], 1000.0)
    assert done.returncode == 130 and done.stderr.strip().endswith(NOTHING_WRITTEN)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text('{"old": true}\n')
    with pytest.raises(ZeroDivisionError), atomic_path(path) as tmp:
        tmp.write_text('{"new"')
        _ = 1 / 0
    assert path.read_text() == '{"old": true}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]


SWEEP_CHILD = """
import sys
from pathlib import Path
from harness.sweep import write_table
from harness.writing import Interrupted

out, points = Path(sys.argv[2]), int(sys.argv[3])
rows = [{"point": i, "rho": 1.0 + i, "x0": [i, 0], "status": "ok"} for i in range(points)]
if sys.argv[1]:
    import os
    replace = os.replace
    def paused_replace(src, dst):
        if Path(dst).name == sys.argv[1]:
            print(sys.argv[1], flush=True)
            sys.stdin.readline()
        return replace(src, dst)
    os.replace = paused_replace
try:
    write_table(rows, out)
except Interrupted as err:
    print(err.written, file=sys.stderr)
    sys.exit(128 + err.signum)
"""
"""write_table of ``points`` rows into ``out``, stopping (when named) at the rename of one of
its two files."""


def read_table(out: Path) -> tuple[list[int], list[int]]:
    """The points of sweep.parquet and of sweep.csv (each read in full)."""
    import pyarrow.csv as pa_csv
    import pyarrow.parquet as pq

    return (pq.read_table(out / "sweep.parquet").column("point").to_pylist(),
            pa_csv.read_csv(out / "sweep.csv").column("point").to_pylist())


@pytest.mark.slow
@pytest.mark.parametrize("moment", ["sweep.parquet", "sweep.csv"])
def test_sweep_table_is_written_whole_and_together(tmp_path, moment):
    pytest.importorskip("pyarrow")
    out = tmp_path / "sweep"
    out.mkdir()
    first = signalled_run(SWEEP_CHILD, [], [], [str(out), "3"])
    assert first.returncode == 0, first.stderr
    assert read_table(out) == ([0, 1, 2], [0, 1, 2])
    done = signalled_run(SWEEP_CHILD, [moment], [signal.SIGINT], [str(out), "400"])
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip() == f"the sweep table was written to {out} (points/ holds each " \
                                  "point's row)"
    assert read_table(out) == (list(range(400)), list(range(400)))
    assert sorted(p.name for p in out.iterdir()) == ["sweep.csv", "sweep.parquet"]
