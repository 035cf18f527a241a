"""Observer design: from a plant spec to certified gains (Theorems 1 and 2 of the paper).

:func:`design_observer` takes the plant as arrays (or a python-control ``StateSpace``) and the
tuning as keywords, in the manner of python-control's design functions, validates them
(:func:`fhobs.design.spec.plant_spec`) and returns the certified design; :func:`design_for_spec`
does the same for a validated :class:`~fhobs.design.spec.PlantSpec` (a spec file's,
:func:`fhobs.design.spec.load_spec`).
The steps:

1. homogenisation (:mod:`fhobs.design.homogenisation`): n_tilde, G0, L0, G_d;
2. Theorem 2's LMI for the filtering observer: (L_tilde; L) and P_bar;
3. Theorem 1's LMI for the prescribed-time observer: L_pt and P_pt;
4. the Luenberger baseline L_lin (given in the spec, or an LMI with decay equal to the
   filtering observer's slowest linear mode, so both observers are compared at equal speed);
5. the numpy certificate (:mod:`fhobs.core.certificate`), which must pass.

Fast output filter (``[observer] filter_scale = c``, default 1). After step 2, L_tilde is
multiplied by c (L unchanged) and P_bar is found again for the fixed gain by
:func:`fhobs.design.lmi.certify_gain_lmi` (convex in P_bar), at the largest rho in (gamma/2, rho]
that certifies it (bisection); that rho is the design's (``filtering.rho``, used by the
certificate and the prescribed-time observer). The LMI's rho is then a speed knob; the certified
rho is roughly 0.85 rho / c. Why: in the chain basis the filtering observer is, per output, a
third-order chain (psi, position, velocity) whose only self-feedback is L_tilde; a fast psi pole
(one pole near -c L_tilde, the two others slower) changes the level sigma that the xi equation
settles at under measurement noise, and with it the noise-to-velocity-error balance: with the
pendulum's noise the velocity errors drop by about 30 % at equal perturbed accuracy. Imposing the
filter gain inside the LMI instead is not convex in (P, Y) (L_tilde = (P^-1 Y)_psi), and the
convex restriction that makes it linear (P block-diagonal between psi and z in the chain basis)
is infeasible: the z block of the LMI then has no injection.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import scipy.linalg

from ..core.certificate import certify, certify_parts
from ..core.disturbance import extended_model, model_perturbation_matrix
from ..core.gains import (
    FilteringGains,
    HomogeneousModel,
    LuenbergerGains,
    ObserverDesign,
    PlantModel,
    PrescribedTimeGains,
)
from ..core.linalg import diagonal_congruence, diagonal_similarity
from ..errors import CertificateError, LMIError, SpecError
from ..paper import PAPER_REFERENCE
from .cache import cached
from .feedback import state_feedback
from .homogenisation import Homogenisation, dilation_basis, homogenise
from .kalman import with_kalman
from .limits import check_design_limits
from .lmi import (
    LMI_MARGIN,
    certify_gain_lmi,
    chain_basis,
    solve_gain_lmi,
)
from .partial import (
    LMI_SLACK,
    completed_lyapunov,
    embedded_generator,
    fast_mode_cut,
    split_modes,
)
from .settling import ErrorResponse, communication_step_bracket, error_response
from .spec import (
    DEFAULT_OBJECTIVE,
    DEFAULT_SETTLING_TIME,
    PlantSpec,
    plant_spec,
    spec_from_dict,
)
from .supervised import with_supervised

RHO_START = 1.5
RHO_GROWTH = 2.0**0.5
RHO_MAX = 1e4
"""The automatic choice of rho climbs ``rho_0 * RHO_GROWTH**j`` up to ``RHO_MAX``, from
``rho_0 = RHO_START * DEFAULT_SETTLING_TIME / settling_time`` (a slower request starts lower:
the homogeneous observer's time scale is about 1 / rho)."""
CLIMB_PATIENCE = 4
"""Once a rung has certified, the climb stops after this many rungs in a row that fail or are
no faster than the best one."""
MAX_PEAKING = 1e3
"""Largest predicted ``|e(t)| / |e(0)|`` that the automatic choice of rho accepts."""
MARGIN_ATTEMPTS = 4
MARGIN_GROWTH = 2.0
"""A design failing an LMI check by its rounding allowance is solved again with the margin the
check needed times this factor, up to MARGIN_ATTEMPTS solves."""
RHO_BISECTION_TOL = 2e-2
"""Relative tolerance of the certified rho found for a design with filter_scale != 1."""


def matched_perturbation_residual(G_d: np.ndarray, E: np.ndarray, n_tilde: int) -> float:
    """Relative residual of Corollary 1's condition (n_tilde + 1) G_d E = E.

    Parameters
    ----------
    G_d : numpy.ndarray
        Dilation generator (Theorem 2's form).
    E : numpy.ndarray
        Perturbation input matrix.
    n_tilde : int
        Observability index.

    Returns
    -------
    float
        ||(n_tilde + 1) G_d E - E|| / ||E||; about 0 when the HOSM observer rejects E q.
    """
    return float(np.linalg.norm((n_tilde + 1) * G_d @ E - E) / max(np.linalg.norm(E), 1e-300))


def augmented_system(
    A0: np.ndarray, C_model: np.ndarray, G_d: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (psi, z) system of Theorem 2 that the design solves for: bar_A0 = [[0, C], [0, A0]],
    bar_G = diag(I_k, G_d), bar_C = [I_k, 0] (the certificate builds its own,
    :func:`fhobs.core.certificate.augmented_matrices`)."""
    k, n = C_model.shape
    bar_A0 = np.block([[np.zeros((k, k)), C_model], [np.zeros((n, k)), A0]])
    bar_G = scipy.linalg.block_diag(np.eye(k), G_d)
    bar_C = np.hstack([np.eye(k), np.zeros((k, n))])
    return bar_A0, bar_G, bar_C


def _chain_levels(
    A: np.ndarray, C: np.ndarray, nu: float, hom: Homogenisation
) -> tuple[np.ndarray, list[np.ndarray]]:
    """A0 = A + L0 C and the eigenspaces of G_d by weight (the input of :func:`chain_basis`)."""
    V = dilation_basis(hom.G_d, nu, hom.n_tilde)
    weights = np.linalg.solve(V, hom.G_d @ V).diagonal()
    levels = [V[:, np.abs(weights - 1 - (j + 1) * nu) < 1e-6] for j in range(hom.n_tilde)]
    return A + hom.L0 @ C, levels


def _luenberger_gain(
    spec: PlantSpec, decay: float, objective: str, margin: float
) -> tuple[np.ndarray, str | None]:
    """The spec's L_lin (status None), or the plant's Luenberger LMI at ``decay`` (in the chain
    basis of the plant's balanced coordinates, mapped back) and the solver's status."""
    if spec.L_lin is not None:
        return spec.L_lin, None
    n = spec.A.shape[0]
    d = _balancing(spec.A)
    A_b, C_b = diagonal_similarity(spec.A, d), spec.C * d[None, :]
    A0, levels = _chain_levels(A_b, C_b, spec.nu, homogenise(A_b, C_b, spec.nu))
    basis = chain_basis(A0, levels)
    solution = solve_gain_lmi(A_b, np.eye(n), C_b, decay, basis, objective, margin)
    return solution.gain * d[:, None], solution.status


def _balancing(A: np.ndarray) -> np.ndarray:
    """Powers of two d balancing A (``scipy.linalg.matrix_balance`` without permutations)."""
    return scipy.linalg.matrix_balance(A, permute=False, separate=True)[1][0]


def design_observer(
    A: Any,
    B: Any = None,
    C: Any = None,
    *,
    E: Any = None,
    L_lin: Any = None,
    disturbance_order: int = 0,
    nu: float | None = None,
    rho: float | None = None,
    gamma: float | None = None,
    settling_time: float = DEFAULT_SETTLING_TIME,
    state_scale: Any = 1.0,
    filter_scale: float = 1.0,
    objective: str = DEFAULT_OBJECTIVE,
    margin: float = LMI_MARGIN,
    fast_mode_rate: float | None = None,
) -> ObserverDesign:
    """Design and certify the filtering homogeneous observer of ``dx/dt = A x + B u + E q``,
    ``y = C x``.

    Parameters
    ----------
    A, B, C : array_like
        Plant matrices (n x n, n x m, k x n). ``A`` may instead be a continuous-time
        python-control ``StateSpace`` (then B and C are not given, and its D must be zero).
    E : array_like, optional
        Perturbation input matrix (n x r).
    L_lin : array_like, optional
        The Luenberger baseline's gain (n x k); default: designed by LMI at the filtering
        observer's slowest linear decay.
    disturbance_order : int
        Model q as a polynomial of degree ``disturbance_order - 1`` (0..3; > 0 needs E) and
        estimate it (:mod:`fhobs.core.disturbance`).
    nu : float, optional
        Homogeneity degree in [-1/(n_tilde+1), 0); default -1/(n_tilde+1).
    rho, gamma : float, optional
        LMI decay parameter and xi-equation gain (0 < gamma < 2 rho); default: the smallest
        rho of the automatic climb (``RHO_START * RHO_GROWTH**j``) that meets
        ``settling_time``, gamma = rho.
    settling_time : float
        Seconds for an initial error of the size of ``state_scale`` to fall to 1e-3 of itself
        (used when rho is not given).
    state_scale : float or array_like
        Typical size of each state (one number for all, or n).
    filter_scale : float
        >= 1: L_tilde is multiplied by it after the LMI (module docstring).
    objective : {"min_cond", "min_gain"}
        LMI objective (:data:`fhobs.design.spec.OBJECTIVES`).
    margin : float
        Margin imposed on the strict LMI inequalities.
    fast_mode_rate : float, optional
        Stable modes decaying faster than this (1/s; and than ``2 rho (1 + nu)``) are kept by
        the model, the rest homogenised (:mod:`fhobs.design.partial`); default
        ``50 / settling_time``; ``math.inf`` homogenises every mode, as in the paper.

    Returns
    -------
    ObserverDesign
        The records of the three observers (gains, Lyapunov matrices and each one's
        ``certificate`` holding its checked figures).

    Raises
    ------
    fhobs.errors.SpecError
        If an argument is invalid (the message names it).
    fhobs.errors.LMIError, fhobs.errors.CertificateError
        As :func:`design_for_spec`.

    Examples
    --------
    A double integrator measured in position:

    >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> design.plant.n, design.plant.k, design.model.n_tilde, design.filtering.rho
    (2, 1, 2, 2.0)
    >>> bool(design.luenberger.certificate["checks"]["hurwitz_luenberger"] < 0)
    True
    """
    if B is None and C is None and not isinstance(A, np.ndarray | list | tuple):
        A, B, C = _state_space_matrices(A)
    elif B is None or C is None:
        raise SpecError("design_observer: give A, B and C, or a python-control StateSpace alone")
    spec = plant_spec(
        A, B, C, E=E, L_lin=L_lin, disturbance_order=disturbance_order, nu=nu, rho=rho,
        gamma=gamma, settling_time=settling_time, state_scale=state_scale,
        filter_scale=filter_scale, objective=objective, fast_mode_rate=fast_mode_rate,
    )
    return design_for_spec(spec, margin=margin)


def _state_space_matrices(system: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A, B, C of a continuous-time python-control ``StateSpace`` whose D is zero."""
    if not all(hasattr(system, name) for name in ("A", "B", "C", "D")):
        raise SpecError(
            f"design_observer: A must be a matrix or a StateSpace, got {type(system).__name__}"
        )
    if getattr(system, "dt", 0) not in (0, None):
        raise SpecError(f"design_observer: the system is discrete-time (dt = {system.dt}); "
                        "the observer needs a continuous-time plant")
    D = np.asarray(system.D, dtype=float)
    if D.size and np.any(D != 0.0):
        raise SpecError("design_observer: the system's D must be zero (the observer's plant "
                        "has no direct feedthrough from u to y)")
    return np.asarray(system.A), np.asarray(system.B), np.asarray(system.C)


def design_for_spec(
    spec: PlantSpec,
    objective: str | None = None,
    margin: float = LMI_MARGIN,
    filter_scale: float | None = None,
) -> ObserverDesign:
    """Everything a validated plant spec asks for: the certified filtering homogeneous
    observer (with its prescribed-time and Luenberger companions) and, with a ``[noise]``
    table, the Kalman filter baseline; what ``build_fmu.py`` and ``harness plant`` build.

    A design of equal inputs made before with the same code and libraries is read from the
    user's cache (:mod:`fhobs.design.cache`) and certified again; ``FHOBS_NO_DESIGN_CACHE=1``
    designs afresh.

    Parameters
    ----------
    spec : PlantSpec
        Validated plant and tuning (:func:`fhobs.design.spec.load_spec`,
        :func:`fhobs.design.spec.plant_spec`).
    objective : str, optional
        LMI objective (see :mod:`fhobs.design.lmi`); defaults to the spec's.
    margin : float
        Margin imposed on the strict LMI inequalities.
    filter_scale : float, optional
        Factor applied to L_tilde after the LMI (module docstring); defaults to the spec's.

    Returns
    -------
    ObserverDesign
        Each estimator's record with its ``certificate`` holding its checked figures,
        ``kalman`` the Kalman filter of the spec's ``[noise]`` table and ``supervised`` its
        supervised observer (:func:`fhobs.design.supervised.with_supervised`; both None
        without the table).

    Raises
    ------
    fhobs.errors.SpecError
        If the spec is beyond the design's limits (:func:`fhobs.design.limits.check_design_limits`),
        before any design work.
    fhobs.errors.LMIError
        If an LMI solve fails, or a linear-algebra step of the design does (numpy's
        LinAlgError is not passed on).
    fhobs.errors.CertificateError
        If the solver's result does not pass the numpy certificate, also after solving the
        LMIs again with the margin the failed checks asked for (``MARGIN_ATTEMPTS`` solves in
        all: the certificate allows for the rounding error of its own figures, which grows
        with cond(P) and the gains, so a margin that is too thin for a plant with large
        entries is widened rather than reported as a failure).
    fhobs.errors.KalmanDesignError
        If the ``[noise]`` table's Kalman filter, or that of the homogeneous model for the
        supervised observer, cannot be designed (:func:`fhobs.design.kalman.with_kalman`,
        :func:`fhobs.design.supervised.with_supervised`).

    Examples
    --------
    >>> from fhobs.design.spec import spec_from_dict
    >>> spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]],
    ...                        "observer": {"rho": 2.0, "gamma": 3.0}})
    >>> design = design_for_spec(spec)
    >>> design.filtering.gamma, design.kalman is None
    (3.0, True)
    """
    check_design_limits(spec)
    design, _ = cached("design", (replace(spec, source=""), objective, margin, filter_scale),
                       lambda: _designed(spec, objective, margin, filter_scale),
                       _certified_design)
    return design


def _designed(spec: PlantSpec, objective: str | None, margin: float,
              filter_scale: float | None) -> ObserverDesign:
    """:func:`design_for_spec` computed (no cache)."""
    design = with_communication_step(_observer_for_spec(spec, objective, margin, filter_scale),
                                     spec)
    if spec.noise is None:
        return design
    return with_supervised(with_kalman(design, spec.noise), spec.noise)


def with_communication_step(design: ObserverDesign, spec: PlantSpec) -> ObserverDesign:
    """``design`` with its filtering record's ``max_communication_step``: the longest
    communication step over which the observer tolerates its inputs held
    (:func:`fhobs.design.settling.communication_step_bracket`), in the closed loop of the LQR
    feedback on the estimate (:func:`fhobs.design.feedback.state_feedback`), from errors of
    the size of ``spec.state_scale``, against the settling time at the fine step of
    ``spec.settling_time``. A plant whose LQR gain cannot be computed (scipy's Riccati solver
    fails, as on long chains of integrators) keeps the figure 0: no figure, no warning.

    Examples
    --------
    >>> from fhobs.design.spec import spec_from_dict
    >>> spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]],
    ...                        "observer": {"rho": 2.0, "gamma": 3.0}})
    >>> design = with_communication_step(design_for_spec(spec), spec)
    >>> bool(design.filtering.max_communication_step > spec.settling_time / 500)
    True
    """
    scale = np.ones(spec.A.shape[0]) if spec.state_scale is None else spec.state_scale
    try:
        K = state_feedback(design.plant.A, design.plant.B)
    except (np.linalg.LinAlgError, ValueError):
        return design
    held, _ = communication_step_bracket(design.filtering, scale, spec.settling_time, K)
    return replace(design, filtering=replace(design.filtering, max_communication_step=held))


def _certified_design(design: ObserverDesign) -> None:
    """Raise CertificateError unless ``design`` is a design whose every record certifies."""
    if not isinstance(design, ObserverDesign):
        raise CertificateError(f"not an observer design: {type(design).__name__}")
    certify(design)


def _observer_for_spec(spec: PlantSpec, objective: str | None, margin: float,
                       filter_scale: float | None) -> ObserverDesign:
    """The certified observer design of ``spec`` (no Kalman filter): at the spec's rho, or by
    the settling-time search when it names none (see :func:`design_for_spec`)."""
    objective = objective or spec.objective
    if spec.rho is None:
        return _design_for_settling_time(spec, objective, margin, filter_scale)
    if spec.gamma is None:
        spec = replace(spec, gamma=spec.rho)
    for attempt in range(MARGIN_ATTEMPTS):
        try:
            return _design_at_margin(spec, objective, margin, filter_scale)
        except CertificateError as err:
            if not err.lmi_margin_needed or attempt + 1 == MARGIN_ATTEMPTS:
                raise
            margin = max(MARGIN_GROWTH * err.lmi_margin_needed, MARGIN_GROWTH * margin)
        except np.linalg.LinAlgError as err:
            raise LMIError(f"numerical failure in the design at rho = {spec.rho:g} (a singular "
                           f"or non-converging linear-algebra step): {err}") from err
    raise AssertionError("unreachable")


def _design_for_settling_time(
    spec: PlantSpec, objective: str, margin: float, filter_scale: float | None
) -> ObserverDesign:
    """The design at the smallest rho of the climb (:data:`RHO_START`) whose predicted
    settling time (:func:`fhobs.design.settling.error_response` from errors of the size of
    ``spec.state_scale``) meets ``spec.settling_time`` with a peaking of at most
    ``MAX_PEAKING``; gamma is the spec's, or rho. A rho that does not certify is passed over,
    not an end: the climb goes on up to ``RHO_MAX``, and stops early only after
    ``CLIMB_PATIENCE`` rungs in a row, once one has certified, that fail or make no progress
    (:func:`_progress`). If no rung meets the request, :func:`_fallback` chooses; the design's
    ``settling_tuning`` says whether the request was met."""
    scale = np.ones(spec.A.shape[0]) if spec.state_scale is None else spec.state_scale

    def rung(rho: float) -> _Rung:
        gamma = rho if spec.gamma is None else spec.gamma
        design = _observer_for_spec(replace(spec, rho=rho, gamma=gamma), objective, margin,
                                    filter_scale)
        return _Rung(rho, design, error_response(design.filtering, scale, spec.settling_time))

    candidates: list[_Rung] = []
    failures: list[tuple[float, Exception]] = []
    stalled = 0  # consecutive rungs, once one has certified, that failed or made no progress
    for rho in _rho_climb(spec):
        try:
            candidate = rung(rho)
        except (LMIError, CertificateError) as exc:
            failures.append((rho, exc))
            stalled += bool(candidates)
            if stalled >= CLIMB_PATIENCE:
                break
            continue
        best = min((_progress(c.response) for c in candidates), default=(np.inf, np.inf))
        stalled = stalled + 1 if candidates and not _progress(candidate.response) < best else 0
        candidates.append(candidate)
        if _met(candidate.response, spec.settling_time) or stalled >= CLIMB_PATIENCE:
            break
    if not candidates:
        raise LMIError(_no_design_message(spec, failures))
    chosen = _fallback(candidates, spec.settling_time)
    design, response = chosen.design, chosen.response
    tuning = {
        "settling_time_requested": spec.settling_time,
        "settling_time_predicted": response.settling_time,
        "peaking": response.peaking,
        "peaking_limit": MAX_PEAKING,
        "met": bool(response.settling_time <= spec.settling_time
                    and response.peaking <= MAX_PEAKING),
    }
    return replace(design, settling_tuning=tuning)


class _Rung(NamedTuple):
    """A rho of the automatic choice, its design and the design's predicted error response."""

    rho: float
    design: ObserverDesign
    response: ErrorResponse


def _met(response: ErrorResponse, settling_time: float) -> bool:
    """Whether a predicted response meets the request within the peaking limit."""
    return response.peaking <= MAX_PEAKING and response.settling_time <= settling_time


def _fallback(candidates: list[_Rung], settling_time: float) -> _Rung:
    """The climb's choice: its last rung if that meets the request; else the fastest rung
    within the peaking limit; else, of those meeting the settling time, the one that peaks
    least; else the fastest."""
    if _met(candidates[-1].response, settling_time):
        return candidates[-1]
    bounded = [c for c in candidates if c.response.peaking <= MAX_PEAKING
               and np.isfinite(c.response.settling_time)]
    if bounded:
        return min(bounded, key=lambda c: (c.response.settling_time, c.response.peaking))
    in_time = [c for c in candidates if c.response.settling_time <= settling_time]
    if in_time:
        return min(in_time, key=lambda c: c.response.peaking)
    return min(candidates, key=lambda c: (c.response.settling_time, c.response.peaking))


def _progress(response: ErrorResponse) -> tuple[float, float]:
    """How far a rung of the climb got: its settling time, then (for errors that have not
    settled within the prediction's horizon) the error left at its end, to 10 %."""
    final = 0.0 if response.final <= 0.0 else float(np.round(np.log(response.final) / 0.1))
    return response.settling_time, final


def _rho_climb(spec: PlantSpec) -> list[float]:
    """The rho values the automatic choice tries, in order (those above gamma / 2 when the
    spec fixes gamma)."""
    start = RHO_START * DEFAULT_SETTLING_TIME / spec.settling_time
    count = int(np.floor(np.log(RHO_MAX / start) / np.log(RHO_GROWTH))) + 1
    rhos = [float(start * RHO_GROWTH**j) for j in range(count)]
    return [rho for rho in rhos if spec.gamma is None or rho > spec.gamma / 2]


def _no_design_message(spec: PlantSpec, failures: list[tuple[float, Exception]]) -> str:
    """The failure of the automatic choice of rho, in the user's terms."""
    if not failures:
        return (f"no rho to try for a settling time of {spec.settling_time:g} s: the climb "
                f"starts at rho = {RHO_START * DEFAULT_SETTLING_TIME:g} / settling_time and "
                f"ends at {RHO_MAX:g}" + (f", above gamma / 2 = {spec.gamma / 2:g}"
                                           if spec.gamma is not None else "")
                + f". What to change: a settling_time of at least "
                f"{RHO_START * DEFAULT_SETTLING_TIME / RHO_MAX:g} s (or rescale time), or rho "
                f"and gamma given by hand")
    tried = f"rho from {failures[0][0]:.3g} to {failures[-1][0]:.3g} ({len(failures)} values)"
    reasons = sorted({type(exc).__name__ + ": " + str(exc) for _, exc in failures[-2:]})
    return (f"no certified design for a settling time of {spec.settling_time:g} s: tried "
            f"{tried}, none certified (last: {'; '.join(reasons)}). What to change: a longer "
            f"[observer] settling_time, state_scale nearer the states' sizes, a lower "
            f"fast_mode_rate (keep more fast stable modes by the model), or rho and gamma "
            f"given by hand")


def _design_at_margin(
    spec: PlantSpec, objective: str, margin: float, filter_scale: float | None
) -> ObserverDesign:
    """One design: homogenisation, the three LMIs at ``margin``, the certificate.

    The homogeneous observers are designed in balanced coordinates ``x = D x_b`` (D diagonal,
    powers of two, from ``scipy.linalg.matrix_balance`` of the observer's model: exact in
    floating point) and mapped back; for a plant whose entries span many decades this keeps
    the eigenvectors of G_d and the LMI well conditioned. Fast stable modes are kept by the
    model and the rest homogenised (:mod:`fhobs.design.partial`) when the spec's
    ``fast_mode_rate`` finds some.
    """
    A_model, _, C_model = extended_model(spec.A, spec.B, spec.C, spec.E, spec.disturbance_order)
    d = _balancing(A_model)
    A_b, C_b = diagonal_similarity(A_model, d), C_model * d[None, :]
    n, k = A_model.shape[0], spec.C.shape[0]
    split = split_modes(A_b, fast_mode_cut(spec.fast_mode_rate, spec.settling_time, spec.rho,
                                           spec.nu))
    basis, nu = (np.eye(n) if split is None else split.slow), spec.nu
    part = _homogeneous_part(A_b if split is None else split.T[:split.n_slow, :split.n_slow],
                             C_b @ basis, spec, objective, margin, filter_scale)
    hom, bar_L, P_bar, rho, L_pt, P_pt, _ = part
    L0, G_d = basis @ hom.L0, hom.G_d
    if split is not None:  # embedded: nothing injected along the modes kept by the model
        rho = rho / LMI_SLACK
        G_d = embedded_generator(split, hom.G_d, nu)
        bar_L = np.vstack([bar_L[:k], basis @ bar_L[k:]])
        L_pt = basis @ L_pt
    A0 = A_b + L0 @ C_b
    bar_A0, bar_G, bar_C = augmented_system(A0, C_b, G_d)
    H = bar_A0 + bar_L @ bar_C
    if split is not None:  # the whole model's Lyapunov matrices from the homogenised part's
        P_bar = completed_lyapunov(H, bar_G, P_bar, rho,
                                   scipy.linalg.block_diag(np.eye(k), split.Q))
        P_pt = completed_lyapunov(A0 + L_pt @ C_b, G_d - nu * np.eye(n), P_pt, rho, split.Q)
    decay = -float(np.max(np.linalg.eigvals(H).real))
    d_bar = np.concatenate([np.ones(k), d])
    L_lin, luenberger_status = _luenberger_gain(spec, decay, objective, margin)
    made = {name: {"objective": objective, "lmi_margin": margin, "solver_status": status}
            for name, status in (*part.statuses, ("luenberger", luenberger_status))
            if status is not None}
    plant = PlantModel(spec.A, spec.B, spec.C, spec.E)
    model = HomogeneousModel(
        spec.disturbance_order, hom.n_tilde, nu,
        G0=diagonal_similarity(hom.G0 if split is None else (G_d - np.eye(n)) / nu - np.eye(n),
                               1.0 / d),
        L0=L0 * d[:, None], G_d=diagonal_similarity(G_d, 1.0 / d),
        slow_projector=diagonal_similarity(basis @ basis.T, 1.0 / d),
    )
    design = ObserverDesign(
        plant, model,
        filtering=FilteringGains(plant, model, rho, spec.gamma, L_tilde=bar_L[:k],
                                 L=bar_L[k:] * d[:, None],
                                 P_bar=diagonal_congruence(P_bar, 1.0 / d_bar)),
        prescribed_time=PrescribedTimeGains(plant, model, rho, L_pt=L_pt * d[:, None],
                                            P_pt=diagonal_congruence(P_pt, 1.0 / d)),
        luenberger=LuenbergerGains(plant, L_lin),
    )
    return _certified(design, made)


class _HomogeneousPart(NamedTuple):
    """The homogeneous observers' design of one (A, C) pair (the model, or its homogenised
    part), before any embedding."""

    hom: Homogenisation
    bar_L: np.ndarray
    P_bar: np.ndarray
    rho: float
    L_pt: np.ndarray
    P_pt: np.ndarray
    statuses: tuple[tuple[str, str | None], ...]


def _homogeneous_part(A: np.ndarray, C: np.ndarray, spec: PlantSpec, objective: str,
                      margin: float, filter_scale: float | None) -> _HomogeneousPart:
    """Homogenisation of (A, C), Theorem 2's LMI (with the fast output filter of
    ``filter_scale``) and Theorem 1's, at ``spec.nu`` and ``spec.rho``."""
    n, k = A.shape[0], C.shape[0]
    hom = homogenise(A, C, spec.nu)
    A0, levels = _chain_levels(A, C, spec.nu, hom)
    bar_A0, bar_G, bar_C = augmented_system(A0, C, hom.G_d)
    filtering = solve_gain_lmi(
        bar_A0, bar_G, bar_C, spec.rho, chain_basis(A0, levels, C), objective, margin
    )
    G_pt = hom.G_d - spec.nu * np.eye(n)
    pt = solve_gain_lmi(A0, G_pt, C, spec.rho, chain_basis(A0, levels), objective, margin)
    bar_L, P_bar, rho = filtering.gain, filtering.P, spec.rho
    scale = getattr(spec, "filter_scale", 1.0) if filter_scale is None else filter_scale
    if scale != 1.0:
        bar_L = np.vstack([scale * bar_L[:k], bar_L[k:]])
        rho, P_bar = _max_certified_rho(bar_A0 + bar_L @ bar_C, bar_G, spec, margin)
    return _HomogeneousPart(hom, bar_L, P_bar, rho, pt.gain, pt.P,
                            (("filtering", filtering.status), ("prescribed_time", pt.status)))


def _max_certified_rho(
    H: np.ndarray, bar_G: np.ndarray, spec: PlantSpec, margin: float
) -> tuple[float, np.ndarray]:
    """Largest rho in (gamma/2, spec.rho] certifying H (bisection in ln rho), and its P_bar."""
    def attempt(rho: float) -> np.ndarray | None:
        try:
            return certify_gain_lmi(H, bar_G, rho, margin)
        except LMIError:
            return None

    lo, hi = spec.gamma / 2 * (1 + RHO_BISECTION_TOL), spec.rho
    P = attempt(lo)
    if P is None:
        raise LMIError(
            f"filter_scale: the scaled gains are not certified for any rho > gamma/2 = "
            f"{spec.gamma / 2:g}; lower filter_scale or gamma, or raise rho"
        )
    while hi / lo > 1 + RHO_BISECTION_TOL:
        mid = np.sqrt(lo * hi)
        P_mid = attempt(mid)
        lo, hi, P = (mid, hi, P_mid) if P_mid is not None else (lo, mid, P)
    return float(lo), P


def _certified(design: ObserverDesign, made: dict[str, dict[str, Any]]) -> ObserverDesign:
    """Run the numpy certificate on a candidate and give each homogeneous or Luenberger record
    its report: its checked figures and ``made[name]``, how its gain was made (the objective
    and margin of the LMI behind it and that solve's status: ``"optimal_inaccurate"`` ones are
    kept when they pass the certificate, which is the judge; or ``"published"`` gains'
    objective and the margin of their P); none but the figures for a record not in ``made``
    (a given L_lin)."""
    parts = certify_parts(design)
    plant, model = design.plant, design.model
    E = plant.E
    if E is not None and model.disturbance_order:  # the model's unknown input is q^(order)
        E = model_perturbation_matrix(E.shape[0], E.shape[1], model.disturbance_order)

    def report(name: str) -> dict[str, Any]:
        return {"checks": parts[name]} | made.get(name, {})

    residual = None if E is None else matched_perturbation_residual(model.G_d, E, model.n_tilde)
    return replace(
        design,
        filtering=replace(design.filtering, certificate=report("filtering")
                          | {"matched_perturbation_residual": residual}),
        prescribed_time=replace(design.prescribed_time, certificate=report("prescribed_time")),
        luenberger=replace(design.luenberger, certificate=report("luenberger")),
    )


def paper_gains(reference: str | Path = PAPER_REFERENCE) -> ObserverDesign:
    """The paper's pendulum design: published L_tilde, L, L_lin, certified here.

    L0 and G_d are recomputed by :func:`fhobs.design.homogenisation.homogenise` (they equal the
    published values to the printed digits, which the tests check) because the printed,
    rounded values satisfy the identities only to about 1e-5. P_bar and P_pt are found by
    :func:`fhobs.design.lmi.certify_gain_lmi` for the published gains; L_pt is designed (the paper
    publishes none). Each record's ``certificate`` says how it was made: ``"published"`` for
    the filtering gains, Theorem 1's LMI (objective, margin, solver status) for L_pt, the
    figures alone for the given L_lin.

    Parameters
    ----------
    reference : str or Path
        The JSON file of published numbers (``examples/pendulum-paper.json``).

    Returns
    -------
    ObserverDesign

    Examples
    --------
    >>> design = paper_gains()
    >>> design.plant.n, design.plant.k, design.filtering.L.shape
    (4, 2, (4, 2))
    >>> design.filtering.certificate["objective"], design.prescribed_time.certificate["objective"]
    ('published', 'min_cond')
    """
    ref = json.loads(Path(reference).read_text())
    plant, published = ref["plant"], ref["design"]
    spec = spec_from_dict(
        {
            "A": plant["A"], "B": plant["B"], "C": plant["C"], "E": plant["B"],
            "L_lin": ref["linear_observer"]["L_lin"],
            "observer": {k: published[k] for k in ("nu", "rho", "gamma")},
        },
        source=str(reference),
    )
    tuned = _observer_for_spec(spec, None, LMI_MARGIN, None)
    filtering = tuned.filtering
    L_tilde, L = np.array(published["L_tilde"]), np.array(published["L"])
    bar_A0, bar_G, bar_C = augmented_system(filtering.A0, filtering.model_matrices[2],
                                            tuned.model.G_d)
    bar_L = np.vstack([L_tilde, L])
    P_bar = certify_gain_lmi(bar_A0 + bar_L @ bar_C, bar_G, spec.rho)
    published_filtering = replace(filtering, L_tilde=L_tilde, L=L, P_bar=P_bar)
    made = {name: {key: value for key, value in getattr(tuned, name).certificate.items()
                   if key != "checks"} for name in ("prescribed_time", "luenberger")}
    made["filtering"] = {"objective": "published", "lmi_margin": LMI_MARGIN}
    return _certified(replace(tuned, filtering=published_filtering), made)
