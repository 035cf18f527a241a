"""``harness plant`` with a ``[disturbance]`` table: q reaches the plant FMU, the observer with a
disturbance model estimates it, the figures separate the transient from the steady window."""

from __future__ import annotations

import contextlib
import io
import json
import math

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from fhobs.core.plant import noise_samples
from fhobs.design.spec import DISTURBANCE_SHAPES as SHAPES
from fhobs.design.spec import DisturbanceSpec
from fhobs.design.tuning import disturbance_samples

from harness.blocks import block_fmu
from harness.cli import main
from harness.master import run_system
from harness.system import ConnectionSpec, FmuSpec, SystemSpec, resolve_system

A = np.array([[0.0, 1.0, 0.0], [0.0, -10.0, 1.0], [0.0, -0.02, -2.0]])
B = np.array([[0.0], [0.0], [2.0]])
C = np.array([[1.0, 0.0, 0.0]])
E = np.array([[0.0], [-100.0], [0.0]])
PLANT = """A = [[0, 1, 0], [0, -10.0, 1.0], [0, -0.02, -2.0]]
B = [[0], [0], [2.0]]
C = [[1, 0, 0]]
"""
WITH_E = PLANT + "E = [[0], [-100.0], [0]]\n"
SPEC = WITH_E + """[observer]
settling_time = 1.0
disturbance_order = 1
[disturbance]
shape = "step"
size = 0.05
start = 0.2
"""
H, STOP, SETTLED = 1e-3, 2.0, 1.0


def lqr(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """K = -B^T X, X of the continuous ARE with Q = I, R = I (scipy)."""
    X = scipy.linalg.solve_continuous_are(A, B, np.eye(A.shape[0]), np.eye(B.shape[1]))
    return -B.T @ X


def read_csv(path) -> dict[str, np.ndarray]:
    data = np.genfromtxt(path, delimiter=",", names=True, deletechars="")
    return {name: data[name] for name in data.dtype.names}


@pytest.fixture(scope="module")
def step_run(tmp_path_factory):
    """One run of SPEC (stdout, summary, the CSV's columns, the output folder)."""
    folder = tmp_path_factory.mktemp("step")
    (folder / "spec.toml").write_text(SPEC)
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(["plant", str(folder / "spec.toml"), "--out", str(folder / "out"),
                     "--stop-time", str(STOP), "--no-plots"])
    assert code == 0, stdout.getvalue()
    summary = json.loads((folder / "out" / "summary.json").read_text())
    return stdout.getvalue(), summary, read_csv(folder / "out" / "results.csv"), folder / "out"


def test_step_reaches_the_plant_as_scipy_zoh_says(step_run):
    """The recorded q is the step; the plant's x is the ZOH closed loop with it (scipy's
    cont2discrete, u = K x with scipy's LQR); an undisturbed run of the same plant.fmu differs
    from it by scipy's ZOH response to q alone."""
    _, _, csv, out = step_run
    t = csv["time"]
    q = csv["disturbance.y[1]"]
    np.testing.assert_array_equal(q, np.where(t >= 0.2 - 1e-12, 0.05, 0.0))
    Ad, BEd, *_ = scipy.signal.cont2discrete((A, np.hstack([B, E]), C, np.zeros((1, 2))), H,
                                              method="zoh")
    Bd, Ed = BEd[:, :1], BEd[:, 1:]
    K = lqr(A, B)
    x = np.ones(3)
    x_hist, dx, dx_hist = [x], np.zeros(3), [np.zeros(3)]
    for k in range(t.size - 1):
        x = Ad @ x + Bd @ (K @ x) + Ed[:, 0] * q[k]
        dx = (Ad + Bd @ K) @ dx + Ed[:, 0] * q[k]
        x_hist.append(x)
        dx_hist.append(dx)
    recorded = np.column_stack([csv[f"plant.x[{i}]"] for i in (1, 2, 3)])
    assert np.max(np.abs(recorded - np.array(x_hist))) <= 1e-9 * np.max(np.abs(x_hist))
    system = SystemSpec(
        "undisturbed", {"plant": FmuSpec("plant", out / "fmus" / "plant.fmu",
                                         {"x0[1]": 1.0, "x0[2]": 1.0, "x0[3]": 1.0,
                                          "q[1]": 0.0})},
        (ConnectionSpec("plant.x", "plant.u", K),), H, STOP, record=("plant.x",))
    undisturbed = run_system(resolve_system(system), progress=False).vector("plant.x")
    difference = recorded - undisturbed
    assert np.max(np.abs(difference)) > 1e-3  # q moved the plant
    assert np.max(np.abs(difference - np.array(dx_hist))) <= 1e-9 * np.max(np.abs(dx_hist))


def test_observer_q_hat_converges_to_the_step(step_run):
    """disturbance_order = 1: the filtering and prescribed-time observers' q_hat reach the step
    by the settling time; the steady-window figures are those of the CSV's columns."""
    _, summary, csv, _ = step_run
    t = csv["time"]
    steady = t >= SETTLED - 1e-9
    for label, kind in (("homogeneous", "observer"), ("prescribed_time", "prescribed_time")):
        q_error = np.abs(csv[f"{kind}.q_hat[1]"] - csv["disturbance.y[1]"])
        figures = summary[label]
        assert figures["q_max_steady"] == pytest.approx(np.max(q_error[steady]), rel=1e-12)
        assert figures["q_rms_steady"] == pytest.approx(
            math.sqrt(np.mean(q_error[steady] ** 2)), rel=1e-12)
        assert figures["q_max_steady"] < 1e-3 * 0.05
        assert q_error[-1] < 1e-8 and figures["q_max_transient"] > 1e-2
        x_error = np.linalg.norm(np.column_stack(
            [csv[f"plant.x[{i}]"] - csv[f"{kind}.x_hat[{i}]"] for i in (1, 2, 3)]), axis=1)
        assert figures["x_max_transient"] == pytest.approx(np.max(x_error[t <= SETTLED + 1e-9]),
                                                           rel=1e-12)
        assert figures["x_max_steady"] == figures["max_error_1_2"]
    assert not any(k.startswith("q_") for k in summary["linear"])  # no disturbance model


def test_table_separates_transient_and_steady_windows(step_run):
    stdout, summary, _, _ = step_run
    header = next(line for line in stdout.splitlines() if line.startswith("estimator"))
    assert header.split() == ["estimator", "x_max_transient", "x_rms_transient", "x_max_steady",
                              "x_rms_steady", "q_max_transient", "q_rms_transient",
                              "q_max_steady", "q_rms_steady"]
    assert "windows: transient [0, 1] s, steady [1, 2] s" in stdout
    row = next(line for line in stdout.splitlines() if line.startswith("linear")).split()
    assert row[5:] == ["-"] * 4
    assert summary["transient_end"] == SETTLED
    assert summary["disturbance"] == {"shape": "step", "size": [0.05], "start": 0.2,
                                      "frequency": None, "seed": 0}


def test_signal_block_shapes_follow_their_definitions():
    """The signal block alone (two channels, start 0.25, h = 0.05): ramp, sine and the seeded
    random walk against their formulas (the walk's increments the Box-Muller Gaussians of the
    product's noise generator, fhobs.core.plant.noise_samples of the seed)."""
    h, stop, start = 0.05, 0.6, 0.25
    fmu = block_fmu("signal", (2,))
    t = h * np.arange(round(stop / h) + 1)
    on = t >= start - 1e-12
    size = np.array([1.0, -0.5])
    draws = noise_samples(4, t.size, 1.0, 4)
    w = np.sqrt(-2.0 * np.log(0.5 * (1.0 - draws[:, :2]))) * np.cos(np.pi * draws[:, 2:])
    walk = np.zeros((t.size, 2))
    for k in range(t.size - 1):
        walk[k + 1] = walk[k] + (size * math.sqrt(h) * w[int(np.sum(on[:k]))] if on[k] else 0.0)
    expected = {1: size * np.maximum(t - start, 0.0)[:, None],
                2: size * (on * np.sin(2 * np.pi * 2.0 * (t - start)))[:, None],
                3: walk}
    for shape, extra in ((1, {}), (2, {"frequency": 2.0}), (3, {"seed": 4})):
        start_values = {"shape": shape, "size[1]": 1.0, "size[2]": -0.5, "start": start, **extra}
        system = SystemSpec("signal", {"q": FmuSpec("q", fmu, start_values)}, (), h, stop,
                            record=("q.y",))
        result = run_system(resolve_system(system), progress=False)
        np.testing.assert_allclose(result.vector("q.y"), expected[shape], rtol=0, atol=1e-12)
        predicted = disturbance_samples(  # the design's replay of the block (noise tuning)
            DisturbanceSpec(SHAPES[shape], size, start, extra.get("frequency"),
                            extra.get("seed", 0)), 2, h, t.size)
        np.testing.assert_allclose(predicted, expected[shape], rtol=0, atol=1e-12)


BAD_TABLES = [
    (WITH_E + "[disturbance]\nsize = 1.0\n", "disturbance.shape is missing"),
    (WITH_E + "[disturbance]\nshape = 'square'\nsize = 1.0\n",
     "disturbance.shape = 'square' is not one of step, ramp, sine, random_walk"),
    (WITH_E + "[disturbance]\nshape = 'step'\n", "disturbance.size is missing"),
    (WITH_E + "[disturbance]\nshape = 'step'\nsize = [1, 2]\n",
     "disturbance.size has 2 entries, expected 1 or 1"),
    (WITH_E + "[disturbance]\nshape = 'step'\nsize = 'big'\n",
     "disturbance.size = 'big' is not a number"),
    (WITH_E + "[disturbance]\nshape = 'sine'\nsize = 1.0\n", "disturbance.frequency is missing"),
    (WITH_E + "[disturbance]\nshape = 'sine'\nsize = 1.0\nfrequency = 0\n",
     "disturbance.frequency = 0 must be > 0"),
    (WITH_E + "[disturbance]\nshape = 'step'\nsize = 1.0\nfrequency = 2\n",
     "disturbance.frequency applies to shape = 'sine' only"),
    (WITH_E + "[disturbance]\nshape = 'ramp'\nsize = 1.0\nseed = 2\n",
     "disturbance.seed applies to shape = 'random_walk' only"),
    (WITH_E + "[disturbance]\nshape = 'random_walk'\nsize = 1.0\nseed = -1\n",
     "disturbance.seed = -1 must be an integer >= 0"),
    (WITH_E + "[disturbance]\nshape = 'random_walk'\nsize = -1.0\n",
     "disturbance.size = -1.0 must be >= 0"),
    (WITH_E + "[disturbance]\nshape = 'step'\nsize = 1.0\nstart = -1\n",
     "disturbance.start = -1 must be >= 0"),
    (WITH_E + "[disturbance]\nshape = 'step'\nsize = 1.0\namplitude = 1\n",
     "unknown key disturbance.amplitude"),
    (WITH_E + "disturbance = 3\n", "disturbance must be a table"),
    (PLANT + "[disturbance]\nshape = 'step'\nsize = 1.0\n", "the [disturbance] table needs E"),
]


@pytest.mark.parametrize(("text", "message"), BAD_TABLES)
def test_bad_disturbance_table_is_one_paragraph_exit_2(tmp_path, capsys, text, message):
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    code = main(["plant", str(spec), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and err.count("\n") == 1
    assert err.startswith("error: ") and message in err, err
    assert not (tmp_path / "out" / "fmus").exists()


@pytest.mark.slow
def test_kalman_filter_with_a_disturbance_model_reports_q_hat(tmp_path, capsys):
    """A [noise] table with disturbance_order 1: kalman.fmu's q_hat is in the table; over the
    steady window its q error is a few % of the step (measurement noise 1e-5 on x[1]: a
    steady-state filter of process intensity 1e-2 converges slower than the homogeneous
    observer) and its mean over the last half second is the step's height within 2 %."""
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC + "[noise]\nmeasurement_std = [1e-5]\nsample_time = 1e-3\n"
                           "process_intensity = 1e-2\n")
    code = main(["plant", str(spec), "--out", str(tmp_path / "out"), "--stop-time", str(STOP),
                 "--no-plots"])
    out = capsys.readouterr().out
    assert code == 0, out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["seeds"] == [0] and "prescribed_time" not in summary
    assert summary["homogeneous"]["q_rms_steady"] < 0.05 * 0.05
    assert summary["kalman"]["q_rms_steady"] < 0.1 * 0.05
    csv = read_csv(tmp_path / "out" / "results.csv")
    last = csv["time"] >= STOP - 0.5
    assert np.mean(csv["kalman.q_hat[1]"][last]) == pytest.approx(0.05, rel=0.02)
    row = next(line for line in out.splitlines() if line.startswith("kalman")).split()
    assert "-" not in row
