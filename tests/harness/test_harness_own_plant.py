"""``python -m harness plant``: a user's own plant from its spec to FMUs, a run and plots."""

from __future__ import annotations

import json

import pytest
from fhobs.paper import EXAMPLES
from results_csv import BUILDS_RTOL, column_differences, read_results

from harness.cli import main


@pytest.mark.slow  # 4000 steps, ~2.6 s; test_disturbance_plant's step run is the fast `plant` run
def test_own_plant_converges_through_its_fmus(tmp_path, capsys):
    """The DC motor spec (defaults only): designed, built, run for 4 s through the FMUs; the
    homogeneous and prescribed-time observers' errors over the last half are at the noise-free
    floor, far below the error they started from (the plant starts at state_scale = ones, the
    observers at zero)."""
    code = main(["plant", str(EXAMPLES / "zoo" / "dc_motor.toml"), "--out", str(tmp_path),
                 "--stop-time", "4", "--no-plots"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "predicted settling time" in out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["steps"] == 4000 and summary["step"] == 1e-3
    assert summary["homogeneous"]["max_error_2_4"] <= 1e-9
    assert {"homogeneous", "linear"} <= set(summary)
    # transient [0, 2] (the requested settling time, >= the predicted one), steady [2, 4]
    assert summary["transient_end"] == 2.0
    assert summary["homogeneous"]["x_max_steady"] == summary["homogeneous"]["max_error_2_4"]
    assert summary["homogeneous"]["x_max_transient"] == summary["homogeneous"]["max_error_0_2"]
    assert "windows: transient [0, 2] s, steady [2, 4] s" in out
    assert sorted(p.name for p in (tmp_path / "fmus").glob("*.fmu")) == [
        "luenberger.fmu", "observer.fmu", "plant.fmu", "prescribed_time.fmu"]
    # the prescribed-time observer, T0 = the requested settling time (2 s): 1e-5 at T0 (from
    # 1.7; the sampled gain is capped), round-off within 0.1 s after it
    prescribed = summary["prescribed_time"]
    assert prescribed["max_error_2_4"] <= 1e-4 and prescribed["rms_error_2_4"] <= 1e-6


@pytest.mark.slow
def test_own_plant_with_noise_runs_the_kalman_filter_at_its_sample_time(tmp_path, capsys):
    """A spec with a [noise] table: kalman.fmu is built and run, the step is its sample time,
    the plant's measurement is noisy, and states.png shows the estimates."""
    code = main(["plant", str(EXAMPLES / "pendulum.toml"), "--out", str(tmp_path),
                 "--stop-time", "0.2"])
    out = capsys.readouterr().out
    assert code == 0, out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["step"] == 5e-5 and summary["seeds"] == [0]
    assert {"homogeneous", "linear", "kalman"} <= set(summary)
    assert "prescribed_time" not in summary  # noise-free runs only
    assert (tmp_path / "states.png").stat().st_size > 10_000


def test_bad_spec_is_one_paragraph(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("A = [[0, 1], [0, 0]]\nB = [[0], [1]]\nC = [[0, 1, 0]]\n")
    code = main(["plant", str(bad), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert err.startswith("error: ") and "C has 3 columns, expected 2" in err

@pytest.mark.slow

def test_csv_every_thins_the_csv_not_the_figures(tmp_path, capsys):
    """--csv-every 10 writes every 10th point (and the last) to results.csv; the summary's
    figures are the same as with every point."""
    spec = str(EXAMPLES / "zoo" / "dc_motor.toml")
    figures = {}
    for every in (1, 10):
        out = tmp_path / str(every)
        assert main(["plant", spec, "--out", str(out), "--stop-time", "1.005", "--step", "1e-3",
                     "--csv-every", str(every), "--no-plots"]) == 0
        rows = (out / "results.csv").read_text().splitlines()[1:]
        figures[every] = json.loads((out / "summary.json").read_text())["homogeneous"]
        times = [float(r.split(",")[0]) for r in rows]
        assert len(times) == (1006 if every == 1 else 102)
        assert times[-1] == pytest.approx(1.005) and times[1] == pytest.approx(every * 1e-3)
    capsys.readouterr()
    assert figures[1] == figures[10]
    assert main(["plant", spec, "--out", str(tmp_path / "bad"), "--csv-every", "0"]) == 2
    assert "--csv-every = 0 must be >= 1" in capsys.readouterr().err


def test_a_spec_beyond_the_design_limits_is_refused_before_any_design(tmp_path, capsys):
    """The same early limits as build_fmu.py (fhobs.design.limits): one paragraph, exit 2."""
    spec = tmp_path / "huge.toml"
    spec.write_text("A = [[0, 1], [0, 0]]\nB = [[0], [1]]\nC = [[1, 0]]\n"
                    "[observer]\nrho = 1e300\n")
    code = main(["plant", str(spec), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert "observer.rho = 1e+300 is beyond the design's range" in err
    assert not (tmp_path / "out" / "fmus").exists()


@pytest.mark.slow
def test_own_plant_with_native_fmus_gives_the_same_results(tmp_path, capsys):
    """``harness plant --native`` builds native FMUs for its step into fmus/native and runs
    them: the same results.csv as with the pythonfmu FMUs, every column to ``BUILDS_RTOL``
    of its largest magnitude."""
    spec = str(EXAMPLES / "zoo" / "dc_motor.toml")
    for folder, extra in (("python", []), ("native", ["--native"])):
        assert main(["plant", spec, "--out", str(tmp_path / folder), "--stop-time", "1",
                     "--no-plots", *extra]) == 0, capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "native" / "fmus" / "native").glob("*.fmu")) == [
        "luenberger.fmu", "observer.fmu", "plant.fmu", "prescribed_time.fmu"]
    python, native = (tmp_path / folder / "results.csv" for folder in ("python", "native"))
    assert "prescribed_time.x_hat[1]" in read_results(native)[0]
    assert column_differences(native, python).max() <= BUILDS_RTOL


def test_tune_noise_without_a_disturbance_table_is_one_paragraph(tmp_path, capsys):
    """``harness plant --tune-noise`` on a spec without ``[disturbance]``: exit 2, a message
    naming the option and what the spec lacks, no traceback, no results written."""
    spec = tmp_path / "di.toml"
    spec.write_text('A = [[0, 1], [0, 0]]\nB = [[0], [1]]\nC = [[1, 0]]\nE = [[0], [1]]\n'
                    '[noise]\nmeasurement_std = [1e-3]\nsample_time = 1e-2\n'
                    'process_intensity = 1.0\n')
    assert main(["plant", str(spec), "--out", str(tmp_path / "out"), "--tune-noise",
                 "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "--tune-noise needs" in err and "no [disturbance] table" in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "out" / "summary.json").exists()


@pytest.mark.slow
@pytest.mark.xdist_group("noise_tuning")  # one search of their spec, then the cache
def test_tune_noise_measures_what_the_tuning_predicted(tmp_path, capsys):
    """``harness plant --tune-noise``: the FMUs of the noise-tuned design, co-simulated with the
    spec's noise and disturbance, measure the noisy RMS the tuning predicted from its own
    simulation (other noise draws: within 10 %), for ours and the Kalman filter; summary.json
    keeps the prediction."""
    spec = tmp_path / "di.toml"
    spec.write_text('A = [[0, 1], [0, 0]]\nB = [[0], [1]]\nC = [[1, 0]]\nE = [[0], [1]]\n'
                    '[observer]\ndisturbance_order = 1\n'
                    '[noise]\nmeasurement_std = [1e-3]\nsample_time = 1e-2\n'
                    'process_intensity = 1.0\n'
                    '[disturbance]\nshape = "step"\nsize = 0.2\nstart = 0.5\n')
    assert main(["plant", str(spec), "--out", str(tmp_path / "out"), "--tune-noise",
                 "--no-plots"]) == 0
    assert "predicted over" in capsys.readouterr().out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    predicted = summary["predicted"]
    for label, key in (("homogeneous", "predicted_noisy_rms"),
                       ("kalman", "kalman_predicted_noisy_rms")):
        measured = summary[label]["x_rms_steady"]
        assert abs(measured / predicted[key] - 1.0) < 0.1, (label, measured, predicted[key])
