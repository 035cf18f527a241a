"""The spec's plant name, ``[signals]`` and ``[plant_model]`` tables (fhobs.design.signals,
fhobs.design.plant_model), loaded through the spec loader as a user writes them."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from fhobs.design.spec import load_spec
from fhobs.errors import SpecError

MOTOR = """A = [[-500.0, -50.0, 0.0], [50.0, -1.0, 0.0], [0.0, 1.0, 0.0]]
B = [[1000.0], [0.0], [0.0]]
C = [[0.0, 0.0, 1.0]]
E = [[0.0], [1000.0], [0.0]]
"""
SIGNALS = """[signals]
states = ["inductor.i", "inertia.w", "inertia.phi"]
state_units = ["A", "rad/s", "rad"]
inputs = ["U"]
input_units = ["V"]
outputs = ["phiB"]
unknown_inputs = ["M_load"]
unknown_input_units = ["N.m"]
"""
MODEL = """[plant_model]
path = "motor.ssp"
system = "DC-Motor.SuT"
inputs = ["U"]
outputs = ["phiB"]
unknown_inputs = ["M_load"]
states = ["emachine.inductor.i", "mass.inertia.w", "mass.inertia.phi"]
start = { "mass.inertia.J" = 0.01, "emachine.useHeatPort" = false }
at = 0.5
"""


def write(folder: Path, text: str, name: str = "motor.toml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def test_names_units_and_model_are_read_with_the_paths_resolved(tmp_path):
    (tmp_path / "motor.ssp").write_bytes(b"PK")
    spec = load_spec(write(tmp_path, 'name = "DC-Motor.SuT"\n' + MOTOR + SIGNALS + MODEL))
    assert spec.name == "DC-Motor.SuT"
    assert spec.names.states == ("inductor.i", "inertia.w", "inertia.phi")
    assert spec.names.label("states", 1) == "inertia.w [rad/s]"
    assert spec.names.output_units == ("",) and spec.names.label("outputs", 0) == "phiB"
    assert spec.names.label("unknown_inputs", 0) == "M_load [N.m]"
    model = spec.plant_model
    assert model.path == tmp_path / "motor.ssp" and model.system == "DC-Motor.SuT"
    assert model.states[2] == "mass.inertia.phi" and model.at == 0.5
    assert model.start == {"mass.inertia.J": 0.01, "emachine.useHeatPort": False}


def test_an_unnamed_spec_gets_the_file_stem_and_indexed_names(tmp_path):
    spec = load_spec(write(tmp_path, MOTOR, "two_mass.toml"))
    assert spec.name == "two_mass" and spec.plant_model is None
    assert spec.names.states == ("x[1]", "x[2]", "x[3]")
    assert spec.names.unknown_inputs == ("q[1]",) and spec.names.state_units == ("",) * 3


@pytest.mark.parametrize("text, field", [
    (SIGNALS.replace('"inductor.i", ', ""), "signals.states has 2 entries, expected 3"),
    (SIGNALS.replace('"inertia.w"', '"inertia.phi"'), "signals.states names 'inertia.phi'"),
    (SIGNALS.replace("input_units", "input_unit"), "unknown key signals.input_unit"),
    (SIGNALS.replace('["V"]', '[1.0]'), "signals.input_units must be a list of strings"),
    (SIGNALS.replace('["U"]', '[""]'), "signals.inputs entry ''"),
    (MODEL.replace("motor.ssp", "other.ssp"), "plant_model.path = 'other.ssp': no such file"),
    (MODEL.replace("motor.ssp", "motor.zip"), "neither an FMU (.fmu) nor an SSP"),
    (MODEL.replace('outputs = ["phiB"]', 'outputs = []'),
     "plant_model.outputs has 0 entries, expected 1"),
    (MODEL.replace('states = ', 'state = '), "unknown key plant_model.state (did you mean states?"),
    (MODEL.replace('outputs = ["phiB"]\n', ''), "plant_model.outputs is missing"),
    (MODEL.replace("at = 0.5", "at = -1.0"), "plant_model.at = -1.0 must be a finite time"),
    (MODEL.replace("= 0.01", "= nan"), "plant_model.start.mass.inertia.J = nan"),
    ('name = ""\n', "name = '' must be a non-empty line"),
])
def test_bad_tables_name_the_field(tmp_path, text, field):
    (tmp_path / "motor.ssp").write_bytes(b"PK")
    with pytest.raises(SpecError) as caught:
        load_spec(write(tmp_path, MOTOR + text))
    assert field in str(caught.value), str(caught.value)


def test_an_fmu_model_refuses_a_system(tmp_path):
    (tmp_path / "motor.fmu").write_bytes(b"PK")
    with pytest.raises(SpecError, match="plant_model.system is given but motor.fmu is not an SSP"):
        load_spec(write(tmp_path, MOTOR + MODEL.replace("motor.ssp", "motor.fmu")))


def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "spec.toml"
    os.mkfifo(fifo)
    with pytest.raises(SpecError, match="not a regular file"):
        load_spec(fifo)
