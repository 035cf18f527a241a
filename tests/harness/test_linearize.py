"""``python -m harness linearize``: plant FMUs and an SSP linearised against matrices derived
by hand (tests/me_fmus.py generates and compiles the FMUs), the refusals, and the written
spec read back and designed."""

import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from harness.cli import main
from harness.linearize import linearize

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from me_fmus import (  # noqa: E402
    DC_MOTOR_BOUND,
    DC_MOTOR_DEFAULTS,
    Variable,
    dc_motor_matrices,
    dc_motor_ssp,
    linear_fmu,
    me_fmu,
    vanderpol_fmu,
    vanderpol_jacobian,
)

FREQUENCIES = np.array([0.1j, 1.0j, 3.0 + 10.0j, 100.0j, 1e3j])
"""Where the transfer functions are compared (s, rad/s; none a pole of the plants)."""


def relative(a, b):
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b)))


def transfer(A, B, C, s):
    """C (sI - A)^-1 B at each s: invariant under any change of state coordinates."""
    n = A.shape[0]
    return np.array([C @ np.linalg.solve(si * np.eye(n) - A, B) for si in s])


@pytest.fixture(scope="module")
def plant():
    """A random stable 3-state plant (seed 4), two inputs, two outputs, one unknown input."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(3, 3)) - 3.0 * np.eye(3)
    return {"A": A, "B": rng.normal(size=(3, 2)), "C": rng.normal(size=(2, 3)),
            "E": rng.normal(size=(3, 1))}


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, plant):
    folder = tmp_path_factory.mktemp("linearize")
    names = {"states": ["pos", "vel", "cur"], "inputs": ["u_a", "u_b"],
             "outputs": ["y_a", "y_b"], "unknown_inputs": ["load"],
             "state_units": ["m", "m/s", "A"], "input_units": ["V", "V"],
             "output_units": ["m", "A"], "unknown_input_units": ["N"]}
    return {
        "directional": linear_fmu(folder / "lin_dd.fmu", plant["A"], plant["B"], plant["C"],
                                  E=plant["E"], nominals=[0.5, 2.0, 10.0], **names),
        "differences": linear_fmu(folder / "lin_fd.fmu", plant["A"], plant["B"], plant["C"],
                                  E=plant["E"], directional=False, name="linear_fd",
                                  nominals=[0.5, 2.0, 10.0], **names),
        "feedthrough": linear_fmu(folder / "lin_d.fmu", plant["A"], plant["B"], plant["C"],
                                  E=plant["E"], D=[[0.0, 0.0], [0.0, 0.3]], **names),
        "cosim": linear_fmu(folder / "lin_cs.fmu", plant["A"], plant["B"], plant["C"],
                            E=plant["E"], model_exchange=False, name="linear_cs", **names),
        "vanderpol": vanderpol_fmu(folder / "vdp.fmu"),
        "vanderpol_fd": vanderpol_fmu(folder / "vdp_fd.fmu", directional=False),
        "ssp": dc_motor_ssp(folder / "dcmotor.ssp"),
        "ssp_fd": dc_motor_ssp(folder / "dcmotor_fd.ssp", directional=False),
        "ssp_rpm": dc_motor_ssp(folder / "dcmotor_rpm.ssp", w_unit="rpm"),
    }


@pytest.mark.parametrize("kind, tolerance", [("directional", 1e-8), ("differences", 1e-6)])
def test_linear_fmu(fmus, plant, kind, tolerance):
    lin = linearize(fmus[kind], ["u_a", "u_b"], ["y_a", "y_b"], ["load"])
    assert lin.method == {"directional": "directional derivatives",
                          "differences": "central differences"}[kind]
    for name in "ABCE":
        assert relative(getattr(lin, name), plant[name]) <= tolerance, name
    assert relative(transfer(lin.A, lin.B, lin.C, FREQUENCIES),
                    transfer(plant["A"], plant["B"], plant["C"], FREQUENCIES)) <= tolerance
    assert lin.states == ["pos", "vel", "cur"] and lin.state_units == ["m", "m/s", "A"]
    assert lin.input_units == ["V", "V"] and lin.unknown_input_units == ["N"]
    assert lin.state_nominal.tolist() == [0.5, 2.0, 10.0]
    assert lin.accuracy <= tolerance


def test_set_scales_b(fmus, plant):
    lin = linearize(fmus["directional"], ["u_a"], ["y_b"], start={"scale": 2.5})
    assert relative(lin.B, 2.5 * plant["B"][:, :1]) <= 1e-12
    assert relative(lin.C, plant["C"][1:]) <= 1e-12 and lin.E is None


@pytest.mark.parametrize("kind", ["vanderpol", "vanderpol_fd"])
def test_vanderpol_off_the_origin(fmus, kind):
    start = {"x1": 1.5, "x2": -0.7, "mu": 2.0}
    lin = linearize(fmus[kind], ["u"], ["y"], start=start)
    A, B, C = vanderpol_jacobian(1.5, -0.7, 2.0)
    for mine, theirs in ((lin.A, A), (lin.B, B), (lin.C, C)):
        assert relative(mine, theirs) <= 1e-6
    assert not lin.equilibrium and lin.x.tolist() == [1.5, -0.7]
    assert lin.state_units == ["m", "m/s"]  # through the declared type


def test_vanderpol_at(fmus):
    """--at 0.8: the state simulated there (against scipy on the analytic ODE) and the
    Jacobian at it."""
    mu = 1.0
    lin = linearize(fmus["vanderpol"], ["u"], ["y"], at=0.8, start={"x1": 2.0, "mu": mu})
    reference = solve_ivp(lambda t, x: [x[1], mu * (1 - x[0] ** 2) * x[1] - x[0]], (0, 0.8),
                          [2.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    assert np.max(np.abs(lin.x - reference)) <= 1e-7
    assert relative(lin.A, vanderpol_jacobian(*reference, mu)[0]) <= 1e-6
    assert lin.time == 0.8


def test_wrong_directional_derivatives_are_not_used(tmp_path):
    """An FMU whose directional derivatives miss dy/dx (0 instead of 3): central differences
    are used and the method says why."""
    fmu = me_fmu(tmp_path / "wrong.fmu", "wrong",
                 [Variable("x", "state", 1.0), Variable("u", "input"), Variable("y", "output")],
                 {"x": "-2.0 * {x} + {u}"}, {"y": "3.0 * {x}"},
                 {("der(x)", "x"): "-2.0", ("der(x)", "u"): "1.0"})
    lin = linearize(fmu, ["u"], ["y"])
    assert lin.method.startswith("central differences; wrong's directional derivatives differ")
    assert relative(lin.C, [[3.0]]) <= 1e-6 and relative(lin.A, [[-2.0]]) <= 1e-6


@pytest.mark.parametrize("kind, tolerance", [("ssp", 1e-8), ("ssp_fd", 1e-6)])
def test_dc_motor_ssp(fmus, kind, tolerance):
    lin = linearize(fmus[kind], ["U"], ["phiB"], ["M_load"], system="DC-Motor.SuT")
    hand = dc_motor_matrices(**{**DC_MOTOR_BOUND, "L": DC_MOTOR_DEFAULTS["L"]})
    assert lin.states == ["emachine.i", "edrive.phi", "edrive.w"]
    for name in "ABCE":
        assert relative(getattr(lin, name), hand[name]) <= tolerance, name
    for inputs, reference in ((lin.B, hand["B"]), (lin.E, hand["E"])):
        assert relative(transfer(lin.A, inputs, lin.C, FREQUENCIES),
                        transfer(hand["A"], reference, hand["C"], FREQUENCIES)) <= tolerance
    assert lin.unknown_input_units == ["Nm"] and lin.output_units == ["rad"]


def test_dc_motor_set_overrides_the_binding(fmus):
    lin = linearize(fmus["ssp"], ["U"], ["phiB"], system="DC-Motor.SuT",
                    start={"edrive.J": 0.004, "gear.ratio": 3.0})
    hand = dc_motor_matrices(**{**DC_MOTOR_BOUND, "J": 0.004, "ratio": 3.0})
    assert relative(lin.A, hand["A"]) <= 1e-12


def run(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_written_spec_reads_back_and_designs(fmus, tmp_path, capsys):
    out = tmp_path / "specs" / "motor.toml"
    out.parent.mkdir()
    code, printed, err = run(["linearize", fmus["ssp"], "--system", "DC-Motor.SuT", "--input",
                              "U", "--unknown-input", "M_load", "--output", "phiB", "--set",
                              "edrive.J=0.004", "--out", out], capsys)
    assert code == 0, err
    assert "directional derivatives" in printed
    data = tomllib.loads(out.read_text())
    assert data["name"] == "DC-Motor.SuT"
    assert data["signals"] == {
        "states": ["emachine.i", "edrive.phi", "edrive.w"], "state_units": ["A", "rad", "rad/s"],
        "inputs": ["U"], "input_units": ["V"], "outputs": ["phiB"], "output_units": ["rad"],
        "unknown_inputs": ["M_load"], "unknown_input_units": ["Nm"]}
    model = data["plant_model"]
    assert (out.parent / model["path"]).resolve() == Path(fmus["ssp"]).resolve()
    assert model["system"] == "DC-Motor.SuT" and model["start"] == {"edrive.J": 0.004}
    assert model["inputs"] == ["U"] and model["unknown_inputs"] == ["M_load"]
    assert model["at"] == 0.0 and model["states"] == data["signals"]["states"]
    hand = dc_motor_matrices(**{**DC_MOTOR_BOUND, "J": 0.004})
    # each state's typical size: its nominal value or its largest move within the settling
    # time after a 1 V step, by an ODE solver on the hand-derived matrices
    settle = data["observer"]["settling_time"]
    moves = solve_ivp(lambda t, x: hand["A"] @ x + hand["B"][:, 0], (0.0, settle), np.zeros(3),
                      t_eval=np.linspace(0.0, settle, 51), rtol=1e-10, atol=1e-12).y
    expected = np.maximum([1.0, 1.0, 100.0], np.abs(moves).max(axis=1))
    assert np.allclose(data["observer"]["state_scale"], expected, rtol=1e-6)

    from fhobs.design.observer import design_for_spec
    from fhobs.design.spec import load_spec

    spec = load_spec(out)
    for name in "ABCE":
        assert relative(getattr(spec, name), hand[name]) <= 1e-8, name
    assert spec.name == "DC-Motor.SuT"
    assert list(spec.signals.states) == data["signals"]["states"]
    assert list(spec.signals.unknown_input_units) == ["Nm"]
    assert spec.plant_model.path.resolve() == Path(fmus["ssp"]).resolve()
    assert spec.plant_model.system == "DC-Motor.SuT" and spec.plant_model.at == 0.0
    assert spec.plant_model.start == {"edrive.J": 0.004}
    design = design_for_spec(spec)
    assert design.settling_tuning["met"]


REFUSALS = {
    "cosim": (["cosim", "--input", "u_a", "--output", "y_a"],
              "Co-Simulation-only FMU: it has no Model Exchange interface"),
    "unknown input": (["directional", "--input", "u_c", "--output", "y_a"],
                      "no such variable (closest: u_b, u_a)"),
    "unknown output": (["directional", "--input", "u_a", "--output", "ya"],
                       "no such variable (closest: y_a"),
    "parameter as input": (["directional", "--input", "scale", "--output", "y_a"],
                           "not an input (the inputs: u_a, u_b, load); set a parameter's"),
    "feedthrough": (["feedthrough", "--input", "u_a", "u_b", "--output", "y_b"],
                    "the output 'y_b' depends directly on the input 'u_b' (D = 0.3)"),
    "units": (["ssp_rpm", "--system", "DC-Motor.SuT", "--input", "U", "--output", "phiB"],
              "joins the units 'rad/s' and 'rpm', which differ"),
    "no system": (["ssp", "--system", "DC-Motor.Sut", "--input", "U", "--output", "phiB"],
                  "no system 'DC-Motor.Sut' (closest: SuT)"),
    "unknown component": (["ssp", "--system", "DC-Motor.SuT", "--input", "U", "--output",
                           "phiB", "--set", "edrv.J=1"], "has no component of that name"),
    "missing file": (["missing.fmu", "--input", "u", "--output", "y"], "no such FMU file"),
    "not a zip": (["not_a_zip.ssp", "--input", "u", "--output", "y"], "not an SSP (an SSP is"),
}


@pytest.mark.parametrize("case", list(REFUSALS))
def test_refusals(fmus, tmp_path, capsys, case):
    argv, message = REFUSALS[case]
    (tmp_path / "not_a_zip.ssp").write_text("text")
    model = fmus.get(argv[0], tmp_path / argv[0])
    out = tmp_path / "spec.toml"
    code, printed, err = run(["linearize", model, *argv[1:], "--out", out], capsys)
    assert code == 2
    assert message in err, err
    assert "Traceback" not in err and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["not_a_zip.ssp"]
