"""The sweep engine's speed: points per second of the paper's nominal scenario on dask.

Usage::

    python bench/bench_sweep.py [--points 8] [--workers 1 2] [--stop-time 1.5] [--fmus native]

A sweep of ``--points`` points of the paper's nominal scenario (``pendulum_nominal``: our
design of examples/pendulum.toml, native FMUs, ``--stop-time`` simulated seconds; the points
differ by their noise seed only, which the noise-free scenario ignores, so every point is the
same work) runs through :func:`harness.sweep.run_sweep` on an embedded LocalCluster of each
``--workers`` count, into a fresh folder. Printed per worker count:

- the cluster's start and the whole sweep (s),
- points per second, over the whole sweep (with the one design and FMU build) and in steady
  state (the sum over the workers of the points after each one's first, per second; a
  worker's first point waits for the build or installs the FMUs' bytes),
- the engine's per-point overhead: the sweep's time times the workers, less the time the
  points spent in :func:`harness.sweep.run_point` and the build task in
  :func:`harness.sweep.build_bundle`, per point (scheduling, transfer of the point's data,
  the FMUs' bytes and the row, writing the row, and workers idle while the build runs or at
  the end; the cluster's start is apart).

The same point run in this process (:func:`harness.sweep.run_point`, warm caches) gives the
co-simulation's own time.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

from harness.sweep import dask_client, load_sweep, make_job, run_point, run_sweep

SWEEP = """\
# bench: the paper's nominal scenario, {points} points that differ by their (unused) seed
name = "bench_nominal"
base = "pendulum_nominal"
fmus = "{fmus}"
stop_time = {stop}
[grid]
seed = {seeds}
"""


def write_sweep(folder: Path, points: int, stop: float, fmus: str) -> Path:
    """The bench's sweep file in ``folder``."""
    path = folder / "bench_nominal.toml"
    path.write_text(SWEEP.format(points=points, fmus=fmus, stop=stop,
                                 seeds=list(range(points))))
    return path


def in_process(path: Path) -> tuple[float, float]:
    """One point in this process, twice: (first with design and build, second warm) wall s."""
    sweep = load_sweep(path)
    job = make_job(sweep.bases["pendulum_nominal"], sweep.points[0].params, sweep.settings)
    first = run_point(job)
    second = run_point(job)
    for row in (first, second):
        if row["status"] != "ok":
            raise RuntimeError(row["reason"])
    return first["wall_time_s"], second["wall_time_s"]


def on_cluster(path: Path, workers: int) -> dict[str, float]:
    """Start a LocalCluster (timed), then run the sweep on it; the figures of the docstring."""
    sweep = load_sweep(path)
    started = time.perf_counter()
    with dask_client(workers=workers) as client, tempfile.TemporaryDirectory() as out:
        client.wait_for_workers(workers)
        cluster_s = time.perf_counter() - started
        report = run_sweep(sweep, Path(out), progress=False, plots=False, client=client)
    rows = report.rows
    if any(r["status"] != "ok" for r in rows):
        raise RuntimeError(next(r["reason"] for r in rows if r["status"] != "ok"))
    by_worker: dict[int, list[dict]] = {}
    for row in sorted(rows, key=lambda r: r["finished_at"]):
        by_worker.setdefault(row["pid"], []).append(row)
    steady = [r for done in by_worker.values() for r in done[1:]]
    rate = sum((len(done) - 1) / (done[-1]["finished_at"] - done[0]["finished_at"])
               for done in by_worker.values() if len(done) > 1)
    builds = {r["build_s"] for r in rows}  # one design: one build task
    busy = sum(r["wall_time_s"] for r in rows) + sum(builds)
    return {
        "workers": workers, "cluster_s": cluster_s, "sweep_s": report.elapsed_s,
        "points_per_s": len(rows) / report.elapsed_s,
        "steady_points_per_s": rate if steady else float("nan"),
        "overhead_s": (report.elapsed_s * workers - busy) / len(rows),
        "point_s": statistics.median(r["wall_time_s"] for r in steady) if steady else
        float("nan"),
    }


def main(argv: list[str] | None = None) -> int:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=8)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--stop-time", type=float, default=1.5)
    parser.add_argument("--fmus", choices=("native", "pythonfmu"), default="native")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = write_sweep(Path(tmp), args.points, args.stop_time, args.fmus)
        cold, warm = in_process(path)
        print(f"pendulum_nominal, {args.fmus} FMUs, {args.stop_time:g} s simulated, "
              f"{args.points} points")
        print(f"in process: first point {cold:.2f} s (design + build + run), "
              f"then {warm:.2f} s per point")
        print("| workers | cluster start s | sweep s | points/s | steady points/s | "
              "steady point s | engine overhead s/point |")
        print("|---|---|---|---|---|---|---|")
        for workers in args.workers:
            r = on_cluster(path, workers)
            print(f"| {workers} | {r['cluster_s']:.1f} | {r['sweep_s']:.1f} | "
                  f"{r['points_per_s']:.3f} | {r['steady_points_per_s']:.3f} | "
                  f"{r['point_s']:.2f} | {r['overhead_s']:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
