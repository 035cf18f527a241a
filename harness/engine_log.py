"""The sweep engine's log file: dask.distributed's messages (a task's "Compute Failed" with its
traceback, a worker that died, a connection lost) written to ``DIR/engine.log`` of the sweep
rather than to the console, where the command prints one line per failure reason.

In the sweep's own process (the client, and with a local cluster its scheduler and nannies)
:func:`engine_log` routes the engine's loggers, and the warnings its modules raise, to the
file while the sweep runs;
:class:`EngineLog`, a worker plugin, does the same in each worker process of a local cluster
(whose console is the command's). Workers started by the user (``--scheduler``) keep their
own logging.
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Iterator
from pathlib import Path

from distributed.diagnostics.plugin import WorkerPlugin

ENGINE_LOG = "engine.log"
"""The log file's name in the sweep's results folder."""
ENGINE_LOGGERS = ("distributed", "asyncio", "tornado")
"""The loggers of the engine and of the event loop it runs on."""
LOG_FORMAT = "%(asctime)s - %(process)d - %(name)s - %(levelname)s - %(message)s"


def route_to_file(path: Path) -> dict[str, tuple[list[logging.Handler], bool]]:
    """Send the engine's loggers to ``path`` (appended; created at the first message) and to
    nothing else; return their previous handlers and propagation for :func:`restore`.

    Examples
    --------
    >>> import tempfile
    >>> path = Path(tempfile.mkdtemp()) / "engine.log"
    >>> saved = route_to_file(path)
    >>> logging.getLogger("distributed.worker").error("Compute Failed")
    >>> restore(saved)
    >>> "distributed.worker - ERROR - Compute Failed" in path.read_text()
    True
    """
    handler = logging.FileHandler(path, mode="a", delay=True)
    handler.setFormatter(logging.Formatter(LOG_FORMAT))
    saved = {}
    for name in ENGINE_LOGGERS:
        logger = logging.getLogger(name)
        saved[name] = (list(logger.handlers), logger.propagate)
        logger.handlers[:] = [handler]
        logger.propagate = False
    return saved


def restore(saved: dict[str, tuple[list[logging.Handler], bool]]) -> None:
    """Give the loggers back the handlers and propagation :func:`route_to_file` replaced,
    closing the file."""
    for name, (handlers, propagate) in saved.items():
        logger = logging.getLogger(name)
        for handler in logger.handlers:
            if handler not in handlers:
                handler.close()
        logger.handlers[:] = handlers
        logger.propagate = propagate


@contextlib.contextmanager
def engine_log(path: Path) -> Iterator[Path]:
    """Inside the block, this process's engine messages go to ``path`` only.

    Examples
    --------
    >>> import tempfile
    >>> with engine_log(Path(tempfile.mkdtemp()) / "engine.log") as path:
    ...     logging.getLogger("distributed.scheduler").warning("worker lost")
    >>> path.read_text().count("worker lost")
    1
    """
    saved = route_to_file(path)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _engine_warning(warnings.showwarning)
            yield path
    finally:
        restore(saved)


def _engine_warning(show):  # noqa: ANN001, ANN202 - warnings.showwarning's own signature
    """``warnings.showwarning`` that logs the engine's warnings (raised in its own modules: a
    dashboard port in use, a slow event loop) to its loggers, and shows the others with
    ``show``."""
    def showwarning(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        if any(f"/{name}/" in str(filename) for name in ("distributed", "dask", "tornado")):
            logging.getLogger("distributed").warning(
                "%s:%s: %s: %s", filename, lineno, category.__name__, message)
        else:
            show(message, category, filename, lineno, file, line)
    return showwarning


class EngineLog(WorkerPlugin):
    """Worker plugin: the worker process's engine messages go to ``path`` (an absolute path
    on the workers' disk: a local cluster's).

    Examples
    --------
    >>> client.register_plugin(EngineLog(out / ENGINE_LOG))        # doctest: +SKIP
    """

    def __init__(self, path: Path) -> None:
        self.path = str(Path(path).resolve())

    def setup(self, worker: object) -> None:
        """Route the worker process's engine loggers, and the engine's warnings, to the file
        (for the process's life)."""
        route_to_file(Path(self.path))
        warnings.showwarning = _engine_warning(warnings.showwarning)


__all__ = ["ENGINE_LOG", "EngineLog", "engine_log", "restore", "route_to_file"]
