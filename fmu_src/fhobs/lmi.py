"""The design LMIs, solved with cvxpy + Clarabel.

One LMI shape serves the three observers. For a matrix ``H0``, a generator ``G``, an output
matrix ``Cout`` and a decay parameter ``rho``, find ``P = P^T`` and ``Y`` with

    sym(P H0 + Y Cout + rho P G) <= -margin P,    sym(P G) >= margin P,    I <= P <= kappa I,

and return the gain ``P^-1 Y``. ``sym(M) = (M + M^T)/2``, so the first inequality is the paper's
``P H0 + H0^T P + Y C + C^T Y^T + rho (P G + G^T P) <= 0`` halved, made strict by the margin:
a decay rate (1/s) beyond rho, in the norm of P, which is what the certificate measures.

- Theorem 2 (filtering observer): H0 = bar_A0, G = bar_G, Cout = bar_C, gain (L_tilde; L).
- Theorem 1 (prescribed-time observer): H0 = A0, G = G_d - nu I, Cout = C, gain L_pt.
- Luenberger baseline: H0 = A, G = I, Cout = C, rho = decay rate: every eigenvalue of
  A + L_lin C then has real part <= -rho.

Normalisation: the LMIs are homogeneous in (P, Y), so P >= I fixes the scale.
Conditioning: the LMI is solved in the coordinates of a given ``basis`` T (the design passes
the eigenvectors of the dilation generator, in which G is diagonal); the solution maps back by
congruence, P = T^-T P' T^-1 and gain = T gain', and still satisfies the LMI exactly (the
certificate re-checks it in the original coordinates). In the original coordinates Clarabel
failed on about a third of the random test plants with n >= 4; in the eigenbasis it solves them.

Objectives (``OBJECTIVES``):

- ``"min_cond"`` (default): minimise kappa, the condition number bound of P (in the basis T):
  the best-conditioned certificate, whose gains are moderate because a large gain needs an
  ill-conditioned P to satisfy the LMI.
- ``"min_gain"``: two stages: min_cond first, then minimise ||Y||_2 with kappa allowed to grow
  to ``GAIN_STAGE_KAPPA`` times its optimum: smaller gains (less noise amplification) at equal
  decay rho. Numerically harder: on some plants Clarabel fails, and the error says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import cvxpy as cp
import numpy as np

OBJECTIVES = ("min_cond", "min_gain")
GAIN_STAGE_KAPPA = 10.0
DEFAULT_MARGIN = 1e-2


class LMIError(RuntimeError):
    """The solver found no solution (infeasible, or numerical failure)."""


@dataclass(frozen=True)
class LMISolution:
    """A solution of the LMI of the module docstring.

    Attributes
    ----------
    P : numpy.ndarray
        Lyapunov matrix, symmetric, >= I.
    Y : numpy.ndarray
        Auxiliary variable, P @ gain.
    gain : numpy.ndarray
        P^-1 Y.
    status : str
        cvxpy's status.
    solve_time : float
        Solver time in seconds (as reported by cvxpy).
    """

    P: np.ndarray
    Y: np.ndarray
    gain: np.ndarray
    status: str
    solve_time: float


def _sym(M: cp.Expression) -> cp.Expression:
    return 0.5 * (M + M.T)


def solve_gain_lmi(
    H0: np.ndarray,
    G: np.ndarray,
    Cout: np.ndarray,
    rho: float,
    objective: str = "min_cond",
    margin: float = DEFAULT_MARGIN,
    basis: np.ndarray | None = None,
) -> LMISolution:
    """Solve the LMI of the module docstring for (P, Y) and return the gain P^-1 Y.

    Parameters
    ----------
    H0 : numpy.ndarray
        N x N open-loop matrix.
    G : numpy.ndarray
        N x N generator.
    Cout : numpy.ndarray
        p x N output matrix.
    rho : float
        Decay parameter.
    objective : str
        One of :data:`OBJECTIVES`.
    margin : float
        Margin on the strict inequalities, a rate in 1/s.
    basis : numpy.ndarray, optional
        Invertible N x N matrix T; the LMI is solved for T^-1 H0 T, T^-1 G T, Cout T.

    Returns
    -------
    LMISolution
        In the original coordinates.

    Raises
    ------
    LMIError
        If Clarabel reports no optimal solution.
    ValueError
        For an unknown objective.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"objective {objective!r} is not one of {OBJECTIVES}")
    T = np.eye(H0.shape[0]) if basis is None else basis
    T_inv = np.linalg.inv(T)
    H0_t, G_t, C_t = T_inv @ H0 @ T, T_inv @ G @ T, Cout @ T
    P, Y, kappa, constraints = _lmi_problem(H0_t, G_t, C_t, rho, margin)
    solve_time = _solve(cp.Problem(cp.Minimize(kappa), constraints), rho, "min_cond")
    if objective == "min_gain":
        p, N = C_t.shape
        mu = cp.Variable()
        constraints = constraints[:-1] + [
            P << GAIN_STAGE_KAPPA * kappa.value * np.eye(N),
            cp.bmat([[mu * np.eye(p), Y.T], [Y, np.eye(N)]]) >> 0,
        ]
        solve_time += _solve(cp.Problem(cp.Minimize(mu), constraints), rho, objective)
    P_t = 0.5 * (P.value + P.value.T)
    P_val = T_inv.T @ P_t @ T_inv
    gain = T @ np.linalg.solve(P_t, Y.value)
    return LMISolution(0.5 * (P_val + P_val.T), P_val @ gain, gain, "optimal", solve_time)


def _lmi_problem(H0, G, Cout, rho, margin):
    """Variables and constraints of the LMI (kappa bound last)."""
    N, p = H0.shape[0], Cout.shape[0]
    eye = np.eye(N)
    P = cp.Variable((N, N), symmetric=True)
    Y = cp.Variable((N, p))
    kappa = cp.Variable()
    constraints = [
        _sym(P @ H0 + Y @ Cout + rho * P @ G) << -margin * P,
        _sym(P @ G) >> margin * P,
        P >> eye,
        P << kappa * eye,
    ]
    return P, Y, kappa, constraints


def _solve(problem: cp.Problem, rho: float, objective: str) -> float:
    """Solve with Clarabel; return the solve time or raise LMIError.

    An ``optimal_inaccurate`` result is kept: the numpy certificate, not the solver's
    status, decides whether it is used.
    """
    try:
        problem.solve(solver=cp.CLARABEL)
    except cp.SolverError as exc:
        raise LMIError(f"Clarabel failed (rho = {rho}, objective {objective}): {exc}") from exc
    if problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        raise LMIError(
            f"LMI solver status {problem.status!r} (rho = {rho}, objective {objective})"
        )
    return float(problem.solver_stats.solve_time or 0.0)


def certify_gain_lmi(
    H: np.ndarray, G: np.ndarray, rho: float, margin: float = DEFAULT_MARGIN
) -> np.ndarray:
    """Find a Lyapunov matrix P for a given closed-loop matrix H (a gain fixed beforehand).

    Solves sym(P (H + rho G)) <= -margin P, sym(P G) >= margin P, I <= P <= kappa I with kappa
    minimal. Used to certify published gains.

    Parameters
    ----------
    H : numpy.ndarray
        Closed-loop matrix (e.g. bar_A0 + bar_L bar_C).
    G : numpy.ndarray
        Generator.
    rho : float
        Decay parameter.
    margin : float
        Margin on the strict inequalities.

    Returns
    -------
    numpy.ndarray
        P.

    Raises
    ------
    LMIError
        If no such P exists.
    """
    P, Y, kappa, constraints = _lmi_problem(H, G, np.zeros((1, H.shape[0])), rho, margin)
    _solve(cp.Problem(cp.Minimize(kappa), constraints), rho, "certificate of a given gain")
    return 0.5 * (P.value + P.value.T)
