"""The C test host itself: it refuses to run when libpython is in its process, and it drives
a Python-free FMU through the FMI call sequence (the native FMU tests rely on both)."""

from __future__ import annotations

import sysconfig
import zipfile
from pathlib import Path

import numpy as np
import pytest
from host_runner import EXIT_LIBPYTHON, libpython_environment, run_host, write_inputs


@pytest.fixture(scope="module")
def unzipped_observer(tmp_path_factory, pendulum_fmus) -> Path:
    target = tmp_path_factory.mktemp("observer")
    with zipfile.ZipFile(pendulum_fmus["observer"]) as z:
        z.extractall(target)
    return target


def test_host_detects_libpython_in_its_process(native_host, unzipped_observer, tmp_path):
    if not (Path(sysconfig.get_config_var("LIBDIR"))
            / sysconfig.get_config_var("LDLIBRARY")).exists():
        pytest.skip("this interpreter has no shared libpython to preload")
    inputs = tmp_path / "in.csv"
    write_inputs(inputs, ["y[1]", "y[2]", "u[1]"], np.array([0.0, 5e-5]), np.zeros((2, 3)))
    done = run_host(native_host, unzipped_observer, inputs, tmp_path / "out.csv", 5e-5,
                    env=libpython_environment())
    assert done.returncode == EXIT_LIBPYTHON, done.stderr
    assert "libpython is mapped" in done.stderr


def test_host_rejects_an_unknown_input_name(native_host, unzipped_observer, tmp_path):
    inputs = tmp_path / "in.csv"
    write_inputs(inputs, ["y[9]"], np.array([0.0, 5e-5]), np.zeros((2, 1)))
    done = run_host(native_host, unzipped_observer, inputs, tmp_path / "out.csv", 5e-5)
    assert done.returncode == 1
    assert "'y[9]' is not a Real input" in done.stderr
