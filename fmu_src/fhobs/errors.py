"""The exceptions of fhobs, one module for all.

Each message names the item at fault and the reason, in one paragraph (the command-line tools
print it and exit with code 2).

Examples
--------
>>> from fhobs.errors import SpecError
>>> issubclass(SpecError, ValueError)
True
"""

from __future__ import annotations

from .core.errors import CertificateError


class SpecError(ValueError):
    """A plant specification is malformed; the message names the field and the reason."""


class LMIError(RuntimeError):
    """The solver found no solution (infeasible, or numerical failure)."""


class KalmanDesignError(ValueError):
    """The Kalman filter cannot be designed (bad argument, no accurate stabilising Riccati
    solution)."""


class BuildError(RuntimeError):
    """The FMUs cannot be built (missing tool, another platform...)."""


__all__ = ["BuildError", "CertificateError", "KalmanDesignError", "LMIError", "SpecError"]
