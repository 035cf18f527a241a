"""Figures in the style of the paper's Figures 1-3: estimation errors, homogeneous vs linear (and
the Kalman filter when the result has one)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from fhobs.extras import require
from fhobs.paper import PAPER_SCENARIOS

from harness.reference import SimulationResult
from harness.writing import atomic_path

matplotlib = require("matplotlib", "plots")
Figure = require("matplotlib.figure", "plots").Figure
offset_copy = require("matplotlib.transforms", "plots").offset_copy

_PERTURBED, _NOISY = PAPER_SCENARIOS["perturbed"], PAPER_SCENARIOS["perturbed_noisy"]
FIGURE_TITLES = {
    "nominal": "Figure 1: nominal case",
    "perturbed": f"Figure 2: perturbation {_PERTURBED.q_amplitude:g} B "
                 f"sin({_PERTURBED.q_frequency:g}t)",
    "perturbed_noisy": f"Figure 3: perturbation and noise of magnitude "
                       f"{_NOISY.noise_amplitude:g}",
}
PLOT_POINTS = 4000
"""At most this many points of a line are drawn (:func:`envelope`)."""


FIXED_TITLES = {"axes.titley": 1.0}
"""matplotlib settings under which :func:`new_figure` makes its axes: a title placed at the top
of its axes as given, not moved clear of tick labels measured at every draw (the figures have
none above their axes)."""


def new_figure(rows: int, columns: int, size: tuple[float, float], layout: str | None = None,
               **subplots: Any) -> tuple[Figure, np.ndarray]:
    """A figure of ``size`` inches (and matplotlib's ``layout`` engine, if any) with a
    ``rows`` x ``columns`` array of axes (``Figure.subplots`` options ``subplots``, always a
    2-D array, made under :data:`FIXED_TITLES`), drawn by savefig with matplotlib's Agg
    renderer: no pyplot, so the caller's backend, open figures, interactive state and
    settings are left alone, and nothing is to close.

    Examples
    --------
    >>> fig, axes = new_figure(2, 1, (4, 3), sharex=True)
    >>> axes.shape
    (2, 1)
    """
    with matplotlib.rc_context(FIXED_TITLES):
        fig = Figure(figsize=size, layout=layout)
        return fig, fig.subplots(rows, columns, squeeze=False, **subplots)


def save_figure(fig: Figure, path: str | Path, dpi: int) -> Path:
    """Draw ``fig`` into ``path`` whole (:func:`harness.writing.atomic_path`), in the format
    its suffix names; return the path.

    Examples
    --------
    >>> import tempfile
    >>> fig, _ = new_figure(1, 1, (2, 2))
    >>> save_figure(fig, Path(tempfile.mkdtemp()) / "f.png", 50).read_bytes()[1:4]
    b'PNG'
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip("."))
    return path


LEGEND_WIDTH = 2.4
"""Inches right of the axes kept for a legend (:func:`outside_legend`)."""


def fixed_margins(fig: Figure, top: float = 0.4, right: float = 0.15) -> None:
    """Place the axes of ``fig`` with margins fixed in inches (0.8 left, ``right`` right: add
    :data:`LEGEND_WIDTH` for a legend beside the axes, 0.5 below, ``top`` above, 0.3 between
    rows and 0.2 between columns), and their axis labels at fixed distances from the axes
    (0.62 inch left, 0.27 inch below): a layout engine (constrained or tight layout), like the
    labels' automatic placement, measures every tick label and costs as much as the drawing
    itself."""
    width, height = fig.get_size_inches()
    fig.subplots_adjust(left=0.8 / width, right=1 - right / width, bottom=0.5 / height,
                        top=1 - top / height, hspace=0.3 * len(fig.axes) / height,
                        wspace=0.2 * len(fig.axes) / width)
    for ax in fig.axes:
        ax.yaxis.set_label_coords(0.0, 0.5, transform=offset_copy(ax.transAxes, fig, x=-0.62))
        ax.xaxis.set_label_coords(0.5, 0.0, transform=offset_copy(ax.transAxes, fig, y=-0.27))


def outside_legend(ax: Any, **options: Any) -> Any:
    """The legend of ``ax`` right of its axes, its top at the axes' top, over no data (the
    figure keeps :data:`LEGEND_WIDTH` for it, :func:`fixed_margins`); ``options`` as for
    ``Axes.legend``.

    Examples
    --------
    >>> fig, axes = new_figure(1, 1, (4, 2))
    >>> _ = axes[0, 0].plot([0, 1], label="a")
    >>> bool(outside_legend(axes[0, 0]).get_bbox_to_anchor().x0 > axes[0, 0].bbox.x1)
    True
    """
    return ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0,
                     fontsize="small", **options)


def decade_grid(ax: Any) -> None:
    """A grid at the decades of the log axis ``ax``, labelled ``1e-4``, without minor ticks:
    over the 10 to 16 decades an estimation error spans they are unreadable, and making them
    (like typesetting each decade's label as a formula) costs as much as the rest of the
    figure."""
    ax.minorticks_off()
    ax.yaxis.set_major_formatter(decade_label)
    ax.grid(True, alpha=0.3)


def decade_label(value: float, _position: int | None = None) -> str:
    """The label of a decade tick: ``1e-4``, ``1e0``; '' between decades.

    Examples
    --------
    >>> [decade_label(v) for v in (1e-4, 1.0, 100.0, 3.0, 0.0)]
    ['1e-4', '1e0', '1e2', '', '']
    """
    if not value > 0:
        return ""
    exponent = math.log10(value)
    return f"1e{round(exponent)}" if abs(exponent - round(exponent)) < 1e-9 else ""


def envelope(t: np.ndarray, y: np.ndarray,
             points: int = PLOT_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """The samples of ``y(t)`` worth drawing: all of them if there are at most ``points``,
    else the smallest and the largest of each of ``points // 2`` consecutive buckets, in time
    order, so that a line keeps its peaks and dips (a noisy error's spikes too) at a fraction
    of the drawing cost.

    Examples
    --------
    >>> t = np.arange(10.0)
    >>> envelope(t, np.array([0, 5, 1, 1, 1, 1, 1, 1, -3, 1.0]), points=4)
    (array([0., 1., 5., 8.]), array([ 0.,  5.,  1., -3.]))
    """
    if y.size <= points:
        return t, y
    size = -(-y.size // (points // 2))  # samples per bucket: at most points // 2 buckets
    full = y.size // size * size
    buckets = y[:full].reshape(-1, size)
    starts = np.arange(0, full, size)
    keep = [starts + buckets.argmin(axis=1), starts + buckets.argmax(axis=1)]
    if full < y.size:
        keep.append(full + np.array([np.argmin(y[full:]), np.argmax(y[full:])]))
    keep = np.unique(np.concatenate(keep))
    return t[keep], y[keep]


def plot_errors(result: SimulationResult, scenario: str, path: str | Path,
                log_scale: bool = True, subtitle: str = "") -> Path:
    """Write a PNG with the error components ``|z_i - x_i|`` of every observer (homogeneous,
    Luenberger, and the Kalman filter when ``result.z_kalman`` is set), one panel each.

    Parameters
    ----------
    result : SimulationResult
        A run of :func:`harness.reference.simulate`.
    scenario : str
        Scenario name (selects the title).
    path : str or Path
        Output PNG file.
    log_scale : bool
        Logarithmic error axis (linear otherwise).
    subtitle : str
        A second title line (which design, which seed).

    Returns
    -------
    Path
        The written file.
    """
    path = Path(path)
    panels = [("homogeneous (filtering) observer", result.z),
              ("linear (Luenberger) observer", result.z_lin)]
    if result.z_kalman is not None:
        panels.append(("steady-state Kalman filter", result.z_kalman))
    fig, grid = new_figure(1, len(panels), (5 * len(panels), 3.8), sharey=True)
    axes = grid[0]
    for ax, (title, estimate) in zip(axes, panels, strict=True):
        error = abs(estimate - result.x)
        for i in range(error.shape[1]):
            ax.plot(*envelope(result.t, error[:, i]), lw=0.8, label=f"|z{i + 1} - x{i + 1}|")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("t [s]")
        if log_scale:
            ax.set_yscale("log")
            ax.set_ylim(1e-16, None)
            decade_grid(ax)
        else:
            ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("estimation error")
    axes[0].legend(fontsize=8, loc="upper right")
    fig.suptitle(FIGURE_TITLES.get(scenario, scenario) + (f"\n{subtitle}" if subtitle else ""))
    fixed_margins(fig, top=0.75 if subtitle else 0.55)
    return save_figure(fig, path, 120)
