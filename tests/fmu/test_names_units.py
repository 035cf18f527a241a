"""A spec's plant name and signal names and units in the FMUs' modelDescriptions, both builds.

The expected texts are written out here from the spec's lists (not taken from the code that
writes them); the value references, causalities and start values must be those of an unnamed
build of the same design.
"""

import tomllib
from pathlib import Path

import fhobs.build
import pytest
from fhobs.build import build_fmus
from fhobs.design.observer import design_for_spec
from fhobs.design.signals import SignalNames
from fhobs.design.spec import spec_from_dict
from fhobs.fmu.kinds import KINDS as DECLARED
from fhobs.model_description import naming_options
from fhobs.native.build import build_native_fmus
from fmpy import read_model_description
from fmpy.validation import validate_fmu

ROOT = Path(__file__).resolve().parents[2]
KINDS = tuple(DECLARED)
SIGNALS = {"states": ["inductor.i", "inertia.phi", "inertia.w"],
           "state_units": ["A", "rad", ""],
           "inputs": ["U"], "input_units": ["V"],
           "outputs": ["phiB"], "output_units": ["rad"],
           "unknown_inputs": ["M_load"], "unknown_input_units": ["N.m"]}
PARAMETER_UNITS = {"max_communication_step": "s"}
"""The parameters with a unit (the others have none), named or not."""
KEYS = ("name", "valueReference", "type", "causality", "variability", "initial",
        "description", "unit")


def _spec(signals=SIGNALS, name="DC-Motor.SuT"):
    data = tomllib.loads((ROOT / "examples" / "triple_integrator.toml").read_text())
    data["observer"] = {"disturbance_order": 1, "settling_time": 2.0}
    data["noise"] = {"measurement_std": [1e-3], "sample_time": 1e-3, "process_intensity": 1e-2}
    data["name"], data["signals"] = name, signals
    return spec_from_dict(data)


@pytest.fixture(scope="module")
def named(tmp_path_factory):
    """The named spec's design and its FMUs of both builds, and the unnamed pythonfmu build."""
    spec = _spec()
    design = design_for_spec(spec)
    out = tmp_path_factory.mktemp("named")
    naming = {"names": spec.names, "plant_name": spec.name}
    return {"spec": spec,
            "python": build_fmus(design, out / "python", kinds=KINDS, **naming),
            "native": build_native_fmus(design, out / "native", kinds=KINDS, **naming),
            "unnamed": build_fmus(design, out / "unnamed", kinds=KINDS)}


def _variables(fmu):
    return {v.name: v for v in read_model_description(str(fmu)).modelVariables}


def _expected(name, kind="observer"):
    """(description, unit) of a signal element of a ``kind`` FMU, from SIGNALS; None for other
    variables."""
    base, _, index = name.partition("[")
    i = int(index.rstrip("]")) - 1 if index else 0
    state = (SIGNALS["states"][i] if i < 3 else "", (SIGNALS["state_units"] + [""] * 3)[i] or None)
    q = ("M_load" + "'" * i, ("N.m", "N.m/s", "N.m/s2")[i] if i < 3 else None)
    return {"x_hat": (f"estimate of {state[0]}", state[1]),
            "x": (f"true value of {state[0]}", state[1]),
            "y": ("measured phiB" + (" (C x + noise)" if kind == "plant" else ""), "rad"),
            "u": ("input U", "V"),
            "q_hat": (f"estimate of the unknown input {q[0]}", q[1]),
            "q": ("unknown input M_load (through E)", "N.m")}.get(base)


@pytest.mark.parametrize("kind", KINDS)
def test_both_builds_give_the_same_names_descriptions_and_units(named, kind):
    python, native = (read_model_description(str(named[build][kind]))
                      for build in ("python", "native"))
    assert [[getattr(v, key) for key in KEYS] for v in native.modelVariables] == [
        [getattr(v, key) for key in KEYS] for v in python.modelVariables]
    assert python.modelName == native.modelName == kind
    assert python.description.startswith(f"{kind} of DC-Motor.SuT: ")
    assert native.description.startswith(python.description)


@pytest.mark.parametrize("kind", KINDS)
def test_signals_carry_the_spec_names_and_units(named, kind):
    variables = _variables(named["python"][kind])
    signals = {name: v for name, v in variables.items() if v.causality in ("input", "output")
               and _expected(name) is not None}
    if kind == "supervised":  # its x_hat is the mode's estimator's
        for name in [n for n in signals if n.startswith("x_hat")]:
            description, unit = _expected(name)
            assert (signals.pop(name).description, variables[name].unit) == (
                f"{description} (by the mode's estimator)", unit)
    assert signals, kind
    for name, variable in signals.items():
        assert (variable.description, variable.unit) == _expected(name, kind), name
    q_hats = [name for name in variables if name.startswith("q_hat[")]
    assert len(q_hats) == (1 if "q_hat" in {v.name for v in DECLARED[kind].variables} else 0)
    units = {unit.name for unit in read_model_description(
        str(named["python"][kind])).unitDefinitions}
    assert units == {v.unit for v in variables.values() if v.unit}
    assert "" not in units and "rad" in units


@pytest.mark.parametrize("kind", KINDS)
def test_names_change_no_value_reference_start_or_parameter_text(named, kind):
    named_vars, plain = (_variables(named[build][kind]) for build in ("python", "unnamed"))
    assert [(v.name, v.valueReference, v.causality, v.start) for v in named_vars.values()] == [
        (v.name, v.valueReference, v.causality, v.start) for v in plain.values()]
    for name, variable in named_vars.items():
        if variable.causality not in ("input", "output") or _expected(name) is None:
            assert variable.description == plain[name].description, name
            assert variable.unit == PARAMETER_UNITS.get(name), name
    x_hat = plain.get("x_hat[1]") or plain["x[1]"]
    assert x_hat.description.startswith(("estimate of x[1]", "true value of x[1]"))
    assert x_hat.unit is None
    units = read_model_description(str(named["unnamed"][kind])).unitDefinitions
    assert {unit.name for unit in units} == {PARAMETER_UNITS[name] for name in plain
                                             if name in PARAMETER_UNITS}


@pytest.mark.parametrize("build", ["python", "native"])
@pytest.mark.parametrize("kind", ["observer", "supervised", "plant"])
def test_fmpy_validates_the_named_fmus(named, build, kind):
    assert validate_fmu(str(named[build][kind])) == []


def test_renamed_spec_is_not_served_a_cached_fmu(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    cache.mkdir()
    monkeypatch.setattr(fhobs.build, "cache_dir", lambda: cache)
    spec = _spec()
    design = design_for_spec(spec)
    first = build_fmus(design, tmp_path / "a", kinds=("plant",), names=spec.names,
                       plant_name=spec.name)["plant"]
    renamed = _spec({**SIGNALS, "states": ["i", "phi", "w"]}, name="motor")
    second = build_fmus(design, tmp_path / "b", kinds=("plant",), names=renamed.names,
                        plant_name=renamed.name)["plant"]
    assert _variables(first)["x[1]"].description == "true value of inductor.i"
    assert _variables(second)["x[1]"].description == "true value of i"
    assert read_model_description(str(second)).description.startswith("plant of motor: ")
    assert len(list((cache / "fmus").glob("*.fmu"))) == 2


def test_names_of_another_plant_are_refused(named):
    design = design_for_spec(named["spec"])
    with pytest.raises(ValueError, match="names: 2 states named, the design's plant has 3"):
        naming_options(design, SignalNames.default(2, 1, 1, 1))
