"""Native harness blocks: the sine source and the matrix gain as FMUs of compiled C.

A native block has the interface of the pythonfmu block of the same kind and dimensions (its
modelDescription is that block's, with this FMU's identity and capabilities): the same names,
value references, causalities, variabilities, start values and output dependencies. Its
binary is ``native_blocks.c`` (libc and libm only, no Python) compiled with the native FMUs'
compiler helper (:func:`fhobs.native.build.compile_binary`) from a generated unit
``sources/fhobs_fmu.c`` that holds the block's variable table, read from the modelDescription.
So a host without Python (OMSimulator, fmusim, the FMU Compliance Checker) runs a system with
harness blocks, such as an exported SSP (:func:`harness.ssp.export_ssp`).
"""

from __future__ import annotations

import hashlib
import re
import shutil
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from harness.blocks.build import BLOCK_KINDS, SOURCE, block_fmu, default_cache_dir

HERE = Path(__file__).resolve().parent
C_SOURCES = ("native_blocks.c", "native_blocks.h")
"""The block layer's C files (in this folder), shipped in every native block's ``sources/``."""
KIND_MACROS = {"sine": "BLOCK_SINE", "gain": "BLOCK_GAIN"}
"""The block kinds with a native version, and their ``BLOCK_KIND`` in ``native_blocks.c``."""
ROLES = {"parameter": "ROLE_PARAMETER", "input": "ROLE_INPUT", "output": "ROLE_OUTPUT"}
CAPABILITIES = {
    "needsExecutionTool": "false",
    "canHandleVariableCommunicationStepSize": "true",
    "canInterpolateInputs": "false",
    "canBeInstantiatedOnlyOncePerProcess": "false",
    "canNotUseMemoryManagementFunctions": "false",
    "canGetAndSetFMUstate": "false",
    "canSerializeFMUstate": "false",
    "providesDirectionalDerivative": "false",
}
"""The modelDescription's ``<CoSimulation>`` attributes of a native block."""


def native_block_fmu(kind_name: str, dims: tuple[int, ...], cache_dir: Path | None = None) -> Path:
    """Path of the native block FMU ``kind_name`` with dimensions ``dims``, building it if needed.

    Parameters
    ----------
    kind_name
        A key of :data:`harness.blocks.BLOCK_KINDS` (``"sine"``: ``(n_outputs,)``; ``"gain"``:
        ``(n_outputs, n_inputs)``).
    dims
        Positive dimensions, one per name in the kind's ``dimensions``.
    cache_dir
        Where built FMUs are kept (the pythonfmu block whose interface it takes too);
        :func:`harness.blocks.default_cache_dir` if None.

    Returns
    -------
    Path
        The ``.fmu`` file (``binaries/linux64`` and ``sources/``).

    Raises
    ------
    fhobs.errors.BuildError
        For a kind without a native version (not in :data:`KIND_MACROS`), without a C
        compiler on PATH, or if compiling fails.

    Examples
    --------
    >>> import tempfile, zipfile
    >>> with tempfile.TemporaryDirectory() as cache:
    ...     fmu = native_block_fmu("gain", (1, 4), Path(cache))
    ...     names = zipfile.ZipFile(fmu).namelist()
    >>> sorted(n.split("/")[0] for n in names if n.endswith((".so", ".xml")))
    ['binaries', 'modelDescription.xml']
    """
    from fhobs.errors import BuildError
    from fhobs.native.build import FMI_HEADERS, _fmi_headers, compile_binary

    if kind_name not in KIND_MACROS:
        raise BuildError(f"harness block {kind_name!r} has no native version (native blocks: "
                         f"{', '.join(KIND_MACROS)})")
    kind = BLOCK_KINDS[kind_name]
    reference = block_fmu(kind_name, dims, cache_dir)  # checks kind_name and dims
    dims = tuple(int(d) for d in dims)
    digest = hashlib.sha256(repr((kind_name, dims)).encode() + SOURCE.read_bytes())
    for name in C_SOURCES:
        digest.update(name.encode() + (HERE / name).read_bytes())
    suffix = "x".join(str(d) for d in dims)
    identifier = f"harness_{kind.module}_{suffix}_native_{digest.hexdigest()[:10]}"
    guid = str(uuid.UUID(bytes=digest.digest()[:16]))
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = cache / f"{identifier}.fmu"
    if target.exists():
        return target
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise BuildError("native harness blocks need a C compiler (cc or gcc) on PATH")
    root = ET.fromstring(zipfile.ZipFile(reference).read("modelDescription.xml"))
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        stage = Path(tmp) / "fmu"
        sources = stage / "sources"
        sources.mkdir(parents=True)
        (sources / "fhobs_fmu.c").write_text(block_unit(kind_name, root, guid))
        for name in C_SOURCES:
            shutil.copy(HERE / name, sources / name)
        for name in FMI_HEADERS:  # the native FMUs' FMI headers (fmpy's copy)
            shutil.copy(_fmi_headers() / name, sources / name)
        compile_binary(sources, stage / "binaries" / "linux64" / f"{identifier}.so", compiler)
        ET.ElementTree(native_model_description(root, identifier, guid)).write(
            stage / "modelDescription.xml", encoding="UTF-8", xml_declaration=True)
        built = Path(tmp) / target.name
        with zipfile.ZipFile(built, "w", zipfile.ZIP_DEFLATED) as archive:
            for path in sorted(stage.rglob("*")):
                if path.is_file():
                    archive.write(path, path.relative_to(stage).as_posix())
        shutil.move(str(built), target)
    return target


def block_unit(kind_name: str, model_description: ET.Element, guid: str) -> str:
    """The generated translation unit ``fhobs_fmu.c`` of a native block.

    Parameters
    ----------
    kind_name
        ``"sine"`` or ``"gain"``.
    model_description
        The root of the pythonfmu block's modelDescription: its variables, in value-reference
        order, become the C variable table, and the first value reference of each array
        (``K``, ``u``, ``y``, ``amplitude``, ...) a ``VR_<NAME>`` macro.
    guid
        The FMU's GUID (``fmi2Instantiate`` checks it).

    Returns
    -------
    str
        C source that defines the block and includes ``native_blocks.c``.

    Raises
    ------
    ValueError
        If the variables are not Real, not numbered 0, 1, ... in order, or an array's elements
        are not contiguous.

    Examples
    --------
    >>> root = ET.fromstring(
    ...     '<m><ModelVariables>'
    ...     '<ScalarVariable name="K[1,1]" valueReference="0" causality="parameter">'
    ...     '<Real start="0"/></ScalarVariable>'
    ...     '<ScalarVariable name="u[1]" valueReference="1" causality="input">'
    ...     '<Real start="0"/></ScalarVariable>'
    ...     '<ScalarVariable name="y[1]" valueReference="2" causality="output">'
    ...     '<Real start="0"/></ScalarVariable></ModelVariables></m>')
    >>> print(block_unit("gain", root, "g").splitlines()[4])
    #define BLOCK_KIND BLOCK_GAIN
    """
    rows, first, count = [], {}, {}
    for index, var in enumerate(model_description.iterfind("ModelVariables/ScalarVariable")):
        name, real = var.get("name"), var.find("Real")
        if int(var.get("valueReference")) != index or real is None:
            raise ValueError(f"block variable {name}: expected the Real variable of value "
                             f"reference {index}")
        base = re.sub(r"\[.*", "", name)
        if base in first and first[base] + count[base] != index:
            raise ValueError(f"block variable {name}: the elements of {base} are not contiguous")
        first.setdefault(base, index)
        count[base] = count.get(base, 0) + 1
        start = float(real.get("start", "0"))
        rows.append(f'    {{"{name}", {ROLES[var.get("causality")]}, {start.hex()}}},')
    sizes = {"N_VARIABLES": len(rows), "N_OUTPUTS": count["y"]}
    if kind_name == "gain":
        sizes["N_INPUTS"] = count["u"]
    defines = [f"#define BLOCK_KIND {KIND_MACROS[kind_name]}",
               f'#define BLOCK_IDENTITY "{guid}"',
               *(f"#define {key} {value}" for key, value in sizes.items()),
               *(f"#define VR_{base.upper()} {vr}" for base, vr in first.items())]
    return "\n".join([
        "/* Generated by harness.blocks.native from the pythonfmu block's modelDescription: the",
        " * block's kind, sizes and variables. Compile this file (it includes native_blocks.c).",
        " */",
        '#include "native_blocks.h"',
        *defines,
        "static const BlockVariable VARIABLES[N_VARIABLES] = {",
        *rows,
        "};",
        '#include "native_blocks.c"',
        "",
    ])


def native_model_description(reference: ET.Element, identifier: str, guid: str) -> ET.Element:
    """The pythonfmu block's modelDescription with the native block's identity, capabilities
    (:data:`CAPABILITIES`) and source file; the variables and the model structure unchanged.

    Examples
    --------
    >>> root = ET.fromstring('<fmiModelDescription guid="x"><CoSimulation modelIdentifier="p"/>'
    ...                      '</fmiModelDescription>')
    >>> cosim = native_model_description(root, "blk", "g").find("CoSimulation")
    >>> cosim.get("modelIdentifier"), cosim.find("SourceFiles/File").get("name")
    ('blk', 'fhobs_fmu.c')
    """
    root = ET.fromstring(ET.tostring(reference))
    root.set("modelName", identifier)
    root.set("guid", guid)
    root.set("generationTool", "harness.blocks.native (compiled C, no Python at run time)")
    cosim = root.find("CoSimulation")
    cosim.set("modelIdentifier", identifier)
    for name, value in CAPABILITIES.items():
        cosim.set(name, value)
    for child in list(cosim):
        cosim.remove(child)
    ET.SubElement(ET.SubElement(cosim, "SourceFiles"), "File", name="fhobs_fmu.c")
    return root
