"""State feedback for the closed loops the design predicts and the harness runs: the LQR gain of
a plant (Q = I, R = I), which stabilises every stabilisable (A, B)."""

from __future__ import annotations

import numpy as np
import scipy.linalg


def state_feedback(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The LQR gain ``K = -B^T X`` (Q = I, R = I, X the continuous ARE's solution): A + B K is
    Hurwitz for every stabilisable (A, B).

    Examples
    --------
    >>> K = state_feedback(np.array([[1.0]]), np.array([[1.0]]))
    >>> round(float(K[0, 0]), 6)  # -(1 + sqrt(2))
    -2.414214
    """
    X = scipy.linalg.solve_continuous_are(A, B, np.eye(A.shape[0]), np.eye(B.shape[1]))
    return -B.T @ X
