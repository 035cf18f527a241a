"""Partial homogenisation: the fast stable modes kept by the model, the rest homogenised.

The homogenisation of the whole model makes ``A0 = A + L0 C`` nilpotent: it cancels every
mode of the model through the output, however fast and stable. On a stiff plant (a DC motor's
electrical pole near -1000 1/s, seen through an angle two integrations away) that cancellation
costs output-injection gains of 1e8-1e9, which amplify noise, round-off and the coupling's
one-step delay. A mode that decays faster than the observer must converge needs no correction
at all: its error dies out by itself.

So the model (balanced coordinates) is put in real Schur form ``A = Q T Q^T`` with the modes to
homogenise first (``T = [[T11, T12], [0, T22]]``, ``Q = [Q1, Q2]`` orthogonal): the span of Q1 is
invariant under A, and the error's component along Q2 obeys ``de_f/dt = T22 e_f`` whatever the
observer injects along Q1. The homogeneous design (homogenisation, Theorem 2's and Theorem 1's
LMIs) is made for ``(T11, C Q1)``, which is observable when (A, C) is, and embedded:

- ``L0 = Q1 L0_s``, ``L = Q1 L_s``, ``L_pt = Q1 L_pt_s``: nothing is injected along Q2;
- ``G_d = Q1 G_s Q1^T + (1 + nu) Q2 Q2^T``: then ``C G_d = (1 + nu) C`` still holds on the whole
  model, so the runtime's exact injection flow and every step plan are unchanged;
- ``Pi_s = Q1 Q1^T`` (the model's ``slow_projector``): the certificate checks the homogeneity
  identities on its range and the split itself (:func:`fhobs.core.certificate.partition_residual`).

The error is then a cascade: the fast part decays by itself, exponentially, faster than
``rho (1 + nu)`` by construction, and enters the homogenised part as a vanishing perturbation
of its state and output (docs/theory.md has the argument). The whole model's LMI is certified
with a Lyapunov matrix made in closed form from the homogenised part's (:func:`completed_lyapunov`),
at a rate ``rho / LMI_SLACK``: the slack keeps the homogenised part's LMI strictly negative, so
the fast block's weight, and cond(P_bar), stay moderate.

Which modes: those whose decay rate exceeds ``fast_mode_rate`` (the spec's; default
``FAST_MODE_FACTOR / settling_time``) and ``FAST_RHO_MARGIN rho (1 + nu)``; when none does, or
every mode would, the whole model is homogenised, as in the paper.

Examples
--------
>>> A = np.array([[-1000.0, 0.0], [1.0, 0.0]])
>>> split = split_modes(A, 100.0)
>>> split.n_slow, round(float(split.T[1, 1]), 6)
(1, -1000.0)
>>> split_modes(A, 2000.0) is None
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

FAST_MODE_FACTOR = 50.0
"""Default ``fast_mode_rate`` is this over the settling time: such a mode falls by e^-50 within
the settling time, far below the 1e-3 the settling time is defined by."""
FAST_RHO_MARGIN = 2.0
"""A mode is kept by the model only if it decays faster than this times ``rho (1 + nu)``, the
rate the whole model's LMI asks of it."""
LMI_SLACK = 1.25
"""The homogenised part's LMIs are solved at rho, the whole model's certified at
``rho / LMI_SLACK``."""


@dataclass(frozen=True)
class ModeSplit:
    """A real Schur basis of the model with the modes to homogenise first.

    Attributes
    ----------
    Q : numpy.ndarray
        Orthogonal (N x N), ``Q^T A Q = T`` upper quasi-triangular.
    T : numpy.ndarray
        The Schur form.
    n_slow : int
        Number of homogenised modes (the leading block of T).
    """

    Q: np.ndarray
    T: np.ndarray
    n_slow: int

    @property
    def slow(self) -> np.ndarray:
        """Q1: an orthonormal basis of the homogenised modes' invariant subspace."""
        return self.Q[:, :self.n_slow]

    @property
    def fast(self) -> np.ndarray:
        """Q2: the rest of the basis (the fast modes' coordinates are the error along it)."""
        return self.Q[:, self.n_slow:]


def fast_mode_cut(fast_mode_rate: float | None, settling_time: float, rho: float,
                  nu: float) -> float:
    """The decay rate (1/s) beyond which a stable mode is kept by the model.

    Examples
    --------
    >>> fast_mode_cut(None, 2.0, 4.0, -0.2)
    25.0
    >>> fast_mode_cut(None, 2.0, 40.0, -0.2)
    64.0
    """
    rate = FAST_MODE_FACTOR / settling_time if fast_mode_rate is None else fast_mode_rate
    return max(rate, FAST_RHO_MARGIN * rho * (1.0 + nu))


def split_modes(A: np.ndarray, cut: float) -> ModeSplit | None:
    """The real Schur basis of A with the modes of decay rate below ``cut`` first, or None
    when no mode, or every mode, decays faster than ``cut`` (the whole model is then
    homogenised).

    Examples
    --------
    >>> split_modes(np.array([[0.0, 1.0], [0.0, 0.0]]), 10.0) is None
    True
    """
    if not np.isfinite(cut):
        return None
    T, Q, n_slow = scipy.linalg.schur(A, output="real", sort=lambda re, im: re > -cut)
    if n_slow in (0, A.shape[0]):
        return None
    return ModeSplit(Q, T, int(n_slow))


def embedded_generator(split: ModeSplit, G_s: np.ndarray, nu: float) -> np.ndarray:
    """``G_d = Q1 G_s Q1^T + (1 + nu) Q2 Q2^T``: the homogenised part's dilation, and the
    output's own weight (1 + nu) on the fast modes' coordinates."""
    Q1, Q2 = split.slow, split.fast
    return Q1 @ G_s @ Q1.T + (1.0 + nu) * Q2 @ Q2.T


def completed_lyapunov(H: np.ndarray, G: np.ndarray, P_s: np.ndarray, rho: float,
                       U: np.ndarray) -> np.ndarray:
    """A Lyapunov matrix of the whole model's LMI ``P H + H^T P + rho (P G + G^T P) < 0``
    from the homogenised part's.

    In the coordinates ``w = U^T x`` (U orthogonal, the homogenised coordinates first), H is
    block upper triangular ``[[H_s, H_sf], [0, H_f]]`` and G block diagonal ``diag(G_s, g_f I)``.
    With ``M_s`` the homogenised part's LMI matrix at ``P_s`` (negative definite) and ``P_f``
    the solution of ``P_f A_f + A_f^T P_f = -I``, ``A_f = H_f + rho g_f I`` (Hurwitz: the fast
    modes decay faster than ``rho g_f``), ``P = diag(P_s, mu P_f)`` satisfies the LMI as soon
    as ``mu > lambda_max(X^T (-M_s)^-1 X)``, ``X = P_s H_sf`` (Schur complement); mu is twice
    that. Returned in the x coordinates: ``U P U^T``.

    Raises
    ------
    numpy.linalg.LinAlgError
        If ``M_s`` is not negative definite or ``A_f`` is not Hurwitz.

    Examples
    --------
    >>> H = np.array([[-1.0, 5.0], [0.0, -100.0]])
    >>> P = completed_lyapunov(H, np.eye(2), np.array([[1.0]]), 0.5, np.eye(2))
    >>> bool(np.linalg.eigvalsh(P @ H + H.T @ P + 0.5 * (P + P)).max() < 0)
    True
    """
    n_s = P_s.shape[0]
    Hq, Gq = U.T @ H @ U, U.T @ G @ U
    H_s, H_sf, H_f = Hq[:n_s, :n_s], Hq[:n_s, n_s:], Hq[n_s:, n_s:]
    M_s = P_s @ H_s + H_s.T @ P_s + rho * (P_s @ Gq[:n_s, :n_s] + Gq[:n_s, :n_s].T @ P_s)
    A_f = H_f + rho * Gq[n_s:, n_s:]
    if np.max(np.linalg.eigvals(A_f).real) >= 0.0:
        raise np.linalg.LinAlgError(
            f"the fast modes kept by the model do not decay faster than rho (1 + nu) = "
            f"{rho * float(Gq[-1, -1]):.4g} 1/s")
    P_f = scipy.linalg.solve_continuous_lyapunov(A_f.T, -np.eye(A_f.shape[0]))
    X = P_s @ H_sf
    coupling = X.T @ np.linalg.solve(-M_s, X)
    if np.min(np.linalg.eigvalsh(-0.5 * (M_s + M_s.T))) <= 0.0:
        raise np.linalg.LinAlgError("the homogenised part's LMI is not strictly negative")
    mu = max(2.0 * float(np.max(np.linalg.eigvalsh(0.5 * (coupling + coupling.T)))),
             float(np.min(np.linalg.eigvalsh(P_s))) / float(np.max(np.linalg.eigvalsh(P_f))))
    P = scipy.linalg.block_diag(P_s, mu * P_f)
    P = U @ P @ U.T
    return 0.5 * (P + P.T)
