"""pythonfmu slave of ``kalman.fmu``: the steady-state discrete Kalman filter baseline.

One cycle per sample time Ts: measurement update with the gain ``kalman_gain``, prediction with
the exact ZOH of the (extended) model (:mod:`fhobs.core.kalman_filter`). A communication step of
any size runs the cycles whose sample instants fall inside it and holds the estimate between
samples. Shipped in the FMU by :mod:`fhobs.build` like ``observer.py``.
"""

from __future__ import annotations

import numpy as np

from .kinds import KINDS
from .slave_base import ObserverSlave, positive_parameter


class FhobsKalman(ObserverSlave):
    """Kalman filter; its error map Phi (I - M C) must stay Schur stable when parameters are
    edited."""

    kind = KINDS["kalman"]

    def _check_timing(self) -> None:
        positive_parameter(self, "Ts", "sample time Ts")

    def _model_state_problem(self, model_state: np.ndarray) -> str:
        """The offset to the next sample (the state's last entry) is in ``[0, Ts)``."""
        offset, ts = float(model_state[-1]), float(self.array("Ts"))
        if 0.0 <= offset < ts:
            return ""
        return (f"its Kalman filter's offset to the next sample {offset!r} is not in "
                f"[0, Ts = {ts!r})")
