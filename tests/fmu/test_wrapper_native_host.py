"""The pythonfmu FMUs in a native host (tests/fmu/wrapper_host.c, a C program that neither
links nor loads Python): the status wrapper finds and loads the interpreter itself, refuses
cleanly where there is none, lets the host exit cleanly, and answers a NULL component with
fmi2Error.

Every run is a child process with an empty environment (``env -i``) unless a test gives one.
"""

from __future__ import annotations

import csv
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fhobs.build import PYTHON_RECORD, python_record
from fhobs.core.kernel import compile_source
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

HOST_SOURCE = Path(__file__).resolve().with_name("wrapper_host.c")
FMI_HEADERS = Path(fmpy.__file__).resolve().parent / "c-code"
FMI_ERROR = 3
NULL_INSTANCE = 2
"""Exit code of the host when fmi2Instantiate returned NULL."""
DT = 5e-5
RTOL = 1e-12
SUPPRESSIONS = """\
{
   ld.so reads past the end of a short rpath string (python -c 'import numpy' shows it too)
   Memcheck:Addr8
   fun:strncmp
   fun:is_dst
}
{
   CPython 3.11's own uninitialised values (int.from_bytes; python -c pass shows them too)
   Memcheck:Value8
   obj:*libpython3.11*
}
{
   CPython 3.11's own uninitialised values, in its conditional jumps
   Memcheck:Cond
   obj:*libpython3.11*
}
{
   CPython 3.11's own uninitialised values, in its extension modules (_json)
   Memcheck:Value8
   obj:*/python3.11/lib-dynload/*
}
"""
"""Valgrind reports that the interpreter and the loader give without any FMU; every invalid
read, write or free stays reported."""


@pytest.fixture(scope="module")
def host(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The compiled C host."""
    if shutil.which("cc") is None:
        pytest.skip("the C host needs a C compiler")
    target = tmp_path_factory.mktemp("wrapper_host") / "wrapper_host"
    compile_source(HOST_SOURCE, target, "cc", ("-O2", f"-I{FMI_HEADERS}"), ("-ldl",))
    return target


@pytest.fixture(scope="module")
def folders(tmp_path_factory: pytest.TempPathFactory, pendulum_fmus) -> dict[str, Path]:
    """The pendulum FMUs extracted (kind -> folder); skipped when they have no status wrapper
    (built without a C compiler)."""
    root = tmp_path_factory.mktemp("extracted")
    extracted = {}
    for kind, path in pendulum_fmus.items():
        extracted[kind] = root / kind
        with zipfile.ZipFile(path) as archive:
            archive.extractall(extracted[kind])
    if not list((extracted["observer"] / "binaries" / "linux64").glob("*_pythonfmu.so")):
        pytest.skip("the FMUs were built without the status wrapper")
    return extracted


def preloaded() -> dict[str, str]:
    """The environment that maps this interpreter's libpython into the host before the FMU is
    loaded (LD_PRELOAD, PYTHONHOME); skips the test when there is no shared libpython."""
    library = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("LDLIBRARY")
    if not library.is_file() or ".so" not in library.name:
        pytest.skip("this interpreter has no shared libpython to preload")
    return {"LD_PRELOAD": str(library), "PYTHONHOME": sys.base_prefix}


def run_host(host: Path, *args: str | Path, env: dict[str, str] | None = None,
             tool: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    """Run the host as a child process, by default with an empty environment."""
    return subprocess.run([*tool, str(host), *map(str, args)], env={} if env is None else env,
                          capture_output=True, text=True, timeout=600, check=False)


def signals(folder: Path, steps: int, seed: int) -> tuple[list[str], np.ndarray]:
    """The Real inputs of the extracted FMU in ``folder`` and a seeded random walk of them, one
    row per step boundary."""
    description = read_model_description(str(folder / "modelDescription.xml"))
    names = [v.name for v in description.modelVariables if v.causality == "input"]
    rng = np.random.default_rng(seed)
    values = 0.1 + np.cumsum(rng.normal(scale=0.01, size=(steps + 1, len(names))), axis=0)
    return names, values


def write_inputs(path: Path, names: list[str], values: np.ndarray) -> None:
    """The host's input CSV: time, then one column per input (exact decimals)."""
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["time", *names])
        for k, row in enumerate(values):
            writer.writerow([repr(k * DT), *(repr(float(v)) for v in row)])


def read_outputs(path: Path) -> tuple[list[str], np.ndarray]:
    with path.open() as f:
        rows = list(csv.reader(f))
    return rows[0][1:], np.array([[float(v) for v in row] for row in rows[1:]])


def fmpy_rows(folder: Path, names: list[str], values: np.ndarray, outputs: list[str]
              ) -> np.ndarray:
    """The host's calling sequence under fmpy, in this process: inputs of t_0, setup,
    initialisation, then (outputs, inputs of t_k, doStep(t_k, DT)) per step, outputs."""
    description = read_model_description(str(folder / "modelDescription.xml"))
    vr = {v.name: v.valueReference for v in description.modelVariables}
    inputs, refs = [vr[n] for n in names], [vr[n] for n in outputs]
    slave = FMU2Slave(guid=description.guid, unzipDirectory=str(folder),
                      modelIdentifier=description.coSimulation.modelIdentifier,
                      instanceName="reference")
    slave.instantiate()
    slave.setReal(inputs, values[0].tolist())
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    rows = [slave.getReal(refs)]
    for k, row in enumerate(values[:-1]):
        slave.setReal(inputs, row.tolist())
        slave.doStep(k * DT, DT)
        rows.append(slave.getReal(refs))
    slave.terminate()
    slave.freeInstance()
    return np.array(rows)


def run_kind(host: Path, folder: Path, kind: str, tmp_path: Path, steps: int = 3,
             env: dict[str, str] | None = None, tool: tuple[str, ...] = ()
             ) -> subprocess.CompletedProcess:
    names, values = signals(folder, steps, seed=1)
    write_inputs(tmp_path / f"{kind}_in.csv", names, values)
    return run_host(host, "run", folder, tmp_path / f"{kind}_in.csv", tmp_path / f"{kind}_out.csv",
                    repr(DT), env=env, tool=tool)


@pytest.mark.parametrize("kind", ["observer", "plant"])
def test_empty_environment_runs_the_fmu_as_fmpy_does(host, folders, kind, tmp_path):
    """No LD_PRELOAD, no PYTHONHOME, no PATH: the wrapper loads the Python recorded at build
    time; the outputs equal fmpy's (plant: with its seeded noise) to 1e-12 relative."""
    names, values = signals(folders[kind], 200, seed=10)
    write_inputs(tmp_path / "in.csv", names, values)
    done = run_host(host, "run", folders[kind], tmp_path / "in.csv", tmp_path / "out.csv",
                    repr(DT))
    assert done.returncode == 0, done.stderr
    assert "fhobs status wrapper: Python: " in done.stderr and "the build's Python" in done.stderr
    columns, rows = read_outputs(tmp_path / "out.csv")
    assert np.allclose(rows[:, 0], DT * np.arange(len(values)), rtol=0, atol=1e-15)
    expected = fmpy_rows(folders[kind], names, values, columns)
    scale = np.where(np.abs(expected).max(axis=0) > 0, np.abs(expected).max(axis=0), 1.0)
    assert np.all(np.abs(rows[:, 1:] - expected).max(axis=0) <= RTOL * scale)


def test_build_records_this_interpreter_in_each_fmu(pendulum_fmus, folders):
    """resources/fhobs_python.txt: this interpreter's shared library, prefix, executable and
    numpy's directory."""
    record = python_record()
    for path in pendulum_fmus.values():
        with zipfile.ZipFile(path) as archive:
            assert archive.read(PYTHON_RECORD).decode() == record
    facts = dict(line.split("=", 1) for line in record.splitlines() if "=" in line)
    assert facts["home"] == sys.base_prefix and facts["executable"] == sys.executable
    assert (Path(facts["site"]) / "numpy" / "__init__.py").is_file()
    assert facts["library"] == "" or Path(facts["library"]).is_file()


def test_python_on_path_is_used_when_the_record_points_nowhere(host, folders, tmp_path):
    """A record of another machine: the python3.11 on PATH (its prefix's libpython) runs it."""
    folder = broken_copy(folders["observer"], tmp_path)
    done = run_kind(host, folder, "observer", tmp_path,
                    env={"PATH": str(Path(sys.base_prefix) / "bin")})
    if "no libpython" in done.stderr:
        pytest.skip("this interpreter's prefix has no shared libpython")
    assert done.returncode == 0, done.stderr
    assert "on PATH" in done.stderr and "/nowhere" not in done.stderr


def broken_copy(folder: Path, tmp_path: Path) -> Path:
    """A copy of the extracted FMU whose build record points nowhere."""
    copy = tmp_path / "moved"
    shutil.copytree(folder, copy)
    (copy / PYTHON_RECORD).write_text(
        "version=3.11\nlibrary=/nowhere/lib/libpython3.11.so.1.0\nhome=/nowhere\n"
        "executable=/nowhere/bin/python3.11\nsite=/nowhere/lib/python3.11/site-packages\n")
    return copy


def test_no_usable_python_is_a_clean_refusal_naming_what_was_tried(host, folders, tmp_path):
    """The record points nowhere and PATH has no python: fmi2Instantiate returns NULL with a
    message naming what is missing and each place tried; the host exits normally."""
    folder = broken_copy(folders["observer"], tmp_path)
    (tmp_path / "empty").mkdir()
    done = run_kind(host, folder, "observer", tmp_path, env={"PATH": str(tmp_path / "empty")})
    if done.returncode == 0 and "standard place" in done.stderr:
        pytest.skip("a Python 3.11 with numpy is installed in a standard place")
    assert done.returncode == NULL_INSTANCE, done.stderr
    assert "fmi2Instantiate returned NULL" in done.stderr
    (message,) = [line for line in done.stderr.splitlines() if "no usable Python" in line]
    assert message.startswith(f"[host] status {FMI_ERROR} ")
    assert "no file /nowhere/lib/libpython3.11.so.1.0" in message
    assert "no python3.11 or python3 on PATH" in message
    assert "numpy" in message and "LD_PRELOAD" in message and "--native" in message


@pytest.mark.parametrize("preload", [False, True], ids=["loaded_by_wrapper", "ld_preload"])
def test_pythonhome_without_a_standard_library_is_refused_not_an_abort(host, folders, tmp_path,
                                                                      preload):
    """PYTHONHOME at a virtual environment (no lib/python3.11/encodings) would make Python abort
    the host in Py_Initialize; the wrapper refuses instead (also with libpython preloaded)."""
    venv = tmp_path / "venv"
    (venv / "lib" / "python3.11" / "site-packages").mkdir(parents=True)
    (venv / "pyvenv.cfg").write_text(f"home = {Path(sys.base_prefix) / 'bin'}\n")
    env = {**(preloaded() if preload else {}), "PYTHONHOME": str(venv)}
    done = run_kind(host, folders["observer"], "observer", tmp_path, env=env)
    assert done.returncode == NULL_INSTANCE, done.stderr
    assert f"PYTHONHOME={venv} has no lib/python3.11/encodings" in done.stderr


@pytest.mark.parametrize("preload", [False, True], ids=["loaded_by_wrapper", "ld_preload"])
@pytest.mark.parametrize("kind", ["observer", "plant", "kalman"])
def test_host_exits_cleanly_after_a_run(host, folders, kind, preload, tmp_path):
    """Instantiate, step, terminate, free, exit: a normal exit, twice per kind (pythonfmu's
    static destructor would otherwise free its interpreter state before its unload hook
    resets it, and the host dies with SIGABRT at exit)."""
    env = preloaded() if preload else None
    for _ in range(2):
        done = run_kind(host, folders[kind], kind, tmp_path, env=env)
        assert done.returncode == 0, (done.returncode, done.stderr[-2000:])


@pytest.mark.slow
@pytest.mark.parametrize("preload", [False, True], ids=["loaded_by_wrapper", "ld_preload"])
def test_repeated_runs_none_killed(host, folders, preload, tmp_path):
    """15 child runs (observer, plant and kalman in turn) with captured output: none killed
    (before the fix every such run of the observer was: 30 of 30)."""
    env = preloaded() if preload else None
    kinds = ["observer", "plant", "kalman"]
    codes = [run_kind(host, folders[kinds[i % 3]], kinds[i % 3], tmp_path, env=env).returncode
             for i in range(15)]
    assert codes == [0] * 15


@pytest.mark.slow
def test_valgrind_finds_no_memory_error(host, folders, tmp_path):
    """Under valgrind (PYTHONMALLOC=malloc) a run and the host's exit make no invalid read,
    write or free (the interpreter's and the loader's own reports suppressed)."""
    if shutil.which("valgrind") is None:
        pytest.skip("valgrind is not installed")
    suppressions = tmp_path / "python.supp"
    suppressions.write_text(SUPPRESSIONS)
    done = run_kind(host, folders["observer"], "observer", tmp_path,
                    env={"PYTHONMALLOC": "malloc"},
                    tool=(shutil.which("valgrind"), "--error-exitcode=9",
                          f"--suppressions={suppressions}"))
    assert done.returncode == 0, done.stderr[-4000:]
    assert "Invalid read" not in done.stderr and "Invalid free" not in done.stderr
    assert "ERROR SUMMARY: 0 errors" in done.stderr


NULL_FUNCTIONS = [
    "fmi2DoStep", "fmi2Terminate", "fmi2Reset", "fmi2EnterInitializationMode",
    "fmi2ExitInitializationMode", "fmi2SetupExperiment", "fmi2SetDebugLogging", "fmi2CancelStep",
    "fmi2GetReal", "fmi2SetReal", "fmi2GetInteger", "fmi2SetInteger", "fmi2GetBoolean",
    "fmi2SetBoolean", "fmi2GetString", "fmi2SetString", "fmi2GetFMUstate", "fmi2SetFMUstate",
    "fmi2FreeFMUstate", "fmi2SerializedFMUstateSize", "fmi2SerializeFMUstate",
    "fmi2DeSerializeFMUstate", "fmi2GetStatus", "fmi2GetRealStatus", "fmi2GetIntegerStatus",
    "fmi2GetBooleanStatus", "fmi2GetStringStatus", "fmi2GetDirectionalDerivative",
    "fmi2SetRealInputDerivatives", "fmi2GetRealOutputDerivatives",
]


@pytest.fixture(scope="module")
def null_calls(host, folders) -> subprocess.CompletedProcess:
    """One host process (its embedded interpreter started once, not once per function: 30
    starts took 18 s) calls each of NULL_FUNCTIONS in turn with a NULL component."""
    return run_host(host, "null", folders["observer"], *NULL_FUNCTIONS, env=preloaded())


@pytest.mark.parametrize("function", NULL_FUNCTIONS)
def test_null_component_is_an_error(null_calls, function):
    """With an instance made (pythonfmu's library loaded; libpython preloaded as any native
    host could), ``function`` given a NULL component returns fmi2Error (as do the calls before
    it, in the same process); the host goes on, frees its instance and exits normally."""
    lines = null_calls.stdout.splitlines()
    index = NULL_FUNCTIONS.index(function)
    assert len(lines) > index, f"{function} not reached: {null_calls.stderr[-2000:]}"
    assert lines[index] == f"STATUS {FMI_ERROR}", null_calls.stderr[-2000:]
    assert (null_calls.returncode, len(lines)) == (0, len(NULL_FUNCTIONS)), \
        null_calls.stderr[-2000:]


def test_free_instance_of_null_does_nothing(host, folders):
    done = run_host(host, "null", folders["observer"], "fmi2FreeInstance", env=preloaded())
    assert (done.returncode, done.stdout) == (0, "CALLED\n"), done.stderr[-2000:]


def broken_stdlib(tmp_path: Path, fault: str) -> Path:
    """A PYTHONHOME that passes for a prefix (lib/python3.11/encodings/__init__.py exists) but
    whose standard library is broken: ``"empty"`` (that file empty, no codecs) or ``"raises"``
    (that file raises). (An os.py that raises would not do: Python 3.11 starts with a frozen
    os module.)"""
    home = tmp_path / f"home_{fault}"
    (home / "lib" / "python3.11" / "encodings").mkdir(parents=True)
    text = "" if fault == "empty" else "raise ImportError('this standard library is broken')\n"
    (home / "lib" / "python3.11" / "encodings" / "__init__.py").write_text(text)
    return home


@pytest.mark.parametrize("fault", ["empty", "raises"])
@pytest.mark.parametrize("preload", [False, True], ids=["loaded_by_wrapper", "ld_preload"])
def test_pythonhome_with_a_broken_standard_library_is_refused_not_an_abort(
        host, folders, tmp_path, fault, preload):
    """PYTHONHOME at a prefix whose standard library is broken: the interpreter fails to start
    (Python would end the host, "Fatal Python error"); fmi2Instantiate returns NULL with a
    message naming PYTHONHOME and what failed, and the host exits normally."""
    home = broken_stdlib(tmp_path, fault)
    env = {**(preloaded() if preload else {}), "PYTHONHOME": str(home)}
    done = run_kind(host, folders["observer"], "observer", tmp_path, env=env)
    assert done.returncode == NULL_INSTANCE, (done.returncode, done.stderr[-2000:])
    assert "Fatal Python error" not in done.stderr
    (message,) = [line for line in done.stderr.splitlines() if "could not start" in line]
    assert message.startswith(f"[host] status {FMI_ERROR} ")
    assert f"PYTHONHOME={home}" in message
    assert "init_fs_encoding" in message and "encoding" in message.split("could not start")[1]
