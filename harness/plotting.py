"""PNG plots of a run.

- ``errors.png`` (any system with evaluation errors): ``||x - x_hat||`` of every named error
  signal on a log scale, the evaluation windows shaded.
- ``figure.png`` (systems with a ``[plots]`` figure, i.e. the paper's scenarios): the paper's
  Figures 1-3 as :func:`fhobs.plots.plot_errors` draws them for the in-process reference, from
  the co-simulated signals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.master import CoSimResult
from harness.results import error_norm
from harness.system import SystemSpec


def plot_results(result: CoSimResult, spec: SystemSpec, out: Path) -> list[Path]:
    """Write the plots of ``result`` into ``out`` and return their paths."""
    paths = [plot_error_norms(result, spec, out / "errors.png")] if spec.evaluation.errors else []
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
