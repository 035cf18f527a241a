"""The paper's numerical example as data: the one place the code reads its facts from.

The published plant, gains and simulation set-up live in the package data file
``examples/pendulum-paper.json`` (copied from the paper, rounded as printed). This module reads
it once and exposes the simulation set-up as arrays: the feedback ``u = K z`` (K_PAPER), the
plant's initial state (X0_PAPER), the step of the published runs (H_PAPER) and the three
scenarios (perturbation ``q = q_amplitude sin(q_frequency t)`` through E = B, uniform
measurement noise of half-width ``noise_amplitude``).

Examples
--------
>>> from fhobs.paper import K_PAPER, PAPER_SCENARIOS
>>> K_PAPER.tolist(), PAPER_SCENARIOS["perturbed_noisy"].noise_amplitude
([[2.0, -35.0, 1.5, -3.0]], 0.001)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

EXAMPLES = Path(__file__).resolve().with_name("examples")
"""The bundled examples (package data): the pendulum spec, the paper's numbers, the zoo."""
PAPER_REFERENCE = EXAMPLES / "pendulum-paper.json"
PENDULUM_SPEC = EXAMPLES / "pendulum.toml"


@dataclass(frozen=True)
class PaperScenario:
    """Perturbation ``q_amplitude sin(q_frequency t)`` through E and uniform noise of
    half-width ``noise_amplitude`` on each output."""

    q_amplitude: float
    q_frequency: float
    noise_amplitude: float


def published() -> dict[str, Any]:
    """The published numbers (the parsed JSON file ``PAPER_REFERENCE``).

    Examples
    --------
    >>> numbers = published()
    >>> sorted(numbers["design"])
    ['G_d', 'L', 'L0', 'L_tilde', 'gamma', 'nu', 'rho']
    >>> numbers["simulation"]["x0"]
    [2, 2, 1, 2]
    """
    return json.loads(PAPER_REFERENCE.read_text())


def _simulation() -> tuple[np.ndarray, np.ndarray, float, dict[str, PaperScenario]]:
    simulation = published()["simulation"]
    scenarios = {name: PaperScenario(float(s["q_amplitude"]), float(s["q_frequency"]),
                                     float(s["noise_amplitude"]))
                 for name, s in simulation["scenarios"].items()}
    return (np.array(simulation["K"], dtype=float), np.array(simulation["x0"], dtype=float),
            float(simulation["step"]), scenarios)


K_PAPER, X0_PAPER, H_PAPER, PAPER_SCENARIOS = _simulation()
