"""Mistakes on the harness command line that used to end in the internals' words, or in a
silent success: each is one paragraph naming the mistake, exit 2, no traceback. Evaluation
entries beyond the run are refused in the file and noted when --stop-time cuts the run."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from harness.cli import main as harness_main

ROOT = Path(__file__).resolve().parents[2]
SYSTEM = """
name = "blocks"
[run]
step = 0.01
stop_time = {stop_time}
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
at = {at}
windows = {windows}
[evaluation.errors]
half = ["wave.y", "g.y"]
"""


@pytest.fixture(scope="module")
def block_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("blocks")


def system(tmp_path: Path, stop_time: str = "1.0", at: str = "[0.5]",
           windows: str = "[[0.2, 0.8]]") -> Path:
    path = tmp_path / "system.toml"
    path.write_text(SYSTEM.format(stop_time=stop_time, at=at, windows=windows))
    return path


def run(capsys, block_cache, scenario: Path | str, out: Path,
        *options: str) -> tuple[int, str, str]:
    code = harness_main(["run", str(scenario), "--out", str(out), "--no-plots",
                         "--block-cache", str(block_cache), *options])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_paragraph(err: str) -> None:
    assert err.startswith("error: ") and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("at", "windows", "named"),
    [("[10.0]", "[[0.01, 0.04]]", "at = 10 lies outside the run [0, 0.05]"),
     ("[0.02]", "[[1.0, 3.0]]", "window [1, 3] lies outside the run [0, 0.05]"),
     ("[-1.0]", "[]", "at = -1 lies outside")],
)
def test_evaluation_beyond_the_files_run_is_refused(tmp_path, capsys, block_cache, at, windows,
                                                    named):
    path = system(tmp_path, stop_time="0.05", at=at, windows=windows)
    code, _, err = run(capsys, block_cache, path, tmp_path / "out")
    assert code == 2
    one_paragraph(err)
    assert named in err and "[evaluation]" in err
    assert not (tmp_path / "out" / "summary.json").exists()


def test_stop_time_option_before_the_evaluation_is_noted(tmp_path, capsys, block_cache):
    """--stop-time shortening the run (as the README's and the tests' quick runs of the bundled
    scenarios do) clips: the run goes ahead and a note names what has no figures."""
    code, out, err = run(capsys, block_cache, system(tmp_path), tmp_path / "out",
                         "--stop-time", "0.3")
    assert code == 0, err
    assert "note: --stop-time 0.3 ends blocks before its [evaluation] at = 0.5, window " \
           "[0.2, 0.8]: no figures for them" in out
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["half"] == {}


def test_stop_time_option_within_the_evaluation_prints_no_note(tmp_path, capsys, block_cache):
    code, out, err = run(capsys, block_cache, system(tmp_path), tmp_path / "out",
                         "--stop-time", "0.9")
    assert code == 0, err
    assert "note:" not in out
    figures = json.loads((tmp_path / "out" / "summary.json").read_text())["half"]
    assert set(figures) == {"error_at_0_5", "max_error_0_2_0_8", "rms_error_0_2_0_8"}


@pytest.mark.parametrize(
    ("case", "named"),
    [("binary file", "is not a text file: byte"),
     ("folder", "is a folder, not a file"),
     ("stop_time = 1e300", "is 1e+302 steps, more than a run can record"),
     ("--stop-time 1e300", "is 1e+302 steps, more than a run can record"),
     ("--out /proc/x", "cannot create the output folder --out /proc/x")],
)
def test_message_names_the_mistake(tmp_path, capsys, block_cache, case, named):
    scenario, out, options = system(tmp_path), tmp_path / "out", []
    if case == "binary file":
        scenario.write_bytes(bytes(range(256)) * 4)
    elif case == "folder":
        scenario = tmp_path / "folder"
        scenario.mkdir()
    elif case == "stop_time = 1e300":
        scenario = system(tmp_path, stop_time="1e300")
    elif case == "--stop-time 1e300":
        options = ["--stop-time", "1e300"]
    elif Path("/proc/self").exists():
        out = Path("/proc/x")
    else:
        pytest.skip("no /proc")
    code, _, err = run(capsys, block_cache, scenario, out, *options)
    assert code == 2
    one_paragraph(err)
    assert named in err
    for internal in ("UnicodeDecodeError", "Maximum allowed dimension", "does not exist",
                     "Errno"):
        assert internal not in err


def test_binary_scenario_in_a_subprocess_prints_no_traceback(tmp_path):
    path = tmp_path / "scenario.toml"
    path.write_bytes(b"\x7fELF\x02\x01\x01\x00" + bytes(range(128, 256)))
    done = subprocess.run([sys.executable, "-m", "harness", "run", str(path), "--out",
                           str(tmp_path / "out")], cwd=ROOT, capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "is not a text file" in done.stderr
