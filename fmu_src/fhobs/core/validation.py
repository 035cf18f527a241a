"""Checks of the values a model is stepped with: finite vectors, step sizes, arithmetic failures.

Shared by the plant, the observers and the Kalman filter; numpy-only.
"""

from __future__ import annotations

import math

import numpy as np


def as_finite_vector(value: np.ndarray | float, size: int, name: str) -> np.ndarray:
    """Return ``value`` as a finite float vector of length ``size``, else raise ValueError."""
    vec = np.asarray(value, dtype=float).reshape(-1)
    if vec.size != size:
        raise ValueError(f"{name} must have {size} entries, got {vec.size}")
    if not all_finite(vec):
        raise ValueError(f"{name} must be finite, got {vec}")
    return vec


def all_finite(vec: np.ndarray) -> bool:
    """Whether every entry of a (small) 1-D float array is finite; faster than
    ``np.isfinite(vec).all()`` for the few entries of a runtime state."""
    return all(map(math.isfinite, vec.tolist()))


def floating_point_failure(step: str, err: ArithmeticError) -> ValueError:
    """The ValueError of a ``step`` (its name, e.g. ``"plant"``) that raised an arithmetic
    error: numpy's under the caller's ``np.errstate(all="raise")``, or Python's math."""
    return ValueError(f"the {step} step failed with a floating-point error ({err}); "
                      "state left unchanged")


def check_step_size(dt: float) -> float:
    """Return dt as a float if it is finite and positive, else raise ValueError."""
    dt = float(dt)
    if not (dt > 0.0 and math.isfinite(dt)):
        raise ValueError(f"the step size must be finite and positive, got {dt}")
    return dt
