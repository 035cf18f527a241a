"""fmpy and pythonfmu are pinned exactly in pyproject.toml because the code relies on their
internals: a different installed version fails here, naming what to re-check."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import fmpy
import pytest
import pythonfmu

PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"
RELIES_ON = {
    "fmpy": (fmpy, "harness/master.py drives FMU2Slave's ctypes library and component directly "
                   "(fmu.dll, fmu.component) and fhobs.native.build copies fmpy's FMI headers "
                   "(fmpy/c-code)"),
    "pythonfmu": (pythonfmu, "fhobs/build.py's slave script takes back the reference pythonfmu "
                             "releases at every instantiation and renames its linux64 binary "
                             "for the status wrapper (fmu/status_wrapper.c), which calls the "
                             "binary's fmi2 functions and reads the slave's status variable"),
}


def pins() -> dict[str, str]:
    dependencies = tomllib.loads(PYPROJECT.read_text())["project"]["dependencies"]
    return dict(re.fullmatch(r"([\w-]+)==([\w.]+)", d).groups() for d in dependencies
                if "==" in d)


def test_exactly_the_packages_relied_on_are_pinned():
    assert set(pins()) == set(RELIES_ON)


@pytest.mark.parametrize("name", sorted(RELIES_ON))
def test_installed_version_is_the_pinned_one(name):
    module, what = RELIES_ON[name]
    assert module.__version__ == pins()[name], (
        f"{name} {module.__version__} is installed, the code is written for {pins()[name]}: "
        f"{what}; re-check these before changing the pin in pyproject.toml")
