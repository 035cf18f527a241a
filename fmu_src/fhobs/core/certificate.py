"""Independent numpy check of a design: homogeneity identities and LMI certificates.

numpy-only: it also runs inside the FMU, on parameters a user may have edited.

Every check yields one number, compared with one bound:

============================  ===========================================================  =======
check                         value                                                        pass if
============================  ===========================================================  =======
``homogenisation_residual``   ||A0 G_d - (G_d + nu I) A0|| / (||A0|| ||G_d||)               <= tol
``output_homogeneity``        ||C G_d - (1 + nu) C|| / ||C||                               <= tol
``nilpotency``                ||A0^n_tilde|| / ||A0||^n_tilde                                <= tol
``dilation_anti_hurwitz``     min Re eig(G_d)                                              > 0
``gamma_rho``                 rho - gamma / 2                                              > 0
``P_bar_positive``            lambda_min(P_bar) / lambda_max(P_bar)                        > r
``P_bar_monotone``            lambda_min(P^-1/2 sym(P_bar bar_G) P^-1/2)                   > m + r
``lmi_filtering``             lambda_max(P^-1/2 sym(P_bar (H + rho bar_G)) P^-1/2)         < -m - r
``hurwitz_filtering``         max Re eig(H + rho bar_G), H = bar_A0 + bar_L bar_C          < 0
``P_pt_positive`` etc.        the same four checks for Theorem 1 with G = G_d - nu I       ...
``hurwitz_luenberger``        max Re eig(A + L_lin C)                                      < 0
============================  ===========================================================  =======

The figures are computed in balanced coordinates ``x = diag(d) x_b`` (d powers of two from
:func:`fhobs.core.linalg.balancing_scale` of the model matrix): an exact similarity (congruence for
P), so every value is that of the original coordinates, with a rounding error that stays small
for plants whose entries span many decades. The homogeneous observers' figures are of the
observer's model (the plant, or its extended-state model, built here by :func:`checked_model`
independently of the design's :mod:`fhobs.core.disturbance`); ``hurwitz_luenberger`` is of the
plant.
sym(M) = (M + M^T) / 2. The LMIs are homogeneous in P, so their figures are generalised
eigenvalues (rates in 1/s in the P-norm, independent of P's scale): ``lmi`` is the decay rate the
LMI guarantees beyond rho, ``monotone`` the dilation's monotonicity rate. ``m`` is the required
margin; ``r`` (reported as ``<P>_rounding``) bounds the rounding error of the computed figures,
n eps cond(P) max(||H + rho G||, ||G||): a check passes only if it holds by more than the
rounding could explain. Before any figure, P_bar and P_pt must be symmetric to round-off
(:func:`check_symmetry`): the figures use sym(P), which would hide an edited entry.
"""

from __future__ import annotations

import numpy as np

from .errors import CertificateError
from .gains import ObserverGains
from .linalg import balancing_scale, diagonal_congruence, diagonal_similarity

DEFAULT_TOLERANCE = 1e-7
CERTIFICATE_MARGIN = 1e-6
"""What the certificate asks beyond round-off: an LMI's largest eigenvalue below
``-(margin + rounding)``, a monotonicity figure above ``margin + rounding``; far below the
margin the design solves with (:data:`fhobs.design.lmi.LMI_MARGIN`)."""
EPS = float(np.finfo(float).eps)


def checked_model(gains: ObserverGains) -> tuple[np.ndarray, np.ndarray]:
    """``(A_model, C_model)``, the observer's model, built here from the plant's A, C, E and
    ``disturbance_order`` (not by :mod:`fhobs.core.disturbance`, which the design uses, so that
    one error in building the model cannot pass both the design and its certificate).

    With r = ``disturbance_order`` and p the columns of E: ``A_model = [[A, E S], [0, J]]``
    with ``S = [I_p, 0, ..., 0]`` (p x r p) and ``J = kron(shift_r, I_p)``, ``shift_r`` the
    r x r upper shift; ``C_model = [C, 0]``.
    """
    A, C, order = gains.A, gains.C, gains.disturbance_order
    if order == 0:
        return A, C
    p = gains.E.shape[1]
    S = np.kron(np.eye(1, order), np.eye(p))
    J = np.kron(np.eye(order, k=1), np.eye(p))
    A_model = np.block([[A, gains.E @ S], [np.zeros((order * p, A.shape[0])), J]])
    return A_model, np.hstack([C, np.zeros((C.shape[0], order * p))])


def augmented_matrices(gains: ObserverGains) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (psi, z) system of Theorem 2: bar_A0, bar_G, bar_C, from :func:`checked_model`.

    Parameters
    ----------
    gains : ObserverGains

    Returns
    -------
    bar_A0 : numpy.ndarray
        [[0, C_model], [0, A0]], (k+n) x (k+n), A0 = A_model + L0 C_model.
    bar_G : numpy.ndarray
        diag(I_k, G_d).
    bar_C : numpy.ndarray
        [I_k, 0], k x (k+n).
    """
    A_model, C_model = checked_model(gains)
    n, k = A_model.shape[0], C_model.shape[0]
    A0 = A_model + gains.L0 @ C_model
    bar_A0 = np.block([[np.zeros((k, k)), C_model], [np.zeros((n, k)), A0]])
    bar_G = np.block([[np.eye(k), np.zeros((k, n))], [np.zeros((n, k)), gains.G_d]])
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


def homogeneity_values(gains: ObserverGains) -> dict[str, float]:
    """The four homogeneity figures of the table in the module docstring (in balanced
    coordinates, :func:`fhobs.core.linalg.balancing_scale` of the model matrix)."""
    A_model, C_model = checked_model(gains)
    d = balancing_scale(A_model)
    A0 = diagonal_similarity(A_model + gains.L0 @ C_model, d)
    G_d = diagonal_similarity(gains.G_d, d)
    C, nu = C_model * d, gains.nu
    eye = np.eye(A0.shape[0])
    a0_norm = max(np.linalg.norm(A0), 1e-300)
    return {
        "homogenisation_residual": float(
            np.linalg.norm(A0 @ G_d - (G_d + nu * eye) @ A0) / (a0_norm * np.linalg.norm(G_d))
        ),
        "output_homogeneity": float(
            np.linalg.norm(C @ G_d - (1.0 + nu) * C) / max(np.linalg.norm(C), 1e-300)
        ),
        "nilpotency": float(
            np.linalg.norm(np.linalg.matrix_power(A0, gains.n_tilde)) / a0_norm**gains.n_tilde
        ),
        "dilation_anti_hurwitz": float(np.min(np.linalg.eigvals(G_d).real)),
    }


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


def certificate_values(gains: ObserverGains) -> dict[str, float]:
    """Every figure of the module docstring's table, without judging them."""
    values = homogeneity_values(gains)
    values["gamma_rho"] = gains.rho - gains.gamma / 2
    A_model, C_model = checked_model(gains)
    d = balancing_scale(A_model)
    d_bar = np.concatenate([np.ones(gains.k), d])
    bar_A0, bar_G, bar_C = augmented_matrices(gains)
    bar_L = np.vstack([gains.L_tilde, gains.L])
    values |= lmi_values(diagonal_congruence(gains.P_bar, d_bar),
                         diagonal_similarity(bar_A0 + bar_L @ bar_C, d_bar),
                         diagonal_similarity(bar_G, d_bar), gains.rho, "filtering")
    values |= prescribed_time_lmi_values(gains)
    values["hurwitz_luenberger"] = luenberger_abscissa(gains)
    return values


def prescribed_time_lmi_values(gains: ObserverGains) -> dict[str, float]:
    """The four Theorem 1 figures (``P_pt_positive``, ``P_pt_monotone``, ``lmi_pt``,
    ``hurwitz_pt``, with ``P_pt_rounding``): the LMI with P_pt, ``H = A0 + L_pt C_model`` and
    ``G = G_d - nu I``, in balanced coordinates."""
    A_model, C_model = checked_model(gains)
    d = balancing_scale(A_model)
    G_pt = gains.G_d - gains.nu * np.eye(A_model.shape[0])
    return lmi_values(diagonal_congruence(gains.P_pt, d),
                      diagonal_similarity(A_model + (gains.L0 + gains.L_pt) @ C_model, d),
                      diagonal_similarity(G_pt, d), gains.rho, "pt")


def certify_prescribed_time(
    gains: ObserverGains, tolerance: float = DEFAULT_TOLERANCE, margin: float = CERTIFICATE_MARGIN
) -> dict[str, float]:
    """The part of :func:`certify` that covers Theorem 1, the prescribed-time observer: nu and
    rho in range (:func:`tuning_problem`, gamma not used), the homogeneity identities and the
    LMI with P_pt. The prescribed-time FMU's check of edited parameters.

    Parameters and Raises as for :func:`certify`; returns the figures checked.

    Examples
    --------
    >>> import dataclasses
    >>> from fhobs.design.observer import design_observer
    >>> gains = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> bool(certify_prescribed_time(gains)["lmi_pt"] < 0)
    True
    >>> certify_prescribed_time(dataclasses.replace(gains, L_pt=-gains.L_pt))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: ...lmi_pt...
    """
    problem = tuning_problem(gains.nu, gains.rho, None, gains.n_tilde)
    if problem:
        raise CertificateError(problem)
    check_symmetry(P_pt=gains.P_pt)
    values = homogeneity_values(gains) | prescribed_time_lmi_values(gains)
    _judge(values, tolerance, margin)
    return values


def luenberger_abscissa(gains: ObserverGains) -> float:
    """``max Re eig(A + L_lin C)``, the Luenberger baseline's check (< 0: Hurwitz)."""
    return float(np.max(np.linalg.eigvals(gains.A + gains.L_lin @ gains.C).real))


def check_luenberger(gains: ObserverGains) -> None:
    """Raise :class:`CertificateError` unless ``A + L_lin C`` is Hurwitz (the Luenberger FMU's
    check of edited parameters; :func:`certify` makes it with the others)."""
    abscissa = luenberger_abscissa(gains)
    if not abscissa < 0.0:
        raise CertificateError(
            f"check hurwitz_luenberger failed: max Re eig(A + L_lin C) = {abscissa:.3e} "
            "(required < 0)"
        )


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


def check_tuning(gains: ObserverGains) -> None:
    """Raise CertificateError if :func:`tuning_problem` finds the design's nu, gamma or rho
    outside Theorem 2's ranges (the spec loader's rules).

    Examples
    --------
    >>> import dataclasses
    >>> from fhobs.design.observer import paper_gains
    >>> check_tuning(paper_gains())
    >>> check_tuning(dataclasses.replace(paper_gains(), gamma=-5.0))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: gamma = -5.0 must be > 0 (the xi equation's gain)
    """
    problem = tuning_problem(gains.nu, gains.rho, gains.gamma, gains.n_tilde)
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
        if name in ("homogenisation_residual", "output_homogeneity", "nilpotency"):
            ok, need = value <= tolerance, f"<= {tolerance:g}"
        elif name.startswith("lmi_"):
            bound = margin + rounding
            ok, need = value < -bound, f"< {-bound:.3g}"
        elif name.startswith("hurwitz_"):
            ok, need = value < 0.0, "< 0"
        elif name.endswith("_monotone"):
            bound = margin + rounding
            ok, need = value > bound, f"> {bound:.3g}"
        elif name.endswith("_positive"):
            ok, need = value > 1e-14, "> 1e-14"
        else:  # dilation_anti_hurwitz, gamma_rho
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


def certify(
    gains: ObserverGains, tolerance: float = DEFAULT_TOLERANCE, margin: float = CERTIFICATE_MARGIN
) -> dict[str, float]:
    """Check a design and return its figures; raise if any is out of bounds.

    Parameters
    ----------
    gains : ObserverGains
        The design (possibly with user-edited entries).
    tolerance : float
        Bound of the relative identity residuals.
    margin : float
        Margin required on each strict LMI inequality (scaled as in the module docstring).

    Returns
    -------
    dict
        Check name -> value, as in the module docstring's table.

    Raises
    ------
    CertificateError
        Naming every failed check with its value and bound; first, naming the entry of a
        Lyapunov matrix (P_bar, P_pt) that is not symmetric to round-off
        (:func:`symmetry_problem`).

    Examples
    --------
    >>> import dataclasses
    >>> from fhobs.design.observer import design_observer
    >>> gains = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> bool(certify(gains)["lmi_filtering"] < 0)
    True
    >>> certify(dataclasses.replace(gains, L_lin=-gains.L_lin))
    Traceback (most recent call last):
    ...
    fhobs.core.errors.CertificateError: ...hurwitz_luenberger...
    """
    check_symmetry(P_bar=gains.P_bar, P_pt=gains.P_pt)
    values = certificate_values(gains)
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
