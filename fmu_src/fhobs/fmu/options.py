"""The build options: the start values of the FMUs' setting parameters, each with its default
and its check (:data:`OPTIONS`), and which kinds a design builds, for both builds.

A setting parameter of a kind (:mod:`fhobs.fmu.kinds`, role ``setting``) names its option
(:attr:`~fhobs.fmu.kinds.Variable.option`); :func:`fmu_options` gives every option's value
for a design (``fmu_config.json`` of the pythonfmu FMUs, the native FMUs' start values),
checked by the option's own rule and by each kind's (:attr:`~fhobs.fmu.kinds.Kind.check_options`).

Examples
--------
>>> from fhobs.design.observer import paper_gains
>>> fmu_options(paper_gains(), ["plant"], noise_seed=3)["noise_seed"]
3
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.gains import ObserverDesign
from ..core.plant import PLANT_SCHEMES
from ..core.runtime import DEFAULT_H, SCHEMES
from .kinds import KINDS

DEFAULT_INPUT_BOUND = 1e8
"""The default ``input_bound``: larger inputs are rejected as absurd."""


@dataclass(frozen=True)
class Option:
    """One build option.

    Attributes
    ----------
    name : str
        The key (of ``fmu_config.json``, of :func:`fmu_options`' keywords).
    default : callable
        ``default(design)``: its value when not given.
    value : callable
        ``value(given, design)``: the value to store (a float, a list, an int, a name);
        ValueError naming the option and the reason.
    settable : bool
        Given by the user (False: the design's own number, such as
        ``max_communication_step``).
    """

    name: str
    default: Callable[[ObserverDesign], Any]
    value: Callable[[Any, ObserverDesign], Any]
    settable: bool = True


def _vector(name: str, size: Callable[[ObserverDesign], int]) -> Option:
    """A start vector: zeros by default, its length ``size(design)`` checked."""
    def value(given: Iterable[float], design: ObserverDesign) -> list[float]:
        vector = np.asarray(list(given), dtype=float)
        if vector.shape != (size(design),):
            raise ValueError(f"{name}: expected {size(design)} values, got {vector.shape}")
        return vector.tolist()

    return Option(name, lambda design: [0.0] * size(design), value)


def _choice(name: str, choices: tuple[str, ...]) -> Option:
    """One of ``choices`` (the first by default)."""
    def value(given: str, design: ObserverDesign) -> str:
        if given not in choices:
            raise ValueError(f"{name} {given!r} is not one of {choices}")
        return given

    return Option(name, lambda design: choices[0], value)


def _number(name: str, default: float, kind: type = float) -> Option:
    return Option(name, lambda design: default, lambda given, design: kind(given))


OPTIONS: dict[str, Option] = {option.name: option for option in (
    _number("input_bound", DEFAULT_INPUT_BOUND),
    _number("h", DEFAULT_H),
    _choice("scheme", SCHEMES),
    _vector("z0", lambda design: design.plant.n),
    _vector("psi0", lambda design: design.plant.k),
    _number("xi0", 0.0),
    _number("T0", 1.0),
    _vector("x0", lambda design: design.plant.n),
    _number("noise_amplitude", 0.0),
    _number("noise_seed", 0, int),
    _choice("plant_scheme", PLANT_SCHEMES),
    Option("max_communication_step",
           lambda design: float(design.filtering.max_communication_step),
           lambda given, design: float(given), settable=False),
)}
"""Every build option, in the order of ``fmu_config.json``: ``h`` (the observers' internal
step), ``scheme`` (their integration scheme), ``z0``, ``psi0``, ``xi0`` (their initial state;
the disturbance states start at zero), ``T0`` (the prescribed-time observer's convergence
time, s), ``x0``, ``noise_amplitude``, ``noise_seed``, ``plant_scheme`` (the plant's),
``input_bound`` (every FMU's) and the design's ``max_communication_step``."""


def default_kinds(design: ObserverDesign) -> tuple[str, ...]:
    """The kinds built by default: every kind of :data:`~fhobs.fmu.kinds.KINDS` built for the
    design (:meth:`~fhobs.fmu.kinds.Kind.built_when`: ``kalman`` and ``supervised`` only with
    the ``[noise]`` table's records).

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> default_kinds(paper_gains())
    ('observer', 'prescribed_time', 'luenberger', 'plant')
    """
    return tuple(name for name, kind in KINDS.items() if kind.built_when(design))


def fmu_options(design: ObserverDesign, kinds: Iterable[str], **given: Any) -> dict[str, Any]:
    """The start values of the FMUs' setting parameters (``fmu_config.json``; the
    :attr:`~fhobs.fmu.kinds.Variable.option` keys), checked, for both builds.

    Parameters
    ----------
    design : ObserverDesign
        The design.
    kinds : iterable of str
        The kinds to build: each needs its record in the design and passes its own check of
        the options (a prescribed-time FMU a T0 that gives an initial xi).
    **given
        Values of the settable options of :data:`OPTIONS` (the others take their default).

    Returns
    -------
    dict

    Raises
    ------
    ValueError
        Naming the option and the reason.
    TypeError
        For a keyword that is no settable option.

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> fmu_options(paper_gains(), ["observer"], z0=[1, 0, 0, 0])["z0"]
    [1.0, 0.0, 0.0, 0.0]
    """
    unknown = sorted(set(given) - {name for name, o in OPTIONS.items() if o.settable})
    if unknown:
        raise TypeError(f"fmu_options() got an unexpected keyword argument {unknown[0]!r}")
    kinds = tuple(kinds)
    for kind in kinds:
        record = KINDS[kind].record
        if getattr(design, record) is None:
            what = KINDS[kind].description.split(" (")[0].split(":")[0]
            raise ValueError(f"{kind}.fmu ({what}) needs a design with a {record} record "
                             f"(design.{record} is None; give the spec a [noise] table)")
    options = {name: option.default(design) if given.get(name) is None
               else option.value(given[name], design) for name, option in OPTIONS.items()}
    for kind in kinds:
        check = KINDS[kind].check_options
        if check is not None:
            check(KINDS[kind].runs(design), options)
    return options
