"""pythonfmu slave of ``prescribed_time.fmu``: the prescribed-time observer (Theorem 1).

Shipped in the FMU by :mod:`fhobs.build` like ``observer.py``.

The start of ``xi`` is given as the prescribed time ``T0`` (parameter, default 1 s) rather
than as ``xi0``: T0 is what a user chooses (the instant from which the nominal estimate is
exact), while the xi0 giving it depends on nu and rho; with T0 as the parameter an edited rho
keeps the convergence time and changes xi0, which is derived at initialisation as
``xi0 = (-nu rho T0)^(-1/nu)`` (:func:`fhobs.core.runtime.prescribed_xi0`) and is the first
value of the output ``xi``.
"""

from __future__ import annotations

from ..core.runtime import prescribed_xi0
from .kinds import KINDS
from .slave_base import ObserverSlave, positive_parameter


class FhobsPrescribedTime(ObserverSlave):
    """Prescribed-time observer with Theorem 1's certificate re-checked at initialisation."""

    kind = KINDS["prescribed_time"]

    def _check_gains(self) -> None:
        """The certificate, then T0: ValueError naming T0 if it gives no xi0."""
        prescribed_time = self.edited_record()
        self.kind.certificate(prescribed_time)
        prescribed_xi0(positive_parameter(self, "T0", "prescribed time T0"),
                       prescribed_time.model.nu, prescribed_time.rho)
