"""FMI 3.0 builds of the native FMUs: the modelDescription 3.0, the buildDescription, the
generated array table and the C layer's sources.

A native FMU of FMI 3.0 (``build_fmu.py SPEC --native --fmi 3``,
``build_native_fmus(..., fmi_version=3)``) has the model of its FMI 2.0 build (``family_<family>.c``
behind ``model.h``, the generated ``model_data``: the same results) and its instance core
``instance.c``, under the FMI 3.0 layer ``fmi3_layer.c`` in place of ``fmi2_layer.c``. Its
modelDescription is written here from the same scalar variables
(:func:`fhobs.native.build._variables`, from the kind's declaration :mod:`fhobs.fmu.kinds`):

- every array of the declaration (``y``, ``u``, ``x_hat``, ``q_hat``, ``psi``, ``A``, ``L``,
  ``P_bar``, ``z0``...) is one variable with fixed dimensions (``<Dimension start="n"/>``), its
  start value the elements row-major; scalars stay scalars; Real variables are ``<Float64>``,
  Integer ones ``<Int32>``; ``time`` is the independent variable;
- value references (:func:`value_references`): an array's is the FMI 2.0 value reference of
  its first element (``[1]`` / ``[1,1]``), a scalar's its FMI 2.0 one, ``time``'s the one
  after the last FMI 2.0 value reference; they change only when the FMI 2.0 ones do (the
  declaration's order);
- names, descriptions and units of the signals as :mod:`fhobs.model_description` gives them
  to each element: an array's description lists its elements' (``"estimate of inductor.i;
  estimate of phi"``) and its unit is theirs when they share one (else each element's unit in
  brackets in the description);
- ``<ModelStructure>``: each output (``<Output valueReference=... dependencies=""/>``: no
  output depends on an input); the outputs' start values are exact, so nothing is an initial
  unknown;
- ``<CoSimulation>``: variable communication steps, FMU states (get, set, serialize), event mode
  (the FMU has no events: a host that uses event mode passes through it), no early return, no
  intermediate update; ``binaries/x86_64-linux/<modelIdentifier>.so``; ``sources/`` with
  ``buildDescription.xml``.

Examples
--------
>>> variables = [{"name": "status", "vr": 0}, {"name": "y[1]", "vr": 1},
...              {"name": "y[2]", "vr": 2}, {"name": "xi", "vr": 3}]
>>> [(a.name, a.vr, a.shape) for a in arrays(variables)]
[('status', 0, ()), ('y', 1, (2,)), ('xi', 3, ())]
>>> value_references(variables)
{'status': 0, 'y': 1, 'xi': 3, 'time': 4}
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..fmu.kinds import Kind

HERE = Path(__file__).resolve().parent
BINARY_FOLDER = "x86_64-linux"
"""The binaries' folder of the FMI 3.0 platform tuple."""
LAYER_SOURCES = ("fmi3_layer.c",)
"""The FMI 3.0 layer's files from this folder (in place of ``fmi2_layer.c``)."""
FMI_HEADERS = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
ARRAY_HEADER = "fhobs_fmi3.h"
"""The generated header of :func:`c_header`."""
LOG_CATEGORIES = ("logStatusWarning", "logStatusError")
"""The log categories: the FMUs log their errors and the coarse-step warning only."""
CAPABILITIES = (("needsExecutionTool", "false"),
                ("canBeInstantiatedOnlyOncePerProcess", "false"),
                ("canGetAndSetFMUState", "true"), ("canSerializeFMUState", "true"),
                ("providesDirectionalDerivatives", "false"),
                ("providesAdjointDerivatives", "false"),
                ("canHandleVariableCommunicationStepSize", "true"),
                ("maxOutputDerivativeOrder", "0"), ("providesIntermediateUpdate", "false"),
                ("mightReturnEarlyFromDoStep", "false"),
                ("canReturnEarlyAfterIntermediateUpdate", "false"), ("hasEventMode", "true"))
"""The ``<CoSimulation>`` attributes after ``modelIdentifier``."""


@dataclass(frozen=True)
class Array:
    """One FMI 3.0 variable: the scalars of the FMI 2.0 build it holds.

    Attributes
    ----------
    name : str
        Base name (``x_hat``).
    vr : int
        Its value reference (its first element's FMI 2.0 one).
    shape : tuple of int
        ``()`` for a scalar, else the dimensions (row-major elements).
    elements : tuple of dict
        The scalar variables (:func:`fhobs.native.build._variables`'s entries), in order.
    """

    name: str
    vr: int
    shape: tuple[int, ...]
    elements: tuple[dict[str, Any], ...]


def arrays(variables: Sequence[Mapping[str, Any]]) -> list[Array]:
    """The FMI 3.0 variables of the scalar ``variables`` (value-reference order): consecutive
    elements of one base name form one array, its dimensions those of its last element's
    index.

    Examples
    --------
    >>> names = ["A[1,1]", "A[1,2]", "A[2,1]", "A[2,2]", "nu"]
    >>> [(a.name, a.shape) for a in arrays([{"name": n, "vr": i} for i, n in enumerate(names)])]
    [('A', (2, 2)), ('nu', ())]
    """
    grouped: list[list[Mapping[str, Any]]] = []
    for var in variables:
        base = var["name"].split("[")[0]
        if grouped and "[" in var["name"] and grouped[-1][0]["name"].split("[")[0] == base:
            grouped[-1].append(var)
        else:
            grouped.append([var])
    out = []
    for group in grouped:
        name, _, index = group[-1]["name"].partition("[")
        shape = tuple(int(i) for i in index.rstrip("]").split(",")) if index else ()
        out.append(Array(name, int(group[0]["vr"]), shape, tuple(dict(v) for v in group)))
    return out


def value_references(variables: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    """``{name: value reference}`` of the FMI 3.0 variables of ``variables``, ``time`` last (the
    rule of the module docstring)."""
    return {**{a.name: a.vr for a in arrays(variables)}, "time": len(variables)}


def c_header(variables: Sequence[Mapping[str, Any]]) -> str:
    """``fhobs_fmi3.h``: ``FHOBS3_TIME_VR`` and ``FHOBS3_SIZE`` (per FMI 2.0 value reference:
    the elements of the FMI 3.0 variable whose value reference it is, 0 for the others)."""
    sizes = [0] * len(variables)
    for array in arrays(variables):
        sizes[array.vr] = len(array.elements)
    return ("/* Generated by fhobs.native.fmi3: the FMI 3.0 variables of this FMU by value\n"
            " * reference (an array's is its first element's). Do not edit. */\n"
            "#ifndef FHOBS_FMI3_H\n#define FHOBS_FMI3_H\n\n#include \"model_data.h\"\n\n"
            f"#define FHOBS3_TIME_VR {len(variables)}u\n"
            "static const unsigned FHOBS3_SIZE[FHOBS_N_VARIABLES] = {"
            + ", ".join(map(str, sizes)) + "};\n\n#endif\n")


def layer_sources(variables: Sequence[Mapping[str, Any]]) -> dict[str, str]:
    """The FMI 3.0 layer's sources: :data:`LAYER_SOURCES` and the generated
    :data:`ARRAY_HEADER`."""
    sources = {name: (HERE / name).read_text() for name in LAYER_SOURCES}
    sources[ARRAY_HEADER] = c_header(variables)
    return sources


def _text(kind: Kind, array: Array, signals: Mapping[str, Sequence[str]]) -> tuple[str, str]:
    """The description and unit of ``array``: a signal's from its elements' (their
    descriptions joined, their unit when they share one), else the declaration's."""
    base = kind.variable(array.name)
    if not base.signal:
        return array.elements[0]["description"], ""
    texts = [base.element_text(i, signals) for i in range(len(array.elements))]
    units = {unit for _, unit in texts}
    if len(units) == 1:
        return "; ".join(text for text, _ in texts), units.pop()
    return "; ".join(f"{text} [{unit}]" if unit else text for text, unit in texts), ""


def _start(array: Array) -> str:
    values = [v["start"] for v in array.elements]
    return " ".join(str(v) if isinstance(v, int) else repr(float(v)) for v in values)


def model_description(kind: Kind, variables: Sequence[Mapping[str, Any]], identifier: str,
                      token: str, naming: Mapping[str, Any]) -> ET.ElementTree:
    """The modelDescription 3.0 of the native FMU of ``kind`` (see the module docstring).

    Parameters
    ----------
    kind : Kind
        The FMU's kind.
    variables : sequence of dict
        The scalar variables (:func:`fhobs.native.build._variables`).
    identifier, token : str
        The modelIdentifier and the instantiationToken (the FMI 2.0 build's GUID scheme).
    naming : mapping
        :func:`fhobs.model_description.naming_options`.
    """
    plant_name = naming["plant_name"]
    description = f"{kind.description} -- native FMU"
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0", "modelName": kind.name, "instantiationToken": token,
        "description": f"{kind.name} of {plant_name}: {description}" if plant_name
        else description,
        "generationTool": "fhobs.native.build (compiled C, no Python at run time)",
        "variableNamingConvention": "structured", "author": "fhobs", "license": "MIT"})
    ET.SubElement(root, "CoSimulation", {"modelIdentifier": identifier, **dict(CAPABILITIES)})
    texts = {a.name: _text(kind, a, naming["signals"]) for a in arrays(variables)}
    units = sorted({unit for _, unit in texts.values() if unit})
    if units:
        definitions = ET.SubElement(root, "UnitDefinitions")
        for unit in units:
            ET.SubElement(definitions, "Unit", name=unit)
    categories = ET.SubElement(root, "LogCategories")
    for name in LOG_CATEGORIES:
        ET.SubElement(categories, "Category", name=name)
    model_variables = ET.SubElement(root, "ModelVariables")
    ET.SubElement(model_variables, "Float64", {
        "name": "time", "valueReference": str(len(variables)), "causality": "independent",
        "variability": "continuous", "description": "simulation time"})
    outputs = []
    for array in arrays(variables):
        causality = array.elements[0]["causality"]
        text, unit = texts[array.name]
        attributes = {"name": array.name, "valueReference": str(array.vr), "description": text,
                      **array.elements[0]["attributes"]}
        if unit:
            attributes["unit"] = unit
        attributes["start"] = _start(array)
        tag = "Float64" if array.elements[0]["type"] == "real" else "Int32"
        element = ET.SubElement(model_variables, tag, attributes)
        for size in array.shape:
            ET.SubElement(element, "Dimension", start=str(size))
        if causality == "output":
            outputs.append(array.vr)
    structure = ET.SubElement(root, "ModelStructure")
    for vr in outputs:
        ET.SubElement(structure, "Output", valueReference=str(vr), dependencies="")
    tree = ET.ElementTree(root)
    ET.indent(tree, "\t")
    return tree


def build_description(identifier: str, files: Sequence[str]) -> ET.ElementTree:
    """``sources/buildDescription.xml``: the C files to compile (C99) and libm.

    Examples
    --------
    >>> tree = build_description("fhobs_observer_0", ["models.c"])
    >>> [f.get("name") for f in tree.iter("SourceFile")]
    ['models.c']
    """
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    configuration = ET.SubElement(root, "BuildConfiguration", modelIdentifier=identifier)
    file_set = ET.SubElement(configuration, "SourceFileSet", language="C99")
    for name in files:
        ET.SubElement(file_set, "SourceFile", name=name)
    ET.SubElement(configuration, "Library", name="m",
                  description="the C maths library (link with -lm)")
    tree = ET.ElementTree(root)
    ET.indent(tree, "\t")
    return tree


def documentation(fmi2_text: str) -> str:
    """``documentation/index.html`` of an FMI 3.0 build from the FMI 2.0 build's text (the same
    FMU but for the version, its functions and its binaries' folder).

    Examples
    --------
    >>> documentation("<p>FMI 2.0 FMU: fmi2Error, binaries/linux64/x.so</p>")
    '<p>FMI 3.0 FMU: fmi3Error, binaries/x86_64-linux/x.so</p>'
    """
    return (fmi2_text.replace("FMI 2.0", "FMI 3.0").replace("fmi2", "fmi3")
            .replace("binaries/linux64", f"binaries/{BINARY_FOLDER}"))
