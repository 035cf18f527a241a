"""Build ``observer.fmu``, ``luenberger.fmu``, ``plant.fmu`` and, when the design has a Kalman
filter, ``kalman.fmu`` from an :class:`ObserverGains`.

Each FMU is a pythonfmu 0.7.0 co-simulation FMU whose ``resources/`` hold:

- ``fhobs_<tag>/``: the numpy-only fhobs modules the slave needs (``gains``,
  ``certificate``, ``runtime``, ``plant``, their fhobs imports, ``fmu/slave_base``), with
  every ``fhobs`` import renamed to ``fhobs_<tag>``; ``<tag>`` is a hash of the code and
  the design, so FMUs of different designs loaded in one process never share a module
  (pythonfmu shares ``sys.modules`` between the FMUs of a process, PythonFMU#228);
- ``fhobs_<kind>_<tag>.py``: the slave script, its class renamed ``Fhobs<Kind>_<tag>``;
- ``design.json`` and ``fmu_config.json``: read by each instance from its own resources.

On linux64 a small C wrapper (``fmu/status_wrapper.c``, compiled here with the system C
compiler) is placed in front of pythonfmu's binary so that rejected inputs and rejected
parameters are answered with ``fmi2Error`` (see :mod:`fhobs.fmu.slave_base`), and the runtime's
step kernel (``kernel.c``, :mod:`fhobs.kernel`) is compiled into the vendored package as
``kernel_linux64.so``: the models step in C inside the FMU. Without it (no compiler, another
platform, ``kernel=False``) the FMU runs the numpy runtime alone, with the same results to
round-off.
"""

from __future__ import annotations

import ast
import hashlib
import json
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from .certificate import certify
from .fmu.slave_base import CONFIG_FILE, DESIGN_FILE, STATUS_VALUE_REFERENCE
from .gains import ObserverGains
from .kernel import SHIPPED, SOURCE, compile_library
from .plant import PLANT_SCHEMES
from .runtime import SCHEMES

PACKAGE_DIR = Path(__file__).resolve().parent
SLAVE_SCRIPTS = {"observer": "observer.py", "luenberger": "luenberger.py", "plant": "plant.py",
                 "kalman": "kalman.py"}
DEFAULT_KINDS = ("observer", "luenberger", "plant")
"""Built by default; ``kalman`` too when the design has a Kalman filter."""
ALLOWED_THIRD_PARTY = {"numpy", "pythonfmu"}
DEFAULT_INPUT_BOUND = 1e8
_LIB_DIR = "binaries/linux64/"


class BuildError(RuntimeError):
    """The FMUs cannot be built (forbidden import, missing tool...)."""


def build_fmus(
    gains: ObserverGains,
    out_dir: Path,
    *,
    kinds: Iterable[str] | None = None,
    h: float = 5e-5,
    scheme: str | None = None,
    z0: Iterable[float] | None = None,
    psi0: Iterable[float] | None = None,
    xi0: float = 0.0,
    x0: Iterable[float] | None = None,
    noise_amplitude: float = 0.0,
    noise_seed: int = 0,
    plant_scheme: str = "zoh",
    input_bound: float = DEFAULT_INPUT_BOUND,
    status_wrapper: bool | None = None,
    kernel: bool | None = None,
) -> dict[str, Path]:
    """Build the requested FMUs into ``out_dir`` and return ``{kind: path}``.

    Parameters
    ----------
    gains : ObserverGains
        The certified design; it is re-certified here (numpy-only check) before building.
    out_dir : Path
        Created if missing; the FMUs are written as ``<kind>.fmu``.
    kinds : iterable of {"observer", "luenberger", "plant", "kalman"}, optional
        Default: ``DEFAULT_KINDS``, plus ``kalman`` when ``gains.kalman`` is set.
    h : float
        Start value of the observers' internal step.
    scheme : str, optional
        Start value of the observers' integration scheme (default: the runtime's first).
    z0, psi0, xi0 : optional
        Start values of the observers' initial state (default zero; the Kalman filter's
        disturbance states start at zero).
    x0 : iterable of float, optional
        Start value of the plant's initial state (default zero).
    noise_amplitude, noise_seed : float, int
        Start values of the plant's measurement noise.
    plant_scheme : str
        Start value of the plant's step scheme (``fhobs.plant.PLANT_SCHEMES``).
    input_bound : float
        Start value of every FMU's ``input_bound`` (larger inputs are rejected).
    status_wrapper : bool, optional
        Put the ``fmi2Error`` wrapper in front of pythonfmu's linux64 binary. Default: when
        a C compiler is found. True without a compiler raises :class:`BuildError`.
    kernel : bool, optional
        Ship the compiled step kernel (linux64). Default: on Linux when a C compiler is found.
        True without a compiler or on another platform raises :class:`BuildError`; False
        builds FMUs that run the numpy runtime alone.

    Returns
    -------
    dict of str to Path
    """
    if kinds is None:
        kinds = DEFAULT_KINDS + (("kalman",) if gains.kalman is not None else ())
    kinds = tuple(kinds)
    unknown = set(kinds) - set(SLAVE_SCRIPTS)
    if unknown:
        raise ValueError(f"unknown FMU kind(s) {sorted(unknown)}; known: {list(SLAVE_SCRIPTS)}")
    if "kalman" in kinds and gains.kalman is None:
        raise ValueError("kalman.fmu needs a design with a Kalman filter (gains.kalman is None; "
                         "give the spec a [noise] table)")
    certify(gains)
    compiler = shutil.which("cc") or shutil.which("gcc")
    if status_wrapper is None:
        status_wrapper = compiler is not None
    if status_wrapper and compiler is None:
        raise BuildError("status_wrapper=True needs a C compiler (cc or gcc) on PATH")
    if kernel is None:
        kernel = compiler is not None and sys.platform == "linux"
    if kernel and (compiler is None or sys.platform != "linux"):
        raise BuildError("kernel=True needs Linux and a C compiler (cc or gcc) on PATH")
    config = {
        "status_wrapper": status_wrapper,
        "kernel": kernel,
        "input_bound": float(input_bound),
        "h": float(h),
        "scheme": SCHEMES[0] if scheme is None else scheme,
        "z0": _vector(z0, gains.n),
        "psi0": _vector(psi0, gains.k),
        "xi0": float(xi0),
        "x0": _vector(x0, gains.n),
        "noise_amplitude": float(noise_amplitude),
        "noise_seed": int(noise_seed),
        "plant_scheme": plant_scheme,
    }
    if config["scheme"] not in SCHEMES:
        raise ValueError(f"scheme {config['scheme']!r} is not one of {SCHEMES}")
    if plant_scheme not in PLANT_SCHEMES:
        raise ValueError(f"plant_scheme {plant_scheme!r} is not one of {PLANT_SCHEMES}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fhobs_build_") as tmp:
        stage = Path(tmp)
        design_json = json.dumps(gains.to_dict(), indent=1)
        tag = build_tag(design_json + json.dumps(config, sort_keys=True))
        package = stage / f"fhobs_{tag}"
        vendor_modules(package, tag)
        if kernel:
            _compile_kernel(package, compiler)
        (stage / DESIGN_FILE).write_text(design_json)
        (stage / CONFIG_FILE).write_text(json.dumps(config, indent=1))
        wrapper = _compile_wrapper(stage, compiler) if status_wrapper else None
        built = {}
        for kind in kinds:
            script = _write_script(stage, kind, tag)
            built[kind] = _build_one(script, stage, package, out_dir / f"{kind}.fmu")
            if wrapper is not None:
                _install_wrapper(built[kind], wrapper)
        _forget_modules(stage, tag)
    return built


def _vector(value: Iterable[float] | None, size: int) -> list[float]:
    """A start vector as a list of floats (zeros by default), its length checked."""
    vector = np.zeros(size) if value is None else np.asarray(list(value), dtype=float)
    if vector.shape != (size,):
        raise ValueError(f"expected {size} values, got {vector.shape}")
    return vector.tolist()


def build_tag(extra: str) -> str:
    """Hash of the code shipped in the FMUs and of ``extra`` (design + options), 12 hex digits."""
    digest = hashlib.sha256(extra.encode())
    for path in sorted(PACKAGE_DIR.rglob("*.py")) + [PACKAGE_DIR / "fmu" / "status_wrapper.c",
                                                     SOURCE]:
        digest.update(path.relative_to(PACKAGE_DIR).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def fhobs_imports(path: Path) -> set[str]:
    """Module files (relative to the package) that a source file imports from fhobs.

    Raises
    ------
    BuildError
        If the file imports anything but the standard library, numpy, pythonfmu and fhobs.
    """
    tree = ast.parse(path.read_text(), filename=str(path))
    here = path.parent.relative_to(PACKAGE_DIR).parts
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [(alias.name, ()) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [_absolute(node, here, alias.name) for alias in node.names]
        else:
            continue
        for module, fromlist in names:
            top = module.split(".")[0]
            if top == "fhobs":
                found |= _module_files(module, fromlist)
            elif top not in ALLOWED_THIRD_PARTY and top not in sys.stdlib_module_names:
                raise BuildError(f"{path.name} imports {module!r}: FMU code must be numpy-only")
    return found


def _absolute(node: ast.ImportFrom, here: tuple[str, ...], name: str) -> tuple[str, tuple]:
    """(absolute module, (imported name,)) of one ``from X import name``."""
    if node.level == 0:
        return node.module, (name,)
    base = ("fhobs",) + here[: len(here) - node.level + 1]
    return ".".join(base + ((node.module,) if node.module else ())), (name,)


def _module_files(module: str, fromlist: tuple) -> set[str]:
    """Existing package files for ``module`` and for ``module.name`` submodules."""
    files = set()
    for dotted in [module] + [f"{module}.{name}" for name in fromlist]:
        parts = dotted.split(".")[1:]
        if not parts:
            continue
        for candidate in (Path(*parts).with_suffix(".py"), Path(*parts, "__init__.py")):
            if (PACKAGE_DIR / candidate).is_file():
                files.add(candidate.as_posix())
    return files


def vendored_files() -> list[str]:
    """Package files the slave scripts need, found by following their fhobs imports."""
    todo = [f"fmu/{script}" for script in SLAVE_SCRIPTS.values()]
    seen: set[str] = set()
    while todo:
        rel = todo.pop()
        if rel in seen:
            continue
        seen.add(rel)
        todo.extend(fhobs_imports(PACKAGE_DIR / rel) - seen)
    scripts = {f"fmu/{script}" for script in SLAVE_SCRIPTS.values()}
    return sorted((seen - scripts) | {"fmu/__init__.py"})


def _rename_fhobs(source: str, tag: str) -> str:
    """Rewrite ``import fhobs...`` / ``from fhobs... import`` to the vendored package name."""
    return re.sub(r"^(\s*)(from|import)(\s+)fhobs\b", rf"\1\2\3fhobs_{tag}", source, flags=re.M)


def vendor_modules(package: Path, tag: str) -> None:
    """Copy the numpy-only modules into ``package`` (named ``fhobs_<tag>``), imports renamed."""
    package.mkdir()
    (package / "__init__.py").write_text(
        '"""numpy-only fhobs modules vendored into this FMU by fhobs.build."""\n'
    )
    for rel in vendored_files():
        target = package / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(_rename_fhobs((PACKAGE_DIR / rel).read_text(), tag))


def _write_script(stage: Path, kind: str, tag: str) -> Path:
    """The slave script with fhobs imports renamed and its class made build-unique."""
    source = _rename_fhobs((PACKAGE_DIR / "fmu" / SLAVE_SCRIPTS[kind]).read_text(), tag)
    source, count = re.subn(r"^class (Fhobs\w+)\(", rf"class \1_{tag}(", source, flags=re.M)
    if count != 1:
        raise BuildError(f"expected one slave class in {SLAVE_SCRIPTS[kind]}, found {count}")
    script = stage / f"fhobs_{kind}_{tag}.py"
    script.write_text(source)
    return script


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


def _compile_wrapper(stage: Path, compiler: str) -> Path:
    """Compile ``fmu/status_wrapper.c`` for linux64 (FMI headers: fmpy's copy)."""
    import fmpy

    source = PACKAGE_DIR / "fmu" / "status_wrapper.c"
    library = stage / "status_wrapper.so"
    command = [
        compiler, "-shared", "-fPIC", "-O2", f"-DFHOBS_STATUS_VR={STATUS_VALUE_REFERENCE}",
        f"-I{Path(fmpy.__file__).parent / 'c-code'}", "-o", str(library), str(source), "-ldl",
        "-lpthread",
    ]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise BuildError(f"compiling the status wrapper failed:\n{result.stderr}")
    return library


def _compile_kernel(package: Path, compiler: str) -> None:
    """Compile ``kernel.c`` into the vendored package, where its ``fhobs.kernel`` finds it."""
    try:
        compile_library(package / SHIPPED.name, compiler)
    except (OSError, subprocess.SubprocessError) as err:
        detail = getattr(err, "stderr", None) or err
        raise BuildError(f"compiling the step kernel failed:\n{detail}") from err


def _install_wrapper(fmu: Path, wrapper: Path) -> None:
    """Rename pythonfmu's linux64 library ``<id>_pythonfmu.so``; the wrapper becomes ``<id>.so``."""
    rebuilt = fmu.with_suffix(".tmp")
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(rebuilt, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename.startswith(_LIB_DIR) and item.filename.endswith(".so"):
                stem = item.filename[: -len(".so")]
                dst.writestr(f"{stem}_pythonfmu.so", data)
                dst.write(wrapper, item.filename)
            else:
                dst.writestr(item, data)
    rebuilt.replace(fmu)


def _forget_modules(stage: Path, tag: str) -> None:
    """Undo what pythonfmu's builder leaves in this process: sys.path entry, imported modules."""
    while str(stage) in sys.path:
        sys.path.remove(str(stage))
    for name in [m for m in sys.modules if tag in m]:
        del sys.modules[name]

