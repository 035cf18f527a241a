"""Build ``observer.fmu``, ``luenberger.fmu``, ``prescribed_time.fmu``, ``plant.fmu`` and, when
the design has the ``[noise]`` table's records, ``kalman.fmu`` and ``supervised.fmu`` from an
:class:`ObserverDesign`.

Each FMU is a pythonfmu 0.7.0 co-simulation FMU whose ``resources/`` hold:

- ``fhobs_<kind>_<tag>/``: a copy of :mod:`fhobs.core` (the numpy-only maths) and of
  :mod:`fhobs.fmu` (the slave classes), taken whole: both import only relatively, numpy,
  pythonfmu and the standard library. ``<tag>`` is a hash of that code, the design and the
  options, and ``<kind>`` the FMU's kind, so two FMUs loaded in one process never share a module
  (pythonfmu shares ``sys.modules`` between the FMUs of a process), not even the
  FMUs of one design;
- ``slave_<kind>_<tag>.py``: the slave script, a subclass ``Fhobs<Kind>_<tag>`` of the slave
  class in ``fhobs_<kind>_<tag>.fmu``;
- ``design.json`` and ``fmu_config.json``: read by each instance from its own resources.

The modelDescription names the plant's signals (:mod:`fhobs.model_description`: descriptions,
units, the model name), rewritten after pythonfmu's builder.

On linux64 a small C wrapper (``fmu/status_wrapper.c``, compiled here with the system C
compiler) is placed in front of pythonfmu's binary so that rejected inputs and rejected
parameters are answered with ``fmi2Error`` (see :mod:`fhobs.fmu.slave_base`), and the runtime's
step kernel (``core/kernel.c``, :mod:`fhobs.core.kernel`) is compiled into the shipped core as
``kernel_linux64.so``: the models step in C inside the FMU. Without it (no compiler, another
platform, ``kernel=False``) the FMU runs the numpy runtime alone, with the same results to
round-off.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .core.cache_files import cache_unusable, is_fmu, trusted
from .core.certificate import certify
from .core.gains import ObserverDesign
from .core.kernel import (
    HEADER,
    LIBRARY_FLAGS,
    SHIPPED,
    SOURCE,
    cache_dir,
    cached_build,
    replaced_atomically,
)
from .design.signals import SignalNames
from .errors import BuildError
from .fmu import call_rules
from .fmu.kinds import KINDS, Kind
from .fmu.modes import STATUS_VALUE_REFERENCE
from .fmu.options import default_kinds, fmu_options
from .fmu.slave_base import CONFIG_FILE, DESIGN_FILE
from .model_description import describe, naming_options

PACKAGE_DIR = Path(__file__).resolve().parent
SHIPPED_PACKAGES = ("core", "fmu")
"""The subpackages of fhobs copied whole into each FMU."""
_LIB_DIR = "binaries/linux64/"
PYTHON_RECORD = "resources/fhobs_python.txt"
MODEL_DESCRIPTION = "modelDescription.xml"
"""Where the status wrapper finds :func:`python_record` in an FMU."""


def build_fmus(
    design: ObserverDesign,
    out_dir: Path,
    *,
    kinds: Iterable[str] | None = None,
    status_wrapper: bool | None = None,
    kernel: bool | None = None,
    names: SignalNames | None = None,
    plant_name: str | None = None,
    **options: Any,
) -> dict[str, Path]:
    """Build the requested FMUs into ``out_dir`` and return ``{kind: path}``.

    Parameters
    ----------
    design : ObserverDesign
        The certified design; it is re-certified here (numpy-only check) before building.
    out_dir : Path
        Created if missing; the FMUs are written as ``<kind>.fmu``.
    kinds : iterable of str, optional
        Among :data:`fhobs.fmu.kinds.KINDS`: observer, luenberger, plant, kalman,
        supervised, prescribed_time. Default: all whose record the design has
        (:func:`default_kinds`).
    status_wrapper : bool, optional
        Put the ``fmi2Error`` wrapper in front of pythonfmu's linux64 binary. Default: when
        a C compiler is found. True without a compiler raises :class:`BuildError`.
    kernel : bool, optional
        Ship the compiled step kernel (linux64). Default: on Linux when a C compiler is found.
        True without a compiler or on another platform raises :class:`BuildError`; False
        builds FMUs that run the numpy runtime alone.
    names : SignalNames, optional
        The names and units of the plant's signals (a spec's ``spec.names``), written into
        the modelDescriptions (:mod:`fhobs.model_description`); default ``x[i]``, ``u[i]``...
    plant_name : str, optional
        The plant's name (``spec.name``) for the modelDescriptions' description.
    **options
        Start values of the setting parameters, as for :func:`fmu_options` (``h``,
        ``scheme``, ``z0``, ``psi0``, ``xi0``, ``T0``, ``x0``, ``noise_amplitude``,
        ``noise_seed``, ``plant_scheme``, ``input_bound``).

    Returns
    -------
    dict of str to Path

    Examples
    --------
    >>> import tempfile
    >>> from fhobs.design.observer import design_observer
    >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> built = build_fmus(design, tempfile.mkdtemp(), kinds=("observer", "plant"),
    ...                    x0=[1.0, 0.0], status_wrapper=False, kernel=False)
    >>> sorted(path.name for path in built.values())
    ['observer.fmu', 'plant.fmu']
    """
    kinds = tuple(default_kinds(design) if kinds is None else kinds)
    unknown = set(kinds) - set(KINDS)
    if unknown:
        raise ValueError(f"unknown FMU kind(s) {sorted(unknown)}; known: {list(KINDS)}")
    compiler = shutil.which("cc") or shutil.which("gcc")
    if status_wrapper is None:
        status_wrapper = compiler is not None
    if status_wrapper and compiler is None:
        raise BuildError("status_wrapper=True needs a C compiler (cc or gcc) on PATH")
    if kernel is None:
        kernel = compiler is not None and sys.platform == "linux"
    if kernel and (compiler is None or sys.platform != "linux"):
        raise BuildError("kernel=True needs Linux and a C compiler (cc or gcc) on PATH")
    certify(design)
    config = {"status_wrapper": status_wrapper, "kernel": kernel,
              **fmu_options(design, kinds, **options),
              **naming_options(design, names, plant_name)}
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fhobs_build_") as tmp:
        stage = Path(tmp)
        design_json = json.dumps(design.to_dict(), indent=1)
        tag = build_tag(design_json + json.dumps(config, sort_keys=True))
        library = _compile_kernel() if kernel else None
        (stage / DESIGN_FILE).write_text(design_json)
        (stage / CONFIG_FILE).write_text(json.dumps(config, indent=1))
        wrapper = _compile_wrapper() if status_wrapper else None
        built = {}
        made_of = _fmu_key(tag, wrapper, library)
        for kind in kinds:
            dest = out_dir / f"{kind}.fmu"
            key = f"{kind}_{made_of}"
            if _from_cache(key, dest):
                built[kind] = dest
                continue
            package = stage / package_name(kind, tag)
            ship_package(package, library)
            script = _write_script(stage, kind, tag)
            built[kind] = _build_one(script, stage, package, dest)
            _finish(built[kind], KINDS[kind], config, wrapper)
            _to_cache(key, built[kind])
        _forget_modules(stage, tag)
    return built


def build_tag(extra: str) -> str:
    """Hash of the code shipped in the FMUs and of ``extra`` (design + options), 12 hex digits."""
    digest = hashlib.sha256(extra.encode())
    for path in sorted(_shipped_files()) + [PACKAGE_DIR / "fmu" / "status_wrapper.c", SOURCE,
                                            HEADER]:
        digest.update(path.relative_to(PACKAGE_DIR).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def _shipped_files() -> list[Path]:
    """The Python files copied into each FMU (those of ``SHIPPED_PACKAGES``)."""
    return [path for sub in SHIPPED_PACKAGES for path in (PACKAGE_DIR / sub).rglob("*.py")]


def package_name(kind: str, tag: str) -> str:
    """Name of the package shipped in the ``kind`` FMU of build ``tag``: ``fhobs_<kind>_<tag>``."""
    return f"fhobs_{kind}_{tag}"


def ship_package(package: Path, kernel_library: Path | None) -> None:
    """Copy :mod:`fhobs.core` and :mod:`fhobs.fmu` whole into ``package`` (their imports are
    relative), with the compiled step kernel ``kernel_library`` (if any) beside the core."""
    package.mkdir()
    (package / "__init__.py").write_text(
        '"""fhobs.core and fhobs.fmu, shipped in this FMU by fhobs.build."""\n'
    )
    for sub in SHIPPED_PACKAGES:
        shutil.copytree(PACKAGE_DIR / sub, package / sub,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.so", "*.c", "*.h"))
    if kernel_library is not None:
        shutil.copy2(kernel_library, package / "core" / SHIPPED.name)


def _write_script(stage: Path, kind: str, tag: str) -> Path:
    """The slave script: a build-unique subclass of the kind's slave class in the package
    (:func:`slave_script`): of ``fhobs.fmu.<slave_module>.<slave>``, or of the generic
    :class:`~fhobs.fmu.slave_base.ObserverSlave` with the kind's declaration."""
    declared = KINDS[kind]
    base, module = declared.slave, declared.slave_module
    package = package_name(kind, tag)
    if module:
        summary = f":class:`fhobs.fmu.{module}.{base}`"
        definition = (f"from {package}.fmu import {module} as _slaves\n\n\n"
                      f"class {base}_{tag}(_slaves.{base}):\n"
                      f'    """{base} under a class name unique to this build."""\n')
    else:
        summary = f":class:`fhobs.fmu.slave_base.ObserverSlave` of the {kind} kind"
        definition = (f"from {package}.fmu.kinds import KINDS as _kinds\n"
                      f"from {package}.fmu.slave_base import ObserverSlave as _base\n\n\n"
                      f"class {base}_{tag}(_base):\n"
                      f'    """{base} under a class name unique to this build."""\n\n'
                      f"    kind = _kinds[{kind!r}]\n")
    script = stage / f"slave_{kind}_{tag}.py"
    script.write_text(slave_script(f"The {kind} FMU of build {tag}: {summary}.",
                                   f"{base}_{tag}", definition))
    return script


def slave_script(summary: str, class_name: str, definition: str) -> str:
    """The text of a pythonfmu slave script whose ``definition`` (source code) defines the
    slave class ``class_name``, guarded against pythonfmu 0.7.0.

    pythonfmu runs the script again, in the module's namespace, at every instantiation, keeps
    the class it finds there, inserts the resources folder into ``sys.path`` once more and
    releases one reference to the namespace too many. So that an instantiate/free cycle
    leaves nothing behind, the script defines the class only on its first run (a class per
    run stayed alive: 6 KB for an fhobs slave, 36 KB for a harness block with its module),
    removes the repeated folder from ``sys.path`` and takes back the released reference
    (``Py_IncRef`` of the namespace) at every run.

    Examples
    --------
    >>> text = slave_script("A block.", "Gain2", "class Gain2(Base):\\n    pass\\n")
    >>> "except NameError:\\n    class Gain2(Base):" in text
    True
    """
    body = "".join(f"    {line}" if line.strip() else line
                   for line in definition.splitlines(keepends=True))
    return (
        f'"""{summary}\n\n'
        "pythonfmu runs this script at every instantiation, in this module's namespace, and\n"
        "releases one reference to the namespace too many: the class is defined once, the\n"
        'reference taken back and the resources folder kept once in sys.path."""\n\n'
        "import ctypes\n"
        "import sys\n\n"
        "ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))\n"
        "while sys.path.count(sys.path[0]) > 1:\n"
        "    sys.path.remove(sys.path[0])\n"
        "try:\n"
        f"    {class_name}\n"
        "except NameError:\n"
        f"{body}"
        f"{class_name} = {class_name}  # the one class pythonfmu finds in this run's names\n"
    )


FMU_CACHE_KEPT = 200
"""How many built FMUs the user's cache keeps (:func:`_to_cache`; the oldest go beyond)."""


def _fmu_key(tag: str, wrapper: Path | None, library: Path | None) -> str:
    """What the FMUs of build ``tag`` are made of (each kind's cache key is its name and
    this): the tag (the shipped code, the design and the options), this module (how an FMU is
    put together), pythonfmu's version, the interpreter the status wrapper is told about
    (:func:`python_record`) and the compiled wrapper and kernel; 24 hex digits."""
    import pythonfmu

    digest = hashlib.sha256(f"{tag} {pythonfmu.__version__}".encode())
    digest.update(Path(__file__).read_bytes())
    digest.update(python_record().encode())
    for binary in (wrapper, library):
        digest.update(b"-" if binary is None else binary.read_bytes())
    return digest.hexdigest()[:24]


def _from_cache(key: str, dest: Path) -> bool:
    """Copy the FMU built earlier from the same inputs (:func:`_fmu_key`) to ``dest``, if the
    user's cache has it and it is trusted (:func:`fhobs.core.cache_files.trusted`: this user's,
    an FMU): rebuilding an unchanged design is a file copy."""
    try:
        cached = cache_dir() / "fmus" / f"{key}.fmu"
        if not trusted(cached, is_fmu):
            return False
        shutil.copyfile(cached, dest)
    except OSError:
        return False
    return True


def _to_cache(key: str, fmu: Path) -> None:
    """Keep a copy of the freshly built ``fmu`` in the user's cache (:func:`cache_copy`); the
    oldest beyond :data:`FMU_CACHE_KEPT` are removed. A cache that cannot be written is
    skipped (one warning line)."""
    try:
        folder = cache_dir() / "fmus"
    except OSError:
        return
    try:
        folder.mkdir(mode=0o700, exist_ok=True)
        cache_copy(fmu, folder / f"{key}.fmu")
        kept = sorted(folder.glob("*.fmu"), key=lambda path: path.stat().st_mtime)
        for old in kept[:-FMU_CACHE_KEPT]:
            old.unlink(missing_ok=True)
    except OSError as err:
        cache_unusable(folder, err)


def cache_copy(source: Path, target: Path) -> None:
    """Copy ``source`` to ``target`` in the user's cache: written under another name, then
    renamed, so that a concurrent build never reads a partial file (the partial file is
    removed if the copy fails).

    Raises
    ------
    OSError
        If the cache cannot be written.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = (folder / "a.o").write_bytes(b"object")
    >>> cache_copy(folder / "a.o", folder / "b.o")
    >>> (folder / "b.o").read_bytes(), sorted(p.name for p in folder.iterdir())
    (b'object', ['a.o', 'b.o'])
    """
    with replaced_atomically(target) as partial:
        shutil.copyfile(source, partial)


def _build_one(script: Path, stage: Path, package: Path, dest: Path) -> Path:
    """Run pythonfmu's builder on one slave script."""
    from pythonfmu import FmuBuilder

    dest.unlink(missing_ok=True)
    return FmuBuilder.build_FMU(
        script,
        dest=dest,
        project_files=[package, stage / DESIGN_FILE, stage / CONFIG_FILE],
        canGetAndSetFMUstate=True,
        canSerializeFMUstate=True,
    )


def _compile_wrapper() -> Path:
    """``fmu/status_wrapper.c`` compiled for linux64 (FMI headers: fmpy's copy; this
    interpreter's Python.h, for the types of the PyConfig it starts Python with), once per
    machine (:func:`fhobs.core.kernel.cached_build`; the call-rules header it includes is
    written to a folder named by its content)."""
    import fmpy

    header = call_rules.c_header()
    include = _header_folder(call_rules.HEADER, header)
    flags = ("-shared", "-fPIC", "-O2", f"-DFHOBS_STATUS_VR={STATUS_VALUE_REFERENCE}",
             f"-I{Path(fmpy.__file__).parent / 'c-code'}", f"-I{include}",
             f"-I{sysconfig.get_paths()['include']}")
    return _cached(PACKAGE_DIR / "fmu" / "status_wrapper.c", "fhobs_status_wrapper", flags,
                   ("-ldl", "-lpthread"), (include / call_rules.HEADER,), "the status wrapper")


def _header_folder(name: str, text: str) -> Path:
    """A folder holding the header ``name`` with the content ``text``: in the user's cache,
    named by the content (written there once; a file there that is not this user's alone or
    differs is written again), else a private temporary folder."""

    def this_header(path: Path) -> bool:
        """the header of this build: its text"""
        return path.read_text() == text

    try:
        folder = cache_dir() / f"{Path(name).stem}_{hashlib.sha256(text.encode()).hexdigest()[:16]}"
    except OSError:
        folder = None
    if folder is not None:
        try:
            folder.mkdir(mode=0o700, exist_ok=True)
            if not trusted(folder / name, this_header):
                with replaced_atomically(folder / name) as partial:
                    partial.write_text(text)
            return folder
        except OSError as err:
            cache_unusable(folder, err)
    folder = Path(tempfile.mkdtemp(prefix="fhobs_headers_"))
    (folder / name).write_text(text)
    return folder


def _compile_kernel() -> Path:
    """``core/kernel.c`` compiled as :mod:`fhobs.core.kernel` ships it, once per machine."""
    return _cached(SOURCE, "fhobs_kernel", LIBRARY_FLAGS, ("-lm",), (HEADER,), "the step kernel")


def _cached(source: Path, prefix: str, flags: tuple[str, ...], libs: tuple[str, ...],
            depends: tuple[Path, ...], what: str) -> Path:
    """:func:`fhobs.core.kernel.cached_build`, its failures as :class:`BuildError`."""
    try:
        library = cached_build(source, prefix, flags, libs, depends)
    except (OSError, subprocess.SubprocessError) as err:
        detail = getattr(err, "stderr", None) or err
        if isinstance(detail, bytes):
            detail = detail.decode(errors="replace")
        raise BuildError(f"compiling {what} failed:\n{detail}") from err
    if library is None:
        raise BuildError(f"compiling {what} needs a C compiler (cc or gcc) on PATH")
    return library


def python_record() -> str:
    """The facts about this interpreter that the status wrapper reads in a native host.

    ``status_wrapper.c`` reads them from ``resources/fhobs_python.txt`` when no Python is in
    the importer's process: the Python version, its shared library, its prefix
    (``sys.base_prefix``), its executable (``sys.executable``, whose prefix and virtual
    environment the embedded interpreter takes) and the directory that holds numpy.
    An empty ``library`` (an interpreter without a shared libpython) or paths missing on the
    importing machine make the wrapper search the usual places.

    Returns
    -------
    str
        Lines ``key=value`` (``version``, ``library``, ``home``, ``executable``, ``site``)
        after a comment.

    Examples
    --------
    >>> record = dict(line.split("=", 1) for line in python_record().splitlines()
    ...               if not line.startswith("#"))
    >>> sorted(record)
    ['executable', 'home', 'library', 'site', 'version']
    >>> record["version"] == "{}.{}".format(*sys.version_info[:2])
    True
    """
    import numpy

    libdir = Path(sysconfig.get_config_var("LIBDIR") or Path(sys.base_prefix) / "lib")
    names = [sysconfig.get_config_var(key) for key in ("INSTSONAME", "LDLIBRARY")]
    found = [libdir / name for name in names
             if name and ".so" in name and (libdir / name).is_file()]
    lines = [
        "# The Python that built this FMU (read by the status wrapper in a native host)",
        "version={}.{}".format(*sys.version_info[:2]),
        f"library={found[0] if found else ''}",
        f"home={sys.base_prefix}",
        f"executable={sys.executable}",
        f"site={Path(numpy.__file__).resolve().parent.parent}",
    ]
    return "\n".join(lines) + "\n"


def _finish(fmu: Path, kind: Kind, config: dict[str, Any], wrapper: Path | None) -> None:
    """Rewrite pythonfmu's FMU: its modelDescription names the plant's signals
    (:func:`fhobs.model_description.describe`); with a status ``wrapper``, pythonfmu's linux64
    library is renamed ``<id>_pythonfmu.so``, the wrapper becomes ``<id>.so`` and
    :func:`python_record` is written as ``resources/fhobs_python.txt`` for it."""
    rebuilt = fmu.with_suffix(".tmp")
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(rebuilt, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == MODEL_DESCRIPTION:
                root = ET.fromstring(data)
                describe(root, kind, config["signals"], config["plant_name"])
                dst.writestr(item, ET.tostring(root, encoding="UTF-8", xml_declaration=True))
            elif (wrapper is not None and item.filename.startswith(_LIB_DIR)
                  and item.filename.endswith(".so")):
                stem = item.filename[: -len(".so")]
                dst.writestr(f"{stem}_pythonfmu.so", data)
                dst.write(wrapper, item.filename)
            elif item.filename != PYTHON_RECORD:
                dst.writestr(item, data)
        if wrapper is not None:
            dst.writestr(PYTHON_RECORD, python_record())
    rebuilt.replace(fmu)


def _forget_modules(stage: Path, tag: str) -> None:
    """Undo what pythonfmu's builder leaves in this process: sys.path entry, imported modules."""
    while str(stage) in sys.path:
        sys.path.remove(str(stage))
    for name in [m for m in sys.modules if tag in m]:
        del sys.modules[name]

