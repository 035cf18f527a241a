"""In-process reference simulation of the paper's closed loop (the ground truth for co-simulation).

Plant + filtering homogeneous observer + Luenberger observer (+ the Kalman filter when the design
has one), control ``u = K z`` with z the filtering observer's estimate, the paper's set-up
(:mod:`fhobs.paper`: K, x(0), perturbation and noise), observers at zero. Jacobi convention of
docs/architecture.md: fixed communication step dt, ``t_k = k dt``; at t_k
``y_k = C x_k + eta_k``, ``u_k = K z_k``, ``q_k = q_amplitude sin(q_frequency t_k)``;
then the plant and every observer advance by dt with these inputs held. The loop is closed
through the homogeneous observer only, so the data (x, y, u) are the same for every estimator:
the others run open-loop on the recorded (y, u) (:func:`replay` runs any further estimator on
them). Other plants (the zoo of ``examples/``) run the
same loop with their own ``K`` and ``x0``, optionally with the feedback on the true state.
With the compiled kernel the loop runs in C (``reference_loop.c``), else from Python.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np
from fhobs.core.gains import ObserverDesign
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.kernel import StepperHandle
from fhobs.core.plant import LTIPlant, noise_samples
from fhobs.core.runtime import SCHEMES, FilteringObserver, LuenbergerObserver
from fhobs.core.validation import check_step_size
from fhobs.paper import H_PAPER, K_PAPER, PAPER_SCENARIOS, X0_PAPER

from harness.native import ReferenceLoop, ReferenceRecord, reference_library

FEEDBACKS = ("estimate", "state")


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
    z_kalman : np.ndarray or None
        The Kalman filter's estimate of x (None without a Kalman filter in the design).
    y, u : np.ndarray or None
        The measured outputs and the inputs held over the steps from t_k, k = 0 .. N - 1;
        None when not recorded.
    """

    t: np.ndarray
    x: np.ndarray
    z: np.ndarray
    z_lin: np.ndarray
    psi: np.ndarray
    xi: np.ndarray
    sigma: np.ndarray
    q_hat: np.ndarray | None = None
    z_kalman: np.ndarray | None = None
    y: np.ndarray | None = None
    u: np.ndarray | None = None

    @property
    def error(self) -> np.ndarray:
        """``norm(x - z)`` of the filtering observer at each t_k."""
        return np.linalg.norm(self.x - self.z, axis=1)

    @property
    def error_lin(self) -> np.ndarray:
        """``norm(x - z_lin)`` of the Luenberger observer at each t_k."""
        return np.linalg.norm(self.x - self.z_lin, axis=1)

    @property
    def error_kalman(self) -> np.ndarray:
        """``norm(x - z_kalman)`` of the Kalman filter at each t_k."""
        return np.linalg.norm(self.x - self.z_kalman, axis=1)

    def at(self, t: float) -> int:
        """Index of the sample nearest to t."""
        return int(np.argmin(np.abs(self.t - t)))

    def window(self, t0: float, t1: float) -> np.ndarray:
        """Boolean mask of the samples with t0 <= t <= t1."""
        tol = 1e-9 * max(1.0, abs(t1))
        return (self.t >= t0 - tol) & (self.t <= t1 + tol)


def simulate(
    design: ObserverDesign,
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
    kernel: bool = True,
) -> SimulationResult:
    """Run the paper's closed loop (or another plant's, with ``K`` and ``x0``) under the Jacobi
    convention.

    Parameters
    ----------
    design : ObserverDesign
        Observer design (its plant's E is used for the perturbation; B if E is None).
    scenario : str
        Key of :data:`fhobs.paper.PAPER_SCENARIOS`.
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
    kernel : bool
        Step the plant and the estimators in the compiled kernel when it is available
        (:mod:`fhobs.core.kernel`), the loop itself in C when it is compiled
        (``reference_loop.c``, :func:`harness.native.reference_library`: the same steps in the
        same order, about 20 times faster); False: the numpy runtime only, stepped from
        Python. The Kalman filter, open loop, is replayed on the recorded (y, u) either way.

    Returns
    -------
    SimulationResult

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> result = simulate(paper_gains(), "nominal", t_end=0.1)
    >>> float(result.t[-1]), result.x.shape
    (0.1, (2001, 4))
    >>> bool(result.error[-1] < result.error[0])
    True
    """
    if feedback not in FEEDBACKS:
        raise ValueError(f"unknown feedback {feedback!r}; choose one of {FEEDBACKS}")
    spec = PAPER_SCENARIOS[scenario]
    dt = check_step_size(dt)
    model = design.plant
    E = model.B if model.E is None else model.E
    plant = LTIPlant(model.A, model.B, model.C, E, x0=x0,
                     noise_amplitude=spec.noise_amplitude, seed=seed, scheme=plant_scheme,
                     kernel=kernel)
    h = dt if h is None else h
    obs = FilteringObserver(design.filtering, h=h, scheme=scheme, tau_max=tau_max,
                            kernel=kernel)
    others = [LuenbergerObserver(design.luenberger, h=h, scheme=scheme, kernel=kernel)]
    n_steps = int(round(t_end / dt))
    t = np.arange(n_steps + 1) * dt
    q = np.repeat(spec.q_amplitude * np.sin(spec.q_frequency * t)[:, None], E.shape[1], axis=1)
    K = np.asarray(K, dtype=float)
    if K.shape != (model.m, model.n) or not np.all(np.isfinite(K)):
        raise ValueError(f"K must be a finite {model.m} x {model.n} matrix (inputs x states) for "
                         f"this plant; got shape {K.shape}")
    loop = _loop_in_c if _runs_in_c(kernel, plant, obs, others) else _loop_in_python
    x, obs_state, estimates, ys, us = loop(plant, obs, others, K, q, n_steps, dt, feedback)
    z_kalman = None if design.kalman is None else _replay_records(
        KalmanObserver(design.kalman, kernel=kernel), ys, us, dt)
    n, n_model, k = model.n, design.model.n_model, model.k
    psi, xi = obs_state[:, n_model:n_model + k], obs_state[:, -1]
    sigma = np.sqrt(np.maximum(np.maximum(xi, 0.5 * np.sum(psi**2, axis=1)), 0.0))
    return SimulationResult(t=t, x=x, z=obs_state[:, :n],
                            z_lin=estimates[0], psi=psi, xi=xi, sigma=sigma,
                            q_hat=obs_state[:, n:n_model],
                            z_kalman=z_kalman, y=ys, u=us)


C_CHUNK = 100_000
"""Steps per call of the C loop (about 0.2 s on the pendulum)."""
Trajectories = tuple[np.ndarray, np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]
"""x, the filtering observer's states [z, psi, xi], the other observers' estimates, y, u."""


def _runs_in_c(kernel: bool, plant: LTIPlant, obs: FilteringObserver, others: list) -> bool:
    """Whether :func:`simulate`'s loop runs in C: the kernel asked for, the loop compiled, the
    plant and the observers compiled."""
    return (kernel and reference_library() is not None and plant.compiled and obs.compiled
            and all(other.compiled for other in others))


def _loop_in_python(plant: LTIPlant, obs: FilteringObserver, others: list, K: np.ndarray,
                    q: np.ndarray, n_steps: int, dt: float, feedback: str) -> Trajectories:
    """The loop of :func:`simulate`, a step of every model per communication step."""
    n, size = plant.A.shape[0], obs.get_state().size
    x = np.empty((n_steps + 1, n))
    obs_state = np.empty((n_steps + 1, size))
    estimates = np.empty((len(others), n_steps + 1, n))
    ys, us = np.empty((n_steps, plant.C.shape[0])), np.empty((n_steps, K.shape[0]))
    # with K checked the loop computes y, u and q itself (finite, of the right sizes): the
    # models' advance, their step without the argument checks; a non-finite result still raises
    for step in range(n_steps + 1):
        x[step], obs_state[step] = plant.x, obs.get_state()
        for estimate, other in zip(estimates, others, strict=True):
            estimate[step] = other.x_hat
        if step == n_steps:
            break
        y = ys[step] = plant.y
        u = us[step] = K @ (obs.x_hat if feedback == "estimate" else plant.x)
        plant.advance(u, q[step], dt)
        obs.advance(y, u, dt)
        for other in others:
            other.advance(y, u, dt)
    return x, obs_state, list(estimates), ys, us


def _loop_in_c(plant: LTIPlant, obs: FilteringObserver, others: list, K: np.ndarray,
               q: np.ndarray, n_steps: int, dt: float, feedback: str) -> Trajectories:
    """The loop of :func:`simulate` in ``reference_loop.c`` (the models' kernel steps, y and u
    computed in C, in calls of :data:`C_CHUNK` steps). The models are :func:`simulate`'s, new:
    the noise starts at step 0."""
    n, k, m = plant.A.shape[0], plant.C.shape[0], K.shape[0]
    handles = [model.kernel_handle(dt) for model in (plant, obs, *others)]
    others_handles = (StepperHandle * len(others))(*handles[2:])
    C = np.ascontiguousarray(plant.C, dtype=float)
    K = np.ascontiguousarray(K)
    eta = noise_samples(plant.seed, n_steps, plant.noise_amplitude, k)
    q = np.ascontiguousarray(q[:n_steps])
    x = np.empty((n_steps + 1, n))
    obs_state = np.empty((n_steps + 1, handles[1].size))
    estimates = np.empty((len(others), n_steps + 1, n))
    ys, us = np.empty((n_steps, k)), np.empty((n_steps, m))
    loop = ReferenceLoop(n_steps, n, k, m, q.shape[1], int(feedback == "state"),
                         *(array.ctypes.data for array in (C, K, eta, q)),
                         ctypes.pointer(handles[0]), ctypes.pointer(handles[1]),
                         others_handles, len(others))
    record = ReferenceRecord(*(array.ctypes.data for array in (x, obs_state, estimates, ys, us)))
    sides, failed = (ctypes.c_int * (len(others) + 2))(), (ctypes.c_long * 2)()
    run = reference_library().reference_run
    for k_from in range(0, max(n_steps, 1), C_CHUNK):  # Ctrl-C is seen between chunks
        k_to = min(k_from + C_CHUNK, n_steps)
        if run(ctypes.byref(loop), ctypes.byref(record), sides, ctypes.c_long(k_from),
               ctypes.c_long(k_to), failed):
            model = ("plant", "filtering observer", *(type(o).__name__ for o in others))
            raise ValueError(f"the {model[failed[0]]}'s state became non-finite at step "
                             f"{failed[1]}")
    return x, obs_state, list(estimates), ys, us


def replay(observer, result: SimulationResult) -> np.ndarray:
    """Run an estimator open-loop on the recorded (y, u) of ``result``; its x_hat at every t_k.

    Parameters
    ----------
    observer
        Any object with the runtime interface (``step(y, u, dt)``, ``x_hat``), at its start.
    result : SimulationResult
        A run of :func:`simulate` (y and u recorded).

    Returns
    -------
    np.ndarray
        (N + 1, n) estimates, row k at t_k: what the observer would have given in the loop.

    Examples
    --------
    >>> result = simulate(design, "perturbed_noisy")            # doctest: +SKIP
    >>> z = replay(KalmanObserver(design.kalman), result)       # doctest: +SKIP
    """
    return _replay_records(observer, result.y, result.u, float(result.t[1] - result.t[0]))


def _replay_records(observer, ys: np.ndarray, us: np.ndarray, dt: float) -> np.ndarray:
    """:func:`replay` on the inputs ``ys``, ``us`` held over steps of size dt."""
    out = np.empty((len(ys) + 1, observer.x_hat.size))
    for step in range(len(ys) + 1):
        out[step] = observer.x_hat
        if step < len(ys):
            observer.step(ys[step], us[step], dt)
    return out


def accuracy_metrics(results: list[SimulationResult], scenario: str) -> dict[str, float]:
    """The target metrics of one of the paper's scenarios (several results = several seeds).

    Returns
    -------
    dict
        ``nominal``: ``error_1_5`` = norm(x - z) at t = 1.5 (and ``error_1_0``);
        ``perturbed``: ``max_1_3`` = max of norm(x - z) over [1, 3];
        ``perturbed_noisy``: ``rms_1_3`` and ``rms_lin_1_3`` (means over the results of the RMS
        of norm(x - z) over [1, 3]) and their ``ratio`` (linear / homogeneous).
        Each also has the Luenberger counterpart with the suffix ``_lin``, and the Kalman
        filter's with the suffix ``_kalman`` when the results have one.
    """
    out = _metrics(results, scenario, "error", "")
    out |= _metrics(results, scenario, "error_lin", "_lin")
    if results[0].z_kalman is not None:
        out |= _metrics(results, scenario, "error_kalman", "_kalman")
    if scenario == "perturbed_noisy":
        out["ratio"] = out["rms_1_3_lin"] / out["rms_1_3"]
    return out


def _metrics(results: list[SimulationResult], scenario: str, error: str,
             suffix: str) -> dict[str, float]:
    """The metrics of one estimator's error (the attribute ``error`` of each result)."""
    r = results[0]
    if scenario == "nominal":
        out = {f"error_1_5{suffix}": float(getattr(r, error)[r.at(1.5)])}
        if not suffix:
            out["error_1_0"] = float(r.error[r.at(1.0)])
        return out
    if scenario == "perturbed":
        return {f"max_1_3{suffix}": float(np.max(getattr(r, error)[r.window(1.0, 3.0)]))}
    rms = np.mean([_rms(getattr(r, error)[r.window(1.0, 3.0)]) for r in results])
    return {f"rms_1_3{suffix}": float(rms)}


def _rms(values: np.ndarray) -> float:
    """Root mean square."""
    return float(np.sqrt(np.mean(values**2)))
