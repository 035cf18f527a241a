"""Results of a run: summary figures, the CSV of recorded signals, summary.json.

The system description's ``[evaluation]`` names instants, windows and error signals; for each
error signal ``name = [reference, estimate]`` (vector signals), with ``e(t) = ||ref - est||``:

- ``error_at_<t>``: ``e`` at the sample nearest to ``t``,
- ``max_error_<a>_<b>``, ``rms_error_<a>_<b>``: max and RMS of ``e`` over ``a <= t <= b``,

where ``<t>`` is the number with ``.`` replaced by ``_`` (``1.5 -> 1_5``, ``3.0 -> 3``), and,
with the relative error ``r(t) = e(t) / max_t ||ref||`` (over the whole run):

- ``time_to_<tol>`` for each tolerance of ``converged``: the time from which ``r`` stays
  ``<= tol`` to the end (the run's start if it always does, inf if it ends above; a NaN counts
  as above), ``<tol>`` written as ``1e-3`` (``2.5e-4 -> 2_5e-4``),
- ``peak`` with ``peak = true``: ``max_t e / e(t0)``, how far the error grows beyond its start
  (inf, or NaN if the error stays 0, for an estimator that starts exact),
- ``floor`` with ``floor = D``: the max of ``r`` over the last ``D`` seconds of the run, the
  error left at the end (absent if the run is shorter than ``D``; the commands say so).

An estimator whose error is not finite somewhere or grows beyond ``DIVERGENCE_FACTOR`` times
its initial error ``e(t0)`` has diverged (:func:`diverged`): its summary carries
``"diverged": true`` (the key is absent otherwise), the tables mark its row
(:func:`table_label`) and the plots keep it out of the others' range.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from harness.master import CoSimResult
from harness.system import Evaluation
from harness.writing import atomic_path, write_text

FIGURE_PREFIXES = ("error_at_", "max_error_", "rms_error_", "time_to_", "peak", "floor")
"""The figures of :func:`error_figures`, by the start of their names (module docstring)."""
DIVERGENCE_FACTOR = 1e6
"""An error growing beyond this many times its initial value has diverged."""
DIVERGED = "diverged"
"""The summary's flag of a diverged estimator (present, and true, only for those)."""


def time_key(t: float) -> str:
    """``1.5 -> "1_5"``, ``3.0 -> "3"``."""
    return f"{t:g}".replace(".", "_").replace("-", "m")


def tolerance_key(tol: float) -> str:
    """``1e-3 -> "1e-3"``, ``2.5e-4 -> "2_5e-4"``: a tolerance in a figure's name.

    Examples
    --------
    >>> tolerance_key(1e-3), tolerance_key(2.5e-4), tolerance_key(0.1)
    ('1e-3', '2_5e-4', '1e-1')
    """
    return np.format_float_scientific(tol, trim="-", exp_digits=1).replace(".", "_")


def error_norm(result: CoSimResult, reference: str, estimate: str) -> np.ndarray:
    """``||reference - estimate||`` at every recorded time."""
    return np.linalg.norm(result.vector(reference) - result.vector(estimate), axis=1)


def window_mask(time: np.ndarray, a: float, b: float) -> np.ndarray:
    """Samples with ``a <= t <= b`` (with a tolerance of 1e-9 relative to the bounds)."""
    tol = 1e-9 * max(1.0, abs(a), abs(b))
    return (time >= a - tol) & (time <= b + tol)


def error_figures(result: CoSimResult, evaluation: Evaluation) -> dict[str, dict[str, float]]:
    """The evaluation's figures per error signal (see the module docstring).

    Examples
    --------
    >>> t = np.linspace(0.0, 2.0, 5)
    >>> x, x_hat = np.full(5, 4.0), np.array([0.0, -2.0, 4.0 - 2.0**-9, 4.0, 4.0])
    >>> r = CoSimResult(t, ("p.x", "o.x"), np.column_stack((x, x_hat)), 4, 0.0)
    >>> ev = Evaluation(at=(0.5,), converged=(1e-3,), peak=True, floor=1.0,
    ...                 errors={"o": ("p.x", "o.x")})
    >>> error_figures(r, ev)
    {'o': {'error_at_0_5': 6.0, 'time_to_1e-3': 1.0, 'peak': 1.5, 'floor': 0.00048828125}}
    """
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
        scale = float(np.max(np.linalg.norm(result.vector(reference), axis=1)))
        figures[name] = out | settling_figures(result.time, e, scale, evaluation)
    return figures


def settling_figures(time: np.ndarray, e: np.ndarray, scale: float,
                     evaluation: Evaluation) -> dict[str, float]:
    """``time_to_<tol>``, ``peak`` and ``floor`` of an error signal (module docstring), those
    the evaluation asks for.

    Parameters
    ----------
    time, e : numpy.ndarray
        The sample times and the error norm at each.
    scale : float
        What the relative error is relative to: ``max_t ||reference||``.
    evaluation : Evaluation
        Its ``converged``, ``peak`` and ``floor``.

    Examples
    --------
    >>> settling_figures(np.arange(4.0), np.array([2.0, 1.0, 0.0, 0.0]), 10.0,
    ...                  Evaluation(converged=(0.15, 0.05), peak=True, floor=2.0))
    {'time_to_1_5e-1': 1.0, 'time_to_5e-2': 2.0, 'peak': 1.0, 'floor': 0.1}
    """
    out: dict[str, float] = {}
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = e / scale
        for tol in evaluation.converged:
            above = np.flatnonzero(~(rel <= tol))  # a NaN counts as above
            out[f"time_to_{tolerance_key(tol)}"] = (
                float(time[0]) if above.size == 0
                else math.inf if above[-1] == rel.size - 1 else float(time[above[-1] + 1]))
        if evaluation.peak:
            out["peak"] = float(np.max(e) / e[0])
    start = None if evaluation.floor is None else time[-1] - evaluation.floor
    if start is not None and start >= time[0] - 1e-9 * max(1.0, abs(start)):
        out["floor"] = float(np.max(rel[window_mask(time, start, time[-1])]))
    return out


def diverged(e: np.ndarray) -> bool:
    """Whether an error signal has diverged: a value that is not finite, or a value beyond
    ``DIVERGENCE_FACTOR`` times the first (never by growth for an error that starts at 0).

    Examples
    --------
    >>> diverged(np.array([1.0, 5e3, 1e-9])), diverged(np.array([1.0, 1e3, 2e6]))
    (False, True)
    >>> diverged(np.array([0.0, 1.0])), diverged(np.array([1.0, np.nan]))
    (False, True)
    """
    if not np.isfinite(e).all():
        return True
    return bool(e[0] > 0.0 and np.max(e) > DIVERGENCE_FACTOR * e[0])


def divergence(result: CoSimResult, evaluation: Evaluation) -> dict[str, bool]:
    """``{error signal: diverged}`` of the evaluation's error signals (:func:`diverged`)."""
    return {name: diverged(error_norm(result, reference, estimate))
            for name, (reference, estimate) in evaluation.errors.items()}


def flagged(figures: dict[str, dict[str, Any]],
            flags: dict[str, bool]) -> dict[str, dict[str, Any]]:
    """The figures per error signal, those of a diverged one with ``"diverged": true``.

    Examples
    --------
    >>> flagged({"a": {"peak": 2.0}, "b": {"peak": 3e9}}, {"a": False, "b": True})
    {'a': {'peak': 2.0}, 'b': {'peak': 3000000000.0, 'diverged': True}}
    """
    return {name: out | ({DIVERGED: True} if flags.get(name) else {})
            for name, out in figures.items()}


def table_label(name: str, figures: dict[str, Any]) -> str:
    """An estimator's name in a table: marked ``(diverged)`` if its figures say so.

    Examples
    --------
    >>> table_label("linear", {"diverged": True}), table_label("homogeneous", {})
    ('linear (diverged)', 'homogeneous')
    """
    return f"{name} ({DIVERGED})" if figures.get(DIVERGED) else name


def divergence_note(names: list[str]) -> str | None:
    """The line under a table whose estimators ``names`` diverged (None for none).

    Examples
    --------
    >>> divergence_note(["linear"])
    'note: linear diverged: its error grew beyond 1e+06 times its initial error'
    """
    if not names:
        return None
    return (f"note: {', '.join(names)} diverged: its error grew beyond {DIVERGENCE_FACTOR:.0e} "
            "times its initial error")


def summary(result: CoSimResult, evaluation: Evaluation, **run: Any) -> dict[str, Any]:
    """summary.json content: the figures per error signal (a diverged one flagged,
    :func:`flagged`) and the run's ``steps``, ``wall_time_s`` and any extra ``run`` items
    (scenario name, seed, ...)."""
    return {
        **run,
        "steps": result.steps,
        "wall_time_s": result.wall_time_s,
        **flagged(error_figures(result, evaluation), divergence(result, evaluation)),
    }


def write_csv(result: CoSimResult, path: Path, every: int = 1) -> Path:
    """Write the recorded signals (``time`` first) as CSV in the format of fmpy's writer
    (``fmpy.util.write_csv``: quoted names, each number as the shortest text that reads back
    as the same double), whole (:func:`harness.writing.atomic_path`): every ``every``-th
    communication point (the first always, the last too). The summary figures are computed
    from every point whatever ``every`` is.

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
    with atomic_path(path) as tmp, open(tmp, "w") as csv:
        csv.write(header + "\n")
        csv.writelines(",".join(map(repr, row)) + "\n" for row in table.tolist())
    return path


def write_summary(data: dict[str, Any], path: Path) -> Path:
    """Write ``data`` as indented JSON (whole: :func:`harness.writing.write_text`)."""
    return write_text(path, json.dumps(data, indent=2) + "\n")
