"""Files written whole: every file a command writes appears complete or not at all.

- :func:`atomic_path`: a file is written to a temporary name in its folder and renamed into
  place when complete (a rename within a folder replaces the old file at once); a failure or
  an interruption while writing leaves the old file, or none, and no temporary file.
- :func:`completed`: the files of one result (results.csv, the plots and summary.json; the
  sweep's two tables) are written together; SIGINT and SIGTERM arriving meanwhile end the
  command after the last of them, with :class:`Interrupted` saying what was written.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from harness.master import deferred_signals

NOTHING_WRITTEN = "nothing of the run in progress was written"
"""What an interruption before any result was written leaves."""


def complete_written(out: Path) -> str:
    """What a run whose results were all written leaves.

    Examples
    --------
    >>> complete_written(Path("out"))
    'the complete results were written to out'
    """
    return f"the complete results were written to {out}"


def rows_written(t: float, out: Path) -> str:
    """What a run stopped at ``t`` leaves: its rows so far and a summary marked incomplete.

    Examples
    --------
    >>> rows_written(0.25, Path("out"))
    'the rows up to t = 0.25 were written to out (summary.json marked incomplete)'
    """
    return f"the rows up to t = {t!r} were written to {out} (summary.json marked incomplete)"


class Interrupted(BaseException):
    """A command ended by SIGINT or SIGTERM: ``signum`` the signal, ``written`` what it wrote
    of the run in progress (a phrase, :data:`NOTHING_WRITTEN` by default).

    Examples
    --------
    >>> Interrupted(signal.SIGTERM, "the complete results were written to out").written
    'the complete results were written to out'
    """

    def __init__(self, signum: int, written: str = NOTHING_WRITTEN) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.written = written


def temporary_name(path: Path) -> Path:
    """The name ``path`` is written under until it is complete: hidden, in the same folder,
    unique to this process, ending in ``.tmp`` (no reader of ``*.json`` or ``*.csv`` takes it).

    Examples
    --------
    >>> temporary_name(Path("out/summary.json")).name == f".summary.json.{os.getpid()}.tmp"
    True
    """
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path to write ``path`` to; rename it to ``path`` when the block ends
    normally, remove it when the block raises (a signal's exception included).

    Examples
    --------
    >>> import tempfile
    >>> target = Path(tempfile.mkdtemp()) / "summary.json"
    >>> with atomic_path(target) as tmp:
    ...     _ = tmp.write_text("{}")
    ...     target.exists()
    False
    >>> target.read_text(), [p.name for p in target.parent.iterdir()]
    ('{}', ['summary.json'])
    """
    tmp = temporary_name(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` whole (:func:`atomic_path`); return ``path``.

    Examples
    --------
    >>> import tempfile
    >>> write_text(Path(tempfile.mkdtemp()) / "summary.md", "# table\\n").read_text()
    '# table\\n'
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path


@contextmanager
def completed(written: str) -> Iterator[None]:
    """Run the block's writes to their end whatever signal arrives: SIGINT and SIGTERM are
    deferred (:func:`harness.master.deferred_signals`) and, when one came, raise
    :class:`Interrupted` with ``written`` (what the block wrote) once the block is done.
    An exception of the block itself propagates unchanged.

    Examples
    --------
    >>> try:
    ...     with completed("the complete results were written to out"):
    ...         os.kill(os.getpid(), signal.SIGINT)
    ...         _ = sum(range(1000))  # the handler notes the signal between bytecodes
    ... except Interrupted as err:
    ...     print(err.signum == signal.SIGINT, err.written)
    True the complete results were written to out
    """
    with deferred_signals() as received:
        yield
    if received:
        raise Interrupted(received[0], written)
