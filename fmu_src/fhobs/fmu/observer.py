"""pythonfmu slave of ``observer.fmu``: the filtering homogeneous observer (Theorem 2).

Shipped in the FMU by :mod:`fhobs.build` (with :mod:`fhobs.core`), which subclasses it under a
build-unique name.
"""

from __future__ import annotations

from ..core.certificate import certify_filtering
from ..core.runtime import FilteringObserver
from .kinds import KINDS
from .slave_base import ObserverSlave


class FhobsObserver(ObserverSlave):
    """Filtering homogeneous observer with its certificate re-checked at initialisation."""

    kind = KINDS["observer"]

    def _check_gains(self) -> None:
        certify_filtering(self.edited_record())

    def _make_model(self) -> FilteringObserver:
        return FilteringObserver(
            self.edited_record(),
            h=float(self.array("h")),
            scheme=self.scheme_name(),
            z0=self._padded_z0(),
            psi0=self.array("psi0"),
            xi0=float(self.array("xi0")),
        )
