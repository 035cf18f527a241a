"""The linear dilation ``d(s) = expm(s G_d)`` evaluated cheaply and safely.

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import numpy as np

from fhobs.linalg import COND_LIMIT, expm


class Dilation:
    """``d(s) = expm(s G)`` from one eigen-decomposition ``G = V diag(g) V^-1``.

    ``d(s) x = V (exp(s g) * (V^-1 x))`` costs two small matrix-vector products. If V is
    ill-conditioned (cond > ``COND_LIMIT``), :func:`fhobs.linalg.expm` of ``s G`` is used.

    Parameters
    ----------
    G : np.ndarray
        Generator of the dilation (anti-Hurwitz), e.g. ``G_d``.
    force_fallback : bool
        Use the expm path even if G is well diagonalisable (for tests).
    """

    def __init__(self, G: np.ndarray, force_fallback: bool = False) -> None:
        self.G = np.array(G, dtype=float)
        g, V = np.linalg.eig(self.G)
        self.use_eig = (not force_fallback) and np.linalg.cond(V) < COND_LIMIT
        if self.use_eig:
            real = bool(np.all(g.imag == 0.0))
            self._g = g.real if real else g
            self._V = V.real if real else V
            self._Vinv = np.linalg.inv(self._V)

    def apply(self, s: float, x: np.ndarray) -> np.ndarray:
        """Return ``d(s) x`` (x a vector or a matrix)."""
        if self.use_eig:
            scale = np.exp(s * self._g)
            scale = scale if x.ndim == 1 else scale[:, None]
            return np.real(self._V @ (scale * (self._Vinv @ x)))
        return expm(s * self.G) @ x

    def matrix(self, s: float) -> np.ndarray:
        """Return the matrix ``d(s)``."""
        return self.apply(s, np.eye(self.G.shape[0]))
