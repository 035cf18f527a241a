"""Numpy-only matrix exponentials for the runtime: scaling-and-squaring expm and a precomputed
eigen-decomposition for the repeated evaluation of expm(tau R) and phi1(tau R).

``phi1(X) = sum_j X^j / (j+1)!`` is the function with ``expm(h M) x0 + h phi1(h M) b`` being the
exact solution at time h of ``dx/dt = M x + b``.

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import math

import numpy as np

# Pade(13) coefficients and the 1-norm bound theta_13 of Higham, SIAM J. Matrix Anal. Appl. 2005.
_PADE13 = (
    64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
    129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
    40840800.0, 960960.0, 16380.0, 182.0, 1.0,
)
_THETA13 = 5.371920351148152
COND_LIMIT = 1e8
"""Eigenvector condition number above which :class:`ExpmFamily` falls back to :func:`expm`."""


def spectral_radius(F: np.ndarray) -> float:
    """Spectral radius of a square matrix.

    Examples
    --------
    >>> spectral_radius(np.array([[0.0, 2.0], [-0.5, 0.0]]))
    1.0
    """
    return float(np.max(np.abs(np.linalg.eigvals(F))))


def expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential by Pade(13) scaling and squaring (Higham 2005), numpy only.

    Parameters
    ----------
    M : np.ndarray
        Square real matrix.

    Returns
    -------
    np.ndarray
        ``expm(M)``, agreeing with ``scipy.linalg.expm`` to a few ulps times cond.
    """
    M = np.asarray(M, dtype=float)
    norm = np.linalg.norm(M, 1)
    squarings = max(0, int(np.ceil(np.log2(norm / _THETA13)))) if norm > _THETA13 else 0
    X = M / 2.0**squarings
    b = _PADE13
    eye = np.eye(M.shape[0])
    X2 = X @ X
    X4 = X2 @ X2
    X6 = X4 @ X2
    U = X @ (X6 @ (b[13] * X6 + b[11] * X4 + b[9] * X2)
             + b[7] * X6 + b[5] * X4 + b[3] * X2 + b[1] * eye)
    V = X6 @ (b[12] * X6 + b[10] * X4 + b[8] * X2) + b[6] * X6 + b[4] * X4 + b[2] * X2 + b[0] * eye
    E = np.linalg.solve(V - U, V + U)
    for _ in range(squarings):
        E = E @ E
    return E


ZOH_CACHE_SIZE = 16
"""ZOH matrices are cached per step size; the cache is cleared when it holds this many."""


def zoh_blocks(A: np.ndarray, inputs: list[np.ndarray], h: float) -> list[np.ndarray]:
    """Exact zero-order-hold discretisation of ``dx/dt = A x + sum_i B_i w_i``.

    Parameters
    ----------
    A : np.ndarray
        (n, n) state matrix.
    inputs : list of np.ndarray
        Input matrices ``B_i`` of shape (n, m_i), inputs held over the step.
    h : float
        Step size.

    Returns
    -------
    list of np.ndarray
        ``[expm(h A), Gamma_1, ...]`` with ``Gamma_i = int_0^h expm(t A) dt B_i``, all from one
        exponential of the augmented matrix ``[[A, B_1, ...], [0, 0, ...]]``.
    """
    n = A.shape[0]
    widths = [B.shape[1] for B in inputs]
    size = n + sum(widths)
    aug = np.zeros((size, size))
    aug[:n, :n] = A
    if inputs:
        aug[:n, n:] = np.hstack(inputs)
    E = expm(h * aug)
    blocks = [E[:n, :n]]
    col = n
    for w in widths:
        blocks.append(E[:n, col:col + w])
        col += w
    return blocks


def phi1(X: np.ndarray) -> np.ndarray:
    """``phi1(X) = X^-1 (expm(X) - I)`` (also for singular X), from one augmented exponential."""
    n = X.shape[0]
    aug = np.zeros((2 * n, 2 * n))
    aug[:n, :n] = X
    aug[:n, n:] = np.eye(n)
    return expm(aug)[:n, n:]


PHI1_SERIES = 1e-8
"""Below this |mu|, phi1(mu) = 1 + mu/2 (to double precision)."""


def phi1_elementwise(mu: np.ndarray) -> np.ndarray:
    """Elementwise ``(exp(mu) - 1) / mu`` for complex mu, with the limit 1 at mu = 0."""
    small = np.abs(mu) < PHI1_SERIES
    safe = np.where(small, 1.0, mu)
    return np.where(small, 1.0 + 0.5 * mu, np.expm1(safe) / safe)


class ExpmFamily:
    """Cheap repeated evaluation of ``expm(tau R) r`` and ``tau phi1(tau R) r`` for a fixed R.

    ``R = V diag(lam) V^-1`` is computed once; each evaluation then costs two small
    matrix-vector products. If the eigenvectors are ill-conditioned (cond(V) > ``COND_LIMIT``,
    e.g. a defective R), every evaluation uses :func:`expm` of an augmented matrix instead.
    ``tau phi1(tau R) r = int_0^tau expm(t R) r dt`` is the flow's integral.

    Parameters
    ----------
    R : np.ndarray
        Square real matrix.
    force_fallback : bool
        Use the :func:`expm` path even if R is well diagonalisable (for tests).

    Attributes
    ----------
    eigenvalues, eigenvectors, eigenvectors_inverse : np.ndarray
        ``lam``, ``V`` and ``V^-1`` (complex unless every eigenvalue is real), set only when
        ``use_eig``.
    tiny : float
        At or below this tau, :meth:`spectral_factors` uses phi1's series where
        ``|tau lam| < PHI1_SERIES`` (set only when ``use_eig``).
    """

    def __init__(self, R: np.ndarray, force_fallback: bool = False) -> None:
        self.R = np.array(R, dtype=float)
        lam, V = np.linalg.eig(self.R)
        self.use_eig = (not force_fallback) and np.linalg.cond(V) < COND_LIMIT
        if self.use_eig:
            size = lam.size
            self.eigenvalues = lam
            self.eigenvectors = V
            self.eigenvectors_inverse = np.linalg.inv(V)
            self._lam2 = np.concatenate((lam, lam))
            self._divisor = np.concatenate((np.ones(size), lam))
            self._offset = np.concatenate((np.ones(size), np.zeros(size)))
            self.tiny = PHI1_SERIES / max(float(np.min(np.abs(lam))), 1e-300)
            self._last: tuple[float, np.ndarray] = (math.nan, self._offset)

    def spectral_factors(self, tau: float) -> np.ndarray:
        """``[exp(tau lam); tau phi1(tau lam)]`` (eigen path only), as ``expm1(tau lam) + 1``
        and ``expm1(tau lam) / lam``, or with the series of phi1 where ``|tau lam|`` may be
        tiny. The last tau's are kept (a capped gain level and the level search evaluate one
        tau repeatedly)."""
        last_tau, factors = self._last
        if tau != last_tau:
            if tau > self.tiny:
                factors = np.expm1(tau * self._lam2) / self._divisor + self._offset
            else:
                mu = tau * self.eigenvalues
                factors = np.concatenate((np.exp(mu), tau * phi1_elementwise(mu)))
            self._last = (tau, factors)
        return factors

    def apply(self, tau: float, r: np.ndarray,
              rows: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(expm(tau R) r, tau phi1(tau R) r)`` for tau >= 0, or their first ``rows``
        entries only."""
        size = self.R.shape[0]
        if self.use_eig:
            c = self.eigenvectors_inverse.dot(r)
            factors = self.spectral_factors(tau)
            V = self.eigenvectors[:rows]
            return V.dot(factors[:size] * c).real, V.dot(factors[size:] * c).real
        aug = np.zeros((size + 1, size + 1))
        aug[:size, :size] = tau * self.R
        aug[:size, size] = tau * r
        E = expm(aug)
        return (E[:size, :size] @ r)[:rows], E[:size, size][:rows]


def diagonal_similarity(M: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``diag(d)^-1 M diag(d)``: M in the coordinates ``x = diag(d) x_b`` (exact in floating
    point when d holds powers of two, as :func:`balancing_scale` gives).

    Examples
    --------
    >>> diagonal_similarity(np.array([[1.0, 8.0], [2.0, 3.0]]), np.array([1.0, 0.25])).tolist()
    [[1.0, 2.0], [8.0, 3.0]]
    """
    return M / d[:, None] * d[None, :]


def diagonal_congruence(P: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``diag(d) P diag(d)``: a quadratic form's matrix in the coordinates ``x = diag(d) x_b``.

    Examples
    --------
    >>> diagonal_congruence(np.eye(2), np.array([2.0, 0.5])).tolist()
    [[4.0, 0.0], [0.0, 0.25]]
    """
    return P * d[:, None] * d[None, :]


BALANCE_SWEEPS = 100
"""Most sweeps of :func:`balancing_scale` (it usually converges in a few)."""


def balancing_scale(M: np.ndarray) -> np.ndarray:
    """Powers of two d with ``diag(d)^-1 M diag(d)`` balanced (off-diagonal row and column
    1-norms within a factor of two of each other), the scaling of LAPACK's ``gebal`` without
    permutations. Scaling by powers of two is exact in floating point.

    Parameters
    ----------
    M : np.ndarray
        Square real matrix.

    Returns
    -------
    np.ndarray
        The vector d (all ones for a balanced M).

    Examples
    --------
    >>> import numpy as np
    >>> balancing_scale(np.array([[1.0, 1024.0], [1.0, 1.0]])).tolist()
    [32.0, 1.0]
    """
    B = np.abs(np.array(M, dtype=float))
    np.fill_diagonal(B, 0.0)
    d = np.ones(B.shape[0])
    for _ in range(BALANCE_SWEEPS):
        converged = True
        for i in range(B.shape[0]):
            col, row = B[:, i].sum(), B[i, :].sum()
            if col == 0.0 or row == 0.0:
                continue
            f, c, r = 1.0, col, row
            while c < r / 2.0:
                f, c, r = 2.0 * f, 2.0 * c, r / 2.0
            while c >= 2.0 * r:
                f, c, r = f / 2.0, c / 2.0, 2.0 * r
            if c + r < 0.95 * (col + row):
                converged = False
                d[i] *= f
                B[:, i] *= f
                B[i, :] /= f
        if converged:
            break
    return d
