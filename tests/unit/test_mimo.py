"""Unknown inputs on multi-output plants: observability chains of unequal lengths.

A disturbance model lengthens the observability chain of the outputs that see q and not the
others (the ball and beam with q on the ball: chains 3 and 2 at order 1). Every observable
extended model of a family of textbook and seeded random MIMO plants (k = 2 to 4 outputs, n = 3
to 6, E random or matched to B, disturbance orders 0 to 3) is designed with the defaults,
certified, its homogeneity identities and observability indices checked here with numpy, and
its continuous-time error system (x and q errors, integrated with scipy) must fall to 1e-3 of
its start within ``SETTLING_FACTOR`` times the requested settling time. Unobservable extended
models are a SpecError naming the directions the outputs cannot see, from the API and from both
command lines. Everything fhobs computes is compared with matrices written out here.
"""

from __future__ import annotations

import functools
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from fhobs.core.certificate import certify
from fhobs.core.gains import ObserverDesign
from fhobs.design.lmi import chain_basis
from fhobs.design.observer import design_observer
from fhobs.errors import LMIError, SpecError
from scipy.integrate import solve_ivp
from test_zoo import CT_PEAK_BOUND, XI0

ROOT = Path(__file__).resolve().parents[2]
SETTLING_TIME = 2.0
"""The defaults' requested settling time (s)."""
SETTLED = 1e-3
SETTLING_FACTOR = 1.5
"""The x and q errors fall to SETTLED of their start within this factor of the settling time
(measured: at most 1.12 over the textbook plants and 72 random ones)."""
IDENTITY_TOL = 1e-9

BALL_BEAM_A = np.array([[0, 1, 0, 0], [0, 0, -7, 0], [0, 0, 0, 1], [0, 0, 0, 0]], float)
BALL_BEAM_B = np.array([[0], [0], [0], [1.0]])
BALL_BEAM_C = np.array([[1, 0, 0, 0], [0, 0, 1, 0.0]])
BALL_ON_BALL = np.array([[0], [1.0], [0], [0]])
"""q on the ball's acceleration: r'' = -7 theta + q."""

TWO_DOUBLE_INTEGRATORS = (
    np.array([[0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1], [0, 0, 0, 0]], float),
    np.array([[0, 0], [1, 0], [0, 0], [0, 1.0]]),
    np.array([[1, 0, 0, 0], [0, 0, 1, 0.0]]),
    np.array([[0], [1.0], [0], [0]]),
)
THREE_OUTPUTS = (
    # chains of 1, 2 and 3 integrators measured at their ends, coupled (x5'' = x1 + x4' + u2),
    # q on the second chain's acceleration
    np.array([[-1, 0, 0, 0, 0, 0], [0, 0, 1, 0, 0, 0], [0.5, 0, 0, 0, 0, 0],
              [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1], [1, 0, 0, 1, 0, 0]], float),
    np.array([[1, 0], [0, 0], [0, 0], [0, 0], [0, 0], [0, 1.0]]),
    np.array([[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 0, 1, 0, 0.0]]),
    np.array([[0], [0], [1.0], [0], [0], [0]]),
)
TEXTBOOK = {
    "ball_beam": (BALL_BEAM_A, BALL_BEAM_B, BALL_BEAM_C, BALL_ON_BALL),
    "two_double_integrators": TWO_DOUBLE_INTEGRATORS,
    "three_outputs": THREE_OUTPUTS,
}
TEXTBOOK_CASES = [(name, order) for name in TEXTBOOK for order in (1, 2, 3)]
FAST_TEXTBOOK = {("three_outputs", 1)}
"""The fast subset's textbook case (ball_beam at order 1 has its own fast test below)."""

RANDOM_SEEDS = range(40)
"""The random family whose chain lengths and orders are checked (no design: cheap)."""
DESIGNED_SEEDS = range(20)
"""The draws designed, certified and integrated by the suite (all 40: seeds 0-39 were run by
hand, see docs/results.md)."""
FAST_SEEDS = (4,)


# -- independent model, observability and chain lengths ----------------------------------------
def extended(A: np.ndarray, C: np.ndarray, E: np.ndarray, order: int):
    """(A_model, C_model) written out: x' = A x + E q, q^(order) = 0, y = C x."""
    n, p = E.shape
    N = n + order * p
    A_model = np.zeros((N, N))
    A_model[:n, :n] = A
    if order:
        A_model[:n, n:n + p] = E
        A_model[n:N - p, n + p:] = np.eye((order - 1) * p)
    return A_model, np.hstack([C, np.zeros((C.shape[0], order * p))])


def observability_matrix(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """[C; C A; ...; C A^(N-1)], each block scaled to unit norm (rank unchanged)."""
    blocks, block = [], C
    for _ in range(A.shape[0]):
        blocks.append(block / max(np.linalg.norm(block), 1e-300))
        block = block @ A
    return np.vstack(blocks)


def is_observable(A: np.ndarray, C: np.ndarray) -> bool:
    return np.linalg.matrix_rank(observability_matrix(A, C)) == A.shape[0]


def chain_lengths(A: np.ndarray, C: np.ndarray) -> list[int]:
    """Observability indices by Luenberger's selection: rows c_i A^j taken in the order
    j = 0, 1, ..., i = 1..k, each kept if independent of the rows kept before; an output's chain
    ends at its first dependent row. Sorted, longest first."""
    k = C.shape[0]
    rows: list[np.ndarray] = []
    lengths, alive = [0] * k, [True] * k
    for j in range(A.shape[0]):
        power = np.linalg.matrix_power(A, j)
        for i in range(k):
            if alive[i]:
                row = C[i] @ power
                if np.linalg.matrix_rank(np.array(rows + [row]), tol=1e-9) > len(rows):
                    rows.append(row)
                    lengths[i] += 1
                else:
                    alive[i] = False
    return sorted(lengths, reverse=True)


def draw(seed: int):
    """A seeded random plant: n in 3..6, k in 2..min(4, n - 1) outputs (mostly measured states,
    some mixed), m in 1..2 inputs, A sparse (which makes chains of unequal lengths likely),
    E matched to B's first column or random, disturbance order 0..3."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 7))
    k = int(rng.integers(2, min(4, n - 1) + 1))
    m = int(rng.integers(1, 3))
    A = rng.normal(size=(n, n)) * (rng.random((n, n)) < 0.45)
    B = rng.normal(size=(n, m))
    C = np.eye(n)[rng.choice(n, k, replace=False)]
    if rng.random() < 0.5:
        C = C + 0.3 * rng.normal(size=C.shape) * (rng.random(C.shape) < 0.3)
    E = B[:, :1].copy() if rng.random() < 0.5 else rng.normal(size=(n, 1))
    return A, B, C, E, int(rng.integers(0, 4))


# -- independent error system -------------------------------------------------------------------
def dilation(G_d: np.ndarray, nu: float, n_tilde: int):
    """s -> d(s) = expm(s G_d) from eigenvectors found per weight 1 + (j + 1) nu (scipy's null
    spaces: numpy's eig returns nearly parallel vectors for the repeated weights of several
    chains), checked against scipy.linalg.expm."""
    weights, columns = [], []
    for j in range(n_tilde):
        w = 1.0 + (j + 1) * nu
        space = scipy.linalg.null_space(G_d - w * np.eye(G_d.shape[0]), rcond=1e-9)
        weights += [w] * space.shape[1]
        columns.append(space)
    V = np.hstack(columns)
    assert V.shape == G_d.shape, "G_d is not diagonalisable with the weights 1 + (j + 1) nu"
    w, V_inv = np.array(weights), np.linalg.inv(V)
    for s in (-20.0, -2.0, 1.5):
        d = V @ np.diag(np.exp(s * w)) @ V_inv
        np.testing.assert_allclose(d, scipy.linalg.expm(s * G_d), rtol=1e-7,
                                   atol=1e-9 * np.max(np.abs(d)))
    return w, V, V_inv


def error_system(gains: ObserverDesign, A_model: np.ndarray, C_model: np.ndarray):
    """Theorem 2's error system in (eps, psi, xi), eps = z - x (x and q errors), with the
    model written out here (tests/unit/test_zoo.py states the equations)."""
    A0 = A_model + gains.model.L0 @ C_model
    N, k, nu, gamma = A_model.shape[0], gains.plant.k, gains.model.nu, gains.filtering.gamma
    w, V, V_inv = dilation(gains.model.G_d, nu, gains.model.n_tilde)
    VL = V_inv @ gains.filtering.L

    def rhs(_t: float, s: np.ndarray) -> np.ndarray:
        eps, psi, xi = s[:N], s[N:N + k], s[-1]
        half = 0.5 * psi @ psi
        sigma = np.sqrt(max(xi, half))
        dpsi = C_model @ eps + sigma**nu * (gains.filtering.L_tilde @ psi)
        deps = A0 @ eps + sigma ** (nu - 1.0) * (V @ (sigma**w * (VL @ psi)))
        gap = xi - half
        dxi = abs(psi @ dpsi) - gamma * np.sign(gap) * abs(gap) ** (nu / 2.0 + 1.0)
        return np.concatenate([deps, dpsi, [dxi]])

    return rhs


def settling(gains: ObserverDesign, A_model: np.ndarray,
             C_model: np.ndarray) -> tuple[float, float]:
    """Time for the plant states' error to fall to SETTLED of |eps(0)|, from eps(0) = (-1 on x,
    +1 on q), and the peak |eps(t)| / |eps(0)|; the whole error (x and q) must be below SETTLED
    by the end, 3 settling times; RK45 as in test_zoo (the right-hand side is not smooth)."""
    N, k = A_model.shape[0], gains.plant.k
    eps0 = np.concatenate([-np.ones(gains.plant.n), np.ones(N - gains.plant.n)])
    size0 = np.linalg.norm(eps0)

    def done(_t, s):
        return np.linalg.norm(s[:N]) - 0.1 * SETTLED * size0
    done.terminal = True

    sol = solve_ivp(error_system(gains, A_model, C_model), (0.0, 3 * SETTLING_TIME),
                    np.concatenate([eps0, np.zeros(k), [XI0]]), method="RK45", rtol=1e-8,
                    atol=1e-13, events=done)
    assert sol.status >= 0, sol.message
    error = np.linalg.norm(sol.y[:N], axis=0) / size0
    assert np.all(np.isfinite(error))
    assert error[-1] <= SETTLED, f"x and q error {error[-1]:.3g} of its start after 3 T"
    n = gains.plant.n  # the settling time, as the design defines it: of the plant's states
    above = np.flatnonzero(np.linalg.norm(sol.y[:n], axis=0) / size0 > SETTLED)
    t_settled = sol.t[above[-1] + 1] if above.size and above[-1] + 1 < sol.t.size else np.inf
    return float(t_settled if above.size else 0.0), float(np.max(error))


# -- the checks of one plant ---------------------------------------------------------------------
@functools.cache
def textbook_design(name: str, order: int) -> ObserverDesign:
    A, B, C, E = TEXTBOOK[name]
    return design_observer(A, B, C, E=E, disturbance_order=order)


def check_design(gains: ObserverDesign, A, C, E, order: int) -> dict[str, float]:
    """Certificate, the paper's identities, the observability indices against G_d's weights and
    the convergence of the x and q errors; returns the measured figures."""
    A_model, C_model = extended(A, C, E, order)
    assert certify(gains)  # raises CertificateError naming the failed check
    N, nu = A_model.shape[0], gains.model.nu
    A0 = A_model + gains.model.L0 @ C_model
    scale = np.linalg.norm(A0) * np.linalg.norm(gains.model.G_d)
    assert np.linalg.norm(A0 @ gains.model.G_d - (gains.model.G_d + nu * np.eye(N)) @ A0) <= (
        IDENTITY_TOL * scale)
    assert np.linalg.norm(C_model @ gains.model.G_d - (1 + nu) * C_model) <= (
        IDENTITY_TOL * np.linalg.norm(C_model) * np.linalg.norm(gains.model.G_d))
    lengths = chain_lengths(A_model, C_model)
    assert gains.model.n_tilde == lengths[0]
    assert np.linalg.norm(np.linalg.matrix_power(A0, gains.model.n_tilde)) <= (
        1e-8 * max(np.linalg.norm(A0), 1.0) ** gains.model.n_tilde)
    # the weight 1 + (j + 1) nu has one eigenvector per chain longer than j
    for j in range(gains.model.n_tilde):
        rank = np.linalg.matrix_rank(gains.model.G_d - (1 + (j + 1) * nu) * np.eye(N), tol=1e-8)
        assert N - rank == sum(length > j for length in lengths), (j, lengths)
    t_settled, peak = settling(gains, A_model, C_model)
    assert peak < CT_PEAK_BOUND
    assert t_settled <= SETTLING_FACTOR * SETTLING_TIME, (t_settled, lengths)
    return {"settled": t_settled, "peak": peak}


# -- tests ----------------------------------------------------------------------------------------
def test_chain_basis_with_unequal_chains_is_a_basis():
    """Chains 3 and 2, the level of weight 1 + 2 nu listed with the image of the deeper chain
    second: the chains that started deeper must be followed through A0, not compared unmapped."""
    A0 = np.diag([1.0, 1.0, 0.0, 1.0], k=1)  # x1 <- x2 <- x3, x4 <- x5
    e = np.eye(5)
    basis = chain_basis(A0, [e[:, [0, 3]], e[:, [4, 1]], e[:, [2]]])
    assert basis.sizes == (3, 2)
    assert np.linalg.matrix_rank(basis.T) == 5
    shifted = np.linalg.solve(basis.T, A0 @ basis.T)  # one ones-superdiagonal per chain
    expected = scipy.linalg.block_diag(np.eye(3, k=1), np.eye(2, k=1))
    np.testing.assert_allclose(shifted * (expected != 0), shifted, atol=1e-12)
    assert np.all(np.abs(np.diagonal(shifted, 1)[[0, 1, 3]]) > 0.1)


def test_chain_basis_refuses_levels_that_are_not_chains():
    """A level-1 vector that A0 sends to zero (an unobservable direction) is an LMIError."""
    A0 = np.diag([1.0, 0.0, 0.0], k=1)
    e = np.eye(4)
    with pytest.raises(LMIError, match="chain basis .* singular"):
        chain_basis(A0, [e[:, [0, 2]], e[:, [1, 3]]])


@pytest.mark.parametrize(("name", "order"), [
    case if case in FAST_TEXTBOOK else pytest.param(*case, marks=pytest.mark.slow)
    for case in TEXTBOOK_CASES])
def test_textbook_plant_with_unknown_input(name, order):
    A, _, C, E = TEXTBOOK[name]
    A_model, C_model = extended(A, C, E, order)
    lengths = chain_lengths(A_model, C_model)
    assert is_observable(A_model, C_model) and len(set(lengths)) > 1, lengths
    check_design(textbook_design(name, order), A, C, E, order)


def test_ball_and_beam_estimates_the_ball_disturbance():
    """Order 1: q = r'' + 7 theta; the chain of r is three long (r, r', q), that of theta two."""
    A_model, C_model = extended(BALL_BEAM_A, BALL_BEAM_C, BALL_ON_BALL, 1)
    assert chain_lengths(A_model, C_model) == [3, 2]
    gains = textbook_design("ball_beam", 1)
    assert gains.model.n_tilde == 3 and gains.model.n_model == 5 and gains.plant.k == 2
    assert gains.settling_tuning["met"]


@pytest.mark.parametrize("seed", [
    seed if seed in FAST_SEEDS else pytest.param(seed, marks=pytest.mark.slow)
    for seed in DESIGNED_SEEDS])
def test_random_plant_with_unknown_input(seed):
    """Observable draws design, certify and converge; unobservable ones are a SpecError that
    names the directions the outputs cannot see."""
    A, B, C, E, order = draw(seed)
    A_model, C_model = extended(A, C, E, order)
    if not is_observable(A_model, C_model):
        with pytest.raises(SpecError, match="not observable.*cannot see the direction"):
            design_observer(A, B, C, E=E, disturbance_order=order)
        return
    gains = design_observer(A, B, C, E=E, disturbance_order=order)
    check_design(gains, A, C, E, order)


def test_random_family_has_unequal_chains():
    """The family tests what it is meant to: most observable draws have chains of unequal
    lengths, every order and output count occurs."""
    unequal, orders, outputs, observable = 0, set(), set(), 0
    for seed in RANDOM_SEEDS:
        A, _, C, E, order = draw(seed)
        A_model, C_model = extended(A, C, E, order)
        if is_observable(A_model, C_model):
            observable += 1
            unequal += len(set(chain_lengths(A_model, C_model))) > 1
            orders.add(order)
            outputs.add(C.shape[0])
    assert observable >= 30 and unequal >= observable // 2
    assert orders == {0, 1, 2, 3} and outputs == {2, 3, 4}


def unobservable_ball_and_beam() -> tuple[np.ndarray, ...]:
    """The ball and beam measured in theta only, q on the ball: x1 = r, x2 = r' and q are not
    seen (theta's chain never involves the ball)."""
    return BALL_BEAM_A, BALL_BEAM_B, BALL_BEAM_C[1:], BALL_ON_BALL


def test_unobservable_extended_model_names_the_direction():
    A, B, C, E = unobservable_ball_and_beam()
    with pytest.raises(SpecError) as err:
        design_observer(A, B, C, E=E, disturbance_order=1)
    message = str(err.value)
    assert "disturbance model of order 1 (A, E, C) is not observable" in message
    assert "rank 2, n = 5" in message
    for direction in ("x[1] (vector [1, 0, 0, 0, 0])", "x[2] (vector [0, 1, 0, 0, 0])",
                      "q[1] (vector [0, 0, 0, 0, 1])"):
        assert direction in message, message
    assert "\n" not in message


def test_unobservable_mixed_direction_is_named_as_a_combination():
    """Two double integrators measured through their difference: the common motion x1 + x3
    (and its velocity x2 + x4) is not seen."""
    A, B, _, _ = TWO_DOUBLE_INTEGRATORS
    C = np.array([[1.0, 0.0, -1.0, 0.0]])
    with pytest.raises(SpecError) as err:
        design_observer(A, B, C)
    message = str(err.value)
    assert re.search(r"x\[1\] \+ x\[3\] \(vector \[1, 0, 1, 0\]\)", message), message
    assert re.search(r"x\[2\] \+ x\[4\] \(vector \[0, 1, 0, 1\]\)", message), message


@pytest.mark.parametrize("command", [["build_fmu.py"], ["-m", "harness", "plant"]])
def test_unobservable_extended_model_on_the_command_lines(tmp_path, command):
    A, B, C, E = unobservable_ball_and_beam()
    spec = tmp_path / "unobservable.toml"
    spec.write_text("\n".join(f"{name} = {matrix.tolist()}" for name, matrix in
                              (("A", A), ("B", B), ("C", C), ("E", E)))
                    + "\n[observer]\ndisturbance_order = 1\n")
    args = [*command, str(spec), "--out", str(tmp_path / "out")]
    proc = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "LinAlgError" not in proc.stderr
    assert "not observable" in proc.stderr and "q[1] (vector [0, 0, 0, 0, 1])" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
