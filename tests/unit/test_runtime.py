"""Maths of the discrete-time observers (fhobs.core.runtime) against independent scipy."""

import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg as sl
from designs import whole_model_design, zoo_design
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import (
    AMPLIFICATION_LIMIT,
    SCHEMES,
    FilteringObserver,
    LuenbergerObserver,
    PrescribedTimeObserver,
    spectral_radius,
)
from fhobs.paper import K_PAPER, X0_PAPER
from scipy.integrate import solve_ivp


def d_scipy(G, s):
    """d(s) = expm(s G) by scipy (independent of fhobs.core.dilation)."""
    return sl.expm(s * G)


def augmented(g):
    """bar_A0, bar_G, bar_L, bar_C of Theorem 2."""
    k, n = g.plant.k, g.plant.n
    bar_A0 = np.block([[np.zeros((k, k)), g.plant.C], [np.zeros((n, k)), g.filtering.A0]])
    bar_G = sl.block_diag(np.eye(k), g.model.G_d)
    bar_L = np.vstack([g.filtering.L_tilde, g.filtering.L])
    bar_C = np.hstack([np.eye(k), np.zeros((k, n))])
    return bar_A0, bar_G, bar_L, bar_C


def test_numpy_only_modules_do_not_import_scipy():
    code = ("import sys, fhobs.core.runtime, fhobs.core.plant; "
            "bad = [m for m in ('scipy', 'cvxpy', 'matplotlib') if m in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("s", [1e-6, 1e-2, 0.7, 5.0])
def test_frozen_gain_identity_of_the_notes(paper_design, s):
    """expm(h M(s)) = bar_d(ln s) expm(h s^nu H) bar_d(-ln s), H = bar_A0 + bar_L bar_C."""
    g, h = paper_design, 5e-3
    bar_A0, bar_G, bar_L, bar_C = augmented(g)
    D = d_scipy(bar_G, np.log(s))
    M = bar_A0 + s ** (g.model.nu - 1.0) * D @ bar_L @ bar_C
    rhs = D @ sl.expm(h * s**g.model.nu * (bar_A0 + bar_L @ bar_C)) @ np.linalg.inv(D)
    assert np.allclose(sl.expm(h * M), rhs, rtol=1e-8, atol=1e-9 * np.abs(rhs).max())


def scipy_error_map(g, level, h):
    """Split step on (psi, z - x), built from scipy: ZOH prediction after the exact flow of
    the injection (dpsi = C e + s^nu L_tilde psi, de = s^(nu-1) d(ln s) L psi)."""
    k, n = g.plant.k, g.model.n_model
    A, _, C = g.filtering.model_matrices
    D = d_scipy(g.model.G_d, np.log(level))
    injection = np.block([[level**g.model.nu * g.filtering.L_tilde, C],
                          [level ** (g.model.nu - 1.0) * D @ g.filtering.L, np.zeros((n, n))]])
    aug = np.zeros((n + k, n + k))
    aug[:n, :n], aug[:n, n:] = A, g.model.L0
    E = sl.expm(h * aug)
    prediction = sl.block_diag(np.eye(k), E[:n, :n] + E[:n, n:] @ C)
    return prediction @ sl.expm(h * injection)


def dilated(g, level, M):
    """``S^-1 M S`` with ``S = diag(level I_k, d(ln level))``, the dilation of (psi, z - x)."""
    S = sl.block_diag(level * np.eye(g.plant.k), d_scipy(g.model.G_d, np.log(level)))
    return np.linalg.solve(S, M @ S)


@pytest.mark.parametrize("tau", [1e-4, 1e-2, 0.3])
def test_split_error_map_matches_scipy(paper_design, tau):
    """The runtime's dilated error map of one split step equals the scipy construction."""
    dt = 5e-5
    obs = FilteringObserver(paper_design.filtering, h=dt)
    level = (tau / dt) ** (1.0 / paper_design.model.nu)
    ref = dilated(paper_design, level, scipy_error_map(paper_design, level, dt))
    assert np.allclose(obs.error_map(level, dt), ref, rtol=1e-7, atol=1e-9 * np.abs(ref).max())


@pytest.mark.parametrize("dt", [5e-5, 1e-3])
def test_gain_cap_makes_every_level_above_the_floor_contractive(paper_design, tuned_design, dt):
    """For the communication step dt, the dilated error map (scipy construction) contracts at
    the floor and at every level above it; far below the floor it does not."""
    for g in (paper_design, tuned_design):
        floor = FilteringObserver(g.filtering, h=dt)._floor(dt)
        for factor in (1.0, 10.0, 1e3, 1e6):
            level = factor * floor
            radius = spectral_radius(dilated(g, level, scipy_error_map(g, level, dt)))
            assert radius < 1.0, (factor, radius)
        low = 1e-9 * floor
        assert spectral_radius(dilated(g, low, scipy_error_map(g, low, dt))) > 1.0


def continuous_rhs(g, t, state):
    """Plant (u = 0, q = 0) + filtering observer on its model (the plant's, or the extended one
    of a disturbance model) with the continuous output y = C x (scipy expm)."""
    n, n_model, k = g.plant.n, g.model.n_model, g.plant.k
    A_model, _, C_model = g.filtering.model_matrices
    x, z, psi, xi = state[:n], state[n:n + n_model], state[n + n_model:-1], state[-1]
    assert psi.size == k
    sigma = np.sqrt(max(xi, psi @ psi / 2))
    v = C_model @ z - g.plant.C @ x
    dpsi = v + sigma**g.model.nu * g.filtering.L_tilde @ psi
    dz = (A_model @ z + g.model.L0 @ v
          + sigma ** (g.model.nu - 1) * d_scipy(g.model.G_d, np.log(sigma)) @ g.filtering.L @ psi)
    w = xi - psi @ psi / 2
    dxi = abs(psi @ dpsi) - g.filtering.gamma * np.sign(w) * abs(w) ** (g.model.nu / 2 + 1)
    return np.concatenate([g.plant.A @ x, dz, dpsi, [dxi]])


def discrete_run(g, scheme, h, t_end, z0, psi0, xi0):
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, x0=X0_PAPER)
    obs = FilteringObserver(g.filtering, h=h, scheme=scheme, z0=z0, psi0=psi0, xi0=xi0)
    for _ in range(int(round(t_end / h))):
        y = plant.y
        plant.step([0.0], None, h)
        obs.step(y, [0.0], h)
    return np.concatenate([obs.z, obs.diagnostics()["psi"]]), plant.x


@pytest.mark.parametrize("design", ["paper_design", "tuned_design"])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_scheme_converges_to_fine_step_reference(request, design, scheme):
    """Short horizon, sigma away from 0: both schemes approach the solve_ivp solution of the
    continuous plant + observer at first order in h (the paper's design and ours, whose
    observer runs on the extended model of its disturbance model)."""
    g = request.getfixturevalue(design)
    z0 = np.concatenate([[1.0, 1.5], np.zeros(g.model.n_model - 2)])
    psi0, xi0, t_end = np.array([0.5, -0.3]), 0.5, 0.05
    state0 = np.concatenate([X0_PAPER, z0, psi0, [xi0]])
    sol = solve_ivp(lambda t, s: continuous_rhs(g, t, s), (0.0, t_end), state0,
                    method="DOP853", rtol=1e-11, atol=1e-12)
    ref = sol.y[g.plant.n:-1, -1]
    errors = []
    for h in (2e-4, 1e-4):
        zpsi, x = discrete_run(g, scheme, h, t_end, z0, psi0, xi0)
        assert np.allclose(x, sol.y[:g.plant.n, -1], rtol=1e-8)
        errors.append(np.linalg.norm(zpsi - ref) / np.linalg.norm(ref))
    assert errors[1] < 2e-3
    assert 1.6 < errors[0] / errors[1] < 2.5


def test_luenberger_split_is_the_closed_form_sampled_error(paper_design):
    """At a step whose held-innovation error map contracts (this one), e_k = (expm(h A) +
    int_0^h expm(tA) dt L_lin C)^k e_0 exactly, whatever u does, and it approaches the
    continuous expm(t (A + L_lin C)) e_0 as h -> 0."""
    g, h, steps = paper_design, 1e-3, 500
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, x0=X0_PAPER)
    obs = LuenbergerObserver(g.luenberger, h=h)
    assert obs.holds_innovation(h)
    for k in range(steps):
        u = [0.3 * np.sin(7.0 * k * h)]
        y = plant.y
        plant.step(u, None, h)
        obs.step(y, u, h)
    assert np.allclose(obs.z - plant.x, sampled_error(g, h, steps), rtol=1e-8, atol=1e-10)
    e_cont = sl.expm(steps * h * (g.plant.A + g.luenberger.L_lin @ g.plant.C)) @ -X0_PAPER
    gaps = [np.linalg.norm(sampled_error(g, hh, round(steps * h / hh)) - e_cont)
            for hh in (h, h / 10)]
    assert gaps[0] < 0.1 * np.linalg.norm(e_cont) and 8.0 < gaps[0] / gaps[1] < 12.0


def sampled_error(g, h, steps):
    """(expm(h A) + int_0^h expm(t A) dt L_lin C)^steps e_0 with e_0 = -x0 (scipy)."""
    aug = np.zeros((2 * g.plant.n, 2 * g.plant.n))
    aug[:g.plant.n, :g.plant.n], aug[:g.plant.n, g.plant.n:] = g.plant.A, np.eye(g.plant.n)
    Gamma = sl.expm(h * aug)[:g.plant.n, g.plant.n:]
    F = sl.expm(h * g.plant.A) + Gamma @ g.luenberger.L_lin @ g.plant.C
    return np.linalg.matrix_power(F, steps) @ -X0_PAPER


def test_luenberger_euler_is_explicit_euler(paper_design):
    g, h, steps = paper_design, 1e-4, 300
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, x0=X0_PAPER, scheme="euler")
    obs = LuenbergerObserver(g.luenberger, h=h, scheme="euler")
    for _ in range(steps):
        y = plant.y
        plant.step([0.5], None, h)
        obs.step(y, [0.5], h)
    F = np.eye(g.plant.n) + h * (g.plant.A + g.luenberger.L_lin @ g.plant.C)
    assert np.allclose(obs.z - plant.x, np.linalg.matrix_power(F, steps) @ -X0_PAPER,
                       rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("design", ["paper_design", "tuned_design"])
def test_xi_invariant_after_t_delta(request, design):
    """xi >= |psi|^2/2 once w = xi - |psi|^2/2 has reached 0 (T_delta = |w0|^(1-p)/((1-p) gamma)
    for w0 < 0, p = nu/2 + 1), and it is then kept by the split scheme to round-off: the
    kernel sums |psi|^2 with fused multiply-adds, numpy's dot of a short vector may not, so
    the two can differ by an ulp or two."""
    g, h = request.getfixturevalue(design), 5e-5
    p = g.model.nu / 2 + 1
    xi0 = -1e-4
    t_delta = abs(xi0) ** (1 - p) / ((1 - p) * g.filtering.gamma)
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, x0=X0_PAPER)
    obs = FilteringObserver(g.filtering, h=h, xi0=xi0)
    gaps = []
    for k in range(int(round(0.8 / h))):
        y, u = plant.y, K_PAPER @ obs.x_hat
        plant.step(u, None, h)
        obs.step(y, u, h)
        d = obs.diagnostics()
        half = 0.5 * d["psi"] @ d["psi"]
        gaps.append((k + 1) * h > t_delta and d["xi"] < half - 4 * np.spacing(half))
    assert 0.3 < t_delta < 0.6 and not any(gaps)


@pytest.mark.parametrize("design", ["paper_design", "tuned_design"])
def test_edges_stay_finite(request, design):
    g = request.getfixturevalue(design)
    for scheme in SCHEMES:
        obs = FilteringObserver(g.filtering, scheme=scheme)
        obs.step(np.zeros(2), [0.0], 5e-5)  # sigma = 0 and zero innovation
        expected = np.zeros(g.model.n_model + g.plant.k + 1)
        if scheme == "split":  # xi carries the step's gain-level floor (squared)
            expected[-1] = obs._floor(5e-5) ** 2
        assert np.array_equal(obs.get_state(), expected)
        for y in ([1e6, -1e6], [1e-14, 0.0], [0.0, 0.0], [3.0, 2.0]):
            for _ in range(50):
                obs.step(np.array(y), [0.0], 5e-5)
            assert np.all(np.isfinite(obs.get_state()))
    pt = PrescribedTimeObserver(g.prescribed_time, xi0=0.0)  # xi = 0: capped gain, no 0 * inf
    pt.step([1.0, 1.0], [0.0], 1e-3)
    assert np.all(np.isfinite(pt.get_state()))


def closed_loop_pt(g, h, t_end, xi0):
    """Plant stabilised by u = K x, prescribed-time observer from zero."""
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, x0=X0_PAPER)
    obs = PrescribedTimeObserver(g.prescribed_time, h=h, xi0=xi0)
    errors, xis = [], []
    for _ in range(int(round(t_end / h))):
        y, u = plant.y, K_PAPER @ plant.x
        plant.step(u, None, h)
        obs.step(y, u, h)
        errors.append(np.linalg.norm(obs.z - plant.x))
        xis.append(obs.diagnostics()["xi"])
    return np.array(errors), np.array(xis)


def test_prescribed_time_observer_through_t0(paper_design):
    g, h, xi0 = paper_design, 1e-4, 0.125
    t0 = xi0 ** (-g.model.nu) / (-g.model.nu * g.filtering.rho)
    errors, xis = closed_loop_pt(g, h, 1.5, xi0)
    t = h * np.arange(1, errors.size + 1)
    assert abs(t0 - 1.0) < 1e-12 and np.all(np.isfinite(errors))
    assert np.all(xis[t >= t0 + h] == 0.0) and np.all(xis[t < t0 - h] > 0.0)
    assert errors[np.searchsorted(t, 0.3)] > 1e-2  # still converging ...
    assert errors[-1] < 1e-9  # ... and at round-off after T0


def test_state_round_trip_is_bit_exact(paper_design):
    g = paper_design
    for make in (lambda: FilteringObserver(g.filtering),
                 lambda: PrescribedTimeObserver(g.prescribed_time),
                 lambda: LuenbergerObserver(g.luenberger)):
        obs = make()
        obs.step([1.0, 2.0], [0.1], 1e-3)
        saved = obs.get_state()
        first = [(obs.step([1.0 + 0.1 * i, 2.0], [0.1], 1e-3), obs.get_state())[1]
                 for i in range(4)]
        obs.set_state(saved)
        again = [(obs.step([1.0 + 0.1 * i, 2.0], [0.1], 1e-3), obs.get_state())[1]
                 for i in range(4)]
        assert np.array_equal(np.array(first), np.array(again))


@pytest.mark.parametrize("y, u, dt", [([np.nan, 0.0], [0.0], 1e-3), ([1.0], [0.0], 1e-3),
                                      ([0.0, 0.0], [np.inf], 1e-3), ([0.0, 0.0], [0.0], 0.0)])
def test_invalid_inputs_raise_and_leave_state(paper_design, y, u, dt):
    obs = FilteringObserver(paper_design.filtering, psi0=[0.1, 0.2], xi0=0.3)
    saved = obs.get_state()
    with pytest.raises(ValueError):
        obs.step(y, u, dt)
    assert np.array_equal(obs.get_state(), saved)


@pytest.mark.parametrize("numpy_errors", ["ignore", "warn", "raise"])
@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy's own, under "warn"
def test_divergence_raises_instead_of_inf(paper_design, numpy_errors):
    """Whatever numpy's floating-point error handling of the caller, a diverging step raises
    ValueError and leaves the last finite state."""
    obs = LuenbergerObserver(paper_design.luenberger, h=1.0, scheme="euler")
    saved = obs.get_state()
    with np.errstate(all=numpy_errors), pytest.raises(ValueError,
                                                      match="diverged|floating-point error"):
        for _ in range(100):
            obs.step([1e300, 1e300], [0.0], 1.0)
            saved = obs.get_state()
    assert np.array_equal(obs.get_state(), saved) and np.all(np.isfinite(saved))


@pytest.mark.parametrize("dt", [1e4, 1e300])
def test_absurd_step_size_raises_value_error(paper_design, dt):
    """A finite but absurd step size (more than MAX_SUBSTEPS internal steps of h = 5e-5) is a
    ValueError, the state untouched."""
    obs = FilteringObserver(paper_design.filtering, psi0=[0.1, 0.2], xi0=0.3)
    saved = obs.get_state()
    with pytest.raises(ValueError, match="internal steps"):
        obs.step([0.0, 0.0], [0.0], dt)
    assert np.array_equal(obs.get_state(), saved)


@pytest.mark.parametrize(("cls", "record"), [(FilteringObserver, "filtering"),
                                             (PrescribedTimeObserver, "prescribed_time"),
                                             (LuenbergerObserver, "luenberger")])
def test_advance_is_step_without_checks(tuned_design, cls, record):
    """advance (the FMU slaves' call) gives bit for bit what step gives for valid arguments."""
    gains = getattr(tuned_design, record)
    checked, unchecked = cls(gains), cls(gains)
    rng = np.random.default_rng(3)
    for y, u in zip(rng.standard_normal((50, tuned_design.plant.k)),
                    rng.standard_normal((50, tuned_design.plant.m)), strict=True):
        checked.step(list(y), list(u), 1e-4)
        unchecked.advance(y, u, 1e-4)
    assert np.array_equal(checked.get_state(), unchecked.get_state())


def test_unknown_scheme_is_rejected(paper_design):
    with pytest.raises(ValueError, match="scheme"):
        FilteringObserver(paper_design.filtering, scheme="rk4")


def test_step_without_a_contractive_gain_level_is_refused():
    """maglev (unstable mode +44 rad/s), every mode homogenised, at dt = 0.1: no gain level
    makes the sampled observer contract; the step says so (ValueError, state unchanged) instead
    of diverging silently."""
    obs = FilteringObserver(whole_model_design("maglev").filtering, psi0=[0.1], xi0=0.3)
    saved = obs.get_state()
    with pytest.raises(ValueError, match="no gain level makes the split step of size 0.1"):
        obs.step([0.01], [0.0], 0.1)
    assert np.array_equal(obs.get_state(), saved)


def test_ceiling_where_small_gains_do_not_contract():
    """maglev, every mode homogenised, at dt = 1e-3: the dilated map (scipy construction) does
    not contract for the smallest taus, so the level gets a ceiling; at the ceiling and the
    floor it contracts."""
    g = whole_model_design("maglev")
    dt = 1e-3
    obs = FilteringObserver(g.filtering, h=dt)
    floor, ceiling = obs._floor(dt), obs._ceiling(dt)
    assert np.isfinite(ceiling) and ceiling > floor
    for level in (floor, ceiling):
        assert spectral_radius(dilated(g, level, scipy_error_map(g, level, dt))) < 1.0
    huge = 1e6 * ceiling
    assert spectral_radius(dilated(g, huge, scipy_error_map(g, huge, dt))) > 1.0


@pytest.mark.slow
def test_roundoff_floor_bounds_the_output_amplification():
    """spring_chain3 (n_tilde = 6): the floor keeps ||C|| ||d(ln s)|| / s^(1+nu) at or below
    AMPLIFICATION_LIMIT (d from scipy's expm); the contraction floor alone would not."""
    g = zoo_design("spring_chain3")
    dt = 1e-3
    obs = FilteringObserver(g.filtering, h=dt)
    floor = obs._floor(dt)

    def amplification(s):
        return (np.linalg.norm(g.plant.C, 2) * np.linalg.norm(d_scipy(g.model.G_d, np.log(s)), 2)
                / s ** (1.0 + g.model.nu))

    assert amplification(floor) <= AMPLIFICATION_LIMIT * (1 + 1e-2)
    assert amplification((obs.cap(dt) / dt) ** (1.0 / g.model.nu)) > AMPLIFICATION_LIMIT


@pytest.mark.parametrize("h", [5e-5, 1e-4, 1.0])
def test_split_step_does_not_depend_on_h(tuned_design, h):
    """The split scheme covers the communication step in one step: h only bounds euler."""
    rng = np.random.default_rng(7)
    filtering = tuned_design.filtering
    ref, obs = FilteringObserver(filtering, h=1e-3), FilteringObserver(filtering, h=h)
    for y, u in zip(rng.standard_normal((20, tuned_design.plant.k)),
                    rng.standard_normal((20, tuned_design.plant.m)), strict=True):
        ref.step(y, u, 1e-3)
        obs.step(y, u, 1e-3)
    assert np.array_equal(ref.get_state(), obs.get_state())
