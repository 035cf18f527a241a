"""What the user's cache folder may hand back: a file read from ``$XDG_CACHE_HOME/fhobs`` (a
compiled library that is loaded, an object file that is linked, an FMU that is copied out, a
pickle that is read) is used only if this user alone could have put it there and it looks like
what it claims to be.

An entry is *trusted* when it belongs to this user, neither its group nor others may write it,
its folder is likewise this user's and writable by no one else, and its content passes the
caller's check (:func:`is_elf` for a library or an object file, :func:`is_fmu` for an FMU). An
entry that fails is not used (the caller builds it again, over it), with one warning line
naming the file and the reason.

A cache folder that cannot be used (a file in its place, not writable, not private, a full
disk) costs the caller its cache, never its result: :func:`cache_unusable` logs one warning line
naming the folder and the reason, and the caller builds without the cache.

The warnings go to the logger ``fhobs.cache`` (without a handler, Python prints a warning's
message alone on stderr). This module is standard library only: it runs inside the FMUs.
"""

from __future__ import annotations

import logging
import os
import stat
import zipfile
from collections.abc import Callable
from pathlib import Path
from xml.etree import ElementTree

LOG = logging.getLogger("fhobs.cache")
ELF_MAGIC = b"\x7fELF"
"""The first bytes of a shared library or an object file on Linux."""
MODEL_DESCRIPTION = "modelDescription.xml"
_WARNED: set[tuple[str, str]] = set()


def check_private(path: Path) -> None:
    """PermissionError unless ``path`` belongs to this user and neither its group nor others may
    write it.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> check_private(folder)
    >>> folder.chmod(0o777)
    >>> check_private(folder)
    Traceback (most recent call last):
    ...
    PermissionError: ... may be written by others (mode 777)
    """
    info = path.stat()
    if info.st_uid != os.getuid():
        raise PermissionError(f"{path} belongs to user {info.st_uid}, not to this user "
                              f"({os.getuid()})")
    if info.st_mode & 0o022:
        raise PermissionError(f"{path} may be written by others "
                              f"(mode {stat.S_IMODE(info.st_mode):o})")


def check_entry(path: Path, looks_right: Callable[[Path], bool] | None = None) -> None:
    """OSError unless ``path`` is a trusted cache entry (module docstring): a regular file,
    private to this user as its folder is, whose content ``looks_right`` (if given).

    Raises
    ------
    FileNotFoundError
        If there is no such file.
    PermissionError
        If it or its folder is not private to this user, or its content is not what it
        should be.
    """
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    check_private(path)
    check_private(path.parent)
    if looks_right is not None and not looks_right(path):
        what = (looks_right.__doc__ or looks_right.__name__).split(":")[0]
        raise PermissionError(f"{path} is not what it should be ({what} expected)")


def trusted(path: Path, looks_right: Callable[[Path], bool] | None = None) -> bool:
    """Whether the cache entry ``path`` may be used (:func:`check_entry`); False, quietly,
    when there is none, and with one warning line when it fails a check (the caller builds
    it again).

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> entry = folder / "kernel.so"
    >>> trusted(entry, is_elf)
    False
    >>> _ = entry.write_bytes(ELF_MAGIC + bytes(60))
    >>> trusted(entry, is_elf)
    True
    >>> _ = entry.write_text("not a library")
    >>> trusted(entry, is_elf)
    False
    """
    try:
        check_entry(path, looks_right)
    except FileNotFoundError:
        return False
    except OSError as err:
        _warn_once(str(path), f"cache entry not used, built again: {err}")
        return False
    return True


def cache_unusable(folder: Path, reason: BaseException | str) -> None:
    """Log (once per folder and reason in a process) that the cache ``folder`` is not used.

    Examples
    --------
    >>> cache_unusable(Path("/nonexistent/fhobs"), "read-only file system")  # doctest: +SKIP
    """
    _warn_once(str(folder), f"the cache folder {folder} is not used ({reason}); "
                            "building without it")


def is_elf(path: Path) -> bool:
    """ELF file: a shared library or an object file (its first four bytes).

    Examples
    --------
    >>> import sys
    >>> is_elf(Path(sys.executable).resolve()) == sys.platform.startswith("linux")
    True
    """
    with open(path, "rb") as handle:
        return handle.read(len(ELF_MAGIC)) == ELF_MAGIC


def is_fmu(path: Path) -> bool:
    """FMU: a zip archive holding a ``modelDescription.xml`` that parses into an
    ``fmiModelDescription`` with a GUID.

    Examples
    --------
    >>> import tempfile
    >>> fmu = Path(tempfile.mkdtemp()) / "a.fmu"
    >>> with zipfile.ZipFile(fmu, "w") as archive:
    ...     archive.writestr(MODEL_DESCRIPTION, '<fmiModelDescription guid="{1}"/>')
    >>> is_fmu(fmu), fmu_guid(fmu)
    (True, '{1}')
    """
    return fmu_guid(path) is not None


def fmu_guid(path: Path) -> str | None:
    """The GUID of the FMU ``path``, None when it is not an FMU (:func:`is_fmu`)."""
    try:
        with zipfile.ZipFile(path) as archive:
            root = ElementTree.fromstring(archive.read(MODEL_DESCRIPTION))
    except (OSError, KeyError, zipfile.BadZipFile, ElementTree.ParseError):
        return None
    guid = root.get("guid")
    return guid if root.tag == "fmiModelDescription" and guid else None


def _warn_once(where: str, message: str) -> None:
    """One warning line per place and message in a process."""
    if (where, message) not in _WARNED:
        _WARNED.add((where, message))
        LOG.warning("fhobs: %s", message)
