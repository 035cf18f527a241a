"""PNG plots of a run.

- ``errors.png`` (any system with evaluation errors): ``||x - x_hat||`` of every named error
  signal on a log scale, the evaluation windows shaded.
- ``figure.png`` (systems with a ``[plots]`` figure, i.e. the paper's scenarios): the paper's
  Figures 1-3 as :func:`fhobs.plots.plot_errors` draws them for the in-process reference, from
  the co-simulated signals.
- ``states.png`` (systems whose error signals all compare with one reference, e.g. ``plant.x``):
  each component of the reference and of every estimate over time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.master import CoSimResult
from harness.results import error_norm
from harness.system import SystemSpec


def plot_results(result: CoSimResult, spec: SystemSpec, out: Path) -> list[Path]:
    """Write the plots of ``result`` into ``out`` and return their paths."""
    errors = spec.evaluation.errors
    paths = [plot_error_norms(result, spec, out / "errors.png")] if errors else []
    references = {reference for reference, _ in errors.values()}
    if len(references) == 1:
        estimates = {name: estimate for name, (_, estimate) in errors.items()}
        paths.append(plot_state_estimates(result, references.pop(), estimates,
                                          out / "states.png"))
    if spec.figure is not None:
        paths.append(plot_paper_figure(result, spec, out / "figure.png"))
    return paths


def plot_paper_figure(result: CoSimResult, spec: SystemSpec, path: Path) -> Path:
    """The paper-style figure of fhobs.plots from the co-simulated signals."""
    from fhobs.plots import plot_errors
    from fhobs.reference import SimulationResult

    fields = {}
    for name, signal in spec.figure.signals.items():
        columns = result.vector(signal)
        fields[name] = columns[:, 0] if name in ("xi", "sigma") else columns
    return plot_errors(SimulationResult(t=result.time, **fields), spec.figure.scenario, path)


def plot_error_norms(result: CoSimResult, spec: SystemSpec, path: Path) -> Path:
    """``errors.png``: the norms of the evaluation's error signals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), layout="constrained")
    for name, (reference, estimate) in spec.evaluation.errors.items():
        e = error_norm(result, reference, estimate)
        ax.semilogy(
            result.time, np.maximum(e, 1e-16), label=f"{name}: ||{reference} - {estimate}||"
        )
    for a, b in spec.evaluation.windows:
        ax.axvspan(a, b, color="0.9", zorder=0)
    ax.set_xlim(result.time[0], result.time[-1])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("estimation error")
    ax.set_title(spec.name)
    ax.legend(fontsize="small")
    ax.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_state_estimates(result: CoSimResult, state: str, estimates: dict[str, str],
                         path: Path) -> Path:
    """``states.png``: one panel per component of ``state`` with the same component of every
    estimate (``{label: signal}``) over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = result.vector(state)
    n = x.shape[1]
    columns = {label: result.vector(signal) for label, signal in estimates.items()}
    fig, axes = plt.subplots(n, 1, figsize=(7, 1.6 * n + 0.6), sharex=True,
                             layout="constrained", squeeze=False)
    for i, ax in enumerate(axes[:, 0]):
        ax.plot(result.time, x[:, i], color="k", lw=2, label=state)
        for label, estimate in columns.items():
            ax.plot(result.time, estimate[:, i], lw=1, label=label)
        ax.set_ylabel(f"x[{i + 1}]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize="small", ncol=len(estimates) + 1)
    axes[-1, 0].set_xlabel("t [s]")
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
