"""Build the utility blocks into FMUs on demand, into a cache directory.

Each (kind, dimensions) gets its own FMU whose Python module and class names encode the
dimensions and a hash of the block's source, so that two different blocks loaded in one
process never share a module (pythonfmu FMUs reuse the host's ``sys.modules``).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from fhobs.core.cache_files import is_fmu, trusted

from harness.fmu_files import description

CACHE_ENV = "FHOBS_HARNESS_CACHE"


SOURCE = Path(__file__).with_name("slaves.py")
"""The blocks' slave classes (one self-contained module, copied into every block FMU)."""


@dataclass(frozen=True)
class BlockKind:
    """A block template: the name of its FMUs' modules, its class in its source file
    (:data:`SOURCE` unless ``source_file`` names another module of this folder) and the names
    of its dimensions."""

    module: str
    class_name: str
    dimensions: tuple[str, ...]
    source_file: str = SOURCE.name

    @property
    def source(self) -> Path:
        return SOURCE.with_name(self.source_file)


BLOCK_KINDS: dict[str, BlockKind] = {
    "sine": BlockKind("sine_source", "SineSource", ("n_outputs",)),
    "constant": BlockKind("constant_source", "ConstantSource", ("n_outputs",)),
    "gain": BlockKind("matrix_gain", "MatrixGain", ("n_outputs", "n_inputs")),
    "sum": BlockKind("sum", "Sum", ("n_outputs", "n_terms")),
    "signal": BlockKind("signal_source", "SignalSource", ("n_outputs",), "signal_source.py"),
    "noise": BlockKind("noise_source", "NoiseSource", ("n_outputs",), "signal_source.py"),
}
"""The block kinds: :mod:`harness.blocks.slaves` (sine, constant, gain, sum) and the seeded
sources of :mod:`harness.blocks.signal_source` (``signal``: a step, ramp, sine or random walk
from a start time; ``noise``: uniform or Gaussian white noise). Each has a native build too
(:mod:`harness.blocks.native`)."""


def default_cache_dir() -> Path:
    """``$FHOBS_HARNESS_CACHE`` if set, else ``~/.cache/fhobs/harness-blocks``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env) if env else Path.home() / ".cache" / "fhobs" / "harness-blocks"


def _script(kind: BlockKind, dims: tuple[int, ...], digest: str) -> tuple[str, str]:
    """Module name and source of the generated slave script for ``kind`` with ``dims``: a
    subclass with the dimensions of the kind's class, imported from the block's copy of its
    source module (``<module>_slaves``), guarded against pythonfmu re-running the script
    (:func:`fhobs.build.slave_script`)."""
    from fhobs.build import slave_script

    suffix = "x".join(str(d) for d in dims)
    module = f"harness_{kind.module}_{suffix}_{digest}"
    class_name = f"{kind.class_name}{suffix}_{digest}"
    args = ", ".join(f"{name}={d}" for name, d in zip(kind.dimensions, dims, strict=True))
    definition = (
        f"from {module}_slaves import {kind.class_name}\n\n\n"
        f"class {class_name}({kind.class_name}):\n"
        f"    def __init__(self, **kwargs):\n"
        f"        super().__init__({args}, **kwargs)\n"
    )
    summary = f"Harness block {kind.class_name} of dimensions {dims}."
    return module, slave_script(summary, class_name, definition)


def block_fmu(kind_name: str, dims: tuple[int, ...], cache_dir: Path | None = None,
              native: bool = False) -> Path:
    """Path of the block FMU ``kind_name`` with dimensions ``dims``, building it if needed.

    Parameters
    ----------
    kind_name
        A key of :data:`BLOCK_KINDS` (``"sine"``, ``"constant"``, ``"signal"``, ``"noise"``:
        ``(n_outputs,)``; ``"gain"``: ``(n_outputs, n_inputs)``; ``"sum"``: ``(n_outputs,
        n_terms)``).
    dims
        Positive dimensions, one per name in the kind's ``dimensions``.
    cache_dir
        Where built FMUs are kept; :func:`default_cache_dir` if None.
    native
        The native block (compiled C, no Python at run time, the same interface:
        :func:`harness.blocks.native.native_block_fmu`) instead of the pythonfmu one.

    Returns
    -------
    Path
        The ``.fmu`` file.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as cache:
    ...     print(block_fmu("sine", (2,), Path(cache)).name)  # doctest: +ELLIPSIS
    harness_sine_source_2_....fmu
    """
    if native:
        from harness.blocks.native import native_block_fmu

        return native_block_fmu(kind_name, dims, cache_dir)
    kind = BLOCK_KINDS[kind_name]
    dims = tuple(int(d) for d in dims)
    if len(dims) != len(kind.dimensions) or min(dims) < 1:
        raise ValueError(
            f"block {kind_name!r} needs positive dimensions {kind.dimensions}, got {dims}"
        )
    digest = hashlib.sha256(kind.source.read_bytes() + SOURCE.read_bytes()
                            + Path(__file__).read_bytes()).hexdigest()[:10]
    module, text = _script(kind, dims, digest)
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = cache / f"{module}.fmu"
    if not trusted(target, is_fmu):  # a cached FMU is used only if this user alone made it
        _build(module, text, target, kind.source)
    return target


def is_pythonfmu(fmu: str | Path) -> bool:
    """Whether ``fmu`` is a pythonfmu FMU (its binary needs libpython at run time).

    Examples
    --------
    >>> is_pythonfmu(block_fmu("sine", (1,)))  # doctest: +SKIP
    True
    """
    return (description(fmu).generationTool or "").startswith("PythonFMU")


def native_by_default(own_fmus: Iterable[str | Path]) -> bool:
    """Whether a system whose own FMUs (its blocks aside) are the files ``own_fmus`` gets
    native blocks by default: when each of them is an FMU, none a pythonfmu one. A system of
    native FMUs then runs with no Python in any FMU (and its user has the C compiler they
    were built with); a file that is not an FMU is left for the system's resolution to
    report, with pythonfmu blocks.

    Examples
    --------
    >>> native_by_default([])
    True
    >>> native_by_default(["/nonexistent/plant.fmu"])
    False
    """
    try:
        return not any(is_pythonfmu(path) for path in own_fmus)
    except Exception:  # noqa: BLE001 - fmpy raises plain Exception for a file it cannot read
        return False


def _build(module: str, text: str, target: Path, source: Path) -> None:
    """Build the script ``text`` as module ``module``, with the block's ``source`` module as
    ``<module>_slaves``, into ``target`` (atomic rename)."""
    from pythonfmu import FmuBuilder

    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        script = Path(tmp) / f"{module}.py"
        script.write_text(text)
        slaves = Path(tmp) / f"{module}_slaves.py"
        shutil.copyfile(source, slaves)
        built = FmuBuilder.build_FMU(script, dest=tmp, project_files=[slaves],
                                     needsExecutionTool="false")
        shutil.move(str(built), target)
