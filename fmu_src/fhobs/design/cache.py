"""The user's cache of design computations (every design of a spec, the noise tuning's search):
a result is kept under a hash of everything it is made of (its inputs, the design layer's and
the runtime's source code, the numerical libraries' versions), in
``$XDG_CACHE_HOME/fhobs/designs``, and checked again when it is read (a design is certified
again: a cached design never skips its certificate).

The cache holds pickles written by this package in the user's private cache folder (the one
the compiled kernel is loaded from); a file is read only if it and its folder belong to the user
and no one else may write them (:func:`fhobs.core.cache_files.trusted`; one warning line
otherwise). A file that cannot be read, or whose result fails its check, is computed
again and replaced; deleting the folder only costs the next call its time. The folder keeps
the :data:`KEPT` most recently used files. With the environment variable
``FHOBS_NO_DESIGN_CACHE`` set (non-empty) every result is computed, nothing read or written.
"""

from __future__ import annotations

import hashlib
import os
import pickle
from collections.abc import Callable
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any, TypeVar

from ..core.cache_files import cache_unusable, trusted
from ..core.kernel import cache_dir, library, replaced_atomically
from ..errors import CertificateError

T = TypeVar("T")

LIBRARIES = ("fhobs", "numpy", "scipy", "cvxpy", "clarabel")
"""The packages whose version is part of every key: fhobs itself (an install without sources
still keys by its version) and the libraries whose numbers make the results."""
DISABLE_ENV = "FHOBS_NO_DESIGN_CACHE"
"""Set (non-empty): compute every result, read and write no file."""
KEPT = 2000
"""Files the folder keeps (the most recently used; a design's file is a few KB)."""
UNREADABLE = (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError,
              TypeError, ValueError, IndexError, CertificateError)
"""What reading a stale, partial or foreign cache file raises, and a result failing its check
(CertificateError is a ValueError; named for the reader)."""


def cached(kind: str, inputs: Any, compute: Callable[[], T], check: Callable[[T], Any],
           ) -> tuple[T, bool]:
    """``compute()``, or the result a previous call with equal ``inputs`` kept.

    Parameters
    ----------
    kind : str
        What is computed (a file-name prefix, e.g. ``"noise_tuning"``).
    inputs : object
        Everything the result depends on besides the code (picklable; equal inputs pickle
        to equal bytes: arrays, numbers, strings, tuples, dicts, dataclasses of these).
    compute : callable
        Makes the result (picklable) when the cache has none.
    check : callable
        Called on a result read from the cache; a CertificateError (or any error of
        :data:`UNREADABLE`) it raises discards the file (a design is certified again: a cached
        design never skips its certificate).

    Returns
    -------
    (result, from_cache)

    Examples
    --------
    >>> import tempfile, os
    >>> saved = os.environ.get("XDG_CACHE_HOME")
    >>> os.environ["XDG_CACHE_HOME"] = tempfile.mkdtemp()
    >>> cached("example", (1, 2), lambda: 3, check=int)
    (3, False)
    >>> cached("example", (1, 2), lambda: 4, check=int)
    (3, True)
    >>> _ = os.environ.pop("XDG_CACHE_HOME") if saved is None else os.environ.update(
    ...     XDG_CACHE_HOME=saved)
    """
    if os.environ.get(DISABLE_ENV):
        return compute(), False
    try:
        path = cache_dir() / "designs" / f"{kind}_{_key(inputs)}.pickle"
    except OSError:  # no cache folder to be had: computed every time
        return compute(), False
    if trusted(path):  # this user's alone (else one warning line): read
        try:
            result = pickle.loads(path.read_bytes())
            check(result)
            os.utime(path)  # recently used: the last to be dropped
            return result, True
        except UNREADABLE:
            pass  # a stale or partial file, or a result that fails its check
    result = compute()
    _write(path, result)
    return result, False


def _key(inputs: Any) -> str:
    """Hash of ``inputs``, the code, the libraries' versions and whether the runtime steps in
    the compiled kernel (the settling-time search runs it; its results differ from numpy's
    by round-off)."""
    digest = hashlib.sha256(_code_digest())
    digest.update(b"kernel" if library() is not None else b"numpy")
    digest.update(pickle.dumps(inputs, protocol=4))
    return digest.hexdigest()[:24]


@cache
def _code_digest() -> bytes:
    """Hash of the design layer's and the runtime's sources and of the libraries' versions
    (computed once per process)."""
    package = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for sub in ("design", "core"):
        for path in sorted((package / sub).rglob("*")):
            if path.suffix in (".py", ".c", ".h"):
                digest.update(path.relative_to(package).as_posix().encode())
                digest.update(path.read_bytes())
    for name in LIBRARIES:
        try:
            digest.update(f"{name}={version(name)}".encode())
        except PackageNotFoundError:
            digest.update(f"{name}=none".encode())
    return digest.digest()


def _write(path: Path, result: Any) -> None:
    """Pickle ``result`` into ``path`` (whole or not at all), then drop the least recently
    used files beyond :data:`KEPT` (a partial file a killed process left among them); a cache
    that cannot be written is only a slower next call."""
    try:
        data = pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL)
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        with replaced_atomically(path) as partial:
            partial.write_bytes(data)
        files = list(path.parent.iterdir())
        if len(files) > KEPT:
            for old in sorted(files, key=_modified)[:len(files) - KEPT]:
                old.unlink(missing_ok=True)
    except OSError as err:
        cache_unusable(path.parent, err)
    except (pickle.PicklingError, TypeError, AttributeError):
        pass  # a result that cannot be kept is computed again next time


def _modified(path: Path) -> float:
    """Modification time of ``path`` (0 for a file another process has just removed)."""
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0
