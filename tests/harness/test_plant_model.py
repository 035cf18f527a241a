"""``harness plant`` against the spec's ``[plant_model]``: the user's FMU or SSP run through its
Co-Simulation interface in deviation coordinates, checked against the same loop run with the
generated ``plant.fmu`` of the same A, B, C, E, the master's noise and the refusals."""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fhobs.build import build_fmus
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import DisturbanceSpec, load_spec
from me_fmus import DC_MOTOR_BOUND, dc_motor_matrices, dc_motor_ssp, linear_fmu

from harness import master
from harness.cli import main
from harness.master import run_system
from harness.own_plant import own_plant_system
from harness.plant_model import (
    DEVIATION,
    model_ports,
    operating_point,
    plant_model_system,
)
from harness.system import ConnectionSpec, FmuSpec, SystemSpec, resolve_system

MOTOR = dc_motor_matrices(**DC_MOTOR_BOUND)
"""The DC motor of tests/me_fmus.py: states i, phi, w; input U; output phiB; load M_load."""
EQUILIBRIUM = {"i": 1.0, "phi": 0.3, "U": 0.5, "M_load": -0.1}
"""An operating point of the motor off the origin: R i = U, k i + M_load = 0, w = 0."""
STEP, STOP = 1e-3, 1.0
SUBSTEP = min(1e-5, STEP / 100)
"""The generated FMUs' RK4 substep (tests/me_fmus.py)."""
STATE_SCALE = [1.0, 0.1, 1.0]
LOAD = {"shape": "step", "size": [0.01], "start": 0.6}


def _matrix(a: np.ndarray) -> str:
    return "[" + ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in a) + "]"


def _spec_text(model: str, states: list[str], *, start: dict | None = None,
               system: str | None = None, noise: bool = False, matrices: dict = MOTOR,
               names: bool = True) -> str:
    start_text = ", ".join(f'"{k}" = {v!r}' for k, v in (start or {}).items())
    lines = ['name = "motor"', *(f"{k} = {_matrix(matrices[k])}" for k in "ABCE"),
             "[observer]", "settling_time = 0.5", f"state_scale = {STATE_SCALE}",
             "disturbance_order = 1",
             "[disturbance]", 'shape = "step"', "size = [0.01]", "start = 0.6"]
    if noise:
        lines += ["[noise]", "measurement_std = [1e-4]", f"sample_time = {STEP!r}",
                  "process_intensity = 1e-2", "disturbance_order = 1"]
    if names:
        lines += ["[signals]", 'states = ["i", "phi", "w"]',
                  'state_units = ["A", "rad", "rad/s"]']
    lines += ["[plant_model]", f'path = "{model}"', 'inputs = ["U"]', 'outputs = ["phiB"]',
              'unknown_inputs = ["M_load"]', f"states = {json.dumps(states)}",
              f"start = {{ {start_text} }}"]
    if system:
        lines.append(f'system = "{system}"')
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def motor(tmp_path_factory):
    """The motor as a generated ME+CS FMU, its spec (operating point off the origin), the
    design and the estimator and plant FMUs."""
    folder = tmp_path_factory.mktemp("motor")
    linear_fmu(folder / "motor.fmu", MOTOR["A"], MOTOR["B"], MOTOR["C"], E=MOTOR["E"],
               states=["i", "phi", "w"], inputs=["U"], outputs=["phiB"],
               unknown_inputs=["M_load"], state_units=["A", "rad", "rad/s"])
    path = folder / "motor.toml"
    path.write_text(_spec_text("motor.fmu", ["i", "phi", "w"], start=EQUILIBRIUM))
    spec = load_spec(path)
    design = design_for_spec(spec)
    fmus = build_fmus(design, folder / "fmus", kinds=("observer", "luenberger", "plant"),
                      x0=spec.state_scale, h=STEP)
    return folder, spec, design, fmus


def _errors(result, system: SystemSpec) -> dict[str, np.ndarray]:
    return {label: result.vector(ref) - result.vector(est)
            for label, (ref, est) in system.evaluation.errors.items()}


def test_operating_point_is_the_models_equilibrium(motor):
    """x_op, u_op, q_op, y_op from the start values, in the spec's state order."""
    _, spec, _, _ = motor
    point = operating_point(spec.plant_model)
    np.testing.assert_allclose(point.x, [1.0, 0.3, 0.0], atol=1e-14)
    np.testing.assert_allclose(point.u, [0.5]), np.testing.assert_allclose(point.q, [-0.1])
    np.testing.assert_allclose(point.y, [0.3])
    np.testing.assert_allclose(MOTOR["A"] @ point.x + MOTOR["B"] @ point.u
                               + MOTOR["E"] @ point.q, 0.0, atol=1e-12)


def test_linear_model_gives_the_generated_plants_errors(motor):
    """The model FMU in deviation coordinates about (x_op, u_op, q_op, y_op) != 0 and the
    generated plant.fmu (exact ZOH) in the same loop: the same estimator errors, to the
    model's RK4 accuracy. The RK4 error of a substep hs is ~ (hs rho)^5 / 120 of the state
    (rho the spectral radius of A), over T / hs substeps; the estimators pass a difference in
    y on with at most their gains' size over the plant's (|L| / rho), allowed in full."""
    folder, spec, design, fmus = motor
    disturbance = DisturbanceSpec("step", np.array([0.01]), start=0.6)
    ports = model_ports(spec.plant_model, folder)
    point = operating_point(spec.plant_model)
    system, initial = plant_model_system(design, fmus, ports, point, spec.state_scale, STOP,
                                         STEP, disturbance=disturbance)
    assert initial == "model"
    reference = own_plant_system(design, fmus, spec.state_scale, STOP, STEP,
                                 disturbance=disturbance)
    ours, theirs = (run_system(resolve_system(s), progress=False) for s in (system, reference))
    rho = float(np.max(np.abs(np.linalg.eigvals(MOTOR["A"]))))
    gains = max(float(np.linalg.norm(design.filtering.L)), float(np.linalg.norm(
        design.luenberger.L_lin)))
    size = float(np.max(np.abs(theirs.vector("plant.x"))))
    rk4 = STOP / SUBSTEP * (SUBSTEP * rho) ** 5 / 120.0 * size
    tolerance = rk4 * (1.0 + gains / rho) + 1e-12 * size
    np.testing.assert_allclose(ours.vector(DEVIATION), theirs.vector("plant.x"),
                               atol=rk4 + 1e-12 * size, rtol=0)
    mine, generated = _errors(ours, system), _errors(theirs, reference)
    assert set(mine) == set(generated) == {"homogeneous", "linear"}
    for label, error in mine.items():
        assert np.max(np.abs(error - generated[label])) <= tolerance, label
    # the homogeneous observer (with its disturbance model) removes the initial error; the
    # Luenberger observer keeps the load's offset
    assert np.max(np.abs(mine["homogeneous"][-1])) < 1e-2 * np.max(np.abs(mine["homogeneous"][0]))
    # the model's own variables are recorded as they are, x = x_op + deviation
    np.testing.assert_allclose(ours.vector("model.phi")[:, 0], 0.3 + ours.vector(DEVIATION)[:, 1],
                               atol=1e-15)


def test_states_without_start_values_start_the_estimators_off(motor, tmp_path):
    """A model whose state variables accept no start value (initial calculated): it starts
    at its own start (the origin), the estimators at z0 = -state_scale: the initial error is
    state_scale all the same, and the homogeneous observer removes it."""
    source = motor[0] / "motor.fmu"
    path = _edited(source, tmp_path / "calculated.fmu", rb'(causality="local" variability='
                   rb'"continuous") initial="exact"><Real start="0.0"', rb'\1 initial='
                   rb'"calculated"><Real')
    spec_path = tmp_path / "motor.toml"
    spec_path.write_text(_spec_text(path.name, ["i", "phi", "w"]))
    spec, design, fmus = load_spec(spec_path), motor[2], motor[3]
    ports = model_ports(spec.plant_model, tmp_path)
    assert not ports.settable
    system, initial = plant_model_system(design, fmus, ports, operating_point(spec.plant_model),
                                         spec.state_scale, 0.5, STEP)
    assert initial == "estimators"
    result = run_system(resolve_system(system), progress=False)
    errors = _errors(result, system)
    for error in errors.values():
        np.testing.assert_allclose(error[0], STATE_SCALE, rtol=0, atol=1e-15)
    assert np.max(np.abs(errors["homogeneous"][-1])) < 1e-2


def _receiver(path: Path) -> Path:
    """y1 = u1 (feedthrough; after a step from t_k its output is the input set at t_k)."""
    return linear_fmu(path, [[-1.0]], [[0.0]], [[0.0]], [[1.0]], name="receiver")


@pytest.mark.parametrize("loop", ["c", "python"])
def test_master_adds_the_seeded_noise_without_delay(tmp_path, monkeypatch, loop):
    """The value two receivers get from t_k to t_k+1 is the model's output at t_k minus the
    offset plus draw k of the noise block's generator (default_rng([seed, 0]) uniforms v, w,
    the Gaussian sqrt(-2 log((1 - v) / 2)) cos(pi w)) times the std: the same draw for both,
    no block and no step of delay; the C and Python loops alike."""
    if loop == "python":
        monkeypatch.setattr(master, "step_library", lambda: None)
    model = linear_fmu(tmp_path / "decay.fmu", [[-2.0]], [[0.0]], [[1.0]], x0=[1.0])
    receiver = _receiver(tmp_path / "receiver.fmu")
    std, offset, seed, steps = 0.05, 0.25, 7, 40
    fmus = {"model": FmuSpec("model", model, {"u1": 0.0}),
            "a": FmuSpec("a", receiver), "b": FmuSpec("b", receiver)}
    noisy = {"offset": np.array([offset]), "noise": np.array([std])}
    system = SystemSpec("noise", fmus, (ConnectionSpec("model.y1", "a.u1", **noisy),
                                        ConnectionSpec("model.y1", "b.u1", **noisy)),
                        0.01, steps * 0.01, record=("a.y1", "b.y1")).with_seed(seed)
    result = run_system(resolve_system(system), progress=False)
    v, w = np.random.default_rng([seed, 0]).uniform(-1.0, 1.0, (1024, 2))[:steps].T
    draws = np.sqrt(-2.0 * np.log(0.5 * (1.0 - v))) * np.cos(np.pi * w) * std
    y = result.signal("model.y1")
    for receiver_name in ("a", "b"):
        got = result.signal(f"{receiver_name}.y1")[1:]
        np.testing.assert_allclose(got, y[:-1] - offset + draws, rtol=0, atol=1e-15)
    np.testing.assert_allclose(y, np.exp(-2.0 * result.time), rtol=1e-9)


def test_description_file_reads_locals_offsets_biases_and_derived_signals(tmp_path):
    """The TOML keys: ``from`` a list of signals (a local state and an output), ``offset``,
    ``bias``, ``[run] noise_seed`` and ``[[derived]]``: the receiver gets
    ``gain @ (from - offset) + bias`` one step on, the derived signal is computed from the
    recorded rows."""
    linear_fmu(tmp_path / "decay.fmu", [[-2.0]], [[0.0]], [[3.0]], x0=[1.0])
    _receiver(tmp_path / "receiver.fmu")
    (tmp_path / "system.toml").write_text("\n".join([
        "[run]", "step = 0.01", "stop_time = 0.2", "noise_seed = 3",
        "[fmus.model]", 'path = "decay.fmu"', "start = { u1 = 0.0 }",
        "[fmus.r]", 'path = "receiver.fmu"',
        "[[connections]]", 'from = ["model.x1", "model.y1"]', 'to = "r.u1"',
        "gain = [[2.0, -1.0]]", "offset = [0.5, 0.25]", "bias = [4.0]",
        "[[derived]]", 'from = ["model.x1"]', 'to = "deviation.x"', "offset = [1.0]",
        "[evaluation.errors]", 'r = ["deviation.x", "r.y1"]', ""]))
    from harness.system import load_system

    spec = load_system(tmp_path / "system.toml")
    assert spec.noise_seed == 3 and spec.connections[0].sources == ("model.x1", "model.y1")
    result = run_system(resolve_system(spec), progress=False)
    x = np.exp(-2.0 * result.time)
    np.testing.assert_allclose(result.signal("r.y1")[1:],
                               2.0 * (x[:-1] - 0.5) - (3.0 * x[:-1] - 0.25) + 4.0, rtol=1e-9)
    np.testing.assert_allclose(result.vector("deviation.x")[:, 0], x - 1.0, atol=1e-9)


def test_noisy_spec_sends_the_measurement_std_to_every_estimator(motor):
    """With [noise]: each estimator's y connection carries measurement_std, offset y_op."""
    folder, spec, design, fmus = motor
    ports = model_ports(spec.plant_model, folder)
    point = operating_point(spec.plant_model)
    system, _ = plant_model_system(design, fmus, ports, point, spec.state_scale, STOP, STEP,
                                   measurement_std=np.array([1e-4]))
    to_y = [c for c in system.connections if c.target.endswith(".y")]
    assert sorted(c.target for c in to_y) == ["luenberger.y", "observer.y"]
    for c in to_y:
        assert c.noise.tolist() == [1e-4] and c.offset.tolist() == [0.3]


def test_plant_command_names_the_states_and_records_the_model(motor, tmp_path, capsys):
    """The CLI run: the per-state table and summary.json name each state from the spec, the
    model, its operating point and how the initial error was made; the figures written."""
    folder = motor[0]
    out = tmp_path / "run"
    code = main(["plant", str(folder / "motor.toml"), "--out", str(out), "--stop-time", "0.3"])
    text = capsys.readouterr().out
    assert code == 0, text
    summary = json.loads((out / "summary.json").read_text())
    model = summary["plant_model"]
    assert model["states"] == ["i [A]", "phi [rad]", "w [rad/s]"]
    assert model["path"] == str(folder / "motor.fmu") and model["system"] is None
    assert model["operating_point"]["y"] == pytest.approx([0.3])
    assert model["initial_error"].startswith("the model's states started at x_op")
    assert re.search(r"RMS error, steady\s+i \[A\]\s+phi \[rad\]\s+w \[rad/s\]", text)
    assert len(summary["homogeneous"]["x_rms_states"]) == 3
    for name in ("states.png", "errors.png", "disturbance.png", "results.csv"):
        assert (out / name).stat().st_size > 1000, name


@pytest.mark.slow  # builds the native FMUs (cached after the first time)
def test_native_estimators_give_the_same_run(motor, tmp_path):
    """``--native``: the native estimator FMUs against the same model give results.csv's
    columns of the pythonfmu run to BUILDS_RTOL (C and numpy round differently)."""
    from results_csv import BUILDS_RTOL, column_differences

    common = ["plant", str(motor[0] / "motor.toml"), "--stop-time", "0.3", "--no-plots"]
    assert main([*common, "--out", str(tmp_path / "python")]) == 0
    assert main([*common, "--out", str(tmp_path / "native"), "--native"]) == 0
    assert (tmp_path / "native" / "fmus" / "native" / "observer.fmu").is_file()
    assert column_differences(tmp_path / "native" / "results.csv",
                              tmp_path / "python" / "results.csv").max() <= BUILDS_RTOL


def test_two_fmu_ssp_runs_its_components_coupled(tmp_path, capsys):
    """tests/me_fmus.py's motor SSP (electrical, mechanical and gear FMUs in DC-Motor.SuT,
    bindings in the SSD and an .ssv), linearised by ``harness linearize`` and run: the
    components extracted into fmus/model, the estimators converge, and against the generated
    plant.fmu of the spec's matrices the states agree to the Jacobi coupling's accuracy (each
    FMU sees the others' outputs one step late: a relative error of ~ step x rho per unit
    time, allowed 10 times; measured: 2.5 % of the current's peak, 0.3 % of the speed's,
    0.09 % of the angle's)."""
    dc_motor_ssp(tmp_path / "motor.ssp")
    spec_path = tmp_path / "motor.toml"
    assert main(["linearize", str(tmp_path / "motor.ssp"), "--system", "DC-Motor.SuT",
                 "--input", "U", "--unknown-input", "M_load", "--output", "phiB",
                 "--out", str(spec_path)]) == 0
    text = spec_path.read_text().replace("[signals]", "\n".join(
        ["[disturbance]", 'shape = "step"', "size = [0.01]", "start = 0.15", "[signals]"]))
    spec_path.write_text(text)
    step, stop = 1e-4, 0.3
    out = tmp_path / "run"
    code = main(["plant", str(spec_path), "--out", str(out), "--step", str(step),
                 "--stop-time", str(stop), "--no-plots"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert sorted(p.name for p in (out / "fmus" / "model").glob("*.fmu")) == [
        "edrive.fmu", "emachine.fmu", "gear.fmu"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["plant_model"]["system"] == "DC-Motor.SuT"
    spec = load_spec(spec_path)
    design = design_for_spec(spec)
    fmus = build_fmus(design, tmp_path / "reference", kinds=("observer", "plant"),
                      x0=spec.state_scale, h=step)
    reference = own_plant_system(design, fmus, spec.state_scale, stop, step,
                                 disturbance=spec.disturbance)
    theirs = run_system(resolve_system(reference), progress=False)
    names, values = _csv(out / "results.csv")
    x = values[:, [names.index(f"{DEVIATION}[{i + 1}]") for i in range(3)]]
    rho = float(np.max(np.abs(np.linalg.eigvals(spec.A))))
    scale = np.max(np.abs(theirs.vector("plant.x")), axis=0)
    assert np.all(np.max(np.abs(x - theirs.vector("plant.x")), axis=0)
                  <= 10 * step * rho * stop * scale)
    assert summary["homogeneous"]["x_rms_steady"] < 1e-2 * np.linalg.norm(spec.state_scale)


def _csv(path: Path) -> tuple[list[str], np.ndarray]:
    from results_csv import read_results

    return read_results(path)


def _edited(source: Path, target: Path, pattern: bytes, replacement: bytes) -> Path:
    """``source`` with ``pattern`` replaced in its modelDescription.xml (it must occur)."""
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                data, count = re.subn(pattern, replacement, data)
                assert count, pattern
            zout.writestr(item, data)
    return target


@pytest.mark.parametrize("case", ["model_exchange_only", "unknown_state", "missing_model"])
def test_refusals_are_one_paragraph_and_write_nothing(motor, tmp_path, capsys, case):
    """A Model-Exchange-only FMU, a state the model does not have (the closest named), a
    model file that is not there: exit 2, one paragraph, no results folder content."""
    source = motor[0] / "motor.fmu"
    model, states = "motor.fmu", ["i", "phi", "w"]
    if case == "model_exchange_only":
        model = _edited(source, tmp_path / "me_only.fmu", rb"<CoSimulation[^>]*/>", b"").name
    elif case == "unknown_state":
        (tmp_path / model).write_bytes(source.read_bytes())
        states = ["i", "phii", "w"]
    else:
        model = "nowhere.fmu"
    spec = tmp_path / "spec.toml"
    spec.write_text(_spec_text(model, states))
    out = tmp_path / "out"
    code = main(["plant", str(spec), "--out", str(out), "--stop-time", "0.1"])
    captured = capsys.readouterr()
    message = captured.err.strip()
    assert code == 2 and "Traceback" not in message and "\n" not in message, message
    expected = {"model_exchange_only": "Model-Exchange-only FMU",
                "unknown_state": "'phii'", "missing_model": "nowhere.fmu"}[case]
    assert expected in message
    if case == "unknown_state":
        assert "closest: phi" in message
    assert not out.exists() or not any(out.rglob("*"))
