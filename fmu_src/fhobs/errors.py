"""The exceptions of fhobs, one module for all.

Each message names the item at fault and the reason, in one paragraph (the command-line tools
print it and exit with code 2).

Examples
--------
>>> from fhobs.errors import FhobsError, SpecError
>>> issubclass(SpecError, FhobsError) and issubclass(SpecError, ValueError)
True
"""

from __future__ import annotations

from .core.errors import CertificateError, FhobsError


class SpecError(FhobsError, ValueError):
    """A plant specification is malformed; the message names the field and the reason."""


class LMIError(FhobsError, RuntimeError):
    """The solver found no solution (infeasible, or numerical failure)."""


class KalmanDesignError(FhobsError, ValueError):
    """The Kalman filter cannot be designed (bad argument, no accurate stabilising Riccati
    solution)."""


class BuildError(FhobsError, RuntimeError):
    """The FMUs cannot be built (missing tool, another platform...)."""


__all__ = ["BuildError", "CertificateError", "FhobsError", "KalmanDesignError", "LMIError",
           "SpecError"]
