"""In-process reference simulation of the paper's closed loop (the ground truth for co-simulation).

Plant + filtering homogeneous observer + Luenberger observer, control ``u = K z`` with z the
filtering observer's estimate, ``x(0) = (2, 2, 1, 2)``, observers at zero. Jacobi convention of
docs/architecture.md: fixed communication step dt, ``t_k = k dt``; at t_k
``y_k = C x_k + eta_k``, ``u_k = K z_k``, ``q_k = q_amplitude sin(5 t_k)``; then the plant and both
observers advance by dt with these inputs held. Other plants (the zoo of ``examples/``) run the
same loop with their own ``K`` and ``x0``, optionally with the feedback on the true state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fhobs.gains import ObserverGains
from fhobs.plant import LTIPlant
from fhobs.runtime import SCHEMES, FilteringObserver, LuenbergerObserver

K_PAPER = np.array([[2.0, -35.0, 1.5, -3.0]])
X0_PAPER = np.array([2.0, 2.0, 1.0, 2.0])
H_PAPER = 5e-5
Q_FREQUENCY = 5.0
FEEDBACKS = ("estimate", "state")


@dataclass(frozen=True)
class Scenario:
    """Perturbation ``q_amplitude sin(5 t)`` through E and uniform noise ``noise_amplitude``."""

    q_amplitude: float
    noise_amplitude: float


SCENARIOS = {
    "nominal": Scenario(0.0, 0.0),
    "perturbed": Scenario(0.1, 0.0),
    "perturbed_noisy": Scenario(0.1, 1e-3),
}


@dataclass(frozen=True)
class SimulationResult:
    """Trajectories at ``t_k = k dt`` (rows), k = 0 .. N.

    Attributes
    ----------
    t, x, z, z_lin, psi, xi, sigma : np.ndarray
        Time, plant state, filtering estimate, Luenberger estimate, filter state, xi, sigma.
    q_hat : np.ndarray
        The filtering observer's disturbance-model states (no columns without a disturbance
        model): estimates of q, dq/dt, ...; None when not recorded (co-simulation plots).
    """

    t: np.ndarray
    x: np.ndarray
    z: np.ndarray
    z_lin: np.ndarray
    psi: np.ndarray
    xi: np.ndarray
    sigma: np.ndarray
    q_hat: np.ndarray | None = None

    @property
    def error(self) -> np.ndarray:
        """``norm(x - z)`` of the filtering observer at each t_k."""
        return np.linalg.norm(self.x - self.z, axis=1)

    @property
    def error_lin(self) -> np.ndarray:
        """``norm(x - z_lin)`` of the Luenberger observer at each t_k."""
        return np.linalg.norm(self.x - self.z_lin, axis=1)

    def at(self, t: float) -> int:
        """Index of the sample nearest to t."""
        return int(np.argmin(np.abs(self.t - t)))

    def window(self, t0: float, t1: float) -> np.ndarray:
        """Boolean mask of the samples with t0 <= t <= t1."""
        tol = 1e-9 * max(1.0, abs(t1))
        return (self.t >= t0 - tol) & (self.t <= t1 + tol)


def simulate(
    gains: ObserverGains,
    scenario: str = "nominal",
    t_end: float = 3.0,
    dt: float = H_PAPER,
    h: float | None = None,
    scheme: str = SCHEMES[0],
    seed: int = 0,
    plant_scheme: str = "zoh",
    tau_max: float | None = None,
    K: np.ndarray = K_PAPER,
    x0: np.ndarray = X0_PAPER,
    feedback: str = "estimate",
) -> SimulationResult:
    """Run the paper's closed loop (or another plant's, with ``K`` and ``x0``) under the Jacobi
    convention.

    Parameters
    ----------
    gains : ObserverGains
        Observer design (E is used for the perturbation; B if E is None).
    scenario : str
        Key of ``SCENARIOS``.
    t_end : float
        Final time; ``N = round(t_end / dt)`` communication steps.
    dt : float
        Communication step.
    h : float or None
        Observers' internal step (dt if None).
    scheme : str
        Observers' scheme (both observers).
    seed : int
        Noise seed.
    plant_scheme : str
        ``"zoh"`` (exact, the contract) or ``"euler"`` (the paper's all-Euler runs).
    tau_max : float or None
        Gain cap of the filtering observer's split scheme (None: automatic).
    K : np.ndarray
        State feedback gain (m x n), ``u_k = K v_k``.
    x0 : np.ndarray
        Plant's initial state (the observers start at zero).
    feedback : str
        ``"estimate"`` (v = z, the paper's loop) or ``"state"`` (v = x, the true state: the
        observer's error then does not act on the plant).
    """
    if feedback not in FEEDBACKS:
        raise ValueError(f"unknown feedback {feedback!r}; choose one of {FEEDBACKS}")
    spec = SCENARIOS[scenario]
    E = gains.B if gains.E is None else gains.E
    plant = LTIPlant(gains.A, gains.B, gains.C, E, x0=x0,
                     noise_amplitude=spec.noise_amplitude, seed=seed, scheme=plant_scheme)
    h = dt if h is None else h
    obs = FilteringObserver(gains, h=h, scheme=scheme, tau_max=tau_max)
    lin = LuenbergerObserver(gains, h=h, scheme=scheme)
    n_steps = int(round(t_end / dt))
    n, n_model, k = gains.n, gains.n_model, gains.k
    x = np.empty((n_steps + 1, n))
    obs_state = np.empty((n_steps + 1, n_model + k + 1))  # [z, psi, xi] of the filtering observer
    z_lin = np.empty((n_steps + 1, n))
    for step in range(n_steps + 1):
        x[step], obs_state[step], z_lin[step] = plant.x, obs.get_state(), lin.z
        if step == n_steps:
            break
        t_k = step * dt
        y = plant.y
        u = K @ (obs.x_hat if feedback == "estimate" else plant.x)
        q = np.full(E.shape[1], spec.q_amplitude * np.sin(Q_FREQUENCY * t_k))
        plant.step(u, q, dt)
        obs.step(y, u, dt)
        lin.step(y, u, dt)
    psi, xi = obs_state[:, n_model:n_model + k], obs_state[:, -1]
    sigma = np.sqrt(np.maximum(np.maximum(xi, 0.5 * np.sum(psi**2, axis=1)), 0.0))
    return SimulationResult(t=np.arange(n_steps + 1) * dt, x=x, z=obs_state[:, :n], z_lin=z_lin,
                            psi=psi, xi=xi, sigma=sigma, q_hat=obs_state[:, n:n_model])


def accuracy_metrics(results: list[SimulationResult], scenario: str) -> dict[str, float]:
    """The issue's target metrics for one scenario (several results = several seeds).

    Returns
    -------
    dict
        ``nominal``: ``error_1_5`` = norm(x - z) at t = 1.5 (and ``error_1_0``);
        ``perturbed``: ``max_1_3`` = max of norm(x - z) over [1, 3];
        ``perturbed_noisy``: ``rms_1_3`` and ``rms_lin_1_3`` (means over the results of the RMS
        of norm(x - z) over [1, 3]) and their ``ratio`` (linear / homogeneous).
        Each also has the Luenberger counterpart with the suffix ``_lin``.
    """
    if scenario == "nominal":
        r = results[0]
        return {"error_1_0": float(r.error[r.at(1.0)]), "error_1_5": float(r.error[r.at(1.5)]),
                "error_1_5_lin": float(r.error_lin[r.at(1.5)])}
    if scenario == "perturbed":
        r = results[0]
        mask = r.window(1.0, 3.0)
        return {"max_1_3": float(np.max(r.error[mask])),
                "max_1_3_lin": float(np.max(r.error_lin[mask]))}
    rms = np.mean([_rms(r.error[r.window(1.0, 3.0)]) for r in results])
    rms_lin = np.mean([_rms(r.error_lin[r.window(1.0, 3.0)]) for r in results])
    return {"rms_1_3": float(rms), "rms_1_3_lin": float(rms_lin), "ratio": float(rms_lin / rms)}


def _rms(values: np.ndarray) -> float:
    """Root mean square."""
    return float(np.sqrt(np.mean(values**2)))
