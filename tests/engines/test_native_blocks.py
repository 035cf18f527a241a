"""The native harness blocks (harness/blocks/native.py, native_blocks.c): the pythonfmu blocks'
interface and values (every kind, every signal shape and noise distribution, over runs of odd
steps), the same seeded draws, compiled C without Python, the product's call rules, and
fmi2Error with a message for every caller mistake."""

from __future__ import annotations

import doctest
import math
import re
import shutil
import subprocess
import zipfile
from ctypes import byref
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from fhobs.core.plant import noise_samples
from fhobs.fmu.call_rules import call_problem
from fmpy import extract
from fmpy.fmi2 import (
    FMU2Slave,
    calloc,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2LastSuccessfulTime,
    free,
)
from fmpy.validation import validate_fmu
from fmu_fixtures import FmuDriver, assert_error
from host_runner import read_outputs
from scipy import stats

import harness.blocks.native
from harness.blocks import block_fmu
from harness.blocks.signal_source import NoiseSource, SignalSource

BLOCKS = {"sine": (3,), "constant": (2,), "gain": (2, 4), "sum": (2, 3), "signal": (2,),
          "noise": (3,)}
CAPABILITIES = ("needsExecutionTool", "canGetAndSetFMUstate", "canSerializeFMUstate",
                "canHandleVariableCommunicationStepSize", "canInterpolateInputs")


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("blocks")


@pytest.fixture(scope="module")
def fmus(cache) -> dict[tuple[str, bool], Path]:
    """``(kind, native) -> .fmu`` for every kind, pythonfmu and native."""
    return {(kind, native): block_fmu(kind, dims, cache, native=native)
            for kind, dims in BLOCKS.items() for native in (False, True)}


@pytest.fixture(scope="module")
def unzipped(fmus, tmp_path_factory) -> dict[tuple[str, bool], str]:
    """Each FMU extracted once: every instance of a pythonfmu block in the process loads the
    same library (a second copy of it crashes the process once an instance failed)."""
    folder = tmp_path_factory.mktemp("unzipped")
    return {key: extract(str(fmu), str(folder / f"{key[0]}{key[1]}"))
            for key, fmu in fmus.items()}


@pytest.fixture
def open_block(fmus, unzipped):
    """``open_block(kind, native)`` -> an instantiated :class:`FmuDriver`."""
    drivers = []

    def factory(kind: str, native: bool = True) -> FmuDriver:
        driver = FmuDriver(fmus[kind, native], unzipped[kind, native])
        drivers.append(driver)
        return driver

    yield factory
    for driver in drivers:
        driver.fmu.freeInstance()


def _description(fmu: Path) -> ET.Element:
    return ET.fromstring(zipfile.ZipFile(fmu).read("modelDescription.xml"))


def _interface(root: ET.Element) -> list:
    """Every variable (attributes and start value) and the model structure."""
    variables = [(dict(v.attrib), [(typed.tag, dict(typed.attrib)) for typed in v])
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


def _known(kind: str, i: int, dims: tuple[int, ...]) -> set[str]:
    """What output ``i`` (1-based) of a block of ``kind`` is computed from: its inputs and
    parameters by name, from the formulas of harness/blocks (not from the slaves' code)."""
    if kind == "sine":
        return {f"{p}[{i}]" for p in ("amplitude", "omega", "phase", "offset")}
    if kind == "constant":
        return {f"value[{i}]"}
    if kind == "gain":
        return {f"K[{i},{j}]" for j in range(1, dims[1] + 1)} | {
            f"u[{j}]" for j in range(1, dims[1] + 1)}
    if kind == "sum":
        return {f"u[{k},{i}]" for k in range(1, dims[1] + 1)}
    selector = {"signal": ("shape", "start", "frequency"), "noise": ("distribution",)}[kind]
    return {f"size[{i}]", "seed", *selector}


@pytest.mark.parametrize("native", [False, True])
@pytest.mark.parametrize("kind", BLOCKS)
def test_outputs_are_initial_unknowns_of_what_they_are_computed_from(fmus, kind, native):
    """FMI 2.0: outputs initial="calculated" have no start value and are listed in
    <InitialUnknowns>, here with their dependencies on the inputs and parameters of their
    formula; <Outputs> lists the inputs among them."""
    root = _description(fmus[kind, native])
    variables = root.findall("ModelVariables/ScalarVariable")
    name = {str(k): v.get("name") for k, v in enumerate(variables, start=1)}
    outputs = [(str(k), v) for k, v in enumerate(variables, start=1)
               if v.get("causality") == "output"]
    assert [v.get("initial") for _, v in outputs] == ["calculated"] * BLOCKS[kind][0]
    assert all(v.find("Real").get("start") is None for _, v in outputs)
    initial = root.findall("ModelStructure/InitialUnknowns/Unknown")
    declared = root.findall("ModelStructure/Outputs/Unknown")
    assert [u.get("index") for u in initial] == [k for k, _ in outputs]
    for i, (unknown, output) in enumerate(zip(initial, declared, strict=True), start=1):
        known = _known(kind, i, BLOCKS[kind])
        indices = unknown.get("dependencies").split()
        assert indices == sorted(indices, key=int)
        assert {name[k] for k in indices} == known
        assert {name[k] for k in output.get("dependencies").split()} == {
            n for n in known if n.startswith("u[")}


def _initialising(driver: FmuDriver, t0: float, parameters: dict[str, float]) -> None:
    """setupExperiment(t0), initialisation mode entered, the scalar ``parameters`` set (Integer
    ones as such)."""
    variables = {v.name: v for v in driver.description.modelVariables}
    driver.fmu.setupExperiment(startTime=t0)
    driver.fmu.enterInitializationMode()
    for name, value in parameters.items():
        if variables[name].type == "Integer":
            driver.fmu.setInteger([variables[name].valueReference], [int(value)])
        else:
            driver.fmu.setReal([variables[name].valueReference], [float(value)])


@pytest.mark.parametrize("native", [False, True])
def test_outputs_are_computed_in_initialization_mode(open_block, native):
    """Read in initialisation mode, after their inputs and parameters were set there, the
    outputs are already the formula's values at the start time (what OMSimulator reads when it
    initialises a system through the blocks)."""
    values = {}
    cases = {
        "gain": {"K[1,1]": 2.0, "K[1,2]": -1.0, "K[1,3]": 0.5, "K[1,4]": 3.0,
                 "K[2,1]": 0.0, "K[2,2]": 1.0, "K[2,3]": -4.0, "K[2,4]": 0.25,
                 "u[1]": 1.5, "u[2]": -2.0, "u[3]": 8.0, "u[4]": 0.125},
        "sum": {"u[1,1]": 1.0, "u[1,2]": 2.0, "u[2,1]": 10.0, "u[2,2]": 20.0, "u[3,1]": 0.5,
                "u[3,2]": -0.25},
        "constant": {"value[1]": 2.5, "value[2]": -1.0},
        "sine": {"amplitude[1]": 2.0, "omega[1]": 3.0, "phase[1]": 0.25, "offset[1]": -1.0},
        "signal": {"shape": 0, "start": 0.1, "size[1]": 1.5, "size[2]": -0.25},
        "noise": {"distribution": 1, "seed": 4, "size[1]": 0.5, "size[2]": 2.0,
                  "size[3]": -1.0},
    }
    for kind, parameters in cases.items():
        driver = open_block(kind, native)
        _initialising(driver, T0, parameters)
        outputs = [v.valueReference for v in driver.description.modelVariables
                   if v.causality == "output"]
        values[kind] = np.array(driver.fmu.getReal(outputs))
        driver.fmu.exitInitializationMode()
    K = np.array([[2.0, -1.0, 0.5, 3.0], [0.0, 1.0, -4.0, 0.25]])
    assert values["gain"].tolist() == (K @ [1.5, -2.0, 8.0, 0.125]).tolist()
    assert values["sum"].tolist() == [11.5, 21.75]
    assert values["constant"].tolist() == [2.5, -1.0]
    assert values["sine"][0] == pytest.approx(2.0 * math.sin(3.0 * T0 + 0.25) - 1.0,
                                              rel=1e-15)
    assert values["signal"].tolist() == [1.5, -0.25]  # the step started at 0.1 < T0
    _, w = _draws(4, 1, 3)
    np.testing.assert_allclose(values["noise"], np.array([0.5, 2.0, -1.0]) * w[0],
                               rtol=1e-14)


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
    """The shipped sources (``<SourceFiles>``: fhobs_fmu.c, and noise.c for the seeded
    sources) compile with -std=c99 -pedantic -Wall -Wextra and no warning."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    zipfile.ZipFile(fmus[kind, True]).extractall(tmp_path)
    units = [tmp_path / "sources" / f.get("name")
             for f in _description(fmus[kind, True]).iter("File")]
    assert units[0].name == "fhobs_fmu.c" and len(units) == 1 + (kind in ("signal", "noise"))
    result = subprocess.run(
        [compiler, "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O2", "-shared",
         "-fPIC", f"-I{tmp_path / 'sources'}", "-o", str(tmp_path / "block.so"),
         *map(str, units), "-lm"],
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
    """Out of sequence: the product's call rules and their messages (fhobs.fmu.call_rules)."""
    block = open_block("gain")
    vr = block.vr
    assert_error(block, block.fmu.doStep, 0.0, 1e-3,
                 words=call_problem("fmi2DoStep", "instantiated"))
    assert_error(block, block.fmu.getReal, [vr["y[1]"]],
                 words=call_problem("fmi2GetReal", "instantiated"))
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
    assert_error(block, block.fmu.enterInitializationMode,
                 words=call_problem("fmi2EnterInitializationMode", "step mode"))
    assert_error(block, block.fmu.setupExperiment, None, 0.0,
                 words=call_problem("fmi2SetupExperiment", "step mode"))
    for dt in (0.0, -1e-3, math.nan):
        assert_error(block, block.fmu.doStep, 0.0, dt, words="h positive")
    assert_error(block, block.fmu.getFMUstate, words="canGetAndSetFMUstate = false")
    assert_error(block, block.fmu.cancelStep, words=call_problem("fmi2CancelStep", "step mode"))
    block.set("K", [[0.5, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])  # tunable: set between steps
    assert block.get("y", (2,)).tolist() == [0.5, 0.0]
    block.fmu.doStep(0.0, 1e-3)
    assert_error(block, block.fmu.doStep, 0.5, 1e-3, words="is not the FMU's time 0.001")
    block.fmu.doStep(1e-3 * (1 + 1e-12), 1e-3)  # a host's round-off: accepted
    assert block.fmu.getRealStatus(fmi2LastSuccessfulTime) == 1e-3 * (1 + 1e-12) + 1e-3
    block.fmu.terminate()
    assert_error(block, block.fmu.setReal, [vr["u[1]"]], [1.0],
                 words=call_problem("fmi2SetReal", "terminated"))
    assert_error(block, block.fmu.doStep, 2e-3, 1e-3,
                 words=call_problem("fmi2DoStep", "terminated"))
    block.fmu.reset()
    block.start()
    assert block.get("K", (2, 4)).tolist() == np.zeros((2, 4)).tolist()
    block.fmu.doStep(0.0, 1e-3)


@pytest.mark.parametrize(("kind", "selector", "value", "words"), [
    ("signal", "shape", 4, "shape = 4 is not one of 0..3 (step, ramp, sine, random_walk)"),
    ("noise", "distribution", -1, "distribution = -1 is not one of 0..1 (uniform, gaussian)"),
    ("noise", "seed", -3, "seed = -3 must be >= 0"),
])
def test_bad_integer_parameters_fail_initialisation_in_both_builds(open_block, kind, selector,
                                                                    value, words):
    """The native block's fmi2Error, and the pythonfmu block's slave class raising the same
    (its FMU's fatal error is not exercised here: fmpy freeing a second pythonfmu instance
    after one was fatal crashes the process)."""
    block = open_block(kind)
    block.fmu.setupExperiment(startTime=0.0)
    block.fmu.enterInitializationMode()
    block.fmu.setInteger([block.vr[selector]], [value])
    assert_error(block, block.fmu.exitInitializationMode, words=words)
    slave = {"signal": SignalSource, "noise": NoiseSource}[kind](n_outputs=2, instance_name="s")
    slave.integers[selector] = value
    with pytest.raises(ValueError, match=re.escape(words)):
        slave.exit_initialization_mode()


def test_fixed_parameters_are_set_before_initialisation_only(open_block):
    block = open_block("signal")
    block.fmu.setupExperiment(startTime=0.0)
    block.fmu.setInteger([block.vr["shape"]], [1])
    block.fmu.enterInitializationMode()
    block.set("size", [2.0, 3.0])
    block.fmu.exitInitializationMode()
    assert block.fmu.getInteger([block.vr["shape"]]) == [1]
    for call, ref, value in ((block.fmu.setReal, "size[1]", 1.0),
                             (block.fmu.setInteger, "seed", 1)):
        assert_error(block, call, [block.vr[ref]], [value],
                     words=f"{ref} (value reference {block.vr[ref]}) is a fixed parameter")
    assert_error(block, block.fmu.getReal, [block.vr["shape"]],
                 words="is of type Integer, not Real")
    block.fmu.doStep(0.0, 0.5)
    assert block.get("y", (2,)).tolist() == [1.0, 1.5]


# -- the pythonfmu block's values, over runs of odd steps ---------------------------------------

def _odd_steps(count: int, seed: int) -> np.ndarray:
    """Step sizes of 0.3e-2 .. 1.7e-2 s, none alike."""
    return np.random.default_rng(seed).uniform(0.3e-2, 1.7e-2, count)


def _run(driver: FmuDriver, t0: float, steps: np.ndarray, parameters: dict[str, float],
         inputs: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """setupExperiment(t0), the scalar ``parameters`` (Integer ones as such), initialisation,
    then a doStep of each of ``steps``, the time accumulated in floating point (t += h) as
    OMSimulator does; row k of ``inputs`` set before the outputs are read at t_k. The times
    and the outputs (rows) after initialisation and after each step."""
    outputs = [v.valueReference for v in driver.description.modelVariables
               if v.causality == "output"]
    ins = [v.valueReference for v in driver.description.modelVariables
           if v.causality == "input"]
    _initialising(driver, t0, parameters)
    driver.fmu.exitInitializationMode()
    t, times, rows = t0, [], []
    for k in range(len(steps) + 1):
        if inputs is not None:
            driver.fmu.setReal(ins, inputs[k].tolist())
        times.append(t)
        rows.append(driver.fmu.getReal(outputs))
        if k < len(steps):
            driver.fmu.doStep(t, float(steps[k]))
            t += float(steps[k])
    return np.array(times), np.array(rows)


def _both(open_block, kind: str, t0: float, steps: np.ndarray, parameters: dict[str, float],
          inputs: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The times and the native block's outputs, checked against the pythonfmu block's to
    1e-12 relative to the largest output."""
    times, python = _run(open_block(kind, False), t0, steps, parameters, inputs)
    _, native = _run(open_block(kind, True), t0, steps, parameters, inputs)
    assert np.max(np.abs(native - python)) <= 1e-12 * np.max(np.abs(python))
    return times, native


def _draws(seed: int, count: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Draws 0 .. count - 1 of the product's portable generator (fhobs.core.plant's noise):
    their uniform numbers of [-1, 1) and their Gaussian numbers (Box-Muller of each pair)."""
    rows = noise_samples(seed, count, 1.0, 2 * n)
    v, w = rows[:, :n], rows[:, n:]
    return v, np.sqrt(-2.0 * np.log(0.5 * (1.0 - v))) * np.cos(np.pi * w)


SIZE = np.array([1.5, -0.25])
T0 = 0.125


def _signal(open_block, shape: int, count: int, **extra: float):
    steps = _odd_steps(count, shape)
    start = T0 + float(np.sum(steps[:40])) + 0.37 * float(steps[40])  # between two steps
    parameters = {"shape": shape, "size[1]": SIZE[0], "size[2]": SIZE[1], "start": start,
                  "seed": 9, **extra}
    times, native = _both(open_block, "signal", T0, steps, parameters)
    on = times >= start - 1e-9 * max(1.0, start)
    assert not on[40] and on[41]  # t_40 < start < t_41
    return steps, start, times, on, native


@pytest.mark.parametrize("shape", [0, 1, 2])
def test_signal_shapes_give_the_pythonfmu_values(open_block, shape):
    """Step, ramp and sine from a start between two steps, over 300 steps of odd sizes: the
    pythonfmu block's values and their formulas to 1e-12 relative."""
    _, start, times, on, native = _signal(open_block, shape, 300, frequency=1.7)
    elapsed = (times - start)[:, None]
    unit = [np.ones_like(elapsed), elapsed, np.sin(2 * np.pi * 1.7 * elapsed)][shape]
    expected = np.where(on[:, None], SIZE * unit, 0.0)
    assert np.max(np.abs(native - expected)) <= 1e-12 * np.max(np.abs(expected))


def test_random_walk_draws_the_portable_generators_numbers(open_block):
    """1300 steps (over a generator block of 1024 draws): the pythonfmu block's walk and
    y(t_k + h) = y(t_k) + size sqrt(h) w_j, w_j the Gaussians of the product's generator."""
    steps, _, _, on, native = _signal(open_block, 3, 1300)
    _, w = _draws(9, 1300, 2)
    expected = np.zeros((len(steps) + 1, 2))
    j = 0
    for k, h in enumerate(steps):
        expected[k + 1] = expected[k]
        if on[k]:
            expected[k + 1] += SIZE * math.sqrt(h) * w[j]
            j += 1
    assert j > 1024
    assert np.max(np.abs(native - expected)) <= 1e-12 * np.max(np.abs(expected))


@pytest.mark.parametrize("distribution", [0, 1])
def test_noise_gives_the_pythonfmu_draws_in_value_and_distribution(open_block, distribution):
    """6000 steps of odd sizes: the same numbers in both builds, the product generator's draw
    k after k steps, and uniform in [-size, size) or normal of std size (Kolmogorov-Smirnov)."""
    size = np.array([0.5, 2.0, 1e-3])
    parameters = {"distribution": distribution, "seed": 21,
                  **{f"size[{i + 1}]": a for i, a in enumerate(size)}}
    _, native = _both(open_block, "noise", T0, _odd_steps(6000, 5), parameters)
    v, w = _draws(21, 6001, 3)
    expected = size * (v if distribution == 0 else w)
    assert np.max(np.abs(native - expected)) <= 1e-12 * np.max(np.abs(expected))
    standard = (native / size).ravel()
    reference = stats.uniform(loc=-1.0, scale=2.0) if distribution == 0 else stats.norm()
    assert stats.kstest(standard, reference.cdf).pvalue > 1e-3
    assert abs(standard.mean()) < 4 * reference.std() / math.sqrt(standard.size)


def test_constant_and_sum_give_the_pythonfmu_values(open_block):
    rng = np.random.default_rng(8)
    steps = _odd_steps(30, 8)
    _, constant = _both(open_block, "constant", T0, steps, {"value[1]": 2.5, "value[2]": -1e-7})
    assert constant.tolist() == [[2.5, -1e-7]] * 31
    inputs = rng.normal(size=(31, 6)) * 10.0 ** rng.integers(-6, 6, size=(31, 6))
    _, total = _both(open_block, "sum", T0, steps, {}, inputs)
    expected = inputs.reshape(31, 3, 2).sum(axis=1)  # u[k,i]: term k, entry i
    assert np.max(np.abs(total - expected)) <= 1e-12 * np.max(np.abs(expected))


def test_native_blocks_run_in_the_c_host(native_host, fmus, open_block, tmp_path):
    """The C test host (no Python in its process, every FMI call checked for fmi2OK, the time
    accumulated in floating point): the noise block and the signal's step give the pythonfmu
    blocks' values."""
    steps = _odd_steps(1500, 2)
    start = float(np.sum(steps[:40])) + 0.5 * float(steps[40])
    for kind, parameters in (("noise", {"size[1]": 0.5, "size[2]": 2.0, "size[3]": 3.0}),
                             ("signal", {"size[1]": 1.5, "size[2]": -0.25, "start": start})):
        folder = tmp_path / kind
        zipfile.ZipFile(fmus[kind, True]).extractall(folder)
        with (tmp_path / "in.csv").open("w") as f:
            f.write("time,step\n")
            f.writelines(f"0.0,{float(h)!r}\n" for h in [*steps, 0.0])
        done = subprocess.run([str(native_host), str(folder), str(tmp_path / "in.csv"),
                               str(tmp_path / "out.csv"), "-",
                               *(f"{name}={value!r}" for name, value in parameters.items())],
                              env={}, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        _, host = read_outputs(tmp_path / "out.csv")
        times, python = _run(open_block(kind, False), 0.0, steps, parameters)
        assert host[:, 0].tolist() == times.tolist()
        assert np.max(np.abs(host[:, 1:] - python)) <= 1e-12 * np.max(np.abs(python))
        assert np.max(np.abs(python)) > 0.1


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


@pytest.mark.parametrize("native", [False, True], ids=["pythonfmu", "native"])
def test_a_foreign_or_broken_cached_block_is_built_again(tmp_path, native):
    """A block FMU in the cache is used only if this user alone could have put it there and it
    is an FMU: a text file in its place, or one others may write, is built again over it."""
    from harness.blocks.build import block_fmu
    from harness.blocks.native import native_block_fmu

    build = native_block_fmu if native else block_fmu
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    fmu = build("gain", (1, 2), cache)
    good = fmu.read_bytes()
    fmu.write_text("not an FMU")
    assert build("gain", (1, 2), cache) == fmu and fmu.read_bytes()[:2] == b"PK"
    fmu.chmod(0o666)
    rebuilt = build("gain", (1, 2), cache)
    assert rebuilt.stat().st_mode & 0o022 == 0 and zipfile.is_zipfile(rebuilt)
    assert len(fmu.read_bytes()) > 1000 and len(good) > 1000
