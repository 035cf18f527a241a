"""SSP export: the exported system runs in fmpy's SSP simulator and in libcosim like the harness.

The exported system is the *lowered* one (connection gains carried as gain-block FMUs, see
harness.ssp), so the harness runs ``lower_gains(spec)`` for the comparison. fmpy's simulator
holds connected inputs at 0 during the first step; the harness reproduces that with
``first_inputs="zero"``.
"""

from __future__ import annotations

import zipfile
from dataclasses import replace
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from fhobs.paper import K_PAPER
from fmpy.ssp.ssd import read_ssd
from third_party import run_fmpy_ssp, run_libcosim
from vendor_plant import SYSTEM, build_vendor_plant

from harness.master import run_system
from harness.ssp import export_ssp, lower_gains
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
