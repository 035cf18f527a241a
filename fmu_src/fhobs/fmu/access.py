"""Which get/set calls a slave accepts now: known value references of the right type, no
write to an output or to ``status``, parameters fixed after initialisation."""

from __future__ import annotations

from collections.abc import Sequence

from pythonfmu import Boolean, Fmi2Causality, Integer, Real, String

from .call_rules import ACCESS_MESSAGES
from .modes import INITIALISATION, INSTANTIATED

ACCESS_FUNCTIONS = (
    ("fmi2GetReal", Real), ("fmi2SetReal", Real), ("fmi2GetInteger", Integer),
    ("fmi2SetInteger", Integer), ("fmi2GetBoolean", Boolean), ("fmi2SetBoolean", Boolean),
    ("fmi2GetString", String), ("fmi2SetString", String),
)
"""The get/set functions by the code the wrapper passes (``FHOBS_GET_REAL`` ...), with the
variable type each one serves."""


class AccessRules:
    """The access checks of :class:`fhobs.fmu.slave_base.FhobsSlave` (a mixin)."""

    def _access_problem(self, function: str, vrs: Sequence[int]) -> str:
        """Why ``function`` (``fmi2GetReal``, ``fmi2SetInteger``...) may not be applied to the
        value references ``vrs`` now ('' if it may): unknown reference, another type, or a
        write to an output, to ``status`` or to a parameter after initialisation."""
        kind = dict(ACCESS_FUNCTIONS)[function]
        for vr in vrs:
            var = self.vars.get(vr)
            if var is None:
                return ACCESS_MESSAGES["unknown"] % (function, vr, len(self.vars) - 1)
            if not isinstance(var, kind):
                return ACCESS_MESSAGES["type"] % (function, var.name, vr, type(var).__name__,
                                                  kind.__name__)
            if not function.startswith("fmi2Set"):
                continue
            if var.causality == Fmi2Causality.output:
                return ACCESS_MESSAGES["output"] % (function, var.name, vr)
            if var.causality == Fmi2Causality.local:
                return ACCESS_MESSAGES["local"] % (function, var.name, vr)
            if var.causality == Fmi2Causality.parameter and self._mode not in (
                INSTANTIATED, INITIALISATION
            ):
                return ACCESS_MESSAGES["fixed"] % (function, var.name, vr, self._mode)
        return ""

    def _checked_access(self, function: str, vrs: Sequence[int]) -> None:
        """Refuse a get/set call that :meth:`_access_problem` rejects (ValueError, which
        pythonfmu answers with fmi2Fatal: only reached without the wrapper)."""
        problem = self._access_problem(function, vrs)
        if problem:
            self._fail(problem)
            raise ValueError(problem)
