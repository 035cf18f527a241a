"""The sweep's pictures read back from the figure objects (matplotlib, no file needed): panels,
one colour per estimator, the seeds as a spread, the notes' counts, the value axes against the
data; the Pareto picture's fronts, seed bars, axis titles and labels; the table read back."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from harness.plotting import ESTIMATOR_COLOURS
from harness.sweep import load_sweep, pareto_points, read_table, write_table
from harness.sweep_plots import (
    FLOOR_RATIO,
    axis_figure,
    pareto_figure,
    plot_sweep,
    plotted_axes,
)

ESTIMATORS = ("homogeneous", "kalman", "linear")
RHOS = (2.0, 3.0, 4.0, 6.0)
SEEDS = range(5)


def sweep_of(axes: tuple[str, ...]):
    sweep = load_sweep("pendulum_noisy_seeds")
    return dataclasses.replace(sweep, axes=axes)


def rho_rows() -> list[dict]:
    """A rho grid over 5 seeds: an RMS spread by the seed, a settling time that is inf for the
    linear observer at rho = 2, a floor at round-off for the homogeneous observer, one NaN,
    one failed point."""
    rng = np.random.default_rng(3)
    rows = []
    for rho, seed in itertools.product(RHOS, SEEDS):
        row = {"status": "ok", "base": "pendulum_noisy", "rho": rho, "seed": seed}
        for i, estimator in enumerate(ESTIMATORS):
            row[f"{estimator}.rms_error_1_3"] = (i + 1) * 1e-3 * rho * (1 + 0.2 * rng.random())
            row[f"{estimator}.time_to_1e-3"] = (
                math.inf if (estimator, rho) == ("linear", 2.0) else (i + 1) / rho)
            row[f"{estimator}.floor"] = 1e-110 if estimator == "homogeneous" else 1e-4 * (i + 1)
        rows.append(row)
    rows[7]["kalman.rms_error_1_3"] = math.nan
    rows.append({"status": "failed", "base": "pendulum_noisy", "rho": 5.0, "seed": 0,
                 "reason": "SpecError: x"})
    return rows


@pytest.fixture(scope="module")
def rho_figure():
    rows = rho_rows()
    return rows, axis_figure(rows, sweep_of(("base", "rho", "seed")), "rho")


def panels(fig) -> dict[str, object]:
    return {ax.get_title().split("\n")[0]: ax for ax in fig.axes}


def test_one_panel_per_figure_one_colour_per_estimator(rho_figure):
    """Three figures: three panels; in each, one median line per estimator, in the
    estimator's own colour, all colours distinct; the seed is not an axis."""
    from matplotlib.colors import to_hex

    _, fig = rho_figure
    assert len(fig.axes) == 3
    for ax in fig.axes:
        lines = {line.get_label(): to_hex(line.get_color()) for line in ax.get_lines()
                 if not line.get_label().startswith("_")}
        assert sorted(lines) == sorted(ESTIMATORS)
        assert lines == {e: to_hex(ESTIMATOR_COLOURS[e]) for e in ESTIMATORS}
        assert len(set(lines.values())) == len(ESTIMATORS)
        assert ax.get_xlabel() == "rho"
    assert plotted_axes(sweep_of(("base", "rho", "seed")), rho_figure[0]) == ["base", "rho"]


def test_seeds_are_a_median_and_a_band(rho_figure):
    """The RMS panel: each estimator's line is the median over the seeds at each rho, its band
    spans the least to the largest (NaN left out)."""
    rows, fig = rho_figure
    ax = panels(fig)["RMS ||x - x_hat|| over [1, 3] s"]
    for estimator, line in ((line.get_label(), line) for line in ax.get_lines()
                            if line.get_label() in ESTIMATORS):
        values = {rho: [r[f"{estimator}.rms_error_1_3"] for r in rows
                        if r["rho"] == rho and r["status"] == "ok"] for rho in RHOS}
        values = {rho: [v for v in vs if not math.isnan(v)] for rho, vs in values.items()}
        np.testing.assert_allclose(line.get_xdata(), RHOS)
        np.testing.assert_allclose(line.get_ydata(), [np.median(values[r]) for r in RHOS])
    bands = [c for c in ax.collections if c.get_paths()]
    assert len(bands) == len(ESTIMATORS)
    for band in bands:
        vertices = band.get_paths()[0].vertices
        assert vertices[:, 1].min() < vertices[:, 1].max()


def test_notes_count_what_is_not_drawn_where_it_would_be(rho_figure):
    """The titles count the never-settled points (inf, drawn on the top edge), the round-off
    floors (drawn on the bottom edge), the NaN, and the failed point."""
    rows, fig = rho_figure
    by_title = panels(fig)
    settle = by_title["time to rel. error <= 1e-3 [s]"]
    assert "5 never settled (^ at top)" in settle.get_title()
    top = [line for line in settle.get_lines() if line.get_marker() == "^"]
    assert len(top) == 1 and np.allclose(top[0].get_ydata(), settle.get_ylim()[1])
    assert len(top[0].get_ydata()) == 5
    floor = by_title["rel. error floor (end of run)"]
    assert f"{len(RHOS) * len(SEEDS)} below" in floor.get_title()
    bottom = [line for line in floor.get_lines() if line.get_marker() == "v"]
    assert len(bottom) == 1 and np.allclose(bottom[0].get_ydata(), floor.get_ylim()[0])
    assert "1 NaN" in by_title["RMS ||x - x_hat|| over [1, 3] s"].get_title()
    assert "1 failed point not shown" in fig.get_suptitle()
    assert "over 5 seeds" in fig.get_suptitle()


def test_value_axes_span_the_data(rho_figure):
    """Each panel's limits enclose its finite values above the round-off floor, no lower than
    FLOOR_RATIO times the largest (the floor panel does not reach down to 1e-110); log only
    where the values span more than two decades."""
    rows, fig = rho_figure
    for title, ax in panels(fig).items():
        figure = {"RMS": "rms_error_1_3", "time": "time_to_1e-3", "rel.": "floor"}[
            title.split()[0]]
        values = np.array([r[f"{e}.{figure}"] for r in rows if r["status"] == "ok"
                           for e in ESTIMATORS], dtype=float)
        finite = values[np.isfinite(values)]
        kept = finite[finite >= FLOOR_RATIO * finite.max()]
        low, high = ax.get_ylim()
        assert low <= kept.min() and high >= kept.max(), title
        assert low >= FLOOR_RATIO * kept.max() / 2, title
        assert (ax.get_yscale() == "log") == (np.log10(kept.max() / kept.min()) > 2), title
        assert low > 0.5 * kept.min() or ax.get_yscale() == "log", title


def test_a_sweep_of_seeds_alone_is_drawn_per_estimator(tmp_path):
    """Only the seed swept: spread.png, one category, error bars from least to largest."""
    rows = [{"status": "ok", "seed": s, "kalman.rms_error_1_3": float(s + 1)} for s in SEEDS]
    sweep = sweep_of(("seed",))
    assert plotted_axes(sweep, rows) == [None]
    fig = axis_figure(rows, sweep, None)
    ax, = fig.axes
    assert [t.get_text() for t in ax.get_xticklabels()] == ["all points"]
    container, = ax.containers
    segments = container.lines[2][0].get_segments()
    assert np.allclose(segments[0][:, 1], [1.0, 5.0])
    assert [p.name for p in plot_sweep(rows, sweep, tmp_path)] == ["spread.png"]


# -- the Pareto picture ------------------------------------------------------------------------
def pareto_rows() -> list[dict]:
    """Kalman filters over intensities and homogeneous designs over rho, each perturbed once
    and noisy over three seeds, with a trade-off (a dominated point among them)."""
    rows = []
    designs = [({"spec.noise.process_intensity": w}, "kalman", 1e-3 / math.sqrt(w),
                1e-3 * w ** 0.25) for w in (1e-2, 1.0, 1e2, 1e4)]
    designs += [({"rho": rho}, "homogeneous", 1e-3 * 6 / rho, 5e-4 * rho / 6)
                for rho in (3.0, 6.0, 9.0)]
    designs += [({"rho": 12.0}, "homogeneous", 1e-2, 1e-2)]  # dominated
    for params, estimator, x, y in designs:
        base = {"rho": None, "spec.noise.process_intensity": None, **params}
        rows.append({"status": "ok", "base": "pendulum_perturbed", "seed": None, **base,
                     f"{estimator}.max_error_1_3": x})
        for seed in range(3):
            rows.append({"status": "ok", "base": "pendulum_noisy", "seed": seed, **base,
                         f"{estimator}.rms_error_1_3": y * (1 + 0.1 * seed)})
    return rows


@pytest.fixture(scope="module")
def pareto():
    sweep = sweep_of(("base", "rho", "seed", "spec.noise.process_intensity"))
    sweep = dataclasses.replace(sweep, pareto=sweep.pareto | {"estimators": {
        "kalman": ["spec.noise.process_intensity"], "homogeneous": ["rho"]}})
    rows = pareto_rows()
    return rows, sweep, pareto_figure(rows, sweep)


def dominated(p, others) -> bool:
    return any(o.x <= p.x and o.y <= p.y and (o.x < p.x or o.y < p.y) for o in others)


def test_pareto_fronts_are_step_lines_of_the_undominated_designs(pareto):
    """Each estimator's front line passes through exactly its designs that no other of its
    designs beats in both (checked pairwise here), by x, drawn as steps."""
    rows, sweep, fig = pareto
    ax, = fig.axes
    points = pareto_points(rows, sweep)
    fronts = {line.get_label().split(":")[0]: line for line in ax.get_lines()
              if line.get_label().endswith("Pareto front")}
    assert sorted(fronts) == ["homogeneous", "kalman"]
    for estimator, line in fronts.items():
        expected = sorted((p.x, p.y) for p in points[estimator]
                          if not dominated(p, points[estimator]))
        assert line.get_drawstyle() == "steps-post"
        assert list(zip(line.get_xdata(), line.get_ydata(), strict=True)) == expected
    assert len(fronts["homogeneous"].get_xdata()) == 3  # rho = 12 is dominated


def test_pareto_seed_bars_and_axis_titles(pareto):
    """The noisy figure's bars span the least to the largest RMS over the seeds; the axes
    are titled by the figures with units, no file path; log axes."""
    rows, sweep, fig = pareto
    ax, = fig.axes
    design = ("rho", "spec.noise.process_intensity")
    for container in ax.containers:
        estimator = container.get_label().split(" (")[0]
        x_of = {tuple(r[a] for a in design): r[f"{estimator}.max_error_1_3"] for r in rows
                if r.get(f"{estimator}.max_error_1_3") is not None}
        bars = {}
        for r in rows:
            if r.get(f"{estimator}.rms_error_1_3") is not None:
                bars.setdefault(x_of[tuple(r[a] for a in design)], []).append(
                    r[f"{estimator}.rms_error_1_3"])
        segments = container.lines[2][0].get_segments()
        assert len(segments) == len(bars)
        for seg in segments:
            noisy = bars[seg[0, 0]]
            assert np.allclose(sorted(seg[:, 1]), [min(noisy), max(noisy)])
    assert ax.get_xlabel().startswith("max ||x - x_hat|| over [1, 3] s")
    assert ax.get_ylabel().startswith("RMS ||x - x_hat|| over [1, 3] s")
    for label in (ax.get_xlabel(), ax.get_ylabel()):
        assert "/" not in label and ".toml" not in label
    assert ax.get_xscale() == ax.get_yscale() == "log"


def test_pareto_labels_do_not_overlap(pareto):
    """The design labels drawn lie inside the axes and no two overlap (measured on the drawn
    figure); at least one front point is labelled, by a short design name."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    _, _, fig = pareto
    ax, = fig.axes
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    texts = [t for t in ax.texts if t.get_visible()]
    assert texts and all(" = " in t.get_text() and "spec." not in t.get_text() for t in texts)
    boxes = [t.get_window_extent(renderer) for t in texts]
    frame = ax.get_window_extent(renderer)
    assert all(frame.x0 <= b.x0 and b.x1 <= frame.x1 and frame.y0 <= b.y0
               and b.y1 <= frame.y1 for b in boxes)
    assert not any(a.overlaps(b) for a, b in itertools.combinations(boxes, 2))


def test_pareto_labels_are_at_most_pareto_labels(pareto, monkeypatch):
    """With PARETO_LABELS = 1 one front point is labelled."""
    import harness.sweep_plots as sweep_plots

    rows, sweep, _ = pareto
    monkeypatch.setattr(sweep_plots, "PARETO_LABELS", 1)
    ax, = pareto_figure(rows, sweep).axes
    assert len(ax.texts) == 1


# -- the table ---------------------------------------------------------------------------------
def test_table_reads_back_as_a_data_frame(tmp_path):
    """read_table: the parquet and the CSV as pandas DataFrames with the rows' values (a
    missing figure NaN, a list JSON text)."""
    rows = [{"point": 0, "rho": 3.0, "x0": [1, 0], "kalman.peak": 1.5, "status": "ok"},
            {"point": 1, "rho": 4.0, "x0": [2, 0], "status": "failed"}]
    write_table(rows, tmp_path)
    for path in (tmp_path, tmp_path / "sweep.csv"):
        frame = read_table(path)
        assert frame["rho"].tolist() == [3.0, 4.0]
        assert frame["status"].tolist() == ["ok", "failed"]
        assert frame["x0"].tolist() == ["[1, 0]", "[2, 0]"]
        assert frame["kalman.peak"].iloc[0] == 1.5 and math.isnan(frame["kalman.peak"].iloc[1])


def test_a_failing_table_write_leaves_the_previous_table(tmp_path, monkeypatch):
    """A writer that fails half-way (as a kill would stop it): the previous sweep.parquet and
    sweep.csv are intact and no temporary file is left."""
    import pyarrow.csv as pa_csv
    import pyarrow.parquet as pq

    write_table([{"point": 0, "rho": 3.0}], tmp_path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def broken(table, where, *args, **kwargs):
        with open(where, "wb") as f:
            f.write(b"PAR1")
        raise OSError("disk full")

    for module, name in ((pq, "write_table"), (pa_csv, "write_csv")):
        with monkeypatch.context() as patch:
            patch.setattr(module, name, broken)
            with pytest.raises(OSError, match="disk full"):
                write_table([{"point": 0, "rho": 4.0}, {"point": 1, "rho": 5.0}], tmp_path)
        assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
        assert read_table(tmp_path)["rho"].tolist() == [3.0]


def test_docstring_examples():
    """The Examples sections of harness.sweep_plots run and give what they print."""
    import doctest

    import harness.sweep_plots

    result = doctest.testmod(harness.sweep_plots, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0
