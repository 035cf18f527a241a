"""Native FMI 3.0 FMUs (fhobs.native.fmi3, fmi3_layer.c): every kind built, the same outputs as
the FMI 2.0 native build of the same design (the paper's scenarios through the harness, the
zoo by a direct loop), fmpy's simulate_fmu with and without event mode and early return, the
schema check, array start values, nValues, the call sequence, a NULL instance, the 75 exports
and the value-reference rule."""

from __future__ import annotations

import ctypes
import math
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import load_spec
from fhobs.fmu.call_rules import EXPORTED3
from fhobs.fmu.kinds import KINDS as DECLARED
from fhobs.native import fmi3
from fhobs.native.build import _variables, build_native_fmus
from fmpy.fmi3 import FMU3Slave, fmi3OK, fmi3Warning
from fmpy.validation import validate_fmu

from harness.cli import SCENARIO_DIR
from harness.master import run_system
from harness.system import load_system, resolve_system

pytestmark = pytest.mark.skipif(sys.platform != "linux" or not shutil.which("cc"),
                                reason="native FMUs need linux and cc")
ROOT = Path(__file__).resolve().parents[2]
ZOO = ROOT / "fmu_src" / "fhobs" / "examples" / "zoo"
KINDS = tuple(DECLARED)


def both_builds(spec_path: Path, out: Path) -> dict[int, dict[str, Path]]:
    """The native FMUs of the spec's design, FMI 2.0 and FMI 3.0."""
    spec = load_spec(spec_path)
    design = design_for_spec(spec)
    return {version: build_native_fmus(design, out / f"fmi{version}", names=spec.names,
                                       plant_name=spec.name, fmi_version=version)
            for version in (2, 3)}


@pytest.fixture(scope="module")
def pendulum(tmp_path_factory: pytest.TempPathFactory) -> dict[int, dict[str, Path]]:
    return both_builds(ROOT / "examples" / "pendulum.toml", tmp_path_factory.mktemp("fmi3"))


def test_every_kind_built(pendulum: dict[int, dict[str, Path]]) -> None:
    assert sorted(pendulum[3]) == sorted(KINDS) == sorted(pendulum[2])
    for path in pendulum[3].values():
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
            root = ET.fromstring(z.read("modelDescription.xml"))
        identifier = root.find("CoSimulation").get("modelIdentifier")
        assert root.get("fmiVersion") == "3.0"
        assert f"binaries/x86_64-linux/{identifier}.so" in names
        assert "sources/buildDescription.xml" in names


@pytest.mark.parametrize("kind", KINDS)
def test_validates(pendulum: dict[int, dict[str, Path]], kind: str) -> None:
    assert validate_fmu(str(pendulum[3][kind])) == []


@pytest.mark.parametrize("kind", KINDS)
def test_array_starts_have_every_element(pendulum: dict[int, dict[str, Path]], kind: str) -> None:
    """validate_fmu does not count an array's start values: prod(dimensions) entries each."""
    with zipfile.ZipFile(pendulum[3][kind]) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    arrays = 0
    for variable in root.find("ModelVariables"):
        dims = [int(d.get("start")) for d in variable.iter("Dimension")]
        arrays += bool(dims)
        if variable.get("start") is not None:
            assert len(variable.get("start").split()) == math.prod(dims), variable.get("name")
    assert arrays >= 3


def test_value_references_follow_the_fmi2_build(pendulum: dict[int, dict[str, Path]]) -> None:
    """An array's value reference is its first element's FMI 2.0 one, time the next."""
    md2 = fmpy.read_model_description(str(pendulum[2]["observer"]))
    md3 = fmpy.read_model_description(str(pendulum[3]["observer"]))
    fmi2 = {v.name: v.valueReference for v in md2.modelVariables}
    for v in md3.modelVariables:
        if v.name == "time":
            assert v.valueReference == len(fmi2)
        else:
            first = f"{v.name}[{','.join('1' * len(v.dimensions))}]" if v.dimensions else v.name
            assert v.valueReference == fmi2[first], v.name
    assert fmi3.value_references([{"name": "a[1]", "vr": 0}, {"name": "a[2]", "vr": 1}]) == {
        "a": 0, "time": 2}


def test_exports_all_75_functions(pendulum: dict[int, dict[str, Path]], tmp_path: Path) -> None:
    with zipfile.ZipFile(pendulum[3]["observer"]) as z:
        z.extractall(tmp_path)
    library = next((tmp_path / "binaries" / "x86_64-linux").glob("*.so"))
    symbols = subprocess.run(["nm", "-D", "--defined-only", str(library)], capture_output=True,
                             text=True, check=True).stdout.split()
    exported = {s for s in symbols if s.startswith("fmi")}
    assert exported == set(EXPORTED3) and len(exported) == 75


@pytest.mark.parametrize("scenario", ["pendulum_nominal", "pendulum_perturbed",
                                      "pendulum_prescribed_time", "pendulum_noisy"])
def test_harness_scenarios_agree(pendulum: dict[int, dict[str, Path]], scenario: str) -> None:
    """The paper's scenarios with the FMI 3.0 FMUs give the FMI 2.0 native run's signals to
    1e-12 of each signal's size."""
    runs = []
    for version in (2, 3):
        folder = pendulum[version]["observer"].parent
        spec = load_system(SCENARIO_DIR / f"{scenario}.toml", {"fmu_dir": str(folder)})
        runs.append(run_system(resolve_system(spec), stop_time=1.0, progress=False))
    assert runs[0].names == runs[1].names
    scale = np.maximum(np.abs(runs[0].values).max(axis=0), np.finfo(float).tiny)
    assert np.all(np.abs(runs[1].values - runs[0].values) <= 1e-12 * scale)


def test_harness_mixes_versions(pendulum: dict[int, dict[str, Path]], tmp_path: Path) -> None:
    """An FMI 3.0 observer beside FMI 2.0 plant and estimators: the all-FMI 2.0 run's signals."""
    mixed = tmp_path / "mixed"
    shutil.copytree(pendulum[2]["observer"].parent, mixed)
    shutil.copy(pendulum[3]["observer"], mixed / "observer.fmu")
    runs = []
    for folder in (pendulum[2]["observer"].parent, mixed):
        spec = load_system(SCENARIO_DIR / "pendulum_nominal.toml", {"fmu_dir": str(folder)})
        runs.append(run_system(resolve_system(spec), stop_time=0.5, progress=False))
    assert "observer.x_hat[2]" in runs[1].names
    scale = np.maximum(np.abs(runs[0].values).max(axis=0), np.finfo(float).tiny)
    assert np.all(np.abs(runs[1].values - runs[0].values) <= 1e-12 * scale)


def direct_run(path: Path, steps: int, dt: float) -> np.ndarray:
    """Outputs of an FMU of either version over ``steps`` steps of ``dt``, inputs a seeded
    random walk (row-major arrays), through fmpy's slaves."""
    md = fmpy.read_model_description(str(path))
    folder = fmpy.extract(str(path))
    rng = np.random.default_rng(7)
    is3 = md.fmiVersion == "3.0"
    cls = FMU3Slave if is3 else fmpy.fmi2.FMU2Slave
    fmu = cls(guid=md.guid, unzipDirectory=folder, instanceName="x",
              modelIdentifier=md.coSimulation.modelIdentifier)
    fmu.instantiate()
    if is3:
        fmu.enterInitializationMode(startTime=0.0)
    else:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    inputs = [v for v in md.modelVariables if v.causality == "input"]
    outputs = [v for v in md.modelVariables if v.causality == "output" and v.type in
               ("Real", "Float64")]
    size = (lambda v: math.prod(int(d.start) for d in v.dimensions)) if is3 else (lambda v: 1)
    rows, u = [], 0.0
    for k in range(steps):
        u = u + 0.1 * rng.standard_normal(sum(size(v) for v in inputs))
        if is3:
            fmu.setFloat64([v.valueReference for v in inputs], list(u))
            fmu.doStep(k * dt, dt)
            rows.append(fmu.getFloat64([v.valueReference for v in outputs],
                                       sum(size(v) for v in outputs)))
        else:
            fmu.setReal([v.valueReference for v in inputs], list(u))
            fmu.doStep(k * dt, dt)
            rows.append(fmu.getReal([v.valueReference for v in outputs]))
    fmu.terminate()
    fmu.freeInstance()
    shutil.rmtree(folder, ignore_errors=True)
    return np.array(rows)


def assert_zoo_agrees(name: str, out: Path) -> None:
    builds = both_builds(ZOO / f"{name}.toml", out)
    for kind in builds[3]:
        dt = 0.05 if kind == "supervised" else 1e-3
        a, b = (direct_run(builds[v][kind], 200, dt) for v in (2, 3))
        assert a.shape == b.shape, kind
        scale = np.maximum(np.abs(a).max(axis=0), np.finfo(float).tiny)
        assert np.all(np.abs(b - a) <= 1e-12 * scale), (name, kind)


@pytest.mark.parametrize("name", ["dc_motor", "coupled_oscillators"])
def test_zoo_agrees(name: str, tmp_path: Path) -> None:
    assert_zoo_agrees(name, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(p.stem for p in ZOO.glob("*.toml")))
def test_whole_zoo_agrees(name: str, tmp_path: Path) -> None:
    assert_zoo_agrees(name, tmp_path)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("event_mode", [False, True])
def test_simulate_fmu(pendulum: dict[int, dict[str, Path]], kind: str, event_mode: bool) -> None:
    """fmpy's simulate_fmu with and without event mode and early return: the same outputs as
    the FMI 2.0 build (outputs of the first array compared)."""
    step = 0.05 if kind == "supervised" else 1e-3
    results = [fmpy.simulate_fmu(str(pendulum[v][kind]), stop_time=0.5, output_interval=step,
                                 **({"use_event_mode": event_mode,
                                     "early_return_allowed": event_mode} if v == 3 else {}))
               for v in (2, 3)]
    first = results[1].dtype.names[1]
    a = np.column_stack([results[0][n] for n in results[0].dtype.names
                         if n.split("[")[0] == first])
    b = np.asarray(results[1][first]).reshape(len(results[1]), -1)
    scale = np.maximum(np.abs(a).max(axis=0), np.finfo(float).tiny)
    assert np.all(np.abs(b - a) <= 1e-12 * scale)


COARSE = 0.05
"""A communication step above the pendulum design's max_communication_step (0.0259 s)."""
WARNED_KINDS = ("observer", "prescribed_time", "supervised")
"""The kinds that carry max_communication_step."""


def simulate_logged(path: Path, step: float) -> tuple[np.ndarray, list[tuple[int, str]]]:
    """fmpy.simulate_fmu of an FMU of either version at ``step`` for 0.3 s: the result and the
    FMU's log messages (status, text)."""
    messages: list[tuple[int, str]] = []
    if fmpy.read_model_description(str(path)).fmiVersion == "3.0":
        def logger(env, status, category, text) -> None:  # noqa: ANN001
            messages.append((int(status), text.decode()))
    else:
        def logger(env, name, status, category, text) -> None:  # noqa: ANN001
            messages.append((int(status), text.decode()))
    result = fmpy.simulate_fmu(str(path), stop_time=0.3, output_interval=step, logger=logger)
    return result, messages


def max_communication_step(path: Path) -> float:
    variables = fmpy.read_model_description(str(path)).modelVariables
    return float(next(v.start for v in variables if v.name == "max_communication_step"))


@pytest.mark.parametrize("kind", WARNED_KINDS)
def test_a_coarse_step_is_warned_of_once_as_in_fmi2(pendulum: dict[int, dict[str, Path]],
                                                    kind: str) -> None:
    """simulate_fmu at a communication step longer than max_communication_step: one
    fmi3Warning, the FMI 2.0 build's message naming both steps, and the FMI 2.0 build's
    outputs; at 1 ms (within the figure) no warning."""
    figure = max_communication_step(pendulum[3][kind])
    assert figure == max_communication_step(pendulum[2][kind]) and 1e-3 < figure < COARSE
    runs = {version: simulate_logged(pendulum[version][kind], COARSE) for version in (2, 3)}
    warnings = {version: [text for status, text in messages if status == fmi3Warning]
                for version, (_, messages) in runs.items()}
    assert len(warnings[3]) == 1 and warnings[3] == warnings[2]
    assert warnings[3][0].startswith(f"communication step {COARSE:.3g} s is longer than the "
                                     f"{figure:.3g} s")
    assert all(status in (fmi3OK, fmi3Warning) for status, _ in runs[3][1])
    a, b = (runs[v][0] for v in (2, 3))
    first = b.dtype.names[1]
    a = np.column_stack([a[n] for n in a.dtype.names if n.split("[")[0] == first])
    b = np.asarray(b[first]).reshape(len(b), -1)
    scale = np.maximum(np.abs(a).max(axis=0), np.finfo(float).tiny)
    assert np.all(np.abs(b - a) <= 1e-12 * scale)
    _, fine = simulate_logged(pendulum[3][kind], 1e-3)
    assert [text for status, text in fine if status == fmi3Warning] == []


def test_the_warning_is_once_per_instance_and_off_at_zero(
        pendulum: dict[int, dict[str, Path]]) -> None:
    """fmi3DoStep statuses at the coarse step: fmi3Warning once, then fmi3OK; fmi3Reset gives
    the warning again; max_communication_step = 0 turns it off."""
    fmu = Logged(pendulum[3]["observer"])
    flags = [ctypes.c_bool() for _ in range(3)]
    last = ctypes.c_double()

    def run(steps: int) -> list[int]:
        fmu.fmu.enterInitializationMode(startTime=0.0)
        fmu.fmu.exitInitializationMode()
        return [fmu.status("fmi3DoStep", ctypes.c_double(k * COARSE), ctypes.c_double(COARSE),
                           True, *map(ctypes.byref, flags), ctypes.byref(last))
                for k in range(steps)]

    assert run(4) == [fmi3Warning, fmi3OK, fmi3OK, fmi3OK]
    assert last.value == pytest.approx(4 * COARSE, rel=1e-15)
    assert fmu.fmu.getInt32([fmu.vr["status"]], 1) == [fmi3OK]
    fmu.fmu.reset()
    assert run(2) == [fmi3Warning, fmi3OK]
    assert sum("max_communication_step" in m for m in fmu.messages) == 2
    fmu.fmu.reset()
    fmu.fmu.setFloat64([fmu.vr["max_communication_step"]], [0.0])
    assert run(3) == [fmi3OK] * 3


class Logged:
    """An FMI 3.0 observer instance with its log."""

    def __init__(self, path: Path) -> None:
        self.md = fmpy.read_model_description(str(path))
        self.messages: list[str] = []
        self.fmu = FMU3Slave(guid=self.md.guid, unzipDirectory=fmpy.extract(str(path)),
                             instanceName="x",
                             modelIdentifier=self.md.coSimulation.modelIdentifier)
        self.fmu.instantiate(logMessage=lambda env, status, category, message:
                             self.messages.append(message.decode()))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}

    def status(self, function: str, *args) -> int:  # noqa: ANN002
        return getattr(self.fmu.dll, function)(self.fmu.component, *args)


def test_nvalues_checked(pendulum: dict[int, dict[str, Path]]) -> None:
    fmu = Logged(pendulum[3]["observer"])
    fmu.fmu.enterInitializationMode(startTime=0.0)
    vr = (ctypes.c_uint * 1)(fmu.vr["x_hat"])
    values = (ctypes.c_double * 16)()
    assert fmu.status("fmi3GetFloat64", vr, 1, values, 3) == 3  # fmi3Error
    assert "nValues = 3" in fmu.messages[-1] and "hold 4 values" in fmu.messages[-1]
    assert fmu.status("fmi3GetFloat64", vr, 1, values, 4) == 0
    assert fmu.status("fmi3SetFloat64", (ctypes.c_uint * 1)(fmu.vr["y"]), 1, values, 5) == 3
    assert "nValues = 5" in fmu.messages[-1]
    head = (ctypes.c_uint * 1)(fmu.vr["x_hat"] + 1)  # an element that is not the first
    assert fmu.status("fmi3GetFloat64", head, 1, values, 1) == 3
    assert "not a variable of this FMU" in fmu.messages[-1]


def test_out_of_sequence_and_unsupported(pendulum: dict[int, dict[str, Path]]) -> None:
    fmu = Logged(pendulum[3]["observer"])
    flags = [ctypes.c_bool() for _ in range(3)]
    last = ctypes.c_double()
    status = fmu.status("fmi3DoStep", ctypes.c_double(0.0), ctypes.c_double(1e-3), True,
                        *map(ctypes.byref, flags), ctypes.byref(last))
    assert status == 3 and "not allowed in the state instantiated" in fmu.messages[-1]
    assert fmu.status("fmi3EnterStepMode") == 3
    assert fmu.status("fmi3EnterConfigurationMode") == 3
    assert "not supported" in fmu.messages[-1]
    assert fmu.status("fmi3GetNumberOfContinuousStates", ctypes.byref(ctypes.c_size_t())) == 3
    fmu.fmu.enterInitializationMode(startTime=0.0)
    fmu.fmu.exitInitializationMode()
    assert fmu.status("fmi3EnterEventMode") == 3  # instantiated without eventModeUsed
    status = fmu.status("fmi3DoStep", ctypes.c_double(0.0), ctypes.c_double(1e-3), True,
                        *map(ctypes.byref, flags), ctypes.byref(last))
    assert status == 0 and last.value == 1e-3 and not any(f.value for f in flags)


def test_null_instance(pendulum: dict[int, dict[str, Path]]) -> None:
    """Every function with a NULL instance: fmi3Error, no crash (the FMU's process survives)."""
    path = pendulum[3]["observer"]
    script = f"""
import ctypes, fmpy, pathlib
folder = pathlib.Path(fmpy.extract({str(path)!r}))
lib = ctypes.CDLL(str(next((folder / "binaries" / "x86_64-linux").glob("*.so"))))
names = {[f for f in EXPORTED3 if not f.startswith(("fmi3GetVersion", "fmi3Instantiate"))]!r}
bad = []
for name in names:
    function = getattr(lib, name)
    function.restype = ctypes.c_int
    if name == "fmi3FreeInstance":
        function(None)
        continue
    args = [None] + [ctypes.c_void_p(0)] * 11
    if function(*args) != 3:
        bad.append(name)
print("bad", bad)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "bad []"


def test_state_roundtrip_checked(pendulum: dict[int, dict[str, Path]]) -> None:
    """Serialized FMU states replay bit for bit; changed bytes are refused (the checksum)."""
    fmu = Logged(pendulum[3]["observer"])
    fmu.fmu.enterInitializationMode(startTime=0.0)
    fmu.fmu.exitInitializationMode()
    fmu.fmu.setFloat64([fmu.vr["y"]], [0.1, -0.2])
    fmu.fmu.doStep(0.0, 1e-3)
    state = fmu.fmu.getFMUState()
    data = fmu.fmu.serializeFMUState(state)
    fmu.fmu.doStep(1e-3, 1e-3)
    after = fmu.fmu.getFloat64([fmu.vr["x_hat"]], 4)
    fmu.fmu.setFMUState(fmu.fmu.deserializeFMUState(data))
    fmu.fmu.doStep(1e-3, 1e-3)
    assert fmu.fmu.getFloat64([fmu.vr["x_hat"]], 4) == after
    changed = bytearray(data)
    changed[100] ^= 1
    buffer = (ctypes.c_uint8 * len(changed)).from_buffer(changed)
    assert fmu.status("fmi3DeserializeFMUState", buffer, len(changed),
                      ctypes.byref(ctypes.c_void_p())) == 3
    assert "checksum" in fmu.messages[-1]


def test_fmi3_layout_of_variables() -> None:
    """arrays() groups the scalar variables of a kind's declaration."""
    from fhobs.build import fmu_options
    from fhobs.design.observer import paper_gains
    from fhobs.fmu.kinds import KINDS as ALL

    design = paper_gains()
    variables = _variables(ALL["observer"], design, fmu_options(design, ("observer",)))
    shapes = {a.name: a.shape for a in fmi3.arrays(variables)}
    assert shapes["P_bar"] == (6, 6) and shapes["x_hat"] == (4,) and shapes["nu"] == ()
