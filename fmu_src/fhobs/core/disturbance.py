"""Extended-state model: the observer also estimates the perturbation q.

With ``disturbance_order = r >= 1`` the observer does not treat ``E q`` as an unknown input but
models q as a polynomial in time of degree r - 1 (``q^(r) = 0``, an extended-state observer):
its internal model has the state ``(x, q, dq/dt, ..., q^(r-1))`` and the matrices

    A_model = [[A, E, 0, ...], [0, 0, I, ...], ..., [0, ..., 0]],  B_model = [B; 0],
    C_model = [C, 0].

Everything of the paper (homogenisation, LMIs, the observer itself) is applied to this model
unchanged; the estimate of x is the first n entries of the observer's state, the rest estimate
q and its derivatives. A slowly varying q is then estimated instead of being fought by high gain,
which is what lets the observer filter measurement noise harder at equal perturbed accuracy.
The unknown input of the model is ``q^(r)``, entering through ``E_model = [0; ...; 0; I]``.

This module is numpy-only: it runs inside the FMUs.
"""

from __future__ import annotations

import numpy as np


def extended_model(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, E: np.ndarray | None, order: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The observer's model ``(A_model, B_model, C_model)`` (the module docstring).

    Parameters
    ----------
    A, B, C : numpy.ndarray
        Plant matrices (n x n, n x m, k x n).
    E : numpy.ndarray or None
        Perturbation input matrix (n x r_q); required when ``order >= 1``.
    order : int
        Disturbance order r >= 0 (0: the plant itself).

    Returns
    -------
    tuple of numpy.ndarray
        ``A_model`` ((n + r r_q) square), ``B_model``, ``C_model``.

    Examples
    --------
    A double integrator with a constant perturbation on its second state (order 1):

    >>> A = np.array([[0.0, 1.0], [0.0, 0.0]])
    >>> B = E = np.array([[0.0], [1.0]])
    >>> C = np.array([[1.0, 0.0]])
    >>> A_model, B_model, C_model = extended_model(A, B, C, E, order=1)
    >>> A_model.tolist()
    [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]
    >>> B_model.ravel().tolist(), C_model.tolist()
    ([0.0, 1.0, 0.0], [[1.0, 0.0, 0.0]])
    """
    if order == 0:
        return A, B, C
    if E is None:
        raise ValueError("a disturbance model (disturbance_order >= 1) needs E")
    n, p = E.shape
    size = n + order * p
    A_model = np.zeros((size, size))
    A_model[:n, :n] = A
    A_model[:n, n:n + p] = E
    for j in range(order - 1):
        rows = slice(n + j * p, n + (j + 1) * p)
        A_model[rows, n + (j + 1) * p:n + (j + 2) * p] = np.eye(p)
    B_model = np.vstack([B, np.zeros((order * p, B.shape[1]))])
    C_model = np.hstack([C, np.zeros((C.shape[0], order * p))])
    return A_model, B_model, C_model


def model_perturbation_matrix(n: int, p: int, order: int) -> np.ndarray:
    """``E_model``: where the model's unknown input ``q^(order)`` enters (order >= 1)."""
    E_model = np.zeros((n + order * p, p))
    E_model[-p:] = np.eye(p)
    return E_model


def model_state_names(n: int, p: int, order: int) -> list[str]:
    """Names of the extended model's states: ``x[1]..x[n]``, then q and its derivatives per
    component (``q[1]``, ``q[1]'``, ``q[1]''``; one block of p per derivative).

    Examples
    --------
    >>> model_state_names(2, 1, 2)
    ['x[1]', 'x[2]', 'q[1]', "q[1]'"]
    """
    return [f"x[{i + 1}]" for i in range(n)] + [
        f"q[{i + 1}]" + "'" * j for j in range(order) for i in range(p)
    ]


MAX_TERMS = 8
"""The most terms :func:`describe_direction` writes out (the rest are counted)."""


def describe_direction(vector: np.ndarray, names: list[str], digits: int = 3) -> str:
    """A direction of the state space as a readable combination of named states, rounded to
    ``digits`` significant digits of its largest entry (entries below that are left out; past
    :data:`MAX_TERMS` terms, counted).

    Examples
    --------
    >>> describe_direction(np.array([0.0, 1.0, -0.5]), ["x[1]", "x[2]", "q[1]"])
    'x[2] - 0.5 q[1]'
    >>> describe_direction(np.array([0.0, -2.0, 0.0]), ["x[1]", "x[2]", "q[1]"])
    'x[2]'
    >>> describe_direction(np.ones(10), [f"x[{i}]" for i in range(1, 11)])
    'x[1] + x[2] + x[3] + x[4] + x[5] + x[6] + x[7] + x[8] + 2 more terms'
    """
    vector = np.asarray(vector, dtype=float)
    vector = vector / vector[int(np.argmax(np.abs(vector)))]  # largest entry 1
    terms = []
    for value, name in zip(vector, names, strict=True):
        value = float(f"{value:.{digits}g}")
        if abs(value) < 10.0 ** -digits:
            continue
        size = "" if abs(value) == 1.0 else f"{abs(value):g} "
        sign = "-" if value < 0 else "+"
        terms.append(f"{sign} {size}{name}")
    if len(terms) > MAX_TERMS:
        terms = terms[:MAX_TERMS] + [f"+ {len(terms) - MAX_TERMS} more terms"]
    text = " ".join(terms)
    return text[2:] if text.startswith("+ ") else "-" + text[2:]
