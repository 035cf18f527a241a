"""Files written whole: every file a command writes appears complete or not at all.

- :func:`atomic_path`: a file is written to a temporary name in its folder and renamed into
  place when complete (a rename within a folder replaces the old file at once); a failure or
  an interruption while writing leaves the old file, or none, and no temporary file.
- :func:`completed`: the files of one result (results.csv, the plots and summary.json; the
  sweep's two tables) are written together; SIGINT and SIGTERM arriving meanwhile end the
  command after the last of them, with :class:`Interrupted` saying what was written.
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from fhobs.core.kernel import replaced_atomically

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


atomic_path = replaced_atomically
"""Yield a temporary path to write a file to; rename it over the file when the block ends
normally, remove it when the block raises (a signal's exception included):
:func:`fhobs.core.kernel.replaced_atomically`, the one such helper of the product."""


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
    >>> import os
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
