"""The base of every fhobs exception and the one raised by the code inside the FMUs (both
re-exported by :mod:`fhobs.errors`)."""

from __future__ import annotations


class FhobsError(Exception):
    """The base of fhobs' exceptions: a caller catches this one class. Each message names the
    item at fault and the reason, in one paragraph."""


class CertificateError(FhobsError, ValueError):
    """A design fails a check; the message names the check, the value and the bound.

    Attributes
    ----------
    lmi_margin_needed : float
        The largest margin (1/s) that a failed LMI check required (its margin plus its
        rounding allowance), 0 if no LMI check failed: a design may be solved again with a
        larger margin than that.
    """

    def __init__(self, message: str, lmi_margin_needed: float = 0.0) -> None:
        super().__init__(message)
        self.lmi_margin_needed = lmi_margin_needed
