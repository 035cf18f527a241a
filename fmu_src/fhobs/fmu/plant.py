"""pythonfmu slave of ``plant.fmu``: the LTI plant with reproducible measurement noise.

dx/dt = A x + B u + E q, y = C x + eta, with eta uniform in [-a, a], a function of
(noise_seed, step index) only. Shipped in the FMU by :mod:`fhobs.build` like ``observer.py``.
"""

from __future__ import annotations

import numpy as np

from ..core.plant import PLANT_SCHEMES, LTIPlant
from .slave_base import FhobsSlave, zoh_problem


class FhobsPlant(FhobsSlave):
    """The plant of the spec, stepped exactly (zero-order hold) by the numpy runtime."""

    description = "LTI plant dx/dt = A x + B u + E q, y = C x + noise"

    def _declare(self) -> None:
        design, config = self.design, self.config
        self.add_array("A", design.A, "parameter", "state matrix (n x n)")
        self.add_array("B", design.B, "parameter", "input matrix (n x m)")
        self.add_array("C", design.C, "parameter", "output matrix (k x n)")
        if design.E is not None:
            self.add_array("E", design.E, "parameter", "perturbation matrix (n x r)")
        self.add_array("x0", config["x0"], "parameter", "initial state")
        self.add_array(
            "noise_amplitude", config["noise_amplitude"], "parameter",
            "measurement noise is uniform in [-noise_amplitude, noise_amplitude]",
        )
        self.add_integer("noise_seed", config["noise_seed"], "seed of the measurement noise")
        self.add_integer(
            "scheme",
            PLANT_SCHEMES.index(config["plant_scheme"]),
            "plant step: " + ", ".join(f"{i} = {s}" for i, s in enumerate(PLANT_SCHEMES)),
        )
        self.add_array("u", np.zeros(design.m), "input", "control input")
        if design.E is not None:
            self.add_array("q", np.zeros(design.E.shape[1]), "input", "perturbation (through E)")
        self.add_array("y", np.zeros(design.k), "output", "measured output C x + noise")
        self.add_array("x", np.zeros(design.n), "output", "true state")

    def _check_parameters(self) -> None:
        """LTIPlant itself rejects a negative noise amplitude or seed (ValueError)."""
        self.choice("scheme", PLANT_SCHEMES)

    def _step_problem(self, step_size: float) -> str:
        """The exact ZOH over the step must be computable to some digits."""
        return zoh_problem(self._arrays["A"], step_size, "the plant")

    def _make_model(self) -> LTIPlant:
        return LTIPlant(
            self.array("A"),
            self.array("B"),
            self.array("C"),
            E=self.array("E") if "E" in self._arrays else None,
            x0=self.array("x0"),
            noise_amplitude=float(self.array("noise_amplitude")),
            seed=self.integer("noise_seed"),
            scheme=self.choice("scheme", PLANT_SCHEMES),
        )

    def _model_step_arguments(self) -> tuple[np.ndarray, np.ndarray | None]:
        """``(u, q)``; q is None without a perturbation input (``LTIPlant.advance`` takes it so)."""
        return self._arrays["u"], self._arrays.get("q")

    def _model_outputs(self) -> list[float]:
        """``[y, x]`` (declaration order)."""
        model = self.model
        return model.y.tolist() + model.x.tolist()
