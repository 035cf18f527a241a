"""The design LMIs, solved with cvxpy + Clarabel in a chain basis of the dilation.

One LMI shape serves the three observers. For a matrix ``H0``, a generator ``G``, an output
matrix ``Cout`` and a decay parameter ``rho``, find ``P = P^T`` and ``Y`` with

    sym(P H0 + Y Cout + rho P G) <= -margin P,    sym(P G) >= margin P,    I <= P <= kappa I,

and return the gain ``P^-1 Y``. ``sym(M) = (M + M^T)/2``, so the first inequality is the paper's
``P H0 + H0^T P + Y C + C^T Y^T + rho (P G + G^T P) <= 0`` halved, made strict by the margin:
a decay rate (1/s) beyond rho, in the norm of P, which is what the certificate measures.

- Theorem 2 (filtering observer): H0 = bar_A0, G = bar_G, Cout = bar_C, gain (L_tilde; L).
- Theorem 1 (prescribed-time observer): H0 = A0, G = G_d - nu I, Cout = C, gain L_pt.
- Luenberger baseline: H0 = A, G = I, Cout = C, rho = decay rate: every eigenvalue of
  A + L_lin C then has real part <= -rho.

Normalisation: the LMIs are homogeneous in (P, Y), so P >= I fixes the scale.

Working coordinates (:func:`chain_basis`). The LMI is solved in a basis T (N x N) made of
chains v, A0 v, ..., A0^j v of eigenvectors of the dilation (the observer form of the
nilpotent A0), each chain ordered head first, its head A0^j v on the level that C sees; for
Theorem 2 the psi vector (C A0^j v; 0) heads each chain. The m chains of one length are mixed by
one invertible m x m matrix, the same on every level, that makes them orthonormal in the sum
over their levels, and every level is scaled to unit rms norm (this keeps T, hence P in the
original coordinates, as well conditioned as the eigenvectors allow). In T:

- ``T^-1 H0 T = Hs + X E``: Hs the direct sum of one matrix h_s (nonzero only on the first
  superdiagonal) per chain of length s, E (k x N) the selector of the chain heads, X (N x k)
  the head columns (zero for Theorems 1 and 2; -T^-1 L0 C heads for the Luenberger A = A0 - L0 C);
- ``T^-1 G T = Gs``, the direct sum of diagonal g_s (the dilation weights);
- ``Cout T = K E`` with K (k x k) invertible.

solve_gain_lmi checks this structure (relative tolerance ``STRUCTURE_RTOL``). With
P_t = T^T P T and Y~ = P_t (T^-1 gain K + X), the LMI is exactly

    sym(P_t (Hs + rho Gs) + Y~ E) <= -margin P_t,  sym(P_t Gs) >= margin P_t,
    I <= P_t <= kappa I,

with Y~ free (X E is absorbed by the output injection; the feasible set of P_t is the same).
Rotating the chains of one length among themselves (Q (x) I_s, Q orthogonal) maps a solution to
a solution with the same kappa and the same ||Y~||_2, and the problem is convex, so averaging
over the rotations shows that the optimum is attained, without loss, at P_t = (+) p_s and Y~ =
(+) y_s: one s x s block p_s and one column y_s per chain, shared by the chains of one length,
nothing between chains. Clarabel solves only these blocks (size <= n_tilde + 1, one set per
distinct chain length), instead of four dense N x N cones with N^2/2 + N k unknowns: n = 50
takes well under a second instead of minutes. The solution maps back exactly:
P = T^-T P_t T^-1, gain = T (P_t^-1 Y~ - X) K^-1. The numpy certificate re-checks it in the
original coordinates.

Objectives (``OBJECTIVES``), functions of P_t and Y~ measured in the basis T:

- ``"min_cond"`` (default): minimise kappa, the condition number bound of P_t: the
  best-conditioned certificate, whose gains are moderate because a large gain needs an
  ill-conditioned P to satisfy the LMI.
- ``"min_gain"``: two stages: min_cond first, then minimise ||Y~||_2 = max_s ||y_s||_2 with kappa
  allowed to grow to ``GAIN_STAGE_KAPPA`` times its optimum: smaller gains (less noise
  amplification) at equal decay rho.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse

from ..errors import LMIError
from ..extras import require
from .spec import OBJECTIVES

cp = require("cvxpy", "design")
clarabel = require("clarabel", "design")

GAIN_STAGE_KAPPA = 10.0
LMI_MARGIN = 1e-2
"""The margin that makes the LMIs strict when solving (``<= -margin P``, ``>= margin P``), so
that the numpy certificate, which asks far less (:data:`fhobs.core.certificate.CERTIFICATE_MARGIN`),
accepts the solver's rounded solution."""
STRUCTURE_RTOL = 1e-8
CHAIN_COND_LIMIT = 1e12
"""A chain basis more ill-conditioned than this is reported as singular (LMIError)."""
# A relative duality gap of 1e-7 on kappa (or ||Y~||) is plenty; at Clarabel's default 1e-8 some
# reduced LMIs stop one step short with status "optimal_inaccurate".
SOLVER_OPTIONS = {"tol_gap_rel": 1e-7}
CLARABEL_STATUS = {"Solved": "optimal", "AlmostSolved": "optimal_inaccurate"}
"""Clarabel's statuses that give a solution, and the status reported for each (cvxpy's
names); any other is an LMIError."""


@dataclass(frozen=True)
class LMISolution:
    """A solution of the LMI of the module docstring.

    Attributes
    ----------
    P : numpy.ndarray
        Lyapunov matrix in the original coordinates, symmetric.
    Y : numpy.ndarray
        Auxiliary variable, P @ gain.
    gain : numpy.ndarray
        P^-1 Y.
    status : str
        cvxpy's status: ``"optimal"``, or ``"optimal_inaccurate"`` if any of the solves behind
        the solution stopped short of the solver's tolerances.
    solve_time : float
        Solver time in seconds (as reported by cvxpy).
    """

    P: np.ndarray
    Y: np.ndarray
    gain: np.ndarray
    status: str
    solve_time: float


@dataclass(frozen=True)
class ChainBasis:
    """Working coordinates of the LMI (module docstring).

    Attributes
    ----------
    T : numpy.ndarray
        N x N invertible; its columns are the chains, one after the other, head first.
    sizes : tuple of int
        Length of each chain, in the order of T's columns.
    """

    T: np.ndarray
    sizes: tuple[int, ...]


def chain_basis(
    A0: np.ndarray, levels: Sequence[np.ndarray], C: np.ndarray | None = None
) -> ChainBasis:
    """Chains v, A0 v, ..., A0^j v of dilation eigenvectors, heads on level 0.

    Level j - 1 holds A0 times level j, and A0 maps level j >= 1 one to one into level j - 1
    (a vector of level j >= 1 that A0 sends to zero would be unobservable: C G_d = (1 + nu) C
    makes C zero on every level but the first). Going down from the deepest level, the chains
    that started deeper pass through level j as A0 times their vectors of level j + 1; new
    chains start on the orthogonal complement, within level j, of these images (orthonormal),
    so the observability chains may have any lengths, equal or not (the number of chains of
    length > j is the dimension of level j: the observability indices). With ``C``, every
    chain gets the head (C h; 0), h its level-0 vector: the (psi, z) coordinates of Theorem 2.
    Then the chains of each length are made orthogonal, in the sum over their levels, to the
    leading rows of every longer chain (those rows are a chain of the same length: adding them
    keeps the structure) and mixed to be orthonormal, and each level (position in the chains)
    is scaled to unit rms norm; none of this changes the chain structure. Without the first
    step two
    chains of different lengths can end in nearly parallel heads (two outputs that see the
    disturbance almost alike), which makes T, hence P, nearly singular.

    Parameters
    ----------
    A0 : numpy.ndarray
        n x n nilpotent homogeneous matrix.
    levels : sequence of numpy.ndarray
        ``levels[j]``: orthonormal basis (n x r_j) of the eigenspace of G_d of weight
        1 + nu + j nu; A0 maps level j into level j - 1 and level 0 to 0.
    C : numpy.ndarray, optional
        k x n output matrix, for the augmented (psi, z) basis.

    Returns
    -------
    ChainBasis

    Raises
    ------
    LMIError
        If the chain vectors do not form a basis (condition number beyond
        ``CHAIN_COND_LIMIT``).

    Examples
    --------
    A triple integrator with a double integrator, both positions measured (chains 3 and 2);
    G_d = diag(1 + nu, 1 + 2 nu, 1 + 3 nu, 1 + nu, 1 + 2 nu) levels them:

    >>> A0 = np.diag([1.0, 1.0, 0.0, 1.0], k=1)
    >>> e = np.eye(5)
    >>> basis = chain_basis(A0, [e[:, [0, 3]], e[:, [4, 1]], e[:, [2]]])
    >>> basis.sizes, int(np.linalg.matrix_rank(basis.T))
    ((3, 2), 5)
    """
    chains: list[np.ndarray] = []
    deeper = np.zeros((A0.shape[0], 0))  # the chain vectors of level j + 1
    for j in range(len(levels) - 1, -1, -1):
        images = A0 @ deeper  # in level j: the chains that started deeper pass through here
        u = np.linalg.svd(levels[j].T @ images, full_matrices=True)[0]
        starts = levels[j] @ u[:, images.shape[1]:]
        chains += [np.array([np.linalg.matrix_power(A0, i) @ v for i in range(j, -1, -1)])
                   for v in starts.T]
        deeper = np.hstack([images, starts])
    if C is not None:
        chains = [np.vstack([np.hstack([C @ ch[0], 0 * ch[0]]),
                             np.hstack([np.zeros((len(ch), C.shape[0])), ch])]) for ch in chains]
    mixed: list[np.ndarray] = []
    for s in sorted({len(ch) for ch in chains}, reverse=True):
        W = np.array([ch for ch in chains if len(ch) == s])
        if mixed:  # leading s rows of a longer chain form a chain of length s: project them out
            longer = np.array([ch[:s].ravel() for ch in mixed]).T
            Q = np.linalg.qr(longer)[0]
            flat = W.reshape(len(W), -1)
            W = (flat - (flat @ Q) @ Q.T).reshape(W.shape)
        w, U = np.linalg.eigh(np.einsum("ilx,jlx->ij", W, W))
        mixed += list(np.einsum("ij,jlx->ilx", (U / np.sqrt(w)) @ U.T, W))
    rms = [np.sqrt(np.mean([np.sum(ch[i] ** 2) for ch in mixed if len(ch) > i]))
           for i in range(len(mixed[0]))]
    T = np.vstack([ch / np.array(rms[: len(ch)])[:, None] for ch in mixed]).T
    if T.shape[0] != T.shape[1] or not np.linalg.cond(T) < CHAIN_COND_LIMIT:
        raise LMIError(
            f"the chain basis of the dilation is singular ({T.shape[1]} chain vectors for "
            f"{T.shape[0]} states, condition number {np.linalg.cond(T):.3g}): A0 does not map "
            "each level of G_d's eigenvectors one to one into the next"
        )
    return ChainBasis(T, tuple(len(ch) for ch in mixed))


def solve_gain_lmi(
    H0: np.ndarray,
    G: np.ndarray,
    Cout: np.ndarray,
    rho: float,
    basis: ChainBasis,
    objective: str = "min_cond",
    margin: float = LMI_MARGIN,
) -> LMISolution:
    """Solve the LMI of the module docstring in a chain basis and return the gain P^-1 Y.

    Parameters
    ----------
    H0 : numpy.ndarray
        N x N open-loop matrix.
    G : numpy.ndarray
        N x N generator.
    Cout : numpy.ndarray
        p x N output matrix.
    rho : float
        Decay parameter.
    basis : ChainBasis
        Working coordinates, with the structure of the module docstring for H0, G, Cout.
    objective : str
        One of :data:`OBJECTIVES`.
    margin : float
        Margin on the strict inequalities, a rate in 1/s.

    Returns
    -------
    LMISolution
        In the original coordinates.

    Raises
    ------
    LMIError
        If Clarabel reports no optimal solution.
    ValueError
        For an unknown objective, or a basis without the chain structure.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"objective {objective!r} is not one of {OBJECTIVES}")
    T, sizes = basis.T, basis.sizes
    heads = np.cumsum((0,) + sizes[:-1])
    H_t, G_t = np.linalg.solve(T, H0 @ T), np.linalg.solve(T, G @ T)
    C_t, X = Cout @ T, H_t[:, heads]
    H_t[:, heads] = 0.0
    blocks = {
        s: (H_t[h:h + s, h:h + s], G_t[h:h + s, h:h + s]) for s, h in zip(sizes, heads, strict=True)
    }
    Hs = scipy.linalg.block_diag(*(blocks[s][0] for s in sizes))
    Gs = scipy.linalg.block_diag(*(blocks[s][1] for s in sizes))
    C_s = np.zeros_like(C_t)
    C_s[:, heads] = C_t[:, heads]
    for M, M_s in ((H_t, Hs), (G_t, Gs), (C_t, C_s)):
        if np.linalg.norm(M - M_s) > STRUCTURE_RTOL * max(np.linalg.norm(M), 1.0):
            raise ValueError("the basis does not have the chain structure of H0, G and Cout")
    try:
        p, y, solve_time, status = _solve_chains(blocks, rho, objective, margin, margin)
    except LMIError:
        p, y, solve_time, status = _solve_normalised_chains(blocks, rho, objective, margin)
    P_t = scipy.linalg.block_diag(*(p[s] for s in sizes))
    gain_t = scipy.linalg.block_diag(*(np.linalg.solve(p[s], y[s]) for s in sizes)) - X
    gain = T @ np.linalg.solve(C_t[:, heads].T, gain_t.T).T
    T_inv = np.linalg.inv(T)
    P = T_inv.T @ P_t @ T_inv
    P = 0.5 * (P + P.T)
    return LMISolution(P, P @ gain, gain, status, solve_time)


def _solve_normalised_chains(
    blocks: dict[int, tuple[np.ndarray, np.ndarray]], rho: float, objective: str, margin: float
) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray], float, str]:
    """The reduced LMI solved in the chains' normalised coordinates, for when the direct solve
    fails (long chains, large rho, links of very different sizes).

    With ``c_0 = 1``, ``c_(i+1) = c_i rho / h[i, i+1]`` and ``S = diag(c)``,
    ``S^-1 (h + rho g) S = rho (J + g)`` (J: ones on the superdiagonal) and ``e1 S = e1``, so
    ``p = S^-1 p' S^-1``, ``y = rho S^-1 y'`` solve the LMI if ``p', y'`` solve
    ``sym(p' (J + g) + y' e1) <= -(margin / rho) p'``, ``sym(p' g) >= margin p'``: one
    well-conditioned problem whatever rho and the link sizes (the spread they cause moves into
    the exact diagonal map back). The objectives are measured on p' and y'.
    """
    scales, normalised = {}, {}
    for s, (h, g) in blocks.items():
        with np.errstate(all="ignore"):
            c = np.cumprod(np.concatenate(([1.0], rho / np.diagonal(h, 1))))
            normalised[s] = (h * c[None, :] / c[:, None] / rho, g)
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(normalised[s][0]))):
            raise LMIError(f"the chains' links span more than double precision (rho = {rho})")
        scales[s] = c
    p, y, solve_time, status = _solve_chains(normalised, 1.0, objective, margin / rho, margin)
    return (
        {s: p[s] / scales[s][:, None] / scales[s][None, :] for s in blocks},
        {s: rho * y[s] / scales[s][:, None] for s in blocks},
        solve_time,
        status,
    )


def _solve_chains(
    blocks: dict[int, tuple[np.ndarray, np.ndarray]], rho: float, objective: str,
    decay_margin: float, monotone_margin: float,
) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray], float, str]:
    """The reduced LMI: one block p_s, y_s per chain size s, with the margins of its decay and
    monotonicity inequalities; returns p, y, the solve time and the status (:func:`_worse` of
    the stages').

    Clarabel is called directly on the conic programs of :class:`_ChainProgram` (no modelling
    layer to canonicalise them at every rho).
    """
    program = _ChainProgram(blocks, rho, decay_margin, monotone_margin)
    x, solve_time, status = _solve(program.min_cond(), rho, "min_cond")
    if objective == "min_gain":
        x, stage_time, stage_status = _solve(program.min_gain(GAIN_STAGE_KAPPA * x[0]), rho,
                                             objective)
        solve_time, status = solve_time + stage_time, _worse(status, stage_status)
    p, y = program.blocks_of(x)
    return p, y, solve_time, status


@functools.lru_cache(maxsize=32)
def _symmetric_basis(s: int) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray], np.ndarray]:
    """The unknowns of a symmetric s x s matrix and Clarabel's vector of one.

    Returns ``(E, index, w)``: ``E[k]`` the symmetric matrix of the k-th unknown (ones at the
    k-th entry of the upper triangle, row by row, and its mirror), and ``svec(M) = w *
    M[index]``, Clarabel's ``PSDTriangleConeT`` vector (the upper triangle column by column,
    ``w`` 1 on the diagonal and sqrt(2) off it, so that ``svec(M) . svec(N) = trace(M N)``).
    """
    rows, cols = np.triu_indices(s)
    E = np.zeros((len(rows), s, s))
    E[np.arange(len(rows)), rows, cols] = 1.0
    E[np.arange(len(rows)), cols, rows] = 1.0
    lower_cols, lower_rows = np.tril_indices(s)
    return E, (lower_rows, lower_cols), np.where(lower_rows == lower_cols, 1.0, np.sqrt(2.0))


def _svec(M: np.ndarray) -> np.ndarray:
    """Clarabel's vector of the symmetric matrix M (of each matrix of a stack, the last axis)."""
    _, index, w = _symmetric_basis(M.shape[-1])
    return (w * M[..., index[0], index[1]]).T


def _sym_map(M: np.ndarray) -> np.ndarray:
    """The matrix of ``p -> svec(sym(p M))`` on the unknowns of p (:func:`_symmetric_basis`)."""
    EM = _symmetric_basis(M.shape[0])[0] @ M
    return _svec(0.5 * (EM + EM.transpose(0, 2, 1)))


def _head_map(s: int) -> np.ndarray:
    """The matrix of ``y -> svec(sym(y e1))``, y in R^s, e1 the first row of I_s."""
    Y = np.zeros((s, s, s))
    Y[np.arange(s), np.arange(s), 0] = 1.0
    return _svec(0.5 * (Y + Y.transpose(0, 2, 1)))


Cone = tuple[np.ndarray, np.ndarray, object]
"""A constraint ``J x + F0`` in a cone: ``(J, F0, clarabel cone)``."""


class _ChainProgram:
    """The reduced LMI of :func:`_solve_chains` as Clarabel's conic programs.

    Per chain size s, with ``M = h + rho g``, ``p_s`` symmetric and ``y_s`` in R^s:

    - decay: ``-(sym(p_s M) + sym(y_s e1) + decay_margin p_s)`` PSD;
    - monotonicity: ``sym(p_s g) - monotone_margin p_s`` PSD;
    - ``p_s - I`` PSD;
    - ``min_cond``: ``kappa I - p_s`` PSD, minimise kappa;
    - ``min_gain``: ``limit I - p_s`` PSD, ``(r_s, y_s)`` in the second-order cone and
      ``t - r_s >= 0``, minimise t.

    The unknowns ``x``: the objective's variable (kappa or t), then per chain size the entries
    of p_s's upper triangle row by row and y_s, then (min_gain) the r_s. Each constraint is an
    affine map ``F(x) = J x + F0`` into its cone, handed to Clarabel as ``A = -J``, ``b = F0``
    (``A x + s = b``, s in the cone), the cones grouped by kind (non-negative, second-order,
    PSD). This is, entry for entry and in the same order, the program cvxpy canonicalises the
    same LMI to, so Clarabel takes the same steps.
    """

    def __init__(self, blocks: dict[int, tuple[np.ndarray, np.ndarray]], rho: float,
                 decay_margin: float, monotone_margin: float) -> None:
        self.offsets: dict[int, int] = {}  # s -> offset of p_s's unknowns in x; y_s follows
        self.size = 1
        for s in blocks:
            self.offsets[s] = self.size
            self.size += s * (s + 1) // 2 + s
        self.lmis: list[Cone] = []
        with np.errstate(all="ignore"):  # non-finite data are refused by _solve
            self._add_lmis(blocks, rho, decay_margin, monotone_margin)

    def _add_lmis(self, blocks: dict[int, tuple[np.ndarray, np.ndarray]], rho: float,
                  decay_margin: float, monotone_margin: float) -> None:
        """The decay, monotonicity and ``p_s >= I`` constraints of every chain size."""
        for s, (h, g) in blocks.items():
            W = _svec(_symmetric_basis(s)[0])  # p_s -> svec(p_s)
            zero = np.zeros(len(W))
            self.lmis += [
                (self._place(s, -(_sym_map(h + rho * g) + decay_margin * W), -_head_map(s)),
                 zero, clarabel.PSDTriangleConeT(s)),
                (self._place(s, _sym_map(g) - monotone_margin * W), zero,
                 clarabel.PSDTriangleConeT(s)),
                (self._place(s, W), -_svec(np.eye(s)), clarabel.PSDTriangleConeT(s)),
            ]

    def _place(self, s: int, J_p: np.ndarray, J_y: np.ndarray | None = None,
               width: int | None = None) -> np.ndarray:
        """J with the columns of p_s (and y_s) in their places, zero elsewhere."""
        J = np.zeros((J_p.shape[0], width or self.size))
        start = self.offsets[s]
        J[:, start:start + J_p.shape[1]] = J_p
        if J_y is not None:
            J[:, start + J_p.shape[1]:start + J_p.shape[1] + s] = J_y
        return J

    def _bounds(self, width: int) -> list[Cone]:
        """``-p_s`` (to be bounded by the objective's ``kappa I`` or a constant ``limit I``)."""
        return [(self._place(s, -_svec(_symmetric_basis(s)[0]), width=width),
                 np.zeros(s * (s + 1) // 2), clarabel.PSDTriangleConeT(s)) for s in self.offsets]

    def min_cond(self) -> tuple[np.ndarray, list[Cone]]:
        """``(q, constraints)`` of the min_cond stage, x[0] = kappa."""
        bounds = self._bounds(self.size)
        for (J, _, _), s in zip(bounds, self.offsets, strict=True):
            J[:, 0] = _svec(np.eye(s))
        return np.eye(1, self.size)[0], self.lmis + bounds

    def min_gain(self, limit: float) -> tuple[np.ndarray, list[Cone]]:
        """``(q, constraints)`` of the min_gain stage, x[0] = t, ``p_s <= limit I``."""
        width = self.size + len(self.offsets)
        widen = [(np.hstack([J, np.zeros((len(J), len(self.offsets)))]), F0, cone)
                 for J, F0, cone in self.lmis]
        bounds = [(J, limit * _svec(np.eye(s)), cone)
                  for (J, _, cone), s in zip(self._bounds(width), self.offsets, strict=True)]
        epigraphs = np.zeros((len(self.offsets), width))
        epigraphs[:, 0] = 1.0
        epigraphs[:, self.size:] = -np.eye(len(self.offsets))
        norms = []
        for i, s in enumerate(self.offsets):
            J = np.zeros((1 + s, width))
            J[0, self.size + i] = 1.0
            J[1:, self.offsets[s] + s * (s + 1) // 2:][:, :s] = np.eye(s)
            norms.append((J, np.zeros(1 + s), clarabel.SecondOrderConeT(1 + s)))
        return (np.eye(1, width)[0],
                [(epigraphs, np.zeros(len(self.offsets)),
                  clarabel.NonnegativeConeT(len(self.offsets)))] + norms + widen + bounds)

    def blocks_of(self, x: np.ndarray) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
        """p_s (symmetric) and y_s (s x 1) of a solution x."""
        p, y = {}, {}
        for s, start in self.offsets.items():
            m = s * (s + 1) // 2
            p[s] = np.einsum("k,kij->ij", x[start:start + m], _symmetric_basis(s)[0])
            y[s] = x[start + m:start + m + s].reshape(s, 1)
        return p, y


def _solve(program: tuple[np.ndarray, list[Cone]], rho: float, objective: str
           ) -> tuple[np.ndarray, float, str]:
    """Solve ``min q^T x`` s.t. ``J x + F0`` in each cone with Clarabel; return x, the solve
    time and the status (:data:`CLARABEL_STATUS`), or raise LMIError.

    An ``optimal_inaccurate`` result is kept and reported: the numpy certificate, not the
    solver's status, decides whether it is used.
    """
    q, constraints = program
    J = np.vstack([c[0] for c in constraints])
    F0 = np.concatenate([c[1] for c in constraints])
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(F0))):
        raise LMIError(f"the LMI's data are not finite (rho = {rho}, objective {objective})")
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    for name, value in SOLVER_OPTIONS.items():
        setattr(settings, name, value)
    solver = clarabel.DefaultSolver(scipy.sparse.csc_matrix((len(q), len(q))), q,
                                    scipy.sparse.csc_matrix(-J), F0,
                                    [c[2] for c in constraints], settings)
    solution = solver.solve()
    status = CLARABEL_STATUS.get(str(solution.status))
    if status is None:
        raise LMIError(f"LMI solver status {solution.status} (rho = {rho}, objective {objective})")
    return np.asarray(solution.x), float(solution.solve_time), status


def _worse(first: str, second: str) -> str:
    """The less accurate of two accepted statuses (``optimal`` or ``optimal_inaccurate``)."""
    return "optimal" if first == second == "optimal" else "optimal_inaccurate"


def _sym(M: cp.Expression) -> cp.Expression:
    return 0.5 * (M + M.T)


def _solve_problem(problem: cp.Problem, rho: float, objective: str) -> None:
    """Solve a cvxpy problem with Clarabel, or raise LMIError (an ``optimal_inaccurate``
    result is kept: the numpy certificate decides)."""
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Solution may be inaccurate")
            problem.solve(solver=cp.CLARABEL, **SOLVER_OPTIONS)
    except (cp.SolverError, ValueError) as exc:  # ValueError: cvxpy's non-finite data check
        raise LMIError(f"Clarabel failed (rho = {rho}, objective {objective}): {exc}") from exc
    if problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        raise LMIError(
            f"LMI solver status {problem.status!r} (rho = {rho}, objective {objective})"
        )


def certify_gain_lmi(
    H: np.ndarray, G: np.ndarray, rho: float, margin: float = LMI_MARGIN
) -> np.ndarray:
    """Find a Lyapunov matrix P for a given closed-loop matrix H (a gain fixed beforehand).

    Solves sym(P (H + rho G)) <= -margin P, sym(P G) >= margin P, I <= P <= kappa I with kappa
    minimal. Used to certify published gains.

    Parameters
    ----------
    H : numpy.ndarray
        Closed-loop matrix (e.g. bar_A0 + bar_L bar_C).
    G : numpy.ndarray
        Generator.
    rho : float
        Decay parameter.
    margin : float
        Margin on the strict inequalities.

    Returns
    -------
    numpy.ndarray
        P.

    Raises
    ------
    LMIError
        If no such P exists.
    """
    N = H.shape[0]
    P, kappa = cp.Variable((N, N), symmetric=True), cp.Variable()
    constraints = [
        _sym(P @ (H + rho * G)) << -margin * P,
        _sym(P @ G) >> margin * P,
        P >> np.eye(N),
        P << kappa * np.eye(N),
    ]
    _solve_problem(cp.Problem(cp.Minimize(kappa), constraints), rho,
                   "certificate of a given gain")
    return 0.5 * (P.value + P.value.T)
