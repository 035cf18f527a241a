"""Plant spec loading: the examples load, and every defect gets an error naming its field."""

import copy
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fhobs.design.spec import load_spec, spec_from_dict
from fhobs.errors import SpecError
from fhobs.paper import EXAMPLES

GOOD = {
    "A": [[0.0, 1.0], [-2.0, -3.0]],
    "B": [[0.0], [1.0]],
    "C": [[1.0, 0.0]],
    "observer": {"nu": -0.3, "rho": 1.5, "gamma": 2.0},
}


def with_change(path: tuple, value) -> dict:
    """A copy of GOOD with one entry replaced (value None deletes it)."""
    data = copy.deepcopy(GOOD)
    target = data
    for key in path[:-1]:
        target = target[key]
    if value is None:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return data


@pytest.mark.parametrize("name", ["pendulum", "triple_integrator", "mass_chain"])
def test_examples_load(name):
    spec = load_spec(EXAMPLES / f"{name}.toml")
    assert spec.A.shape[0] == spec.C.shape[1]
    assert -1 / (spec.n_tilde + 1) - 1e-12 <= spec.nu < 0
    assert spec.rho is None or spec.rho > spec.gamma / 2


def test_defaults_are_documented_values():
    spec = spec_from_dict(with_change(("observer",), None))
    assert spec.n_tilde == 2
    assert spec.nu == pytest.approx(-1 / 3)
    assert (spec.rho, spec.gamma, spec.objective) == (None, None, "min_cond")  # rho: the design's
    assert spec.settling_time == 2.0
    np.testing.assert_array_equal(spec.state_scale, np.ones(2))
    assert spec.filter_scale == 1.0


@pytest.mark.parametrize(("scale", "expected"), [(0.5, [0.5] * 2), ([1, 2], [1, 2])])
def test_state_scale_is_one_number_or_one_per_state(scale, expected):
    spec = spec_from_dict(with_change(("observer", "state_scale"), scale))
    np.testing.assert_array_equal(spec.state_scale, expected)


@pytest.mark.parametrize(("key", "value", "pattern"), [
    ("state_scale", [1, 2, 3], r"observer.state_scale has 3 entries, expected 1 or 2"),
    ("state_scale", [1, -2], r"observer.state_scale\[2\] = -2 must be > 0"),
    ("settling_time", 0, r"observer.settling_time = 0.0 must be > 0"),
    ("rho", -1.0, r"observer.rho = -1.0 must be > 0"),
])
def test_bad_tuning_requests_name_the_field(key, value, pattern):
    with pytest.raises(SpecError, match=pattern):
        spec_from_dict(with_change(("observer", key), value))


BAD_CASES = [
    (("A",), None, r"A is missing"),
    (("B",), [[0.0], [1.0, 2.0]], r"B is ragged: row 2 has 2 entries, row 1 has 1"),
    (("C",), [[1.0, "x"]], r"C\[1,2\] = 'x' is not a number"),
    (("C",), [[1.0, True]], r"C\[1,2\] = True is not a number"),
    (("A",), [[0.0, math.nan], [-2.0, -3.0]], r"A\[1,2\] = nan is not finite"),
    (("B",), [[math.inf], [1.0]], r"B\[1,1\] = inf is not finite"),
    (("A",), [[0.0, 1.0, 0.0], [-2.0, -3.0, 0.0]], r"A must be square, got 2 x 3"),
    (("B",), [[1.0]], r"B has 1 rows, expected 2"),
    (("C",), [[1.0, 0.0, 0.0]], r"C has 3 columns, expected 2"),
    (("E",), [[1.0]], r"E has 1 rows, expected 2"),
    (("A",), "not a matrix", r"A must be a non-empty list of rows"),
    (("A",), [], r"A must be a non-empty list of rows"),
    (("A",), [[0.0, 0.0], [0.0, -3.0]],
     r"not observable: the observability matrix has rank 1, n = 2"),
    (("observer", "nu"), -0.5, r"observer.nu = -0.5 is outside \[-1/\(n_tilde\+1\), 0\)"),
    (("observer", "nu"), 0.0, r"observer.nu = 0.0 is outside"),
    (("observer", "nu"), 0.2, r"observer.nu = 0.2 is outside"),
    (("observer", "nu"), "fast", r"observer.nu = 'fast' is not a number"),
    (("observer", "gamma"), 0.0, r"observer.gamma = 0.0 must be > 0"),
    (("observer", "gamma"), -1.0, r"observer.gamma = -1.0 must be > 0"),
    (("observer", "rho"), 1.0, r"observer.rho = 1.0 must be > gamma/2 = 1.0"),
    (("observer", "objective"), "fastest", r"observer.objective = 'fastest' is not one of"),
    (("observer", "filter_scale"), 0.5, r"observer.filter_scale = 0.5 must be >= 1"),
    (("observer", "filter_scale"), "x", r"observer.filter_scale = 'x' is not a number"),
    (("observer", "disturbance_order"), 1, r"observer.disturbance_order = 1 needs E"),
    (("observer", "disturbance_order"), 1.0, r"observer.disturbance_order = 1.0 is not an int"),
    (("observer", "disturbance_order"), True, r"observer.disturbance_order = True is not an int"),
    (("observer", "disturbance_order"), 4, r"observer.disturbance_order = 4 is outside 0..3"),
    (("observer", "mu"), 1.0, r"unknown key observer.mu"),
    (("D",), [[0.0]], r"unknown key D"),
    (("L_lin",), [[1.0, 2.0], [3.0, 4.0]], r"L_lin has 2 columns, but C has 1 rows"),
]


@pytest.mark.parametrize(("path", "value", "message"), BAD_CASES)
def test_bad_spec_names_field(path, value, message):
    with pytest.raises(SpecError, match=message):
        spec_from_dict(with_change(path, value), source="bad.toml")


def test_disturbance_model_sets_the_model_index_and_needs_observability():
    data = with_change(("E",), [[0.0], [1.0]])
    data["observer"] = {"disturbance_order": 2}
    spec = spec_from_dict(data)
    assert (spec.disturbance_order, spec.n_tilde) == (2, 4)  # chain y, dy, q, dq
    # E = (1, -3): C A^-1 E = 0, a constant q is invisible in y
    data = with_change(("E",), [[1.0], [-3.0]])
    data["observer"] = {"disturbance_order": 1}
    with pytest.raises(SpecError, match=r"disturbance model of order 1 \(A, E, C\) is not "
                                        r"observable: the observability matrix has rank 2, n = 3"):
        spec_from_dict(data, source="bad.toml")


def test_unobservable_mimo_reports_rank():
    A = np.diag([1.0, 2.0, 3.0, 4.0]).tolist()
    C = [[1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
    data = {"A": A, "B": [[1.0]] * 4, "C": C}
    with pytest.raises(SpecError, match=r"rank 3, n = 4"):
        spec_from_dict(data)


def test_missing_file_and_bad_toml(tmp_path: Path):
    with pytest.raises(SpecError, match="cannot read the spec file"):
        load_spec(tmp_path / "absent.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("A = [[1, 2]\n")
    with pytest.raises(SpecError, match="not valid TOML"):
        load_spec(bad)


def test_toml_nan_literal_is_rejected(tmp_path: Path):
    spec = tmp_path / "nan.toml"
    spec.write_text("A = [[0, 1], [nan, 0]]\nB = [[0], [1]]\nC = [[1, 0]]\n")
    with pytest.raises(SpecError, match=r"A\[2,1\] = nan is not finite"):
        load_spec(spec)


def test_numpy_arrays_are_accepted_as_matrices():
    """A 2-D numpy array is read as its rows: the same spec as the lists; a 1-D array is not a
    matrix and is refused with the field named."""
    arrays = {k: (np.array(v, dtype=float) if k in ("A", "B", "C") else v)
              for k, v in GOOD.items()}
    from_arrays, from_lists = spec_from_dict(arrays), spec_from_dict(GOOD)
    for name in ("A", "B", "C"):
        np.testing.assert_array_equal(getattr(from_arrays, name), getattr(from_lists, name))
    with pytest.raises(SpecError, match="C must be a non-empty list of rows"):
        spec_from_dict(arrays | {"C": np.array([1.0, 0.0])})


def test_loading_a_spec_imports_no_solver():
    """Reading and validating a spec (no design) imports neither cvxpy nor scipy."""
    code = ("import sys, fhobs.design.spec; "
            f"fhobs.design.spec.load_spec({str(EXAMPLES / 'pendulum.toml')!r}); "
            "loaded = [m for m in ('cvxpy', 'clarabel', 'scipy') if m in sys.modules]; "
            "assert not loaded, loaded")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_an_unobservable_large_plant_is_described_in_one_short_sentence():
    """n = 601 unobservable states: the message names a few directions, never every entry."""
    n = 601
    C = np.zeros((1, n))
    C[0, 0] = 1.0
    with pytest.raises(SpecError) as caught:
        spec_from_dict({"A": np.zeros((n, n)), "B": np.ones((n, 1)), "C": C})
    text = str(caught.value)
    assert "not observable" in text and "x[2]" in text and "597 more" in text
    assert len(text) < 400


@pytest.mark.parametrize("scale", [[1e-300, 1.0], [1e300, 1.0], [1e-7, 1e7]])
def test_state_scales_beyond_the_designs_range_are_refused(scale):
    from fhobs.design.limits import check_design_limits
    spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]],
                           "observer": {"state_scale": scale}})
    with pytest.raises(SpecError, match="observer.state_scale from .* is beyond the design"):
        check_design_limits(spec)


def test_a_settling_time_shorter_than_the_climb_can_reach_says_what_to_ask():
    from fhobs.design.observer import RHO_MAX, design_for_spec
    from fhobs.errors import LMIError
    spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]],
                           "observer": {"settling_time": 1e-300}})
    with pytest.raises(LMIError) as caught:
        design_for_spec(spec)
    text = str(caught.value)
    assert "no rho to try" in text and f"{RHO_MAX:g}" in text
    assert "a settling_time of at least 0.0003 s" in text


@pytest.mark.parametrize("key, value", [("sample_time", 1e-300), ("process_intensity", 1e300),
                                        ("measurement_std", [1e300])])
def test_noise_numbers_beyond_the_designs_range_are_refused_before_the_riccati_equation(
        key, value):
    """Such numbers overflow inside scipy's Riccati solver (RuntimeWarnings, then a failure):
    the limits refuse them first, naming the key."""
    from fhobs.design.limits import check_design_limits
    noise = {"measurement_std": [1e-3], "sample_time": 1e-3, "process_intensity": 1.0, key: value}
    spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]],
                           "E": [[0], [1]], "noise": noise})
    with pytest.raises(SpecError, match=f"noise.{key}.* is beyond the design's range"):
        check_design_limits(spec)
