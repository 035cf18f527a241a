"""Reading an SSP (a zip holding ``SystemStructure.ssd`` and its FMUs) into plain data, and the
wiring of one of its (sub)systems: which source feeds each component input and each of the
system's output connectors.

What is read:

- systems, nested to any depth, with their connectors (name, kind, the ``ssc:Real`` unit),
  components (an FMU in the zip: its ``source``, its connectors) and connections;
- parameter bindings: inline ``ssv:ParameterSet`` values and ``.ssv`` files referenced by a
  binding's ``source`` (a path in the zip), with the binding's ``prefix``. A component's own
  bindings apply first, then those of the systems around it up to the chosen system, the outer
  last (a system's binding names its element's variables as ``element.variable``); the
  bindings of the systems around the chosen one are not read;
- the SSD's unit definitions (``ssc:Unit`` with its ``ssc:BaseUnit``).

Parameter mappings (``ssm``) and signal dictionaries are not read.

The SSP export (:mod:`harness.ssp`) writes SSDs; this module reads them and shares its
namespaces.
"""

from __future__ import annotations

import difflib
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any
from xml.etree import ElementTree as ET

from fhobs.errors import FhobsError

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
}
"""The SSP 1.0 namespaces of the SSD and the parameter values (also what SSP 2.0 files use)."""
SSD_NAME = "SystemStructure.ssd"
VALUE_TYPES = {"Real": float, "Integer": int, "Boolean": lambda text: text.strip() == "true",
               "String": str, "Enumeration": int}
"""The ``ssv`` value elements read and the Python type of their ``value``."""


class SsdError(FhobsError, ValueError):
    """An SSP or its SSD that cannot be read, or a name it does not hold; the message names
    the file, the item and the reason."""


@dataclass(frozen=True)
class Connector:
    """A connector of a system or a component: ``kind`` input, output, parameter, ...;
    ``unit`` its ``ssc:Real`` unit ("" when none)."""

    name: str
    kind: str
    unit: str = ""


@dataclass(frozen=True)
class Component:
    """An FMU component: ``source`` its path in the zip, ``parameters`` its bound values."""

    name: str
    source: str
    connectors: dict[str, Connector]
    parameters: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Connection:
    """``start_element.start_connector -> end_element.end_connector``; an element "" is the
    system itself (its own connector)."""

    start_element: str
    start_connector: str
    end_element: str
    end_connector: str


@dataclass(frozen=True)
class System:
    """A system: its connectors, FMU components, nested systems, connections and the
    parameter values its own bindings give (``element.variable`` names)."""

    name: str
    connectors: dict[str, Connector]
    components: dict[str, Component]
    systems: dict[str, System]
    connections: tuple[Connection, ...]
    parameters: dict[str, Any]


@dataclass(frozen=True)
class SystemStructure:
    """An SSP's SSD: its top system and unit definitions (name -> base unit, as
    :func:`base_unit` gives it)."""

    path: Path
    system: System
    units: dict[str, tuple]


@dataclass(frozen=True)
class Endpoint:
    """A signal's end in a flattened system: a component's connector (``component`` its path
    from the chosen system, ``sub.comp``) or, with ``component`` "", the chosen system's own
    connector."""

    component: str
    connector: str

    def __str__(self) -> str:
        return f"{self.component}.{self.connector}" if self.component else self.connector


@dataclass(frozen=True)
class Wiring:
    """A system flattened: its FMU components by path (parameters: their own bindings, then
    the enclosing systems' up to the chosen one), and the source of each component input and
    each output connector of the system that is connected (a component output or an input
    connector of the system)."""

    system: System
    components: dict[str, Component]
    sources: dict[Endpoint, Endpoint]


def read_ssp(path: str | Path) -> SystemStructure:
    """Read the SSD of the SSP at ``path``.

    Raises
    ------
    SsdError
        A missing file, a file that is not a zip, a zip without ``SystemStructure.ssd``, an
        SSD that is not XML or has no system, a missing ``.ssv`` file.

    Examples
    --------
    >>> import io, tempfile
    >>> path = Path(tempfile.mkdtemp()) / "empty.ssp"
    >>> with zipfile.ZipFile(path, "w") as z:
    ...     z.writestr("SystemStructure.ssd", f'<ssd:SystemStructureDescription '
    ...                f'xmlns:ssd="{NS["ssd"]}" name="s"><ssd:System name="top"/>'
    ...                '</ssd:SystemStructureDescription>')
    >>> read_ssp(path).system.name
    'top'
    """
    path = Path(path)
    if not path.is_file():
        raise SsdError(f"{path}: no such SSP file")
    if not zipfile.is_zipfile(path):
        raise SsdError(f"{path}: not an SSP (an SSP is a zip file holding {SSD_NAME})")
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
        if SSD_NAME not in names:
            raise SsdError(f"{path}: the zip holds no {SSD_NAME} (an SSP's system structure)")

        def resource(name: str) -> bytes:
            member = str(PurePosixPath(name))
            if member not in names:
                raise SsdError(f"{path}: the SSD refers to {name!r}, which the zip does not hold")
            return archive.read(member)

        try:
            root = ET.fromstring(archive.read(SSD_NAME))
        except ET.ParseError as err:
            raise SsdError(f"{path}: {SSD_NAME} is not XML ({err})") from None
        top = root.find("ssd:System", NS)
        if top is None:
            raise SsdError(f"{path}: {SSD_NAME} has no ssd:System")
        return SystemStructure(path, _system(top, resource), _units(root))


def find_system(structure: SystemStructure, name: str | None) -> System:
    """The system named ``name`` (``top`` or ``top.sub.subsub``; None: the top system).

    Examples
    --------
    >>> top = System("DC-Motor", {}, {}, {"SuT": System("SuT", {}, {}, {}, (), {})}, (), {})
    >>> find_system(SystemStructure(Path("m.ssp"), top, {}), "DC-Motor.SuT").name
    'SuT'
    """
    system = structure.system
    if name is None:
        return system
    head, *rest = name.split(".")
    path = [head]
    if head != system.name:
        raise SsdError(f"{structure.path}: no system {name!r}: the top system is "
                       f"{system.name!r}; {_system_list(structure.system)}")
    for part in rest:
        path.append(part)
        if part not in system.systems:
            raise SsdError(f"{structure.path}: no system {'.'.join(path)!r}"
                           f"{_closest(part, system.systems)}; {_system_list(structure.system)}")
        system = system.systems[part]
    return system


def wiring(system: System) -> Wiring:
    """Flatten ``system``: its components and those of its nested systems (named by their
    path), and for each component input and output connector of ``system`` that a connection
    reaches, its source, traced through the nested systems' connectors.

    Raises
    ------
    SsdError
        A connection naming an element the system does not hold, a connector with two
        sources, a binding of a system naming no element of it.

    Examples
    --------
    >>> comp = Component("c", "resources/c.fmu", {"u": Connector("u", "input")})
    >>> top = System("s", {"U": Connector("U", "input")}, {"c": comp}, {},
    ...              (Connection("", "U", "c", "u"),), {})
    >>> wiring(top).sources
    {Endpoint(component='c', connector='u'): Endpoint(component='', connector='U')}
    """
    components: dict[str, Component] = {}
    links: dict[tuple[str, str], tuple[str, str]] = {}
    _collect(system, "", components, links)
    sources: dict[Endpoint, Endpoint] = {}
    for path, connector in links:
        if path in components or path == "":
            sources[Endpoint(path, connector)] = _trace(path, connector, links, components,
                                                        system)
    return Wiring(system, components, sources)


def base_unit(element: ET.Element | None) -> tuple:
    """A unit's base unit as (kg, m, s, A, K, mol, cd, rad, factor, offset), from an
    ``ssc:BaseUnit`` (or an FMU's ``BaseUnit``, the same attributes); None without one."""
    if element is None:
        return None
    keys = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
    return (tuple(int(element.get(k, "0")) for k in keys)
            + (float(element.get("factor", "1")), float(element.get("offset", "0"))))


def _units(root: ET.Element) -> dict[str, tuple]:
    units = {}
    for unit in root.iter(f"{{{NS['ssc']}}}Unit"):
        units[unit.get("name", "")] = base_unit(unit.find("ssc:BaseUnit", NS))
    return units


def _connectors(element: ET.Element) -> dict[str, Connector]:
    connectors = {}
    for conn in element.findall("ssd:Connectors/ssd:Connector", NS):
        real = conn.find("ssc:Real", NS)
        unit = real.get("unit", "") if real is not None else ""
        connectors[conn.get("name", "")] = Connector(conn.get("name", ""), conn.get("kind", ""),
                                                     unit)
    return connectors


def _bindings(element: ET.Element, resource) -> dict[str, Any]:
    values: dict[str, Any] = {}
    for binding in element.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS):
        prefix = binding.get("prefix", "")
        pset = binding.find("ssd:ParameterValues/ssv:ParameterSet", NS)
        if pset is None and binding.get("source"):
            source = binding.get("source")
            try:
                pset = ET.fromstring(resource(source))
            except ET.ParseError as err:
                raise SsdError(f"parameter values {source!r}: not XML ({err})") from None
        if pset is None:
            continue
        for param in pset.findall("ssv:Parameters/ssv:Parameter", NS):
            for tag, convert in VALUE_TYPES.items():
                value = param.find(f"ssv:{tag}", NS)
                if value is not None:
                    values[prefix + param.get("name", "")] = convert(value.get("value", ""))
    return values


def _system(element: ET.Element, resource) -> System:
    components, systems = {}, {}
    for comp in element.findall("ssd:Elements/ssd:Component", NS):
        name = comp.get("name", "")
        components[name] = Component(name, comp.get("source", ""), _connectors(comp),
                                     _bindings(comp, resource))
    for sub in element.findall("ssd:Elements/ssd:System", NS):
        systems[sub.get("name", "")] = _system(sub, resource)
    connections = tuple(
        Connection(c.get("startElement", ""), c.get("startConnector", ""),
                   c.get("endElement", ""), c.get("endConnector", ""))
        for c in element.findall("ssd:Connections/ssd:Connection", NS))
    return System(element.get("name", ""), _connectors(element), components, systems,
                  connections, _bindings(element, resource))


def _collect(system: System, prefix: str, components: dict[str, Component],
             links: dict[tuple[str, str], tuple[str, str]]) -> None:
    """Gather the components (by path) and the connections (target -> source, each end a
    (path, connector), a system's own connector under the system's path) of ``system``."""
    for name, comp in system.components.items():
        components[prefix + name] = comp
    for name, sub in system.systems.items():
        _collect(sub, f"{prefix}{name}.", components, links)
    own = prefix[:-1]
    for conn in system.connections:
        ends = []
        for element, connector in ((conn.start_element, conn.start_connector),
                                   (conn.end_element, conn.end_connector)):
            if element and element not in system.components and element not in system.systems:
                raise SsdError(f"system {system.name!r}: a connection names the element "
                               f"{element!r}, which the system does not hold"
                               f"{_closest(element, {**system.components, **system.systems})}")
            ends.append((prefix + element if element else own, connector))
        if ends[1] in links:
            raise SsdError(f"system {system.name!r}: {_show(ends[1])} has two sources")
        links[ends[1]] = ends[0]
    for key, value in system.parameters.items():
        _bind(system, prefix, key, key, value, components)


def _bind(system: System, prefix: str, key: str, name: str, value: Any,
          components: dict[str, Component]) -> None:
    """Apply the binding ``name = value`` of a system (``element.variable``, the element
    possibly a nested system) to the component it names; ``key`` the binding as written."""
    element, _, variable = name.partition(".")
    if element in system.components and variable:
        comp = components[prefix + element]
        components[prefix + element] = Component(comp.name, comp.source, comp.connectors,
                                                  {**comp.parameters, variable: value})
    elif element in system.systems and variable:
        _bind(system.systems[element], f"{prefix}{element}.", key, variable, value, components)
    else:
        raise SsdError(f"system {system.name!r}: the parameter binding {key!r} names no "
                       "component variable (expected element.variable)")


def _trace(path: str, connector: str, links: dict, components: dict[str, Component],
           system: System) -> Endpoint:
    """The source of ``(path, connector)``: followed back through the nested systems'
    connectors to a component output or an input connector of the chosen system; an
    unconnected nested connector ends the trace where it is."""
    seen = set()
    end = (path, connector)
    while end in links:
        if end in seen:
            raise SsdError(f"system {system.name!r}: the connections around {_show(end)} form "
                           "a loop of system connectors")
        seen.add(end)
        end = links[end]
        if end[0] in components or end[0] == "":
            break
    return Endpoint(*end)


def _show(end: tuple[str, str]) -> str:
    return f"{end[0]}.{end[1]}" if end[0] else end[1]


def _closest(name: str, names) -> str:
    close = difflib.get_close_matches(name, list(names), n=3, cutoff=0.5)
    return f" (closest: {', '.join(close)})" if close else ""


def _system_list(system: System, prefix: str = "") -> str:
    def walk(s: System, p: str) -> list[str]:
        here = [p + s.name]
        for sub in s.systems.values():
            here += walk(sub, f"{p}{s.name}.")
        return here

    return "the systems: " + ", ".join(walk(system, prefix))
