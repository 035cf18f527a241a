"""The optional dependencies: a runtime-only user needs none of them, and a part that needs one
says which extra installs it."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from fhobs.design.kalman import with_kalman
from fhobs.design.observer import paper_gains
from fhobs.design.spec import load_spec
from fhobs.extras import EXTRAS
from fhobs.paper import PENDULUM_SPEC

REPO = Path(__file__).resolve().parents[2]
BLOCK = ("import sys\n"
         "for name in {names!r}:\n"
         "    sys.modules[name] = None  # as if not installed\n")


def run_without(names: tuple[str, ...], code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BLOCK.format(names=names) + code],
                          capture_output=True, text=True, timeout=300, cwd=REPO)


def test_pyproject_extras_install_the_modules_the_code_asks_for():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    optional = project["optional-dependencies"]
    for extra, modules in EXTRAS.items():
        names = {re.split(r"[<>=\[]", req)[0] for req in optional[extra]} - {"fhobs"}
        assert names == set(modules), extra
        included = [req for req in optional[extra] if req.startswith("fhobs[")]
        assert all(set(req[6:-1].split(",")) < set(EXTRAS) for req in included), extra
        assert not names & {re.split(r"[<>=\[]", req)[0] for req in project["dependencies"]}
    assert optional["all"] == [f"fhobs[{','.join(EXTRAS)}]"]


@pytest.mark.parametrize(("module", "statement", "extra"), [
    ("cvxpy", "import fhobs.design.observer", "design"),
    ("matplotlib", "import harness.figures", "plots"),
    pytest.param("pyarrow", "from harness.sweep import load_sweep, run_sweep\n"
                 "run_sweep(load_sweep('pendulum_noisy_seeds'), __import__('pathlib').Path("
                 "'/nonexistent/out'))", "sweep", marks=pytest.mark.slow),
])
def test_a_missing_extra_is_named(module, statement, extra):
    done = run_without((module,), statement)
    assert done.returncode == 1
    assert f"pip install 'fhobs[{extra}]'" in done.stderr.splitlines()[-1], done.stderr


@pytest.mark.slow
def test_a_runtime_only_user_builds_and_runs_fmus_without_the_extras(tmp_path):
    """Without cvxpy, clarabel, matplotlib, distributed and pyarrow: FMUs from a design.json
    (the compiled kernel and the status wrapper included) and a harness run without plots."""
    with_kalman(paper_gains(), load_spec(PENDULUM_SPEC).noise).save_json(tmp_path / "design.json")
    code = (f"from pathlib import Path\n"
            f"from fhobs.build import build_fmus\n"
            f"from fhobs.core.gains import ObserverDesign\n"
            f"from harness.cli import main\n"
            f"out = Path({str(tmp_path)!r})\n"
            f"build_fmus(ObserverDesign.load_json(out / 'design.json'), out / 'fmus')\n"
            f"raise SystemExit(main(['run', 'pendulum_nominal', '--fmu-dir', str(out / 'fmus'),"
            f" '--out', str(out / 'run'), '--stop-time', '0.05', '--no-plots',"
            f" '--set', 'plant.noise_amplitude=0']))\n")
    done = run_without(tuple(m for modules in EXTRAS.values() for m in modules), code)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "run" / "results.csv").is_file()
