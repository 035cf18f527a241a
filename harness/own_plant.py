"""The default scenario of a user's own plant: its FMUs in a closed loop the harness can run.

``python -m harness plant SPEC --out DIR`` designs the observer of a plant spec (the design's
defaults where the spec is silent), builds its FMUs into ``DIR/fmus`` (the prescribed-time
observer with T0 = the spec's settling time; it runs only without noise, which its unbounded
gain towards T0 would amplify up to the runtime's round-off limit) and runs
:func:`own_plant_system`: the plant starts at the spec's ``state_scale`` (an initial error of the
size the design was asked to remove in ``settling_time``), every observer at zero, the input is
a stabilising state feedback ``u = K x`` on the true state (LQR with Q = I, R = I; the
observers' errors do not act on the plant, and an unstable plant stays bounded), with the
spec's measurement noise when it has a ``[noise]`` table, for three settling times. The
figures are evaluated over the last half of the run.
"""

from __future__ import annotations

import numpy as np
from fhobs.core.gains import ObserverGains
from fhobs.scenarios_zoo import state_feedback

from harness.system import ConnectionSpec, Evaluation, FmuSpec, SystemSpec, expand_start

RUNS_PER_SETTLING_TIME = 3.0
"""The default stop time, in requested settling times."""
STEP = 1e-3
"""The default communication step (s)."""


def own_plant_system(gains: ObserverGains, fmus: dict[str, object], x0: np.ndarray,
                     stop_time: float, step: float = STEP,
                     noise_amplitude: float = 0.0) -> SystemSpec:
    """The default closed loop of a plant's FMUs (module docstring).

    Parameters
    ----------
    gains : ObserverGains
        The design the FMUs were built from.
    fmus : dict
        ``{kind: path}`` from :func:`fhobs.build.build_fmus` (``plant``, ``observer``,
        ``luenberger`` and, with a ``[noise]`` table, ``kalman``).
    x0 : numpy.ndarray
        The plant's initial state.
    stop_time, step : float
        Run length and communication step (s).
    noise_amplitude : float
        Uniform measurement noise of the plant FMU.

    Returns
    -------
    SystemSpec
        Runnable with :func:`harness.cli.run_scenario`.
    """
    K = state_feedback(gains.A, gains.B)
    plant_start = expand_start("x0", [float(v) for v in x0])
    plant_start["noise_amplitude"] = float(noise_amplitude)
    if gains.E is not None:
        plant_start |= expand_start("q", [0.0] * gains.E.shape[1])
    observers = {"observer": "homogeneous", "prescribed_time": "prescribed_time",
                 "luenberger": "linear", "kalman": "kalman"}
    if noise_amplitude > 0.0:  # its gain grows without bound towards T0: noise, amplified
        observers.pop("prescribed_time")
    present = {kind: label for kind, label in observers.items() if kind in fmus}
    specs = {"plant": FmuSpec("plant", fmus["plant"], plant_start)}
    specs |= {kind: FmuSpec(kind, fmus[kind]) for kind in present}
    connections = [ConnectionSpec("plant.x", "plant.u", K)]
    for kind in present:
        connections += [ConnectionSpec("plant.y", f"{kind}.y"),
                        ConnectionSpec("plant.x", f"{kind}.u", K)]
    return SystemSpec(
        name="own_plant", fmus=specs, connections=tuple(connections), step=step,
        stop_time=stop_time, seed="plant.noise_seed",
        record=("plant.x", *(f"{kind}.x_hat" for kind in present)),
        evaluation=Evaluation(
            windows=((stop_time / 2, stop_time),),
            errors={label: ("plant.x", f"{kind}.x_hat") for kind, label in present.items()},
        ),
    )
