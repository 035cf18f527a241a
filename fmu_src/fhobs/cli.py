"""Command line of ``build_fmu.py``: plant spec -> design.json (-> FMUs)."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from .core.gains import FilteringGains, ObserverDesign
from .core.runtime import DEFAULT_H
from .design.limits import check_design_limits
from .design.settling import HORIZON
from .design.spec import OBJECTIVES, load_spec
from .errors import CertificateError, KalmanDesignError, LMIError, SpecError


def program_name(default: str) -> str:
    """The name the usage line shows: the console script's (``fhobs-build``,
    ``fhobs-harness``) when run as one, else ``default``.

    Examples
    --------
    >>> program_name("build_fmu.py") in ("build_fmu.py", "fhobs-build", "fhobs-harness")
    True
    """
    name = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    return name if name.startswith("fhobs-") else default


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Parse the command line (see ``python build_fmu.py --help``)."""
    parser = argparse.ArgumentParser(
        prog=program_name("build_fmu.py"),
        description="Design the filtering homogeneous observer for a plant spec (TOML) and "
        "write design.json and the FMUs (observer.fmu, luenberger.fmu, prescribed_time.fmu, "
        "plant.fmu, and kalman.fmu when the spec has a [noise] table).",
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
    for name, what in OVERRIDES.items():
        parser.add_argument(f"--{name.replace('_', '-')}", type=float, default=None,
                            metavar="X", help=f"{what} (overrides the spec's [observer] {name})")
    parser.add_argument(
        "--tune-noise", action="store_true",
        help="among certified designs, choose the one with the least predicted error for the "
        "spec's [noise] and [disturbance] tables (needs both and E; the [observer] keys the "
        "spec sets are kept); prints the prediction beside the tuned Kalman filter's. Takes "
        "from about 20 s to a few minutes",
    )
    parser.add_argument(
        "--h", type=float, default=DEFAULT_H, metavar="X",
        help=f"the observer FMUs' internal step h, s (default {DEFAULT_H:g})",
    )
    parser.add_argument(
        "--no-kernel", action="store_true",
        help="do not compile the step kernel into the FMUs (they run the numpy runtime alone)",
    )
    parser.add_argument(
        "--native", action="store_true",
        help="also write OUT/native/ with native FMUs (compiled C, no Python needed to run them)",
    )
    parser.add_argument(
        "--native-step", type=float, action="append", default=None, metavar="DT",
        help="a communication step size to check at build time: the build fails if the "
        "observer cannot follow it (repeatable; the native FMUs take every step size either way)",
    )
    parser.add_argument(
        "--fmi", type=int, choices=(2, 3), default=2,
        help="FMI version of the native FMUs: 2 (default, into OUT/native/) or 3 (FMI 3.0 with "
        "array variables, into OUT/native-fmi3/)",
    )
    return parser.parse_args(argv)


OVERRIDES = {
    "settling_time": "requested settling time, s",
    "rho": "LMI decay rho",
    "gamma": "xi-equation gain gamma",
    "nu": "homogeneity degree nu",
}
"""The spec's [observer] keys that the command line can set."""


def design_summary(design: ObserverDesign) -> list[str]:
    """The achieved figures of a design, one line each, and a warning line where a requested
    figure is missed.

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> design_summary(paper_gains())[0].startswith("observer: nu = -0.333")
    True
    """
    filtering, model = design.filtering, design.model
    bar_L = np.vstack([filtering.L_tilde, filtering.L])
    lines = [
        f"observer: nu = {model.nu:.4g}, rho = {filtering.rho:.4g}, "
        f"gamma = {filtering.gamma:.4g}, n_tilde = {model.n_tilde}, "
        f"model states = {model.n_model}",
        f"gains: |[L_tilde; L]| = {np.linalg.norm(bar_L, 2):.3g}, |L0| = "
        f"{np.linalg.norm(model.L0, 2):.3g}; slowest linear mode "
        f"{slowest_mode(filtering):.3g} 1/s",
    ]
    tuning = design.settling_tuning
    if tuning:
        lines.append(
            f"predicted settling time (error to 1e-3 of its start, from errors of the size of "
            f"state_scale): {_settling_text(tuning)} (requested "
            f"{tuning['settling_time_requested']:.3g} s), peaking {tuning['peaking']:.3g}x"
        )
        if not tuning["met"]:
            lines.append(
                f"warning: the requested settling time is not met with a peaking of at most "
                f"{tuning['peaking_limit']:g}x (faster designs of this plant peak more, or "
                "are not certified): ask for a longer settling_time, give rho yourself, or "
                "accept the figures above"
            )
    if filtering.max_communication_step > 0.0:
        lines.append(f"communication step: at most {filtering.max_communication_step:.3g} s "
                     "(inputs held; the observer FMUs warn once at a longer step)")
    kalman = design.kalman
    if kalman is not None:
        lines.append(f"kalman filter: disturbance order {kalman.disturbance_order}, Ts = "
                     f"{kalman.sample_time:g} s; {kalman.tuning}")
    return lines


def _settling_text(tuning: dict) -> str:
    """The predicted settling time, or the horizon it was not reached within.

    Examples
    --------
    >>> _settling_text({"settling_time_predicted": 0.5, "settling_time_requested": 2.0})
    '0.5 s'
    >>> _settling_text({"settling_time_predicted": math.inf, "settling_time_requested": 2.0})
    "not within 6 s (the prediction's horizon)"
    """
    predicted = tuning["settling_time_predicted"]
    if math.isfinite(predicted):
        return f"{predicted:.3g} s"
    return (f"not within {HORIZON * tuning['settling_time_requested']:.3g} s (the prediction's "
            "horizon)")


def slowest_mode(filtering: FilteringGains) -> float:
    """max Re eig(bar_A0 + bar_L bar_C): the slowest mode of the observer's linear part at
    sigma = 1 (its error decays like exp(that rate * sigma^nu t) at a frozen level sigma)."""
    from .design.observer import augmented_system  # the design extra: imported when used

    bar_A0, _, bar_C = augmented_system(filtering.A0, filtering.model_matrices[2],
                                        filtering.model.G_d)
    bar_L = np.vstack([filtering.L_tilde, filtering.L])
    return float(np.max(np.linalg.eigvals(bar_A0 + bar_L @ bar_C).real))


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


def check_native_options(args: argparse.Namespace) -> None:
    """Raise SpecError naming the option when ``--native`` / ``--native-step`` cannot be used.

    Examples
    --------
    >>> check_native_options(parse_args(["spec.toml", "--native-step", "0"]))
    Traceback (most recent call last):
    ...
    fhobs.errors.SpecError: --native-step 0.0: a communication step size must be positive and finite
    """
    for dt in args.native_step or ():
        if not (math.isfinite(dt) and dt > 0.0):
            raise SpecError(f"--native-step {dt!r}: a communication step size must be positive "
                            "and finite")
    if args.native_step and not args.native:
        raise SpecError("--native-step is for the native FMUs: add --native")
    if args.fmi != 2 and not args.native:
        raise SpecError(f"--fmi {args.fmi} is for the native FMUs: add --native")
    if args.native and args.design_only:
        raise SpecError("--native builds FMUs: drop --design-only")


def main(argv: list[str] | None = None) -> int:
    """Run the command; return the process exit code (0 ok, 2 any failure).

    Every failure is one paragraph on stderr, never a traceback: a bad spec or override, a spec
    beyond the design's limits (:mod:`fhobs.design.limits`), an unusable ``--out`` or ``--h``
    (before any design work), and a design that fails (solver, certificate, or any numerical failure
    inside it).
    """
    args = parse_args(argv)
    try:
        overrides = {name: getattr(args, name) for name in OVERRIDES
                     if getattr(args, name) is not None}
        spec = load_spec(args.spec, overrides)
        check_design_limits(spec)
        check_output_folder(args.out)
        if not (math.isfinite(args.h) and args.h > 0.0):
            raise SpecError(f"--h = {args.h!r}: the internal step must be positive and finite")
        check_native_options(args)
        if args.tune_noise:
            from .design.tuning import check_noise_tables

            check_noise_tables(spec, "--tune-noise")
    except (SpecError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    try:
        from .design.observer import design_for_spec  # the design extra: imported when used
        from .design.tuning import design_for_noise_spec, poor_design_lines

        if args.tune_noise:
            tuned = design_for_noise_spec(spec)
            design, tuning_lines = tuned.design, tuned.summary()
        else:
            design, tuning_lines = design_for_spec(spec, args.objective), []
        tuning_lines += poor_design_lines(spec, design)
    except (LMIError, CertificateError, KalmanDesignError) as exc:
        print(f"error: design failed for {args.spec}: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - last resort: any failure inside the numerics
        print(
            f"error: design failed for {args.spec}: numerical failure inside the design "
            f"({type(exc).__name__}: {exc}); the spec passed every check, so this is a limit of "
            "the design not covered by fhobs.design.limits",
            file=sys.stderr,
        )
        return 2
    elapsed = time.perf_counter() - start
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        path = design.save_json(args.out / "design.json")
        print(f"design: n={design.plant.n} k={design.plant.k} n_tilde={design.model.n_tilde} "
              f"in {elapsed:.2f} s -> {path}")
        for line in design_summary(design) + tuning_lines:
            print(line)
        if not args.design_only:
            from .build import build_fmus

            kernel = False if args.no_kernel else None
            for name, fmu in build_fmus(design, args.out, h=args.h, kernel=kernel,
                                        names=spec.names, plant_name=spec.name).items():
                print(f"{name}: {fmu}")
        if args.native:
            from .build import BuildError
            from .native.build import build_native_fmus

            try:
                folder = args.out / ("native" if args.fmi == 2 else f"native-fmi{args.fmi}")
                native = build_native_fmus(design, folder, steps=args.native_step, h=args.h,
                                           names=spec.names, plant_name=spec.name,
                                           fmi_version=args.fmi)
            except BuildError as exc:
                print(f"error: native FMUs: {exc}", file=sys.stderr)
                return 2
            for name, fmu in native.items():
                print(f"native {name}: {fmu}")
    except OSError as exc:
        print(f"error: --out {args.out}: cannot write ({exc})", file=sys.stderr)
        return 2
    return 0
