"""PNG plots of a run.

- ``errors.png`` (any system with evaluation errors): ``||x - x_hat||`` of every named error
  signal on a log scale, the evaluation windows shaded.
- ``figure.png`` (systems with a ``[plots]`` figure, i.e. the paper's scenarios): the paper's
  Figures 1-3 as :func:`harness.figures.plot_errors` draws them for the in-process reference, from
  the co-simulated signals.
- ``states.png`` (systems whose error signals all compare with one reference, e.g. ``plant.x``):
  each component of the reference and of every estimate over time.
- The plant command (:mod:`harness.own_plant`) draws its own ``errors.png``
  (:func:`plot_plant_errors`: ``||x - x_hat||`` and ``||q - q_hat||``, the transient shaded) and
  ``disturbance.png`` (:func:`plot_disturbance`: each q channel and its estimates).

A diverged estimator (:func:`harness.results.diverged`) does not set the range of these plots:
each axis spans the other curves (:func:`kept_range`) and the diverged one is drawn only while
it lies in that range (:func:`in_view`), its label saying so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from collections.abc import Set as AbstractSet
from pathlib import Path

import numpy as np
from fhobs.design.signals import SignalNames

from harness.figures import (
    LEGEND_WIDTH,
    decade_grid,
    envelope,
    fixed_margins,
    new_figure,
    outside_legend,
    save_figure,
)
from harness.master import CoSimResult
from harness.results import divergence, error_norm
from harness.system import SystemSpec

DIVERGED_LABEL = " (diverged, cut off)"
"""Appended to the label of a diverged estimator's curve."""
ESTIMATOR_COLOURS = {"homogeneous": "tab:red", "prescribed_time": "tab:purple",
                     "linear": "tab:orange", "kalman": "tab:blue", "supervised": "tab:green"}
"""Each estimator's colour (its label, :data:`fhobs.fmu.kinds.LABELS`) in every plot."""
REFERENCE_COLOUR = "black"
"""The colour of the true signal (the plant's state, its q) an estimate is drawn against."""
NOTE_ID = "panel-note"
"""The ``gid`` of a panel's note (:func:`panel_note`)."""
SPARE_COLOURS = ("tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:gray",
                 "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5", "#c49c94", "#f7b6d2",
                 "#c7c7c7", "#dbdb8d", "#9edae5")
"""The colours of other labels, in the order they come: the rest of tab10, then tab20's
light shades; beyond them hues spread evenly (:func:`spare_colours`)."""


def spare_colours(count: int) -> list[str]:
    """``count`` distinct colours for labels without their own: :data:`SPARE_COLOURS` first,
    then hues spread evenly around the HSV circle (none repeats a colour of the map).

    Examples
    --------
    >>> spare_colours(2)
    ['tab:brown', 'tab:pink']
    >>> colours = spare_colours(40)
    >>> len(set(colours)), colours[15]
    (40, '#d90000')
    """
    extra = max(count - len(SPARE_COLOURS), 0)
    hues = [_hsv_hex(i / extra) for i in range(extra)]
    return [*SPARE_COLOURS, *hues][:count]


def _hsv_hex(hue: float) -> str:
    """The saturated colour of ``hue`` (0..1) at 85 % value, as ``#rrggbb``."""
    import colorsys

    return "#" + "".join(f"{round(255 * c):02x}" for c in colorsys.hsv_to_rgb(hue, 1.0, 0.85))


def estimator_colours(labels: list[str]) -> dict[str, str]:
    """``{label: colour}``: an estimator's own (:data:`ESTIMATOR_COLOURS`), other labels the
    spare colours in their order (:func:`spare_colours`): no two labels share a colour.

    Examples
    --------
    >>> estimator_colours(["kalman", "ours", "homogeneous", "theirs"])
    {'kalman': 'tab:blue', 'ours': 'tab:brown', 'homogeneous': 'tab:red', 'theirs': 'tab:pink'}
    >>> len(set(estimator_colours([f"e{i}" for i in range(30)]).values()))
    30
    """
    others = [label for label in dict.fromkeys(labels) if label not in ESTIMATOR_COLOURS]
    spare = dict(zip(others, spare_colours(len(others)), strict=True))
    return {label: ESTIMATOR_COLOURS.get(label) or spare[label] for label in labels}


def kept_range(curves: list[np.ndarray], log: bool = False) -> tuple[float, float] | None:
    """The y range of the curves kept in view (not diverged), with a margin: a decade each way
    on a log axis, 5 % of the span on a linear one; None without a finite (on a log axis:
    positive) value.

    Examples
    --------
    >>> kept_range([np.array([0.0, 1.0]), np.array([-1.0, np.inf])])
    (-1.1, 1.1)
    >>> kept_range([np.array([1e-3, 1e2])], log=True)
    (0.0001, 1000.0)
    """
    values = np.concatenate([np.ravel(curve) for curve in curves]) if curves else np.empty(0)
    values = values[np.isfinite(values) & ((values > 0.0) if log else True)]
    if values.size == 0:
        return None
    lo, hi = float(values.min()), float(values.max())
    if log:
        return lo / 10.0, hi * 10.0
    margin = 0.05 * (hi - lo) or 0.05 * max(abs(hi), 1.0)
    return lo - margin, hi + margin


def panel_note(ax, line: str) -> None:  # noqa: ANN001
    """Add ``line`` to the note in the lower left corner of the panel ``ax`` (one text per
    panel, its lines in the order they come).

    Examples
    --------
    >>> from harness.figures import new_figure
    >>> ax = new_figure(1, 1, (2, 2))[1][0, 0]
    >>> panel_note(ax, "a"); panel_note(ax, "b")
    >>> [t.get_text() for t in ax.texts]
    ['a\\nb']
    """
    for text in ax.texts:
        if text.get_gid() == NOTE_ID:
            text.set_text(f"{text.get_text()}\n{line}")
            return
    ax.text(0.01, 0.02, line, transform=ax.transAxes, ha="left", va="bottom", fontsize="x-small",
            gid=NOTE_ID, bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"})


def in_view(ax, curves: dict[str, np.ndarray], diverged: AbstractSet[str],  # noqa: ANN001
            log: bool = False) -> dict[str, np.ndarray]:
    """``curves`` (``{label: values}``) as an axis draws them: with a diverged one among them
    and others to range over, the axis's y range set to the others' (:func:`kept_range`) and
    the diverged ones drawn only where they lie in it (NaN elsewhere: a growing oscillation
    does not fill the panel), their labels ending in ``DIVERGED_LABEL`` and the panel's note
    saying so (``"linear diverged (max 1e+32), clipped"``); unchanged otherwise.

    Examples
    --------
    >>> from harness.figures import new_figure
    >>> ax = new_figure(1, 1, (2, 2))[1][0, 0]
    >>> out = in_view(ax, {"a": np.array([0.0, 1.0]), "b": np.array([0.5, 1e30])}, {"b"})
    >>> out["b (diverged, cut off)"].tolist()
    [0.5, nan]
    >>> [round(float(y), 12) for y in ax.get_ylim()], ax.texts[0].get_text()
    ([-0.05, 1.05], 'b diverged (max 1e+30), clipped')
    """
    if not diverged & set(curves):
        return curves
    limits = kept_range([values for label, values in curves.items() if label not in diverged],
                        log)
    if limits is None:
        return curves
    ax.set_ylim(*limits)
    lo, hi = limits
    for label in [label for label in curves if label in diverged]:
        values = np.abs(curves[label][~np.isnan(curves[label])])
        peak = float(np.max(values)) if values.size else math.nan
        panel_note(ax, f"{label} diverged (max {peak:.0e}), clipped")
    return {label + DIVERGED_LABEL if label in diverged else label:
            np.where((values >= lo) & (values <= hi), values, np.nan) if label in diverged
            else values for label, values in curves.items()}


def on_log_axis(ax, curves: dict[str, np.ndarray]) -> dict[str, np.ndarray]:  # noqa: ANN001
    """``curves`` as a log axis draws them: the values that are not positive and finite
    (zeros, negatives, infinities, NaN) left off (NaN), their number in the panel's note.

    Examples
    --------
    >>> from harness.figures import new_figure
    >>> ax = new_figure(1, 1, (2, 2))[1][0, 0]
    >>> on_log_axis(ax, {"a": np.array([1.0, 0.0, np.inf])})["a"].tolist()
    [1.0, nan, nan]
    >>> ax.texts[0].get_text()
    '2 points not drawn on the log axis (zero, negative or not finite)'
    """
    kept = {label: np.where(np.isfinite(values) & (values > 0.0), values, np.nan)
            for label, values in curves.items()}
    left_off = sum(int(np.count_nonzero(np.isnan(kept[label]) & ~np.isnan(curves[label]))
                       + np.count_nonzero(np.isnan(curves[label]))) for label in curves)
    if left_off:
        noun = "point" if left_off == 1 else "points"
        panel_note(ax, f"{left_off} {noun} not drawn on the log axis "
                       "(zero, negative or not finite)")
    return kept


def _draw(ax, time: np.ndarray, curves: dict[str, np.ndarray],  # noqa: ANN001
          colours: dict[str, str], diverged: AbstractSet[str], log: bool = False,
          reference: str | None = None, what: str = "{}") -> None:
    """Draw ``curves`` (``{label: values}``) on ``ax``: each in its colour of ``colours``
    (``reference`` in :data:`REFERENCE_COLOUR`, thicker), the ``diverged`` ones clipped
    (:func:`in_view`), on a log axis the points it cannot show left off and counted
    (:func:`on_log_axis`); the legend label ``what`` with ``{}`` for the curve's label."""
    if log:
        ax.set_yscale("log")
        curves = on_log_axis(ax, curves)
    for label, values in in_view(ax, curves, diverged, log).items():
        name = label.removesuffix(DIVERGED_LABEL)
        style = ({"color": REFERENCE_COLOUR, "lw": 2} if name == reference
                 else {"color": colours[name], "lw": 1})
        text = name if name == reference else what.format(name) + label[len(name):]
        ax.plot(*envelope(time, values), label=text, **style)


def _common_unit(units: Sequence[str]) -> str:
    """The unit of a norm of signals in ``units``: theirs when they share one, else ''.

    Examples
    --------
    >>> _common_unit(["rad", "rad"]), _common_unit(["A", "rad"]), _common_unit([])
    ('rad', '', '')
    """
    return units[0] if units and len(set(units)) == 1 else ""


def _unit_label(text: str, unit: str) -> str:
    return f"{text} [{unit}]" if unit else text


def plot_results(result: CoSimResult, spec: SystemSpec, out: Path,
                 title: str | None = None) -> list[Path]:
    """Write the plots of ``result`` into ``out`` and return their paths; ``title`` (default:
    the system's name) heads each plot, so that plots of different designs or seeds differ."""
    title = spec.name if title is None else title
    errors = spec.evaluation.errors
    diverged = {name for name, flag in divergence(result, spec.evaluation).items() if flag}
    paths = [plot_error_norms(result, spec, out / "errors.png", title, diverged)] if errors else []
    references = {reference for reference, _ in errors.values()}
    if len(references) == 1:
        estimates = {name: estimate for name, (_, estimate) in errors.items()}
        paths.append(plot_state_estimates(result, references.pop(), estimates,
                                          out / "states.png", title, diverged))
    if spec.figure is not None:
        paths.append(plot_paper_figure(result, spec, out / "figure.png", title))
    return paths


def plot_paper_figure(result: CoSimResult, spec: SystemSpec, path: Path, title: str) -> Path:
    """The paper-style figure of harness.figures from the co-simulated signals (``title`` under
    the paper's figure title)."""
    from harness.figures import plot_errors
    from harness.reference import SimulationResult

    fields = {}
    for name, signal in spec.figure.signals.items():
        columns = result.vector(signal)
        fields[name] = columns[:, 0] if name in ("xi", "sigma") else columns
    return plot_errors(SimulationResult(t=result.time, **fields), spec.figure.scenario, path,
                       subtitle=title)


def plot_error_norms(result: CoSimResult, spec: SystemSpec, path: Path, title: str,
                     diverged: AbstractSet[str] = frozenset()) -> Path:
    """``errors.png``: the norms of the evaluation's error signals, the evaluation windows
    shaded; the ``diverged`` ones clipped (:func:`in_view`), the legend right of the axes."""
    fig, axes = new_figure(1, 1, (7 + LEGEND_WIDTH, 4))
    ax = axes[0, 0]
    fixed_margins(fig, right=LEGEND_WIDTH + 0.15)
    errors = spec.evaluation.errors
    labels = {name: f"{name}: ||{reference} - {estimate}||"
              for name, (reference, estimate) in errors.items()}
    colours = estimator_colours(list(errors))
    _draw(ax, result.time, {labels[name]: error_norm(result, *signals)
                            for name, signals in errors.items()},
          {labels[name]: colours[name] for name in errors},
          {labels[name] for name in diverged if name in labels}, log=True)
    for i, (a, b) in enumerate(spec.evaluation.windows):
        ax.axvspan(a, b, color="0.9", zorder=0, label="evaluation window" if i == 0 else None)
    ax.set_xlim(result.time[0], result.time[-1])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("estimation error")
    ax.set_title(title)
    outside_legend(ax)
    decade_grid(ax)
    return save_figure(fig, path, 120)


def plot_state_estimates(result: CoSimResult, state: str, estimates: dict[str, str],
                         path: Path, title: str, diverged: AbstractSet[str] = frozenset(),
                         names: Sequence[str] | None = None) -> Path:
    """``states.png``: one panel per component of ``state`` (named ``names[i]``, e.g.
    ``"inductor.i [A]"``, or by its variable, ``plant.x[1]``...) with the same component of
    every estimate (``{label: signal}``, a colour each) over time; the ``diverged`` estimates
    clipped to the range of the others (:func:`in_view`); the legend right of the panels.

    Examples
    --------
    >>> import tempfile
    >>> t = np.linspace(0.0, 1.0, 11)
    >>> result = CoSimResult(t, ("p.x[1]", "a.x_hat[1]", "b.x_hat[1]"),
    ...                      np.column_stack([np.ones(11), 1 - np.exp(-5 * t), 1e9 ** t]), 10, 0.0)
    >>> path = Path(tempfile.mkdtemp()) / "states.png"
    >>> plot_state_estimates(result, "p.x", {"a": "a.x_hat", "b": "b.x_hat"}, path, "t",
    ...                      {"b"}, ["w [rad/s]"]).stat().st_size > 1000
    True
    """
    x = result.vector(state)
    n = x.shape[1]
    columns = {label: result.vector(signal) for label, signal in estimates.items()}
    colours = estimator_colours(list(columns))
    fig, axes = new_figure(n, 1, (7 + LEGEND_WIDTH, 1.6 * n + 0.6), sharex=True)
    fixed_margins(fig, right=LEGEND_WIDTH + 0.15)
    for i, ax in enumerate(axes[:, 0]):
        curves = {state: x[:, i]} | {label: estimate[:, i] for label, estimate in columns.items()}
        _draw(ax, result.time, curves, colours, diverged, reference=state)
        if names is None:
            ax.set_ylabel(f"{state}[{i + 1}]")
        else:  # a model's names are long: each above its panel
            ax.set_title(names[i], loc="left", fontsize="small")
        ax.grid(True, alpha=0.3)
    outside_legend(axes[0, 0])
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("t [s]")
    return save_figure(fig, path, 120)


def plot_plant_errors(result: CoSimResult, errors: dict[str, tuple[str, str]], q: np.ndarray,
                      q_hats: dict[str, np.ndarray], settled: float, path: Path,
                      diverged: AbstractSet[str] = frozenset(), *,
                      names: SignalNames | None = None, title: str = "") -> Path:
    """``errors.png`` of the plant command: ``||x - x_hat||`` per estimator (top) and, when an
    estimator has a disturbance model, ``||q - q_hat||`` (bottom), log scale; the transient
    ``[t0, settled]`` shaded; the ``diverged`` estimators clipped (:func:`in_view`).

    Parameters
    ----------
    result : CoSimResult
        The run.
    errors : dict
        ``{label: (reference, estimate)}`` of the x errors (the evaluation's).
    q : numpy.ndarray
        The q the plant got (time x r).
    q_hats : dict
        ``{label: q_hat}`` (time x r) of the estimators with a disturbance model.
    settled : float
        End of the transient window.
    path : Path
        The PNG to write.
    diverged : set of str
        The labels of the estimators that diverged.
    names : SignalNames, optional
        The plant's signals: a norm's axis carries their unit when they share one.
    title : str
        The plant's name, heading the plot.

    Returns
    -------
    Path

    Examples
    --------
    >>> import tempfile
    >>> t = np.linspace(0.0, 1.0, 11)
    >>> result = CoSimResult(t, ("p.x[1]", "o.x_hat[1]"),
    ...                      np.column_stack([np.ones(11), 1 - np.exp(-5 * t)]), 10, 0.0)
    >>> q = np.ones((11, 1))
    >>> path = Path(tempfile.mkdtemp()) / "errors.png"
    >>> q_hats = {"obs": 1 - np.exp(-3 * t)[:, None]}
    >>> plot_plant_errors(result, {"obs": ("p.x", "o.x_hat")}, q, q_hats, 0.5,
    ...                   path).stat().st_size > 1000
    True
    """
    rows = 2 if q_hats else 1
    fig, axes = new_figure(rows, 1, (7 + LEGEND_WIDTH, 2.6 * rows + 0.8), sharex=True)
    fixed_margins(fig, top=0.6, right=LEGEND_WIDTH + 0.15)
    colours = estimator_colours(list(errors))
    panels = [{label: error_norm(result, reference, estimate)
               for label, (reference, estimate) in errors.items()},
              {label: np.linalg.norm(q - q_hat, axis=1) for label, q_hat in q_hats.items()}]
    units = ([], []) if names is None else (names.state_units, names.unknown_input_units)
    for ax, curves, what, unit in zip(axes[:, 0], panels, ("x", "q"), units, strict=False):
        _draw(ax, result.time, curves, colours, diverged, log=True,
              what=f"{{}}: ||{what} - {what}_hat||")
        ax.axvspan(result.time[0], settled, color="0.92", zorder=0)
        ax.set_ylabel(_unit_label(f"||{what} - {what}_hat||", _common_unit(unit)))
        decade_grid(ax)
        outside_legend(ax)
    axes[0, 0].set_title((f"{title}: " if title else "")
                         + "estimation errors (shaded: transient, up to the settling time)")
    axes[-1, 0].set_xlim(result.time[0], result.time[-1])
    axes[-1, 0].set_xlabel("t [s]")
    return save_figure(fig, path, 120)


def plot_disturbance(time: np.ndarray, q: np.ndarray, q_hats: dict[str, np.ndarray],
                     settled: float, path: Path, diverged: AbstractSet[str] = frozenset(), *,
                     names: Sequence[str] | None = None, title: str = "") -> Path:
    """``disturbance.png``: one panel per q channel (named ``names[i]``, e.g.
    ``"M_load [N.m]"``, else ``q[i]``) with q (the plant's input) and every estimator's
    ``q_hat`` of it; the transient shaded; the ``diverged`` estimators clipped
    (:func:`in_view`).

    Parameters
    ----------
    time : numpy.ndarray
        Sample times.
    q : numpy.ndarray
        The q the plant got (time x r).
    q_hats : dict
        ``{label: q_hat}`` (time x r).
    settled : float
        End of the transient window.
    path : Path
        The PNG to write.
    diverged : set of str
        The labels of the estimators that diverged.
    names : sequence of str, optional
        Each channel's name and unit.
    title : str
        The plant's name, heading the plot.

    Returns
    -------
    Path

    Examples
    --------
    >>> import tempfile
    >>> t = np.linspace(0.0, 1.0, 11)
    >>> path = Path(tempfile.mkdtemp()) / "disturbance.png"
    >>> plot_disturbance(t, np.ones((11, 1)), {"obs": np.zeros((11, 1))}, 0.5,
    ...                  path).stat().st_size > 1000
    True
    """
    r = q.shape[1]
    fig, axes = new_figure(r, 1, (7 + LEGEND_WIDTH, 1.8 * r + 0.8), sharex=True)
    fixed_margins(fig, right=LEGEND_WIDTH + 0.15)
    colours = estimator_colours(list(q_hats))
    for i, ax in enumerate(axes[:, 0]):
        curves = {"q": q[:, i]} | {label: q_hat[:, i] for label, q_hat in q_hats.items()}
        _draw(ax, time, curves, colours, diverged, reference="q", what="{} q_hat")
        ax.axvspan(time[0], settled, color="0.92", zorder=0)
        ax.set_ylabel(f"q[{i + 1}]" if names is None else names[i])
        ax.grid(True, alpha=0.3)
    outside_legend(axes[0, 0])
    axes[0, 0].set_title((f"{title}: " if title else "") + "unknown inputs and their estimates")
    axes[-1, 0].set_xlim(time[0], time[-1])
    axes[-1, 0].set_xlabel("t [s]")
    return save_figure(fig, path, 120)
