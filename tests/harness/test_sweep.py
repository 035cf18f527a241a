"""``python -m harness sweep``: sweep files, points, the dask engine (a LocalCluster, and a
scheduler and workers started as separate processes), a worker killed mid-sweep, resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
import pytest

from harness.cli import main
from harness.sweep import STATUS_FAILED, STATUS_OK, load_sweep, read_rows, run_sweep

ROOT = Path(__file__).resolve().parents[2]
PLANT = """\
A = [[0, 1], [0, -1]]
B = [[0], [1]]
C = [[1, 0]]
E = [[0], [1]]
[observer]
rho = 2.0
[noise]
measurement_std = [1e-3]
sample_time = 1e-3
process_intensity = 1e-2
"""
"""A small plant with a Kalman filter: designed in a fraction of a second."""
SWEEP = """\
base = "plant.toml"
fmus = "pythonfmu"
stop_time = {stop}
[evaluation]
at = [0.1]
windows = [[0.1, {stop}]]
[[grid]]
seed = {seeds}
"""


def write_sweep(folder: Path, seeds: list[int], stop: float = 0.2, extra: str = "") -> Path:
    """plant.toml and sweep.toml in ``folder``: one design, one point per seed."""
    (folder / "plant.toml").write_text(PLANT)
    path = folder / "sweep.toml"
    path.write_text(SWEEP.format(stop=stop, seeds=json.dumps(seeds)) + extra)
    return path


# -- sweep files ------------------------------------------------------------------------------
BAD_FILES = {
    "unknown axis": ('[grid]\nrhoo = [1.0]\n', "unknown axis 'rhoo'"),
    "empty grid": ("[grid]\n", "empty grid"),
    "empty axis": ("[grid]\nseed = []\n", "axis 'seed' is empty"),
    "no grid": ("", "nothing to sweep"),
    "bad TOML": ("[grid\nseed = [1]\n", "not valid TOML"),
    "unknown key": ("colour = 1\n[grid]\nseed = [1]\n", "unknown key 'colour'"),
    "bad distribution": ("[random]\nsamples = 2\n[random.axes]\nrho = {normal = [1, 2]}\n",
                         "must be one distribution"),
    "unknown FMU": ('[grid]\n"set.motor.x0" = [[1, 0]]\n', "no FMU 'motor'"),
    "bad spec value": ("[grid]\nrho = [-1.0]\n", "observer.rho = -1.0 must be > 0"),
    "bad step": ("step = 0.3\n[grid]\nseed = [0]\n", "does not divide"),
    "bad peak": ("[evaluation]\npeak = 1\n[grid]\nseed = [0]\n",
                 "peak = 1 must be true or false"),
    "bad floor": ("[evaluation]\nfloor = -1.0\n[grid]\nseed = [0]\n", "floor = -1.0 must be > 0"),
    "bad tolerance": ("[evaluation]\nconverged = [0]\n[grid]\nseed = [0]\n",
                      "converged = 0 must be > 0"),
    "errors in a sweep": ('[evaluation.errors]\nx = ["plant.x", "observer.x_hat"]\n[grid]\n'
                          'seed = [0]\n', "unknown key 'errors'"),
    "negative seed": ("[grid]\nseed = [0, -1]\n",
                      "point 1 (seed = -1): axis 'seed' = -1 must be a whole number from 0"),
    "fractional seed": ("[grid]\nseed = [1.5]\n", "axis 'seed' = 1.5 must be a whole number"),
    "x0 length": ('[grid]\n"set.plant.x0" = [[1, 0, 3]]\n',
                  "axis 'set.plant.x0' = [1, 0, 3]: plant.x0 takes 2 values, not 3 values"),
    "nested axis": ('[grid.set.plant.x0]\ny = [[1, 0]]\n',
                    "axis 'set.plant.x0.y' = [1, 0]: FMU 'plant' has no variable 'x0.y'"),
    "unknown variable": ('[grid]\n"set.plant.xq" = [1.0]\n', "FMU 'plant' has no variable 'xq'"),
    "huge grid": ("[grid]\n" + "".join(f"{axis} = {list(range(1, 1001))}\n"
                                       for axis in ("rho", "gamma", "nu")),
                  "grid has 1e+09 points, more than a sweep may have (at most 100000)"),
    "huge random": ("[random]\nsamples = 1000000000\n[random.axes]\nrho = {uniform = [1, 2]}\n",
                    "samples has 1e+09 points, more than a sweep may have"),
    "grid times random": ("[grid]\nrho = " + str(list(range(1, 1001))) + "\n[random]\n"
                          "samples = 1000\n[random.axes]\ngamma = {uniform = [1, 2]}\n",
                          "[grid] times [random] has 1e+06 points"),
    "too many seeds": (f"[grid]\nseed = {list(range(1001))}\n",
                       "axis 'seed' has 1001 values, more than a sweep may have (at most 1000)"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_sweep_files_are_one_paragraph_errors(case, tmp_path, capsys):
    """Each defect: exit status 2, one line on stderr naming the field, no traceback, no
    output folder."""
    text, expected = BAD_FILES[case]
    (tmp_path / "plant.toml").write_text(PLANT)
    path = tmp_path / "sweep.toml"
    path.write_text('base = "plant.toml"\nstop_time = 0.2\n' + text)
    code = main(["sweep", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2
    assert expected in err and str(path) in err, err
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_missing_files_and_options_are_errors(tmp_path, capsys):
    """A sweep file or a base that does not exist, and --workers 0: exit 2, one paragraph."""
    assert main(["sweep", str(tmp_path / "none.toml"), "--out", str(tmp_path)]) == 2
    assert "no such sweep file" in capsys.readouterr().err
    path = tmp_path / "sweep.toml"
    path.write_text('base = "missing/plant.toml"\n[grid]\nseed = [0]\n')
    assert main(["sweep", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "base 'missing/plant.toml': no such file" in err and err.count("\n") == 1
    assert main(["sweep", str(path), "--out", str(tmp_path), "--workers", "0"]) == 2
    assert "--workers = 0 must be >= 1" in capsys.readouterr().err
    many = 4 * (os.cpu_count() or 1) + 1
    assert main(["sweep", str(path), "--out", str(tmp_path), "--workers", str(many)]) == 2
    assert f"--workers = {many}: at most {many - 1} (4 per core" in capsys.readouterr().err
    for timeout in ("0", "nan", "1e6"):
        assert main(["sweep", str(path), "--out", str(tmp_path), "--connect-timeout",
                     timeout]) == 2
        assert "--connect-timeout" in capsys.readouterr().err
    assert main(["run", "pendulum_noisy", "--out", str(tmp_path), "--seeds", "1001"]) == 2
    assert "--seeds = 1001: at most 1000 seeds" in capsys.readouterr().err


def silent_server() -> tuple[int, object]:
    """A local TCP server that accepts connections and never answers: its port and socket."""
    import socket
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    held: list = []
    threading.Thread(target=lambda: held.extend(iter(server.accept, None)), daemon=True).start()
    return server.getsockname()[1], server


@pytest.mark.slow
def test_scheduler_that_never_answers_or_is_no_dask_address(tmp_path, capsys):
    """--scheduler: a server that accepts and says nothing is given up after
    --connect-timeout (1 s here, not the 300 s it hung before), an HTTP or TLS address at once:
    exit 2, one line naming the address, no traceback, no point run."""
    path = write_sweep(tmp_path, [0])
    port, server = silent_server()
    try:
        for address, expected, most in (
                (f"tcp://127.0.0.1:{port}", "no dask scheduler answered within 1 s", 8.0),
                (f"http://127.0.0.1:{port}", "not a dask scheduler's address", 2.0),
                (f"tls://127.0.0.1:{port}", "not a dask scheduler's address (TLS", 2.0)):
            started = time.perf_counter()
            code = main(["sweep", str(path), "--out", str(tmp_path / "out"), "--scheduler",
                         address, "--connect-timeout", "1", "--no-progress"])
            elapsed = time.perf_counter() - started
            err = capsys.readouterr().err
            assert code == 2 and elapsed < most, (address, elapsed)
            assert f"--scheduler {address}: {expected}" in err, err
            assert err.count("\n") == 1 and "Traceback" not in err
            assert not read_rows(tmp_path / "out" / "points")
    finally:
        server.close()


def test_points_beyond_their_evaluation_are_marked_as_run_marks_them(tmp_path):
    """A point whose stop_time ends the run before its [evaluation] is ok with a note (the
    words of `harness run --stop-time`) and no figure of those entries; the report has one
    line for it; the other point has figures and no note."""
    from harness.sweep import SweepReport, format_report, run_in_process

    path = write_sweep(tmp_path, [0])
    path.write_text(path.read_text().replace("stop_time = 0.2\n", "").replace(
        "[[grid]]\n", "[[grid]]\nstop_time = [0.05, 0.2]\n"))
    sweep = load_sweep(path)
    rows = run_in_process(sweep)
    short, full = sorted(rows, key=lambda r: r["stop_time"])
    assert short["status"] == full["status"] == STATUS_OK
    assert short["note"] == ("stop_time 0.05 ends the run before its [evaluation] at = 0.1, "
                             "window [0.1, 0.2]: no figures for them")
    assert not [k for k in short if k.endswith(("error_at_0_1", "_error_0_1_0_2"))]
    assert full["note"] == "" and [k for k in full if k.endswith("rms_error_0_1_0_2")]
    report = format_report(SweepReport(rows, 2, 0, 0, [], 1.0), sweep, tmp_path)
    assert f"  note: 1 point (first: point {short['point']}): {short['note']}" in report


def test_grid_and_random_points_are_reproducible(tmp_path):
    """Grids multiply, [[grid]] tables add up, random samples are drawn from the file's seed
    (the same file, the same points), within their bounds, combined with every grid point;
    keys are distinct and depend on the base's file."""
    extra = """
[random]
samples = 4
seed = 7
[random.axes]
rho = {uniform = [2.0, 4.0]}
settling_time = {loguniform = [0.5, 2.0]}
"""
    path = write_sweep(tmp_path, [0, 1], extra=extra)
    first, again = load_sweep(path), load_sweep(path)
    assert [p.params for p in first.points] == [p.params for p in again.points]
    assert len(first.points) == 8 and first.axes == ("rho", "seed", "settling_time")
    assert all(2.0 <= p.params["rho"] <= 4.0 for p in first.points)
    assert all(0.5 <= p.params["settling_time"] <= 2.0 for p in first.points)
    assert len({p.key for p in first.points}) == 8
    (tmp_path / "plant.toml").write_text(PLANT.replace("-1]]", "-2]]"))
    assert {p.key for p in load_sweep(path).points}.isdisjoint(p.key for p in first.points)
    union = tmp_path / "union.toml"
    union.write_text('base = "plant.toml"\n[[grid]]\nseed = [0, 1]\nrho = [1.0, 2.0]\n'
                     '[[grid]]\n"spec.noise.process_intensity" = [1e-3]\n')
    assert len(load_sweep(union).points) == 5


def test_bundled_sweep_is_the_main_jobs_noisy_seeds():
    """pendulum_noisy_seeds: the perturbed scenario once and the noisy one over the paper
    job's 5 seeds, native FMUs, with the Pareto picture."""
    sweep = load_sweep("pendulum_noisy_seeds")
    assert [p.params for p in sweep.points] == [{"base": "pendulum_perturbed"}] + [
        {"base": "pendulum_noisy", "seed": s} for s in range(5)]
    assert sweep.settings["fmus"] == "native" and sweep.pareto


# -- the engine -------------------------------------------------------------------------------
@pytest.mark.slow  # three LocalClusters, ~15 s; the sweep files and points stay in the fast tests
def test_local_cluster_runs_every_point_then_resumes(tmp_path):
    """Two worker processes run four points (one fails: a rho the design refuses, found only
    when designing; the sweep goes on); the table has one row per point in Parquet and CSV,
    with the figures per estimator; the seeds' spread is plotted, not a seed axis; a re-run
    computes nothing (the rows' finish times unchanged); a point whose row is removed is the
    only one run again."""
    path = write_sweep(tmp_path, [0, 1, 2], extra='[[grid]]\nrho = [1e13]\n')
    sweep = load_sweep(path)
    out = tmp_path / "out"
    report = run_sweep(sweep, out, workers=2, progress=False)
    assert (report.ran, report.skipped, report.failed) == (4, 0, 1), report.rows
    table = pq.read_table(out / "sweep.parquet").to_pylist()
    csv = pa_csv.read_csv(out / "sweep.csv").to_pylist()
    assert [(r["key"], r["status"]) for r in csv] == [(r["key"], r["status"]) for r in table]
    assert [r["point"] for r in table] == [0, 1, 2, 3]
    ok = [r for r in table if r["status"] == STATUS_OK]
    assert [r["seed"] for r in ok] == [0, 1, 2]
    for row in ok:
        for estimator in ("homogeneous", "linear", "kalman"):
            assert 0.0 < row[f"{estimator}.rms_error_0_1_0_2"] < 10.0
        assert row["steps"] == 200 and row["wall_time_s"] > 0.0
    assert ok[0]["homogeneous.rms_error_0_1_0_2"] != ok[1]["homogeneous.rms_error_0_1_0_2"]
    failed = table[3]
    assert failed["status"] == STATUS_FAILED and "observer.rho" in failed["reason"]
    assert sorted(p.name for p in (out / "plots").iterdir()) == ["spread.png"]

    before = read_rows(out / "points")
    again = run_sweep(sweep, out, workers=2, progress=False, plots=False)
    assert (again.ran, again.skipped) == (0, 4)
    assert read_rows(out / "points") == before

    lost = sweep.points[1].key
    (out / "points" / f"{lost}.json").unlink()
    third = run_sweep(sweep, out, workers=1, progress=False, plots=False)
    assert (third.ran, third.skipped) == (1, 3)
    after = read_rows(out / "points")
    assert {k: after[k] for k in before if k != lost} == {k: before[k] for k in before
                                                          if k != lost}
    assert after[lost]["finished_at"] > before[lost]["finished_at"]
    assert after[lost]["homogeneous.rms_error_0_1_0_2"] == \
        before[lost]["homogeneous.rms_error_0_1_0_2"]


@pytest.mark.slow
def test_scenario_base_with_native_fmus_step_and_start_value_axes(tmp_path):
    """The paper's nominal scenario, our pendulum design, native FMUs (built once for both
    steps: they take any step): the step and the plant's x(0) as axes; the figures follow
    the step (the homogeneous observer's error at 0.1 s is the same to 1e-3 relative) and
    x(0) (a smaller initial error, a smaller error)."""
    path = tmp_path / "nominal.toml"
    path.write_text('base = "pendulum_nominal"\nstop_time = 0.2\n[evaluation]\nat = [0.1]\n'
                    'windows = [[0.1, 0.2]]\n[grid]\nstep = [5e-5, 1e-4]\n'
                    '"set.plant.x0" = [[2, 2, 1, 2], [0.2, 0.2, 0.1, 0.2]]\n')
    report = run_sweep(load_sweep(path), tmp_path / "out", workers=1, progress=False)
    assert report.failed == 0, [r["reason"] for r in report.rows]
    rows = {(r["step"], r["set.plant.x0"][0]): r for r in report.rows}
    assert rows[(5e-5, 2)]["steps"] == 4000 and rows[(1e-4, 2)]["steps"] == 2000
    for x0 in (2, 0.2):
        fine, coarse = (rows[(dt, x0)]["homogeneous.max_error_0_1_0_2"] for dt in (5e-5, 1e-4))
        assert coarse == pytest.approx(fine, rel=1e-3, abs=1e-9)
    assert rows[(5e-5, 0.2)]["linear.error_at_0_1"] < rows[(5e-5, 2)]["linear.error_at_0_1"]
    assert len({r["pid"] for r in report.rows}) == 1
    assert {p.name for p in (tmp_path / "out" / "plots").glob("*.png")} == {
        "step.png", "set.plant.x0.png"}


def _start(args: list[str], log: Path) -> subprocess.Popen:
    """A dask process of this Python, its output in ``log``."""
    with log.open("w") as handle:
        return subprocess.Popen([sys.executable, "-m", *args], stdout=handle,
                                stderr=subprocess.STDOUT, cwd=ROOT)


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)


def _wait_for(condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.1)


@pytest.mark.slow
def test_scheduler_and_workers_as_processes_survive_a_killed_worker(tmp_path):
    """A scheduler and two workers started as separate processes on 127.0.0.1 (random ports);
    the sweep command given --scheduler. One worker is killed (SIGKILL) while it runs a point,
    after a first row is written: the sweep completes, every point ok, the rows finished
    before the kill are unchanged, and the points the killed worker was running were run
    again by the other."""
    from distributed import Client

    path = write_sweep(tmp_path, list(range(8)), stop=1.0)
    out = tmp_path / "out"
    scheduler_file = tmp_path / "scheduler.json"
    processes = []
    try:
        processes.append(_start(["distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                                 "--port", "0", "--no-dashboard", "--scheduler-file",
                                 str(scheduler_file)], tmp_path / "scheduler.log"))
        _wait_for(lambda: scheduler_file.exists() and "address" in scheduler_file.read_text(),
                  60, "the scheduler file")
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for i in range(2):
            processes.append(_start(
                ["distributed.cli.dask_worker", address, "--no-nanny", "--nthreads", "1",
                 "--host", "127.0.0.1", "--no-dashboard", "--name", f"w{i}",
                 "--local-directory", str(tmp_path / f"w{i}")], tmp_path / f"w{i}.log"))
        with Client(address, timeout="60s") as watcher:
            watcher.wait_for_workers(2, timeout=120)
            victim = processes[2]
            where = {pid: addr for addr, pid in watcher.run(os.getpid).items()}[victim.pid]
            sweep = subprocess.Popen(
                [sys.executable, "-m", "harness", "sweep", str(path), "--out", str(out),
                 "--scheduler", address, "--no-progress", "--no-plots"],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
            processes.append(sweep)
            points = out / "points"
            _wait_for(lambda: points.is_dir() and any(points.glob("*.json"))
                      and watcher.processing().get(where), 240, "a row and a busy worker")
            lost = {key.removeprefix("fhobs-sweep-") for key in watcher.processing()[where]}
            finished = read_rows(points)
            os.kill(victim.pid, signal.SIGKILL)
            killed_at = time.time()
        stdout, stderr = sweep.communicate(timeout=400)
        assert sweep.returncode == 0, stderr
        assert "8 points, 8 run now, 0 done before, 0 failed" in stdout
        final = read_rows(points)
        assert len(final) == 8 and all(r["status"] == STATUS_OK for r in final.values())
        assert {k: final[k] for k in finished} == finished
        assert all(r["finished_at"] < killed_at for r in final.values() if r["pid"] == victim.pid)
        rerun = [k for k in lost if final[k]["pid"] != victim.pid]
        assert rerun and all(final[k]["finished_at"] > killed_at for k in rerun)
        assert len(pq.read_table(out / "sweep.parquet")) == 8
    finally:
        for process in reversed(processes):
            _stop(process)


def test_docstring_examples():
    """The Examples sections of harness.sweep run and give what they print."""
    import doctest

    import harness.sweep

    result = doctest.testmod(harness.sweep, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0


def test_bundled_zoo_sweep_runs_every_zoo_plant_at_two_steps():
    """zoo: every bundled example plant (the zoo bench's; found in the installed examples by
    its relative name) at the communication steps 1e-4 and 1e-3, native FMUs."""
    from fhobs.paper import EXAMPLES

    from harness.zoo import zoo_spec_paths

    sweep = load_sweep("zoo")
    plants = sorted(path.relative_to(EXAMPLES).as_posix() for path in zoo_spec_paths().values())
    assert sorted({p.params["base"] for p in sweep.points}) == plants
    assert sorted((p.params["base"], p.params["step"]) for p in sweep.points) == sorted(
        (plant, step) for plant in plants for step in (1e-4, 1e-3))
    assert sweep.settings["fmus"] == "native"
    assert (sweep.settings["design"], sweep.settings["stop_time"]) == ("defaults", 10.0)
    assert sweep.settings["evaluation"] == {"converged": [1e-3], "peak": True, "floor": 1.0}


def test_defaults_design_takes_the_plant_alone():
    """design = "defaults": a point's spec is its file's plant (A, B, C, E, state_scale,
    settling_time) without L_lin, [noise] and the [observer] tuning, as the zoo designs it;
    the point's axes still apply on top."""
    import tomllib

    from fhobs.paper import EXAMPLES

    from harness.sweep import design_spec_data, make_job

    sweep = load_sweep("zoo")
    file = tomllib.loads((EXAMPLES / "pendulum.toml").read_text())
    assert {"L_lin", "noise"} <= set(file) and file["observer"]["rho"] == 6.0
    job = make_job(sweep.bases["pendulum.toml"], {"rho": 4.0}, sweep.settings)
    data = design_spec_data(job)
    assert not {"L_lin", "noise"} & set(data)
    assert data["observer"] == {"rho": 4.0}
    assert {k: data[k] for k in ("A", "B", "C", "E")} == {k: file[k] for k in ("A", "B", "C", "E")}


@pytest.mark.slow  # 4.5 s (a default design and a 10 s run); the figures' arithmetic stays in
# the fast subset (harness.results' doctests), the engine in the main job's seeds test
def test_zoo_figures_of_a_cosimulation_match_the_in_process_loop():
    """The sweep's time_to_1e-3, peak and floor of a zoo plant (quarter_car, step 1e-3, 10 s,
    native FMUs, in this process) against the zoo's in-process closed loop of the same design
    (harness.zoo.closed_loop, the numpy runtime and its kernel): the same time (one step),
    the same peak (1e-6 relative), both floors below the zoo's 1e-9; for the filtering and the
    Luenberger observers."""
    import dataclasses

    from fhobs.design.observer import design_for_spec

    from harness.sweep import run_in_process
    from harness.zoo import closed_loop, convergence_figures, load_zoo_spec, zoo_spec_paths

    sweep = load_sweep("zoo")
    points = [p for p in sweep.points
              if p.params == {"base": "zoo/quarter_car.toml", "step": 1e-3}]
    row, = run_in_process(dataclasses.replace(sweep, points=points))
    assert row["status"] == STATUS_OK, row["reason"]
    spec = load_zoo_spec(zoo_spec_paths()["quarter_car"])
    gains = design_for_spec(spec)
    loop = closed_loop(gains, 1e-3, 1e-3, 10.0, x0=spec.state_scale)
    for estimator, field in (("homogeneous", "z"), ("linear", "z_lin")):
        here = convergence_figures(loop, field)
        assert 0.5 < here["time_to_1e-3"] < 10.0, here
        assert abs(row[f"{estimator}.time_to_1e-3"] - here["time_to_1e-3"]) <= 1e-3 + 1e-12
        assert row[f"{estimator}.peak"] == pytest.approx(here["peak"], rel=1e-6)
        assert max(row[f"{estimator}.floor"], here["floor"]) <= 1e-9, (row, here)


# -- the Pareto picture's estimators ----------------------------------------------------------
def test_pareto_estimators_must_name_swept_axes(tmp_path):
    """[pareto.estimators]: each estimator's axes must be swept axes (base and seed are not
    design axes) given as a list; an error names the field."""
    from harness.sweep import SweepError

    (tmp_path / "plant.toml").write_text(PLANT)
    (tmp_path / "noisy.toml").write_text(PLANT)
    head = ('stop_time = 0.2\n[[grid]]\nbase = ["plant.toml"]\nrho = [1.0, 2.0]\n'
            '[[grid]]\nbase = ["noisy.toml"]\nseed = [0]\nrho = [1.0, 2.0]\n'
            '[pareto]\nperturbation = "plant.toml"\nnoisy = "noisy.toml"\n')
    path = tmp_path / "sweep.toml"
    for table, expected in (('kalman = ["gamma"]', "'gamma' is not a swept axis"),
                            ('kalman = ["seed"]', "'seed' is not a swept axis"),
                            ('kalman = "rho"', "must be a list of axis names")):
        path.write_text(head + "[pareto.estimators]\n" + table + "\n")
        with pytest.raises(SweepError, match=expected) as err:
            load_sweep(path)
        assert "pareto.estimators.kalman" in str(err.value)
    path.write_text(head + '[pareto.estimators]\nhomogeneous = ["rho"]\nlinear = []\n')
    assert load_sweep(path).pareto["estimators"] == {"homogeneous": ["rho"], "linear": []}


def pareto_rows() -> list[dict]:
    """Rows of a Kalman grid (two intensities) and of a homogeneous grid (two rho), each
    perturbed once and noisy over two seeds; every row has every estimator's figures."""
    rows = []
    designs = [{"spec.noise.process_intensity": w} for w in (1e-3, 1e-1)] + [
        {"rho": rho} for rho in (4.0, 6.0)]
    for i, design in enumerate(designs):
        for base, seed in (("pendulum_perturbed", None), ("pendulum_noisy", 0),
                           ("pendulum_noisy", 1)):
            row = {"base": base, "seed": seed, "rho": None,
                   "spec.noise.process_intensity": None, **design}
            for j, estimator in enumerate(("homogeneous", "kalman", "linear")):
                value = 10.0 * i + j + (seed or 0)  # the seed shifts the noisy RMS by 1
                row[f"{estimator}.max_error_1_3"] = value
                row[f"{estimator}.rms_error_1_3"] = value
            rows.append(row)
    return rows


def test_pareto_estimators_take_their_own_designs():
    """With [pareto.estimators] the Kalman filter's points are the Kalman grid's (labelled by
    the intensity), the homogeneous observer's the rho grid's, linear is not shown; the noisy
    figure is the mean over the seeds. Without it every estimator has a point per design."""
    import dataclasses

    from harness.sweep import pareto_points

    sweep = load_sweep("pendulum_noisy_seeds")
    sweep = dataclasses.replace(sweep, axes=("base", "rho", "seed",
                                             "spec.noise.process_intensity"))
    chosen = dataclasses.replace(sweep, pareto=sweep.pareto | {"estimators": {
        "kalman": ["spec.noise.process_intensity"], "homogeneous": ["rho"]}})
    points = pareto_points(pareto_rows(), chosen)
    assert sorted(points) == ["homogeneous", "kalman"]
    assert [(p.x, p.y, p.params) for p in points["kalman"]] == [
        (1.0, 1.5, {"spec.noise.process_intensity": 1e-3}),
        (11.0, 11.5, {"spec.noise.process_intensity": 1e-1})]
    assert points["kalman"][0].label == "spec.noise.process_intensity = 0.001"
    assert [(p.x, p.y, p.label) for p in points["homogeneous"]] == [
        (20.0, 20.5, "rho = 4.0"), (30.0, 30.5, "rho = 6.0")]
    every = pareto_points(pareto_rows(), sweep)
    assert sorted(every) == ["homogeneous", "kalman", "linear"]
    assert all(len(ps) == 4 for ps in every.values())
    assert [p.x for p in every["kalman"]] == [1.0, 11.0, 21.0, 31.0]


def test_bundled_noise_tradeoff_sweep_is_the_benchs_points():
    """noise_tradeoff: the Kalman filters of orders 0..3 over the 37 intensities 10^(j/2) and
    the bench's 25 homogeneous designs, each perturbed once and noisy over the seeds 0..4;
    the picture shows the Kalman filter and the homogeneous observer over their own axes."""
    import numpy as np

    sweep = load_sweep("noise_tradeoff")
    designs: dict[tuple, list] = {}
    for p in sweep.points:
        design = tuple(sorted((k, v) for k, v in p.params.items() if k not in ("base", "seed")))
        designs.setdefault(design, []).append((p.params["base"], p.params.get("seed")))
    runs = [("pendulum_perturbed", None)] + [("pendulum_noisy", s) for s in range(5)]
    assert all(sorted(v, key=str) == sorted(runs, key=str) for v in designs.values())
    kalman = [dict(d) for d in designs if "spec.noise.process_intensity" in dict(d)]
    homogeneous = [dict(d) for d in designs if "nu" in dict(d)]
    assert len(kalman) + len(homogeneous) == len(designs)
    swept = sorted((d["spec.noise.disturbance_order"], d["spec.noise.process_intensity"])
                   for d in kalman)
    expected = [(r, 10.0 ** (j / 2)) for r in range(4) for j in range(-12, 25)]
    assert [r for r, _ in swept] == [r for r, _ in expected]
    # the file's decimals against a power of ten that libm or a SIMD pow rounds its own way
    np.testing.assert_allclose([w for _, w in swept], [w for _, w in expected], rtol=1e-14)
    assert len(homogeneous) == 25 and all(len(d) == 5 for d in homogeneous)
    assert {"disturbance_order": 1, "nu": -0.25, "rho": 6.0, "gamma": 6.0,
            "filter_scale": 2.0} in homogeneous
    assert sweep.settings["fmus"] == "native" and set(sweep.pareto["estimators"]) == {
        "kalman", "homogeneous"}


# -- the main job's seeds ---------------------------------------------------------------------
@pytest.mark.slow  # the whole main job in a subprocess (5-8 s)
def test_main_jobs_seed_figures_are_the_sweeps_rows(tmp_path):
    """``python -m harness paper`` (our design) runs its noisy seeds on the sweep engine: each
    seed's figures in its summary.json equal, bit for bit, the row of that seed of the bundled
    sweep pendulum_noisy_seeds run here (its own design and native FMU build, in this
    process), and the summary's and the printed table's noisy figures are their means."""
    import dataclasses

    import numpy as np

    from harness.sweep import run_in_process

    job = subprocess.run([sys.executable, "-m", "harness", "paper", "--design", "spec",
                          "--no-plots", "--out", str(tmp_path / "job")],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert job.returncode == 0, job.stderr
    summary = json.loads((tmp_path / "job" / "ours" / "pendulum_noisy" / "summary.json")
                         .read_text())
    sweep = load_sweep("pendulum_noisy_seeds")
    noisy = [p for p in sweep.points if p.params["base"] == "pendulum_noisy"]
    rows = run_in_process(dataclasses.replace(sweep, points=noisy))
    assert [r["seed"] for r in rows] == summary["seeds"] == [0, 1, 2, 3, 4]
    for row, figures in zip(rows, summary["per_seed"], strict=True):
        for estimator in ("homogeneous", "linear", "kalman"):
            columns = {c.partition(".")[2]: v for c, v in row.items()
                       if c.startswith(f"{estimator}.")}
            assert figures[estimator] == columns, (row["seed"], estimator)
    for estimator in ("homogeneous", "linear", "kalman"):
        mean = np.mean([row[f"{estimator}.rms_error_1_3"] for row in rows])
        assert summary[estimator]["rms_error_1_3"] == pytest.approx(mean, rel=1e-15)
        line = next(line for line in job.stdout.splitlines()
                    if line.startswith("ours pendulum_noisy ") and f" {estimator} " in line)
        assert f"{mean:.3e}" in line, line
