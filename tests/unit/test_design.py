"""Design core: pendulum reproduction, identities and certificates on random plants,
rejection of broken solver results, and the design.json contract of build_fmu.py."""

import dataclasses
import json
import subprocess
import sys
import tomllib
from pathlib import Path
from types import SimpleNamespace

import fhobs.design.observer
import numpy as np
import pytest
import scipy.linalg
from fhobs.core.certificate import augmented_matrices, certify, checked_model
from fhobs.core.disturbance import extended_model
from fhobs.design.homogenisation import homogenise, observability_index
from fhobs.design.lmi import LMISolution
from fhobs.design.observer import augmented_system, design_for_spec, matched_perturbation_residual
from fhobs.design.spec import spec_from_dict
from fhobs.errors import CertificateError
from fhobs.paper import EXAMPLES, published

REPO = Path(__file__).resolve().parents[2]
PAPER = published()


def printed_tolerance(value: float) -> float:
    """Half a unit of the last printed digit of a published number."""
    text = repr(float(value))
    decimals = len(text.split(".")[1]) if "." in text and "e" not in text else 0
    return 0.5 * 10.0**-decimals


@pytest.mark.parametrize("name", ["L0", "G_d"])
def test_pendulum_homogenisation_matches_published_digits(paper_design, name):
    """paper_gains recomputes L0 and G_d with fhobs.design.homogenisation (no disturbance model)."""
    published = np.array(PAPER["design"][name])
    ours = getattr(paper_design, name)
    tol = np.vectorize(printed_tolerance)(published)
    assert np.all(np.abs(ours - published) <= tol + 1e-12), ours - published
    assert paper_design.n_tilde == 2


def test_printed_sign_of_the_homogenisation_equation_fails():
    """The paper prints G0 A - A G0 + Y0 C = A; solving that makes A0 non-homogeneous."""
    A = np.array(PAPER["plant"]["A"])
    C = np.array(PAPER["plant"]["C"])
    n, k, nu = 4, 2, -1 / 3
    eye = np.eye(n)
    M = np.vstack([
        np.hstack([np.kron(A.T, eye) - np.kron(eye, A), np.kron(C.T, eye)]),
        np.hstack([np.kron(eye, C), np.zeros((k * n, n * k))]),
    ])
    sol = np.linalg.lstsq(M, np.concatenate([A.ravel("F"), np.zeros(k * n)]), rcond=None)[0]
    G0 = sol[: n * n].reshape(n, n, order="F")
    L0 = -np.linalg.solve(eye + G0, sol[n * n :].reshape(n, k, order="F"))
    A0, G_d = A + L0 @ C, eye + nu * (G0 + eye)
    assert np.linalg.norm(A0 @ G_d - (G_d + nu * eye) @ A0) > 1.0
    hom = homogenise(A, C, nu)
    A0 = A + hom.L0 @ C
    assert np.linalg.norm(A0 @ hom.G_d - (hom.G_d + nu * eye) @ A0) < 1e-9


def test_paper_gains_are_the_published_ones_and_certified(paper_design):
    assert np.array_equal(paper_design.L, np.array(PAPER["design"]["L"]))
    assert np.array_equal(paper_design.L_tilde, np.array(PAPER["design"]["L_tilde"]))
    assert np.array_equal(paper_design.L_lin, np.array(PAPER["linear_observer"]["L_lin"]))
    certify(paper_design)


def test_matched_perturbation_condition_for_pendulum(tuned_gains, paper_design):
    """Corollary 1: E = B satisfies (n_tilde + 1) G_d E = E, E = e1 does not; with the
    disturbance model, the model's unknown input dq/dt (entering the q state) satisfies it."""
    assert paper_design.certificate["matched_perturbation_residual"] < 1e-12
    e1 = np.eye(4)[:, :1]
    assert matched_perturbation_residual(paper_design.G_d, e1, 2) > 0.1
    assert tuned_gains.disturbance_order == 1 and tuned_gains.n_tilde == 3
    E_model = np.eye(5)[:, 4:]
    assert matched_perturbation_residual(tuned_gains.G_d, E_model, 3) < 1e-12
    assert tuned_gains.certificate["matched_perturbation_residual"] < 1e-12


def model_by_loops(A, C, E, order):
    """The observer's model entry by entry (the test's own construction, independent of the
    design's fhobs.core.disturbance and of the certificate's checked_model): x' = A x + E q1,
    q_j' = q_(j+1), q_order' = unknown; y = C x."""
    n, k = A.shape[0], C.shape[0]
    p = 0 if order == 0 else E.shape[1]
    size = n + order * p
    A_model, C_model = np.zeros((size, size)), np.zeros((k, size))
    for i in range(n):
        for j in range(n):
            A_model[i, j] = A[i, j]
        for j in range(p if order else 0):
            A_model[i, n + j] = E[i, j]
    for block in range(order - 1):
        for j in range(p):
            A_model[n + block * p + j, n + (block + 1) * p + j] = 1.0
    for i in range(k):
        for j in range(n):
            C_model[i, j] = C[i, j]
    return A_model, C_model


def augmented_by_loops(gains):
    """bar_A0, bar_G, bar_C of Theorem 2 from :func:`model_by_loops` and scipy's block_diag."""
    A_model, C_model = model_by_loops(gains.A, gains.C, gains.E, gains.disturbance_order)
    k, n = C_model.shape
    bar_A0 = np.zeros((k + n, k + n))
    bar_A0[:k, k:] = C_model
    bar_A0[k:, k:] = A_model + gains.L0 @ C_model
    bar_C = np.zeros((k, k + n))
    for i in range(k):
        bar_C[i, i] = 1.0
    return bar_A0, scipy.linalg.block_diag(np.eye(k), gains.G_d), bar_C


def closed_loop_error_matrix(gains) -> np.ndarray:
    """(psi, z - x) error system of Theorem 2 at sigma = 1: bar_A0 + bar_L bar_C."""
    bar_A0, _, bar_C = augmented_by_loops(gains)
    return bar_A0 + np.vstack([gains.L_tilde, gains.L]) @ bar_C


@pytest.mark.parametrize("order, p", [(0, 1), (1, 1), (2, 1), (3, 1), (1, 2), (3, 2)])
def test_the_three_model_constructions_agree(order, p):
    """The design's extended model, the certificate's own and the test's loops are equal."""
    rng = np.random.default_rng(order * 10 + p)
    A, B = rng.standard_normal((3, 3)), rng.standard_normal((3, 1))
    C, E = rng.standard_normal((2, 3)), rng.standard_normal((3, p))
    expected_A, expected_C = model_by_loops(A, C, E, order)
    design_A, _, design_C = extended_model(A, B, C, E, order)
    gains = SimpleNamespace(A=A, C=C, E=E, disturbance_order=order)
    checked_A, checked_C = checked_model(gains)
    for got in (design_A, checked_A):
        np.testing.assert_array_equal(got, expected_A)
    for got in (design_C, checked_C):
        np.testing.assert_array_equal(got, expected_C)


def test_the_design_and_certificate_augmented_systems_agree_with_the_tests(tuned_gains):
    g = tuned_gains
    expected = augmented_by_loops(g)
    for built in (augmented_matrices(g), augmented_system(g.A0, g.model[2], g.G_d)):
        for got, want in zip(built, expected, strict=True):
            np.testing.assert_array_equal(got, want)


def test_tuned_and_paper_error_systems_are_stable(tuned_gains, paper_design):
    ours = np.linalg.eigvals(closed_loop_error_matrix(tuned_gains))
    theirs = np.linalg.eigvals(closed_loop_error_matrix(paper_design))
    assert ours.size == 2 + 5 and theirs.size == 2 + 4  # (psi, model error) of each design
    assert np.max(ours.real) < 0 and np.max(theirs.real) < 0


def independent_lmi_check(P, H, G, rho):
    """Recompute an LMI's three inequalities with scipy (not the certificate module)."""
    P = 0.5 * (P + P.T)
    lhs = P @ (H + rho * G)
    return (
        scipy.linalg.eigh(P, eigvals_only=True)[0],
        scipy.linalg.eigh(P @ G + G.T @ P, eigvals_only=True)[0],
        scipy.linalg.eigh(lhs + lhs.T, eigvals_only=True)[-1],
    )


def random_spec(seed: int, n: int, k: int) -> dict:
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n)) / np.sqrt(n)
    C = rng.standard_normal((k, n))
    B = rng.standard_normal((n, 2))
    return {"A": A.tolist(), "B": B.tolist(), "C": C.tolist()}


FAST_RANDOM = {(2, 1), (4, 2), (8, 4)}
"""The fast subset's random plants: one and several outputs, up to n = 8."""
RANDOM_CASES = [
    (seed, n, k) if (n, k) in FAST_RANDOM else pytest.param(seed, n, k, marks=pytest.mark.slow)
    for seed, (n, k) in enumerate([(2, 1), (3, 1), (4, 2), (5, 2), (6, 3), (7, 2), (8, 4)])] + [
    pytest.param(seed, n, k, marks=pytest.mark.slow)
    for seed, n, k in ((7, 10, 3), (8, 12, 4), (9, 15, 3), (9, 16, 4), (9, 20, 4), (9, 20, 3))]


@pytest.mark.parametrize(("seed", "n", "k"), RANDOM_CASES)
def test_random_observable_plants(seed, n, k):
    data = random_spec(seed, n, k)
    spec = spec_from_dict(data, source=f"random seed {seed}")
    gains = design_for_spec(spec)
    A, C, nu, eye = spec.A, spec.C, spec.nu, np.eye(n)
    A0 = A + gains.L0 @ C
    scale = np.linalg.norm(A0) * np.linalg.norm(gains.G_d)
    assert np.linalg.norm(A0 @ gains.G_d - (gains.G_d + nu * eye) @ A0) <= 1e-8 * scale
    assert np.linalg.norm(C @ gains.G_d - (1 + nu) * C) <= 1e-9 * np.linalg.norm(C)
    assert np.linalg.norm(np.linalg.matrix_power(A0, gains.n_tilde)) <= (
        1e-8 * np.linalg.norm(A0) ** gains.n_tilde)
    assert np.min(np.linalg.eigvals(gains.G_d).real) > 0
    weights = np.sort(np.linalg.eigvals(gains.G_d).real)
    expected = np.sort([1 + nu + nu * j for j in range(gains.n_tilde)])
    assert np.allclose(np.unique(weights.round(8)), expected, atol=1e-7)
    bar_A0, bar_G, _ = augmented_by_loops(gains)
    p_min, mono, lmi = independent_lmi_check(
        gains.P_bar, closed_loop_error_matrix(gains), bar_G, gains.rho)
    assert p_min > 0 and mono > 0 and lmi < 0
    p_min, mono, lmi = independent_lmi_check(
        gains.P_pt, A0 + gains.L_pt @ C, gains.G_d - nu * eye, gains.rho)
    assert p_min > 0 and mono > 0 and lmi < 0
    assert np.max(np.linalg.eigvals(A + gains.L_lin @ C).real) < 0
    assert observability_index(A, C)[0] == gains.n_tilde


@pytest.mark.parametrize(
    ("field", "edit", "check"),
    [
        ("L", lambda g: -g.L, "lmi_filtering"),
        ("L_tilde", lambda g: -g.L_tilde, "lmi_filtering"),
        ("P_bar", lambda g: g.P_bar - 2 * np.linalg.norm(g.P_bar, 2) * np.eye(len(g.P_bar)),
         "P_bar_positive"),
        ("A", lambda g: g.A + np.diag([0, 0, 0.01, 0]), "homogenisation_residual"),
        ("G_d", lambda g: g.G_d + 0.01 * np.eye(g.n_model)[::-1], "output_homogeneity"),
        ("L_pt", lambda g: 0 * g.L_pt, "lmi_pt"),
        ("L_lin", lambda g: 0 * g.L_lin, "hurwitz_luenberger"),
        ("gamma", lambda g: 2 * g.rho + 0.1, "gamma_rho"),
    ],
)
def test_certificate_rejects_broken_designs(tuned_gains, field, edit, check):
    broken = dataclasses.replace(tuned_gains, **{field: edit(tuned_gains)})
    with pytest.raises(CertificateError, match=rf"{check} = [-+0-9.e]+ \(required"):
        certify(broken)


def test_design_rejects_a_broken_solver_result(monkeypatch, pendulum_spec):
    real = fhobs.design.observer.solve_gain_lmi

    def corrupted(*args, **kwargs):
        sol = real(*args, **kwargs)
        return LMISolution(sol.P, -sol.Y, -sol.gain, sol.status, sol.solve_time)

    monkeypatch.setattr(fhobs.design.observer, "solve_gain_lmi", corrupted)
    with pytest.raises(CertificateError, match="lmi_filtering"):
        design_for_spec(dataclasses.replace(pendulum_spec, filter_scale=1.0))


@pytest.mark.slow
def test_build_fmu_design_only_writes_design_json(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, str(REPO / "build_fmu.py"), str(EXAMPLES / "pendulum.toml"),
         "--design-only", "--out", str(out)],
        capture_output=True, text=True, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    design = json.loads((out / "design.json").read_text())
    for key in ("A", "B", "C", "nu", "rho", "gamma", "n_tilde", "L0", "G_d", "L_tilde", "L",
                "L_lin", "certificate"):
        assert key in design
    assert design["A"] == tomllib.loads((EXAMPLES / "pendulum.toml").read_text())["A"]
    assert design["disturbance_order"] == 1 and np.shape(design["L0"]) == (5, 2)
    assert design["certificate"]["checks"]["lmi_filtering"] < 0
    assert not list(out.glob("*.fmu"))


@pytest.mark.slow
def test_build_fmu_bad_spec_exit_code_and_message(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("A = [[0, 1], [0, 0]]\nB = [[0], [1]]\nC = [[0, 1]]\n")
    proc = subprocess.run(
        [sys.executable, str(REPO / "build_fmu.py"), str(bad), "--design-only",
         "--out", str(tmp_path / "o")],
        capture_output=True, text=True, check=False,
    )
    assert proc.returncode == 2
    assert "not observable" in proc.stderr and "rank 1" in proc.stderr
    assert not (tmp_path / "o").exists()


def test_filter_scale_multiplies_l_tilde_and_certifies_at_a_lower_rho(pendulum_spec):
    base = design_for_spec(dataclasses.replace(pendulum_spec, filter_scale=1.0))
    scaled = design_for_spec(dataclasses.replace(pendulum_spec, filter_scale=2.0))
    assert np.allclose(scaled.L_tilde, 2.0 * base.L_tilde)
    assert np.array_equal(scaled.L, base.L)
    assert pendulum_spec.gamma / 2 < scaled.rho < base.rho == pendulum_spec.rho
    certify(scaled)
