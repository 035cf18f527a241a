"""Model mismatch in ``harness plant``: the plant FMU runs with A and B perturbed as documented
(:meth:`fhobs.design.spec.MismatchSpec.perturb`), the observers keep the nominal model."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from fhobs.design.spec import MismatchSpec, load_spec

from harness.cli import main

A = np.array([[0.0, 1.0, 0.0], [0.0, -10.0, 1.0], [0.0, -0.02, -2.0]])
B = np.array([[0.0], [0.0], [2.0]])
C = np.array([[1.0, 0.0, 0.0]])
PLANT = """A = [[0, 1, 0], [0, -10.0, 1.0], [0, -0.02, -2.0]]
B = [[0], [0], [2.0]]
C = [[1, 0, 0]]
[observer]
settling_time = 1.0
"""


@pytest.mark.parametrize("distribution", ["gaussian", "uniform"])
def test_perturbation_is_the_documented_draw(distribution):
    """M_ij (1 + s w_ij), w drawn for A (row by row) then B from default_rng(seed); zeros stay
    zero; the same seed at another size scales the same w."""
    rng = np.random.default_rng(11)
    if distribution == "gaussian":
        W_A, W_B = rng.standard_normal((3, 3)), rng.standard_normal((3, 1))
    else:
        W_A, W_B = rng.uniform(-1.0, 1.0, (3, 3)), rng.uniform(-1.0, 1.0, (3, 1))
    A_p, B_p = MismatchSpec(0.2, distribution, 11).perturb(A, B)
    np.testing.assert_array_equal(A_p, A * (1.0 + 0.2 * W_A))
    np.testing.assert_array_equal(B_p, B * (1.0 + 0.2 * W_B))
    assert A_p[0, 0] == 0.0 and B_p[0, 0] == 0.0 and not np.array_equal(A_p, A)
    A_q, _ = MismatchSpec(0.1, distribution, 11).perturb(A, B)
    np.testing.assert_allclose(A_q - A, (A_p - A) / 2, rtol=1e-12, atol=1e-15)
    if distribution == "uniform":
        assert np.all(np.abs(A_p - A) <= 0.2 * np.abs(A))


def test_mismatch_table_is_loaded(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text(PLANT + "[mismatch]\nsize = 0.05\ndistribution = 'uniform'\nseed = 4\n")
    assert load_spec(spec).mismatch == MismatchSpec(0.05, "uniform", 4)


BAD = [
    ("[mismatch]\nseed = 1\n", [], "mismatch.size is missing"),
    ("[mismatch]\nsize = -0.1\n", [], "mismatch.size = -0.1 must be >= 0"),
    ("[mismatch]\nsize = 'big'\n", [], "mismatch.size = 'big' is not a number"),
    ("[mismatch]\nsize = 0.1\ndistribution = 'cauchy'\n", [],
     "mismatch.distribution = 'cauchy' is not one of gaussian, uniform"),
    ("[mismatch]\nsize = 0.1\nseed = -1\n", [], "mismatch.seed = -1 must be an integer >= 0"),
    ("[mismatch]\nsize = 0.1\nseed = 1.5\n", [], "mismatch.seed = 1.5 must be an integer >= 0"),
    ("[mismatch]\nsize = 0.1\nscale = 2\n", [], "unknown key mismatch.scale"),
    ("mismatch = 0.1\n", [], "mismatch must be a table"),
    ("", ["--mismatch", "-0.1"], "--mismatch/--mismatch-seed: size = -0.1 must be >= 0"),
    ("", ["--mismatch", "nan"], "--mismatch/--mismatch-seed: size = nan is not finite"),
    ("", ["--mismatch-seed", "3"], "--mismatch-seed needs --mismatch SIZE or a [mismatch] table"),
    ("", ["--mismatch", "0.1", "--mismatch-seed", "-2"],
     "--mismatch/--mismatch-seed: seed = -2 must be an integer >= 0"),
]


@pytest.mark.parametrize(("table", "options", "message"), BAD)
def test_bad_mismatch_is_one_paragraph_exit_2(tmp_path, capsys, table, options, message):
    spec = tmp_path / "bad.toml"
    spec.write_text(PLANT.replace("[observer]", table + "[observer]") if table.startswith(
        "mismatch =") else PLANT + table)
    code = main(["plant", str(spec), "--out", str(tmp_path / "out"), *options])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and err.count("\n") == 1
    assert err.startswith("error: ") and message in err, err
    assert not (tmp_path / "out" / "fmus").exists()


@pytest.mark.slow
def test_plant_fmu_runs_the_perturbed_matrices(tmp_path, capsys):
    """--mismatch 0.2 --mismatch-seed 5: the plant's x is scipy's ZOH closed loop of the
    perturbed (A, B) with the LQR of the perturbed plant (scipy), not the nominal one; the
    summary records the perturbed matrices; the observers' FMUs keep the nominal A."""
    from fmpy import read_model_description

    spec = tmp_path / "spec.toml"
    spec.write_text(PLANT)
    out = tmp_path / "out"
    code = main(["plant", str(spec), "--out", str(out), "--stop-time", "1", "--no-plots",
                 "--mismatch", "0.2", "--mismatch-seed", "5"])
    assert code == 0, capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    rng = np.random.default_rng(5)
    A_p = A * (1.0 + 0.2 * rng.standard_normal((3, 3)))
    B_p = B * (1.0 + 0.2 * rng.standard_normal((3, 1)))
    np.testing.assert_allclose(summary["mismatch"]["A"], A_p, rtol=1e-15)
    assert summary["mismatch"]["seed"] == 5 and summary["mismatch"]["size"] == 0.2
    data = np.genfromtxt(out / "results.csv", delimiter=",", names=True, deletechars="")
    recorded = np.column_stack([data[f"plant.x[{i}]"] for i in (1, 2, 3)])
    X = scipy.linalg.solve_continuous_are(A_p, B_p, np.eye(3), np.eye(1))
    K = -B_p.T @ X
    Ad, Bd, *_ = scipy.signal.cont2discrete((A_p, B_p, C, np.zeros((1, 1))), 1e-3, method="zoh")
    x, expected = np.ones(3), [np.ones(3)]
    for _ in range(len(recorded) - 1):
        x = Ad @ x + Bd @ (K @ x)
        expected.append(x)
    expected = np.array(expected)
    assert np.max(np.abs(recorded - expected)) <= 1e-9 * np.max(np.abs(expected))
    variables = {v.name: v.start for v in read_model_description(
        str(out / "fmus" / "observer.fmu")).modelVariables}
    assert float(variables["A[2,2]"]) == -10.0 and A_p[1, 1] != -10.0
