"""pythonfmu slave of ``supervised.fmu``: the supervised observer (:mod:`fhobs.core.supervisor`).

The filtering homogeneous observer and a Kalman filter of its model run on the same (y, u); an
innovation test with hysteresis and dwell picks the estimate output (``mode``). A communication
step must be a whole number of the Kalman filter's sample times Ts: each sample adds one
innovation to the statistic. Shipped in the FMU by :mod:`fhobs.build` like ``observer.py``.
"""

from __future__ import annotations

from ..core.supervisor import sample_count
from .kinds import KINDS
from .slave_base import ObserverSlave, positive_parameter


class FhobsSupervised(ObserverSlave):
    """Supervised observer; its thresholds and both parts' certificates are checked again
    when parameters are edited."""

    kind = KINDS["supervised"]

    def _check_timing(self) -> None:
        super()._check_timing()
        positive_parameter(self, "Ts", "sample time Ts")

    def _step_problem(self, step_size: float) -> str:
        """The Kalman filter's rule (a whole number of samples Ts), then the ZOH check."""
        try:
            sample_count(step_size, float(self.array("Ts")))
        except ValueError as err:
            return str(err).removesuffix("; state left unchanged")
        return super()._step_problem(step_size)
