"""Portable C: every C file of the native FMUs (each a translation unit of its own), the status
wrapper, the harness's step loop and the native harness blocks compile warning-free with gcc and
clang at ``-std=c99 -Wall -Wextra -pedantic -Werror``; a native FMU linked from its ``sources/``
by either compiler (without ``-fvisibility=hidden``) exports only fmi2* and steps bit for bit as
the shipped binary; the constants the C shares with Python (``/* fhobs.X.Y */`` comments on
their ``#define``s) are Python's.
"""

from __future__ import annotations

import importlib
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import fhobs.native
import numpy as np
import pytest
from fhobs.core import kernel
from fhobs.core.plant import PLANT_SCHEMES
from fhobs.core.runtime import SCHEMES
from fhobs.fmu import call_rules
from fhobs.native.build import FMI_HEADERS, _fmi_headers
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
from fmu_fixtures import COMPARED_KINDS

import harness

needs_gcc = pytest.mark.skipif(sys.platform != "linux" or shutil.which("gcc") is None,
                               reason="native FMUs are built for linux64 with gcc")

KINDS = COMPARED_KINDS
COMPILERS = tuple(name for name in ("gcc", "clang") if shutil.which(name))
STRICT = ("-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror")
NATIVE = Path(fhobs.native.__file__).resolve().parent
REPO_C = (kernel.SOURCE, *sorted(NATIVE.glob("*.[ch]")),
          NATIVE.parent / "fmu" / "status_wrapper.c", Path(harness.__file__).parent / "step_loop.c",
          Path(harness.__file__).parent / "blocks" / "native_blocks.c")


def compile_c(compiler: str, args: list[str]) -> None:
    done = subprocess.run([compiler, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and not done.stderr, (compiler, args, done.stderr)


@pytest.fixture(scope="module")
def native_set(tmp_path_factory, native_fmus) -> dict[str, Path]:
    """The pendulum design's native FMUs (the shared build, plant noise on), unzipped:
    {kind: folder}."""
    root = tmp_path_factory.mktemp("portable")
    folders = {}
    for kind in KINDS:
        fmu = native_fmus[kind]
        folders[kind] = root / kind
        zipfile.ZipFile(fmu).extractall(folders[kind])
    return folders


@pytest.mark.slow
@needs_gcc
@pytest.mark.parametrize("compiler", COMPILERS)
@pytest.mark.parametrize("kind", KINDS)
def test_each_source_compiles_alone_warning_free(native_set, kind, compiler, tmp_path):
    sources = native_set[kind] / "sources"
    units = sorted(path.name for path in sources.glob("*.c"))
    listed = read_model_description(str(native_set[kind])).buildConfigurations[0]
    assert units == sorted(listed.sourceFileSets[0].sourceFiles)
    for unit in units:
        compile_c(compiler, [*STRICT, f"-I{sources}", "-c", str(sources / unit),
                             "-o", str(tmp_path / f"{unit}.o")])


def outputs(folder: Path, binary: Path | None, steps: int = 40) -> np.ndarray:
    """The outputs after each of ``steps`` doSteps of 1e-3 s with varying inputs, the FMU's
    binary replaced by ``binary`` when given."""
    description = read_model_description(str(folder))
    identifier = description.coSimulation.modelIdentifier
    if binary is not None:
        shutil.copy(binary, folder / "binaries" / "linux64" / f"{identifier}.so")
    fmu = FMU2Slave(guid=description.guid, unzipDirectory=str(folder),
                    modelIdentifier=identifier, instanceName="portable")
    variables = description.modelVariables
    inputs = [v.valueReference for v in variables if v.causality == "input"]
    outs = [v.valueReference for v in variables
            if v.causality == "output" and v.type == "Real"]
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    rows = []
    for step in range(steps):
        fmu.setReal(inputs, [0.1 * np.sin(40.0 * step * 1e-3 + i) for i in range(len(inputs))])
        fmu.doStep(step * 1e-3, 1e-3)
        rows.append(fmu.getReal(outs))
    fmu.terminate()
    fmu.freeInstance()
    return np.array(rows)


@pytest.mark.slow
@needs_gcc
@pytest.mark.parametrize("compiler", COMPILERS)
@pytest.mark.parametrize("kind", KINDS)
def test_sources_link_into_a_binary_with_the_shipped_results(native_set, kind, compiler,
                                                             tmp_path):
    folder = tmp_path / "fmu"
    shutil.copytree(native_set[kind], folder)
    sources = folder / "sources"
    library = tmp_path / f"{kind}_{compiler}.so"
    compile_c(compiler, ["-O2", "-shared", "-fPIC", "-ffp-contract=off", *STRICT,
                         f"-I{sources}", "-o", str(library),
                         *sorted(map(str, sources.glob("*.c"))), "-lm"])
    symbols = subprocess.run(["nm", "-D", "--defined-only", str(library)], capture_output=True,
                             text=True, check=True).stdout.split()[2::3]
    assert symbols and all(name.startswith("fmi2") for name in symbols), symbols
    shipped = outputs(native_set[kind], None)
    assert np.any(shipped != 0.0)
    np.testing.assert_array_equal(outputs(folder, library), shipped)


@pytest.mark.slow
@needs_gcc
@pytest.mark.parametrize("compiler", COMPILERS)
def test_other_c_files_compile_warning_free(compiler, tmp_path):
    """The status wrapper (with its generated header and the value reference it is built
    with), the harness's step loop, and the generated unit of each native harness block."""
    from fhobs.fmu.modes import STATUS_VALUE_REFERENCE

    from harness.blocks.native import native_block_fmu

    (tmp_path / call_rules.HEADER).write_text(call_rules.c_header())
    fmi = f"-I{_fmi_headers()}"
    wrapper = NATIVE.parent / "fmu" / "status_wrapper.c"
    for optimise in ("-O0", "-O2"):  # gcc's -Wformat-truncation looks deeper at -O2
        compile_c(compiler, [optimise, *STRICT, f"-DFHOBS_STATUS_VR={STATUS_VALUE_REFERENCE}",
                             fmi, f"-I{tmp_path}", f"-I{sysconfig.get_paths()['include']}",
                             "-c", str(wrapper), "-o",
                             str(tmp_path / "wrapper.o")])
        compile_c(compiler, [optimise, *STRICT, fmi, "-c", str(REPO_C[-2]), "-o",
                             str(tmp_path / "step_loop.o")])
    for kind, dims in (("sine", (3,)), ("gain", (2, 3))):
        folder = tmp_path / kind
        zipfile.ZipFile(native_block_fmu(kind, dims, tmp_path / "blocks")).extractall(folder)
        assert all((folder / "sources" / name).exists() for name in FMI_HEADERS)
        compile_c(compiler, ["-O2", *STRICT, f"-I{folder / 'sources'}", "-c",
                             str(folder / "sources" / "fhobs_fmu.c"), "-o",
                             str(tmp_path / f"{kind}.o")])


def test_no_variable_length_arrays_in_the_c_files():
    for path in REPO_C:
        text = path.read_text()
        declared = re.findall(r"^\s+(?:double|int|cplx|char)\s+\w+\[[^\]]*\b[a-z_]\w*(?:->\w+)?"
                              r"[^\]]*\]", text, re.M)
        assert not [d for d in declared if "sizeof" not in d and not re.search(
            r"\[[A-Z0-9_ *+()-]+\]", d)], (path.name, declared)


# -- constants shared by Python and C ---------------------------------------------------------
PIN = re.compile(r"^#define (\w+) (\S+)\s+/\* (fhobs(?:\.\w+)+)\.(\w+) \*/", re.M)


def c_defines(path: Path) -> dict[str, str]:
    return dict(re.findall(r"^#define (\w+) (.+?)(?:\s+/\*.*)?$", path.read_text(), re.M))


def test_constants_pinned_to_python_values():
    """Every ``#define NAME VALUE /* fhobs.module.ATTR */`` has ATTR's value."""
    pins = [(path.name, *match) for path in (kernel.HEADER, *REPO_C)
            for match in PIN.findall(path.read_text())]
    assert len(pins) >= 11, pins
    for file, name, value, module, attribute in pins:
        expected = getattr(importlib.import_module(module), attribute)
        assert float(value) == float(expected), (file, name, value, module, attribute)
    models = c_defines(NATIVE / "model_common.h")
    euler = int(models["FHOBS_SCHEME_EULER"])
    assert SCHEMES[euler] == "euler" and PLANT_SCHEMES[euler] == "euler"


@pytest.mark.parametrize("n, k", [(1, 1), (4, 2), (7, 3)])
def test_scratch_sizes_of_kernel_h_are_kernel_py(n, k):
    """kernel.h's FHOBS_*_WORK macros, evaluated, against kernel.py's *_work_size."""
    macros = dict(re.findall(r"^#define (FHOBS_\w+_C?WORK)\(n, k\) (.+)$",
                             kernel.HEADER.read_text(), re.M))

    def size(name: str) -> int:
        return eval(macros[name], {}, {"n": n, "k": k})  # noqa: S307 (arithmetic of n, k)

    assert size("FHOBS_KALMAN_WORK") == kernel.kalman_work_size(n, k)
    assert (size("FHOBS_FILTER_WORK"), size("FHOBS_FILTER_CWORK")) \
        == kernel.filter_work_size(n, k)
    assert (size("FHOBS_EULER_WORK"), size("FHOBS_EULER_CWORK")) == kernel.euler_work_size(n, k)


def c_struct_fields(name: str) -> list[str]:
    """The field names of ``typedef struct {...} name;`` in kernel.h, in order."""
    text = kernel.HEADER.read_text()
    end = text.index("\n} " + name + ";")
    body = text[text.rindex("typedef struct {\n", 0, end) + len("typedef struct {\n"):end]
    fields = []
    for line in body.splitlines():
        declaration = re.sub(r"/\*.*?\*/", "", line).strip().rstrip(";")
        if declaration:
            names = declaration.split(" ", 1)[1] if not declaration.startswith("const ") \
                else declaration.split(" ", 2)[2]
            fields += [part.strip().lstrip("*") for part in names.split(",")]
    return fields


@pytest.mark.parametrize("name", ["PlantPlan", "LinearPlan", "FilterPlan", "EulerPlan",
                                  "PrescribedPlan", "Call"])
def test_ctypes_structures_follow_kernel_h(name):
    """kernel.py's Structures name kernel.h's fields in kernel.h's order."""
    assert [field for field, _ in getattr(kernel, name)._fields_] == c_struct_fields(name)
