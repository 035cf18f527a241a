"""Command line of ``build_fmu.py``: plant spec -> design.json (-> FMUs)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .certificate import CertificateError
from .design import design_observer
from .kalman import KalmanDesignError, with_kalman
from .lmi import OBJECTIVES, LMIError
from .spec import SpecError, load_spec


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Parse the command line (see ``python build_fmu.py --help``)."""
    parser = argparse.ArgumentParser(
        prog="build_fmu.py",
        description="Design the filtering homogeneous observer for a plant spec (TOML) and "
        "write design.json and the FMUs (observer.fmu, luenberger.fmu, plant.fmu, and "
        "kalman.fmu when the spec has a [noise] table).",
    )
    parser.add_argument("spec", type=Path, help="plant spec TOML file (see examples/)")
    parser.add_argument("--out", type=Path, default=Path("build"), help="output folder")
    parser.add_argument(
        "--design-only", action="store_true", help="write design.json only, no FMUs"
    )
    parser.add_argument(
        "--objective", choices=OBJECTIVES, default=None,
        help="LMI objective (default: the spec's, else min_cond)",
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the command; return the process exit code (0 ok, 2 bad spec, 1 design failure)."""
    args = parse_args(argv)
    try:
        spec = load_spec(args.spec)
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    try:
        gains = design_observer(spec, objective=args.objective)
        if spec.noise is not None:
            gains = with_kalman(gains, spec.noise)
    except (LMIError, CertificateError, KalmanDesignError) as exc:
        print(f"error: design failed for {args.spec}: {exc}", file=sys.stderr)
        return 1
    elapsed = time.perf_counter() - start
    args.out.mkdir(parents=True, exist_ok=True)
    path = gains.save_json(args.out / "design.json")
    print(f"design: n={gains.n} k={gains.k} n_tilde={gains.n_tilde} in {elapsed:.2f} s -> {path}")
    if not args.design_only:
        from .build import build_fmus

        for name, fmu in build_fmus(gains, args.out).items():
            print(f"{name}: {fmu}")
    return 0
