"""The linear dilation ``d(s) = expm(s G_d)`` evaluated cheaply and safely.

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import numpy as np

from .linalg import COND_LIMIT, expm


class Dilation:
    """``d(s) = expm(s G)`` from one eigen-decomposition ``G = V diag(g) V^-1``.

    ``d(s) M x = V (exp(s g) * (V^-1 M x))`` costs two small matrix-vector products (``V^-1 M``
    is precomputed). If V is ill-conditioned (cond > ``COND_LIMIT``), :func:`fhobs.core.linalg.expm`
    of ``s G`` is used.

    Parameters
    ----------
    G : np.ndarray
        Generator of the dilation (anti-Hurwitz), e.g. ``G_d``.
    right : np.ndarray or None
        Fixed right factor M (identity if None), e.g. a gain ``L``.
    force_fallback : bool
        Use the expm path even if G is well diagonalisable (for tests).

    Attributes
    ----------
    eigenvalues, eigenvectors, inverse_right : np.ndarray
        ``g``, ``V`` and ``V^-1 M`` (real if every eigenvalue is), set only when ``use_eig``.
    """

    def __init__(self, G: np.ndarray, right: np.ndarray | None = None,
                 force_fallback: bool = False) -> None:
        self.G = np.array(G, dtype=float)
        self.right = np.eye(self.G.shape[0]) if right is None else np.array(right, dtype=float)
        g, V = np.linalg.eig(self.G)
        self.use_eig = (not force_fallback) and np.linalg.cond(V) < COND_LIMIT
        if self.use_eig:
            real = bool(np.all(g.imag == 0.0))
            self.eigenvalues = g.real if real else g
            self.eigenvectors = V.real if real else V
            self.inverse_right = np.linalg.solve(self.eigenvectors, self.right)

    def apply(self, s: float, x: np.ndarray) -> np.ndarray:
        """Return ``d(s) M x`` (x a vector or a matrix)."""
        if self.use_eig:
            scale = np.exp(s * self.eigenvalues)
            scale = scale if x.ndim == 1 else scale[:, None]
            out = self.eigenvectors.dot(scale * self.inverse_right.dot(x))
            return out if out.dtype.kind == "f" else out.real
        return expm(s * self.G) @ (self.right @ x)

    def matrix(self, s: float) -> np.ndarray:
        """Return the matrix ``d(s) M``."""
        return self.apply(s, np.eye(self.right.shape[1]))
