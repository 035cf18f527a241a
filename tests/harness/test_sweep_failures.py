"""A sweep with failed points says so: exit status 1, one line per failure reason (how many
points, the first of them), and the engine's tracebacks in ``--out``'s engine.log, never on
the console."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from harness.sweep import STATUS_FAILED, SweepReport, format_report, load_sweep, read_rows

ROOT = Path(__file__).resolve().parents[2]
PLANT = """\
A = [[0, 1], [0, -1]]
B = [[0], [1]]
C = [[1, 0]]
[observer]
rho = 2.0
"""
SWEEP = """\
base = "plant.toml"
fmus = "pythonfmu"
stop_time = 0.1
[[grid]]
rho = [1e13]
seed = [0, 1]
[[grid]]
rho = [2e13]
"""
"""Three points whose design the worker refuses (rho beyond the design's range, found only
when designing: the sweep file itself is valid), two of them for the same reason."""


def test_failure_lines_group_the_rows_by_reason():
    """Each reason once, with its count and its first point, in the order first met."""
    reasons = ["A: x", "B: y", "A: x", "C: z", "B: y", "A: x"]
    rows = [{"point": 0, "status": "ok", "reason": ""}] + [
        {"point": i + 1, "status": STATUS_FAILED, "reason": r} for i, r in enumerate(reasons)]
    report = SweepReport(rows, len(rows), 0, len(reasons), [], 1.0)
    text = format_report(report, load_sweep("pendulum_noisy_seeds"), Path("out"))
    lines = [line for line in text.splitlines() if "failed (first: point" in line]
    counts = Counter(reasons)
    first = {r: 1 + reasons.index(r) for r in counts}
    assert len(lines) == len(counts)
    for line, reason in zip(lines, dict.fromkeys(reasons), strict=True):
        noun = "points" if counts[reason] > 1 else "point"
        assert line == f"  {counts[reason]} {noun} failed (first: point {first[reason]}): {reason}"
    assert "engine log" not in text


@pytest.mark.slow
def test_failed_points_exit_1_with_the_tracebacks_in_the_engine_log(tmp_path):
    """The sweep command on a local cluster: exit 1; stdout has one line per reason (2 points
    of rho = 1e13, 1 of rho = 2e13) and names the log; the console has no traceback and none
    of dask's messages; DIR/engine.log has dask's "Compute Failed" with the traceback of the
    design that failed; each failed row keeps its reason."""
    (tmp_path / "plant.toml").write_text(PLANT)
    (tmp_path / "sweep.toml").write_text(SWEEP)
    out = tmp_path / "out"
    job = subprocess.run(
        [sys.executable, "-m", "harness", "sweep", str(tmp_path / "sweep.toml"), "--out",
         str(out), "--workers", "1", "--no-progress", "--no-plots"],
        capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert job.returncode == 1, job.stderr
    assert job.stderr == ""
    console = job.stdout + job.stderr
    for word in ("Traceback", "Compute Failed", "distributed.", "File \""):
        assert word not in console
    lines = [line for line in job.stdout.splitlines() if "failed (first: point" in line]
    assert len(lines) == 2, job.stdout
    assert lines[0].startswith("  2 points failed (first: point 0): SpecError: ")
    assert "observer.rho = 10000000000000.0" in lines[0]
    assert lines[1].startswith("  1 point failed (first: point 2): SpecError: ")
    assert "observer.rho = 20000000000000.0" in lines[1]
    assert "3 points, 3 run now, 0 done before, 3 failed" in job.stdout
    log = out / "engine.log"
    assert f"engine log (tracebacks): {log}" in job.stdout
    text = log.read_text()
    assert text.count("Compute Failed") == 2
    assert "Traceback" in text and "build_bundle" in text and "check_design_limits" in text
    rows = read_rows(out / "points")
    assert sorted(json.dumps(r["status"]) for r in rows.values()) == ['"failed"'] * 3


def test_engine_log_docstring_examples():
    """The Examples sections of harness.engine_log run and give what they print (the routed
    loggers are given back their handlers)."""
    import doctest
    import logging

    import harness.engine_log

    before = list(logging.getLogger("distributed").handlers)
    result = doctest.testmod(harness.engine_log)
    assert result.attempted > 0 and result.failed == 0
    assert logging.getLogger("distributed").handlers == before


def test_a_sweep_file_that_is_a_fifo_is_refused_without_blocking(tmp_path):
    from harness.sweep import SweepError
    fifo = tmp_path / "sweep.toml"
    os.mkfifo(fifo)
    with pytest.raises(SweepError, match="not a regular file"):
        load_sweep(fifo)
