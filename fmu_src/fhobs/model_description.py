"""The plant's name and its signals' names and units in an FMU's modelDescription, both builds.

A spec's ``name`` and ``[signals]`` table (:mod:`fhobs.design.signals`) name the plant and its
states, inputs, outputs and unknown inputs. :func:`describe` writes them into the
modelDescription of either build (:mod:`fhobs.build` rewrites pythonfmu's,
:mod:`fhobs.native.build` its own) from the kind's declaration (:mod:`fhobs.fmu.kinds`: each
signal variable's :attr:`~fhobs.fmu.kinds.Variable.signal` and text), so both builds say the same:

- every element of ``y``, ``u``, ``x_hat``, ``q_hat`` (and the plant's ``x``, ``y``, ``u``,
  ``q``) gets a description naming its signal ("estimate of inductor.i", "measured phiB",
  "input U", "estimate of the unknown input M_load") and the signal's ``unit`` when it has one;
- ``<UnitDefinitions>`` lists each unit used (a ``<Unit name=.../>``, no ``BaseUnit``: units
  are free text in a spec, their SI exponents are not known);
- ``modelName`` is the kind (``"observer"``), the description starts with the kind and the
  plant's name (``"observer of DC-Motor.SuT: Filtering homogeneous observer ..."``).

The modelIdentifier and the GUID keep their hash: the identifier names the binary and, in a
pythonfmu FMU, the slave class (unique per build, so that two FMUs in one process never share
a class or module).

Value references, causalities, start values and the parameters' generic descriptions do not
change.
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from typing import Any

from .core.gains import ObserverDesign
from .design.signals import SignalNames
from .fmu.kinds import Kind

FMI2_ORDER = ("ModelExchange", "CoSimulation", "UnitDefinitions", "TypeDefinitions",
              "LogCategories", "DefaultExperiment", "VendorAnnotations", "ModelVariables",
              "ModelStructure")
"""The children of ``fmiModelDescription`` in the order FMI 2.0's schema requires."""


def naming_options(design: ObserverDesign, names: SignalNames | None = None,
                   plant_name: str | None = None) -> dict[str, Any]:
    """The build options that name the FMUs' signals: ``{"signals": {key: list}, "plant_name":
    str or None}`` (JSON; part of the build's identity, so an FMU built for other names is
    never taken from the cache).

    Parameters
    ----------
    design : ObserverDesign
        The design the FMUs run.
    names : SignalNames, optional
        The spec's names (``spec.names``); default ``x[i]``, ``u[i]``, ``y[i]``, ``q[i]``
        without units.
    plant_name : str, optional
        The plant's name (``spec.name``); None: the descriptions name no plant.

    Raises
    ------
    ValueError
        If a group of ``names`` has not as many names as the design's plant has signals.

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> naming_options(paper_gains(), plant_name="pendulum")["signals"]["states"]
    ['x[1]', 'x[2]', 'x[3]', 'x[4]']
    """
    plant = design.plant
    sizes = {"states": plant.n, "inputs": plant.m, "outputs": plant.k,
             "unknown_inputs": 0 if plant.E is None else plant.E.shape[1]}
    if names is None:
        names = SignalNames.default(*sizes.values())
    for group, size in sizes.items():
        given = len(getattr(names, group))
        if given != size:
            raise ValueError(f"names: {given} {group.replace('_', ' ')} named, the design's "
                             f"plant has {size} (names of another plant?)")
    return {"signals": {key: list(value) for key, value in dataclasses.asdict(names).items()},
            "plant_name": plant_name}


def describe(root: ET.Element, kind: Kind, signals: Mapping[str, Sequence[str]],
             plant_name: str | None) -> None:
    """Name the signals of the modelDescription ``root`` of an FMU of ``kind`` (in place).

    Parameters
    ----------
    root : xml.etree.ElementTree.Element
        ``fmiModelDescription``.
    kind : Kind
        The FMU's kind.
    signals : mapping
        ``naming_options(...)["signals"]``.
    plant_name : str or None
        The plant's name for the description (None: the description is left as it is).

    Examples
    --------
    >>> from fhobs.fmu.kinds import KINDS
    >>> root = ET.fromstring('<fmiModelDescription modelName="Fhobs_1" description="LTI">'
    ...     '<CoSimulation/><ModelVariables><ScalarVariable name="x[1]"><Real/>'
    ...     '</ScalarVariable></ModelVariables></fmiModelDescription>')
    >>> describe(root, KINDS["plant"], {"states": ["w"], "state_units": ["rad/s"]}, "motor")
    >>> root.get("modelName"), root.get("description")
    ('plant', 'plant of motor: LTI')
    >>> variable = root.find("ModelVariables/ScalarVariable")
    >>> variable.get("description"), variable.find("Real").get("unit")
    ('true value of w', 'rad/s')
    >>> [unit.get("name") for unit in root.iterfind("UnitDefinitions/Unit")]
    ['rad/s']
    """
    root.set("modelName", kind.name)
    if plant_name:
        root.set("description", f"{kind.name} of {plant_name}: {root.get('description', '')}")
    units = set()
    for element in root.iterfind("ModelVariables/ScalarVariable"):
        base, _, index = element.get("name", "").partition("[")
        try:
            variable = kind.variable(base)
        except KeyError:
            continue
        if variable.unit:
            element.find("Real").set("unit", variable.unit)
            units.add(variable.unit)
        if not variable.signal:
            continue
        position = int(index.rstrip("]")) - 1 if index else 0
        description, unit = variable.element_text(position, signals)
        element.set("description", description)
        if unit:
            element.find("Real").set("unit", unit)
            units.add(unit)
    for old in root.findall("UnitDefinitions"):
        root.remove(old)
    if units:
        definitions = ET.Element("UnitDefinitions")
        for unit in sorted(units):
            ET.SubElement(definitions, "Unit", name=unit)
        later = [i for i, child in enumerate(root)
                 if child.tag in FMI2_ORDER[FMI2_ORDER.index("UnitDefinitions") + 1:]]
        root.insert(later[0] if later else len(root), definitions)
