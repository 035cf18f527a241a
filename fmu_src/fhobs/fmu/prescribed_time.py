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

from ..core.certificate import certify_prescribed_time
from ..core.runtime import PrescribedTimeObserver, prescribed_xi0
from .slave_base import ObserverSlave, positive_parameter


class FhobsPrescribedTime(ObserverSlave):
    """Prescribed-time observer with Theorem 1's certificate re-checked at initialisation."""

    description = ("Prescribed-time observer (Ping, Zimenko, Polyakov, Efimov), Theorem 1: "
                   "nominal convergence at T0")

    def _declare_gains(self) -> None:
        design = self.design
        # N: states of the observer's model (n, or n + r q-states with a disturbance model)
        for name, text in (
            ("L0", "homogenisation gain, A0 = A_model + L0 C_model nilpotent (N x k)"),
            ("G_d", "dilation generator of Theorem 2; Theorem 1 uses G_d - nu I (N x N)"),
            ("L_pt", "gain of the prescribed-time injection (N x k)"),
            ("P_pt", "Lyapunov matrix of the Theorem 1 LMI (N x N)"),
        ):
            self.add_array(name, getattr(design, name), "parameter", text)
        self.add_array("nu", design.nu, "parameter", "homogeneity degree")
        self.add_array("rho", design.rho, "parameter", "decay parameter of the xi equation")
        self.add_array("T0", self.config["T0"], "parameter",
                       "prescribed convergence time (s); xi0 = (-nu rho T0)^(-1/nu)")
        self.add_array("xi", 0.0, "output", "scalar gain state xi (0 from T0 on)")
        self._declare_q_hat()

    def _check_gains(self) -> None:
        design = self.edited_design()
        certify_prescribed_time(design)
        self._xi0(design.nu, design.rho)

    def _xi0(self, nu: float, rho: float) -> float:
        """xi0 of the parameter T0; ValueError naming T0 if it gives none."""
        return prescribed_xi0(positive_parameter(self, "T0", "prescribed time T0"), nu, rho)

    def _make_model(self) -> PrescribedTimeObserver:
        design = self.edited_design()
        return PrescribedTimeObserver(
            design,
            h=float(self.array("h")),
            scheme=self.scheme_name(),
            z0=self._padded_z0(),
            xi0=self._xi0(design.nu, design.rho),
        )

    def _output_layout(self) -> list[str]:
        """The model state ``[z, xi]``, z = (x_hat, q_hat) (no q_hat without a disturbance
        model)."""
        return [*self._state_layout(), "xi"]

    def _model_outputs(self) -> list[float]:
        """``[x_hat, q_hat, xi]``: the model state."""
        return self.model.get_state().tolist()
