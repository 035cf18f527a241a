"""Noise against perturbation: the Pareto picture of the homogeneous designs and Kalman filters.

Usage::

    python bench/bench_noise_tradeoff.py [--out DIR] [--workers 2]

Runs the bundled sweep ``harness/sweeps/noise_tradeoff.toml`` (:func:`harness.sweep.run_sweep`
on a local cluster of ``--workers`` processes; ``python -m harness sweep noise_tradeoff`` runs
the same points): the paper's pendulum loop with our design of examples/pendulum.toml (u = K
x_hat of its homogeneous observer, K = (2, -35, 1.5, -3), x0 = (2, 2, 1, 2), estimators at 0,
dt = h = 5e-5, 3 s, matched perturbation 0.1 sin 5t), co-simulated with native FMUs, once
without noise and with the uniform noise 1e-3 of the seeds 0..4. The points that set the
``[noise]`` table are the Kalman filters (:mod:`fhobs.design.kalman`) of disturbance orders 0..3
over the process intensities 10^(j/2), j = -12..24, the default homogeneous design in the loop; the
points that set ``[observer]`` keys are the homogeneous designs
(:func:`fhobs.design.observer.design_for_spec`: the default and variants of disturbance_order, nu,
rho, gamma, filter_scale, among them the least noisy designs of each order found by a search over
these keys whose perturbed max stays below ``STRONG_PERTURBED``), each in the loop. Per
estimator (:func:`harness.sweep.pareto_points`): the noise-free max of norm(x - x_hat) over
[1, 3] s against the noisy RMS over [1, 3] s (mean of the seeds). A design whose LMI, certificate
or Riccati equation fails is a failed point of the sweep, reported with its reason.

The tables: per Kalman order the tuned intensity (the least noisy RMS over the seeds 0..4) and
the fastest (the least noisy point whose perturbed max is within ``FASTEST_TOLERANCE`` of the
order's smallest); the homogeneous designs; where each estimator wins, per disturbance-model
order r = 1..3: the tuned Kalman filter of order r against the least noisy homogeneous design
of order r among those with a perturbed max below ``STRONG_PERTURBED``, and whether any
homogeneous design of order r meets the accuracy targets (perturbed max <= ``PERTURBED_TARGET``
and a noisy RMS at most the tuned Kalman filter's of the same order).

The tuning on a separate seed (10) of the former in-process bench is not a sweep point: the
Pareto figures average every noisy point of a design, so a tuning seed would enter the mean.
The tuned intensity is therefore chosen on the evaluation seeds 0..4 themselves (the former
"best noisy (seeds 0-4)" row), an in-sample choice.

Writes the sweep's folder ``DIR`` (``points/``, ``sweep.parquet``, ``sweep.csv``, ``plots/``;
a re-run skips the points it has) and ``DIR/noise_tradeoff.png``, and prints the tables.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from harness.sweep import (
    STATUS_OK,
    ParetoPoint,
    load_sweep,
    make_job,
    pareto_points,
    point_design,
    run_sweep,
)

SWEEP = "noise_tradeoff"
KALMAN_ORDER, KALMAN_INTENSITY = "spec.noise.disturbance_order", "spec.noise.process_intensity"
FASTEST_TOLERANCE = 1.01
"""'fastest' Kalman point: the least noisy one whose perturbed max is within 1 % of the order's
smallest (the floor set by the transient's tail at t = 1, about 4.6e-4 here)."""
PERTURBED_TARGET = 1e-6
"""The accuracy target on the perturbed max of the pendulum's default design."""
STRONG_PERTURBED = 1e-5
"""A homogeneous design counts as keeping its strength against the perturbation below this
perturbed max (more than two decades below every Kalman filter of the sweep)."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results") / "bench" / SWEEP)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    sweep = load_sweep(SWEEP)
    report = run_sweep(sweep, args.out, workers=args.workers)
    points = pareto_points(report.rows, sweep)
    kalman, homogeneous = points.get("kalman", []), points.get("homogeneous", [])
    failed = [r for r in report.rows if r["status"] != STATUS_OK
              and r["base"] == sweep.pareto["perturbation"]]
    rho = certified_rho(sweep, homogeneous)
    default = sweep.bases[sweep.pareto["perturbation"]].spec_data["observer"]
    print(f"sweep {sweep.name}: {len(sweep.points)} points, {report.ran} run now, "
          f"{report.skipped} done before, {report.failed} failed, {report.elapsed_s:.0f} s")
    print()
    print(format_tables(kalman, homogeneous, failed, rho, default))
    print()
    print(format_wins(tuned_kalman(kalman), homogeneous))
    print(f"picture: {plot(kalman, homogeneous, args.out / 'noise_tradeoff.png')}")
    return 0


def certified_rho(sweep, homogeneous: list[ParetoPoint]) -> dict[str, float]:
    """The certified rho of each homogeneous design by label (designed here: a fraction of a
    second each; the sweep's rows hold figures only)."""
    base = sweep.bases[sweep.pareto["perturbation"]]
    return {p.label: float(point_design(make_job(base, p.params, sweep.settings))[1].filtering.rho)
            for p in homogeneous}


def label(params: dict) -> str:
    """'r=1 nu=-1/4 rho=6 gamma=6 fs=2' of a homogeneous design's axes."""
    nu = params["nu"]
    k = round(-1.0 / nu)
    nu_text = f"-1/{k}" if abs(nu + 1.0 / k) < 1e-12 else f"{nu:g}"
    return (f"r={params['disturbance_order']} nu={nu_text} rho={params['rho']:g} "
            f"gamma={params['gamma']:g} fs={params['filter_scale']:g}")


def by_order(kalman: list[ParetoPoint]) -> dict[int, list[ParetoPoint]]:
    """The Kalman points per disturbance order, by intensity."""
    out: dict[int, list[ParetoPoint]] = {}
    for p in sorted(kalman, key=lambda p: p.params[KALMAN_INTENSITY]):
        out.setdefault(int(p.params[KALMAN_ORDER]), []).append(p)
    return dict(sorted(out.items()))


def tuned_kalman(kalman: list[ParetoPoint]) -> dict[int, ParetoPoint]:
    """The tuned Kalman filter of each order: the least noisy RMS over the seeds."""
    return {order: min(ps, key=lambda p: p.y) for order, ps in by_order(kalman).items()}


def format_tables(kalman: list[ParetoPoint], homogeneous: list[ParetoPoint],
                  failed: list[dict], rho: dict[str, float], default: dict) -> str:
    """Kalman per order (tuned, fastest), then the homogeneous designs (failed ones with
    their reason; the spec's own ``default`` [observer] marked)."""
    lines = ["Kalman filters (intensity W of the white noise driving q^(r); default "
             "homogeneous design in the loop)",
             f"{'order':>5}  {'choice':<22} {'W':>8}  {'perturbed max':>13}  {'noisy RMS':>10}"]
    for order, ps in by_order(kalman).items():
        floor = min(p.x for p in ps)
        fastest = [p for p in ps if p.x <= FASTEST_TOLERANCE * floor]
        for name, p in (("tuned (seeds 0-4)", min(ps, key=lambda p: p.y)),
                        ("fastest", min(fastest, key=lambda p: p.y))):
            lines.append(f"{order:>5}  {name:<22} {p.params[KALMAN_INTENSITY]:8.1e}  "
                         f"{p.x:13.2e}  {p.y:10.2e}")
        lost = [r for r in failed if r.get(KALMAN_ORDER) == order]
        if lost:
            lines.append(f"{order:>5}  ({len(lost)} grid points failed: "
                         f"{lost[0]['reason'][:80]})")
    lines += ["", "Homogeneous designs (each in the loop)",
              f"{'design':<40} {'rho cert.':>9}  {'perturbed max':>13}  {'noisy RMS':>10}"]
    for p in homogeneous:
        name = label(p.params) + (" (default)" if all(default.get(k) == v for k, v in
                                                      p.params.items()) else "")
        lines.append(f"{name:<40} {rho[p.label]:9.3g}  {p.x:13.2e}  {p.y:10.2e}")
    for r in failed:
        if r.get("nu") is not None:
            lines.append(f"{label(r):<40} design failed: {r['reason'][:90]}")
    return "\n".join(lines)


def format_wins(tuned: dict[int, ParetoPoint], homogeneous: list[ParetoPoint]) -> str:
    """Where each estimator wins, per disturbance-model order 1..3 (module docstring)."""
    lines = ["Where each estimator wins (ratios: loser / winner)",
             f"{'r':>2}  {'Kalman: pert. max':>17} {'noisy RMS':>9}  "
             f"{'homogeneous (least noisy, pert. max < ' + f'{STRONG_PERTURBED:.0e})':<42} "
             f"{'pert. max':>9} {'noisy RMS':>9}  {'noise':<16} {'perturbation':<18} targets"]
    for order in (1, 2, 3):
        kf = tuned[order]
        mine = [h for h in homogeneous if h.params["disturbance_order"] == order]
        met = any(h.x <= PERTURBED_TARGET and h.y <= kf.y for h in mine)
        strong = [h for h in mine if h.x < STRONG_PERTURBED]
        if not strong:
            lines.append(f"{order:>2}  {kf.x:17.2e} {kf.y:9.2e}  {'(none)':<42}")
            continue
        h = min(strong, key=lambda p: p.y)
        lines.append(f"{order:>2}  {kf.x:17.2e} {kf.y:9.2e}  {label(h.params):<42} "
                     f"{h.x:9.2e} {h.y:9.2e}  {_winner(kf.y, h.y):<16} "
                     f"{_winner(kf.x, h.x):<18} {'met' if met else 'not met'}")
    return "\n".join(lines)


def _winner(kalman: float, homogeneous: float) -> str:
    """'Kalman x1.6' or 'homogeneous x540': the smaller figure wins."""
    name, ratio = (("Kalman", homogeneous / kalman) if kalman <= homogeneous
                   else ("homogeneous", kalman / homogeneous))
    return f"{name} x{ratio:.3g}" if ratio < 100 else f"{name} x{ratio:.0f}"


def plot(kalman: list[ParetoPoint], homogeneous: list[ParetoPoint], path: Path) -> Path:
    """The Pareto PNG: Kalman sweeps as lines (tuned points marked), homogeneous designs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 6.5), layout="constrained")
    colours = {}  # by disturbance order: a Kalman sweep and the homogeneous designs alike
    for order, ps in by_order(kalman).items():
        line, = ax.loglog([p.x for p in ps], [p.y for p in ps], ".-", lw=0.8, ms=4,
                          label=f"Kalman, order {order} (intensity sweep)")
        colours[order] = line.get_color()
        best = min(ps, key=lambda p: p.y)
        ax.loglog(best.x, best.y, "s", color=colours[order], ms=8, mfc="none")
        ax.hlines(best.y, 1e-9, best.x, color=colours[order], ls="--", lw=0.8)
    ax.axvline(PERTURBED_TARGET, color="grey", ls=":", lw=1)
    markers = "*PDXvo^<>hp"
    for order in sorted(colours):
        mine = [p for p in homogeneous if p.params["disturbance_order"] == order]
        for i, p in enumerate(mine):
            ax.loglog(p.x, p.y, markers[i % len(markers)], ms=9, color=colours[order], mec="k",
                      mew=0.5, label=f"homogeneous: {label(p.params)}")
    ax.set_xlim(1e-9, 1.0)
    ax.set_ylim(1e-3, 1.0)
    ax.set_xlabel("noise-free perturbed: max ||x - x_hat|| over [1, 3] s")
    ax.set_ylabel("noise 1e-3: RMS ||x - x_hat|| over [1, 3] s (seeds 0..4)")
    ax.set_title("Pendulum (FMU co-simulation): noise against perturbation. Colour: disturbance "
                 "order r; squares and dashed:\nthe least noisy Kalman filter of order r (the "
                 "noise target of order r); dotted: the perturbed target", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    fig.legend(fontsize=8, loc="outside right upper")
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


if __name__ == "__main__":
    raise SystemExit(main())
