"""pythonfmu slave of ``luenberger.fmu``: the linear baseline observer.

dz/dt = A z + B u + L_lin (C z - y). Shipped in the FMU by :mod:`fhobs.build` like
``observer.py``.
"""

from __future__ import annotations

from ..core.certificate import certify_luenberger
from ..core.runtime import LuenbergerObserver
from .kinds import KINDS
from .slave_base import ObserverSlave


class FhobsLuenberger(ObserverSlave):
    """Luenberger observer; A + L_lin C must stay Hurwitz when parameters are edited."""

    kind = KINDS["luenberger"]

    def _check_gains(self) -> None:
        certify_luenberger(self.edited_record())

    def _make_model(self) -> LuenbergerObserver:
        return LuenbergerObserver(
            self.edited_record(),
            h=float(self.array("h")),
            scheme=self.scheme_name(),
            z0=self.array("z0"),
        )
