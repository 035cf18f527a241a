"""Command line of ``build_fmu.py``: plant spec -> design.json (-> FMUs)."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from .certificate import CertificateError
from .design import design_observer
from .limits import check_design_limits
from .lmi import OBJECTIVES, LMIError
from .spec import SpecError, load_spec


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Parse the command line (see ``python build_fmu.py --help``)."""
    parser = argparse.ArgumentParser(
        prog="build_fmu.py",
        description="Design the filtering homogeneous observer for a plant spec (TOML) and "
        "write design.json and the FMUs (observer.fmu, luenberger.fmu, plant.fmu).",
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


def check_output_folder(path: Path) -> None:
    """Raise OSError saying why ``path`` cannot become the output folder; create nothing.

    Parameters
    ----------
    path : Path
        The ``--out`` folder (created later, with its parents, when the design succeeded).

    Raises
    ------
    NotADirectoryError
        If ``path`` names a file or lies under a file.
    PermissionError
        If the nearest existing folder of ``path`` is not writable.

    Examples
    --------
    >>> check_output_folder(Path("/dev/null"))
    Traceback (most recent call last):
    ...
    NotADirectoryError: --out /dev/null: exists and is not a folder
    """
    if path.exists() and not path.is_dir():
        raise NotADirectoryError(f"--out {path}: exists and is not a folder")
    existing = next(p for p in (path, *path.absolute().parents) if p.exists())
    if not existing.is_dir():
        raise NotADirectoryError(
            f"--out {path}: cannot be created under {existing}, which is a file"
        )
    if not os.access(existing, os.W_OK | os.X_OK):
        raise PermissionError(f"--out {path}: the folder {existing} is not writable")


def main(argv: list[str] | None = None) -> int:
    """Run the command; return the process exit code (0 ok, 2 bad spec, 1 design failure).

    Every failure is one paragraph on stderr, never a traceback: a bad spec, a spec beyond the
    design's limits (:mod:`fhobs.limits`) or an unusable ``--out`` exit with 2 before any
    design work; a design that fails (solver, certificate, or any numerical failure inside it)
    exits with 1.
    """
    args = parse_args(argv)
    try:
        spec = load_spec(args.spec)
        check_design_limits(spec)
        check_output_folder(args.out)
    except (SpecError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    try:
        gains = design_observer(spec, objective=args.objective)
    except (LMIError, CertificateError) as exc:
        print(f"error: design failed for {args.spec}: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - last resort: any failure inside the numerics
        print(
            f"error: design failed for {args.spec}: numerical failure inside the design "
            f"({type(exc).__name__}: {exc}); the spec passed every check, so this is a limit of "
            "the design not covered by fhobs.limits",
            file=sys.stderr,
        )
        return 1
    elapsed = time.perf_counter() - start
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        path = gains.save_json(args.out / "design.json")
        print(
            f"design: n={gains.n} k={gains.k} n_tilde={gains.n_tilde} in {elapsed:.2f} s -> {path}"
        )
        if not args.design_only:
            from .build import build_fmus

            for name, fmu in build_fmus(gains, args.out).items():
                print(f"{name}: {fmu}")
    except OSError as exc:
        print(f"error: --out {args.out}: cannot write ({exc})", file=sys.stderr)
        return 2
    return 0
