"""pythonfmu slave of ``plant.fmu``: the LTI plant with reproducible measurement noise.

dx/dt = A x + B u + E q, y = C x + eta, with eta uniform in [-a, a], a function of
(noise_seed, step index) only. Shipped in the FMU by :mod:`fhobs.build` like ``observer.py``.
"""

from __future__ import annotations

import numpy as np

from ..core.plant import PLANT_SCHEMES
from .call_rules import MAX_STEP_INDEX
from .kinds import KINDS
from .slave_base import FhobsSlave, zoh_problem


class FhobsPlant(FhobsSlave):
    """The plant of the spec, stepped exactly (zero-order hold) by the numpy runtime."""

    kind = KINDS["plant"]

    def _check_parameters(self) -> None:
        """LTIPlant itself rejects a negative noise amplitude or seed (ValueError)."""
        self.choice("scheme", PLANT_SCHEMES)

    def _step_problem(self, step_size: float) -> str:
        """The exact ZOH over the step must be computable to some digits."""
        return zoh_problem(self._arrays["A"], step_size, "the plant")

    def _model_state_problem(self, model_state: np.ndarray) -> str:
        """The step index k (the state's last entry) is a whole number in
        ``[0, MAX_STEP_INDEX)``."""
        k = float(model_state[-1])
        if k.is_integer() and 0.0 <= k < MAX_STEP_INDEX:
            return ""
        return (f"its step index k = {k!r} is not a whole number in [0, {MAX_STEP_INDEX}) (the "
                "plant's noise sample)")
