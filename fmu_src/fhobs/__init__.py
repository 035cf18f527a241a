"""fhobs: the filtering homogeneous observer (Ping, Zimenko, Polyakov, Efimov) for FMI 2.0.

Import the submodules you need; :mod:`fhobs.core` is numpy-only and runs inside the FMUs (with
the slave classes of :mod:`fhobs.fmu`).
"""

__version__ = "0.1.0"
