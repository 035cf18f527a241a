"""Homogenisation of (A, C): observability index, G0 and Y0, then L0 and G_d.

The paper (Theorem 1) prints the homogenisation equation as ``G0 A - A G0 + Y0 C = A``; its own
numerical example (the pendulum's published L0 and G_d) solves the equation with the commutator's
sign flipped,

    A G0 - G0 A + Y0 C = A,   C G0 = 0,                                       (H)

and only (H) makes A0 = A + L0 C homogeneous: with the printed sign the identity
A0 G_d = (G_d + nu I) A0 fails by orders of magnitude (checked in the tests). From a solution,

    L0  = -(I + G0)^-1 Y0,      A0 = A + L0 C  (nilpotent),
    G_d = I + nu (G0 + I)       (Theorem 2's form: C G_d = (1 + nu) C).

(H) is linear in (G0, Y0) and can have several solutions when the observability indices differ.
We solve it by the observability staircase (:func:`solve_homogenisation`), in O(n_tilde n^3);
the solution reproduces the paper's pendulum exactly and gives G0 the eigenvalues
0, 1, ..., n_tilde - 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RANK_RTOL = 1e-9


@dataclass(frozen=True)
class Homogenisation:
    """Solution of the homogenisation equation (H) and the derived L0, G_d.

    Attributes
    ----------
    n_tilde : int
        Observability index of (A, C).
    G0 : numpy.ndarray
        The solution's G0 of (H) (its Y0 gives L0).
    L0 : numpy.ndarray
        Homogenisation gain, n x k.
    G_d : numpy.ndarray
        Dilation generator in Theorem 2's form.

    The identities that (H) makes true are checked on the design by
    :func:`fhobs.core.certificate.homogeneity_values`.
    """

    n_tilde: int
    G0: np.ndarray
    L0: np.ndarray
    G_d: np.ndarray


def observability_index(A: np.ndarray, C: np.ndarray) -> tuple[int | None, int]:
    """Observability index of (A, C) and the rank of the observability matrix.

    The subspaces K_j = span(C^T, A^T C^T, ..., (A^T)^(j-1) C^T) are grown with an orthonormal
    basis (:func:`observable_basis`), which stays well conditioned where the plain stacked
    matrix [C; CA; ...] would not.

    Parameters
    ----------
    A : numpy.ndarray
        n x n system matrix.
    C : numpy.ndarray
        k x n output matrix.

    Returns
    -------
    n_tilde : int or None
        Least j with rank [C; CA; ...; CA^(j-1)] = n, or None when (A, C) is unobservable.
    rank : int
        Rank of the observability matrix (dimension of the observable subspace).

    Examples
    --------
    >>> observability_index(np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[1.0, 0.0]]))
    (2, 2)
    >>> observability_index(np.eye(2), np.array([[1.0, 0.0]]))
    (None, 1)
    """
    n_tilde, basis = observable_basis(A, C)
    return n_tilde, basis.shape[1]


def observable_basis(A: np.ndarray, C: np.ndarray) -> tuple[int | None, np.ndarray]:
    """Observability index of (A, C) and an orthonormal basis of the observable subspace
    (the row space of the observability matrix).

    K_(j+1) = K_j + A^T N_j, N_j the directions K_j added to K_(j-1), so each stage
    orthogonalises only A^T N_j against the basis (O(n^2 k) per stage, O(n^3) in all). A is
    first shifted by the mean of its diagonal (the subspaces of A - s I are those of A), so a
    large common diagonal does not swamp the couplings that make the pair observable
    (A = [[1e150, 1], [0, 1e150]], C = [1, 0] is observable).

    Parameters
    ----------
    A : numpy.ndarray
        n x n system matrix.
    C : numpy.ndarray
        k x n output matrix.

    Returns
    -------
    n_tilde : int or None
        Least j with rank [C; CA; ...; CA^(j-1)] = n, or None when (A, C) is unobservable.
    basis : numpy.ndarray
        n x rank, orthonormal columns spanning the observable subspace.

    Examples
    --------
    >>> n_tilde, basis = observable_basis(np.eye(2), np.array([[2.0, 0.0]]))
    >>> n_tilde, basis.ravel().tolist()
    (None, [1.0, 0.0])
    """
    n = A.shape[0]
    A = A - np.trace(A / n) * np.eye(n)
    scale = max(np.linalg.norm(A, 2), 1.0)
    basis = _orth(C.T / max(np.linalg.norm(C, 2), 1e-300))
    newest = basis
    for j in range(1, n + 1):
        if basis.shape[1] == n:
            return j, basis
        candidate = A.T @ newest / scale
        for _ in range(2):  # Gram-Schmidt against the basis, repeated once for orthogonality
            candidate -= basis @ (basis.T @ candidate)
        u, s, _ = np.linalg.svd(candidate, full_matrices=False)
        newest = u[:, s > RANK_RTOL]
        if newest.shape[1] == 0:
            return None, basis
        basis = np.hstack([basis, newest])
    return (n if basis.shape[1] == n else None), basis


def unobservable_directions(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """A basis of the unobservable subspace of (A, C), as readable as possible.

    The orthogonal complement of :func:`observable_basis`, brought to reduced row echelon form
    with partial pivoting (each direction then has a 1 on a state that the others do not
    involve) and rounded to zero below ``1e-9`` of its largest entry, so a direction that is
    one state alone comes out as that unit vector.

    Parameters
    ----------
    A : numpy.ndarray
        n x n system matrix.
    C : numpy.ndarray
        k x n output matrix.

    Returns
    -------
    numpy.ndarray
        n x (n - rank); no columns when (A, C) is observable.

    Examples
    --------
    Two integrators, only the first measured: the second is the unobservable direction.

    >>> unobservable_directions(np.zeros((2, 2)), np.array([[1.0, 0.0]])).ravel().tolist()
    [0.0, 1.0]
    """
    n = A.shape[0]
    _, basis = observable_basis(A, C)
    if basis.shape[1] == n:
        return np.zeros((n, 0))
    u = np.linalg.svd(basis, full_matrices=True)[0]
    rows = u[:, basis.shape[1]:].T.copy()  # (n - rank) x n, orthonormal rows
    for i in range(rows.shape[0]):  # Gauss-Jordan with partial pivoting
        pivot = int(np.argmax(np.abs(rows[i])))
        rows[i] /= rows[i, pivot]
        for r in range(rows.shape[0]):
            if r != i:
                rows[r] -= rows[r, pivot] * rows[i]
    rows[np.abs(rows) < 1e-9 * np.max(np.abs(rows), axis=1, keepdims=True)] = 0.0
    first = [int(np.flatnonzero(row)[0]) for row in rows]
    return rows[np.argsort(first, kind="stable")].T


def _orth(M: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the range of M, rank decided with :data:`RANK_RTOL`."""
    u, s, _ = np.linalg.svd(M, full_matrices=False)
    if s.size == 0 or s[0] == 0.0:
        return u[:, :0]
    return u[:, s > RANK_RTOL * s[0]]


def solve_homogenisation(A: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A solution (G0, Y0) of A G0 - G0 A + Y0 C = A, C G0 = 0, by the observability staircase.

    With the SVD C = U S V^T of rank r and the orthogonal change of coordinates Q = V, the
    constraint C G0 = 0 makes the first r rows of G0' = Q^T G0 Q zero. Writing
    G0' = [[0, 0], [X1, I + Z]] and A' = Q^T A Q = [[A11, A12], [A21, A22]] (blocks r and n-r),
    the last n - r columns of (H) reduce to the same equation for the smaller pair (A22, A12):

        A22 Z - Z A22 + (-X1) A12 = A22,   A12 Z = 0,

    solved recursively (depth n_tilde - 1); the first r columns then give Y0' by a
    least-squares solve against the full-column-rank C Q. Cost O(n_tilde n^3) instead of the
    O(n^6) of the Kronecker form. G0 is block lower-triangular with diagonal blocks
    0, 1, ..., n_tilde - 1 (times I); for the paper's pendulum the solution is unique and equals
    the published one.

    Parameters
    ----------
    A, C : numpy.ndarray
        Plant matrices (n x n, k x n); (A, C) observable.

    Returns
    -------
    G0 : numpy.ndarray
        n x n.
    Y0 : numpy.ndarray
        n x k.

    Raises
    ------
    ValueError
        If a stage of the staircase has no observable direction ((A, C) unobservable).
    """
    return _staircase(A, C)


def _staircase(A: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Recursive step of :func:`solve_homogenisation`."""
    n = A.shape[0]
    U, s, Vt = np.linalg.svd(C)
    r = int(np.sum(s > RANK_RTOL * s[0])) if s.size and s[0] > 0 else 0
    if r == 0:
        raise ValueError("(A, C) is not observable: a staircase stage has no observed direction")
    Q = Vt.T
    A_q = Q.T @ A @ Q
    G0_q = np.zeros((n, n))
    if r < n:
        Z, Y_sub = _staircase(A_q[r:, r:], A_q[:r, r:])
        G0_q[r:, :r] = -Y_sub
        G0_q[r:, r:] = np.eye(n - r) + Z
    C_q = U[:, :r] * s[:r]  # C Q = [C_q, 0], C_q of full column rank r
    Y0_q = (A_q - A_q @ G0_q + G0_q @ A_q)[:, :r] @ np.linalg.pinv(C_q)
    return Q @ G0_q @ Q.T, Q @ Y0_q


def homogenise(A: np.ndarray, C: np.ndarray, nu: float) -> Homogenisation:
    """Compute L0 and G_d for an observable pair (A, C) and a degree nu.

    Parameters
    ----------
    A, C : numpy.ndarray
        Plant matrices.
    nu : float
        Homogeneity degree.

    Returns
    -------
    Homogenisation

    Raises
    ------
    ValueError
        If (A, C) is unobservable or I + G0 is singular.
    """
    n_tilde, rank = observability_index(A, C)
    if n_tilde is None:
        raise ValueError(f"(A, C) is not observable: observability rank {rank} < n = {A.shape[0]}")
    G0, Y0 = solve_homogenisation(A, C)
    eye = np.eye(A.shape[0])
    L0 = -np.linalg.solve(eye + G0, Y0)
    G_d = eye + nu * (G0 + eye)
    return Homogenisation(n_tilde, G0, L0, G_d)


def dilation_basis(G_d: np.ndarray, nu: float, n_tilde: int) -> np.ndarray:
    """Real basis of eigenvectors of G_d, eigenspace by eigenspace (orthonormal within each).

    G_d's eigenvalues are the weights 1 + nu + j nu, j = 0, ..., n_tilde - 1, each with the
    multiplicity of the j-th observability block. Used as the LMI's working coordinates.

    Parameters
    ----------
    G_d : numpy.ndarray
        Dilation generator (Theorem 2's form).
    nu : float
        Homogeneity degree.
    n_tilde : int
        Observability index.

    Returns
    -------
    numpy.ndarray
        n x n invertible matrix V with G_d V = V diag(weights).

    Raises
    ------
    ValueError
        If the eigenspaces do not add up to n (G_d not diagonalisable).
    """
    n = G_d.shape[0]
    weights = 1.0 + nu + nu * np.arange(n_tilde)
    nearest = np.argmin(np.abs(np.linalg.eigvals(G_d)[:, None] - weights[None, :]), axis=1)
    columns = []
    for j, weight in enumerate(weights):
        _, s, vt = np.linalg.svd(G_d - weight * np.eye(n))
        rank = int(np.sum(s > RANK_RTOL * max(s[0], 1.0) * 10.0))
        # a G_d of large norm leaves singular values above the rank threshold's reach: the
        # eigenspace's dimension is then the number of eigenvalues nearest to its weight
        rank = max(rank, n - int(np.sum(nearest == j)))
        columns.append(vt[rank:].T)
    V = np.hstack(columns)
    if V.shape[1] != n or np.linalg.cond(V) > 1e12:
        raise ValueError(
            "G_d is not diagonalisable with the weights 1 + nu + j nu "
            f"(found {V.shape[1]} of {n} eigenvectors)"
        )
    return V
