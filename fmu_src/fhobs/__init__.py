"""fhobs: the filtering homogeneous observer (Ping, Zimenko, Polyakov, Efimov) for FMI 2.0.

Import the submodules you need; only ``gains``, ``certificate``, ``runtime`` and ``plant`` (and
their helpers) are numpy-only and run inside the FMUs.
"""

__version__ = "0.1.0"
