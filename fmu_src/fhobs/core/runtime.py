"""Discrete-time observers (numpy only): filtering homogeneous, prescribed-time and Luenberger.

Every observer advances by a communication step ``dt`` with ``y`` and ``u`` held, in internal
substeps of size ``<= h``, with one of two schemes:

``euler``
    The paper's explicit Euler transcription (the paper's numerical example). Faithful, but the
    filtering observer's gain ``sigma^(nu-1) d(ln sigma) L`` grows without bound as the error
    vanishes and explicit Euler loses stability (h * gain large).

``split`` (default)
    A sampled-data scheme whose estimation error obeys an autonomous linear recursion whatever
    the plant's motion between samples, so the nominal error converges to round-off. One step
    covers the whole communication step dt (the observer receives one sample per dt; the
    internal step h only bounds the ``euler`` scheme's steps):

    1. *correction*: the observer's output-injection part (everything driven by ``psi`` and the
       innovation ``v = C z - y``: ``dpsi = v + sigma^nu L_tilde psi``,
       ``dz = sigma^(nu-1) d(ln sigma) L psi``) is integrated *exactly* with the gain frozen at
       the step's start. Because ``C G_d = (1 + nu) C``, the innovation pair ``(psi, v)`` obeys
       ``d/dt (psi/s, v/s^(1+nu)) = s^nu R (psi/s, v/s^(1+nu))`` with the constant
       ``R = [[L_tilde, I], [C L, 0]]``, so one eigen-decomposition of R (done once) gives the
       exact flow for every sigma (:class:`fhobs.core.injection.InjectionFlow`);
    2. *prediction*: ``z <- expm(dt A) z + Gamma_B u + Gamma_L0 v`` (exact zero-order hold of
       the model, the innovation held), the very map that the plant applies to x.

    **Gain cap.** With the gain frozen at a level s the step maps the error ``(psi, z - x)``
    linearly; in the dilated coordinates ``(psi / s, d(-ln s)(z - x))`` that map depends on
    ``tau = dt s^nu`` only (for a given dt), and it contracts for small tau (it tends to the
    continuous flow) but not for tau of order one or more, where the sampled measurement, not
    the gain, limits what can be known. The gain level is therefore floored at
    ``sigma_min = (tau_max / dt)^(1/nu)``: below it the scheme is a fixed linear discrete-time
    observer with contraction ``rho(tau_max)`` per step. By default ``tau_max`` is chosen for
    each communication step size at its first use (:meth:`_Observer.cap`): the tau of
    ``TAU_GRID`` with the smallest spectral radius of the dilated map among the grid's leading
    run of contractive values, so that every level above the floor contracts too. A step size
    for which no tau of the grid contracts is refused with a ValueError. The smallest taus
    (large errors, small gains) need not contract either: held over dt, the homogenisation
    gain L0 makes ``expm(dt A) + Gamma_L0 C`` grow slightly (by 1e-7 to 1e-2 per step on the
    bundled plants, most on fast unstable ones), which a weak homogeneous correction does not
    compensate. The level is therefore also ceiled at ``(tau_min / dt)^(1/nu)``, tau_min the
    end of the run of contractive taus from tau_max towards higher levels, so that large
    errors meet a contractive gain instead of diverging; the ceiling is never below the floor.
    That run reads only radii that double precision can decide: at levels the observer uses
    (at or above the floor) whose dilation is conditioned within ``SCALING_LIMIT``; beyond,
    the radii of the smallest taus (within 1e-9 of one) are round-off and differ between BLAS
    kernels, so the run passes them. Where the radius does not depend on the level, tau_max is
    the largest tau of that plateau (``RADIUS_TIE``).

    **Round-off floor.** At a level s the gain amplifies an error of the measured output by
    about ``||C|| ||(d(ln s))_x|| / s^(1+nu)`` into the estimate of the plant's state (the
    dilated coordinates see the output scaled by ``s^-(1+nu)``, and the plant's rows of
    ``d(ln s)`` map them back; a disturbance model's states are estimates of q, not of the
    plant, and are left out): for deep observability
    chains (n_tilde large) this reaches 1e10 long before the contraction floor, and the
    round-off of y (1e-16 relative) alone then keeps the deep states' error at 1e-6..1e-3 (the
    Levant limit ``eps^(1/n_tilde)`` of exact differentiators). The level is therefore also
    floored at the s where that amplification equals ``AMPLIFICATION_LIMIT``, so the capped
    observer's bandwidth stays where double precision can follow it.

**Variable communication steps.** The floor depends on dt alone, so steps of different sizes
in turn would use levels far apart (a ratio of ``(dt2/dt1)^(-1/nu)``), and the product of
maps that each contract in their own dilated coordinates need not contract. The floor is
therefore carried into the next step in the gain state: the filtering observer's xi is at
least the floor squared after a step, the prescribed-time observer's gain-level state (its
state ``[z, xi, level]``) at least the floor; the level then falls from one step to the next
only as the observer's own gain law lets it (docs/theory.md, "Variable communication steps").

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

import functools
import math
import sys
from collections import OrderedDict
from typing import NamedTuple

import numpy as np

from . import kernel as compiled
from .dilation import Dilation
from .gains import FilteringGains, LuenbergerGains, PrescribedTimeGains
from .injection import InjectionFlow
from .linalg import PHI1_SERIES, ZOH_CACHE_SIZE, ExpmFamily, spectral_radius, zoh_blocks
from .validation import all_finite, as_finite_vector, check_step_size, floating_point_failure


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
DEFAULT_H = 5e-5
"""Default internal step h (s) of the observers: a communication step dt is run in
``ceil(dt / h)`` equal substeps (the paper's step; the observer FMUs' start value of h)."""

TAU_GRID = np.geomspace(1e-7, 3.0, 76)
"""Values of tau, in increasing order, scanned for each communication step size (gain cap and
ceiling)."""
CONTRACTION_LIMIT = 1.0 - 1e-9
"""A dilated error map counts as contractive below this spectral radius."""
HELD_INNOVATION_LIMIT = 1.0 - 1e-6
"""The Luenberger observer's split step holds the innovation when its error map
``expm(dt A) + Gamma_L C`` has a spectral radius below this, else y (the closed loop's hold): a
margin below 1 far beyond the radius's round-off, so that the numpy runtime and the native
planner choose alike."""
RADIUS_TIE = 1e-9
"""Spectral radii of the tau scan within this of the smallest count as the smallest: where the
radius does not depend on the level (a mode of the plant that the injection does not move) its
values differ by round-off only, and the scan takes the largest such tau (the least gain)."""
AMPLIFICATION_LIMIT = 3e5
"""Largest output-to-estimate amplification ``||C|| ||d(ln s)|| / s^(1+nu)`` of a gain level
(module docstring): y's round-off of 1e-16 then moves the estimate by about 3e-11 at most."""
SCALING_LIMIT = 1e8
"""Largest condition number of the dilation S at a gain level (:meth:`_Observer.error_map`) at
which the tau scan reads the spectral radius of the dilated error map: beyond it that radius
carries a rounding error of about ``cond(S) eps`` (1e-9 and more), as large as the distance
of the radii of the smallest taus from one, and the scan ignores it."""
CAP_CACHE_SIZE = 16
"""Gain caps are cached per communication step size; the cache is cleared at this many."""
SIZE_BINS_PER_OCTAVE = 8
"""The tau scan is made once per bin of step sizes (:func:`size_bin`): this many per octave."""
BIN_CACHE_SIZE = 64
"""Tau scans of this many bins are kept (the least recently used one is dropped)."""

MAX_SUBSTEPS = 1_000_000
"""A communication step longer than this many internal steps h is rejected (ValueError) rather
than run for minutes (euler) or through an overflowing exponential (split): a step size of hours
with h = DEFAULT_H is a mistake, not a request."""

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


def size_bin(dt: float) -> float:
    """The representative step size of dt's bin: with ``dt = f 2^e``, ``f`` in [1/2, 1), the
    octave ``[2^(e-1), 2^e)`` is cut into ``SIZE_BINS_PER_OCTAVE`` equal parts of f, and the
    representative is the upper end of dt's part. Exact arithmetic (frexp, a product by a
    power of two, a whole number, ldexp), so the native planner finds the same bins.

    Examples
    --------
    >>> size_bin(1e-4), size_bin(1.05e-4), size_bin(0.75)
    (0.0001068115234375, 0.0001068115234375, 0.8125)
    """
    fraction, exponent = math.frexp(dt)
    part = int((fraction - 0.5) * (2 * SIZE_BINS_PER_OCTAVE))
    return math.ldexp(0.5 + (part + 1) / (2 * SIZE_BINS_PER_OCTAVE), exponent)


class PlanCacheInfo(NamedTuple):
    """What the plans of the homogeneous observers' step sizes cost so far
    (:meth:`_Observer.plan_cache_info`)."""

    scans: int
    """Tau scans made: one per bin of step sizes (again after its scan was dropped), and one
    per step size whose own checks refused its bin's taus."""
    bins: int
    """Bins whose tau scan is kept now (at most ``max_bins``)."""
    max_bins: int
    """``BIN_CACHE_SIZE``."""


Gains = FilteringGains | PrescribedTimeGains | LuenbergerGains
"""The record an observer runs (its plant, and its gains)."""


class _Observer:
    """Common machinery: input checks, substepping, ZOH model, transactional state.

    Subclasses set ``_aux`` (their extra states), ``_L_inj`` (the gain of the held innovation in
    the prediction) and implement ``_correct``, ``_euler_rates`` and ``_level``; the
    homogeneous ones set ``_nu``. ``gains`` is the estimator's record, ``model`` the
    ``(A, B, C)`` the observer runs on: the plant's for the Luenberger observer,
    ``gains.model_matrices`` (possibly with a disturbance model) for the homogeneous ones.
    """

    _aux: np.ndarray
    _n_error_aux = 0
    """Number of leading aux entries that belong to the estimation error (psi)."""
    _nu: float

    def __init__(self, gains: Gains, h: float, scheme: str, z0: np.ndarray | None,
                 L_inj: np.ndarray, model: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        if scheme not in SCHEMES:
            raise ValueError(f"unknown scheme {scheme!r}; choose one of {SCHEMES}")
        self.gains = gains
        self.h = check_step_size(h)
        self.scheme = scheme
        self._n, self._k, self._m = gains.plant.n, gains.plant.k, gains.plant.m
        self._A, self._B, self._C = model
        n = self._A.shape[0]
        self._z = np.zeros(n) if z0 is None else as_finite_vector(z0, n, "z0")
        self._L_inj = L_inj
        self._zoh: dict[float, Prediction] = {}
        self.tau_max: float | None = None
        self._caps: dict[float, tuple[float | None, float, float, float]] = {}
        self._bins: OrderedDict[float, tuple[int | None, int] | None] = OrderedDict()
        self._scans = 0
        self._roundoff_level: float | None = None
        self._trusted_levels: tuple[float, float] | None = None
        self._stepper: compiled.Stepper | None = None

    # -- public interface -------------------------------------------------------------------
    @property
    def z(self) -> np.ndarray:
        """The observer's model state (copy): the plant's state estimate, then, with a
        disturbance model, the estimates of q and its derivatives."""
        return self._z.copy()

    @property
    def x_hat(self) -> np.ndarray:
        """Estimate of the plant's state (copy of the first n entries of z)."""
        return self._z[:self._n].copy()

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
        inputs once). A non-finite result, a step needing more than ``MAX_SUBSTEPS`` internal
        euler steps, or a step size without a contractive gain cap still raises ValueError,
        the state unchanged."""
        stepper = self._stepper
        if stepper is not None:  # the compiled step: OK or NONFINITE
            if stepper.run(dt, self._z, self._aux, y, u) != compiled.OK:
                raise self._diverged()
            self._z, self._aux = stepper.state
            return
        n_sub = self._substeps(dt)
        try:  # the schemes never write into their arguments: the state stays as it was
            if self.scheme == "split":
                z, aux = self._run_split(self._z, self._aux, y, u, dt)
            else:
                z, aux = self._run_euler(self._z, self._aux, y, u, dt / n_sub, n_sub)
        except ArithmeticError as err:
            raise floating_point_failure(self.scheme, err) from err
        if not (all_finite(z) and all_finite(aux)):
            raise self._diverged()
        self._z, self._aux = z, aux

    def _diverged(self) -> ValueError:
        """The error of a step whose result is not finite."""
        return ValueError(f"the {self.scheme} step diverged (non-finite state); "
                          "state left unchanged")

    @property
    def compiled(self) -> bool:
        """Whether the step runs in the compiled kernel (:mod:`fhobs.core.kernel`)."""
        return self._stepper is not None

    def kernel_handle(self, dt: float) -> compiled.StepperHandle:
        """The compiled step of size dt for a loop in C, from the current state ``[z, aux]``
        (:meth:`fhobs.core.kernel.Stepper.handle`; ValueError if the observer is not
        :attr:`compiled` or refuses dt). The observer keeps its state (detached from the
        buffers the loop writes): the loop's steps do not advance it."""
        if self._stepper is None:
            raise ValueError(f"the {self.scheme} step does not run in the compiled kernel")
        self._z, self._aux = self._z.copy(), self._aux.copy()
        return self._stepper.handle(dt, self._z, self._aux)

    def _use_kernel(self, split_function: str) -> None:
        """Make the step run in the kernel (the split step in ``split_function``, the euler
        substeps in ``fhobs_euler_step``) when the library is there (call at the end of a
        subclass's construction, ``_aux`` set)."""
        library = compiled.library()
        if library is not None:
            function = split_function if self.scheme == "split" else "fhobs_euler_step"
            self._stepper = compiled.Stepper(getattr(library, function),
                                             (self._z.size, self._aux.size),
                                             (self._k, self._m), self._first_kernel_step)

    def _first_kernel_step(self, dt: float) -> None:
        """At the first step of size dt: its checks, then the kernel's plan."""
        n_sub = self._substeps(dt)
        try:
            if self.scheme == "split":
                self._kernel_plan(dt)
            else:
                self._euler_kernel_plan(dt, n_sub)
        except ArithmeticError as err:
            raise floating_point_failure(self.scheme, err) from err

    def _kernel_plan(self, dt: float) -> None:
        """Register the kernel's plan of the split step for the communication step dt."""
        raise NotImplementedError

    def _euler_kernel_plan(self, dt: float, n_sub: int) -> None:
        """Register the kernel's plan of the euler scheme for dt (n_sub substeps)."""
        arrays = {name: np.ascontiguousarray(matrix, dtype=float) for name, matrix in
                  (("A", self._A), ("B", self._B), ("C", self._C), ("L_inj", self._L_inj))}
        work, cwork = compiled.euler_work_size(self._z.size, self._k)
        arrays["work"], arrays["cwork"] = np.zeros(work), np.zeros(cwork, dtype=complex)
        gain, values = self._euler_gain_data()
        arrays.update(gain)
        plan = compiled.EulerPlan(n=self._z.size, k=self._k, m=self._m, n_sub=n_sub,
                                  hs=dt / n_sub, **values,
                                  **{name: compiled.pointer(a) for name, a in arrays.items()})
        self._stepper.add_plan(dt, plan, *arrays.values())

    def _euler_gain_data(self) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """Arrays and numbers of the euler plan's gain term (:meth:`_euler_rates`): none for
        an observer without one."""
        return {}, {"homogeneous": 0}

    def _substeps(self, dt: float) -> int:
        """Number of internal steps of size <= h in dt (ValueError beyond ``MAX_SUBSTEPS``)."""
        n_sub = max(1, math.ceil(dt / self.h * (1.0 - 1e-12)))
        if n_sub > MAX_SUBSTEPS:
            raise ValueError(f"the step size {dt!r} is more than {MAX_SUBSTEPS} internal steps "
                             f"of h = {self.h!r}; state left unchanged")
        return n_sub

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

    def _run_split(self, z: np.ndarray, aux: np.ndarray, y: np.ndarray, u: np.ndarray, dt: float,
                   level: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One split step over dt: correction (exact, gain frozen at ``level``, by default the
        observer's own level capped for dt) then the ZOH ``prediction`` with v held:
        ``z+ = Phi (z + dz) + Gamma_B u + Gamma_inj (v + C dz) = M (z, u, v) + F dz``."""
        prediction = self._prediction(dt)
        v = self._C.dot(z) - y
        if level is None:
            aux, dz = self._correct_own_level(aux, v, dt)
        else:
            aux, dz = self._correct(aux, v, dt, level)
        z_new = prediction.M.dot(np.concatenate((z, u, v)))
        return (z_new, aux) if dz is None else (z_new + prediction.F.dot(dz), aux)

    def _run_euler(self, z: np.ndarray, aux: np.ndarray, y: np.ndarray, u: np.ndarray, hs: float,
                   n_sub: int) -> tuple[np.ndarray, np.ndarray]:
        """The paper's explicit Euler over n_sub substeps, y held."""
        for _ in range(n_sub):
            v = self._C @ z - y
            daux, dz_gain = self._euler_rates(aux, v, hs * n_sub)
            z = z + hs * (self._A @ z + self._B @ u + self._L_inj @ v + dz_gain)
            aux = aux + hs * daux
        return z, aux

    def _level(self, aux: np.ndarray, dt: float) -> float:
        """Gain level (sigma or |xi|, capped for the communication step dt) at which the split
        step freezes the gain."""
        return 1.0

    def _floor(self, dt: float) -> float:
        """Gain-level floor for the communication step dt: ``(tau_max / dt)^(1/nu)``, and at
        least the round-off floor (module docstring)."""
        return self._step_size_plan(dt)[2]

    def _ceiling(self, dt: float) -> float:
        """Gain-level ceiling for the communication step dt: ``(tau_min / dt)^(1/nu)`` when the
        dilated map does not contract for the smallest taus (module docstring), else inf."""
        return self._step_size_plan(dt)[3]

    def cap(self, dt: float) -> float:
        """``tau_max`` for the communication step dt: the fixed one given at construction, or
        the automatic choice of the module docstring (computed once per step size).

        Raises
        ------
        ValueError
            If no tau of ``TAU_GRID`` gives a contractive error map for this dt.
        """
        return self._step_size_plan(dt)[1]

    def _step_size_plan(self, dt: float) -> tuple[float | None, float, float, float]:
        """``(tau_min, tau_max, floor, ceiling)`` for the communication step dt (tau_min None:
        no ceiling), computed at the first step of that size and cached."""
        plan = self._caps.get(dt)
        if plan is None:
            if self._roundoff_level is None:
                self._roundoff_level = self._amplification_level()
                self._trusted_levels = self._scaling_band()
            if self.tau_max is not None:
                tau_min, tau_max = None, self.tau_max
                floor = max((tau_max / dt) ** (1.0 / self._nu), self._roundoff_level)
            else:
                tau_min, tau_max, floor = self._binned_taus(dt, self._roundoff_level)
            ceiling = math.inf if tau_min is None else max((tau_min / dt) ** (1.0 / self._nu),
                                                           floor)
            if len(self._caps) >= CAP_CACHE_SIZE:
                self._caps.clear()
            plan = self._caps[dt] = (tau_min, tau_max, floor, ceiling)
        return plan

    def _amplification_level(self) -> float:
        """The level s at which ``||C|| ||(d(ln s))_x|| / s^(1+nu)`` equals
        ``AMPLIFICATION_LIMIT`` (bisection in ln s; 0 if no level below 1 reaches it);
        ``(.)_x``: the rows of the plant's states (a disturbance model's states are not)."""
        dilation, c_norm = self._plain_dilation, np.linalg.norm(self._C, 2)
        n, nu = self._n, self._nu

        def amplification(log_s: float) -> float:
            return c_norm * np.linalg.norm(dilation.matrix(log_s)[:n], 2) / math.exp(
                (1.0 + nu) * log_s)

        lo, hi = -700.0, 0.0
        if amplification(lo) <= AMPLIFICATION_LIMIT:
            return 0.0
        while hi - lo > 1e-3:
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if amplification(mid) <= AMPLIFICATION_LIMIT else (mid, hi)
        return math.exp(hi)

    def _correct_own_level(self, aux: np.ndarray, v: np.ndarray,
                           dt: float) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`_correct` at the observer's own gain level."""
        return self._correct(aux, v, dt, self._level(aux, dt))

    def _correct(self, aux: np.ndarray, v: np.ndarray, dt: float,
                 level: float) -> tuple[np.ndarray, np.ndarray | None]:
        """Exact correction flow over dt: return (new aux, increment of z), the increment
        None for an observer without one."""
        return aux, None

    def _euler_rates(self, aux: np.ndarray, v: np.ndarray,
                     dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Paper's right-hand side beyond ``A z + B u + L_inj v``: (d aux/dt, gain term of dz);
        dt is the communication step (for a gain cap)."""
        return np.zeros_like(aux), np.zeros(self._z.size)

    @functools.cached_property
    def _plain_dilation(self) -> Dilation:
        """The dilation ``d(s) = expm(s G_d)`` of the homogeneous model (no right factor), for
        the dilated error maps and the round-off floor."""
        return Dilation(self.gains.model.G_d)

    def _error_scaling(self, level: float) -> np.ndarray:
        """The dilation ``S`` with error = S (dilated error) at a gain level (identity for an
        observer without levels)."""
        return np.eye(self._n_error_aux + self._z.size)

    def error_map(self, level: float, dt: float) -> np.ndarray:
        """Matrix of one split step of size dt acting on the *dilated* estimation error
        ``S^-1 (psi, z - x)`` (:meth:`_error_scaling`; ``z - x`` alone for the observers
        without a filter) at a frozen gain level (sigma or |xi|). It is the observer's step
        with x = 0, y = 0 and u = 0, which is linear in the error; for the gain cap, analysis
        and tests. In these coordinates its entries are of moderate size at every level, so
        its eigenvalues are computed accurately (those of the unscaled map are not)."""
        n_lin = self._n_error_aux
        S = self._error_scaling(level)
        columns = []
        for e in S.T:
            aux = np.zeros_like(self._aux)
            aux[:n_lin] = e[:n_lin]
            z, aux = self._run_split(e[n_lin:], aux, np.zeros(self._k), np.zeros(self._m), dt,
                                     level)
            columns.append(np.concatenate([aux[:n_lin], z]))
        return np.linalg.solve(S, np.column_stack(columns))

    def _dilated_radius(self, level: float, dt: float) -> float:
        """Spectral radius of :meth:`error_map` at ``level``; inf where the map cannot be
        formed (a dilation that over- or underflows at an extreme level is singular)."""
        try:
            with np.errstate(all="ignore"):
                radius = spectral_radius(self.error_map(level, dt))
        except (np.linalg.LinAlgError, ArithmeticError, ValueError):
            return math.inf
        return radius if math.isfinite(radius) else math.inf

    def _scaling_band(self) -> tuple[float, float]:
        """The gain levels ``(low, high)`` around 1 between which the dilation S of
        :meth:`error_map` has a condition number of at most ``SCALING_LIMIT`` (bisection in
        ln s to 1e-3, as :meth:`_amplification_level`): the levels whose dilated radii the tau
        scan reads (S is the identity at level 1, and its condition grows with |ln s|)."""
        def trusted(log_s: float) -> bool:
            with np.errstate(all="ignore"):
                try:
                    cond = float(np.linalg.cond(self._error_scaling(math.exp(log_s))))
                except np.linalg.LinAlgError:
                    return False
            return cond <= SCALING_LIMIT

        edges = []
        for outside in (-700.0, 700.0):
            inside = 0.0
            if trusted(outside):
                edges.append(math.exp(outside))
                continue
            while abs(outside - inside) > 1e-3:
                mid = 0.5 * (inside + outside)
                inside, outside = (mid, outside) if trusted(mid) else (inside, mid)
            edges.append(math.exp(inside))
        return edges[0], edges[1]

    def plan_cache_info(self) -> PlanCacheInfo:
        """The tau scans made so far and the bins of step sizes whose scan is kept.

        Examples
        --------
        Sizes of one bin share one scan:

        >>> from fhobs.design.observer import design_observer
        >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
        >>> obs = FilteringObserver(design.filtering)
        >>> for dt in (1.00e-3, 1.01e-3, 1.02e-3):
        ...     obs.step(y=[0.0], u=[0.0], dt=dt)
        >>> obs.plan_cache_info()
        PlanCacheInfo(scans=1, bins=1, max_bins=64)
        """
        return PlanCacheInfo(self._scans, len(self._bins), BIN_CACHE_SIZE)

    def _binned_taus(self, dt: float, roundoff: float) -> tuple[float | None, float, float]:
        """``(tau_min, tau_max, floor)`` for dt from the tau scan of dt's bin
        (:func:`size_bin`), checked at dt (docs/theory.md, "Variable communication steps"):
        the floor's level must contract at dt, else dt gets a scan of its own
        (:meth:`_auto_taus`); the ceiling is the level of the first tau from the bin's tau_min
        towards tau_max whose level is trusted (at or above the floor, within the scaling
        band) and contracts at dt, the floor when none does; no ceiling when the bin has
        none."""
        scan = self._bin_scan(size_bin(dt), roundoff)
        if scan is None:
            return self._auto_taus(dt, roundoff)
        first, best = scan
        inverse_nu = 1.0 / self._nu
        floor = max((float(TAU_GRID[best]) / dt) ** inverse_nu, roundoff)
        if not self._dilated_radius(floor, dt) < CONTRACTION_LIMIT:
            return self._auto_taus(dt, roundoff)
        if first is None:
            return None, float(TAU_GRID[best]), floor
        low, high = self._trusted_levels
        for index in range(first, best):
            level = (float(TAU_GRID[index]) / dt) ** inverse_nu
            if (level >= floor and low <= level <= high
                    and self._dilated_radius(level, dt) < CONTRACTION_LIMIT):
                return float(TAU_GRID[index]), float(TAU_GRID[best]), floor
        return float(TAU_GRID[best]), float(TAU_GRID[best]), floor

    def _bin_scan(self, representative: float,
                  roundoff: float) -> tuple[int | None, int] | None:
        """The indices ``(first, best)`` into ``TAU_GRID`` of the tau scan at the bin's
        representative step size (:meth:`_tau_scan`), None where no tau contracts there;
        kept for the ``BIN_CACHE_SIZE`` bins used last."""
        bins = self._bins
        if representative in bins:
            bins.move_to_end(representative)
            return bins[representative]
        try:
            scan = self._tau_scan(representative, roundoff)[:2]
        except ValueError:
            scan = None
        if len(bins) >= BIN_CACHE_SIZE:
            bins.popitem(last=False)
        bins[representative] = scan
        return scan

    def _auto_taus(self, dt: float, roundoff: float) -> tuple[float | None, float, float]:
        """``(tau_min, tau_max, floor)`` of dt's own tau scan (:meth:`_tau_scan`)."""
        first, best, floor = self._tau_scan(dt, roundoff)
        return (None if first is None else float(TAU_GRID[first])), float(TAU_GRID[best]), floor

    def _tau_scan(self, dt: float, roundoff: float) -> tuple[int | None, int, float]:
        """``(first, best, floor)`` on ``TAU_GRID`` (module docstring): ``TAU_GRID[best]``
        (tau_max) minimises the spectral radius of the dilated error map (the largest such
        tau, ``RADIUS_TIE``), the floor is its level or the round-off floor ``roundoff``,
        whichever is higher; ``TAU_GRID[first]`` (tau_min) is the smallest tau of the run of
        contractive taus from tau_max towards higher levels, None when that run reaches the
        grid's first tau. The run reads only the radii it can trust: those of the levels that
        the observer uses (at or above the floor) and whose dilation is conditioned within
        ``SCALING_LIMIT`` (:meth:`_scaling_band`); it passes the others (round-off, or not
        finite), so the ceiling is the highest level that contracts as far as double
        precision can tell. ValueError where no tau contracts."""
        self._scans += 1
        inverse_nu = 1.0 / self._nu
        levels = [(float(tau) / dt) ** inverse_nu for tau in TAU_GRID]
        radii = [self._dilated_radius(level, dt) for level in levels]
        smallest = min(radii)
        if not smallest < CONTRACTION_LIMIT:
            raise ValueError(f"no gain level makes the split step of size {dt!r} contractive "
                             f"(smallest spectral radius {smallest:.6g}); use a smaller "
                             "communication step")
        best = max(index for index, radius in enumerate(radii)
                   if radius <= smallest + RADIUS_TIE)
        floor = max(levels[best], roundoff)
        low, high = self._trusted_levels
        first = best
        for index in range(best - 1, -1, -1):
            if not (levels[index] >= floor and low <= levels[index] <= high
                    and math.isfinite(radii[index])):
                continue
            if not radii[index] < CONTRACTION_LIMIT:
                return first, best, floor
            first = index
        return None, best, floor


class FilteringObserver(_Observer):
    """Filtering homogeneous observer (Theorem 2; HOSM case nu = -1/(n_tilde+1) included).

    Parameters
    ----------
    filtering : FilteringGains
        The observer's record (a design's ``filtering``).
    h : float
        Maximal internal step.
    scheme : str
        One of ``SCHEMES``.
    z0, psi0 : array_like or None
        Initial model state (``filtering.model.n_model`` entries: x, then the disturbance
        model's) and filter state (zeros if None).
    xi0 : float
        Initial xi.
    tau_max : float or None
        Gain cap of the split scheme, ``dt sigma^nu <= tau_max`` (dt the communication step);
        None picks it automatically.
    kernel : bool
        Run the step (split, or the euler substeps) in the compiled kernel when it is
        available (:mod:`fhobs.core.kernel`; not with the expm fallbacks of the injection flow or
        of the dilation); False: numpy only.

    Examples
    --------
    >>> from fhobs.design.observer import design_observer
    >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> obs = FilteringObserver(design.filtering, h=1e-3, z0=[0.5, 0.0])
    >>> obs.step(y=[0.5], u=[0.0], dt=1e-2)
    >>> obs.x_hat.shape, bool(abs(obs.x_hat[0] - 0.5) < 1e-6)
    ((2,), True)
    """

    def __init__(self, filtering: FilteringGains, h: float = DEFAULT_H,
                 scheme: str = SCHEMES[0], z0: np.ndarray | None = None,
                 psi0: np.ndarray | None = None, xi0: float = 0.0,
                 tau_max: float | None = None, kernel: bool = True) -> None:
        model = filtering.model
        super().__init__(filtering, h, scheme, z0, model.L0, filtering.model_matrices)
        self._nu = nu = model.nu
        k = self._k
        psi = np.zeros(k) if psi0 is None else as_finite_vector(psi0, k, "psi0")
        self._aux = np.append(psi, as_finite_vector(xi0, 1, "xi0"))
        self._n_error_aux = k
        self._dilation = Dilation(model.G_d, right=filtering.L)
        self._flow = InjectionFlow(filtering.L_tilde, self._C, self._dilation, nu)
        self._p = nu / 2.0 + 1.0
        self.tau_max = None if tau_max is None else float(tau_max)
        if kernel and (self._flow.eigen if scheme == "split" else self._dilation.use_eig):
            self._use_kernel("fhobs_filter_step")

    def diagnostics(self) -> dict[str, float | np.ndarray]:
        """``z``, ``psi``, ``xi`` and ``sigma``."""
        psi, xi = self._aux[:-1], float(self._aux[-1])
        return {"z": self.z, "psi": psi.copy(), "xi": xi, "sigma": self._sigma(self._aux)}

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
        """sigma between the floor and the ceiling of dt (module docstring)."""
        return min(max(self._sigma(aux), self._floor(dt)), self._ceiling(dt))

    def _error_scaling(self, level: float) -> np.ndarray:
        """``diag(level I_k, d(ln level))``: the dilation of ``(psi, z - x)``."""
        k, n = self._k, self._z.size
        S = np.zeros((k + n, k + n))
        S[:k, :k] = level * np.eye(k)
        S[k:, k:] = self._plain_dilation.matrix(math.log(level))
        return S

    def _correct_own_level(self, aux: np.ndarray, v: np.ndarray,
                           dt: float) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`_consistent_correction`, then xi raised to at least the square of dt's floor:
        the floor is carried into the next step in the gain state (module docstring,
        variable communication steps)."""
        aux_new, dz = self._consistent_correction(aux, v, dt)
        floor = self._floor(dt)
        aux_new[-1] = max(float(aux_new[-1]), floor * floor)
        return aux_new, dz

    def _consistent_correction(self, aux: np.ndarray, v: np.ndarray,
                               dt: float) -> tuple[np.ndarray, np.ndarray | None]:
        """Correction at the level of :meth:`_level`, redone at a self-consistent level when it
        leaves sigma above ``LEVEL_MISMATCH`` times the frozen level (e.g. at an all-zero start,
        where sigma = 0 but psi grows at once): that level s solves ``sigma_after(s) = s``
        (bisection in ln s; sigma_after(s) / s decreases in s), so the frozen gain matches the
        psi it produces; it is at most the ceiling."""
        level, ceiling = self._level(aux, dt), self._ceiling(dt)
        result = self._correct(aux, v, dt, level)
        after = self._sigma(result[0])
        if after <= LEVEL_MISMATCH * level:
            return result
        log_ceiling = math.log(ceiling)
        lo, hi = math.log(level), min(math.log(after), log_ceiling)
        for _ in range(BISECTION_STEPS):
            result = self._correct(aux, v, dt, math.exp(hi))
            if self._sigma(result[0]) <= math.exp(hi):
                break
            if hi >= log_ceiling:
                return result
            lo, hi = hi, min(hi + 2.0, log_ceiling)
        while hi - lo > BISECTION_TOL:
            mid = 0.5 * (lo + hi)
            trial = self._correct(aux, v, dt, math.exp(mid))
            if self._sigma(trial[0]) <= math.exp(mid):
                hi, result = mid, trial
            else:
                lo = mid
        return result

    def _kernel_plan(self, dt: float) -> None:
        """The kernel's plan for dt: the ZOH prediction, the gain-level floor and ceiling and
        the injection flow's eigen data."""
        prediction = self._prediction(dt)
        floor, ceiling = self._floor(dt), self._ceiling(dt)
        data = self._flow.kernel_arrays()
        arrays = {"C": np.ascontiguousarray(self._C, dtype=float),
                  "M": np.ascontiguousarray(prediction.M), "F": np.ascontiguousarray(prediction.F),
                  **{name: data[name] for name in ("V_inv", "V_k", "WL", "V_g", "g", "lam")},
                  "factors": np.zeros(4 * self._k, dtype=complex),
                  "last_tau": np.array([math.nan])}
        work, cwork = compiled.filter_work_size(self._z.size, self._k)
        arrays["work"], arrays["cwork"] = np.zeros(work), np.zeros(cwork, dtype=complex)
        plan = compiled.FilterPlan(
            n=self._z.size, k=self._k, m=self._m, real_lam=int(data["real_lam"]), nu=self._nu,
            gamma=float(self.gains.gamma), p=self._p, dt=dt, floor_level=floor,
            ceiling=ceiling, mismatch=LEVEL_MISMATCH, tiny=data["tiny"], series=PHI1_SERIES,
            **{name: compiled.pointer(array) for name, array in arrays.items()})
        self._stepper.add_plan(dt, plan, *arrays.values())

    def _euler_gain_data(self) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """The dilation's eigen data, L_tilde and the xi equation's constants."""
        dilation = self._dilation
        arrays = {"L_tilde": np.ascontiguousarray(self.gains.L_tilde, dtype=float),
                  "V_d": np.ascontiguousarray(dilation.eigenvectors, dtype=complex),
                  "inverse_L": np.ascontiguousarray(dilation.inverse_right, dtype=complex),
                  "g": np.ascontiguousarray(dilation.eigenvalues, dtype=complex)}
        values = {"homogeneous": 1, "real_g": int(not np.iscomplexobj(dilation.eigenvalues)),
                  "nu": self._nu, "gamma": float(self.gains.gamma), "p": self._p,
                  "guard": SIGMA_GUARD}
        return arrays, values

    def _correct(self, aux: np.ndarray, v: np.ndarray, hs: float,
                 level: float) -> tuple[np.ndarray, np.ndarray | None]:
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

    def _euler_rates(self, aux: np.ndarray, v: np.ndarray,
                     dt: float) -> tuple[np.ndarray, np.ndarray]:
        g, nu = self.gains, self._nu
        psi, xi = aux[:-1], float(aux[-1])
        sigma = self._sigma(aux)
        if sigma > 0.0:
            log_s = math.log(max(sigma, SIGMA_GUARD))
            dz_gain = math.exp((nu - 1.0) * log_s) * self._dilation.apply(log_s, psi)
            dpsi = v + math.exp(nu * log_s) * (g.L_tilde @ psi)
        else:  # sigma = 0 forces psi = 0: the homogeneous terms vanish
            dz_gain, dpsi = np.zeros(self._z.size), v
        dxi = abs(psi @ dpsi) - g.gamma * signed_power(xi - 0.5 * psi @ psi, self._p)
        return np.append(dpsi, dxi), dz_gain


def prescribed_xi0(T0: float, nu: float, rho: float) -> float:
    """The initial xi for which the prescribed-time observer converges at ``T0``: the inverse
    of ``T0 = xi0^(-nu) / (-nu rho)``, i.e. ``xi0 = (-nu rho T0)^(-1/nu)`` (positive).

    Raises
    ------
    ValueError
        If T0, -nu or rho is not a positive finite number, or xi0 is outside the normal
        floats (T0 so small or so large that xi0 overflows or underflows).

    Examples
    --------
    >>> prescribed_xi0(1.0, -0.5, 2.0)  # (0.5 * 2 * 1)^2
    1.0
    >>> round(prescribed_xi0(0.5, -0.25, 4.0), 12)  # (0.25 * 4 * 0.5)^4
    0.0625
    """
    for name, value in (("T0", T0), ("-nu", -nu), ("rho", rho)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} = {float(value)!r} is not a positive finite number")
    try:
        xi0 = (-nu * rho * T0) ** (-1.0 / nu)
    except OverflowError:
        xi0 = math.inf
    if not (math.isfinite(xi0) and xi0 >= sys.float_info.min):
        raise ValueError(f"T0 = {float(T0)!r} s gives xi0 = (-nu rho T0)^(-1/nu) = {xi0!r}, "
                         "outside the normal floating-point numbers")
    return xi0


class PrescribedTimeObserver(_Observer):
    """Prescribed-time observer (Theorem 1), dilation generator ``G = G_d - nu I``.

    The gain ``|xi|^(nu-1) expm(ln|xi| G) L_pt = |xi|^-1 d(ln|xi|) L_pt`` is evaluated at
    ``max(|xi|, (tau_max/dt)^(1/nu))`` (see the module docstring for the behaviour after T0).

    Parameters
    ----------
    prescribed_time : PrescribedTimeGains
        The observer's record (a design's ``prescribed_time``).
    h, scheme, z0 :
        As for :class:`FilteringObserver`.
    xi0 : float
        Initial xi (nonzero); the prescribed time is ``T0 = |xi0|^(-nu) / (-nu rho)``.
    tau_max : float or None
        Gain cap ``dt |xi|^nu <= tau_max`` (dt the communication step); None: automatic.
    kernel : bool
        Run the split step in the compiled kernel when it is available
        (:mod:`fhobs.core.kernel`; not with the expm fallbacks of ``C L_pt``'s exponential or
        of the dilation); False: numpy only. The euler scheme always runs in numpy.

    Examples
    --------
    A double integrator moving at speed 0.5 from x = (1, 0.5), the observer started at zero:
    after the prescribed time T0 the estimate is the state.

    >>> from fhobs.design.observer import design_observer
    >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> obs = PrescribedTimeObserver(design.prescribed_time, h=1e-3, xi0=1.0)
    >>> obs.T0
    1.5
    >>> for k in range(200):
    ...     obs.step(y=[1.0 + 0.5 * k * 1e-2], u=[0.0], dt=1e-2)
    >>> bool(np.allclose(obs.x_hat, [2.0, 0.5], atol=1e-9))
    True
    """

    def __init__(self, prescribed_time: PrescribedTimeGains, h: float = DEFAULT_H,
                 scheme: str = SCHEMES[0], z0: np.ndarray | None = None, xi0: float = 1.0,
                 tau_max: float | None = None, kernel: bool = True) -> None:
        model = prescribed_time.model
        super().__init__(prescribed_time, h, scheme, z0, model.L0,
                         prescribed_time.model_matrices)
        self._nu = model.nu
        xi = as_finite_vector(xi0, 1, "xi0")
        self._aux = np.append(xi, abs(xi))  # xi, then the gain-level state
        self._dilation = Dilation(model.G_d, right=prescribed_time.L_pt)
        self._Q = ExpmFamily(self._C @ prescribed_time.L_pt)
        self.tau_max = None if tau_max is None else float(tau_max)
        if kernel and scheme == "split" and self.eigen:
            self._use_kernel("fhobs_prescribed_step")

    @property
    def eigen(self) -> bool:
        """Whether the correction runs on eigen data (``C L_pt``'s and the dilation's), which
        the compiled kernel needs; False where either falls back to expm."""
        return bool(self._Q.use_eig and self._dilation.use_eig)

    def kernel_arrays(self) -> dict[str, np.ndarray | float | int]:
        """The eigen data of the correction for the compiled kernel (:attr:`eigen` only),
        complex128 and C-contiguous: ``Q_inv``, ``Q_V``, ``lam`` (``C L_pt = Q_V diag(lam)
        Q_inv``), ``V_g``, ``g`` (``G_d = V_g diag(g) V_g^-1``), ``inverse_L`` (``V_g^-1
        L_pt``); ``real_lam`` (numpy's spectral factors are then real) and ``tiny`` (below
        this tau the factors use phi1's series where needed).

        Examples
        --------
        >>> from fhobs.design.observer import design_observer
        >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
        >>> data = PrescribedTimeObserver(design.prescribed_time).kernel_arrays()
        >>> data["Q_inv"].shape, data["V_g"].shape, data["inverse_L"].shape
        ((1, 1), (2, 2), (2, 1))
        """
        family, dilation = self._Q, self._dilation

        def complex_array(array: np.ndarray) -> np.ndarray:
            return np.ascontiguousarray(array, dtype=complex)

        return {"Q_inv": complex_array(family.eigenvectors_inverse),
                "Q_V": complex_array(family.eigenvectors),
                "lam": complex_array(family.eigenvalues),
                "V_g": complex_array(dilation.eigenvectors),
                "g": complex_array(dilation.eigenvalues),
                "inverse_L": complex_array(dilation.inverse_right),
                "real_lam": int(not np.iscomplexobj(family.eigenvalues)),
                "tiny": float(family.tiny)}

    def _kernel_plan(self, dt: float) -> None:
        """The kernel's plan for dt: the ZOH prediction, the gain-level floor and ceiling and
        the correction's eigen data."""
        prediction = self._prediction(dt)
        floor, ceiling = self._floor(dt), self._ceiling(dt)
        data = self.kernel_arrays()
        n, k = self._z.size, self._k
        arrays = {"C": np.ascontiguousarray(self._C, dtype=float),
                  "M": np.ascontiguousarray(prediction.M), "F": np.ascontiguousarray(prediction.F),
                  **{name: data[name] for name in ("Q_inv", "Q_V", "lam", "V_g", "g",
                                                   "inverse_L")},
                  "factors": np.zeros(2 * k, dtype=complex), "last_tau": np.array([math.nan]),
                  "work": np.zeros(compiled.prescribed_work_size(n, k))}
        plan = compiled.PrescribedPlan(
            n=n, k=k, m=self._m, real_lam=data["real_lam"], nu=self._nu,
            rho=float(self.gains.rho), dt=dt, floor_level=floor, ceiling=ceiling,
            tiny=data["tiny"], series=PHI1_SERIES,
            **{name: compiled.pointer(array) for name, array in arrays.items()})
        self._stepper.add_plan(dt, plan, *arrays.values())

    @property
    def T0(self) -> float:
        """Time (from the current state) at which xi reaches 0."""
        nu = self._nu
        return abs(float(self._aux[0])) ** (-nu) / (-nu * self.gains.rho)

    def diagnostics(self) -> dict[str, float | np.ndarray]:
        """``z``, ``xi``, the gain-level state and the gain level a step of size h uses."""
        return {"z": self.z, "xi": float(self._aux[0]), "level_state": float(self._aux[1]),
                "level": self._level(self._aux, self.h)}

    def _error_scaling(self, level: float) -> np.ndarray:
        """``d_pt(ln level) = level^-nu d(ln level)``: the dilation of ``z - x``."""
        return level ** -self._nu * self._plain_dilation.matrix(math.log(level))

    def _level(self, aux: np.ndarray, dt: float) -> float:
        """The gain-level state (|xi| until dt's floor acts) between the floor and the ceiling
        of dt (module docstring)."""
        return min(max(abs(float(aux[1])), self._floor(dt)), self._ceiling(dt))

    def _xi_exact(self, xi: float, hs: float) -> float:
        """Exact flow of ``dxi/dt = -rho |xi|^(1+nu) sign(xi)``: |xi|^-nu decreases linearly."""
        nu = self._nu
        if xi == 0.0:
            return 0.0
        return math.copysign(max(abs(xi) ** (-nu) + nu * self.gains.rho * hs, 0.0) ** (-1.0 / nu),
                             xi)

    def _correct(self, aux: np.ndarray, v: np.ndarray, hs: float,
                 level: float) -> tuple[np.ndarray, np.ndarray | None]:
        """Exact flow of ``dz = gain (C z - y)`` with x frozen: ``dv = xi^nu C L_pt v``."""
        nu = self._nu
        log_x = math.log(level)
        tau = hs * math.exp(nu * log_x)
        _, phi_v = self._Q.apply(tau, v * math.exp(-(1.0 + nu) * log_x))  # tau phi1(tau Q) v
        dz = self._dilation.apply(log_x, phi_v)
        return np.array([self._xi_exact(float(a), hs) for a in aux]), dz

    def _correct_own_level(self, aux: np.ndarray, v: np.ndarray,
                           dt: float) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`_correct` at :meth:`_level`, the gain-level state then raised to at least
        dt's floor: the floor carried into the next step (module docstring, variable
        communication steps)."""
        aux_new, dz = self._correct(aux, v, dt, self._level(aux, dt))
        aux_new[1] = max(float(aux_new[1]), self._floor(dt))
        return aux_new, dz

    def _euler_rates(self, aux: np.ndarray, v: np.ndarray,
                     dt: float) -> tuple[np.ndarray, np.ndarray]:
        log_x = math.log(self._level(aux, dt))
        dz_gain = math.exp(-log_x) * self._dilation.apply(log_x, v)
        rates = [-self.gains.rho * signed_power(float(a), 1.0 + self._nu) for a in aux]
        return np.array(rates), dz_gain


class LuenbergerObserver(_Observer):
    """Luenberger baseline ``dz/dt = A z + B u + L_lin (C z - y)``.

    The split scheme's step is ``z+ = M (z, y, u)`` (:meth:`step_map`), one of two exact
    holds, chosen per step size dt where the plan is made:

    - the held innovation, ``z+ = expm(dt A) z + Gamma_B u + Gamma_L (C z - y)``: the error
      obeys ``e+ = (expm(dt A) + Gamma_L C) e`` exactly, whatever the plant does, so it falls
      to round-off; used when that error map's spectral radius is below
      ``HELD_INNOVATION_LIMIT`` (:meth:`holds_innovation`), which coarse steps on stiff
      plants fail;
    - else the closed loop with y held, ``z+ = expm(dt A_cl) z + Gamma_y y + Gamma_u u`` with
      ``A_cl = A + L_lin C`` (:meth:`closed_loop_map`): stable at every dt when A_cl is
      Hurwitz (what the record's certificate checks), but the held y lags a moving output,
      an error of order dt times the output's rate.

    ``euler`` is explicit Euler, which needs h small against the closed loop's fastest mode.
    The parameters are those of :class:`FilteringObserver`, the record a
    :class:`~fhobs.core.gains.LuenbergerGains` (the gain is its ``L_lin``).

    Examples
    --------
    >>> from fhobs.design.observer import design_observer
    >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> obs = LuenbergerObserver(design.luenberger, h=1e-3)
    >>> obs.holds_innovation(1e-2)
    True
    >>> for _ in range(2000):
    ...     obs.step(y=[1.0], u=[0.0], dt=1e-2)
    >>> bool(np.allclose(obs.x_hat, [1.0, 0.0], atol=1e-6))
    True
    """

    def __init__(self, luenberger: LuenbergerGains, h: float = DEFAULT_H,
                 scheme: str = SCHEMES[0], z0: np.ndarray | None = None,
                 kernel: bool = True) -> None:
        super().__init__(luenberger, h, scheme, z0, luenberger.L_lin, luenberger.model_matrices)
        self._aux = np.zeros(0)
        self._A_cl = self._A + self._L_inj @ self._C
        self._maps: dict[float, np.ndarray] = {}
        if kernel:
            self._use_kernel("fhobs_luenberger_step")

    @property
    def zoh_top(self) -> np.ndarray:
        """The first rows ``[A_cl, -L_lin, B]`` of the augmented matrix whose exponential
        gives :meth:`closed_loop_map` (what the native planner exponentiates)."""
        return np.hstack((self._A_cl, -self._L_inj, self._B))

    def held_innovation_radius(self, dt: float) -> float:
        """Spectral radius of the held innovation's error map ``expm(dt A) + Gamma_L C`` (inf
        when the map overflows).

        Examples
        --------
        A scalar plant ``dx/dt = -x + u``, ``y = x``, gain ``L_lin = -4``: the map is
        ``5 exp(-dt) - 4``, of modulus below one for dt < ln(5/3) only.

        >>> from fhobs.core.gains import LuenbergerGains, PlantModel
        >>> one = np.ones((1, 1))
        >>> obs = LuenbergerObserver(LuenbergerGains(plant=PlantModel(A=-one, B=one, C=one),
        ...                                          L_lin=-4.0 * one))
        >>> [round(obs.held_innovation_radius(dt), 6) for dt in (0.1, 1.0)]
        [0.524187, 2.160603]
        """
        with np.errstate(all="ignore"):  # an overflowing map is not chosen, not an error
            F = self._prediction(dt).F
        return spectral_radius(F) if np.isfinite(F).all() else math.inf

    def holds_innovation(self, dt: float) -> bool:
        """Whether the step of size dt holds the innovation (its error map's spectral radius
        below ``HELD_INNOVATION_LIMIT``) rather than y."""
        return self.held_innovation_radius(dt) < HELD_INNOVATION_LIMIT

    def held_innovation_map(self, dt: float) -> np.ndarray:
        """``[expm(dt A) + Gamma_L C, -Gamma_L, Gamma_B]``: the held innovation's step
        ``expm(dt A) z + Gamma_B u + Gamma_L (C z - y)`` as ``M (z, y, u)``."""
        prediction = self._prediction(dt)
        n = self._z.size
        return np.hstack((prediction.F, -prediction.Gamma_inj, prediction.M[:, n:n + self._m]))

    def closed_loop_map(self, dt: float) -> np.ndarray:
        """``[expm(dt A_cl), Gamma_y, Gamma_u]``, the closed loop's hold with y and u held:
        the first rows of ``expm(dt [[A_cl, -L_lin, B], [0, 0, 0]])``
        (:func:`fhobs.core.linalg.zoh_blocks`).

        Examples
        --------
        A scalar plant ``dx/dt = -x + u``, ``y = x``, gain ``L_lin = -1``: ``A_cl = -2``, and
        with y = u = 1 held the estimate tends to the equilibrium ``(y + u) / 2 = 1``.

        >>> from fhobs.core.gains import LuenbergerGains, PlantModel
        >>> one = np.ones((1, 1))
        >>> plant = PlantModel(A=-one, B=one, C=one)
        >>> obs = LuenbergerObserver(LuenbergerGains(plant=plant, L_lin=-one))
        >>> M = obs.closed_loop_map(0.5)
        >>> bool(np.allclose(M, [[np.exp(-1.0), (1 - np.exp(-1.0)) / 2,
        ...                       (1 - np.exp(-1.0)) / 2]]))
        True
        """
        return np.hstack(zoh_blocks(self._A_cl, [-self._L_inj, self._B], dt))

    def step_map(self, dt: float) -> np.ndarray:
        """``M`` of the split step ``z+ = M (z, y, u)`` of size dt: :meth:`held_innovation_map`
        where :meth:`holds_innovation`, else :meth:`closed_loop_map`; cached per step size.

        Examples
        --------
        The scalar plant of :meth:`held_innovation_radius`:

        >>> from fhobs.core.gains import LuenbergerGains, PlantModel
        >>> one = np.ones((1, 1))
        >>> obs = LuenbergerObserver(LuenbergerGains(plant=PlantModel(A=-one, B=one, C=one),
        ...                                          L_lin=-4.0 * one))
        >>> bool(np.array_equal(obs.step_map(0.1), obs.held_innovation_map(0.1)))
        True
        >>> bool(np.array_equal(obs.step_map(1.0), obs.closed_loop_map(1.0)))
        True
        """
        M = self._maps.get(dt)
        if M is None:
            if len(self._maps) >= ZOH_CACHE_SIZE:  # variable steps: keep the cache bounded
                self._maps.clear()
            M = self._maps[dt] = (self.held_innovation_map(dt) if self.holds_innovation(dt)
                                  else self.closed_loop_map(dt))
        return M

    def _run_split(self, z: np.ndarray, aux: np.ndarray, y: np.ndarray, u: np.ndarray, dt: float,
                   level: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One exact hold over dt (no gain level): ``z+ = M (z, y, u)``."""
        return self.step_map(dt).dot(np.concatenate((z, y, u))), aux

    def _kernel_plan(self, dt: float) -> None:
        """The kernel's plan for dt: ``z+ = M (z, y, u)``."""
        M = self.step_map(dt)
        plan = compiled.LinearPlan(n=self._z.size, k=self._k, m=self._m, cycles=1,
                                   M=compiled.pointer(M))
        self._stepper.add_plan(dt, plan, M)
