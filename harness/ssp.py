"""Export a system description as an SSP 1.0 file (``SystemStructure.ssd`` + FMUs).

What the engines here understand (checked with fmpy 0.3.32 and libcosimpy 0.0.6):

- connections: both; transformations on connections: fmpy ignores them, and SSP 1.0 has no
  matrix transformation, offset, summation or noise anyway. So :func:`lower_gains` turns every
  connection ``to = gain @ (from - offset + draw) + bias`` of the system (resolved: each
  source and target a scalar) into plain wires and :mod:`harness.blocks` FMUs, connection
  ``i`` (1-based) into:

  ========================  =================================================================
  ``constant_i``            a ``constant`` block: ``-offset``, the zeros of sources without
                            noise in a noisy connection, ``bias`` (only the values used)
  ``shift_i``               a ``sum`` block of the sources, ``-offset`` (when an offset is not
                            0) and the draws (when the connection has noise):
                            ``from - offset + draw``, in the master's order of operations
  ``noise`` (one)           a ``noise`` block (Gaussian) of every noisy source of the system,
                            in the master's column order (:attr:`harness.master.Master
                            .noise_sources`), sizes the standard deviations, seed the run's
                            ``noise_seed``: its output at ``t_k`` is exactly the draw the
                            master adds over the step from ``t_k``
  ``gain_i``                a ``gain`` block ``K`` when the gain is not the identity
  ``bias_i``                a ``sum`` block adding ``bias`` (when a bias is not 0)
  ========================  =================================================================

  Several sources are wired element by element into the first block (or the targets). Each
  block computes what the master computes, in the same order (``((0 + from) + (-offset)) +
  draw``, ``0 + sum_j K_ij v_j``, ``(0 + w) + bias``), so the lowered system's values equal
  the system's. Every one of these blocks feeds through (its output depends on its inputs):
  OMSimulator orders its exchange by those declared dependencies, as the master applies a
  connection, with no delay, and so follows the system itself; a Jacobi engine (fmpy,
  libcosim, the harness running the exported system, ``resolve_system(exported_system
  (spec))``) reads each block's output at ``t_k`` before its input of ``t_k`` is set, so the
  path lags one communication step per block on it (up to three: shift, gain, bias). The
  noise block has no input: its draws reach an estimator whose outputs do not depend on its
  inputs without a lag in both.
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
the file. The run's tolerance (``[run] tolerance``, :attr:`harness.system.SystemSpec.tolerance`),
when it has one, goes into that ``oms:FixedStepMaster`` as ``relativeTolerance`` and
``absoluteTolerance``: OMSimulator 3.0 reads them when it imports the SSP and passes the
relative one to every FMU's ``fmi2SetupExperiment``, as the harness does. Its command line
(``OMSimulator file.ssp``) then replaces both with its ``--tolerance`` option (default 1e-4):
pass the run's tolerance there too (``bench/check_omsimulator.py`` does).
"""

from __future__ import annotations

import re
import zipfile
from dataclasses import replace
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from harness.blocks.build import is_pythonfmu
from harness.blocks.signal_source import NOISE_DISTRIBUTIONS
from harness.master import Master
from harness.system import (
    ConnectionSpec,
    DescriptionError,
    FmuSpec,
    ResolvedConnection,
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
NOISE = "noise"
"""The name of the lowered system's noise block (the master's connection noise)."""


def lower_gains(spec: SystemSpec, block_cache: Path | None = None) -> SystemSpec:
    """The same system with every connection lowered to plain wires and block FMUs (the
    module docstring's table): gains, offsets, biases, the master's noise, several sources.

    Parameters
    ----------
    spec
        The system (its blocks built or not).
    block_cache
        Where the system's own blocks are built to resolve it (see
        :func:`harness.blocks.block_fmu`); the new blocks are left unbuilt.

    Returns
    -------
    SystemSpec
        The system with scalar wires only (``"fmu.var" -> "fmu.var"``).

    Raises
    ------
    ValueError
        The system already has an FMU of a block's name.

    Examples
    --------
    >>> from harness.cli import SCENARIO_DIR
    >>> from harness.system import load_system
    >>> spec = load_system(SCENARIO_DIR / "pendulum_nominal.toml",
    ...                    {"fmu_dir": "build/pendulum/native"})
    >>> sorted(lower_gains(spec).fmus)  # doctest: +SKIP
    ['gain_4', 'gain_5', 'gain_6', 'gain_7', 'kalman', 'linear', 'observer', 'plant']
    """
    system = resolve_system(build_blocks(spec, block_cache))
    noise = Master(system).noise_sources
    fmus = dict(spec.fmus)
    if noise:
        start = {"distribution": NOISE_DISTRIBUTIONS.index("gaussian"), "seed": spec.noise_seed,
                 **{f"size[{c + 1}]": std for c, std in enumerate(noise.values())}}
        _add_block(fmus, FmuSpec(NOISE, None, start, ("noise", (len(noise),))))
    columns = {name: c + 1 for c, name in enumerate(noise)}
    wires: list[ConnectionSpec] = []
    for i, conn in enumerate(system.connections, start=1):
        wires += _lowered(i, conn, columns, fmus)
    return replace(spec, fmus=fmus, connections=tuple(wires))


def _add_block(fmus: dict[str, FmuSpec], block: FmuSpec) -> None:
    if block.name in fmus:
        raise ValueError(f"cannot lower the connections: the system already has an FMU "
                         f"{block.name!r}")
    fmus[block.name] = block


def _lowered(i: int, conn: ResolvedConnection, columns: dict[str, int],
             fmus: dict[str, FmuSpec]) -> list[ConnectionSpec]:
    """Connection ``i`` as wires and blocks (added to ``fmus``); ``columns``: the noise
    block's output of each noisy source."""
    sources = [f"{f}.{v.name}" for f, v in conn.sources]
    wires: list[ConnectionSpec] = []
    constants: list[float] = []

    def constant(value: float) -> str:
        constants.append(float(value))
        return f"constant_{i}.y[{len(constants)}]"

    terms = [sources]
    if np.any(conn.offset != 0.0):
        terms.append([constant(-o) for o in conn.offset])
    if conn.noise is not None and np.any(conn.noise > 0.0):
        terms.append([f"{NOISE}.y[{columns[s]}]" if sigma > 0.0 else constant(0.0)
                      for s, sigma in zip(sources, conn.noise, strict=True)])
    values = _summed(f"shift_{i}", terms, fmus, wires)
    p, m = conn.gain.shape
    if p != m or not np.array_equal(conn.gain, np.eye(m)):
        start = {f"K[{r + 1},{c + 1}]": float(conn.gain[r, c]) for r in range(p) for c in range(m)}
        _add_block(fmus, FmuSpec(f"gain_{i}", None, start, ("gain", (p, m))))
        wires += [ConnectionSpec(v, f"gain_{i}.u[{j + 1}]") for j, v in enumerate(values)]
        values = [f"gain_{i}.y[{r + 1}]" for r in range(p)]
    if np.any(conn.bias != 0.0):
        values = _summed(f"bias_{i}", [values, [constant(b) for b in conn.bias]], fmus, wires)
    if constants:
        _add_block(fmus, FmuSpec(f"constant_{i}", None,
                                 {f"value[{k + 1}]": v for k, v in enumerate(constants)},
                                 ("constant", (len(constants),))))
    return wires + [ConnectionSpec(v, f"{f}.{t.name}")
                    for v, (f, t) in zip(values, conn.targets, strict=True)]


def _summed(name: str, terms: list[list[str]], fmus: dict[str, FmuSpec],
            wires: list[ConnectionSpec]) -> list[str]:
    """The element-wise sum of the signal lists ``terms``: the first itself when alone, else
    the outputs of a sum block ``name`` (added to ``fmus``, its inputs wired in ``wires``)."""
    if len(terms) == 1:
        return terms[0]
    width = len(terms[0])
    _add_block(fmus, FmuSpec(name, None, {}, ("sum", (width, len(terms)))))
    wires += [ConnectionSpec(signal, f"{name}.u[{k + 1},{j + 1}]")
              for k, term in enumerate(terms) for j, signal in enumerate(term)]
    return [f"{name}.y[{j + 1}]" for j in range(width)]


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
    lowered = lower_gains(spec, block_cache)
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


def identifier(name: str) -> str:
    """``name`` as the SSD's model and system name: OMSimulator takes only identifiers
    (letters, digits, ``_``, not a digit first), so every other character becomes ``_``.

    Examples
    --------
    >>> identifier("DC-Motor.SuT"), identifier("2nd")
    ('DC_Motor_SuT', '_2nd')
    """
    text = re.sub(r"\W", "_", name, flags=re.ASCII)
    return f"_{text}" if not text or text[0].isdigit() else text


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _ssd(system: ResolvedSystem, resources: dict[str, tuple[Path, str]]) -> ET.Element:
    for prefix, uri in NS.items():
        ET.register_namespace(prefix, uri)
    spec = system.spec
    name = identifier(spec.name)
    root = ET.Element(_q("ssd", "SystemStructureDescription"), version="1.0", name=name)
    sys_el = ET.SubElement(root, _q("ssd", "System"), name=name)
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
    _oms_annotation(sys_el, spec.step, spec.tolerance)
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


def _oms_annotation(system: ET.Element, step: float, tolerance: float | None) -> None:
    """OMSimulator's annotation of a system: a fixed-step master with the communication step
    and, if there is one, the run's tolerance (relative and absolute, as OMSimulator's
    ``--tolerance`` sets them)."""
    note = ET.SubElement(
        ET.SubElement(system, _q("ssd", "Annotations")),
        _q("ssc", "Annotation"),
        type="org.openmodelica",
    )
    info = ET.SubElement(
        ET.SubElement(note, _q("oms", "Annotations")), _q("oms", "SimulationInformation")
    )
    master = ET.SubElement(info, _q("oms", "FixedStepMaster"), description="oms-ma",
                           stepSize=repr(step))
    if tolerance is not None:
        master.set("absoluteTolerance", repr(tolerance))
        master.set("relativeTolerance", repr(tolerance))


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
