"""fhobs: the filtering homogeneous observer (Ping, Zimenko, Polyakov, Efimov) for FMI 2.0.

The main functions are available here: :func:`design_observer` (a plant as arrays -> a certified
design), :func:`load_spec` (a plant spec file), :func:`design_for_spec`, :func:`certify` and
:func:`build_fmus`, and :class:`FhobsError` (the base of every exception) with
:class:`SpecError`; they are imported on first use, so ``import fhobs`` stays light.
:mod:`fhobs.core` is numpy-only and runs inside the FMUs (with the slave classes of
:mod:`fhobs.fmu`).

Examples
--------
>>> import fhobs
>>> gains = fhobs.design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
>>> gains.n_tilde
2
"""

from importlib import import_module

__version__ = "0.1.0"

_PUBLIC = {
    "design_observer": "fhobs.design",
    "design_for_spec": "fhobs.design",
    "load_spec": "fhobs.spec",
    "certify": "fhobs.core.certificate",
    "build_fmus": "fhobs.build",
    "FhobsError": "fhobs.errors",
    "SpecError": "fhobs.errors",
}
__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    """The public functions, imported from their modules on first use."""
    if name not in _PUBLIC:
        raise AttributeError(f"module 'fhobs' has no attribute {name!r}")
    return getattr(import_module(_PUBLIC[name]), name)
