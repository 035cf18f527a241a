"""FMU files as an importer holds them: each extracted once and its model description read once
per process while the file is unchanged (same path, size, modification time and inode), as a
tool loads an FMU once and instantiates it many times. Used by the master (the extracted
folder), the system's resolution (the model description) and the blocks' choice of flavour
(which tool generated an FMU).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
from collections import OrderedDict

from fmpy import extract, read_model_description
from fmpy.model_description import ModelDescription

KEPT = 16
"""How many FMUs each cache keeps (the least recently used goes beyond)."""
_lock = threading.Lock()
_folders: OrderedDict[tuple, str] = OrderedDict()
_descriptions: OrderedDict[tuple, ModelDescription] = OrderedDict()
_root: list[tempfile.TemporaryDirectory] = []


def identity(path: str | os.PathLike) -> tuple:
    """What tells an FMU file from any other and from its earlier versions: its real path,
    size, modification time and inode (OSError if it cannot be read)."""
    info = os.stat(path)
    return os.path.realpath(path), info.st_size, info.st_mtime_ns, info.st_ino


def unzipped(path: str | os.PathLike) -> str:
    """The folder holding the FMU at ``path`` extracted, in a temporary folder removed when
    the process ends; the last :data:`KEPT` FMUs stay extracted (extracted again if their
    folder has gone).

    Examples
    --------
    >>> import pathlib, zipfile
    >>> fmu = pathlib.Path(tempfile.mkdtemp()) / "m.fmu"
    >>> with zipfile.ZipFile(fmu, "w") as z:
    ...     z.writestr("modelDescription.xml", "<fmiModelDescription/>")
    >>> unzipped(fmu) == unzipped(fmu)
    True
    """
    key = identity(path)
    with _lock:
        if key in _folders and os.path.isdir(_folders[key]):  # a temp cleaner may remove it
            _folders.move_to_end(key)
            return _folders[key]
        if not _root:
            _root.append(tempfile.TemporaryDirectory(prefix="harness_fmus_"))
        folder = str(extract(str(path), unzipdir=tempfile.mkdtemp(dir=_root[0].name)))
        _folders[key] = folder
        while len(_folders) > KEPT:
            shutil.rmtree(_folders.popitem(last=False)[1], ignore_errors=True)
        return folder


def description(path: str | os.PathLike) -> ModelDescription:
    """fmpy's model description of the FMU at ``path`` (not validated against the schema; as
    fmpy raises for a file it cannot read). The object is shared: do not modify it.

    Examples
    --------
    >>> from harness.blocks import block_fmu
    >>> description(block_fmu("sine", (1,))).fmiVersion  # doctest: +SKIP
    '2.0'
    """
    key = identity(path)
    with _lock:
        if key in _descriptions:
            _descriptions.move_to_end(key)
            return _descriptions[key]
    read = read_model_description(str(path), validate=False)
    with _lock:
        _descriptions[key] = read
        while len(_descriptions) > KEPT:
            _descriptions.popitem(last=False)
    return read
