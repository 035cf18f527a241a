"""Export a system description as an SSP 1.0 file (``SystemStructure.ssd`` + FMUs).

What the engines here understand (checked with fmpy 0.3.32 and libcosimpy 0.0.6):

- connections: both; transformations on connections: fmpy ignores them, and SSP 1.0 has no
  matrix transformation or summation anyway. So every connection gain ``u = K x`` is carried as
  a :mod:`harness.blocks` matrix-gain FMU (:func:`lower_gains`). Under a Jacobi exchange that
  block delays its path by one communication step (its output is read at ``t_k`` before its
  input of ``t_k`` is set): the exported system is the *lowered* system, which the harness runs
  the same way (``resolve_system(lower_gains(spec))``).
- start values: written as component ``ParameterBindings`` with inline ``ssv:ParameterSet``
  values (libcosim applies them; fmpy's ``simulate_ssp`` parses but does not apply them, so
  a caller hands them over as its ``parameter_set``).
- signal sources: carried as :mod:`harness.blocks` FMUs (sine, signal, noise: the systems
  already use them).
- the blocks are native (compiled C, :mod:`harness.blocks.native`) when the system's own FMUs
  are (none of them a pythonfmu FMU), or when asked for: the SSP then runs in a host without
  Python (OMSimulator, ``bench/check_omsimulator.py``); else they are the pythonfmu blocks.
- an SSP with an FMU that needs Python (a pythonfmu FMU: the pythonfmu builds of the observers
  and the plant, the pythonfmu blocks) runs only in a host with Python 3.11 and numpy (every
  block kind has a native build): ``export_ssp(..., allow_python=False)`` (the
  command's default) refuses it, naming each such FMU (:func:`python_fmus`).

The default experiment (start, stop) is written; the step size goes into two vendor
annotations, which other engines ignore: OSP's ``osp:FixedStepAlgorithm baseStepSize`` on the
default experiment (libcosim) and OpenModelica's ``oms:FixedStepMaster stepSize`` in the
``oms:SimulationInformation`` of the top-level system, without which OMSimulator does not load
the file.
"""

from __future__ import annotations

import zipfile
from dataclasses import replace
from pathlib import Path
from xml.etree import ElementTree as ET

from harness.blocks.build import is_pythonfmu
from harness.system import (
    ConnectionSpec,
    DescriptionError,
    FmuSpec,
    ResolvedSystem,
    SystemSpec,
    build_blocks,
    resolve_system,
    split_signal,
)
from harness.writing import atomic_path

__all__ = ["PythonFmuError", "export_ssp", "exported_system", "is_pythonfmu", "lower_gains",
           "python_fmus"]


class PythonFmuError(DescriptionError):
    """An SSP export refused: FMUs of the system need Python at run time (the message names
    each one and its file)."""

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
    "oms": "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd",
}
FMU_MIME = "application/x-fmu-sharedlibrary"


def lower_gains(spec: SystemSpec) -> SystemSpec:
    """The same system with every connection gain replaced by a matrix-gain block FMU.

    A connection ``from -> to`` with gain ``K`` (p x m) becomes ``from -> gain_i.u`` and
    ``gain_i.y -> to`` with a block ``gain_i`` whose start values are ``K``.
    """
    fmus = dict(spec.fmus)
    connections: list[ConnectionSpec] = []
    for i, conn in enumerate(spec.connections, start=1):
        extras = [key for key in ("offset", "bias", "noise") if getattr(conn, key) is not None]
        if extras or not isinstance(conn.source, str):
            what = ", ".join(extras) or "several sources"
            raise DescriptionError(f"connection {conn}: {what}, which the master applies and "
                                   "an SSP cannot express; export a system without them")
        if conn.gain is None:
            connections.append(conn)
            continue
        name = f"gain_{i}"
        if name in fmus:
            raise ValueError(f"cannot lower gains: the system already has an FMU {name!r}")
        p, m = conn.gain.shape
        start = {f"K[{r + 1},{c + 1}]": float(conn.gain[r, c]) for r in range(p) for c in range(m)}
        fmus[name] = FmuSpec(name, None, start, ("gain", (p, m)))
        connections += [
            ConnectionSpec(conn.source, f"{name}.u"),
            ConnectionSpec(f"{name}.y", conn.target),
        ]
    return replace(spec, fmus=fmus, connections=tuple(connections))


def exported_system(spec: SystemSpec, block_cache: Path | None = None,
                    native_blocks: bool | None = None) -> SystemSpec:
    """The system :func:`export_ssp` writes: gains lowered to blocks, every block built.

    Parameters
    ----------
    spec
        The system.
    block_cache
        Where the blocks are built (see :func:`harness.blocks.block_fmu`).
    native_blocks
        As for :func:`harness.system.build_blocks`: by default native blocks when none of the
        system's own FMUs is a pythonfmu FMU, so that the SSP of native FMUs needs no Python.
        Blocks the spec already has files for are replaced by the chosen ones.

    Returns
    -------
    SystemSpec
        What the harness runs to compare with an engine running the SSP
        (``run_system(resolve_system(exported_system(spec)))``).

    Examples
    --------
    >>> from harness.cli import SCENARIO_DIR
    >>> from harness.system import load_system
    >>> spec = load_system(SCENARIO_DIR / "pendulum_nominal.toml",
    ...                    {"fmu_dir": "build/pendulum/native"})
    >>> sorted(exported_system(spec).fmus)  # doctest: +SKIP
    ['gain_4', 'gain_5', 'gain_6', 'gain_7', 'kalman', 'linear', 'observer', 'plant']
    """
    lowered = lower_gains(spec)
    fmus = {name: replace(fs, path=None) if fs.block else fs for name, fs in lowered.fmus.items()}
    return build_blocks(replace(lowered, fmus=fmus), block_cache, native_blocks)


def python_fmus(system: ResolvedSystem) -> dict[str, Path]:
    """The components whose FMU needs Python at run time (a pythonfmu FMU), with their files,
    in the system's order.

    Examples
    --------
    >>> from harness.cli import SCENARIO_DIR
    >>> from harness.system import load_system
    >>> spec = load_system(SCENARIO_DIR / "pendulum_nominal.toml",
    ...                    {"fmu_dir": "build/pendulum"})
    >>> sorted(python_fmus(resolve_system(exported_system(spec))))  # doctest: +SKIP
    ['gain_4', 'gain_5', 'gain_6', 'gain_7', 'kalman', 'linear', 'observer', 'plant']
    """
    return {name: rf.spec.path for name, rf in system.fmus.items() if is_pythonfmu(rf.spec.path)}


def check_no_python(system: ResolvedSystem) -> None:
    """PythonFmuError naming every FMU of ``system`` that needs Python, if any."""
    found = python_fmus(system)
    if found:
        named = ", ".join(f"{name} ({path})" for name, path in found.items())
        raise PythonFmuError(
            f"export-ssp: {len(found)} FMU(s) of system {system.spec.name!r} need Python 3.11 "
            f"with numpy at run time (pythonfmu FMUs), so a host without Python cannot run "
            f"the SSP: {named}; use native FMUs (build_fmu.py --native, --fmu-dir DIR/native, "
            "and native blocks) or pass --allow-python to export them anyway"
        )


def export_ssp(spec: SystemSpec, path: str | Path, block_cache: Path | None = None,
               native_blocks: bool | None = None, allow_python: bool = True) -> Path:
    """Write ``spec`` (gains lowered to blocks) as an SSP file at ``path``, whole
    (:func:`harness.writing.atomic_path`).

    Parameters
    ----------
    spec
        The system; its connections, start values, recorded signals and experiment go in.
    path
        The ``.ssp`` file to write.
    block_cache
        Where the gain blocks are built (see :func:`harness.blocks.block_fmu`).
    native_blocks
        As for :func:`exported_system`: by default native blocks when the system's own FMUs
        are native, so that the SSP of native FMUs needs no Python.
    allow_python
        Write the SSP even when FMUs of it need Python (:func:`python_fmus`); False: refuse
        with a :class:`PythonFmuError` naming them, nothing written.

    Returns
    -------
    Path
        ``path``.

    Examples
    --------
    With the pendulum's FMUs built into ``build/pendulum`` (see
    :func:`harness.system.resolve_system`):

    >>> from harness.cli import SCENARIO_DIR
    >>> from harness.system import load_system
    >>> spec = load_system(SCENARIO_DIR / "pendulum_perturbed.toml", {"fmu_dir": "build/pendulum"})
    >>> export_ssp(spec, "out/pendulum_perturbed.ssp")  # doctest: +SKIP
    PosixPath('out/pendulum_perturbed.ssp')
    """
    system = resolve_system(exported_system(spec, block_cache, native_blocks))
    if not allow_python:
        check_no_python(system)
    resources = _resource_names(system)
    root = _ssd(system, resources)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(
            "SystemStructure.ssd", ET.tostring(root, encoding="unicode", xml_declaration=True)
        )
        for source, resource in {src: res for src, res in resources.values()}.items():
            zf.write(source, resource)
    return path


def _resource_names(system: ResolvedSystem) -> dict[str, tuple[Path, str]]:
    """Component name -> (FMU file, resource path); one resource per distinct FMU file."""
    by_file: dict[Path, str] = {}
    out = {}
    for name, rf in system.fmus.items():
        src = rf.spec.path
        if src not in by_file:
            stem = src.stem if src.stem not in {Path(r).stem for r in by_file.values()} else name
            by_file[src] = f"resources/{stem}.fmu"
        out[name] = (src, by_file[src])
    return out


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _ssd(system: ResolvedSystem, resources: dict[str, tuple[Path, str]]) -> ET.Element:
    for prefix, uri in NS.items():
        ET.register_namespace(prefix, uri)
    spec = system.spec
    root = ET.Element(_q("ssd", "SystemStructureDescription"), version="1.0", name=spec.name)
    sys_el = ET.SubElement(root, _q("ssd", "System"), name=spec.name)
    elements = ET.SubElement(sys_el, _q("ssd", "Elements"))
    connectors = _connectors(system)
    for name, rf in system.fmus.items():
        comp = ET.SubElement(
            elements, _q("ssd", "Component"), name=name, source=resources[name][1], type=FMU_MIME
        )
        conns = ET.SubElement(comp, _q("ssd", "Connectors"))
        for var, kind in connectors[name]:
            c = ET.SubElement(conns, _q("ssd", "Connector"), name=var, kind=kind)
            ET.SubElement(c, _q("ssc", "Real"))
        if rf.spec.start:
            _bindings(comp, rf.spec.start, rf.variables)
    links = ET.SubElement(sys_el, _q("ssd", "Connections"))
    for conn in system.connections:
        for (sf, sv), (tf, tv) in zip(conn.sources, conn.targets, strict=True):
            ET.SubElement(
                links,
                _q("ssd", "Connection"),
                startElement=sf,
                startConnector=sv.name,
                endElement=tf,
                endConnector=tv.name,
            )
    _oms_annotation(sys_el, spec.step)
    exp = ET.SubElement(
        root,
        _q("ssd", "DefaultExperiment"),
        startTime=repr(spec.start_time),
        stopTime=repr(spec.stop_time),
    )
    notes = ET.SubElement(
        ET.SubElement(exp, _q("ssd", "Annotations")),
        _q("ssc", "Annotation"),
        type="com.opensimulationplatform",
    )
    algo = ET.SubElement(notes, _q("osp", "Algorithm"))
    ET.SubElement(algo, _q("osp", "FixedStepAlgorithm"), baseStepSize=repr(spec.step))
    return root


def _oms_annotation(system: ET.Element, step: float) -> None:
    """OMSimulator's annotation of a system: a fixed-step master with the communication step."""
    note = ET.SubElement(
        ET.SubElement(system, _q("ssd", "Annotations")),
        _q("ssc", "Annotation"),
        type="org.openmodelica",
    )
    info = ET.SubElement(
        ET.SubElement(note, _q("oms", "Annotations")), _q("oms", "SimulationInformation")
    )
    ET.SubElement(info, _q("oms", "FixedStepMaster"), description="oms-ma", stepSize=repr(step))


def _connectors(system: ResolvedSystem) -> dict[str, list[tuple[str, str]]]:
    """Per component: the connected inputs and the connected or recorded outputs."""
    out: dict[str, list[tuple[str, str]]] = {name: [] for name in system.fmus}
    for conn in system.connections:
        for fmu, v in conn.targets:
            out[fmu].append((v.name, "input"))
    for signal in system.recorded:
        fmu, var = split_signal(signal)
        out[fmu].append((var, "output"))
    return {name: list(dict.fromkeys(items)) for name, items in out.items()}


def _bindings(comp: ET.Element, start: dict, variables: dict) -> None:
    binding = ET.SubElement(
        ET.SubElement(comp, _q("ssd", "ParameterBindings")), _q("ssd", "ParameterBinding")
    )
    pset = ET.SubElement(
        ET.SubElement(binding, _q("ssd", "ParameterValues")),
        _q("ssv", "ParameterSet"),
        version="1.0",
        name="start_values",
    )
    params = ET.SubElement(pset, _q("ssv", "Parameters"))
    for var, value in start.items():
        kind = variables[var].type
        p = ET.SubElement(params, _q("ssv", "Parameter"), name=var)
        if kind == "Real":
            text = repr(float(value))
        elif kind == "Boolean":
            text = str(bool(value)).lower()
        else:
            text = str(int(value))
        ET.SubElement(p, _q("ssv", "Integer" if kind == "Enumeration" else kind), value=text)
