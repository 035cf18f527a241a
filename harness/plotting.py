"""PNG plots of a run: the estimation errors of the evaluation's error signals.

One figure per run, ``errors.png``: ``||x - x_hat||`` of every named error signal (for the
paper's scenarios the homogeneous and the linear observer, as in the paper's Figures 1-3) on a
log scale, with the evaluation windows shaded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.master import CoSimResult
from harness.results import error_norm
from harness.system import SystemSpec


def plot_results(result: CoSimResult, spec: SystemSpec, out: Path) -> list[Path]:
    """Write the plots of ``result`` into ``out`` and return their paths."""
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
    ax.set_xlabel("t [s]")
    ax.set_ylabel("estimation error")
    ax.set_title(spec.name)
    ax.legend(fontsize="small")
    ax.grid(True, which="both", alpha=0.3)
    path = out / "errors.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return [path]
