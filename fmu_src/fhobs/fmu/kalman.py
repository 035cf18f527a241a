"""pythonfmu slave of ``kalman.fmu``: the steady-state discrete Kalman filter baseline.

One cycle per sample time Ts: measurement update with the gain ``kalman_gain``, prediction with
the exact ZOH of the (extended) model (:mod:`fhobs.core.kalman_filter`). A communication step of
any size runs the cycles whose sample instants fall inside it and holds the estimate between
samples. Shipped in the FMU by :mod:`fhobs.build` like ``observer.py``.
"""

from __future__ import annotations

import numpy as np

from ..core.disturbance import extended_model
from ..core.kalman_filter import KalmanObserver
from ..core.linalg import expm
from .kinds import KINDS
from .slave_base import ObserverSlave, positive_parameter


class FhobsKalman(ObserverSlave):
    """Kalman filter; its error map Phi (I - M C) must stay Schur stable when parameters are
    edited."""

    kind = KINDS["kalman"]

    def _check_timing(self) -> None:
        positive_parameter(self, "Ts", "sample time Ts")

    def _check_gains(self) -> None:
        design = self.edited_design()
        kalman = design.kalman
        A, _, C = extended_model(design.A, design.B, design.C, design.E,
                                 kalman.disturbance_order)
        Phi = expm(kalman.sample_time * A)
        radius = float(np.max(np.abs(np.linalg.eigvals(Phi - Phi @ kalman.gain @ C))))
        if not radius < 1.0:
            raise ValueError(
                f"check schur_kalman failed: spectral radius of Phi (I - M C) = {radius:.6g} "
                "(required < 1)"
            )

    def _make_model(self) -> KalmanObserver:
        design = self.edited_design()
        return KalmanObserver(design, z0=self._padded_z0(), kalman=design.kalman)
