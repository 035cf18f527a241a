"""The zoo bench: every example plant with the design's defaults, noise-free closed loop.

Usage::

    python bench/bench_zoo.py [--out DIR] [--workers N | --scheduler ADDRESS]

Runs the bundled sweep ``zoo`` (``harness/sweeps/zoo.toml``: every zoo plant of
:func:`harness.zoo.zoo_spec_paths` designed with the design's defaults, its FMUs co-simulated
in the closed loop of ``harness plant``: ``u = K x`` on the true state, x(0) = state_scale,
estimators at zero, no noise, 10 s, communication steps 1e-4 and 1e-3) with the code of
``python -m harness sweep zoo --out DIR``, and prints from its table (``DIR/sweep.parquet``) one
row per plant and step: the filtering observer's time from which the relative error
``|x - x_hat| / max_t |x|`` stays <= 1e-3, its peak ``max |x - x_hat| / |x(0) - x_hat(0)|``
and floor (the relative error's max over the last second), the prescribed-time observer's
time and floor and the Luenberger observer's floor. ``MISS`` marks a filtering observer's
floor > 1e-9 and a time > 5 s (the zoo's targets). The sweep's plots are in ``DIR/plots``.
``DIR`` (default: a new temporary folder) keeps the rows: run again on the same folder, the
bench prints them without running the points again.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

from harness.results import tolerance_key
from harness.zoo import CONVERGED

FLOOR_TARGET = 1e-9
TIME_TARGET = 5.0
TIME = f"time_to_{tolerance_key(CONVERGED)}"
"""The sweep's figure of the time to CONVERGED."""
HEAD = ("| plant | dt | t(1e-3) s | peak | floor | prescribed-time t(1e-3) s | "
        "prescribed-time floor | Luenberger floor |\n|---|---|---|---|---|---|---|---|")


def zoo_table(rows: list[dict[str, Any]]) -> str:
    """The bench's table of the sweep's rows, by plant and step.

    Examples
    --------
    >>> row = {"base": "zoo/maglev.toml", "step": 1e-3, "status": "ok",
    ...        "homogeneous.time_to_1e-3": 1.35, "homogeneous.peak": 225.0,
    ...        "homogeneous.floor": 0.0, "prescribed_time.time_to_1e-3": 1.9,
    ...        "prescribed_time.floor": 1e-12, "linear.floor": 3.7e-24}
    >>> print(zoo_table([row]).splitlines()[-1])
    | maglev | 0.001 | 1.35 | 225 | 0.0e+00 | 1.90 | 1.0e-12 | 3.7e-24 |
    """
    lines = [HEAD]
    for row in sorted(rows, key=lambda r: (Path(r["base"]).stem, r["step"])):
        head = f"| {Path(row['base']).stem} | {row['step']:g} |"
        if row["status"] != "ok":
            lines.append(f"{head} failed: {row['reason']} |")
            continue
        lines.append(
            f"{head} {_time(row['homogeneous.' + TIME], TIME_TARGET)} | "
            f"{row['homogeneous.peak']:.3g} | {_floor(row['homogeneous.floor'], FLOOR_TARGET)} | "
            f"{_time(row.get('prescribed_time.' + TIME))} | "
            f"{_floor(row.get('prescribed_time.floor'))} | {_floor(row['linear.floor'])} |")
    return "\n".join(lines)


def _time(t: float | None, target: float = math.inf) -> str:
    """A time to 1e-3, marked when above the target ("-" when the row lacks it)."""
    if t is None:
        return "-"
    text = "never" if math.isinf(t) else f"{t:.2f}"
    return text + (" MISS" if t > target else "")


def _floor(value: float | None, target: float = math.inf) -> str:
    """A noise-free floor, marked when above the target (NaN included)."""
    if value is None:
        return "-"
    return f"{value:.1e}" + ("" if value <= target else " MISS")


def main(argv: list[str] | None = None) -> int:
    """Run the sweep ``zoo`` and print its table; the sweep command's exit code."""
    import pyarrow.parquet as pq

    from harness.cli import main as harness

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None,
                        help="the sweep's folder (default: a new temporary folder)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="local worker processes")
    where.add_argument("--scheduler", default=None, help="a dask scheduler's address")
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_zoo_"))
    command = ["sweep", "zoo", "--out", str(out), "--no-progress"]
    command += [] if args.workers is None else ["--workers", str(args.workers)]
    command += [] if args.scheduler is None else ["--scheduler", args.scheduler]
    code = harness(command)
    if code != 0:
        return code
    print("noise-free closed loop u = K x, x(0) = state_scale, 10 s, native FMUs "
          "(the sweep zoo)")
    print(zoo_table(pq.read_table(out / "sweep.parquet").to_pylist()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
