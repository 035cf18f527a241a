"""The C test host itself: it refuses to run when libpython is in its process, and it drives
a Python-free FMU through the FMI call sequence (the native FMU tests rely on both); in FMI 3.0
mode it drives the FMI 3.0 build through whole arrays to the FMI 2.0 build's outputs with its
checks (NULL instance, call sequence, nValues, FMU states), and the whole run is clean under
valgrind's memcheck."""

from __future__ import annotations

import shutil
import sysconfig
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fhobs.native.build import build_native_fmus
from fmpy import read_model_description
from fmu_fixtures import NOISE_AMPLITUDE, NOISE_SEED, PENDULUM_X0, SHARED_KINDS, H
from host_runner import EXIT_LIBPYTHON, libpython_environment, read_outputs, run_host, write_inputs


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


# -- FMI 3.0 mode: the host drives the FMI 3.0 build through whole arrays ----------------------
FMI3_CHECKS = (
    "fmi3EnterInitializationMode(NULL) -> 3", "fmi3ExitInitializationMode(NULL) -> 3",
    "fmi3GetFloat64(NULL) -> 3", "fmi3SetFloat64(NULL) -> 3", "fmi3DoStep(NULL) -> 3",
    "fmi3GetFMUState(NULL) -> 3", "fmi3Terminate(NULL) -> 3", "fmi3Reset(NULL) -> 3",
    "fmi3FreeInstance(NULL) returned",
    "fmi3DoStep before the initialisation -> 3",
    "fmi3ExitInitializationMode before fmi3EnterInitializationMode -> 3",
    "fmi3EnterStepMode before the initialisation -> 3",
    "fmi3GetFloat64 with nValues one less than the variable's size -> 3",
    "fmi3GetFloat64 with nValues one more than the variable's size -> 3",
    "fmi3SerializedFMUStateSize -> 0",
    "fmi3DeserializeFMUState of bytes with a flipped bit -> 3",
    "the rows replayed from the FMU state in memory are the same, bit for bit",
    "the rows replayed from the deserialized FMU state are the same, bit for bit",
    "fmi3DoStep after fmi3Terminate -> 3")
"""The checks the host reports of an FMI 3.0 run ("check: ..." lines), in their order."""
ROWS = 41


@pytest.fixture(scope="module")
def unzipped(tmp_path_factory, native_fmus, kalman_design) -> dict[tuple[int, str], Path]:
    """The native FMUs of ``native_fmus``' design and options, FMI 2.0 and FMI 3.0, extracted:
    {(version, kind): folder}."""
    fmi3 = build_native_fmus(kalman_design, tmp_path_factory.mktemp("native3"),
                             kinds=SHARED_KINDS, x0=PENDULUM_X0, noise_amplitude=NOISE_AMPLITUDE,
                             noise_seed=NOISE_SEED, h=H, fmi_version=3)
    folders = {}
    for version, fmus in ((2, native_fmus), (3, fmi3)):
        for kind in SHARED_KINDS:
            folders[version, kind] = tmp_path_factory.mktemp(f"fmi{version}_{kind}")
            with zipfile.ZipFile(fmus[kind]) as z:
                z.extractall(folders[version, kind])
    return folders


def random_inputs(path: Path, folder: Path, seed: int) -> None:
    """The host's input CSV for the FMI 2.0 FMU in ``folder`` (the scalar signals' names, for
    both builds): its inputs a seeded random walk."""
    names = [v.name for v in read_model_description(str(folder)).modelVariables
             if v.causality == "input"]
    steps = np.random.default_rng(seed).normal(scale=0.01, size=(ROWS, len(names)))
    write_inputs(path, names, np.arange(ROWS) * H, np.cumsum(steps, axis=0))


def host_checks(stdout: str) -> list[str]:
    return [line.removeprefix("check: ") for line in stdout.splitlines()
            if line.startswith("check: ")]


@pytest.mark.parametrize("kind", SHARED_KINDS)
def test_the_fmi3_build_runs_in_the_host_as_the_fmi2_build(native_host, unzipped, kind,
                                                           tmp_path):
    """The FMI 3.0 FMU through whole arrays gives the FMI 2.0 build's outputs (the same names,
    row for row) and passes the host's checks: NULL instance, call sequence, nValues, FMU
    states in memory and serialized replaying bit for bit, a flipped bit refused."""
    inputs = tmp_path / "in.csv"
    random_inputs(inputs, unzipped[2, kind], seed=11)
    runs = {}
    for version in (2, 3):
        outputs = tmp_path / f"out{version}.csv"
        done = run_host(native_host, unzipped[version, kind], inputs, outputs, H)
        assert done.returncode == 0, done.stderr
        assert host_checks(done.stdout) == (list(FMI3_CHECKS) if version == 3 else [])
        runs[version] = read_outputs(outputs)
    assert runs[3][0] == runs[2][0] and runs[2][1].shape == (ROWS, len(runs[2][0]) + 1)
    scale = np.maximum(np.abs(runs[2][1]).max(axis=0), np.finfo(float).tiny)
    assert np.all(np.abs(runs[3][1] - runs[2][1]) <= 1e-12 * scale)


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("kind", ["observer", "plant"])
def test_the_host_runs_clean_under_valgrind(native_host, unzipped, version, kind, tmp_path):
    """memcheck finds no invalid access, no uninitialised value used and nothing lost in the
    whole run (FMI 3.0: with its checks, the states and the refused calls)."""
    valgrind = shutil.which("valgrind")
    if valgrind is None:
        pytest.skip("valgrind is not installed (apt-get install valgrind)")
    inputs = tmp_path / "in.csv"
    random_inputs(inputs, unzipped[2, kind], seed=5)
    done = run_host(native_host, unzipped[version, kind], inputs, tmp_path / "out.csv", H,
                    wrapper=(valgrind, "--error-exitcode=99", "--leak-check=full",
                             "--errors-for-leak-kinds=definite,indirect"))
    assert done.returncode == 0, done.stderr
    assert "ERROR SUMMARY: 0 errors" in done.stderr
    assert "in use at exit: 0 bytes" in done.stderr
    assert len(host_checks(done.stdout)) == (len(FMI3_CHECKS) if version == 3 else 0)
