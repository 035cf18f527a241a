"""pythonfmu slave of ``observer.fmu``: the filtering homogeneous observer (Theorem 2).

Shipped in the FMU by :mod:`fhobs.build` (with :mod:`fhobs.core`), which subclasses it under a
build-unique name.
"""

from __future__ import annotations

import numpy as np

from ..core.certificate import certify, check_tuning
from ..core.runtime import FilteringObserver
from .slave_base import ObserverSlave


class FhobsObserver(ObserverSlave):
    """Filtering homogeneous observer with the certificate re-checked at initialisation."""

    description = "Filtering homogeneous observer (Ping, Zimenko, Polyakov, Efimov), Theorem 2"

    def _declare_gains(self) -> None:
        design, config = self.design, self.config
        # N: states of the observer's model (n, or n + r q-states with a disturbance model)
        for name, text in (
            ("L0", "homogenisation gain, A0 = A_model + L0 C_model nilpotent (N x k)"),
            ("G_d", "dilation generator of Theorem 2 (N x N)"),
            ("L_tilde", "gain of the output filter psi (k x k)"),
            ("L", "gain of the estimate z (N x k)"),
            ("P_bar", "Lyapunov matrix of the Theorem 2 LMI ((k+N) x (k+N))"),
        ):
            self.add_array(name, getattr(design, name), "parameter", text)
        self.add_array("nu", design.nu, "parameter", "homogeneity degree")
        self.add_array("gamma", design.gamma, "parameter", "gain of the xi equation")
        self.add_array("rho", design.rho, "parameter", "LMI decay parameter, rho > gamma/2")
        self.add_array("psi0", config["psi0"], "parameter", "initial output-filter state")
        self.add_array("xi0", config["xi0"], "parameter", "initial xi")
        self.add_array("psi", np.zeros(design.k), "output", "output-filter state psi")
        self.add_array("xi", 0.0, "output", "scalar gain state xi")
        self.add_array("sigma", 0.0, "output", "sigma = sqrt(max(xi, |psi|^2 / 2))")
        self._declare_q_hat()

    def _check_gains(self) -> None:
        design = self.edited_design()
        check_tuning(design)
        certify(design)

    def _make_model(self) -> FilteringObserver:
        return FilteringObserver(
            self.edited_design(),
            h=float(self.array("h")),
            scheme=self.scheme_name(),
            z0=self._padded_z0(),
            psi0=self.array("psi0"),
            xi0=float(self.array("xi0")),
        )

    def _output_layout(self) -> list[str]:
        """The model state ``[z, psi, xi]``, z = (x_hat, q_hat), then sigma (no q_hat without a
        disturbance model)."""
        return [*self._state_layout(), "psi", "xi", "sigma"]

    def _model_outputs(self) -> list[float]:
        """``[x_hat, q_hat, psi, xi, sigma]``: the model state, then sigma."""
        model = self.model
        values = model.get_state().tolist()
        values.append(model.sigma)
        return values
