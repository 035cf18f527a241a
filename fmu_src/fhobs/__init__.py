"""fhobs: the filtering homogeneous observer (Ping, Zimenko, Polyakov, Efimov) for FMI 2.0.

What a user needs is here: the design (:func:`design_observer`: a plant as arrays -> a
certified :class:`ObserverDesign`: the :class:`PlantModel`, the :class:`HomogeneousModel` and one
record per estimator, :class:`FilteringGains`, :class:`PrescribedTimeGains`,
:class:`LuenbergerGains`, :class:`KalmanGains`; :func:`load_spec` and :func:`design_for_spec`
for a plant spec file; :func:`paper_gains`, the paper's published design; :func:`certify`), the
FMUs (:func:`build_fmus`), the runtime estimators the FMUs run (:class:`FilteringObserver`,
:class:`PrescribedTimeObserver`, :class:`LuenbergerObserver`, :class:`KalmanObserver`,
:class:`LTIPlant`) and the errors (:class:`FhobsError`, the base of every exception, and its
subclasses). They are imported on first use, so ``import fhobs`` stays light; ``dir(fhobs)``
and type checkers see them all. :mod:`fhobs.core` is numpy-only and runs inside the FMUs (with
the slave classes of :mod:`fhobs.fmu`).

Examples
--------
>>> import fhobs
>>> design = fhobs.design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
>>> design.model.n_tilde
2
>>> "FilteringObserver" in dir(fhobs)
True
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING

__version__ = "0.1.0"

_PUBLIC = {
    "design_observer": "fhobs.design.observer",
    "design_for_spec": "fhobs.design.observer",
    "paper_gains": "fhobs.design.observer",
    "load_spec": "fhobs.design.spec",
    "certify": "fhobs.core.certificate",
    "build_fmus": "fhobs.build",
    "ObserverDesign": "fhobs.core.gains",
    "PlantModel": "fhobs.core.gains",
    "HomogeneousModel": "fhobs.core.gains",
    "FilteringGains": "fhobs.core.gains",
    "PrescribedTimeGains": "fhobs.core.gains",
    "LuenbergerGains": "fhobs.core.gains",
    "KalmanGains": "fhobs.core.gains",
    "FilteringObserver": "fhobs.core.runtime",
    "PrescribedTimeObserver": "fhobs.core.runtime",
    "LuenbergerObserver": "fhobs.core.runtime",
    "KalmanObserver": "fhobs.core.kalman_filter",
    "LTIPlant": "fhobs.core.plant",
    "FhobsError": "fhobs.errors",
    "SpecError": "fhobs.errors",
    "CertificateError": "fhobs.errors",
    "LMIError": "fhobs.errors",
    "KalmanDesignError": "fhobs.errors",
    "BuildError": "fhobs.errors",
}
__all__ = [
    "BuildError", "CertificateError", "FhobsError", "FilteringGains", "FilteringObserver",
    "HomogeneousModel", "KalmanDesignError", "KalmanGains", "KalmanObserver", "LMIError",
    "LTIPlant", "LuenbergerGains", "LuenbergerObserver", "ObserverDesign", "PlantModel",
    "PrescribedTimeGains", "PrescribedTimeObserver", "SpecError", "build_fmus", "certify",
    "design_for_spec", "design_observer", "load_spec", "paper_gains",
]

if TYPE_CHECKING:  # what the lazy imports below give, for type checkers and editors
    from fhobs.build import build_fmus
    from fhobs.core.certificate import certify
    from fhobs.core.gains import (
        FilteringGains,
        HomogeneousModel,
        KalmanGains,
        LuenbergerGains,
        ObserverDesign,
        PlantModel,
        PrescribedTimeGains,
    )
    from fhobs.core.kalman_filter import KalmanObserver
    from fhobs.core.plant import LTIPlant
    from fhobs.core.runtime import FilteringObserver, LuenbergerObserver, PrescribedTimeObserver
    from fhobs.design.observer import design_for_spec, design_observer, paper_gains
    from fhobs.design.spec import load_spec
    from fhobs.errors import (
        BuildError,
        CertificateError,
        FhobsError,
        KalmanDesignError,
        LMIError,
        SpecError,
    )


def __getattr__(name: str):  # noqa: ANN202 - any of the public objects
    """The public objects, imported from their modules on first use."""
    if name not in _PUBLIC:
        raise AttributeError(f"module 'fhobs' has no attribute {name!r}")
    return getattr(import_module(_PUBLIC[name]), name)


def __dir__() -> list[str]:
    """The module's names with the public objects not yet imported."""
    return sorted(set(globals()) | set(_PUBLIC))
