"""The C test host (``tests/native_host.c``, FMI 2.0 and FMI 3.0) for the native FMU tests:
compiled once per session, run with a CSV of inputs, its output CSV read back."""

from __future__ import annotations

import csv
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fhobs.core.kernel import compile_source

HOST_SOURCE = Path(__file__).resolve().with_name("native_host.c")
FMI_HEADERS = Path(fmpy.__file__).resolve().parent / "c-code"
EXIT_LIBPYTHON = 3
"""Exit code of the host when libpython is mapped into its process."""


@pytest.fixture(scope="session")
def native_host(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The compiled host (the tests that use it need a C compiler)."""
    if shutil.which("cc") is None:
        pytest.skip("the native host needs a C compiler")
    target = tmp_path_factory.mktemp("host") / "native_host"
    compile_source(HOST_SOURCE, target, "cc", ("-O2", f"-I{FMI_HEADERS}"), ("-ldl",))
    return target


def write_inputs(path: Path, names: list[str], times: np.ndarray, values: np.ndarray) -> None:
    """The host's input CSV: a time column, then one column per input (exact decimals)."""
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["time", *names])
        for t, row in zip(times, values, strict=True):
            writer.writerow([repr(float(t)), *(repr(float(v)) for v in row)])


def run_host(host: Path, fmu_dir: Path, inputs: Path, outputs: Path, step: float,
             parameters: dict[str, float] | None = None, env: dict[str, str] | None = None,
             wrapper: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    """Run the host (by default with an empty environment; under ``wrapper``, a command such as
    valgrind with its options, when given) and return the finished process."""
    args = [*wrapper, str(host), str(fmu_dir), str(inputs), str(outputs), repr(step)]
    args += [f"{name}={value!r}" for name, value in (parameters or {}).items()]
    return subprocess.run(args, env={} if env is None else env, capture_output=True,
                          text=True, timeout=300)


def read_outputs(path: Path) -> tuple[list[str], np.ndarray]:
    """The host's output CSV: (column names without time, rows of time then outputs)."""
    with path.open() as f:
        rows = list(csv.reader(f))
    return rows[0][1:], np.array([[float(v) for v in row] for row in rows[1:]])


def libpython_environment() -> dict[str, str]:
    """An environment that maps this interpreter's libpython into a native process."""
    library = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("LDLIBRARY")
    return {"LD_PRELOAD": str(library), "PYTHONHOME": sys.prefix}
