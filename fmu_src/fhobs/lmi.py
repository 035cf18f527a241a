"""The design LMIs, solved with cvxpy + Clarabel.

One LMI shape serves the three observers. For a matrix ``H0``, a generator ``G``, an output
matrix ``Cout`` and a decay parameter ``rho``, find ``P = P^T`` and ``Y`` with

    sym(P H0 + Y Cout + rho P G) <= -margin I,    sym(P G) >= margin I,    I <= P <= kappa I,

and return the gain ``P^-1 Y``. ``sym(M) = (M + M^T)/2``, so the first inequality is the paper's
``P H0 + H0^T P + Y C + C^T Y^T + rho (P G + G^T P) <= 0`` halved, made strict by the margin.

- Theorem 2 (filtering observer): H0 = bar_A0, G = bar_G, Cout = bar_C, gain (L_tilde; L).
- Theorem 1 (prescribed-time observer): H0 = A0, G = G_d - nu I, Cout = C, gain L_pt.
- Luenberger baseline: H0 = A, G = I, Cout = C, rho = decay rate: every eigenvalue of
  A + L_lin C then has real part <= -rho.

Normalisation: the LMIs are homogeneous in (P, Y), so P >= I fixes the scale and makes the
margins absolute. Objectives (``OBJECTIVES``):

- ``"min_gain"`` (default): minimise ``kappa + ||Y||_2^2 / scale``: a well-conditioned P and the
  smallest gains that meet the decay ``rho``; small gains amplify measurement noise least.
  ``scale`` makes the two terms comparable (the squared norm of the plant's H0).
- ``"min_cond"``: minimise kappa only (best-conditioned certificate, gains unbounded).
"""

from __future__ import annotations

from dataclasses import dataclass

import cvxpy as cp
import numpy as np

OBJECTIVES = ("min_gain", "min_cond")
DEFAULT_MARGIN = 1e-3


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
    objective: str = "min_gain",
    margin: float = DEFAULT_MARGIN,
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
        Margin on the strict inequalities (absolute, since P >= I).

    Returns
    -------
    LMISolution

    Raises
    ------
    LMIError
        If Clarabel reports no optimal solution.
    ValueError
        For an unknown objective.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"objective {objective!r} is not one of {OBJECTIVES}")
    N, p = H0.shape[0], Cout.shape[0]
    eye = np.eye(N)
    P = cp.Variable((N, N), symmetric=True)
    Y = cp.Variable((N, p))
    kappa = cp.Variable()
    constraints = [
        _sym(P @ H0 + Y @ Cout + rho * P @ G) << -margin * eye,
        _sym(P @ G) >> margin * eye,
        P >> eye,
        P << kappa * eye,
    ]
    cost = kappa
    if objective == "min_gain":
        mu = cp.Variable()
        constraints.append(cp.bmat([[mu * np.eye(p), Y.T], [Y, eye]]) >> 0)
        cost = kappa + mu / max(np.linalg.norm(H0, 2) ** 2, 1.0)
    problem = cp.Problem(cp.Minimize(cost), constraints)
    problem.solve(solver=cp.CLARABEL)
    if problem.status != cp.OPTIMAL or P.value is None:
        raise LMIError(f"LMI solver status {problem.status!r} (rho = {rho}, objective {objective})")
    P_val = 0.5 * (P.value + P.value.T)
    gain = np.linalg.solve(P_val, Y.value)
    return LMISolution(P_val, Y.value, gain, problem.status, float(problem.solver_stats.solve_time))


def certify_gain_lmi(
    H: np.ndarray, G: np.ndarray, rho: float, margin: float = DEFAULT_MARGIN
) -> np.ndarray:
    """Find a Lyapunov matrix P for a given closed-loop matrix H (a gain fixed beforehand).

    Solves sym(P (H + rho G)) <= -margin I, sym(P G) >= margin I, I <= P <= kappa I with kappa
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
    N = H.shape[0]
    eye = np.eye(N)
    P = cp.Variable((N, N), symmetric=True)
    kappa = cp.Variable()
    constraints = [
        _sym(P @ (H + rho * G)) << -margin * eye,
        _sym(P @ G) >> margin * eye,
        P >> eye,
        P << kappa * eye,
    ]
    problem = cp.Problem(cp.Minimize(kappa), constraints)
    problem.solve(solver=cp.CLARABEL)
    if problem.status != cp.OPTIMAL or P.value is None:
        raise LMIError(f"no Lyapunov certificate for the given gain: status {problem.status!r}")
    return 0.5 * (P.value + P.value.T)
