"""A diverged estimator is named, not averaged into the figures silently.

A synthetic run: the plant's two states decay, ``homogeneous`` converges to them after peaking
by a factor of 4e3 (a high-gain observer's transient), ``linear`` starts with the same error
and oscillates with a growing amplitude, 1e10 times its initial error at the end. The summary
flags ``linear`` (and only it), the tables mark its row and name it under them, the seeds'
mean keeps the flag, and the plots' range is that of the other curves.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness.cli import format_table, mean_summary
from harness.figures import new_figure
from harness.master import CoSimResult
from harness.own_plant import plant_table
from harness.plotting import DIVERGED_LABEL, in_view, plot_plant_errors, plot_state_estimates
from harness.results import DIVERGENCE_FACTOR, diverged, summary, write_summary
from harness.system import Evaluation, SystemSpec

T = np.linspace(0.0, 4.0, 401)
ERRORS = {"homogeneous": ("plant.x", "observer.x_hat"),
          "linear": ("plant.x", "luenberger.x_hat")}
"""The labels of the plant command's table: ``homogeneous`` converges, ``linear`` diverges."""
EVALUATION = Evaluation(at=(1.0,), windows=((1.0, 4.0),), peak=True, errors=ERRORS)


def synthetic_run() -> CoSimResult:
    """The plant, a converging and a diverging estimate (module docstring)."""
    x = np.column_stack([np.exp(-T), 0.5 * np.exp(-2.0 * T)])
    start = np.array([1.0, 0.5])  # both estimators start at 0: error x(0)
    bump = 4e3 * T * np.exp(-20.0 * T) * 20.0 * np.e  # peak 4e3 at t = 0.05
    good = x - np.outer(np.exp(-5.0 * T) + bump, start)
    bad = x - np.outer(np.exp(T * np.log(1e10) / T[-1]) * np.cos(40.0 * T), start)
    names = ("plant.x[1]", "plant.x[2]", "observer.x_hat[1]", "observer.x_hat[2]",
             "luenberger.x_hat[1]", "luenberger.x_hat[2]")
    return CoSimResult(T, names, np.column_stack([x, good, bad]), T.size - 1, 0.1)


def test_divergence_is_growth_beyond_the_factor():
    e0 = 0.25
    assert not diverged(np.array([e0, DIVERGENCE_FACTOR * e0, 1e-12]))
    assert diverged(np.array([e0, DIVERGENCE_FACTOR * e0 * (1.0 + 1e-9)]))
    assert diverged(np.array([e0, 1.0, np.inf])) and diverged(np.array([e0, np.nan]))
    assert not diverged(np.array([0.0, 5.0]))  # an estimator that starts exact


def test_summary_flags_the_diverged_estimator_only(tmp_path):
    result = synthetic_run()
    e = {name: np.linalg.norm(result.vector(ref) - result.vector(est), axis=1)
         for name, (ref, est) in ERRORS.items()}
    assert 3e3 < e["homogeneous"].max() / e["homogeneous"][0] < 5e3  # peaking, not divergence
    assert e["linear"].max() / e["linear"][0] > 1e9
    data = summary(result, EVALUATION, scenario="synthetic")
    path = write_summary(data, tmp_path / "summary.json")
    written = json.loads(path.read_text())
    assert written["linear"]["diverged"] is True
    assert "diverged" not in written["homogeneous"]
    assert written["linear"]["peak"] == pytest.approx(e["linear"].max() / e["linear"][0])


def test_tables_mark_and_name_the_diverged_estimator():
    data = summary(synthetic_run(), EVALUATION)
    for table, row_start in ((format_table({"synthetic": data}), "synthetic  linear (diverged)"),
                             (plant_table(data), "linear (diverged)")):
        lines = table.splitlines()
        assert sum(line.startswith(row_start) for line in lines) == 1, table
        assert not any("homogeneous (diverged)" in line for line in lines)
        assert lines[-1].startswith("note: ") and "linear" in lines[-1]
        assert "diverged" not in lines[0]  # not a column of figures
    calm = {"steps": 1, "wall_time_s": 0.0, "homogeneous": data["homogeneous"]}
    assert "note" not in format_table({"synthetic": calm}) + plant_table(calm)


def test_mean_over_seeds_keeps_the_flag_of_any_seed():
    result = synthetic_run()
    diverging, calm = (summary(result, EVALUATION) for _ in range(2))
    calm["linear"] = dict(diverging["homogeneous"])
    spec = SystemSpec("synthetic", {}, (), 0.01, 4.0, evaluation=EVALUATION)
    mean = mean_summary([calm, diverging], spec, [0, 1], 4.0)
    assert mean["linear"]["diverged"] is True and "diverged" not in mean["homogeneous"]
    peak = (calm["linear"]["peak"] + diverging["linear"]["peak"]) / 2.0
    assert mean["linear"]["peak"] == pytest.approx(peak)


def test_plots_keep_the_range_of_the_other_curves(tmp_path):
    result = synthetic_run()
    x, good, bad = (result.vector(name)
                    for name in ("plant.x", "observer.x_hat", "luenberger.x_hat"))
    ax = new_figure(1, 1, (3, 2))[1][0, 0]
    drawn = in_view(ax, {"x": x[:, 0], "good": good[:, 0], "bad": bad[:, 0]}, {"bad"})
    lo, hi = min(x[:, 0].min(), good[:, 0].min()), max(x[:, 0].max(), good[:, 0].max())
    margin = 0.05 * (hi - lo)
    assert ax.get_ylim() == pytest.approx((lo - margin, hi + margin))
    cut = drawn["bad" + DIVERGED_LABEL]
    inside = (bad[:, 0] >= lo - margin) & (bad[:, 0] <= hi + margin)
    assert np.array_equal(cut[inside], bad[inside, 0]) and np.isnan(cut[~inside]).all()
    assert np.array_equal(drawn["good"], good[:, 0])
    for path in (plot_state_estimates(result, "plant.x", {n: e for n, (_, e) in ERRORS.items()},
                                      tmp_path / "states.png", "synthetic", {"linear"}),
                 plot_plant_errors(result, ERRORS, np.zeros((T.size, 1)), {}, 1.0,
                                   tmp_path / "errors.png", {"linear"})):
        assert path.stat().st_size > 1000
