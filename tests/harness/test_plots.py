"""The run plots as matplotlib figures (Agg): names and units on the axes, the plant's name in
the title, a colour per curve, legends beside the axes, a diverged curve clipped with a note,
points a log axis cannot show counted."""

import numpy as np
import pytest
from fhobs.design.signals import signal_names
from matplotlib.colors import to_hex

import harness.own_plant
import harness.plotting
from harness.master import CoSimResult
from harness.plotting import (
    plot_disturbance,
    plot_plant_errors,
    plot_state_estimates,
)
from harness.system import Evaluation, SystemSpec

T = np.linspace(0.0, 2.0, 201)
NAMES = signal_names({"states": ["inductor.i", "inertia.w"], "state_units": ["A", "rad/s"],
                      "unknown_inputs": ["M_load"], "unknown_input_units": ["N.m"]},
                     {"states": 2, "inputs": 1, "outputs": 1, "unknown_inputs": 1})
ESTIMATORS = ["homogeneous", "linear", "kalman", "supervised", "prescribed_time",
              *(f"extra{i}" for i in range(7))]  # 12 estimates, the five own colours first


@pytest.fixture
def figures(monkeypatch):
    """The figures the plot functions save, in order."""
    saved = []
    original = harness.plotting.save_figure

    def keep(fig, path, dpi):
        saved.append(fig)
        return original(fig, path, dpi)

    monkeypatch.setattr(harness.plotting, "save_figure", keep)
    return saved


def _run(estimators, diverged_value=None):
    """A run: x = (e^-t, cos t); estimator j's estimate off by (j + 1) 0.1 e^-3t; the
    linear one at ``diverged_value`` from t = 1 on if given."""
    x = np.column_stack([np.exp(-T), np.cos(T)])
    columns, names = [x], ["plant.x[1]", "plant.x[2]"]
    for j, label in enumerate(estimators):
        estimate = x + (j + 1) * 0.1 * np.exp(-3 * T)[:, None]
        if label == "linear" and diverged_value is not None:
            estimate = np.where(T[:, None] >= 1.0, diverged_value, estimate)
        columns.append(estimate)
        names += [f"{label}.x_hat[1]", f"{label}.x_hat[2]"]
    return CoSimResult(T, tuple(names), np.column_stack(columns), T.size - 1, 0.0)


def _legend_beside(fig, ax):
    fig.canvas.draw()  # Agg (matplotlib.figure.Figure's own canvas)
    legend = ax.get_legend()
    return legend is not None and legend.get_window_extent().x0 >= ax.get_window_extent().x1


def test_state_panels_carry_names_units_and_a_colour_per_curve(figures, tmp_path):
    result = _run(ESTIMATORS)
    labels = [NAMES.label("states", i) for i in range(2)]
    plot_state_estimates(result, "plant.x", {e: f"{e}.x_hat" for e in ESTIMATORS},
                         tmp_path / "states.png", "DC-Motor.SuT", names=labels)
    (fig,) = figures
    axes = fig.axes
    assert [ax.get_title(loc="left") for ax in axes] == ["inductor.i [A]", "inertia.w [rad/s]"]
    assert axes[0].get_title() == "DC-Motor.SuT"
    for ax in axes:
        colours = [to_hex(line.get_color()) for line in ax.get_lines()]
        assert len(colours) == 13 and len(set(colours)) == 13
    assert _legend_beside(fig, axes[0])


def test_a_diverged_curve_is_clipped_with_a_note(figures, tmp_path):
    result = _run(["homogeneous", "linear", "kalman"], diverged_value=1e32)
    errors = {e: ("plant.x", f"{e}.x_hat") for e in ("homogeneous", "linear", "kalman")}
    plot_plant_errors(result, errors, np.zeros((T.size, 1)), {}, 0.5, tmp_path / "errors.png",
                      {"linear"}, names=NAMES, title="DC-Motor.SuT")
    (fig,) = figures
    (ax,) = fig.axes
    others = [np.linalg.norm((j + 1) * 0.1 * np.exp(-3 * T)[:, None] * np.ones((1, 2)), axis=1)
              for j in (0, 2)]
    lo, hi = min(o.min() for o in others), max(o.max() for o in others)
    assert ax.get_ylim() == pytest.approx((lo / 10, hi * 10))
    notes = [text.get_text() for text in ax.texts]
    assert notes == ["linear diverged (max 1e+32), clipped"]
    assert ax.get_title().startswith("DC-Motor.SuT: ")
    assert ax.get_ylabel() == "||x - x_hat||"  # A and rad/s: no common unit
    assert _legend_beside(fig, ax)


def test_points_left_off_a_log_axis_are_counted(figures, tmp_path):
    result = _run(["homogeneous"])
    q = np.ones((T.size, 1))
    q_hat = q.copy()
    q_hat[T > 1.5] = 0.0  # error 1 from then on; exactly 0 before
    plot_plant_errors(result, {"homogeneous": ("plant.x", "homogeneous.x_hat")}, q,
                      {"homogeneous": q_hat}, 0.5, tmp_path / "errors.png",
                      names=NAMES)
    (fig,) = figures
    x_panel, q_panel = fig.axes
    zeros = int(np.count_nonzero(T <= 1.5))
    assert [text.get_text() for text in q_panel.texts] == [
        f"{zeros} points not drawn on the log axis (zero, negative or not finite)"]
    assert not x_panel.texts
    assert q_panel.get_ylabel() == "||q - q_hat|| [N.m]"


def test_disturbance_panels_and_the_plant_command_use_the_spec(figures, tmp_path):
    result = _run(["homogeneous", "kalman"])
    q = np.column_stack([np.where(T > 0.5, 0.3, 0.0)])
    q_hats = {"homogeneous": q * 0.9, "kalman": q * 1.1}
    plot_disturbance(T, q, q_hats, 0.5, tmp_path / "d.png",
                     names=[NAMES.label("unknown_inputs", 0)], title="DC-Motor.SuT")
    (fig,) = figures
    assert fig.axes[0].get_ylabel() == "M_load [N.m]"
    colours = [to_hex(line.get_color()) for line in fig.axes[0].get_lines()]
    assert len(set(colours)) == 3

    figures.clear()
    system = SystemSpec("own_plant", {}, (), 0.01, 2.0, evaluation=Evaluation(
        errors={e: ("plant.x", f"{e}.x_hat") for e in ("homogeneous", "kalman")}))
    harness.own_plant._plots(result, system, 0.5, 0, tmp_path, names=NAMES, title="DC-Motor.SuT")
    errors, states = figures
    assert errors.axes[0].get_title().startswith("DC-Motor.SuT: ")
    assert states.axes[0].get_title() == "DC-Motor.SuT"
    assert [ax.get_title(loc="left") for ax in states.axes] == ["inductor.i [A]",
                                                                 "inertia.w [rad/s]"]
    assert all("own_plant" not in fig.axes[0].get_title() for fig in figures)
