"""Independent reference computations shared by the tests (scipy only, no fhobs)."""

from __future__ import annotations

import numpy as np
import scipy.linalg


def zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order hold of ``dx/dt = A x + B u`` over ``dt``: ``(Phi, Gamma)`` with
    ``x+ = Phi x + Gamma u``, both blocks of scipy's expm of the augmented matrix
    ``dt [[A, B], [0, 0]]``."""
    n, m = B.shape
    block = scipy.linalg.expm(dt * np.block([[A, B], [np.zeros((m, n + m))]]))
    return block[:n, :n], block[:n, n:]


def relative(a: np.ndarray, b: np.ndarray) -> float:
    """``max |a - b| / max |b|``: the largest difference relative to the reference b."""
    return float(np.max(np.abs(np.asarray(a) - b)) / np.max(np.abs(b)))
