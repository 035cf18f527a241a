"""The run's tolerance: ``[run] tolerance``, passed by the master to every FMU's
``fmi2SetupExperiment``, written into an exported SSP's OMSimulator annotation, and ``harness
plant``'s default of 1e-10 for a ``[plant_model]``; the command line's refusals of a bad
tolerance or seed."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from fmpy.fmi2 import FMU2Slave
from me_fmus import DC_MOTOR_BOUND, dc_motor_matrices, linear_fmu

from harness.cli import main
from harness.master import run_system
from harness.ssp import NS, export_ssp
from harness.system import (
    ConnectionSpec,
    DescriptionError,
    FmuSpec,
    SystemSpec,
    load_system,
    resolve_system,
)


@pytest.fixture
def tolerances(monkeypatch) -> list:
    """The ``tolerance`` of every ``fmi2SetupExperiment`` fmpy makes (None: undefined)."""
    seen = []
    original = FMU2Slave.setupExperiment

    def recording(self, tolerance=None, startTime=0.0, stopTime=None):  # noqa: N803 - fmpy's
        seen.append(tolerance)
        return original(self, tolerance=tolerance, startTime=startTime, stopTime=stopTime)

    monkeypatch.setattr(FMU2Slave, "setupExperiment", recording)
    return seen


def _blocks(tolerance: float | None) -> SystemSpec:
    """A sine block into a gain block, 10 steps."""
    fmus = {"sine": FmuSpec("sine", None, {"amplitude[1]": 1.0, "omega[1]": 3.0},
                            ("sine", (1,))),
            "gain": FmuSpec("gain", None, {"K[1,1]": 2.0}, ("gain", (1, 1)))}
    return SystemSpec("blocks", fmus, (ConnectionSpec("sine.y[1]", "gain.u[1]"),), 0.01, 0.1,
                      record=("gain.y",), tolerance=tolerance)


def _write(path: Path, run: str) -> Path:
    path.write_text(f'[run]\n{run}\n[fmus.q]\nblock = "sine"\noutputs = 1\n')
    return path


def test_run_table_takes_a_tolerance_in_zero_one(tmp_path):
    assert load_system(_write(tmp_path / "a.toml", "tolerance = 1e-8")).tolerance == 1e-8
    assert load_system(_write(tmp_path / "b.toml", "step = 0.1")).tolerance is None
    for value in ("0", "1", "-1e-6", '"small"', "nan"):
        with pytest.raises(DescriptionError, match=r"run\.tolerance = .* in \(0, 1\)"):
            load_system(_write(tmp_path / "c.toml", f"tolerance = {value}"))


@pytest.mark.parametrize("tolerance", [1e-9, None])
def test_master_passes_the_tolerance_to_every_fmu(tmp_path, tolerances, tolerance):
    from harness.system import build_blocks

    spec = build_blocks(_blocks(tolerance), tmp_path / "blocks", native=True)
    result = run_system(resolve_system(spec), progress=False)
    assert tolerances == [tolerance, tolerance]
    t = result.time
    np.testing.assert_allclose(result.signal("gain.y[1]")[1:], 2.0 * np.sin(3.0 * t[:-1]),
                               rtol=0, atol=1e-15)


def _fixed_step_master(ssp: Path) -> ET.Element:
    with zipfile.ZipFile(ssp) as zf:
        root = ET.fromstring(zf.read("SystemStructure.ssd"))
    found = root.findall(".//oms:FixedStepMaster", NS)
    assert len(found) == 1
    return found[0]


def test_ssp_carries_the_tolerance_for_omsimulator(tmp_path):
    master = _fixed_step_master(export_ssp(_blocks(1e-7), tmp_path / "a.ssp", tmp_path / "b"))
    assert float(master.get("relativeTolerance")) == 1e-7
    assert float(master.get("absoluteTolerance")) == 1e-7
    assert float(master.get("stepSize")) == 0.01
    master = _fixed_step_master(export_ssp(_blocks(None), tmp_path / "c.ssp", tmp_path / "b"))
    assert master.get("relativeTolerance") is None and master.get("absoluteTolerance") is None


def _motor_spec(folder: Path) -> Path:
    """A [plant_model] spec of the DC motor FMU of tests/me_fmus.py (its origin)."""
    m = dc_motor_matrices(**DC_MOTOR_BOUND)
    linear_fmu(folder / "motor.fmu", m["A"], m["B"], m["C"], E=m["E"],
               states=["i", "phi", "w"], inputs=["U"], outputs=["phiB"],
               unknown_inputs=["M_load"])

    def matrix(a: np.ndarray) -> str:
        return json.dumps(np.asarray(a, dtype=float).tolist())

    path = folder / "motor.toml"
    path.write_text("\n".join([
        'name = "motor"', *(f"{k} = {matrix(m[k])}" for k in "ABCE"),
        "[observer]", "settling_time = 0.5", "state_scale = [1.0, 0.1, 1.0]",
        "[plant_model]", 'path = "motor.fmu"', 'inputs = ["U"]', 'outputs = ["phiB"]',
        'unknown_inputs = ["M_load"]', 'states = ["i", "phi", "w"]', ""]))
    return path


def test_plant_model_runs_at_1e10_by_default(tmp_path, tolerances, capsys):
    """harness plant with a [plant_model]: every FMU of the run gets 1e-10, the summary says
    so, and the exported SSP carries it."""
    spec, ssp, out = _motor_spec(tmp_path), tmp_path / "motor.ssp", tmp_path / "out"
    code = main(["plant", str(spec), "--out", str(out), "--no-plots", "--stop-time", "0.02",
                 "--export-ssp", str(ssp), "--allow-python", "--block-cache",
                 str(tmp_path / "blocks")])
    assert code == 0, capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["tolerance"] == 1e-10
    assert len(tolerances) >= 2 and set(tolerances) == {1e-10}
    assert float(_fixed_step_master(ssp).get("relativeTolerance")) == 1e-10


@pytest.mark.parametrize("argv, message", [
    (["plant", "SPEC", "--tolerance", "0"], "--tolerance = 0.0 must be a number in (0, 1)"),
    (["plant", "SPEC", "--tolerance", "2"], "--tolerance = 2.0 must be a number in (0, 1)"),
    (["plant", "SPEC", "--seed", "-1"], "--seed = -1 must be an integer in 0..2147483647"),
    (["run", "pendulum_noisy", "--seed", "-3"], "--seed = -3 must be an integer in 0..2147483647"),
    (["run", "pendulum_noisy", "--seed", str(2**31)],
     f"--seed = {2**31} must be an integer in 0..2147483647"),
])
def test_bad_tolerance_or_seed_is_one_sentence_exit_2(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    code = main([a.replace("SPEC", str(tmp_path / "missing.toml")) for a in argv]
                + ["--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith(f"error: {message}") and err.count("\n") == 1
    assert not out.exists()
