"""Discrete-time observers (numpy only): filtering homogeneous, prescribed-time and Luenberger.

Every observer advances by a communication step ``dt`` with ``y`` and ``u`` held, in internal
substeps of size ``<= h``, with one of two schemes:

``euler``
    The paper's explicit Euler transcription (the paper's numerical example). Faithful, but the
    filtering observer's gain ``sigma^(nu-1) d(ln sigma) L`` grows without bound as the error
    vanishes and explicit Euler loses stability (h * gain large).

``split`` (default)
    A sampled-data scheme whose estimation error obeys an autonomous linear recursion whatever
    the plant's motion between samples, so the nominal error converges to round-off:

    1. *correction*: the observer's output-injection part (everything driven by ``psi`` and the
       innovation ``v = C z - y``: ``dpsi = v + sigma^nu L_tilde psi``,
       ``dz = sigma^(nu-1) d(ln sigma) L psi``) is integrated *exactly* with the gain frozen at
       the step's start. Because ``C G_d = (1 + nu) C``, the innovation pair ``(psi, v)`` obeys
       ``d/dt (psi/s, v/s^(1+nu)) = s^nu R (psi/s, v/s^(1+nu))`` with the constant
       ``R = [[L_tilde, I], [C L, 0]]``, so one eigen-decomposition of R (done once) gives the
       exact flow for every sigma (:class:`fhobs.injection.InjectionFlow`);
    2. *prediction*: ``z <- expm(h A) z + Gamma_B u + Gamma_L0 v`` (exact zero-order hold of the
       model, the innovation held), the very map that the plant applies to x.

    Within a communication step with several substeps the innovation is propagated with the
    observer's own model (``v = C (z - m) + (C z_k - y_k)``, m the open-loop prediction from
    ``z_k``), so that it stays a linear function of the error at ``t_k``.

    **Gain cap.** The frozen-gain map is contractive only while ``tau = dt sigma^nu`` stays
    moderate, dt the communication step (for large tau the sampled measurement, not the gain,
    limits what can be known; one sample per dt is all the observer gets): the gain level is
    therefore floored at ``sigma_min = (tau_max / dt)^(1/nu)``. Below that level the scheme is a
    fixed linear discrete-time observer (the discrete limit of the homogeneous one) with
    contraction ``rho(tau_max)`` per communication step. ``tau_max`` defaults to the value
    minimising that spectral radius for dt = h (computed at construction); with substeps the
    per-step map stays contractive (checked in the tests).

Edges: ``sigma = 0`` (all-zero start) and ``xi = 0`` (prescribed time reached) use the capped
level, so no 0 * inf appears; a step that would produce a non-finite state raises ValueError
and leaves the state untouched.

Prescribed-time observer at and after ``T0 = xi0^(-nu) / (-nu rho)``: ``xi`` is integrated
exactly (``|xi|^(-nu)`` decreases linearly), reaches 0 exactly and stays 0; the gain
``|xi|^(nu-1) expm(ln|xi| (G_d - nu I)) L_pt`` is evaluated at ``max(|xi|, xi_min)`` with
``xi_min = (tau_max / dt)^(1/nu)`` (both schemes), so after T0 the observer is the capped
constant-gain discrete observer: finite, convergent in the nominal case, never NaN.

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from fhobs.dilation import Dilation
from fhobs.gains import ObserverGains
from fhobs.injection import InjectionFlow
from fhobs.linalg import ExpmFamily, zoh_blocks
from fhobs.plant import (
    ZOH_CACHE_SIZE,
    all_finite,
    as_finite_vector,
    check_step_size,
    floating_point_failure,
)


class Prediction(NamedTuple):
    """Exact zero-order hold of the observer's model over a substep, the innovation v held:
    ``z+ = Phi z + Gamma_B u + Gamma_inj v = M (z, u, v)``; ``F = Phi + Gamma_inj C`` carries a
    correction dz of z (which also moves v by C dz) into z+."""

    Phi: np.ndarray
    Gamma_inj: np.ndarray
    M: np.ndarray
    F: np.ndarray


SCHEMES = ("split", "euler")
"""Integration schemes; the first one is the default."""

TAU_GRID = np.geomspace(0.05, 3.0, 40)
"""Candidate values of tau_max scanned at construction (spectral radius of the capped map)."""

MAX_SUBSTEPS = 1_000_000
"""A communication step needing more internal steps than this is rejected (ValueError) rather
than run for minutes: a step size of hours with h = 5e-5 is a mistake, not a request."""

LEVEL_MISMATCH = 2.0
"""Split scheme: the frozen level is made self-consistent when sigma would exceed it by this."""
BISECTION_STEPS = 40
BISECTION_TOL = 0.05
"""Bracket expansion steps and tolerance (in ln sigma) of the self-consistent level."""

SIGMA_GUARD = 1e-150
"""Euler scheme of the filtering observer: the gain is evaluated at max(sigma, SIGMA_GUARD).
Since |psi| <= sqrt(2) sigma, the gain term stays finite and the guard never acts in practice."""


def signed_power(w: float, p: float) -> float:
    """``floor(w)^p = |w|^p sign(w)``."""
    return math.copysign(abs(w) ** p, w) if w else 0.0


def signed_power_decay(w: float, gamma: float, p: float, h: float) -> float:
    """Exact flow over h of ``dw/dt = -gamma floor(w)^p`` with 0 < p < 1 (reaches 0, stays 0)."""
    q = 1.0 - p
    return math.copysign(max(abs(w) ** q - q * gamma * h, 0.0) ** (1.0 / q), w) if w else 0.0


def spectral_radius(F: np.ndarray) -> float:
    """Spectral radius of a square matrix."""
    return float(np.max(np.abs(np.linalg.eigvals(F))))


class _Observer:
    """Common machinery: input checks, substepping, ZOH model, transactional state.

    Subclasses set ``_aux`` (their extra states), ``_L_inj`` (the gain of the held innovation in
    the prediction) and implement ``_correct``, ``_euler_rates`` and ``_level``. ``model`` is the
    ``(A, B, C)`` the observer runs on: the plant's for the Luenberger observer,
    ``gains.model`` (possibly with a disturbance model) for the homogeneous ones.
    """

    _aux: np.ndarray
    _n_error_aux = 0
    """Number of leading aux entries that belong to the estimation error (psi)."""

    def __init__(self, gains: ObserverGains, h: float, scheme: str, z0: np.ndarray | None,
                 L_inj: np.ndarray, model: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        if scheme not in SCHEMES:
            raise ValueError(f"unknown scheme {scheme!r}; choose one of {SCHEMES}")
        self.gains = gains
        self.h = check_step_size(h)
        self.scheme = scheme
        self._k, self._m, self._nu = gains.k, gains.m, gains.nu
        self._A, self._B, self._C = model
        n = self._A.shape[0]
        self._z = np.zeros(n) if z0 is None else as_finite_vector(z0, n, "z0")
        self._L_inj = L_inj
        self._zoh: dict[float, Prediction] = {}

    # -- public interface -------------------------------------------------------------------
    @property
    def z(self) -> np.ndarray:
        """The observer's model state (copy): the plant's state estimate, then, with a
        disturbance model, the estimates of q and its derivatives."""
        return self._z.copy()

    @property
    def x_hat(self) -> np.ndarray:
        """Estimate of the plant's state (copy of the first n entries of z)."""
        return self._z[:self.gains.n].copy()

    def step(self, y: np.ndarray, u: np.ndarray, dt: float) -> None:
        """Advance by dt with y and u held, in substeps of size <= h.

        Raises
        ------
        ValueError
            On invalid y, u or dt, or if the step would make the state non-finite or raises a
            floating-point error (the state is then left unchanged). Numpy's floating-point
            error handling is the caller's (a diverging step may warn of the overflow first;
            under ``np.errstate(all="raise")`` any overflow or underflow raises, and becomes
            this ValueError): a context of our own would cost about 2 us per step.
        """
        self.advance(as_finite_vector(y, self._k, "y"), as_finite_vector(u, self._m, "u"),
                     check_step_size(dt))

    def advance(self, y: np.ndarray, u: np.ndarray, dt: float) -> None:
        """:meth:`step` without checking its arguments, for a caller that has: y and u finite
        float vectors of k and m entries, dt positive and finite (the FMU slaves check their
        inputs once). A non-finite result, or a step needing more than ``MAX_SUBSTEPS``
        internal steps, still raises ValueError, the state unchanged."""
        n_sub = max(1, math.ceil(dt / self.h * (1.0 - 1e-12)))
        if n_sub > MAX_SUBSTEPS:
            raise ValueError(f"the step size {dt!r} needs {n_sub} internal steps of h = "
                             f"{self.h!r}, more than {MAX_SUBSTEPS}; state left unchanged")
        hs = dt / n_sub
        run = self._run_split if self.scheme == "split" else self._run_euler
        try:  # the schemes never write into their arguments: the state stays as it was
            z, aux = run(self._z, self._aux, y, u, hs, n_sub)
        except ArithmeticError as err:
            raise floating_point_failure(self.scheme, err) from err
        if not (all_finite(z) and all_finite(aux)):
            raise ValueError(f"the {self.scheme} step diverged (non-finite state); "
                             "state left unchanged")
        self._z, self._aux = z, aux

    def get_state(self) -> np.ndarray:
        """Full internal state ``[z, aux]`` (a copy)."""
        return np.concatenate([self._z, self._aux])

    def set_state(self, arr: np.ndarray) -> None:
        """Restore a state from :meth:`get_state` exactly."""
        n = self._z.size
        arr = as_finite_vector(arr, n + self._aux.size, "observer state")
        self._z, self._aux = arr[:n].copy(), arr[n:].copy()

    def diagnostics(self) -> dict[str, float | np.ndarray]:
        """Scalars/arrays describing the internal state (subclasses add theirs)."""
        return {"z": self.z}

    # -- schemes ----------------------------------------------------------------------------
    def _prediction(self, hs: float) -> Prediction:
        """The exact ZOH prediction over a substep hs (cached per substep size)."""
        prediction = self._zoh.get(hs)
        if prediction is None:
            if len(self._zoh) >= ZOH_CACHE_SIZE:  # variable steps: keep the cache bounded
                self._zoh.clear()
            Phi, Gamma_B, Gamma_inj = zoh_blocks(self._A, [self._B, self._L_inj], hs)
            prediction = self._zoh[hs] = Prediction(
                Phi, Gamma_inj, np.hstack((Phi, Gamma_B, Gamma_inj)), Phi + Gamma_inj @ self._C)
        return prediction

    def _run_split(self, z, aux, y, u, hs, n_sub, level=None):
        """The split scheme over n_sub substeps (see the module docstring); the gain level is
        the observer's own (capped for the communication step hs * n_sub) unless given."""
        C = self._C
        prediction = self._prediction(hs)
        innovation0 = C.dot(z) - y
        v = innovation0
        drift = np.zeros(z.size)  # z - m, m the observer's open-loop model prediction from t_k
        for i in range(n_sub):
            z, aux, F_dz = self._split_substep(prediction, z, aux, v, u, hs, hs * n_sub, level)
            if i + 1 < n_sub:
                drift = prediction.Phi.dot(drift) + prediction.Gamma_inj.dot(v)
                if F_dz is not None:
                    drift = drift + F_dz
                v = C.dot(drift) + innovation0
        return z, aux

    def _split_substep(self, prediction, z, aux, v, u, hs, dt, level=None):
        """Correction (exact, gain frozen at ``level``, by default the observer's own level
        capped for the communication step dt) then the ZOH ``prediction`` over hs with v held:
        ``z+ = Phi (z + dz) + Gamma_B u + Gamma_inj (v + C dz) = M (z, u, v) + F dz``.

        Returns the new z and aux and ``F dz`` (None if the observer has no correction).
        """
        if level is None:
            aux, dz = self._correct_own_level(aux, v, hs, dt)
        else:
            aux, dz = self._correct(aux, v, hs, level)
        z_new = prediction.M.dot(np.concatenate((z, u, v)))
        if dz is None:
            return z_new, aux, None
        F_dz = prediction.F.dot(dz)
        return z_new + F_dz, aux, F_dz

    def _run_euler(self, z, aux, y, u, hs, n_sub):
        """The paper's explicit Euler over n_sub substeps, y held."""
        for _ in range(n_sub):
            v = self._C @ z - y
            daux, dz_gain = self._euler_rates(aux, v, hs * n_sub)
            z = z + hs * (self._A @ z + self._B @ u + self._L_inj @ v + dz_gain)
            aux = aux + hs * daux
        return z, aux

    def _level(self, aux: np.ndarray, dt: float) -> float:
        """Gain level (sigma or |xi|, capped for the communication step dt) at which the split
        substep freezes the gain."""
        return 1.0

    def _floor(self, dt: float) -> float:
        """Gain-level cap ``(tau_max / dt)^(1/nu)`` for the communication step dt."""
        return (self.tau_max / dt) ** (1.0 / self.gains.nu)

    def _correct_own_level(self, aux: np.ndarray, v: np.ndarray, hs: float,
                           dt: float) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`_correct` at the observer's own gain level."""
        return self._correct(aux, v, hs, self._level(aux, dt))

    def _correct(self, aux: np.ndarray, v: np.ndarray, hs: float,
                 level: float) -> tuple[np.ndarray, np.ndarray | None]:
        """Exact correction flow over hs: return (new aux, increment of z), the increment
        None for an observer without one."""
        return aux, None

    def _euler_rates(self, aux: np.ndarray, v: np.ndarray,
                     dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Paper's right-hand side beyond ``A z + B u + L_inj v``: (d aux/dt, gain term of dz);
        dt is the communication step (for a gain cap)."""
        return np.zeros_like(aux), np.zeros(self._z.size)

    def error_map(self, level: float, n_sub: int = 1) -> np.ndarray:
        """Matrix of one split communication step of n_sub substeps of size h acting on the
        estimation error at a frozen gain level (sigma or |xi|): the error is ``(psi, z - x)``
        for the filtering observer and ``z - x`` otherwise. It is the observer's step with
        x = 0, y = 0 and u = 0, which is linear in the error; for analysis and tests."""
        g = self.gains
        n_lin = self._n_error_aux
        columns = []
        for e in np.eye(n_lin + self._z.size):
            aux = np.zeros_like(self._aux)
            aux[:n_lin] = e[:n_lin]
            z, aux = self._run_split(e[n_lin:], aux, np.zeros(g.k), np.zeros(g.m), self.h,
                                     n_sub, level)
            columns.append(np.concatenate([aux[:n_lin], z]))
        return np.column_stack(columns)

    def _auto_tau_max(self) -> float:
        """tau in TAU_GRID minimising the spectral radius of the capped error map (size h)."""
        nu = self.gains.nu
        radii = [spectral_radius(self.error_map((t / self.h) ** (1.0 / nu))) for t in TAU_GRID]
        return float(TAU_GRID[int(np.argmin(radii))])


class FilteringObserver(_Observer):
    """Filtering homogeneous observer (Theorem 2; HOSM case nu = -1/(n_tilde+1) included).

    Parameters
    ----------
    gains : ObserverGains
        The design (uses A, B, C, L0, G_d, L_tilde, L, nu, gamma).
    h : float
        Maximal internal step.
    scheme : str
        One of ``SCHEMES``.
    z0, psi0 : array_like or None
        Initial model state (``gains.n_model`` entries: x, then the disturbance model's) and
        filter state (zeros if None).
    xi0 : float
        Initial xi.
    tau_max : float or None
        Gain cap of the split scheme, ``dt sigma^nu <= tau_max`` (dt the communication step);
        None picks it automatically.
    """

    def __init__(self, gains: ObserverGains, h: float = 5e-5, scheme: str = SCHEMES[0],
                 z0: np.ndarray | None = None, psi0: np.ndarray | None = None,
                 xi0: float = 0.0, tau_max: float | None = None) -> None:
        super().__init__(gains, h, scheme, z0, gains.L0, gains.model)
        k = gains.k
        psi = np.zeros(k) if psi0 is None else as_finite_vector(psi0, k, "psi0")
        self._aux = np.append(psi, as_finite_vector(xi0, 1, "xi0"))
        self._n_error_aux = k
        self._dilation = Dilation(gains.G_d, right=gains.L)
        self._flow = InjectionFlow(gains.L_tilde, self._C, self._dilation, gains.nu)
        self._p = gains.nu / 2.0 + 1.0
        self.tau_max = (self._auto_tau_max()
                        if tau_max is None else float(tau_max))

    def diagnostics(self) -> dict[str, float | np.ndarray]:
        """``z``, ``psi``, ``xi``, ``sigma`` and the capped gain level of the split scheme."""
        psi, xi = self._aux[:-1], float(self._aux[-1])
        return {"z": self.z, "psi": psi.copy(), "xi": xi, "sigma": self._sigma(self._aux),
                "sigma_min": self._floor(self.h)}

    @property
    def sigma(self) -> float:
        """Current ``sigma = sqrt(max(xi, |psi|^2 / 2))``."""
        return self._sigma(self._aux)

    @staticmethod
    def _sigma(aux: np.ndarray) -> float:
        """``sigma = sqrt(max(xi, |psi|^2 / 2))``."""
        *psi, xi = aux.tolist()
        return math.sqrt(max(xi, 0.5 * sum(p * p for p in psi), 0.0))

    def _level(self, aux: np.ndarray, dt: float) -> float:
        """``max(sigma, sigma_min)`` with ``sigma_min = (tau_max / dt)^(1/nu)``."""
        return max(self._sigma(aux), self._floor(dt))

    def _correct_own_level(self, aux, v, hs, dt):
        """Correction at ``max(sigma, sigma_min)``, redone at a self-consistent level when it
        leaves sigma above ``LEVEL_MISMATCH`` times the frozen level (e.g. at an all-zero start,
        where sigma = 0 but psi grows at once): that level s solves ``sigma_after(s) = s``
        (bisection in ln s; sigma_after(s) / s decreases in s), so the frozen gain matches the
        psi it produces."""
        level = self._level(aux, dt)
        result = self._correct(aux, v, hs, level)
        after = self._sigma(result[0])
        if after <= LEVEL_MISMATCH * level:
            return result
        lo, hi = math.log(level), math.log(after)
        for _ in range(BISECTION_STEPS):
            result = self._correct(aux, v, hs, math.exp(hi))
            if self._sigma(result[0]) <= math.exp(hi):
                break
            lo, hi = hi, hi + 2.0
        while hi - lo > BISECTION_TOL:
            mid = 0.5 * (lo + hi)
            trial = self._correct(aux, v, hs, math.exp(mid))
            if self._sigma(trial[0]) <= math.exp(mid):
                hi, result = mid, trial
            else:
                lo = mid
        return result

    def _correct(self, aux, v, hs, level):
        """Exact flow of the (psi, z) injection with sigma frozen at ``level``, then xi."""
        k = self._k
        psi = aux[:k]
        log_s = math.log(level)
        psi_new, dz = self._flow.apply(psi, v, log_s, hs * math.exp(self._nu * log_s))
        aux_new = np.empty(k + 1)
        aux_new[:k] = psi_new
        aux_new[k] = self._xi_update(psi, aux_new[:k], float(aux[k]), hs)
        return aux_new, dz

    def _xi_update(self, psi: np.ndarray, psi_new: np.ndarray, xi: float, hs: float) -> float:
        """xi: ``|psi^T dpsi/dt|`` integrated as ``|Delta |psi|^2/2|``, then the exact decay of
        ``w = xi - |psi|^2/2`` under ``-gamma floor(w)^(nu/2+1)``."""
        # 0.5 * (p . p) is bit for bit (0.5 p) . p: scaling by 2^-1 is exact
        half_old, half_new = 0.5 * float(psi.dot(psi)), 0.5 * float(psi_new.dot(psi_new))
        w = xi + abs(half_new - half_old) - half_new
        return signed_power_decay(w, self.gains.gamma, self._p, hs) + half_new

    def _euler_rates(self, aux, v, dt):
        g = self.gains
        psi, xi = aux[:-1], float(aux[-1])
        sigma = self._sigma(aux)
        if sigma > 0.0:
            log_s = math.log(max(sigma, SIGMA_GUARD))
            dz_gain = math.exp((g.nu - 1.0) * log_s) * self._dilation.apply(log_s, psi)
            dpsi = v + math.exp(g.nu * log_s) * (g.L_tilde @ psi)
        else:  # sigma = 0 forces psi = 0: the homogeneous terms vanish
            dz_gain, dpsi = np.zeros(self._z.size), v
        dxi = abs(psi @ dpsi) - g.gamma * signed_power(xi - 0.5 * psi @ psi, self._p)
        return np.append(dpsi, dxi), dz_gain


class PrescribedTimeObserver(_Observer):
    """Prescribed-time observer (Theorem 1), dilation generator ``G = G_d - nu I``.

    The gain ``|xi|^(nu-1) expm(ln|xi| G) L_pt = |xi|^-1 d(ln|xi|) L_pt`` is evaluated at
    ``max(|xi|, (tau_max/dt)^(1/nu))`` (see the module docstring for the behaviour after T0).

    Parameters
    ----------
    gains : ObserverGains
        The design (uses A, B, C, L0, G_d, L_pt, nu, rho).
    h, scheme, z0 :
        As for :class:`FilteringObserver`.
    xi0 : float
        Initial xi (nonzero); the prescribed time is ``T0 = |xi0|^(-nu) / (-nu rho)``.
    tau_max : float or None
        Gain cap ``dt |xi|^nu <= tau_max`` (dt the communication step); None: automatic.
    """

    def __init__(self, gains: ObserverGains, h: float = 5e-5, scheme: str = SCHEMES[0],
                 z0: np.ndarray | None = None, xi0: float = 1.0,
                 tau_max: float | None = None) -> None:
        super().__init__(gains, h, scheme, z0, gains.L0, gains.model)
        self._aux = as_finite_vector(xi0, 1, "xi0")
        self._dilation = Dilation(gains.G_d, right=gains.L_pt)
        self._Q = ExpmFamily(self._C @ gains.L_pt)
        self.tau_max = (self._auto_tau_max()
                        if tau_max is None else float(tau_max))

    @property
    def T0(self) -> float:
        """Time (from the current state) at which xi reaches 0."""
        g = self.gains
        return abs(float(self._aux[0])) ** (-g.nu) / (-g.nu * g.rho)

    def diagnostics(self) -> dict[str, float | np.ndarray]:
        """``z``, ``xi`` and the gain level actually used."""
        return {"z": self.z, "xi": float(self._aux[0]), "level": self._level(self._aux, self.h)}

    def _level(self, aux: np.ndarray, dt: float) -> float:
        """``max(|xi|, xi_min)`` with ``xi_min = (tau_max / dt)^(1/nu)``."""
        return max(abs(float(aux[0])), self._floor(dt))

    def _xi_exact(self, xi: float, hs: float) -> float:
        """Exact flow of ``dxi/dt = -rho |xi|^(1+nu) sign(xi)``: |xi|^-nu decreases linearly."""
        g = self.gains
        if xi == 0.0:
            return 0.0
        return math.copysign(max(abs(xi) ** (-g.nu) + g.nu * g.rho * hs, 0.0) ** (-1.0 / g.nu),
                             xi)

    def _correct(self, aux, v, hs, level):
        """Exact flow of ``dz = gain (C z - y)`` with x frozen: ``dv = xi^nu C L_pt v``."""
        g = self.gains
        log_x = math.log(level)
        tau = hs * math.exp(g.nu * log_x)
        _, phi_v = self._Q.apply(tau, v * math.exp(-(1.0 + g.nu) * log_x))  # tau phi1(tau Q) v
        dz = self._dilation.apply(log_x, phi_v)
        return np.array([self._xi_exact(float(aux[0]), hs)]), dz

    def _euler_rates(self, aux, v, dt):
        g = self.gains
        xi = float(aux[0])
        log_x = math.log(self._level(aux, dt))
        dz_gain = math.exp(-log_x) * self._dilation.apply(log_x, v)
        return np.array([-g.rho * signed_power(xi, 1.0 + g.nu)]), dz_gain


class LuenbergerObserver(_Observer):
    """Luenberger baseline ``dz/dt = A z + B u + L_lin (C z - y)``.

    The split scheme is the exact ZOH of the model with the innovation held, i.e. the error
    obeys ``e_{k+1} = (expm(h A) + Gamma_Llin C) e_k`` exactly; ``euler`` is explicit Euler.
    """

    def __init__(self, gains: ObserverGains, h: float = 5e-5, scheme: str = SCHEMES[0],
                 z0: np.ndarray | None = None) -> None:
        super().__init__(gains, h, scheme, z0, gains.L_lin, (gains.A, gains.B, gains.C))
        self._aux = np.zeros(0)
