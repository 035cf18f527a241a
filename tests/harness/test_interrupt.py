"""A harness run stopped by SIGINT or SIGTERM keeps what it recorded: results.csv with the rows
up to the interruption, summary.json marked incomplete with the reason "interrupted", one line
on stderr and the shell's exit code (130, 143); with pythonfmu FMUs and with native ones."""

from __future__ import annotations

import csv
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from fhobs.paper import H_PAPER

from harness.cli import build_paper_fmus

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(sys.platform != "linux" or shutil.which("cc") is None,
                       reason="native FMUs and signals as on linux64 (built with cc)"),
]

ROOT = Path(__file__).resolve().parents[2]
STOP_TIME = 200.0
"""Far longer than any machine takes to reach the signal (4 million steps)."""
EVERY = 200
"""results.csv holds every 200th row (and the last): a native run makes a million rows."""
STEPPING = "stepping"
"""What the child prints on stdout once its first chunk of steps is recorded."""
CHILD = f"""
import sys
from harness import master
from harness.cli import main

steps = master.Master._steps

def announced_steps(self, *args, **kwargs):
    steps(self, *args, **kwargs)
    if not getattr(self, "announced", False):
        self.announced = True
        print({STEPPING!r}, flush=True)

master.Master._steps = announced_steps
sys.exit(main(sys.argv[1:]))
"""
"""``python -m harness`` that says when it is stepping: the signal then arrives during the
run whatever the machine's load, rather than after a guessed delay."""
MARKER_TIMEOUT = 300.0
"""Seconds allowed for building, instantiating and the first chunk of steps."""


@pytest.fixture(scope="module")
def fmu_dirs(tmp_path_factory) -> dict[str, Path]:
    """The pendulum FMUs of the paper's gains: pythonfmu ones and native ones."""
    out = build_paper_fmus(tmp_path_factory.mktemp("fmus"), design="paper", native=True)
    return {"pythonfmu": out.parent, "native": out}


def wait_for_marker(child: subprocess.Popen) -> None:
    """Read the child's stdout until it prints ``STEPPING`` (fails if it ends or takes longer
    than ``MARKER_TIMEOUT``)."""
    deadline = time.monotonic() + MARKER_TIMEOUT
    while (remaining := deadline - time.monotonic()) > 0:
        if select.select([child.stdout], [], [], remaining)[0]:
            line = child.stdout.readline()
            assert line, ("the run ended before stepping", child.communicate())
            if line.strip() == STEPPING:
                return
    pytest.fail(f"no step within {MARKER_TIMEOUT} s")


def interrupted_run(fmu_dir: Path, out: Path, signum: int) -> subprocess.CompletedProcess:
    """``python -m harness run pendulum_nominal`` sent ``signum`` once it is stepping."""
    command = [sys.executable, "-c", CHILD, "run", "pendulum_nominal", "--fmu-dir",
               str(fmu_dir), "--out", str(out), "--no-plots", "--stop-time", str(STOP_TIME),
               "--csv-every", str(EVERY)]
    child = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        wait_for_marker(child)
    except BaseException:
        child.kill()
        child.communicate()
        raise
    assert child.poll() is None, child.communicate()
    child.send_signal(signum)
    stdout, stderr = child.communicate(timeout=120)
    return subprocess.CompletedProcess(command, child.returncode, stdout, stderr)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("build", ["pythonfmu", "native"])
def test_interrupted_run_keeps_its_rows(fmu_dirs, tmp_path, build, signum):
    out = tmp_path / "out"
    done = interrupted_run(fmu_dirs[build], out, signum)
    assert done.returncode == 128 + signum, done.stderr
    lines = done.stderr.strip().splitlines()
    name = signal.Signals(signum).name
    assert len(lines) == 1 and lines[0].startswith(f"interrupted by {name}"), done.stderr
    assert "Traceback" not in done.stderr and "plant" not in done.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["incomplete"] is True and summary["reason"] == "interrupted"
    with (out / "results.csv").open() as f:
        rows = list(csv.reader(f))
    times = np.array([float(row[0]) for row in rows[1:]])
    assert rows[0][0].strip('"') == "time" and len(times) > 2
    every = EVERY * H_PAPER * np.arange(len(times) - 1)
    np.testing.assert_allclose(times[:-1], every, rtol=0, atol=1e-9)
    assert times[-1] == pytest.approx(summary["stop_time"], abs=1e-12)
    assert summary["steps"] == round(summary["stop_time"] / H_PAPER) < STOP_TIME / H_PAPER
    assert str(out) in lines[0] and f"t = {summary['stop_time']!r}" in lines[0]
