"""The native harness blocks (harness/blocks/native.py, native_blocks.c): the pythonfmu blocks'
interface and values, compiled C without Python, and fmi2Error with a message for every caller
mistake."""

from __future__ import annotations

import doctest
import math
import shutil
import subprocess
import zipfile
from ctypes import byref
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from fmpy import extract
from fmpy.fmi2 import (
    FMU2Slave,
    calloc,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    free,
)
from fmpy.validation import validate_fmu
from fmu_fixtures import FmuDriver, assert_error

import harness.blocks.native
from harness.blocks import block_fmu

BLOCKS = {"sine": (3,), "gain": (2, 4)}
CAPABILITIES = ("needsExecutionTool", "canGetAndSetFMUstate", "canSerializeFMUstate",
                "canHandleVariableCommunicationStepSize", "canInterpolateInputs")


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("blocks")


@pytest.fixture(scope="module")
def fmus(cache) -> dict[tuple[str, bool], Path]:
    """``(kind, native) -> .fmu`` for both kinds, pythonfmu and native."""
    return {(kind, native): block_fmu(kind, dims, cache, native=native)
            for kind, dims in BLOCKS.items() for native in (False, True)}


@pytest.fixture
def open_block(fmus, tmp_path):
    """``open_block(kind, native)`` -> an instantiated :class:`FmuDriver`."""
    drivers = []

    def factory(kind: str, native: bool = True) -> FmuDriver:
        driver = FmuDriver(fmus[kind, native], extract(str(fmus[kind, native]),
                                                       str(tmp_path / f"{kind}{native}")))
        drivers.append(driver)
        return driver

    yield factory
    for driver in drivers:
        driver.fmu.freeInstance()


def _description(fmu: Path) -> ET.Element:
    return ET.fromstring(zipfile.ZipFile(fmu).read("modelDescription.xml"))


def _interface(root: ET.Element) -> list:
    """Every variable (attributes and start value) and the model structure."""
    variables = [(dict(v.attrib), dict(v.find("Real").attrib))
                 for v in root.iterfind("ModelVariables/ScalarVariable")]
    structure = [(u.tag, dict(u.attrib)) for u in root.find("ModelStructure").iter()]
    return [variables, structure]


@pytest.mark.parametrize("kind", BLOCKS)
def test_interface_is_the_pythonfmu_blocks(fmus, kind):
    python, native = (_description(fmus[kind, n]) for n in (False, True))
    assert _interface(native) == _interface(python)
    cosim = native.find("CoSimulation")
    assert {name: cosim.get(name) for name in CAPABILITIES} == {
        "needsExecutionTool": "false", "canGetAndSetFMUstate": "false",
        "canSerializeFMUstate": "false", "canHandleVariableCommunicationStepSize": "true",
        "canInterpolateInputs": "false"}
    assert native.get("guid") != python.get("guid")
    assert not native.get("generationTool").startswith("PythonFMU")


def test_gain_outputs_declare_every_input():
    """The interface test compares with the pythonfmu block; this checks what that block says."""
    root = _description(block_fmu("gain", (2, 3)))
    inputs = [str(i) for i, v in enumerate(root.iterfind("ModelVariables/ScalarVariable"), 1)
              if v.get("causality") == "input"]
    unknowns = root.findall("ModelStructure/Outputs/Unknown")
    assert len(unknowns) == 2 and all(u.get("dependencies").split() == inputs for u in unknowns)


@pytest.mark.parametrize("kind", BLOCKS)
def test_fmpy_validates_the_native_block(fmus, kind):
    assert validate_fmu(str(fmus[kind, True])) == []


@pytest.mark.parametrize("kind", BLOCKS)
def test_binary_needs_no_python(fmus, kind, tmp_path):
    with zipfile.ZipFile(fmus[kind, True]) as archive:
        (name,) = [n for n in archive.namelist() if n.startswith("binaries/linux64/")]
        binary = Path(archive.extract(name, tmp_path))
    linked = subprocess.run(["ldd", str(binary)], capture_output=True, text=True,
                            check=True).stdout
    assert "python" not in linked.lower()
    assert {line.split()[0] for line in linked.splitlines() if "=>" in line} <= {
        "libm.so.6", "libc.so.6"}
    symbols = subprocess.run(["nm", "-D", "--defined-only", str(binary)], capture_output=True,
                             text=True, check=True).stdout.split()
    assert {s for s in symbols if s.isidentifier() and s[0].islower()} >= {
        "fmi2Instantiate", "fmi2DoStep", "fmi2GetReal"}
    assert all(s.startswith("fmi2") for s in symbols if s.isidentifier() and s[0].islower())


@pytest.mark.parametrize("kind", BLOCKS)
def test_sources_compile_warning_free_as_c99(fmus, kind, tmp_path):
    """The shipped sources (``<SourceFiles>``: fhobs_fmu.c) compile with -std=c99 -pedantic
    -Wall -Wextra and no warning."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    zipfile.ZipFile(fmus[kind, True]).extractall(tmp_path)
    result = subprocess.run(
        [compiler, "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O2", "-shared",
         "-fPIC", f"-I{tmp_path / 'sources'}", "-o", str(tmp_path / "block.so"),
         str(tmp_path / "sources" / "fhobs_fmu.c"), "-lm"],
        capture_output=True, text=True, check=False)
    assert result.returncode == 0 and result.stderr == "", result.stderr


def test_sine_gives_the_pythonfmu_values_bit_for_bit(open_block):
    """From setupExperiment(t0) the outputs are the signal at t0, after doStep(t, h) at t + h;
    parameters tuned between steps take effect at once."""
    rng = np.random.default_rng(3)
    params = {name: rng.uniform(-3, 3, 3) for name in ("amplitude", "omega", "phase", "offset")}
    runs = []
    for native in (False, True):
        block = open_block("sine", native)
        block.fmu.setupExperiment(startTime=0.25)
        for name, value in params.items():
            block.set(name, value)
        block.fmu.enterInitializationMode()
        block.fmu.exitInitializationMode()
        rows = [block.get("y", (3,))]
        for k in range(50):
            if k == 20:
                block.set("omega", params["omega"] * 2)
            block.fmu.doStep(0.25 + k * 1e-3, 1e-3)
            rows.append(block.get("y", (3,)))
        runs.append(np.array(rows))
    p = params
    expected = p["amplitude"] * np.sin(p["omega"] * 0.25 + p["phase"]) + p["offset"]
    assert runs[1][0].tolist() == expected.tolist()
    t = 0.25 + 5e-3 + 1e-3  # after doStep(0.25 + 5e-3, 1e-3)
    assert runs[1][6][0] == p["amplitude"][0] * math.sin(p["omega"][0] * t + p["phase"][0]) \
        + p["offset"][0]
    assert runs[1].tobytes() == runs[0].tobytes()


def test_gain_is_direct_feedthrough_with_the_pythonfmu_values(open_block):
    """y = K u from the inputs just set (no doStep between), bit for bit the pythonfmu block's."""
    rng = np.random.default_rng(5)
    gain = rng.normal(size=(2, 4)) * 10.0 ** rng.integers(-8, 8, size=(2, 4))
    inputs = rng.normal(size=(20, 4)) * 1e3
    outputs = []
    for native in (False, True):
        block = open_block("gain", native)
        block.start({"K": gain})
        rows = []
        for u in inputs:
            block.set("u", u)
            rows.append(block.get("y", (2,)))
            expected = [sum(k * x for k, x in zip(row, u, strict=True)) for row in gain]
            assert rows[-1].tolist() == expected
        block.fmu.doStep(0.0, 0.1)
        rows.append(block.get("y", (2,)))
        outputs.append(np.array(rows))
    assert outputs[1].tobytes() == outputs[0].tobytes()


def test_caller_mistakes_are_errors_that_change_nothing(open_block):
    block = open_block("gain")
    vr = block.vr
    assert_error(block, block.fmu.doStep, 0.0, 1e-3, words="doStep runs between")
    block.start({"K": [[1.0, 2.0, 3.0, 4.0], [0.0, 0.0, 0.0, 1.0]]})
    block.set("u", [1.0, 1.0, 1.0, 1.0])
    assert block.get("y", (2,)).tolist() == [10.0, 1.0]
    assert_error(block, block.fmu.getReal, [99], words="value reference 99 is not a variable")
    assert_error(block, block.fmu.setReal, [vr["u[1]"], 99], [5.0, 0.0],
                 words="value reference 99")
    assert_error(block, block.fmu.getInteger, [vr["u[1]"]],
                 words=f"u[1] (value reference {vr['u[1]']}) is of type Real, not Integer")
    assert_error(block, block.fmu.setBoolean, [0], [True], words="not Boolean")
    assert_error(block, block.fmu.setReal, [vr["y[1]"]], [1.0],
                 words=f"y[1] (value reference {vr['y[1]']}) is an output")
    for bad in (math.nan, math.inf):
        assert_error(block, block.fmu.setReal, [vr["u[1]"], vr["u[2]"]], [7.0, bad],
                     words="input u[2] = ")
    assert_error(block, block.fmu.setReal, [vr["K[1,1]"]], [math.nan], words="parameter K[1,1]")
    assert block.get("y", (2,)).tolist() == [10.0, 1.0]  # nothing of a refused call was set
    assert_error(block, block.fmu.enterInitializationMode, words="initialised once")
    assert_error(block, block.fmu.setupExperiment, None, 0.0, words="only before")
    for dt in (0.0, -1e-3, math.nan):
        assert_error(block, block.fmu.doStep, 0.0, dt, words="h positive")
    assert_error(block, block.fmu.getFMUstate, words="canGetAndSetFMUstate=false")
    block.set("K", [[0.5, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])  # tunable: set between steps
    assert block.get("y", (2,)).tolist() == [0.5, 0.0]
    block.fmu.doStep(0.0, 1e-3)
    block.fmu.terminate()
    assert_error(block, block.fmu.setReal, [vr["u[1]"]], [1.0], words="after fmi2Terminate")
    assert_error(block, block.fmu.doStep, 1e-3, 1e-3, words="called in terminated")
    block.fmu.reset()
    assert block.get("K", (2, 4)).tolist() == np.zeros((2, 4)).tolist()
    block.start()
    block.fmu.doStep(0.0, 1e-3)


def test_wrong_guid_and_model_exchange_are_refused(fmus, tmp_path):
    """fmi2Instantiate returns NULL (fmpy raises) and logs why."""
    fmu = fmus["sine", True]
    unzipped = extract(str(fmu), str(tmp_path / "x"))
    description = _description(fmu)
    identifier = description.find("CoSimulation").get("modelIdentifier")
    messages = []
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(lambda *args: messages.append(args[-1].decode()))
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    slave = FMU2Slave(guid="not-the-guid", unzipDirectory=unzipped, modelIdentifier=identifier)
    with pytest.raises(Exception, match="instantiate"):
        slave.instantiate(callbacks=callbacks, loggingOn=True)
    assert "the GUID is not this FMU's" in messages[-1]
    model_exchange = 0
    component = slave.fmi2Instantiate(b"me", model_exchange, description.get("guid").encode(),
                                      b"", byref(callbacks), False, True)
    assert not component and "co-simulation only" in messages[-1]


def test_kinds_without_a_native_version_are_refused(cache):
    from fhobs.errors import BuildError

    from harness.blocks.native import native_block_fmu

    with pytest.raises(BuildError, match="'ramp' has no native version"):
        native_block_fmu("ramp", (1,), cache)


def test_docstring_examples():
    result = doctest.testmod(harness.blocks.native, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0
