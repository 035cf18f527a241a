"""A non-editable install works on its own: the package data (examples, C sources) is
installed and the main job runs from another directory, importing nothing from the clone."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow


def run(args: list[str], cwd: Path, env: dict[str, str], timeout: float = 600
        ) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    """``pip install --no-deps --target`` of a copy of the clone (pip builds in the source
    folder); an environment that imports the installed package."""
    target, source = tmp_path_factory.mktemp("site"), tmp_path_factory.mktemp("clone") / "src"
    shutil.copytree(REPO, source, symlinks=True, ignore=shutil.ignore_patterns(
        ".git", "build", "results", "*.egg-info", "__pycache__", ".*_cache"))
    done = run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target",
                str(target), str(source)], cwd=target, env=dict(os.environ))
    assert done.returncode == 0, done.stderr
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    env["PYTHONPATH"] = str(target)
    return target, env


def test_modules_and_package_data_come_from_the_install(installed, tmp_path):
    target, env = installed
    done = run([sys.executable, "-c",
                "import fhobs, harness, fhobs.paper as p; print(fhobs.__file__); "
                "print(harness.__file__); print(p.PENDULUM_SPEC.is_file(), "
                "len(list(p.EXAMPLES.glob('zoo/*.toml'))))"], cwd=tmp_path, env=env)
    sources = [target / name for name in ("fhobs/core/kernel.c", "harness/step_loop.c",
                                          "fhobs/fmu/status_wrapper.c", "fhobs/native/noise.c")]
    assert all(path.is_file() for path in sources), [p for p in sources if not p.is_file()]
    assert done.returncode == 0, done.stderr
    fhobs_file, harness_file, data = done.stdout.splitlines()
    assert Path(fhobs_file).is_relative_to(target) and Path(harness_file).is_relative_to(target)
    assert data == f"True {len(list((REPO / 'examples' / 'zoo').glob('*.toml')))}"


def test_main_job_runs_from_another_directory(installed, tmp_path):
    _, env = installed
    """The paper's scenarios to t = 1.6 s (past the nominal figure's t = 1.5 s), our design."""
    done = run([sys.executable, "-m", "harness", "paper", "--out", "results", "--design",
                "spec", "--stop-time", "1.6", "--no-plots"], cwd=tmp_path, env=env)
    assert done.returncode == 0, done.stdout + done.stderr
    results = tmp_path / "results" / "ours"
    assert (results / "fmus" / "observer.fmu").is_file()
    for scenario in ("pendulum_nominal", "pendulum_perturbed", "pendulum_noisy"):
        assert (results / scenario / "results.csv").is_file()
    nominal = json.loads((results / "pendulum_nominal" / "summary.json").read_text())
    assert nominal["steps"] == 32000
    assert nominal["homogeneous"]["error_at_1_5"] < 1e-9
    assert nominal["linear"]["error_at_1_5"] > 1e-4
