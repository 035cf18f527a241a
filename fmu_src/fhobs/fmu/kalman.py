"""pythonfmu slave of ``kalman.fmu``: the steady-state discrete Kalman filter baseline.

One cycle per sample time Ts: measurement update with the gain ``kalman_gain``, prediction with
the exact ZOH of the (extended) model (:mod:`fhobs.core.kalman_filter`). A communication step of
any size runs the cycles whose sample instants fall inside it and holds the estimate between
samples. Shipped in the FMU by :mod:`fhobs.build` like ``observer.py``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.disturbance import extended_model
from ..core.gains import KalmanGains
from ..core.kalman_filter import KalmanObserver
from ..core.linalg import expm
from .slave_base import ObserverSlave, positive_parameter


class FhobsKalman(ObserverSlave):
    """Kalman filter; its error map Phi (I - M C) must stay Schur stable when parameters are
    edited."""

    description = "Steady-state discrete Kalman filter (exact ZOH model, disturbance model)"

    def _declare_gains(self) -> None:
        kalman = self.design.kalman
        if kalman is None:
            raise ValueError("the design record has no Kalman filter (its 'kalman' is null)")
        # N: states of the filter's model (n, or n + r q-states with a disturbance model)
        self.add_array("kalman_gain", kalman.gain, "parameter",
                       "measurement-update gain M = P C^T (C P C^T + R)^-1 (N x k)")
        self._declare_q_hat()

    def _model_size(self) -> int:
        """States of the filter's model (its own disturbance model, which may differ from the
        homogeneous observer's)."""
        return self.design.kalman.gain.shape[0]

    def _declare_timing(self) -> None:
        self.add_array("Ts", self.design.kalman.sample_time, "parameter",
                       "sample time of the filter (s): one cycle per sample instant inside a step")

    def _check_timing(self) -> None:
        positive_parameter(self, "Ts", "sample time Ts")

    def _kalman(self) -> KalmanGains:
        """The design's Kalman record with the current ``kalman_gain`` and ``Ts``."""
        return dataclasses.replace(self.design.kalman, gain=self.array("kalman_gain"),
                                   sample_time=float(self.array("Ts")))

    def _check_gains(self) -> None:
        design, kalman = self.edited_design(), self._kalman()
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
        return KalmanObserver(self.edited_design(), z0=self._padded_z0(), kalman=self._kalman())

    def _output_layout(self) -> list[str]:
        """The model state z = (x_hat, q_hat) (no q_hat without a disturbance model)."""
        return self._state_layout()

    def _model_outputs(self) -> list[float]:
        """``[x_hat, q_hat]``: the model state z (the prediction for the next sample)."""
        return self.model.z.tolist()
