"""Results of a run: summary figures, the CSV of recorded signals, summary.json.

The system description's ``[evaluation]`` names instants, windows and error signals; for each
error signal ``name = [reference, estimate]`` (vector signals), with ``e(t) = ||ref - est||``:

- ``error_at_<t>``: ``e`` at the sample nearest to ``t``,
- ``max_error_<a>_<b>``, ``rms_error_<a>_<b>``: max and RMS of ``e`` over ``a <= t <= b``,

where ``<t>`` is the number with ``.`` replaced by ``_`` (``1.5 -> 1_5``, ``3.0 -> 3``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from harness.master import CoSimResult
from harness.system import Evaluation


def time_key(t: float) -> str:
    """``1.5 -> "1_5"``, ``3.0 -> "3"``."""
    return f"{t:g}".replace(".", "_").replace("-", "m")


def error_norm(result: CoSimResult, reference: str, estimate: str) -> np.ndarray:
    """``||reference - estimate||`` at every recorded time."""
    return np.linalg.norm(result.vector(reference) - result.vector(estimate), axis=1)


def window_mask(time: np.ndarray, a: float, b: float) -> np.ndarray:
    """Samples with ``a <= t <= b`` (with a tolerance of 1e-9 relative to the bounds)."""
    tol = 1e-9 * max(1.0, abs(a), abs(b))
    return (time >= a - tol) & (time <= b + tol)


def error_figures(result: CoSimResult, evaluation: Evaluation) -> dict[str, dict[str, float]]:
    """The evaluation's figures per error signal (see the module docstring)."""
    figures: dict[str, dict[str, float]] = {}
    for name, (reference, estimate) in evaluation.errors.items():
        e = error_norm(result, reference, estimate)
        out: dict[str, float] = {}
        for t in evaluation.at:
            if not result.time[0] <= t <= result.time[-1] + 1e-12:
                continue
            out[f"error_at_{time_key(t)}"] = float(e[int(np.argmin(np.abs(result.time - t)))])
        for a, b in evaluation.windows:
            mask = window_mask(result.time, a, b)
            if result.time[-1] + 1e-12 < b or not mask.any():
                continue
            key = f"{time_key(a)}_{time_key(b)}"
            out[f"max_error_{key}"] = float(np.max(e[mask]))
            out[f"rms_error_{key}"] = float(np.sqrt(np.mean(e[mask] ** 2)))
        figures[name] = out
    return figures


def summary(result: CoSimResult, evaluation: Evaluation, **run: Any) -> dict[str, Any]:
    """summary.json content: the figures per error signal and the run's ``steps``, ``wall_time_s``
    and any extra ``run`` items (scenario name, seed, ...)."""
    return {
        **run,
        "steps": result.steps,
        "wall_time_s": result.wall_time_s,
        **error_figures(result, evaluation),
    }


def write_csv(result: CoSimResult, path: Path, every: int = 1) -> Path:
    """Write the recorded signals (``time`` first) as CSV in the format of fmpy's writer
    (``fmpy.util.write_csv``: quoted names, each number as the shortest text that reads back
    as the same double): every ``every``-th communication point (the first always, the last
    too). The summary figures are computed from every point whatever ``every`` is.

    Examples
    --------
    >>> import tempfile
    >>> r = CoSimResult(np.array([0.0, 0.1]), ("p.x",), np.array([[1.0], [1e-17]]), 1, 0.0)
    >>> print(write_csv(r, Path(tempfile.mkdtemp()) / "r.csv").read_text(), end="")
    "time","p.x"
    0.0,1.0
    0.1,1e-17
    """
    rows = np.unique(np.append(np.arange(0, len(result.time), every), len(result.time) - 1))
    table = np.column_stack((result.time[rows], result.values[rows]))
    header = ",".join(f'"{name}"' for name in ("time", *result.names))
    with open(path, "w") as csv:
        csv.write(header + "\n")
        csv.writelines(",".join(map(repr, row)) + "\n" for row in table.tolist())
    return path


def write_summary(data: dict[str, Any], path: Path) -> Path:
    """Write ``data`` as indented JSON."""
    path.write_text(json.dumps(data, indent=2) + "\n")
    return path
