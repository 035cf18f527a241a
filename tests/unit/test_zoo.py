"""The zoo of example plants with the default design: certificate, continuous-time convergence
of the certified error system (integrated here with scipy, independently of fhobs.core.runtime) and
the runtime's noise-free floor in the closed loop of :func:`harness.zoo.closed_loop`."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from designs import ZOO, zoo_design
from fhobs.core.gains import ObserverDesign
from reference_math import zoh
from scipy.integrate import solve_ivp

from harness.zoo import (
    CONVERGED,
    closed_loop,
    convergence_figures,
    load_zoo_spec,
    state_feedback,
)

RUNTIME_SUBSET = ("pendulum", "maglev", "quarter_car", "dc_motor", "spring_chain3")
FAST_SUBSET = ("pendulum", "quarter_car")
"""Of RUNTIME_SUBSET, the plants whose 10 s closed loop runs in the fast subset."""
CT_HORIZON = 10.0
"""The continuous-time error must be below CONVERGED of its initial size before this time."""
CT_STOP = 1e-4
"""The integration stops (event) when the error is CT_STOP of its initial size: near sigma = 0
the right-hand side is singular (sigma^(nu-1)) and its solution reaches 0 in finite time."""
CT_PEAK_BOUND = 1e4
"""Bound on |eps(t)| / |eps(0)| (a divergent error system crosses it)."""
XI0 = 1e-12
"""Initial xi: sigma(0) = 1e-6 > 0 keeps sigma^(nu-1) and ln(sigma) finite at t = 0 (psi = 0
there, so the term it multiplies vanishes: the start is the paper's xi = 0 up to 1e-12)."""
SETTLING_TOLERANCE = 1.25
"""Where the design reports the requested settling time met, the continuous-time error (from
one of the design's two initial errors) falls to 1e-3 within this factor of it: the design
predicts with the runtime at dt = T / 2000, this test integrates the continuous system."""
FLOOR = 1e-9
"""Noise-free floor of the runtime: max relative error over the last second."""


def test_zoo_has_its_thirteen_plants():
    assert len(ZOO) == 13 and {"pendulum", "mass_chain", "triple_integrator"} <= set(ZOO)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(ZOO))
def test_default_design_is_certified(name):
    gains = zoo_design(name)  # raises (LMIError, CertificateError, ...) if not certified
    for record in (gains.filtering, gains.prescribed_time, gains.luenberger):
        assert record.certificate["checks"]


@pytest.mark.parametrize("name", sorted(ZOO))
def test_state_feedback_stabilises(name):
    spec = load_zoo_spec(ZOO[name])
    K = state_feedback(spec.A, spec.B)
    assert np.max(np.linalg.eigvals(spec.A + spec.B @ K).real) < 0


def test_closed_loop_feeds_back_the_true_state():
    """The plant of the zoo's loop follows the sampled LQR loop x_{k+1} = (Phi + Gamma K) x_k
    (ZOH blocks from one expm of the augmented matrix), whatever the observers do."""
    gains = zoo_design("quarter_car")
    dt, n = 1e-3, gains.plant.n
    Phi, Gamma = zoh(gains.plant.A, gains.plant.B, dt)
    step = Phi + Gamma @ state_feedback(gains.plant.A, gains.plant.B)
    result = closed_loop(gains, dt, dt, t_end=0.5)
    x = np.ones(n)
    for k in range(result.t.size):
        np.testing.assert_allclose(result.x[k], x, rtol=1e-9, atol=1e-12)
        x = step @ x


def dilation(G_d: np.ndarray):
    """s -> d(s) = expm(s G_d) through G_d's eigendecomposition (G_d is diagonalisable with
    real weights), checked here against scipy.linalg.expm."""
    w, V = np.linalg.eig(G_d)
    assert np.max(np.abs(w.imag)) < 1e-9
    w, V = w.real, V.real
    V_inv = np.linalg.inv(V)
    for s in (-30.0, -3.0, 2.0):
        d = V @ np.diag(np.exp(s * w)) @ V_inv
        np.testing.assert_allclose(d, scipy.linalg.expm(s * G_d), rtol=1e-8,
                                   atol=1e-10 * np.max(np.abs(d)))
    return w, V, V_inv


def error_system(gains: ObserverDesign):
    """Right-hand side of Theorem 2's extended error system in s = (eps, psi, xi), eps = z - x:

    psi' = C eps + sigma^nu L_tilde psi
    eps' = A0 eps + sigma^(nu-1) d(ln sigma) L psi
    xi'  = |psi^T psi'| - gamma floor(xi - |psi|^2/2)^(nu/2+1),  sigma = sqrt(max(xi, |psi|^2/2))
    """
    A_model, _, C_model = gains.filtering.model_matrices
    A0 = A_model + gains.model.L0 @ C_model
    n_model, k = gains.model.n_model, gains.plant.k
    nu, gamma = gains.model.nu, gains.filtering.gamma
    w, V, V_inv = dilation(gains.model.G_d)
    VL = V_inv @ gains.filtering.L

    def rhs(_t: float, s: np.ndarray) -> np.ndarray:
        eps, psi, xi = s[:n_model], s[n_model:n_model + k], s[-1]
        half = 0.5 * psi @ psi
        sigma = np.sqrt(max(xi, half))
        dpsi = C_model @ eps + sigma**nu * (gains.filtering.L_tilde @ psi)
        deps = A0 @ eps + sigma ** (nu - 1.0) * (V @ (sigma**w * (VL @ psi)))
        gap = xi - half
        dxi = abs(psi @ dpsi) - gamma * np.sign(gap) * abs(gap) ** (nu / 2.0 + 1.0)
        return np.concatenate([deps, dpsi, [dxi]])

    return rhs


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(ZOO))
def test_continuous_error_system_converges(name):
    """x(0) = state_scale, observer at 0: eps(0) = -state_scale on the state, 0 on the
    disturbance model; errors measured in units of state_scale (the peak: in the states' own
    units, relative to |state_scale|).

    RK45 rather than an implicit method: the right-hand side is only mildly stiff (the psi
    pole ~ sigma^nu |L_tilde|) but not smooth (max in sigma, |.| and sign in xi'), and near the
    end the implicit methods' Jacobians chatter (LSODA needs ~3e6 evaluations on
    random_mimo10, RK45 ~1e4; both agree on the convergence times to 1e-3 s elsewhere).
    """
    gains = zoo_design(name)
    n, n_model, k = gains.plant.n, gains.model.n_model, gains.plant.k
    scale = load_zoo_spec(ZOO[name]).state_scale
    eps0 = np.concatenate([-scale, np.zeros(n_model - n)])
    size0 = np.sqrt(n)  # errors in units of state_scale, as the settling time is defined

    def done(_t, s):
        return np.linalg.norm(s[:n] / scale) - CT_STOP * size0
    done.terminal = True

    sol = solve_ivp(error_system(gains), (0.0, CT_HORIZON),
                    np.concatenate([eps0, np.zeros(k), [XI0]]), method="RK45",
                    rtol=1e-9, atol=1e-14, events=done)
    assert sol.status >= 0, sol.message
    error = np.linalg.norm(sol.y[:n] / scale[:, None], axis=0) / size0
    assert np.all(np.isfinite(sol.y))
    raw = np.linalg.norm(sol.y[:n], axis=0) / np.linalg.norm(scale)
    assert np.max(raw) < CT_PEAK_BOUND, f"peak {np.max(raw):.3g}"
    below = np.flatnonzero(error <= CONVERGED)
    assert below.size, f"{name}: error {error[-1]:.3g} of its initial size at t = {sol.t[-1]:.3g}"
    assert np.all(error[below[0]:] <= 10 * CONVERGED), "the error grew back after 1e-3"
    tuning = gains.settling_tuning
    if tuning["met"]:  # the design's prediction (discrete, runtime) against this integration
        assert sol.t[below[0]] <= SETTLING_TOLERANCE * tuning["settling_time_requested"], (
            sol.t[below[0]], tuning)


def runtime_floor(name: str, dt: float, h: float) -> dict[str, float]:
    """Figures of the filtering observer in the zoo's closed loop over 10 s."""
    return convergence_figures(closed_loop(zoo_design(name), dt, h, t_end=10.0,
                                           x0=load_zoo_spec(ZOO[name]).state_scale))


@pytest.mark.parametrize("name", [name if name in FAST_SUBSET else
                                  pytest.param(name, marks=pytest.mark.slow)
                                  for name in RUNTIME_SUBSET])
def test_runtime_reaches_its_floor(name):
    """Split scheme, dt = h = 1e-3, nominal, u = K x: the relative error reaches 1e-9 within
    10 s (max over the last second)."""
    figures = runtime_floor(name, 1e-3, 1e-3)
    assert figures["floor"] <= FLOOR, figures


FINE_STEP_FLOORS = {"spring_chain3": 2 * FLOOR}
"""Plants whose floor at dt = 1e-4 is at FLOOR's edge, and the bound they are held to:
spring_chain3's default design (rho 6, the fastest within the peaking limit; 2 s is not
reachable) amplifies round-off through n_tilde = 6 to 1.01e-9 with the default BLAS kernel and
just below 1e-9 under OPENBLAS_CORETYPE=Haswell (measured 2026-11-28): a known miss of 1e-9 by
round-off, held to twice FLOOR on any kernel."""


@pytest.mark.slow
@pytest.mark.parametrize("name", RUNTIME_SUBSET)
def test_runtime_reaches_its_floor_at_every_step(name):
    """The same at the zoo bench's other communication step, dt = h = 1e-4. Its internal step
    h = 5e-5 (at dt = 1e-4 and 1e-3) gives the same runs bit for bit with the split scheme
    (test_split_scheme_runs_do_not_depend_on_h), so they are not run again here."""
    figures = runtime_floor(name, 1e-4, 1e-4)
    assert figures["floor"] <= FINE_STEP_FLOORS.get(name, FLOOR), figures


@pytest.mark.slow
@pytest.mark.parametrize("name", RUNTIME_SUBSET)
def test_split_scheme_runs_do_not_depend_on_h(name):
    """The zoo's closed loop (0.2 s) at dt = 1e-4 and 1e-3 with the bench's h = 5e-5 and with
    h = dt: every recorded trajectory equal bit for bit (the split step does not sub-step)."""
    x0 = load_zoo_spec(ZOO[name]).state_scale
    for dt in (1e-4, 1e-3):
        runs = [closed_loop(zoo_design(name), dt, h, t_end=0.2, x0=x0) for h in (5e-5, dt)]
        for field in ("t", "x", "z", "z_lin", "psi", "xi", "sigma"):
            np.testing.assert_array_equal(getattr(runs[0], field), getattr(runs[1], field),
                                          err_msg=f"{name} dt={dt} {field}")
