"""The zoo of example plants: their specs with default tuning, a state feedback, the closed loop.

The zoo is the plants of ``examples/zoo/`` plus ``examples/pendulum.toml``,
``examples/mass_chain.toml`` and ``examples/triple_integrator.toml``, each used without its
``L_lin`` and without the tuning of its ``[observer]`` table (the design's defaults decide
everything; only the plant's own ``state_scale`` and ``settling_time`` are kept). The examples
are package data (``fhobs/examples/``, :data:`fhobs.paper.EXAMPLES`), so the zoo is there in an
installed package too. The closed loop is
:func:`harness.reference.simulate`, noise-free, from ``x(0) = state_scale`` with the observers at
zero and the LQR feedback ``u = K x`` on the true state, so that the observers' errors do not act
on the plant and unstable plants stay bounded.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np
from fhobs.core.gains import ObserverDesign
from fhobs.design.feedback import state_feedback
from fhobs.design.spec import PlantSpec, spec_from_dict
from fhobs.paper import EXAMPLES

from harness.reference import SimulationResult, simulate
from harness.results import settling_figures
from harness.system import Evaluation

ZOO_EXTRAS = ("pendulum", "mass_chain", "triple_integrator")
"""Plants of ``examples/`` (outside ``examples/zoo/``) that belong to the zoo."""
PLANT_KEYS = ("state_scale", "settling_time")
"""``[observer]`` keys that describe the plant and the request rather than tune the design."""
CONVERGED = 1e-3
"""Relative error at which the bench and the tests call the transient over."""
ZOO_EVALUATION = Evaluation(converged=(CONVERGED,), peak=True, floor=1.0)
"""The zoo's figures (``harness/sweeps/zoo.toml`` asks a sweep for the same)."""


def zoo_spec_paths(examples: Path = EXAMPLES) -> dict[str, Path]:
    """The zoo's spec files by plant name (the file's stem), sorted by name.

    Examples
    --------
    >>> sorted(zoo_spec_paths())[:2]
    ['aircraft_pitch', 'cart_pole']
    """
    paths = list((examples / "zoo").glob("*.toml"))
    paths += [examples / f"{name}.toml" for name in ZOO_EXTRAS]
    return {path.stem: path for path in sorted(paths, key=lambda p: p.stem)}


def default_spec_data(data: dict[str, Any]) -> dict[str, Any]:
    """A plant spec's parsed TOML without ``L_lin`` and ``[noise]``, and with only
    ``state_scale`` and ``settling_time`` of its ``[observer]`` table: the plant, designed
    with the design's defaults.

    Examples
    --------
    >>> default_spec_data({"A": [[0]], "L_lin": [[1]], "observer": {"rho": 2, "state_scale": 3}})
    {'A': [[0]], 'observer': {'state_scale': 3}}
    """
    kept = {k: v for k, v in data.get("observer", {}).items() if k in PLANT_KEYS}
    plant = {k: v for k, v in data.items() if k not in ("observer", "L_lin", "noise")}
    return plant | {"observer": kept}


def load_zoo_spec(path: Path) -> PlantSpec:
    """A zoo plant's spec with the design's defaults (:func:`default_spec_data`).

    Examples
    --------
    >>> load_zoo_spec(zoo_spec_paths()["pendulum"]).disturbance_order
    0
    """
    data = default_spec_data(tomllib.loads(Path(path).read_text()))
    return spec_from_dict(data, source=str(path))


def closed_loop(design: ObserverDesign, dt: float, h: float, t_end: float = 10.0,
                scheme: str = "split", x0: np.ndarray | None = None) -> SimulationResult:
    """The zoo's nominal closed loop: plant, filtering and Luenberger observers, ``u = K x``.

    Parameters
    ----------
    design : ObserverDesign
        A design of the plant.
    dt, h : float
        Communication step and the observers' internal step.
    t_end : float
        Final time.
    scheme : str
        The observers' scheme.
    x0 : numpy.ndarray, optional
        Initial state (the spec's ``state_scale``; ones if None).

    Returns
    -------
    SimulationResult
        Sampled at ``t_k = k dt``; :func:`convergence_figures` turns it into the figures.
    """
    plant = design.plant
    return simulate(design, "nominal", t_end=t_end, dt=dt, h=h, scheme=scheme,
                    K=state_feedback(plant.A, plant.B),
                    x0=np.ones(plant.n) if x0 is None else x0, feedback="state")


def convergence_figures(result: SimulationResult, estimate: str = "z") -> dict[str, float]:
    """The zoo's figures of one observer in a closed-loop run: those a sweep gives of a
    co-simulation (:func:`harness.results.settling_figures`).

    Returns
    -------
    dict
        ``time_to_1e-3``: the time from which the relative error ``|x - x_hat| / max_t |x|``
        stays <= :data:`CONVERGED` (inf if it ends above); ``peak`` =
        ``max |x - x_hat| / |x(0) - x_hat(0)|``; ``floor`` = max of the relative error over
        the last second.
    """
    error = np.linalg.norm(result.x - getattr(result, estimate), axis=1)
    scale = float(np.max(np.linalg.norm(result.x, axis=1)))
    return settling_figures(result.t, error, scale, ZOO_EVALUATION)
