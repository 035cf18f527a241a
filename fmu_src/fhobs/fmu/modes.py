"""The FMI co-simulation states a slave tracks and the status it reports to the wrapper."""

from __future__ import annotations

from pythonfmu.enums import Fmi2Status

from .call_rules import STATES

STATUS_VALUE_REFERENCE = 0
STATUS_OK = int(Fmi2Status.ok)
STATUS_WARNING = int(Fmi2Status.warning)
STATUS_ERROR = int(Fmi2Status.error)

MODES = STATES
"""The FMI 2.0 co-simulation states a slave tracks (``fmi2Reset`` creates a new slave), in the
order of :data:`fhobs.fmu.call_rules.STATES` (the code the status wrapper reads)."""
INSTANTIATED, INITIALISATION, STEP_MODE, TERMINATED = MODES
