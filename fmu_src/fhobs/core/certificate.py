"""Independent numpy check of a design: homogeneity identities and LMI certificates.

numpy-only: it also runs inside the FMU, on parameters a user may have edited.

Each estimator's record is certified by itself (the FMU that runs it checks it, and nothing
else of the design): :func:`certify_filtering` (nu, gamma and rho in Theorem 2's ranges, the
homogeneity figures and Theorem 2's), :func:`certify_prescribed_time` (nu and rho in range, the
homogeneity figures and Theorem 1's), :func:`certify_luenberger`, :func:`certify_kalman` and
:func:`certify_supervised` (its thresholds, then its two parts' certificates)
(:data:`CERTIFIERS`); :func:`certify` runs them all on a design, so that it refuses whatever
an FMU would. Before its figures, a homogeneous record's tuning must be in range
(:func:`tuning_problem`) and its Lyapunov matrix symmetric (:func:`check_symmetry`). Every
figure is one number, compared with one bound:

============================  ===========================================================  =======
check                         value                                                        pass if
============================  ===========================================================  =======
``homogenisation_residual``   ||(A0 G_d - (G_d + nu I) A0) Pi|| / (||A0|| ||G_d||)          <= tol
``output_homogeneity``        ||C G_d - (1 + nu) C|| / ||C||                               <= tol
``nilpotency``                ||A0^n_tilde Pi|| / ||A0||^n_tilde                             <= tol
``partition_residual``        Pi a projector, (I - Pi) A0 Pi = 0, G_d Pi = Pi G_d,           <= tol
                              (G_d - (1 + nu) I)(I - Pi) = 0 (:func:`partition_residual`)
``injection_partition``       ||(I - Pi) L|| / ||L|| (``_pt``: of L_pt)                       <= tol
``dilation_anti_hurwitz``     min Re eig(G_d)                                              > 0
``P_bar_positive``            lambda_min(P_bar) / lambda_max(P_bar)                        > r
``P_bar_monotone``            lambda_min(P^-1/2 sym(P_bar bar_G) P^-1/2)                   > m + r
``lmi_filtering``             lambda_max(P^-1/2 sym(P_bar (H + rho bar_G)) P^-1/2)         < -m - r
``hurwitz_filtering``         max Re eig(H + rho bar_G), H = bar_A0 + bar_L bar_C          < 0
``P_pt_positive`` etc.        the same four checks for Theorem 1 with G = G_d - nu I       ...
``hurwitz_luenberger``        max Re eig(A + L_lin C)                                      < 0
``schur_kalman``              max |eig(Phi (I - M C))|, Phi = expm(Ts A_model)             < 1
============================  ===========================================================  =======

Pi is the model's ``slow_projector``: the identity when the whole model is homogenised (the
figures are then the paper's identities), else the projector onto the homogenised part along
the fast stable modes the observers keep by their model (:mod:`fhobs.design.partial`; why this
is enough: docs/theory.md). Those modes' stability, with a decay faster than rho (1 + nu), is
part of the LMI figures, which are always of the whole model.
The figures are computed in balanced coordinates ``x = diag(d) x_b`` (d powers of two from
:func:`fhobs.core.linalg.balancing_scale` of the model matrix): an exact similarity (congruence for
P), so every value is that of the original coordinates, with a rounding error that stays small
for plants whose entries span many decades. The homogeneous observers' figures are of the
observer's model (the plant, or its extended-state model, built here by :func:`checked_model`
independently of the design's :mod:`fhobs.core.disturbance`); ``hurwitz_luenberger`` is of the
plant, ``schur_kalman`` of the Kalman filter's own model.
sym(M) = (M + M^T) / 2. The LMIs are homogeneous in P, so their figures are generalised
eigenvalues (rates in 1/s in the P-norm, independent of P's scale): ``lmi`` is the decay rate the
LMI guarantees beyond rho, ``monotone`` the dilation's monotonicity rate. ``m`` is the required
margin; ``r`` (reported as ``<P>_rounding``) bounds the rounding error of the computed figures,
n eps cond(P) max(||H + rho G||, ||G||): a check passes only if it holds by more than the
rounding could explain. Before any figure, P_bar and P_pt must be symmetric to round-off
(:func:`check_symmetry`): the figures use sym(P), which would hide an edited entry.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import CertificateError
from .gains import (
    FilteringGains,
    HomogeneousGains,
    KalmanGains,
    LuenbergerGains,
    ObserverDesign,
    PlantModel,
    PrescribedTimeGains,
    SupervisedGains,
)
from .linalg import balancing_scale, diagonal_congruence, diagonal_similarity, expm, spectral_radius

DEFAULT_TOLERANCE = 1e-7
CERTIFICATE_MARGIN = 1e-6
"""What the certificate asks beyond round-off: an LMI's largest eigenvalue below
``-(margin + rounding)``, a monotonicity figure above ``margin + rounding``; far below the
margin the design solves with (:data:`fhobs.design.lmi.LMI_MARGIN`)."""
EPS = float(np.finfo(float).eps)


def checked_model(plant: PlantModel, order: int) -> tuple[np.ndarray, np.ndarray]:
    """``(A_model, C_model)``, the observer's model with a disturbance model of ``order``,
    built here from the plant's A, C, E (not by :mod:`fhobs.core.disturbance`, which the design
    uses, so that one error in building the model cannot pass both the design and its
    certificate).

    With r = ``order`` and p the columns of E: ``A_model = [[A, E S], [0, J]]`` with
    ``S = [I_p, 0, ..., 0]`` (p x r p) and ``J = kron(shift_r, I_p)``, ``shift_r`` the r x r
    upper shift; ``C_model = [C, 0]``.
    """
    A, C = plant.A, plant.C
    if order == 0:
        return A, C
    p = plant.E.shape[1]
    S = np.kron(np.eye(1, order), np.eye(p))
    J = np.kron(np.eye(order, k=1), np.eye(p))
    A_model = np.block([[A, plant.E @ S], [np.zeros((order * p, A.shape[0])), J]])
    return A_model, np.hstack([C, np.zeros((C.shape[0], order * p))])


def _homogeneous_model(record: HomogeneousGains) -> tuple[np.ndarray, np.ndarray]:
    """:func:`checked_model` of a homogeneous observer's record."""
    return checked_model(record.plant, record.model.disturbance_order)


def augmented_matrices(filtering: FilteringGains) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (psi, z) system of Theorem 2: bar_A0, bar_G, bar_C, from :func:`checked_model`.

    Parameters
    ----------
    filtering : FilteringGains

    Returns
    -------
    bar_A0 : numpy.ndarray
        [[0, C_model], [0, A0]], (k+n) x (k+n), A0 = A_model + L0 C_model.
    bar_G : numpy.ndarray
        diag(I_k, G_d).
    bar_C : numpy.ndarray
        [I_k, 0], k x (k+n).
    """
    A_model, C_model = _homogeneous_model(filtering)
    n, k = A_model.shape[0], C_model.shape[0]
    A0 = A_model + filtering.model.L0 @ C_model
    bar_A0 = np.block([[np.zeros((k, k)), C_model], [np.zeros((n, k)), A0]])
    bar_G = np.block([[np.eye(k), np.zeros((k, n))], [np.zeros((n, k)), filtering.model.G_d]])
    bar_C = np.hstack([np.eye(k), np.zeros((k, n))])
    return bar_A0, bar_G, bar_C


def sym(M: np.ndarray) -> np.ndarray:
    """Symmetric part (M + M^T) / 2."""
    return 0.5 * (M + M.T)


SYMMETRY_ROUNDING = 16.0
"""Allowed asymmetry of a Lyapunov matrix, in units of n eps times the entries' scale."""


def asymmetric_entries(P: np.ndarray) -> list[tuple[int, int]]:
    """The index pairs (i, j), i < j and 0-based, where ``P[i, j]`` and ``P[j, i]`` differ by
    more than round-off.

    The scale of an off-diagonal pair is the largest of ``|P[i, j]|``, ``|P[j, i]|`` and
    ``sqrt(|P[i, i] P[j, j]|)``; the pair may differ by ``SYMMETRY_ROUNDING * n * eps`` times
    it. A NaN entry counts as asymmetric.

    Parameters
    ----------
    P : numpy.ndarray
        A square matrix.

    Returns
    -------
    list of tuple of int
        The asymmetric pairs, row by row.

    Examples
    --------
    >>> asymmetric_entries(np.array([[2.0, 1.0], [1.0, 3.0]]))
    []
    >>> asymmetric_entries(np.array([[2.0, 2.0], [1.0, 3.0]]))
    [(0, 1)]
    """
    P = np.asarray(P, dtype=float)
    diagonal = np.sqrt(np.abs(np.diagonal(P)))
    scale = np.maximum(np.maximum(np.abs(P), np.abs(P.T)), np.outer(diagonal, diagonal))
    bound = SYMMETRY_ROUNDING * P.shape[0] * EPS * scale
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(P - P.T) <= bound)
    return [(int(i), int(j)) for i, j in np.argwhere(np.triu(bad, 1))]


def symmetry_problem(P: np.ndarray, name: str) -> str:
    """Why the Lyapunov matrix ``P`` (called ``name``) is not symmetric to round-off, naming
    its first asymmetric pair with 1-based indices as the FMU variables are named ('' if it
    is symmetric).

    Parameters
    ----------
    P : numpy.ndarray
        The matrix.
    name : str
        Its name in the message (``"P_bar"``, ``"P_pt"``).

    Returns
    -------
    str
        The problem, or ''.

    Examples
    --------
    >>> symmetry_problem(np.array([[2.0, 1.0], [1.0, 3.0]]), "P_bar")
    ''
    >>> print(symmetry_problem(np.array([[2.0, 2.0], [1.0, 3.0]]), "P_bar"))
    P_bar is not symmetric: P_bar[1,2] = 2 but P_bar[2,1] = 1 (a Lyapunov matrix must be ...)
    """
    pairs = asymmetric_entries(P)
    if not pairs:
        return ""
    i, j = pairs[0]
    more = f" ({len(pairs) - 1} more pair(s) differ)" if len(pairs) > 1 else ""
    return (f"{name} is not symmetric: {name}[{i + 1},{j + 1}] = {float(P[i, j]):.17g} but "
            f"{name}[{j + 1},{i + 1}] = {float(P[j, i]):.17g}{more} "
            "(a Lyapunov matrix must be symmetric)")


def check_symmetry(**matrices: np.ndarray) -> None:
    """Raise :class:`CertificateError` naming the first Lyapunov matrix that is not symmetric
    to round-off (:func:`symmetry_problem`).

    Examples
    --------
    >>> check_symmetry(P_bar=np.eye(2))
    >>> check_symmetry(P_bar=np.array([[1.0, 0.5], [0.0, 1.0]]))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: P_bar is not symmetric: P_bar[1,2] = 0.5 but ...
    """
    for name, P in matrices.items():
        problem = symmetry_problem(P, name)
        if problem:
            raise CertificateError(problem)


def homogeneity_values(record: HomogeneousGains) -> dict[str, float]:
    """The homogeneity figures of the table in the module docstring (in balanced coordinates,
    :func:`fhobs.core.linalg.balancing_scale` of the model matrix), of a homogeneous
    observer's record: on the range of the model's ``slow_projector`` Pi (the whole model when
    Pi = I), with the partition's own figure."""
    A_model, C_model = _homogeneous_model(record)
    model = record.model
    d = balancing_scale(A_model)
    A0 = diagonal_similarity(A_model + model.L0 @ C_model, d)
    G_d = diagonal_similarity(model.G_d, d)
    Pi = diagonal_similarity(model.slow_projector, d)
    C, nu = C_model * d, model.nu
    eye = np.eye(A0.shape[0])
    a0_norm = max(np.linalg.norm(A0), 1e-300)
    return {
        "homogenisation_residual": float(
            np.linalg.norm((A0 @ G_d - (G_d + nu * eye) @ A0) @ Pi)
            / (a0_norm * np.linalg.norm(G_d))
        ),
        "output_homogeneity": float(
            np.linalg.norm(C @ G_d - (1.0 + nu) * C) / max(np.linalg.norm(C), 1e-300)
        ),
        "nilpotency": float(
            np.linalg.norm(np.linalg.matrix_power(A0, model.n_tilde) @ Pi)
            / a0_norm**model.n_tilde
        ),
        "partition_residual": partition_residual(A0, G_d, Pi, nu),
        "dilation_anti_hurwitz": float(np.min(np.linalg.eigvals(G_d).real)),
    }


def partition_residual(A0: np.ndarray, G_d: np.ndarray, Pi: np.ndarray, nu: float) -> float:
    """How far Pi is from splitting the model as the partial homogenisation needs (0 for
    Pi = I): Pi a projector, its range invariant under A0, G_d commuting with Pi and equal to
    (1 + nu) I on its kernel; the largest of the four relative residuals.

    Examples
    --------
    >>> A0 = np.array([[0.0, 1.0], [0.0, -50.0]])
    >>> partition_residual(A0, np.eye(2), np.eye(2), -0.5)
    0.0
    >>> partition_residual(A0, np.eye(2), np.diag([0.0, 1.0]), -0.5) > 0.1
    True
    """
    eye = np.eye(Pi.shape[0])
    rest = eye - Pi
    norm = max(np.linalg.norm(Pi), 1.0)
    return float(max(
        np.linalg.norm(Pi @ Pi - Pi) / norm,
        np.linalg.norm(rest @ A0 @ Pi) / (max(np.linalg.norm(A0), 1e-300) * norm),
        np.linalg.norm(G_d @ Pi - Pi @ G_d) / (np.linalg.norm(G_d) * norm),
        np.linalg.norm((G_d - (1.0 + nu) * eye) @ rest) / (np.linalg.norm(G_d) * norm),
    ))


def injection_partition(record: HomogeneousGains, gain: np.ndarray) -> float:
    """||(I - Pi) gain|| / ||gain|| in balanced coordinates: the part of a homogeneous
    observer's gain that would act on the fast modes kept by the model (0 required: their
    error is then autonomous)."""
    d = balancing_scale(_homogeneous_model(record)[0])
    Pi = diagonal_similarity(record.model.slow_projector, d)
    scaled = gain / d[:, None]
    rest = np.eye(Pi.shape[0]) - Pi
    return float(np.linalg.norm(rest @ scaled) / max(np.linalg.norm(scaled), 1e-300))


def lmi_values(
    P: np.ndarray, H: np.ndarray, G: np.ndarray, rho: float, prefix: str
) -> dict[str, float]:
    """Figures of one LMI  sym(P (H + rho G)) < 0,  sym(P G) > 0,  P > 0.

    Parameters
    ----------
    P : numpy.ndarray
        Candidate Lyapunov matrix.
    H : numpy.ndarray
        Closed-loop matrix (bar_A0 + bar_L bar_C, or A0 + L_pt C).
    G : numpy.ndarray
        Dilation generator of the LMI.
    rho : float
        Decay parameter.
    prefix : str
        ``"filtering"`` or ``"pt"``: names the figures.

    Returns
    -------
    dict
        ``P_<x>_positive``, ``P_<x>_monotone``, ``lmi_<x>``, ``hurwitz_<x>``.

    Notes
    -----
    The figures are computed after the exact congruence ``P -> T P T``, ``H -> T^-1 H T``,
    ``G -> T^-1 G T`` with T the powers of two nearest to ``diag(P)^-1/2`` (Jacobi scaling):
    every generalised eigenvalue is unchanged, while the condition number of P, and with it
    the rounding allowance, drops to within a factor n of the best diagonal scaling. Only
    ``P_<x>_positive`` is of the scaled P.
    """
    name = "P_bar" if prefix == "filtering" else f"P_{prefix}"
    diagonal = np.diagonal(P)
    if np.all(diagonal > 0.0) and np.all(np.isfinite(diagonal)):
        t = 2.0 ** np.round(-0.5 * np.log2(diagonal))
        P, H, G = diagonal_congruence(P, t), diagonal_similarity(H, t), diagonal_similarity(G, t)
    P_sym = sym(P)
    M = H + rho * G
    p_eigs = np.linalg.eigvalsh(P_sym)
    positive = float(p_eigs[0]) / max(float(np.max(np.abs(p_eigs))), 1e-300)
    monotone = lmi = rounding = float("nan")
    try:
        chol_inv = np.linalg.inv(np.linalg.cholesky(P_sym)) if positive > 0 else None
    except np.linalg.LinAlgError:  # positive by a hair: the figures stay not computable
        chol_inv = None
    if chol_inv is not None:
        def rate(Q: np.ndarray) -> np.ndarray:
            return np.linalg.eigvalsh(sym(chol_inv @ sym(Q) @ chol_inv.T))

        monotone = float(rate(P_sym @ G)[0])
        lmi = float(rate(P_sym @ M)[-1])
        scale = max(np.linalg.norm(M, 2), np.linalg.norm(G, 2))
        rounding = P.shape[0] * EPS * scale / positive
    return {
        f"{name}_positive": positive,
        f"{name}_monotone": monotone,
        f"lmi_{prefix}": lmi,
        f"hurwitz_{prefix}": float(np.max(np.linalg.eigvals(M).real)),
        f"{name}_rounding": rounding,
    }


def filtering_values(filtering: FilteringGains) -> dict[str, float]:
    """The filtering observer's figures of the module docstring's table (homogeneity, the
    Theorem 2 LMI), without judging them."""
    values = homogeneity_values(filtering)
    A_model, _ = _homogeneous_model(filtering)
    d = balancing_scale(A_model)
    d_bar = np.concatenate([np.ones(filtering.plant.k), d])
    bar_A0, bar_G, bar_C = augmented_matrices(filtering)
    bar_L = np.vstack([filtering.L_tilde, filtering.L])
    values |= lmi_values(diagonal_congruence(filtering.P_bar, d_bar),
                         diagonal_similarity(bar_A0 + bar_L @ bar_C, d_bar),
                         diagonal_similarity(bar_G, d_bar), filtering.rho, "filtering")
    values["injection_partition"] = injection_partition(filtering, filtering.L)
    return values


def prescribed_time_lmi_values(prescribed_time: PrescribedTimeGains) -> dict[str, float]:
    """The four Theorem 1 figures (``P_pt_positive``, ``P_pt_monotone``, ``lmi_pt``,
    ``hurwitz_pt``, with ``P_pt_rounding``): the LMI with P_pt, ``H = A0 + L_pt C_model`` and
    ``G = G_d - nu I``, in balanced coordinates."""
    A_model, C_model = _homogeneous_model(prescribed_time)
    model = prescribed_time.model
    d = balancing_scale(A_model)
    G_pt = model.G_d - model.nu * np.eye(A_model.shape[0])
    return lmi_values(diagonal_congruence(prescribed_time.P_pt, d),
                      diagonal_similarity(A_model + (model.L0 + prescribed_time.L_pt) @ C_model,
                                          d),
                      diagonal_similarity(G_pt, d), prescribed_time.rho, "pt")


def prescribed_time_values(prescribed_time: PrescribedTimeGains) -> dict[str, float]:
    """The prescribed-time observer's figures: homogeneity and the Theorem 1 LMI."""
    return (homogeneity_values(prescribed_time) | prescribed_time_lmi_values(prescribed_time)
            | {"injection_partition_pt": injection_partition(prescribed_time,
                                                             prescribed_time.L_pt)})


def luenberger_values(luenberger: LuenbergerGains) -> dict[str, float]:
    """``hurwitz_luenberger``: ``max Re eig(A + L_lin C)`` (< 0: Hurwitz)."""
    plant = luenberger.plant
    return {"hurwitz_luenberger":
            float(np.max(np.linalg.eigvals(plant.A + luenberger.L_lin @ plant.C).real))}


def kalman_values(kalman: KalmanGains) -> dict[str, float]:
    """``schur_kalman``: the spectral radius of the filter's error map ``Phi (I - M C)``
    (< 1: Schur stable), Phi the exact ZOH of its model over Ts (from :func:`checked_model`)."""
    A, C = checked_model(kalman.plant, kalman.disturbance_order)
    Phi = expm(kalman.sample_time * A)
    return {"schur_kalman": spectral_radius(Phi - Phi @ kalman.gain @ C)}


def certify_filtering(
    filtering: FilteringGains, tolerance: float = DEFAULT_TOLERANCE,
    margin: float = CERTIFICATE_MARGIN,
) -> dict[str, float]:
    """The filtering observer's certificate (``observer.fmu`` checks it on its edited
    parameters): nu, gamma and rho in Theorem 2's ranges (:func:`tuning_problem`, the spec
    loader's rules), P_bar symmetric, then :func:`filtering_values` judged.

    Parameters and Raises as for :func:`certify`; returns the figures checked.

    Examples
    --------
    >>> import dataclasses
    >>> from fhobs.design.observer import design_observer
    >>> filtering = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0).filtering
    >>> bool(certify_filtering(filtering)["lmi_filtering"] < 0)
    True
    >>> certify_filtering(dataclasses.replace(filtering, L=-filtering.L))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: ...lmi_filtering...
    >>> certify_filtering(dataclasses.replace(filtering, gamma=-5.0))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: gamma = -5.0 must be > 0 (the xi equation's gain)
    """
    _check_tuning(filtering, filtering.gamma)
    check_symmetry(P_bar=filtering.P_bar)
    return _judged(filtering_values(filtering), tolerance, margin)


def certify_prescribed_time(
    prescribed_time: PrescribedTimeGains, tolerance: float = DEFAULT_TOLERANCE,
    margin: float = CERTIFICATE_MARGIN,
) -> dict[str, float]:
    """The prescribed-time observer's certificate (Theorem 1): nu and rho in range
    (:func:`tuning_problem`, gamma not used), the homogeneity identities and the LMI with P_pt.
    The prescribed-time FMU's check of edited parameters.

    Parameters and Raises as for :func:`certify`; returns the figures checked.

    Examples
    --------
    >>> import dataclasses
    >>> from fhobs.design.observer import design_observer
    >>> pt = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0).prescribed_time
    >>> bool(certify_prescribed_time(pt)["lmi_pt"] < 0)
    True
    >>> certify_prescribed_time(dataclasses.replace(pt, L_pt=-pt.L_pt))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: ...lmi_pt...
    """
    _check_tuning(prescribed_time, None)
    check_symmetry(P_pt=prescribed_time.P_pt)
    return _judged(prescribed_time_values(prescribed_time), tolerance, margin)


def certify_luenberger(
    luenberger: LuenbergerGains, tolerance: float = DEFAULT_TOLERANCE,
    margin: float = CERTIFICATE_MARGIN,
) -> dict[str, float]:
    """The Luenberger baseline's certificate: ``A + L_lin C`` Hurwitz (``luenberger.fmu``'s
    check of edited parameters).

    Parameters and Raises as for :func:`certify` (the signature of every certificate of
    :data:`CERTIFIERS`; no figure of this one depends on ``tolerance`` or ``margin``);
    returns the figures checked.

    Examples
    --------
    >>> from fhobs.core.gains import LuenbergerGains, PlantModel
    >>> plant = PlantModel(np.zeros((1, 1)), np.ones((1, 1)), np.ones((1, 1)))
    >>> certify_luenberger(LuenbergerGains(plant, np.array([[-2.0]])))
    {'hurwitz_luenberger': -2.0}
    >>> certify_luenberger(LuenbergerGains(plant, np.array([[1.0]])))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: ... hurwitz_luenberger = 1.000e+00 (required < 0)
    """
    return _judged(luenberger_values(luenberger), tolerance, margin)


def certify_kalman(
    kalman: KalmanGains, tolerance: float = DEFAULT_TOLERANCE,
    margin: float = CERTIFICATE_MARGIN,
) -> dict[str, float]:
    """The Kalman filter's certificate: its error map ``Phi (I - M C)`` Schur stable
    (``kalman.fmu``'s check of edited parameters).

    Parameters and Raises as for :func:`certify_luenberger`; returns the figures checked.

    Examples
    --------
    >>> import dataclasses
    >>> from fhobs.core.gains import KalmanGains, PlantModel
    >>> plant = PlantModel(np.zeros((1, 1)), np.ones((1, 1)), np.ones((1, 1)))
    >>> kalman = KalmanGains(plant, 0, 0.1, np.ones(1), 1.0, np.array([[0.5]]), np.eye(1))
    >>> certify_kalman(kalman)
    {'schur_kalman': 0.5}
    >>> certify_kalman(dataclasses.replace(kalman, gain=np.array([[-1.5]])))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: ... schur_kalman = 2.500e+00 (required < 1)
    """
    return _judged(kalman_values(kalman), tolerance, margin)


def tuning_problem(nu: float, rho: float | None, gamma: float | None, n_tilde: int,
                   prefix: str = "") -> str:
    """Why nu, gamma and rho are outside Theorem 2's ranges ('' if they are not):
    -1/(n_tilde+1) <= nu < 0, gamma > 0, rho > 0 and rho > gamma/2; a None rho or gamma (left
    to the design) is not checked. ``prefix`` goes before the names (``"observer."``).

    Examples
    --------
    >>> tuning_problem(-0.25, 6.0, 6.0, 3)
    ''
    >>> tuning_problem(-0.25, 2.0, 6.0, 3)
    'rho = 2.0 must be > gamma/2 = 3.0 (Theorem 2)'
    """
    nu_min = -1.0 / (n_tilde + 1)
    if not nu_min - 1e-12 <= nu < 0.0:
        return (f"{prefix}nu = {float(nu)!r} is outside [-1/(n_tilde+1), 0) = [{nu_min:.6g}, 0) "
                f"(n_tilde = {n_tilde})")
    if gamma is not None and not gamma > 0.0:
        return f"{prefix}gamma = {float(gamma)!r} must be > 0 (the xi equation's gain)"
    if rho is not None and not rho > 0.0:
        return f"{prefix}rho = {float(rho)!r} must be > 0"
    if rho is not None and gamma is not None and not rho > gamma / 2:
        return (f"{prefix}rho = {float(rho)!r} must be > gamma/2 = {float(gamma) / 2!r} "
                "(Theorem 2)")
    return ""


def _check_tuning(record: FilteringGains | PrescribedTimeGains, gamma: float | None) -> None:
    """Raise :class:`CertificateError` if :func:`tuning_problem` finds the homogeneous
    record's nu and rho, or ``gamma`` (the filtering observer's; None: not used), outside
    Theorem 2's ranges."""
    model = record.model
    problem = tuning_problem(model.nu, record.rho, gamma, model.n_tilde)
    if problem:
        raise CertificateError(problem)


def _violations(
    values: dict[str, float], tolerance: float, margin: float
) -> list[tuple[str, float, str]]:
    """List (check, value, requirement) for every figure out of its bound; a figure that
    could not be computed (its Lyapunov matrix is not positive definite) says so."""
    bad = []
    for name, value in values.items():
        rounding = values.get(_rounding_key(name), 0.0)
        if name.endswith("_rounding"):
            continue
        if np.isnan(value) and np.isnan(rounding):
            matrix = _rounding_key(name).removesuffix("_rounding")
            bad.append((name, value, f"not computable: {matrix} is not positive definite"))
            continue
        if name in ("homogenisation_residual", "output_homogeneity", "nilpotency",
                    "partition_residual") or name.startswith("injection_partition"):
            ok, need = value <= tolerance, f"<= {tolerance:g}"
        elif name.startswith("lmi_"):
            bound = margin + rounding
            ok, need = value < -bound, f"< {-bound:.3g}"
        elif name.startswith("hurwitz_"):
            ok, need = value < 0.0, "< 0"
        elif name.endswith("_monotone"):
            bound = margin + rounding
            ok, need = value > bound, f"> {bound:.3g}"
        elif name.startswith("schur_"):
            ok, need = value < 1.0, "< 1"
        elif name.endswith("_positive"):
            ok, need = value > 1e-14, "> 1e-14"
        else:  # dilation_anti_hurwitz
            ok, need = value > 0.0, "> 0"
        if not (ok and np.isfinite(value)):
            bad.append((name, value, need))
    return bad


def _rounding_key(name: str) -> str:
    """The rounding figure that goes with an LMI figure name."""
    if name.startswith("lmi_"):
        prefix = name[4:]
        return "P_bar_rounding" if prefix == "filtering" else f"P_{prefix}_rounding"
    return name.rsplit("_", 1)[0] + "_rounding"


def innovation_covariance(kalman: KalmanGains) -> np.ndarray:
    """The steady-state covariance ``S = C P C^T + R`` of the Kalman filter's innovation.

    Examples
    --------
    >>> from fhobs.core.gains import KalmanGains, PlantModel
    >>> plant = PlantModel(np.zeros((1, 1)), np.ones((1, 1)), np.ones((1, 1)))
    >>> kalman = KalmanGains(plant, 0, 1.0, np.ones(1), 1.0, np.array([[0.6]]), 1.5 * np.eye(1))
    >>> innovation_covariance(kalman).tolist()
    [[2.5]]
    """
    C = kalman.model_matrices[2]
    S = C @ kalman.covariance @ C.T + np.diag(kalman.measurement_std**2)
    return 0.5 * (S + S.T)


def threshold_problems(supervised: SupervisedGains) -> list[str]:
    """What is out of range in the supervisor's own fields (empty if nothing): the Kalman
    filter of the homogeneous model, the window, the ordered bands around the statistic's mean
    k and the ceiling above them, the dwell time and the false-alarm probability.

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> record = NS(plant=NS(k=2), model=NS(disturbance_order=1),
    ...             kalman=NS(disturbance_order=1), window=200.0, lower=1.4, lower_return=1.7,
    ...             upper_return=2.3, upper=2.7, ceiling=5.4, dwell_time=0.02,
    ...             false_alarm=1e-9)
    >>> threshold_problems(record)
    []
    >>> threshold_problems(NS(**{**vars(record), "upper": 2.2}))
    ['upper = 2.2 must exceed upper_return = 2.3 (the hysteresis)']
    """
    k = supervised.plant.k
    problems = []
    if supervised.kalman.disturbance_order != supervised.model.disturbance_order:
        problems.append(f"kalman.disturbance_order = {supervised.kalman.disturbance_order} must "
                        f"equal the homogeneous model's {supervised.model.disturbance_order} "
                        "(the handover maps one state onto the other)")
    values = {name: float(getattr(supervised, name)) for name in
              ("window", "lower", "lower_return", "upper_return", "upper", "ceiling",
               "dwell_time", "false_alarm")}
    bad = [name for name, value in values.items() if not math.isfinite(value)]
    problems += [f"{name} = {values[name]!r} must be finite" for name in bad]
    if bad:
        return problems
    if values["window"] < 1.0:
        problems.append(f"window = {values['window']!r} must be at least 1 sample")
    if values["lower"] < 0.0:
        problems.append(f"lower = {values['lower']!r} must be >= 0")
    for name, below, reason in (("lower_return", "lower", "(the hysteresis)"),
                                ("upper_return", "lower_return", ""),
                                ("upper", "upper_return", "(the hysteresis)"),
                                ("ceiling", "upper", "")):
        if not values[name] > values[below]:
            problems.append(f"{name} = {values[name]!r} must exceed {below} = "
                            f"{values[below]!r} {reason}".rstrip())
    if not values["lower_return"] < k < values["upper_return"]:
        problems.append(f"the return band ({values['lower_return']!r}, "
                        f"{values['upper_return']!r}) must hold the statistic's mean k = {k}")
    if not values["dwell_time"] > 0.0:
        problems.append(f"dwell_time = {values['dwell_time']!r} must be > 0 s")
    if not 0.0 < values["false_alarm"] < 1.0:
        problems.append(f"false_alarm = {values['false_alarm']!r} must be in (0, 1)")
    return problems


def covariance_problems(supervised: SupervisedGains) -> list[str]:
    """What is out of range in the covariances of the handover's time-varying recursion
    (empty if nothing): the Kalman record's ``process_covariance`` Q_d (N x N, symmetric to
    round-off, positive semi-definite to round-off) and ``handover_covariance`` (N x N,
    symmetric to round-off, positive definite on the states of nonzero variance: a state the
    noise never moves has a zero row and column), judged on their correlation matrices
    (:func:`correlation_eigenvalue`: stiff models' covariances span many decades).

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> record = NS(kalman=NS(covariance=np.eye(2), process_covariance=np.eye(2)),
    ...             handover_covariance=np.diag([2.0, 1.0]))
    >>> covariance_problems(record)
    []
    >>> bad = NS(**{**vars(record), "handover_covariance": np.diag([1.0, -1.0])})
    >>> print(*covariance_problems(bad))
    handover_covariance must be positive definite (least eigenvalue of its correlation ...)
    """
    size = supervised.kalman.covariance.shape[0]
    problems = []
    for name, matrix, least in (
            ("kalman.process_covariance", supervised.kalman.process_covariance, -1e-12),
            ("handover_covariance", supervised.handover_covariance, 1e-14)):
        if matrix is None or np.shape(matrix) != (size, size):
            problems.append(f"{name} must be a {size} x {size} matrix, got "
                            f"{None if matrix is None else np.shape(matrix)}")
            continue
        if not np.all(np.isfinite(matrix)) or asymmetric_entries(matrix):
            problems.append(f"{name} must be finite and symmetric")
            continue
        smallest = correlation_eigenvalue(matrix)
        if not smallest > least:
            kind = "positive definite" if least > 0 else "positive semi-definite"
            problems.append(f"{name} must be {kind} (least eigenvalue of its correlation "
                            f"matrix = {smallest:.3e})")
    return problems


def correlation_eigenvalue(matrix: np.ndarray) -> float:
    """The least eigenvalue of a symmetric matrix scaled to its correlation matrix (divided by
    ``sqrt(|M_ii M_jj|)``) on its support, the rows with a nonzero diagonal entry: scale free,
    1 for a diagonal positive definite matrix, at most 1 for a positive semi-definite one,
    negative for an indefinite one (-1 if a row with a zero diagonal entry is not all zero,
    which no positive semi-definite matrix has; 1 for the zero matrix).

    Examples
    --------
    >>> round(correlation_eigenvalue(np.diag([1e-20, 1e20, 0.0])), 12)
    1.0
    >>> round(correlation_eigenvalue(np.array([[1.0, 2.0], [2.0, 1.0]])), 12)
    -1.0
    """
    matrix = sym(np.asarray(matrix, dtype=float))
    support = np.diagonal(matrix) != 0.0
    if np.any(matrix[~support]):
        return -1.0
    if not support.any():
        return 1.0
    root = np.sqrt(np.abs(np.diagonal(matrix)[support]))
    return float(np.linalg.eigvalsh(matrix[np.ix_(support, support)]
                                    / np.outer(root, root))[0])


def _eigenvalue_ratio(matrix: np.ndarray) -> float:
    """``lambda_min / lambda_max`` of a symmetric matrix (-1 if its largest is not positive)."""
    eigenvalues = np.linalg.eigvalsh(sym(matrix))
    return float(eigenvalues[0] / eigenvalues[-1]) if eigenvalues[-1] > 0 else -1.0


def certify_supervised(
    supervised: SupervisedGains, tolerance: float = DEFAULT_TOLERANCE,
    margin: float = CERTIFICATE_MARGIN,
) -> dict[str, float]:
    """The supervised observer's certificate: its thresholds in range
    (:func:`threshold_problems`), the covariances of the handover's recursion
    (:func:`covariance_problems`), the innovation covariance S positive definite, then the
    filtering record's (:func:`fhobs.core.certificate.certify_filtering`) and the Kalman
    record's (:func:`fhobs.core.certificate.certify_kalman`) certificates.

    Returns
    -------
    dict
        Both parts' figures, ``innovation_covariance_positive``
        (``lambda_min(S) / lambda_max(S)``) and ``handover_covariance_positive`` (the least
        eigenvalue of ``handover_covariance``'s correlation matrix,
        :func:`correlation_eigenvalue`).

    Raises
    ------
    CertificateError
        Naming every field out of range, or the part's failed checks.

    Examples
    --------
    >>> from fhobs.design.observer import design_for_spec
    >>> from fhobs.design.spec import load_spec
    >>> from fhobs.paper import PENDULUM_SPEC
    >>> record = design_for_spec(load_spec(PENDULUM_SPEC)).supervised
    >>> figures = certify_supervised(record)
    >>> figures["schur_kalman"] < 1 and figures["lmi_filtering"] < 0
    True
    """
    problems = threshold_problems(supervised)
    if problems:
        raise CertificateError("the supervised observer's thresholds are out of range: "
                               + "; ".join(problems))
    problems = covariance_problems(supervised)
    if problems:
        raise CertificateError("the supervised observer's handover covariances are out of "
                               "range: " + "; ".join(problems))
    positive = _eigenvalue_ratio(innovation_covariance(supervised.kalman))
    if not positive > 1e-14:
        raise CertificateError(f"the Kalman filter's innovation covariance S = C P C^T + R is "
                               f"not positive definite (lambda_min / lambda_max = {positive:.3e})")
    figures = certify_filtering(supervised.filtering, tolerance, margin)
    figures |= certify_kalman(supervised.kalman, tolerance, margin)
    return figures | {"innovation_covariance_positive": positive,
                      "handover_covariance_positive": correlation_eigenvalue(
                          supervised.handover_covariance)}


CERTIFIERS = {"filtering": certify_filtering, "prescribed_time": certify_prescribed_time,
              "luenberger": certify_luenberger, "kalman": certify_kalman,
              "supervised": certify_supervised}
"""Each estimator record's certificate (the check its FMU makes), by the design's attribute
that holds it."""


def certify_parts(
    design: ObserverDesign, tolerance: float = DEFAULT_TOLERANCE,
    margin: float = CERTIFICATE_MARGIN,
) -> dict[str, dict[str, float]]:
    """:func:`certify`, with the figures of each estimator record apart (the design's
    attribute -> its figures; the homogeneity figures in both homogeneous observers').

    Each record present is certified by its own certificate (:data:`CERTIFIERS`), all of them
    before judging: the error names every record that fails and, after its name, what its
    certificate found (every failed figure, or its out-of-range tuning or asymmetric Lyapunov
    matrix); its ``lmi_margin_needed`` is the largest any record needs.

    Examples
    --------
    >>> import dataclasses
    >>> from fhobs.design.observer import design_observer
    >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> parts = certify_parts(design)
    >>> sorted(parts), sorted(parts["luenberger"])
    (['filtering', 'luenberger', 'prescribed_time'], ['hurwitz_luenberger'])
    >>> filtering = dataclasses.replace(design.filtering, gamma=-1.0)
    >>> luenberger = dataclasses.replace(design.luenberger, L_lin=-design.luenberger.L_lin)
    >>> certify_parts(dataclasses.replace(design, filtering=filtering, luenberger=luenberger))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: filtering: gamma = -1.0 must be > 0 ...; luenberger: ...
    """
    parts: dict[str, dict[str, float]] = {}
    failures: list[tuple[str, CertificateError]] = []
    for name, certifier in CERTIFIERS.items():
        record = getattr(design, name)
        if record is None:
            continue
        try:
            parts[name] = certifier(record, tolerance, margin)
        except CertificateError as err:
            failures.append((name, err))
    if failures:
        raise CertificateError("; ".join(f"{name}: {err}" for name, err in failures),
                               max(err.lmi_margin_needed for _, err in failures))
    return parts


def certify(
    design: ObserverDesign, tolerance: float = DEFAULT_TOLERANCE,
    margin: float = CERTIFICATE_MARGIN,
) -> dict[str, float]:
    """Check every estimator record of a design with its own certificate (what the FMU that
    runs it checks at initialisation) and return their figures; raise if any fails (one error
    naming every failed check of every record, :func:`certify_parts`).

    Parameters
    ----------
    design : ObserverDesign
        The design (possibly with user-edited entries).
    tolerance : float
        Bound of the relative identity residuals.
    margin : float
        Margin required on each strict LMI inequality (scaled as in the module docstring).

    Returns
    -------
    dict
        Check name -> value, as in the module docstring's table (``schur_kalman`` too when the
        design has a Kalman filter).

    Raises
    ------
    CertificateError
        Naming each failing record and what its certificate found: every failed check with
        its value and bound, or, before any figure, its nu, gamma or rho out of range
        (:func:`tuning_problem`) or the entry of its Lyapunov matrix (P_bar, P_pt) that is not
        symmetric to round-off (:func:`symmetry_problem`).

    Examples
    --------
    >>> import dataclasses
    >>> from fhobs.design.observer import design_observer
    >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> bool(certify(design)["lmi_filtering"] < 0)
    True
    >>> luenberger = dataclasses.replace(design.luenberger, L_lin=-design.luenberger.L_lin)
    >>> certify(dataclasses.replace(design, luenberger=luenberger))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: ...hurwitz_luenberger...
    """
    return _merged(certify_parts(design, tolerance, margin))


def _merged(parts: dict[str, dict[str, float]]) -> dict[str, float]:
    """The figures of every record in one dict (the homogeneity figures, equal in both
    homogeneous records, once)."""
    return {name: value for part in parts.values() for name, value in part.items()}


def _judged(values: dict[str, float], tolerance: float, margin: float) -> dict[str, float]:
    """``values``, after :func:`_judge` found every figure within its bound."""
    _judge(values, tolerance, margin)
    return values


def _judge(values: dict[str, float], tolerance: float, margin: float) -> None:
    """Raise :class:`CertificateError` naming every figure of ``values`` out of its bound."""
    bad = _violations(values, tolerance, margin)
    if bad:
        detail = "; ".join(
            f"{name} {need}" if need.startswith("not computable")
            else f"{name} = {value:.3e} (required {need})"
            for name, value, need in bad
        )
        needed = max((margin + values.get(_rounding_key(name), 0.0)
                      for name, _, _ in bad if name.startswith("lmi_")), default=0.0)
        raise CertificateError(f"design fails {len(bad)} check(s): {detail}", needed)
