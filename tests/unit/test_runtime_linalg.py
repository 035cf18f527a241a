"""The runtime's numpy-only matrix functions against scipy."""

import numpy as np
import pytest
import scipy.linalg as sl
from fhobs.core.dilation import Dilation
from fhobs.core.injection import InjectionFlow
from fhobs.core.linalg import ExpmFamily, expm, phi1, zoh_blocks


@pytest.mark.parametrize("scale", [1e-6, 0.1, 1.0, 30.0, 80.0])
def test_expm_matches_scipy(scale):
    rng = np.random.default_rng(1)
    M = scale * rng.standard_normal((6, 6))
    ref = sl.expm(M)
    assert np.allclose(expm(M), ref, rtol=1e-11, atol=1e-13 * np.abs(ref).max())


def test_expm_nilpotent_is_polynomial():
    N = np.diag([1.0, 2.0, 3.0], k=1)
    assert np.allclose(expm(N), np.eye(4) + N + N @ N / 2 + N @ N @ N / 6, rtol=0, atol=1e-15)


def test_phi1_and_zoh_blocks_match_scipy():
    rng = np.random.default_rng(2)
    A, B, E = rng.standard_normal((4, 4)), rng.standard_normal((4, 1)), rng.standard_normal((4, 2))
    h = 0.3
    Phi, Gamma_B, Gamma_E = zoh_blocks(A, [B, E], h)
    assert np.allclose(Phi, sl.expm(h * A), rtol=1e-12)
    integral = np.linalg.solve(A, sl.expm(h * A) - np.eye(4))
    assert np.allclose(Gamma_B, integral @ B, rtol=1e-10, atol=1e-13)
    assert np.allclose(Gamma_E, integral @ E, rtol=1e-10, atol=1e-13)
    assert np.allclose(phi1(h * A), integral / h, rtol=1e-10)
    singular = np.diag([0.0, 1.0])
    assert np.allclose(phi1(singular), np.diag([1.0, np.e - 1.0]), rtol=1e-13)


@pytest.mark.parametrize("force_fallback", [False, True])
@pytest.mark.parametrize("tau", [0.0, 1e-9, 1e-3, 0.7, 40.0])
def test_expm_family_exp_and_phi1(force_fallback, tau):
    R = np.array([[-13.9, 0.0, 1.0, 0.0], [0.0, -13.9, 0.0, 1.0],
                  [-90.0, 0.0, 0.0, 0.0], [0.0, -90.0, 0.0, 0.0]])
    r = np.array([0.3, -1.0, 2.0, 0.5])
    family = ExpmFamily(R, force_fallback=force_fallback)
    assert family.use_eig is not force_fallback
    exp_r, integral_r = family.apply(tau, r)
    aug = np.zeros((5, 5))
    aug[:4, :4], aug[:4, 4] = tau * R, tau * r  # expm(aug)[:4, 4] = tau phi1(tau R) r
    ref = sl.expm(aug)
    assert np.allclose(exp_r, ref[:4, :4] @ r, rtol=1e-10, atol=1e-14)
    assert np.allclose(integral_r, ref[:4, 4], rtol=1e-10, atol=1e-14 * max(tau, 1e-9))
    exp_top, integral_top = family.apply(tau, r, rows=2)
    assert np.array_equal(exp_top, exp_r[:2]) and np.array_equal(integral_top, integral_r[:2])


def test_expm_family_falls_back_on_defective_matrix():
    jordan = np.array([[-1.0, 1.0], [0.0, -1.0]])
    family = ExpmFamily(jordan)
    assert not family.use_eig
    exp_r, _ = family.apply(2.0, np.array([0.0, 1.0]))
    assert np.allclose(exp_r, sl.expm(2.0 * jordan) @ [0.0, 1.0], rtol=1e-13)


@pytest.mark.parametrize("force_fallback", [False, True])
def test_dilation_matches_scipy(paper_design, force_fallback):
    dilation = Dilation(paper_design.model.G_d, force_fallback=force_fallback)
    with_gain = Dilation(paper_design.model.G_d, right=paper_design.filtering.L,
                         force_fallback=force_fallback)
    x = np.array([1.0, -2.0, 0.5, 3.0])
    for s in (-30.0, -1.0, 0.0, 2.0):
        ref = sl.expm(s * paper_design.model.G_d)
        ref_gain = ref @ paper_design.filtering.L @ x[:2]
        assert np.allclose(with_gain.apply(s, x[:2]), ref_gain, rtol=1e-10,
                           atol=1e-13 * np.abs(ref).max() * np.abs(paper_design.filtering.L).max())
        atol = 1e-13 * np.abs(ref).max()
        assert np.allclose(dilation.apply(s, x), ref @ x, rtol=1e-10, atol=atol * np.abs(x).max())
        assert np.allclose(dilation.matrix(s), ref, rtol=1e-10, atol=atol)


def flow_reference(L_tilde, L, C, G_d, nu, s, hs, psi, v):
    """``(psi(hs), dz)`` from scipy's expm of the unscaled linear system (psi, v, z-increment)
    with ``d psi = s^nu L_tilde psi + v``, ``dz = s^(nu-1) d(ln s) L psi``, ``dv = C dz``."""
    k, N = L_tilde.shape[0], G_d.shape[0]
    gain = (s ** (nu - 1.0) * sl.expm(np.log(s) * G_d) @ L).real
    system = np.zeros((2 * k + N, 2 * k + N))
    system[:k, :k], system[:k, k:2 * k] = s**nu * L_tilde, np.eye(k)
    system[k:2 * k, :k], system[2 * k:, :k] = C @ gain, gain
    ref = sl.expm(hs * system) @ np.concatenate((psi, v, np.zeros(N)))
    return ref[:k], ref[2 * k:]


def assert_flow_matches(flow, L_tilde, L, C, G_d, nu, levels, steps, seed=5):
    rng = np.random.default_rng(seed)
    for s in levels:
        for hs in steps:
            psi, v = rng.standard_normal(L_tilde.shape[0]), rng.standard_normal(C.shape[0])
            ref_psi, ref_dz = flow_reference(L_tilde, L, C, G_d, nu, s, hs, psi, v)
            psi_new, dz = flow.apply(psi, v, np.log(s), hs * s**nu)
            scale = max(np.abs(ref_psi).max(), np.abs(ref_dz).max())
            assert np.allclose(psi_new, ref_psi, rtol=1e-9, atol=1e-12 * scale)
            assert np.allclose(dz, ref_dz, rtol=1e-9, atol=1e-12 * scale)


@pytest.mark.parametrize("force_fallback", [False, True])
@pytest.mark.parametrize("design", ["paper_design", "tuned_design"])
def test_injection_flow_matches_scipy(request, design, force_fallback):
    """The frozen-level flow of (psi, z) against scipy's expm of the unscaled linear system:
    this also checks the scaling by ``C G_d = (1 + nu) C`` the flow relies on. The smallest
    tau reaches the series branch of phi1."""
    g = request.getfixturevalue(design)
    _, _, C = g.filtering.model_matrices
    flow = InjectionFlow(g.filtering.L_tilde, C, Dilation(g.model.G_d, right=g.filtering.L),
                         g.model.nu,
                         force_fallback=force_fallback)
    assert flow.eigen is not force_fallback
    assert_flow_matches(flow, g.filtering.L_tilde, g.filtering.L, C, g.model.G_d, g.model.nu,
                        levels=(1e-3, 0.7, 40.0, 3e4), steps=(5e-5, 1e-13))


@pytest.mark.parametrize("force_fallback", [False, True])
@pytest.mark.parametrize("case", ["complex_G_d", "singular_R", "complex_R"])
def test_injection_flow_synthetic_spectra(case, force_fallback):
    """Spectra the pendulum does not have: complex eigenvalues of G_d, a singular R (C L = 0:
    phi1's series at every tau) and complex eigenvalues of R. G_d is built with
    ``C G_d = (1 + nu) C`` (C's rows span a left eigenspace of eigenvalue 1 + nu)."""
    nu = -0.25
    C = np.array([[1.0, 0.0, 0.0]])
    rotation = np.array([[0.5, 0.3], [-0.3, 0.5]]) if case == "complex_G_d" else np.diag([0.5, 0.7])
    G_d = np.zeros((3, 3))
    G_d[0, 0], G_d[1:, 1:], G_d[1:, 0] = 1.0 + nu, rotation, [0.2, -0.1]
    assert np.allclose(C @ G_d, (1.0 + nu) * C)
    L = {"complex_G_d": np.array([[-3.0], [-2.0], [-1.0]]),
         "singular_R": np.array([[0.0], [-2.0], [-1.0]]),
         "complex_R": np.array([[-900.0], [-2.0], [-1.0]])}[case]
    L_tilde = np.array([[-4.0]])
    flow = InjectionFlow(L_tilde, C, Dilation(G_d, right=L), nu, force_fallback=force_fallback)
    assert flow.eigen is not force_fallback
    assert_flow_matches(flow, L_tilde, L, C, G_d, nu, levels=(1e-2, 1.0, 50.0),
                        steps=(5e-5, 1e-3, 1e-13))
