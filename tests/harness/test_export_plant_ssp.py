"""Connections with offsets, biases, several sources and the master's noise lowered to block
FMUs (harness.ssp.lower_gains), and ``harness plant --export-ssp``."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
from me_fmus import linear_fmu

from harness.blocks.build import is_pythonfmu
from harness.cli import main
from harness.master import Master, run_system
from harness.ssp import exported_system
from harness.system import ConnectionSpec, FmuSpec, SystemSpec, resolve_system

STEP, STEPS, SEED = 0.01, 1100, 11
"""1100 steps: the draws cross the noise generator's block of 1024."""


def _system(tmp_path: Path) -> SystemSpec:
    """A decaying model (an output and a local state) into two receivers (y1 = u1, direct
    feedthrough): one through a connection with every feature (two sources, gain, offset,
    bias, noise on one source), one with the noise alone."""
    model = linear_fmu(tmp_path / "decay.fmu", [[-2.0]], [[0.0]], [[3.0]], x0=[1.0])
    receiver = linear_fmu(tmp_path / "receiver.fmu", [[-1.0]], [[0.0]], [[0.0]], [[1.0]],
                          name="receiver")
    fmus = {"model": FmuSpec("model", model, {"u1": 0.0}),
            "a": FmuSpec("a", receiver), "b": FmuSpec("b", receiver)}
    every = ConnectionSpec(("model.x1", "model.y1"), "a.u1", np.array([[2.0, -1.5]]),
                           np.array([0.5, 0.25]), np.array([4.0]), np.array([0.0, 0.05]))
    noisy = ConnectionSpec("model.y1", "b.u1", offset=np.array([0.25]), noise=np.array([0.05]))
    return SystemSpec("lowered", fmus, (every, noisy), STEP, STEPS * STEP,
                      record=("a.y1", "b.y1")).with_seed(SEED)


@pytest.mark.slow
@pytest.mark.parametrize("native", [True, False])
def test_noise_block_draws_the_masters_draws(tmp_path, native):
    """The lowered system's noise block reads out at t_k exactly the draw the master adds over
    the step from t_k (the same seed, generator and column), native and pythonfmu builds."""
    spec = _system(tmp_path)
    master = Master(resolve_system(spec))
    assert master.noise_sources == {"model.y1": 0.05}
    draws = master.connections.draw(SEED, 0, STEPS)
    lowered = exported_system(spec, tmp_path / "blocks", native_blocks=native)
    assert is_pythonfmu(lowered.fmus["noise"].path) != native
    result = run_system(resolve_system(lowered), progress=False)
    assert np.array_equal(result.signal("noise.y[1]")[:-1], draws[:, 0])
    assert np.std(draws) == pytest.approx(0.05, rel=0.1)


@pytest.mark.slow
def test_lowered_connections_equal_the_masters_with_one_step_per_block(tmp_path):
    """The harness (a Jacobi engine) on the lowered system: each receiver gets the master's
    value late by one step per feedthrough block on its path (shift, gain, bias: 3; shift: 1),
    the same value otherwise; the model itself is unchanged."""
    spec = _system(tmp_path)
    original = run_system(resolve_system(spec), progress=False)
    lowered_spec = exported_system(spec, tmp_path / "blocks", native_blocks=True)
    assert {"shift_1", "gain_1", "bias_1", "constant_1", "shift_2", "constant_2",
            "noise"} <= set(lowered_spec.fmus)
    assert all(isinstance(c.source, str) for c in lowered_spec.connections)
    lowered = run_system(resolve_system(lowered_spec), progress=False)
    np.testing.assert_array_equal(lowered.signal("model.y1"), original.signal("model.y1"))
    for receiver, lag in (("a.y1", 3), ("b.y1", 1)):
        want = original.signal(receiver)[1:STEPS + 1 - lag]
        got = lowered.signal(receiver)[1 + lag:]
        np.testing.assert_allclose(got, want, rtol=1e-15, atol=1e-15)
    # the independent value of receiver b: y(t_k) - offset + the master's draw k
    y, draws = original.signal("model.y1"), Master(resolve_system(spec)).connections.draw(
        SEED, 0, STEPS)[:, 0]
    np.testing.assert_allclose(original.signal("b.y1")[1:], y[:-1] - 0.25 + draws,
                               rtol=0, atol=1e-15)


def test_plant_export_ssp_is_refused_without_native(tmp_path, capsys):
    """--export-ssp without --native (pythonfmu estimators) is refused before anything is
    built, with the way out named; nothing written."""
    out, ssp = tmp_path / "out", tmp_path / "plant.ssp"
    spec = Path(__file__).parents[2] / "fmu_src/fhobs/examples/triple_integrator.toml"
    code = main(["plant", str(spec), "--out", str(out), "--export-ssp", str(ssp)])
    message = capsys.readouterr().err
    assert code == 2 and "--native" in message and "--allow-python" in message
    assert "Traceback" not in message and not ssp.exists()
    assert not out.exists() or not any(out.rglob("*.fmu"))


def test_plant_export_ssp_native_needs_no_python(tmp_path, capsys):
    """harness plant --native --export-ssp: the SSP holds the run's FMUs, none of them a
    pythonfmu FMU, the plant's start values as the run sets them, and the run goes on."""
    out, ssp = tmp_path / "out", tmp_path / "plant.ssp"
    spec = Path(__file__).parents[2] / "fmu_src/fhobs/examples/triple_integrator.toml"
    code = main(["plant", str(spec), "--out", str(out), "--native", "--no-plots",
                 "--stop-time", "0.05", "--export-ssp", str(ssp), "--block-cache",
                 str(tmp_path / "blocks")])
    assert code == 0, capsys.readouterr().err
    assert (out / "summary.json").is_file()
    with zipfile.ZipFile(ssp) as zf:
        fmus = [name for name in zf.namelist() if name.endswith(".fmu")]
        ssd = zf.read("SystemStructure.ssd").decode()
        assert fmus and "plant" in ssd and 'name="x0[1]"' in ssd
        for name in fmus:
            path = tmp_path / Path(name).name
            path.write_bytes(zf.read(name))
            assert not is_pythonfmu(path), name
