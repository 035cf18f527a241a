"""The FMI co-simulation states a slave tracks and the status it reports to the wrapper."""

from __future__ import annotations

from pythonfmu.enums import Fmi2Status

STATUS_VALUE_REFERENCE = 0
STATUS_OK = int(Fmi2Status.ok)
STATUS_ERROR = int(Fmi2Status.error)

INSTANTIATED, INITIALISATION, STEP_MODE, TERMINATED = (
    "instantiated", "initialisation mode", "step mode", "terminated",
)
MODES = (INSTANTIATED, INITIALISATION, STEP_MODE, TERMINATED)
"""The FMI 2.0 co-simulation states a slave tracks (``fmi2Reset`` creates a new slave)."""
