"""Multi-output plants with an unknown input shared by the design and FMU tests."""

from __future__ import annotations

BALL_BEAM = {
    "A": [[0, 1, 0, 0], [0, 0, -7, 0], [0, 0, 0, 1], [0, 0, 0, 0]], "B": [[0], [0], [0], [1]],
    "C": [[1, 0, 0, 0], [0, 0, 1, 0]], "E": [[0], [1], [0], [0]],
}
"""The ball and beam measured in r and theta, q on the ball: noise through E never reaches the
beam (theta'' = u), a double integrator that the filter would leave uncorrected."""
BALL_BEAM_NOISE = {"measurement_std": [1e-3, 1e-3], "sample_time": 1e-3,
                   "process_intensity": 1e-2}
