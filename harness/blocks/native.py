"""Native harness blocks: every kind of :data:`harness.blocks.BLOCK_KINDS` as an FMU of compiled C.

A native block has the interface of the pythonfmu block of the same kind and dimensions (its
modelDescription is that block's, with this FMU's identity and capabilities): the same names,
value references, causalities, variabilities, start values and output dependencies. Its
binary is ``native_blocks.c`` (libc and libm only, no Python) compiled with the native FMUs'
compiler helper (:func:`fhobs.native.build.compile_binary`) from a generated unit
``sources/fhobs_fmu.c`` that holds the block's variable table, read from the modelDescription,
with the product's call-rules header (``fhobs_call_rules.h``, :mod:`fhobs.fmu.call_rules`) and,
for the seeded sources (``signal``, ``noise``), the product's noise generator
(``fhobs/native/noise.c``, the draws of :mod:`harness.blocks.signal_source`). So a host without
Python (OMSimulator, fmusim, the FMU Compliance Checker) runs a system with harness blocks, such
as an exported SSP (:func:`harness.ssp.export_ssp`).
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

from fhobs.core.cache_files import is_fmu, trusted

from harness.blocks.build import BLOCK_KINDS, block_fmu, default_cache_dir

HERE = Path(__file__).resolve().parent
C_SOURCES = ("native_blocks.c", "native_blocks.h")
"""The block layer's C files (in this folder), shipped in every native block's ``sources/``."""
NOISE_SOURCES = ("noise.c", "noise.h")
"""The product's noise generator (``fhobs/native``), shipped and compiled with the seeded
sources."""
KIND_MACROS = {"sine": "BLOCK_SINE", "constant": "BLOCK_CONSTANT", "gain": "BLOCK_GAIN",
               "sum": "BLOCK_SUM", "signal": "BLOCK_SIGNAL", "noise": "BLOCK_NOISE"}
"""The block kinds with a native version, and their ``BLOCK_KIND`` in ``native_blocks.c``."""
SEEDED = ("signal", "noise")
"""The kinds that draw from the noise generator."""
TYPES = {"Real": "TYPE_REAL", "Integer": "TYPE_INTEGER"}
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
        A key of :data:`harness.blocks.BLOCK_KINDS`, with its dimensions as for
        :func:`harness.blocks.block_fmu`.
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
    import fhobs.native
    from fhobs.errors import BuildError
    from fhobs.fmu import call_rules
    from fhobs.native.build import FMI_HEADERS, _fmi_headers, compile_binary

    if kind_name not in KIND_MACROS:
        raise BuildError(f"harness block {kind_name!r} has no native version (native blocks: "
                         f"{', '.join(KIND_MACROS)})")
    kind = BLOCK_KINDS[kind_name]
    reference = block_fmu(kind_name, dims, cache_dir)  # checks kind_name and dims
    dims = tuple(int(d) for d in dims)
    extra = NOISE_SOURCES if kind_name in SEEDED else ()
    shipped = {name: HERE / name for name in C_SOURCES} | {
        name: Path(fhobs.native.__file__).with_name(name) for name in extra}
    units = [name for name in extra if name.endswith(".c")]
    header = call_rules.c_header()
    digest = hashlib.sha256(repr((kind_name, dims)).encode() + reference.name.encode()
                            + Path(__file__).read_bytes() + header.encode())
    for name, path in shipped.items():
        digest.update(name.encode() + path.read_bytes())
    suffix = "x".join(str(d) for d in dims)
    identifier = f"harness_{kind.module}_{suffix}_native_{digest.hexdigest()[:10]}"
    guid = str(uuid.UUID(bytes=digest.digest()[:16]))
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = cache / f"{identifier}.fmu"
    if trusted(target, is_fmu):  # a cached FMU is used only if this user alone made it
        return target
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise BuildError("native harness blocks need a C compiler (cc or gcc) on PATH")
    root = ET.fromstring(zipfile.ZipFile(reference).read("modelDescription.xml"))
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        stage = Path(tmp) / "fmu"
        sources = stage / "sources"
        sources.mkdir(parents=True)
        (sources / "fhobs_fmu.c").write_text(block_unit(kind_name, dims, root, guid))
        (sources / call_rules.HEADER).write_text(header)
        for name, path in shipped.items():
            shutil.copy(path, sources / name)
        for name in FMI_HEADERS:  # the native FMUs' FMI headers (fmpy's copy)
            shutil.copy(_fmi_headers() / name, sources / name)
        compile_binary(sources, stage / "binaries" / "linux64" / f"{identifier}.so", compiler,
                       ["fhobs_fmu.c", *units])
        ET.ElementTree(native_model_description(root, identifier, guid, units)).write(
            stage / "modelDescription.xml", encoding="UTF-8", xml_declaration=True)
        built = Path(tmp) / target.name
        with zipfile.ZipFile(built, "w", zipfile.ZIP_DEFLATED) as archive:
            for path in sorted(stage.rglob("*")):
                if path.is_file():
                    archive.write(path, path.relative_to(stage).as_posix())
        shutil.move(str(built), target)
    return target


def block_unit(kind_name: str, dims: tuple[int, ...], model_description: ET.Element,
               guid: str) -> str:
    """The generated translation unit ``fhobs_fmu.c`` of a native block.

    Parameters
    ----------
    kind_name
        A key of :data:`KIND_MACROS`.
    dims
        The block's dimensions: ``N_<NAME>`` macros (``N_OUTPUTS``, ``N_INPUTS``, ``N_TERMS``)
        of the kind's dimension names.
    model_description
        The root of the pythonfmu block's modelDescription: its variables (Real or Integer),
        in value-reference order, become the C variable table, and the first value reference
        of each array or scalar (``K``, ``u``, ``y``, ``seed``, ...) a ``VR_<NAME>`` macro.
    guid
        The FMU's GUID (``fmi2Instantiate`` checks it).

    Returns
    -------
    str
        C source that defines the block and includes ``native_blocks.c``.

    Raises
    ------
    ValueError
        If a variable is neither Real nor Integer, the variables are not numbered 0, 1, ... in
        order, or an array's elements are not contiguous.

    Examples
    --------
    >>> root = ET.fromstring(
    ...     '<m><ModelVariables>'
    ...     '<ScalarVariable name="K[1,1]" valueReference="0" causality="parameter" '
    ...     'variability="tunable"><Real start="0"/></ScalarVariable>'
    ...     '<ScalarVariable name="u[1]" valueReference="1" causality="input">'
    ...     '<Real start="0"/></ScalarVariable>'
    ...     '<ScalarVariable name="y[1]" valueReference="2" causality="output">'
    ...     '<Real start="0"/></ScalarVariable></ModelVariables></m>')
    >>> print(block_unit("gain", (1, 1), root, "g").splitlines()[4])
    #define BLOCK_KIND BLOCK_GAIN
    """
    rows, first, count = [], {}, {}
    for index, var in enumerate(model_description.iterfind("ModelVariables/ScalarVariable")):
        name = var.get("name")
        typed = [child for child in var if child.tag in TYPES]
        if int(var.get("valueReference")) != index or len(typed) != 1:
            raise ValueError(f"block variable {name}: expected the Real or Integer variable of "
                             f"value reference {index}")
        base = re.sub(r"\[.*", "", name)
        if base in first and first[base] + count[base] != index:
            raise ValueError(f"block variable {name}: the elements of {base} are not contiguous")
        first.setdefault(base, index)
        count[base] = count.get(base, 0) + 1
        start = float(typed[0].get("start", "0"))
        rows.append(f'    {{"{name}", {_role(var)}, {TYPES[typed[0].tag]}, {start.hex()}}},')
    sizes = {name.removeprefix("n_").upper(): int(d)
             for name, d in zip(BLOCK_KINDS[kind_name].dimensions, dims, strict=True)}
    defines = [f"#define BLOCK_KIND {KIND_MACROS[kind_name]}",
               f'#define BLOCK_IDENTITY "{guid}"',
               f"#define N_VARIABLES {len(rows)}",
               *(f"#define N_{key} {value}" for key, value in sizes.items()),
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


def _role(var: ET.Element) -> str:
    """The variable's ``ROLE_*`` of ``native_blocks.h`` (causality, and a parameter's
    variability)."""
    causality = var.get("causality")
    if causality == "parameter":
        return "ROLE_FIXED" if var.get("variability") == "fixed" else "ROLE_TUNABLE"
    return {"input": "ROLE_INPUT", "output": "ROLE_OUTPUT"}[causality]


def native_model_description(reference: ET.Element, identifier: str, guid: str,
                             units: list[str] | tuple[str, ...] = ()) -> ET.Element:
    """The pythonfmu block's modelDescription with the native block's identity, capabilities
    (:data:`CAPABILITIES`) and source files (``fhobs_fmu.c`` and the other compiled ``units``);
    the variables and the model structure unchanged.

    Examples
    --------
    >>> root = ET.fromstring('<fmiModelDescription guid="x"><CoSimulation modelIdentifier="p"/>'
    ...                      '</fmiModelDescription>')
    >>> cosim = native_model_description(root, "blk", "g", ["noise.c"]).find("CoSimulation")
    >>> cosim.get("modelIdentifier"), [f.get("name") for f in cosim.iter("File")]
    ('blk', ['fhobs_fmu.c', 'noise.c'])
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
    files = ET.SubElement(cosim, "SourceFiles")
    for name in ("fhobs_fmu.c", *units):
        ET.SubElement(files, "File", name=name)
    return root
