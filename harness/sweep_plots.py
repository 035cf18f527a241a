"""The pictures of a sweep (``DIR/plots/``): each figure against each swept axis, and the
Pareto picture.

- ``<axis>.png`` (:func:`axis_figure`): one panel per figure (``rms_error_1_3``,
  ``time_to_1e-3``, ...), one colour per estimator (:func:`harness.plotting.estimator_colours`),
  the points of one axis value (seeds, other axes) as their median and min-max band (error bars
  on an axis of categories: bases, start vectors). The seed is never an axis: its points are
  the spread (a sweep of seeds alone is drawn per estimator, ``spread.png``). Each panel's axes
  span its data: a log scale only where the values span more than :data:`LOG_DECADES` decades,
  the lower limit no lower than :data:`FLOOR_RATIO` times the largest value (values below it,
  round-off floors, drawn on the bottom edge as ``v``), an infinite value (an error that never
  settled) on the top edge as ``^``; the panel's title counts these, the NaN values and the
  points with no value, the figure's title the failed points.
- ``pareto.png`` (:func:`pareto_figure`): per estimator, each design's noisy RMS (mean over the
  seeds, bars from the least to the largest) against its perturbation error, its Pareto front
  (the designs no other of the estimator beats in both) as a step line, front points labelled
  by their design where the labels do not overlap, axis titles the figures' names with units.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import numpy as np

from harness.plotting import estimator_colours
from harness.sweep import (
    STATUS_OK,
    ParetoPoint,
    Sweep,
    figure_columns,
    pareto_figures,
    pareto_points,
)

LOG_DECADES = 2.0
"""A panel's value axis is logarithmic when its values span more than this many decades."""
FLOOR_RATIO = 1e-6
"""A panel's lower limit is at least this times its largest value (round-off floors below)."""
SEED = "seed"
ALL_POINTS = "all points"
"""The one category of a sweep whose only axis is the seed."""
PARETO_LABELS = 12
"""At most this many design labels in the Pareto picture (the front's points, first come)."""


# -- names ------------------------------------------------------------------------------------
def number_text(key: str) -> str:
    """A number as a figure's name writes it (:func:`harness.results.time_key`) read back.

    Examples
    --------
    >>> number_text("1_5"), number_text("m2"), number_text("2_5e-4")
    ('1.5', '-2', '2.5e-4')
    """
    return key.replace("_", ".").replace("m", "-")


def figure_title(figure: str, windows: dict[str, tuple[float, float]] | None = None) -> str:
    """A figure's name in words with its unit (errors in the units of the state x).

    Parameters
    ----------
    figure : str
        ``error_at_<t>``, ``max_error_<a>_<b>``, ``rms_error_<a>_<b>``, ``time_to_<tol>``,
        ``peak`` or ``floor`` (:mod:`harness.results`).
    windows : dict, optional
        ``{"<a>_<b>": (a, b)}`` of the windows the sweep evaluates (:func:`window_keys`): a
        window whose bounds have decimals is read only from them.

    Examples
    --------
    >>> figure_title("rms_error_1_3"), figure_title("time_to_1e-3")
    ('RMS ||x - x_hat|| over [1, 3] s', 'time to rel. error <= 1e-3 [s]')
    >>> figure_title("max_error_0_1_0_2", {"0_1_0_2": (0.1, 0.2)})
    'max ||x - x_hat|| over [0.1, 0.2] s'
    """
    windows = windows or {}
    if figure.startswith("error_at_"):
        return f"||x - x_hat|| at t = {number_text(figure[9:])} s"
    for prefix, what in (("max_error_", "max"), ("rms_error_", "RMS")):
        if figure.startswith(prefix):
            key = figure[len(prefix):]
            if key in windows:
                a, b = windows[key]
                return f"{what} ||x - x_hat|| over [{a:g}, {b:g}] s"
            parts = key.split("_")
            span = f"[{', '.join(map(number_text, parts))}]" if len(parts) == 2 else key
            return f"{what} ||x - x_hat|| over {span} s"
    if figure.startswith("time_to_"):
        return f"time to rel. error <= {number_text(figure[8:])} [s]"
    return {"peak": "peak error / initial error", "floor": "rel. error floor (end of run)"}.get(
        figure, figure)


def window_keys(sweep: Sweep) -> dict[str, tuple[float, float]]:
    """``{"<a>_<b>": (a, b)}`` of the windows of the sweep's ``[evaluation]`` and of its
    scenario bases.

    Examples
    --------
    >>> from harness.sweep import load_sweep
    >>> window_keys(load_sweep("pendulum_noisy_seeds"))
    {'1_3': (1.0, 3.0)}
    """
    from harness.results import time_key

    windows = list((sweep.settings.get("evaluation") or {}).get("windows", []))
    for base in sweep.bases.values():
        if base.system is not None:
            windows += list(base.system.evaluation.windows)
    return {f"{time_key(a)}_{time_key(b)}": (float(a), float(b)) for a, b in windows}


def short_base(name: str) -> str:
    """A base as a picture names it: a scenario's name, a file's stem.

    Examples
    --------
    >>> short_base("examples/zoo/dc_motor.toml"), short_base("pendulum_noisy")
    ('dc_motor', 'pendulum_noisy')
    """
    return Path(name).stem if name.endswith(".toml") else name


# -- one panel's values -----------------------------------------------------------------------
class Scale(NamedTuple):
    """A panel's value axis: limits, log or linear, and the count of finite values below
    ``floor`` (round-off floors, drawn on the bottom edge)."""

    low: float
    high: float
    log: bool
    below: int = 0
    floor: float = -math.inf


def value_scale(values: list[float]) -> Scale | None:
    """The value axis of a panel's values (finite ones count; None if none is).

    Values below ``FLOOR_RATIO`` times the largest (or not positive, when the others are) are
    left out as round-off floors and counted; the axis spans the others, logarithmic when
    they span more than ``LOG_DECADES`` decades, with a margin of 5 % (linear) or a fifth of a
    decade (log).

    Examples
    --------
    >>> value_scale([1e-3, 2e-3, 1e-110])
    Scale(low=0.00095, high=0.00205, log=False, below=1, floor=2e-09)
    >>> s = value_scale([1e-1, 1e-4, 0.0])
    >>> s.log, s.below, round(math.log10(s.low), 6), round(math.log10(s.high), 6)
    (True, 1, -4.2, -0.8)
    >>> value_scale([3.0, 3.0])
    Scale(low=2.85, high=3.15, log=False, below=0, floor=3.0)
    """
    finite = np.array([v for v in values if math.isfinite(v)], dtype=float)
    if finite.size == 0:
        return None
    top = float(finite.max())
    floor = -math.inf
    if top > 0.0 and finite.min() >= 0.0:
        floor = max(float(finite[finite > 0.0].min()), FLOOR_RATIO * top)
    kept = finite[finite >= floor]
    low, below = float(kept.min()), int(finite.size - kept.size)
    if low > 0.0 and math.log10(top / low) > LOG_DECADES:
        return Scale(low / 10 ** 0.2, top * 10 ** 0.2, True, below, floor)
    margin = 0.05 * (top - low) or 0.05 * max(abs(top), 1e-300)
    return Scale(low - margin, top + margin, False, below, floor)


def panel_note(values: list[Any], scale: Scale | None, figure: str) -> str:
    """What a panel does not show where its values would be: the counts of infinite values
    (on the top edge), values below the lower limit (on the bottom edge), NaN values and
    points without the figure; '' when there is none.

    Examples
    --------
    >>> scale = value_scale([1.0, 2.0, 1e-12])
    >>> panel_note([1.0, math.inf, 2.0, 1e-12, math.nan, None], scale, "time_to_1e-3")
    '1 never settled (^ at top), 1 below 2e-06 (v at bottom), 1 NaN, 1 without a value'
    """
    counts = {"inf": sum(v is not None and math.isinf(v) for v in values),
              "below": scale.below if scale is not None else 0,
              "nan": sum(v is not None and math.isnan(v) for v in values),
              "none": sum(v is None for v in values)}
    inf = "never settled" if figure.startswith("time_to_") else "infinite"
    parts = [f"{counts['inf']} {inf} (^ at top)" if counts["inf"] else "",
             f"{counts['below']} below {scale.floor:.3g} (v at bottom)"
             if counts["below"] else "",
             f"{counts['nan']} NaN" if counts["nan"] else "",
             f"{counts['none']} without a value" if counts["none"] else ""]
    return ", ".join(p for p in parts if p)


def spread(xs: list[float], ys: list[float]) -> tuple[np.ndarray, ...]:
    """Per distinct x (sorted): the median, least and largest of its y (NaN left out).

    Examples
    --------
    >>> [a.tolist() for a in spread([1, 2, 1, 1], [3.0, 5.0, 1.0, 2.0])]
    [[1.0, 2.0], [2.0, 5.0], [1.0, 5.0], [3.0, 5.0]]
    """
    groups: dict[float, list[float]] = {}
    for x, y in zip(xs, ys, strict=True):
        if not math.isnan(y):
            groups.setdefault(x, []).append(y)
    keys = sorted(groups)
    stats = np.array([(np.median(groups[k]), min(groups[k]), max(groups[k])) for k in keys],
                     dtype=float).reshape(-1, 3)
    return (np.array(keys, dtype=float), *stats.T)


# -- the per-axis pictures --------------------------------------------------------------------
def plotted_axes(sweep: Sweep, rows: list[dict[str, Any]]) -> list[str | None]:
    """The axes drawn against: the swept ones but the seed that the rows have; ``[None]``
    (the points per estimator) when the seed is the only one.

    Examples
    --------
    >>> from harness.sweep import load_sweep
    >>> plotted_axes(load_sweep("pendulum_noisy_seeds"), [{"base": "a", "seed": 0}])
    ['base']
    """
    axes = [a for a in sweep.axes if a != SEED and any(r.get(a) is not None for r in rows)]
    return axes or [None]


def _positions(rows: list[dict[str, Any]], axis: str | None) -> tuple[list[float], list[str]]:
    """Each row's x and the category names ([] on a numeric axis)."""
    if axis is None:
        return [0.0] * len(rows), [ALL_POINTS]
    values = [r[axis] for r in rows]
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        return [float(v) for v in values], []
    names = list(dict.fromkeys(json.dumps(v) for v in values))
    return [float(names.index(json.dumps(v))) for v in values], [
        short_base(n.strip('"')) if axis == "base" else n.strip('"') for n in names]


def axis_figure(rows: list[dict[str, Any]], sweep: Sweep, axis: str | None) -> Any:
    """The figure of every figure column against ``axis`` (None: the points per estimator);
    the rows that have the axis, failed ones counted in the title.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per figure (module docstring).

    Examples
    --------
    >>> from harness.sweep import load_sweep
    >>> rows = [{"status": "ok", "base": "b", "seed": s, "kalman.rms_error_1_3": 1e-3 * (s + 1)}
    ...         for s in range(3)]
    >>> fig = axis_figure(rows, load_sweep("pendulum_noisy_seeds"), "base")
    >>> [ax.get_title() for ax in fig.axes]
    ['RMS ||x - x_hat|| over [1, 3] s']
    """
    from matplotlib.ticker import MaxNLocator

    from harness.figures import new_figure

    rows = [r for r in rows if axis is None or r.get(axis) is not None]
    ok = [r for r in rows if r.get("status") == STATUS_OK]
    figures = figure_columns(ok)
    estimators = list(dict.fromkeys(e for names in figures.values() for e in names))
    colours = estimator_colours(estimators)
    xs, categories = _positions(ok, axis)
    windows = window_keys(sweep)
    fig, axes = new_figure(1, max(len(figures), 1), (4.6 * max(len(figures), 1), 3.8),
                           layout="constrained")
    for ax, (figure, names) in zip(axes[0], figures.items(), strict=False):
        having = [r for r in ok if r.get("base") in _bases_with(ok, figure, names)]
        x_of = [x for r, x in zip(ok, xs, strict=True) if r.get("base") in
                _bases_with(ok, figure, names)]
        values = {e: [_value(r.get(f"{e}.{figure}")) for r in having] for e in names}
        scale = value_scale([v for vs in values.values() for v in vs if v is not None])
        for i, estimator in enumerate(names):
            dodge = 0.08 * (i - (len(names) - 1) / 2) if categories else 0.0
            _draw_estimator(ax, [x + dodge for x in x_of], values[estimator], scale,
                            colours[estimator], estimator, bool(categories))
        if scale is not None:
            ax.set_yscale("log" if scale.log else "linear")
            ax.set_ylim(scale.low, scale.high)
        note = panel_note([v for vs in values.values() for v in vs], scale, figure)
        ax.set_title(figure_title(figure, windows) + (f"\n{note}" if note else ""), fontsize=8)
        _x_axis(ax, axis, xs, categories, MaxNLocator)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    failed = len(rows) - len(ok)
    seeds = len({r.get(SEED) for r in ok if r.get(SEED) is not None})
    spread_text = f"median and min-max over {seeds} seeds and the other axes" if seeds > 1 \
        else "median and min-max over the other axes' points"
    fig.suptitle(f"sweep {sweep.name}: {len(ok)} points ({spread_text})"
                 + (f"; {failed} failed point{'s' * (failed > 1)} not shown" if failed else ""),
                 fontsize=9)
    return fig


def _bases_with(rows: list[dict[str, Any]], figure: str, estimators: list[str]) -> set[Any]:
    """The bases of which some row has ``figure`` (the rows of other bases are not short of
    it: their runs do not evaluate it)."""
    return {r.get("base") for r in rows
            if any(r.get(f"{e}.{figure}") is not None for e in estimators)}


def _value(value: Any) -> float | None:
    return None if value is None or isinstance(value, bool) else float(value)


def _draw_estimator(ax: Any, xs: list[float], ys: list[float | None], scale: Scale | None,
                    colour: str, label: str, categorical: bool) -> None:
    """One estimator's median line and band (error bars on categories), its infinite values
    on the top edge and values below the lower limit on the bottom edge."""
    pairs = [(x, y) for x, y in zip(xs, ys, strict=True) if y is not None]
    if not pairs or scale is None:
        return
    x = [p[0] for p in pairs]
    y = np.clip([p[1] for p in pairs], scale.low, scale.high)  # inf to the top edge
    at, median, low, high = spread(x, list(y))
    if categorical:
        ax.errorbar(at, median, yerr=[median - low, high - median], fmt="o", color=colour,
                    capsize=3, ms=5, label=label)
    else:
        ax.plot(at, median, "o-", color=colour, ms=4, lw=1.2, label=label)
        ax.fill_between(at, low, high, color=colour, alpha=0.2, lw=0)
    raw = np.array([p[1] for p in pairs])
    for mask, edge, marker in ((np.isposinf(raw), scale.high, "^"),
                               (np.isfinite(raw) & (raw < scale.floor), scale.low, "v")):
        if mask.any():
            ax.plot(np.array(x)[mask], np.full(int(mask.sum()), edge), marker, color=colour,
                    ms=7, clip_on=False, zorder=5)


def _x_axis(ax: Any, axis: str | None, xs: list[float], categories: list[str],
            locator: Any) -> None:
    """Ticks of categories, integer ticks for whole-number values, a log scale for positive
    values over more than ``LOG_DECADES`` decades."""
    ax.set_xlabel(ALL_POINTS if axis is None else axis)
    if categories:
        ax.set_xticks(range(len(categories)), categories, fontsize=7,
                      rotation=20 if len(categories) > 3 else 0)
        ax.set_xlim(-0.5, len(categories) - 0.5)
        return
    if xs and min(xs) > 0 and math.log10(max(xs) / min(xs)) > LOG_DECADES:
        ax.set_xscale("log")
    elif all(float(x).is_integer() for x in xs):
        ax.xaxis.set_major_locator(locator(integer=True))


def plot_sweep(rows: list[dict[str, Any]], sweep: Sweep, out: Path) -> list[Path]:
    """Each figure against each swept axis but the seed (one PNG per axis,
    ``spread.png`` for a sweep of seeds alone) and, with ``[pareto]``, the Pareto picture.

    Returns
    -------
    list of Path
        The PNGs written (none without a finished row that has figures).

    Examples
    --------
    >>> report = run_sweep(sweep, Path("out"), plots=False)         # doctest: +SKIP
    >>> [p.name for p in plot_sweep(report.rows, sweep, Path("out/plots"))]  # doctest: +SKIP
    ['base.png', 'pareto.png']
    """
    from harness.figures import save_figure

    ok = [r for r in rows if r.get("status") == STATUS_OK]
    if not figure_columns(ok):
        return []
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for axis in plotted_axes(sweep, ok):
        name = "spread" if axis is None else re.sub(r"[^\w.-]", "_", axis)
        paths.append(save_figure(axis_figure(rows, sweep, axis), out / f"{name}.png", 100))
    if sweep.pareto:
        fig = pareto_figure(ok, sweep)
        if fig is not None:
            paths.append(save_figure(fig, out / "pareto.png", 100))
    return paths


# -- the Pareto picture -----------------------------------------------------------------------
P = TypeVar("P")


def _xy(point: ParetoPoint) -> tuple[float, float]:
    return point.x, point.y


def pareto_front(points: list[P], figures: Callable[[P], tuple[float, float]] = _xy
                 ) -> list[P]:
    """The points no other beats in both figures (both smaller or equal, one smaller), by the
    first; ``figures``: a point's two figures, a :class:`ParetoPoint`'s x and y by default.

    Examples
    --------
    >>> front = pareto_front([ParetoPoint(1, 3, "a", {}), ParetoPoint(2, 2, "b", {}),
    ...                       ParetoPoint(3, 3, "c", {}), ParetoPoint(4, 1, "d", {})])
    >>> [p.label for p in front]
    ['a', 'b', 'd']
    >>> [p for p in pareto_front([(1, 3), (2, 1), (2, 2)], figures=lambda p: p)]
    [(1, 3), (2, 1)]
    """
    front, best = [], math.inf
    for p in sorted(points, key=figures):
        y = figures(p)[1]
        if y < best:
            front.append(p)
            best = y
    return front


def pareto_figure(rows: list[dict[str, Any]], sweep: Sweep) -> Any:
    """The Pareto picture (module docstring), or None when the sweep lacks one of its two
    figures.

    Examples
    --------
    >>> fig = pareto_figure(rows, load_sweep("pendulum_noisy_seeds"))  # doctest: +SKIP
    """
    from harness.figures import new_figure

    points = pareto_points(rows, sweep)
    if not points:
        return None
    fig, axes = new_figure(1, 1, (8, 5.5), layout="constrained")
    ax = axes[0, 0]
    colours = estimator_colours(list(points))
    fronts = {e: pareto_front(ps) for e, ps in points.items()}
    for estimator, values in points.items():
        colour = colours[estimator]
        y = np.array([p.y for p in values])
        low, high = np.array([p.spread() for p in values]).T
        bars = [y - low, high - y]
        ax.errorbar([p.x for p in values], y, yerr=bars, fmt="o", ms=4, color=colour,
                    alpha=0.6, capsize=2, lw=0.8, label=f"{estimator} ({len(values)} designs)")
        front = fronts[estimator]
        ax.step([p.x for p in front], [p.y for p in front], where="post", color=colour, lw=1.5,
                label=f"{estimator}: Pareto front")
    ax.set_xscale("log")
    ax.set_yscale("log")
    (xfig, yfig), windows = pareto_figures(rows, sweep), window_keys(sweep)
    ax.set_xlabel(f"{figure_title(xfig, windows)}, {short_base(sweep.pareto['perturbation'])}")
    ax.set_ylabel(f"{figure_title(yfig, windows)}, {short_base(sweep.pareto['noisy'])}\n"
                  "(mean over the seeds; bars: least to largest)")
    ax.set_title(f"sweep {sweep.name}: noise against perturbation", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    label_front(fig, ax, [p for front in fronts.values() for p in front])
    return fig


def design_label(params: dict[str, Any]) -> str:
    """A design's short label: each axis by its last name, numbers in short form.

    Examples
    --------
    >>> design_label({"spec.noise.process_intensity": 1000.0, "rho": 6.0})
    'process_intensity = 1e+03, rho = 6'
    """
    return ", ".join(f"{axis.rsplit('.', 1)[-1]} = "
                     f"{f'{value:.3g}' if isinstance(value, float) else json.dumps(value)}"
                     for axis, value in params.items())


def inside(box: Any, frame: Any) -> bool:
    """Whether the bounding box ``box`` lies within ``frame`` (both in display units)."""
    return (frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0
            and box.y1 <= frame.y1)


def label_front(fig: Any, ax: Any, front: list[ParetoPoint]) -> list[Any]:
    """Label front points by their design (:func:`design_label`), at most
    ``PARETO_LABELS``, each only where it lies inside the axes and overlaps no label placed
    before; return the labels placed."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)  # the layout, hence the points' places on the canvas
    frame = ax.get_window_extent(renderer)
    placed, boxes = [], []
    for p in front:
        if len(placed) == PARETO_LABELS:
            break
        text = ax.annotate(design_label(p.params) or p.label, (p.x, p.y), xytext=(4, 4),
                           textcoords="offset points", fontsize=6)
        box = text.get_window_extent(renderer)
        if any(box.overlaps(other) for other in boxes) or not inside(box, frame):
            text.remove()
            continue
        placed.append(text)
        boxes.append(box)
    return placed
