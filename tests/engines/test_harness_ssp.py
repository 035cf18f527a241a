"""SSP export: the exported system runs in fmpy's SSP simulator and in libcosim like the harness.

The exported system is the *lowered* one (connection gains carried as gain-block FMUs, see
harness.ssp), so the harness runs ``lower_gains(spec)`` (``exported_system(spec)``) for the
comparison. fmpy's simulator holds connected inputs at 0 during the first step; the harness
reproduces that with ``first_inputs="zero"``. With native FMUs the SSP is native throughout
(native blocks) and the paper's nominal scenario gives the harness's figures in both engines.
"""

from __future__ import annotations

import subprocess
import zipfile
from dataclasses import replace
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from fhobs.paper import K_PAPER
from fmpy.ssp.ssd import read_ssd
from third_party import run_fmpy_ssp, run_libcosim
from vendor_plant import SYSTEM, build_vendor_plant

from harness.cli import load_scenario
from harness.master import CoSimResult, run_system
from harness.results import error_figures
from harness.ssp import export_ssp, exported_system, is_pythonfmu, lower_gains
from harness.system import build_blocks, load_system, resolve_system

STATE = [f"plant.state[{i}]" for i in range(1, 5)]
NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "oms": "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd",
}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    d = tmp_path_factory.mktemp("ssp")
    cache = d / "blocks"
    (d / "system.toml").write_text(SYSTEM.format(plant=build_vendor_plant(d)))
    spec = build_blocks(load_system(d / "system.toml"), cache)
    return spec, export_ssp(spec, d / "system.ssp", block_cache=cache), cache


def test_ssp_is_schema_valid_and_carries_everything(exported):
    spec, ssp, _ = exported
    names = zipfile.ZipFile(ssp).namelist()
    assert "SystemStructure.ssd" in names
    ssd = read_ssd(str(ssp))  # validates against the SSP 1.0 schema
    components = {c.name: c for c in ssd.system.elements}
    assert set(components) == {"plant", "wave", "gain_1"}
    assert all(c.source in names for c in components.values())
    bound = {p.name: float(p.value) for p in
             components["gain_1"].parameterBindings[0].parameterValues[0].parameters}
    assert [bound[f"K[1,{j}]"] for j in range(1, 5)] == K_PAPER[0].tolist()
    assert len(ssd.system.connections) == 4 + 1 + 1


def test_ssp_carries_omsimulator_fixed_step_master(exported):
    """OMSimulator loads an SSP only with its annotation of the top-level system."""
    spec, ssp, _ = exported
    root = ET.fromstring(zipfile.ZipFile(ssp).read("SystemStructure.ssd"))
    system = root.find("ssd:System", NS)
    notes = system.findall("ssd:Annotations/ssc:Annotation[@type='org.openmodelica']", NS)
    assert len(notes) == 1
    master = notes[0].find("oms:Annotations/oms:SimulationInformation/oms:FixedStepMaster", NS)
    assert master is not None and float(master.get("stepSize")) == spec.step


def _state(result, names=STATE):
    return np.column_stack([result.signal(n) for n in names])


def test_libcosim_equals_harness(exported):
    spec, ssp, cache = exported
    harness = run_system(resolve_system(build_blocks(lower_gains(spec), cache)), progress=False)
    engine = run_libcosim(ssp, spec.step, spec.stop_time, STATE)
    np.testing.assert_allclose(engine.time, harness.time[1:], rtol=0, atol=1e-12)
    assert np.max(np.abs(_state(engine) - harness.vector("plant.state")[1:])) < 1e-12


def test_fmpy_ssp_equals_harness(exported):
    spec, ssp, cache = exported
    lowered = resolve_system(build_blocks(lower_gains(spec), cache))
    harness = run_system(lowered, progress=False, first_inputs="zero")
    engine = run_fmpy_ssp(ssp, spec.step, spec.stop_time)
    assert len(engine.time) == harness.steps
    assert np.max(np.abs(_state(engine) - harness.vector("plant.state")[1:])) < 1e-12
    # and the zero first inputs matter: the default convention differs
    default = run_system(lowered, progress=False)
    assert np.max(np.abs(_state(engine) - default.vector("plant.state")[1:])) > 1e-6


def test_lowered_gain_block_lags_one_step(exported):
    """The gain block's output at t_k is K x_{k-1} (K x_0 needs one exchange to get there)."""
    spec, _, cache = exported
    lowered = replace(build_blocks(lower_gains(spec), cache), record=("gain_1.y[1]",))
    result = run_system(resolve_system(lowered), stop_time=0.01, progress=False)
    u, x = result.signal("gain_1.y[1]"), result.vector("plant.state")
    assert u[0] == 0.0
    np.testing.assert_allclose(u[1:], x[:-1] @ K_PAPER[0], rtol=1e-13, atol=1e-13)
    assert np.ptp(u[1:]) > 1e-3


def test_export_rejects_name_clash(exported, tmp_path):
    spec, _, cache = exported
    clash = replace(spec, fmus={**spec.fmus, "gain_1": spec.fmus["wave"]})
    with pytest.raises(ValueError, match="gain_1"):
        export_ssp(clash, tmp_path / "x.ssp", block_cache=cache)


# -- the paper's nominal scenario with native FMUs: an SSP without Python ----------------------
@pytest.fixture(scope="module")
def native_nominal(tmp_path_factory, native_fmus):
    """The nominal scenario on the native FMUs of our pendulum design (the shared build: the
    design of ``build_paper_fmus(design="spec")``; the scenario sets the plant's x0 and noise)
    and its exported SSP."""
    d = tmp_path_factory.mktemp("native_ssp")
    cache = d / "blocks"
    spec = load_scenario("pendulum_nominal", native_fmus["observer"].parent, cache)
    return spec, export_ssp(spec, d / "nominal.ssp", block_cache=cache), cache


def _nominal_figures(spec, result, names) -> dict[str, dict[str, float]]:
    """The scenario's figures from the rows t_1 .. t_N of a harness or engine result."""
    values = np.column_stack([result.signal(n) for n in names])
    time = np.asarray(result.time)
    if isinstance(result, CoSimResult):
        time, values = time[1:], values[1:]
    return error_figures(CoSimResult(time, tuple(names), values, len(time), 0.0), spec.evaluation)


ROUND_OFF = 2e-12
"""Absolute tolerance of the Luenberger and Kalman figures: the co-simulation's round-off (an
engine that passes its clock's t_k+1 - t_k as the step, as libcosim does, changes the last bits
of the native FMUs' steps). The homogeneous observer's figures are round-off themselves (its
error is zero after its finite settling time): they are only bounded, by 1e-11."""


def _mismatch(figures, reference, rtol) -> float:
    """max |a - b| / (rtol |b| + ROUND_OFF) over the Luenberger and Kalman figures: at most 1
    when they agree."""
    return max(abs(figures[e][k] - reference[e][k]) / (rtol * abs(reference[e][k]) + ROUND_OFF)
               for e in ("linear", "kalman") for k in reference[e])


def _differences(figures, reference) -> str:
    """Per observer, the largest relative and absolute difference of its figures."""
    return ", ".join(
        f"{e} {max(abs(figures[e][k] / reference[e][k] - 1) for k in reference[e]):.1e} rel "
        f"{max(abs(figures[e][k] - reference[e][k]) for k in reference[e]):.1e} abs"
        for e in reference)


@pytest.mark.slow  # the native export, ~2.7 s; test_native_blocks and test_native_fmu ldd theirs
def test_native_ssp_needs_no_python(native_nominal, tmp_path):
    """Every FMU of the SSP, the gain blocks included, is native: no libpython in any binary."""
    spec, ssp, _ = native_nominal
    with zipfile.ZipFile(ssp) as archive:
        fmus = [Path(archive.extract(n, tmp_path)) for n in archive.namelist()
                if n.endswith(".fmu")]
    components = {c.name for c in read_ssd(str(ssp)).system.elements}
    assert components == {"plant", "observer", "linear", "kalman",
                          "gain_4", "gain_5", "gain_6", "gain_7"}
    assert len(fmus) == 5  # the four gains are one FMU file
    for fmu in fmus:
        assert not is_pythonfmu(fmu), fmu.name
        with zipfile.ZipFile(fmu) as archive:
            (name,) = [n for n in archive.namelist() if n.startswith("binaries/linux64/")]
            binary = archive.extract(name, tmp_path / fmu.stem)
        linked = subprocess.run(["ldd", binary], capture_output=True, text=True, check=True)
        assert "python" not in linked.stdout.lower(), fmu.name


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["libcosim", "fmpy"])
def test_native_nominal_ssp_gives_the_harness_figures(native_nominal, engine):
    """The observers' errors at t = 1.5 and over [1, 3] (60 000 steps) in each engine are the
    harness's on the exported system: the Luenberger and Kalman figures to 1e-9 relative or
    :data:`ROUND_OFF` absolute, the homogeneous observer's below 1e-11 in all. Against the
    harness on the scenario itself (gains applied by the master, without the gain blocks'
    one-step lag: ``harness paper --native``) libcosim's figures agree as well, to 1e-8 relative
    (the observers' errors do not depend on u, which plant and observers share); fmpy's zero
    inputs during the first step change the initial errors, so it is compared with the harness
    run with ``first_inputs="zero"`` only."""
    spec, ssp, cache = native_nominal
    direct = run_system(resolve_system(spec), progress=False)
    names = list(direct.names)
    system = resolve_system(exported_system(spec, cache))
    if engine == "libcosim":
        harness = run_system(system, progress=False)
        result = run_libcosim(ssp, spec.step, spec.stop_time, names)
    else:
        harness = run_system(system, progress=False, first_inputs="zero")
        result = run_fmpy_ssp(ssp, spec.step, spec.stop_time)
    figures = _nominal_figures(spec, result, names)
    expected = _nominal_figures(spec, harness, names)
    unlowered = _nominal_figures(spec, direct, names)
    print(f"\n{engine}: {figures}\nharness (exported system): {expected}\n"
          f"harness (scenario): {unlowered}\nagainst the exported system: "
          f"{_differences(figures, expected)}\nagainst the scenario: "
          f"{_differences(figures, unlowered)}")
    assert figures["linear"]["error_at_1_5"] > 1e-3 and figures["kalman"]["error_at_1_5"] > 1e-6
    for run in (figures, expected, unlowered):
        assert max(run["homogeneous"].values()) < 1e-11
    assert _mismatch(figures, expected, 1e-9) <= 1
    if engine == "libcosim":
        assert _mismatch(figures, unlowered, 1e-8) <= 1
