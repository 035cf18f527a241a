"""Design core: pendulum reproduction, identities and certificates on random plants,
rejection of broken solver results, and the design.json contract of build_fmu.py."""

import dataclasses
import importlib
import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path
from types import SimpleNamespace

import fhobs.design.observer
import numpy as np
import pytest
import scipy.linalg
from designs import edited_design
from fhobs.build import build_fmus
from fhobs.core.certificate import (
    augmented_matrices,
    certify,
    certify_filtering,
    certify_kalman,
    certify_luenberger,
    certify_prescribed_time,
    checked_model,
)
from fhobs.core.disturbance import extended_model
from fhobs.core.gains import PlantModel
from fhobs.design.homogenisation import homogenise, observability_index
from fhobs.design.lmi import LMISolution
from fhobs.design.observer import augmented_system, design_for_spec, matched_perturbation_residual
from fhobs.design.spec import DEFAULT_OBJECTIVE, spec_from_dict
from fhobs.errors import CertificateError
from fhobs.fmu.kinds import KINDS
from fhobs.native.build import build_native_fmus
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
    ours = getattr(paper_design.model, name)
    tol = np.vectorize(printed_tolerance)(published)
    assert np.all(np.abs(ours - published) <= tol + 1e-12), ours - published
    assert paper_design.model.n_tilde == 2


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
    assert np.array_equal(paper_design.filtering.L, np.array(PAPER["design"]["L"]))
    assert np.array_equal(paper_design.filtering.L_tilde, np.array(PAPER["design"]["L_tilde"]))
    assert np.array_equal(paper_design.luenberger.L_lin,
                          np.array(PAPER["linear_observer"]["L_lin"]))
    certify(paper_design)


def test_paper_design_reports_how_each_record_was_made(paper_design):
    """The published gains' report says so (no solver); L_pt, designed by Theorem 1's LMI, has
    that LMI's objective and solve status; the given L_lin its checks alone."""
    filtering = paper_design.filtering.certificate
    assert filtering["objective"] == "published" and "solver_status" not in filtering
    prescribed_time = paper_design.prescribed_time.certificate
    assert prescribed_time["objective"] == DEFAULT_OBJECTIVE
    assert prescribed_time["solver_status"] in ("optimal", "optimal_inaccurate")
    assert prescribed_time["lmi_margin"] > 0
    assert prescribed_time["checks"] == certify_prescribed_time(paper_design.prescribed_time)
    assert set(paper_design.luenberger.certificate) == {"checks"}


def test_matched_perturbation_condition_for_pendulum(tuned_design, paper_design):
    """Corollary 1: E = B satisfies (n_tilde + 1) G_d E = E, E = e1 does not; with the
    disturbance model, the model's unknown input dq/dt (entering the q state) satisfies it."""
    assert paper_design.filtering.certificate["matched_perturbation_residual"] < 1e-12
    e1 = np.eye(4)[:, :1]
    assert matched_perturbation_residual(paper_design.model.G_d, e1, 2) > 0.1
    assert tuned_design.model.disturbance_order == 1 and tuned_design.model.n_tilde == 3
    E_model = np.eye(5)[:, 4:]
    assert matched_perturbation_residual(tuned_design.model.G_d, E_model, 3) < 1e-12
    assert tuned_design.filtering.certificate["matched_perturbation_residual"] < 1e-12


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
    A_model, C_model = model_by_loops(gains.plant.A, gains.plant.C, gains.plant.E,
                                      gains.model.disturbance_order)
    k, n = C_model.shape
    bar_A0 = np.zeros((k + n, k + n))
    bar_A0[:k, k:] = C_model
    bar_A0[k:, k:] = A_model + gains.model.L0 @ C_model
    bar_C = np.zeros((k, k + n))
    for i in range(k):
        bar_C[i, i] = 1.0
    return bar_A0, scipy.linalg.block_diag(np.eye(k), gains.model.G_d), bar_C


def closed_loop_error_matrix(gains) -> np.ndarray:
    """(psi, z - x) error system of Theorem 2 at sigma = 1: bar_A0 + bar_L bar_C."""
    bar_A0, _, bar_C = augmented_by_loops(gains)
    return bar_A0 + np.vstack([gains.filtering.L_tilde, gains.filtering.L]) @ bar_C


@pytest.mark.parametrize("order, p", [(0, 1), (1, 1), (2, 1), (3, 1), (1, 2), (3, 2)])
def test_the_three_model_constructions_agree(order, p):
    """The design's extended model, the certificate's own and the test's loops are equal."""
    rng = np.random.default_rng(order * 10 + p)
    A, B = rng.standard_normal((3, 3)), rng.standard_normal((3, 1))
    C, E = rng.standard_normal((2, 3)), rng.standard_normal((3, p))
    expected_A, expected_C = model_by_loops(A, C, E, order)
    design_A, _, design_C = extended_model(A, B, C, E, order)
    checked_A, checked_C = checked_model(PlantModel(A, B, C, E), order)
    for got in (design_A, checked_A):
        np.testing.assert_array_equal(got, expected_A)
    for got in (design_C, checked_C):
        np.testing.assert_array_equal(got, expected_C)


def test_the_design_and_certificate_augmented_systems_agree_with_the_tests(tuned_design):
    g = tuned_design
    expected = augmented_by_loops(g)
    for built in (augmented_matrices(g.filtering),
                  augmented_system(g.filtering.A0, g.filtering.model_matrices[2], g.model.G_d)):
        for got, want in zip(built, expected, strict=True):
            np.testing.assert_array_equal(got, want)


def test_tuned_and_paper_error_systems_are_stable(tuned_design, paper_design):
    ours = np.linalg.eigvals(closed_loop_error_matrix(tuned_design))
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
    A0 = A + gains.model.L0 @ C
    scale = np.linalg.norm(A0) * np.linalg.norm(gains.model.G_d)
    assert np.linalg.norm(A0 @ gains.model.G_d - (gains.model.G_d + nu * eye) @ A0) <= 1e-8 * scale
    assert np.linalg.norm(C @ gains.model.G_d - (1 + nu) * C) <= 1e-9 * np.linalg.norm(C)
    assert np.linalg.norm(np.linalg.matrix_power(A0, gains.model.n_tilde)) <= (
        1e-8 * np.linalg.norm(A0) ** gains.model.n_tilde)
    assert np.min(np.linalg.eigvals(gains.model.G_d).real) > 0
    weights = np.sort(np.linalg.eigvals(gains.model.G_d).real)
    expected = np.sort([1 + nu + nu * j for j in range(gains.model.n_tilde)])
    assert np.allclose(np.unique(weights.round(8)), expected, atol=1e-7)
    bar_A0, bar_G, _ = augmented_by_loops(gains)
    p_min, mono, lmi = independent_lmi_check(
        gains.filtering.P_bar, closed_loop_error_matrix(gains), bar_G, gains.filtering.rho)
    assert p_min > 0 and mono > 0 and lmi < 0
    pt = gains.prescribed_time
    p_min, mono, lmi = independent_lmi_check(
        pt.P_pt, A0 + pt.L_pt @ C, gains.model.G_d - nu * eye, pt.rho)
    assert p_min > 0 and mono > 0 and lmi < 0
    assert np.max(np.linalg.eigvals(A + gains.luenberger.L_lin @ C).real) < 0
    assert observability_index(A, C)[0] == gains.model.n_tilde


CERTIFY = {"filtering": certify_filtering, "prescribed_time": certify_prescribed_time,
           "luenberger": certify_luenberger, "kalman": certify_kalman}


@pytest.mark.parametrize(
    ("path", "edit", "check", "records"),
    [
        ("filtering.L", lambda g: -g.filtering.L, "lmi_filtering", ("filtering",)),
        ("filtering.L_tilde", lambda g: -g.filtering.L_tilde, "lmi_filtering", ("filtering",)),
        ("filtering.P_bar", lambda g: g.filtering.P_bar - 2 * np.linalg.norm(g.filtering.P_bar, 2)
         * np.eye(len(g.filtering.P_bar)), "P_bar_positive", ("filtering",)),
        ("plant.A", lambda g: g.plant.A + np.diag([0, 0, 0.01, 0]), "homogenisation_residual",
         ("filtering", "prescribed_time")),
        ("model.G_d", lambda g: g.model.G_d + 0.01 * np.eye(g.model.n_model)[::-1],
         "output_homogeneity", ("filtering", "prescribed_time")),
        ("prescribed_time.L_pt", lambda g: 0 * g.prescribed_time.L_pt, "lmi_pt",
         ("prescribed_time",)),
        ("luenberger.L_lin", lambda g: 0 * g.luenberger.L_lin, "hurwitz_luenberger",
         ("luenberger",)),
        ("kalman.gain", lambda g: -g.kalman.gain, "schur_kalman", ("kalman",)),
    ],
)
def test_certificate_rejects_broken_designs(kalman_design, path, edit, check, records):
    """certify of the whole design and the certificate of each record that holds the edited
    field (the shared plant and model: every homogeneous record's) name the failed check."""
    broken = edited_design(kalman_design, path, edit(kalman_design))
    failing = re.compile(rf"{check} = [-+0-9.e]+ \(required")
    with pytest.raises(CertificateError, match=failing):
        certify(broken)
    for name in records:
        with pytest.raises(CertificateError, match=failing):
            CERTIFY[name](getattr(broken, name))


def slave_check(kind: str, record) -> None:
    """The gain check the pythonfmu slave of ``kind`` makes at initialisation, on ``record``
    as its edited parameters (the prescribed-time slave's xi0 of its default T0 = 1 s): the
    slave class of its own module, else the generic observer slave."""
    declared = KINDS[kind]
    module = importlib.import_module(f"fhobs.fmu.{declared.slave_module or 'slave_base'}")
    slave = getattr(module, declared.slave if declared.slave_module else "ObserverSlave")
    stub = SimpleNamespace(kind=declared, edited_record=lambda: record,
                           array=lambda name: np.array(1.0))
    slave._check_gains(stub)


@pytest.mark.parametrize(
    ("path", "edit", "kinds", "words"),
    [
        ("filtering.gamma", lambda g: -1.0, ("observer",), "gamma = -1.0 must be > 0"),
        ("filtering.gamma", lambda g: 0.0, ("observer",), "gamma = 0.0 must be > 0"),
        ("filtering.rho", lambda g: g.filtering.gamma / 2, ("observer",), "must be > gamma/2"),
        ("model.nu", lambda g: -0.9, ("observer", "prescribed_time"), "nu = -0.9 is outside"),
        ("model.nu", lambda g: 0.1, ("observer", "prescribed_time"), "nu = 0.1 is outside"),
        ("prescribed_time.rho", lambda g: -1.0, ("prescribed_time",), "rho = -1.0 must be > 0"),
        ("prescribed_time.L_pt", lambda g: -g.prescribed_time.L_pt, ("prescribed_time",),
         "lmi_pt"),
        ("filtering.L", lambda g: -g.filtering.L, ("observer",), "lmi_filtering"),
        ("luenberger.L_lin", lambda g: 0 * g.luenberger.L_lin, ("luenberger",),
         "hurwitz_luenberger"),
        ("kalman.gain", lambda g: -g.kalman.gain, ("kalman",), "schur_kalman"),
    ],
)
def test_what_an_fmu_refuses_certify_and_the_builds_refuse(kalman_design, tmp_path, path, edit,
                                                          kinds, words):
    """Whatever a slave refuses at initialisation (its tuning ranges, a broken gain) certify
    refuses too, and so do both builds before building anything: a native FMU, which does not
    check its design again, never runs a model that skipped its certificate."""
    broken = edited_design(kalman_design, path, edit(kalman_design))
    for kind in kinds:
        with pytest.raises(CertificateError, match=re.escape(words)):
            slave_check(kind, KINDS[kind].runs(broken))
    with pytest.raises(CertificateError, match=re.escape(words)):
        certify(broken)
    with pytest.raises(CertificateError, match=re.escape(words)):
        build_native_fmus(broken, tmp_path / "native")
    with pytest.raises(CertificateError, match=re.escape(words)):
        build_fmus(broken, tmp_path / "pythonfmu", status_wrapper=False, kernel=False)
    assert not any(tmp_path.iterdir())


def test_design_rejects_a_broken_solver_result(monkeypatch, pendulum_spec):
    monkeypatch.setenv("FHOBS_NO_DESIGN_CACHE", "1")  # the solver runs, the cache aside
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
    for record, keys in {"plant": ("A", "B", "C", "E"), "model": ("nu", "n_tilde", "L0", "G_d"),
                         "filtering": ("rho", "gamma", "L_tilde", "L", "P_bar", "certificate"),
                         "prescribed_time": ("rho", "L_pt", "P_pt", "certificate"),
                         "luenberger": ("L_lin", "certificate"), "kalman": ("gain",)}.items():
        for key in keys:
            assert key in design[record], (record, key)
    for record in ("filtering", "prescribed_time", "luenberger", "kalman"):
        assert "plant" not in design[record] and "model" not in design[record]
    assert design["plant"]["A"] == tomllib.loads((EXAMPLES / "pendulum.toml").read_text())["A"]
    assert design["model"]["disturbance_order"] == 1 and np.shape(design["model"]["L0"]) == (5, 2)
    assert design["filtering"]["certificate"]["checks"]["lmi_filtering"] < 0
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
    assert np.allclose(scaled.filtering.L_tilde, 2.0 * base.filtering.L_tilde)
    assert np.array_equal(scaled.filtering.L, base.filtering.L)
    assert pendulum_spec.gamma / 2 < scaled.filtering.rho < base.filtering.rho == pendulum_spec.rho
    certify(scaled)
