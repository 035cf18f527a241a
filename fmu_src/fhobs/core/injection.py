"""Exact flow of the filtering observer's output injection with the gain level frozen.

With sigma frozen at a level s, the part of Theorem 2's observer driven by the filter state
``psi`` and the innovation ``v = C z - y`` (y held) is linear:

    dpsi/dt = v + s^nu L_tilde psi,    dz/dt = s^(nu-1) d(ln s) L psi,    dv/dt = C dz/dt.

Because ``C G_d = (1 + nu) C``, the scaled pair ``r = (psi / s, v / s^(1+nu))`` obeys
``dr/dt = s^nu R r`` with the constant ``R = [[L_tilde, I], [C L, 0]]``, so over a substep hs,
with ``tau = hs s^nu``:

    psi(hs) = s (expm(tau R) r)[:k],    dz = tau d(ln s) L (phi1(tau R) r)[:k].

:class:`InjectionFlow` evaluates this from the eigen-decompositions ``R = V diag(lam) V^-1`` and
``G_d = V_g diag(g) V_g^-1``, each computed once, in few numpy calls (the filtering observer
makes this evaluation once per substep): every power of s is one entry of a single
``exp(ln s * exponents)``, and the two spectral factors ``exp(tau lam)`` and
``tau phi1(tau lam) = expm1(tau lam) / lam`` act on one stacked coefficient vector. If either
eigenvector matrix is ill-conditioned (cond > ``COND_LIMIT``), it uses the expm-based paths of
:class:`~fhobs.core.linalg.ExpmFamily` and :class:`~fhobs.core.dilation.Dilation` instead (also on
request, for tests).

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import math

import numpy as np

from .dilation import Dilation
from .linalg import ExpmFamily


class InjectionFlow:
    """``(psi, v) -> (psi(hs), dz)`` of the frozen-level injection flow (module docstring).

    Parameters
    ----------
    L_tilde : np.ndarray
        Filter gain (k x k).
    C : np.ndarray
        Output matrix of the observer's model (k x N).
    dilation : Dilation
        ``d(s) L``: the dilation of ``G_d`` (N x N, ``C G_d = (1 + nu) C``) with the gain L of
        the estimate (N x k) as its right factor.
    nu : float
        Homogeneity degree.
    force_fallback : bool
        Use the expm-based evaluation even if both decompositions are well conditioned (the
        dilation keeps its own setting).
    """

    def __init__(self, L_tilde: np.ndarray, C: np.ndarray, dilation: Dilation, nu: float,
                 force_fallback: bool = False) -> None:
        k = L_tilde.shape[0]
        self._k, self._nu = k, float(nu)
        R = np.block([[L_tilde, np.eye(k)], [C @ dilation.right, np.zeros((k, k))]])
        self._R = ExpmFamily(R, force_fallback=force_fallback)
        self._dilation = dilation
        self.eigen = self._R.use_eig and self._dilation.use_eig
        """Whether the eigen-decomposition path is used."""
        if self.eigen:
            self._prepare()

    def _prepare(self) -> None:
        """Precompute the stacked matrices of the eigen path.

        ``c2 = [V^-1; V^-1] r`` repeats the coefficients of r, the factors
        ``[exp(tau lam); tau phi1(tau lam)]`` (:meth:`ExpmFamily.spectral_factors`) scale them,
        and ``W = blkdiag(V[:k], V_g^-1 L V[:k])`` maps them to ``(expm(tau R) r)[:k]`` and
        ``V_g^-1 L (tau phi1(tau R) r)[:k]`` (up to round-off imaginary parts: the real part of
        the latter is taken after ``V_g`` instead of before).
        """
        k = self._k
        R, dilation = self._R, self._dilation
        V, V_inv = R.eigenvectors, R.eigenvectors_inverse
        g, V_g, V_g_inv_L = dilation.eigenvalues, dilation.eigenvectors, dilation.inverse_right
        n = V_g.shape[0]
        self._V_inv2 = np.vstack((V_inv, V_inv))
        self._W = np.zeros((k + n, 4 * k), dtype=complex)
        self._W[:k, :2 * k] = V[:k]
        self._W[k:, 2 * k:] = V_g_inv_L.dot(V[:k])
        self._V_g = V_g.astype(complex)
        # s-exponents of r = (psi / s, v / s^(1+nu)), then of psi(hs) = s (...) and d(ln s)
        self._exponents = np.concatenate((np.full(k, -1.0), np.full(k, -(1.0 + self._nu)),
                                          np.ones(k), g)).astype(g.dtype)

    def kernel_arrays(self) -> dict[str, np.ndarray | float]:
        """The eigen path's data for the compiled kernel (:mod:`fhobs.core.kernel`), complex128
        and C-contiguous: ``V_inv`` (2k x 2k), ``V_k = V[:k]``, ``WL = V_g^-1 L V[:k]``, ``V_g``,
        ``g`` (eigenvalues of G_d), ``lam`` (of R); ``real_lam`` (numpy's spectral factors are
        then real) and ``tiny`` (below this tau the factors use phi1's series where needed).
        Only when :attr:`eigen`."""
        k = self._k
        lam = self._R.eigenvalues
        return {
            "V_inv": np.ascontiguousarray(self._R.eigenvectors_inverse, dtype=complex),
            "V_k": np.ascontiguousarray(self._W[:k, :2 * k]),
            "WL": np.ascontiguousarray(self._W[k:, 2 * k:]),
            "V_g": np.ascontiguousarray(self._V_g),
            "g": np.ascontiguousarray(self._exponents[3 * k:], dtype=complex),
            "lam": np.ascontiguousarray(lam, dtype=complex),
            "real_lam": not np.iscomplexobj(lam),
            "tiny": self._R.tiny,
        }

    def apply(self, psi: np.ndarray, v: np.ndarray, log_s: float,
              tau: float) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(psi(hs), dz)`` for the level ``s = exp(log_s)`` and ``tau = hs s^nu``.

        Parameters
        ----------
        psi, v : np.ndarray
            Filter state (k) and innovation ``C z - y`` (k) at the start of the substep.
        log_s : float
            Natural logarithm of the frozen level s.
        tau : float
            ``hs s^nu``.
        """
        if not self.eigen:
            return self._apply_expm(psi, v, log_s, tau)
        k = self._k
        scale = np.exp(log_s * self._exponents)
        c2 = self._V_inv2.dot(np.concatenate((psi, v)) * scale[:2 * k])
        out = self._W.dot(self._R.spectral_factors(tau) * c2) * scale[2 * k:]
        return out[:k].real, self._V_g.dot(out[k:]).real

    def _apply_expm(self, psi: np.ndarray, v: np.ndarray, log_s: float,
                    tau: float) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`apply` through :class:`ExpmFamily` and :class:`Dilation` (their own
        eigen or expm paths)."""
        k = self._k
        level = math.exp(log_s)
        r = np.concatenate((psi / level, v * math.exp(-(1.0 + self._nu) * log_s)))
        exp_r, phi_r = self._R.apply(tau, r, rows=k)  # phi_r: tau phi1(tau R) r
        return level * exp_r, self._dilation.apply(log_s, phi_r)
