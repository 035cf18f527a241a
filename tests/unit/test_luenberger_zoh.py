"""The Luenberger observer's split step: the exact zero-order hold of its closed loop.

``dz/dt = A z + B u + L_lin (C z - y)`` with y and u held over a step is the linear system
``A_cl = A + L_lin C`` with inputs (y, u); its step is checked against scipy's ZOH
(``cont2discrete`` and ``expm`` of the augmented matrix) and against a fine ``solve_ivp`` of
the continuous observer with the inputs held. The stiff motor below (a fast mode at -500, an
integrator, a disturbance model; rho = 64 given) is a plant whose held-innovation
discretisation ``expm(dt A) + Gamma_L C`` is unstable at dt = 1e-3 (checked here with scipy):
the closed-loop hold converges at that step and at coarse ones, in numpy, in the compiled
kernel and in the native FMU.
"""

from __future__ import annotations

import shutil
import sys

import numpy as np
import pytest
import scipy.linalg as sl
from fhobs.core import kernel
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import LuenbergerObserver
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import spec_from_dict
from reference_math import relative
from scipy.integrate import solve_ivp
from scipy.signal import cont2discrete

MOTOR = {"A": [[-500.0, -50.0, 0.0], [50.0, -1.0, 0.0], [0.0, 1.0, 0.0]],
         "B": [[1000.0], [0.0], [0.0]], "C": [[0.0, 0.0, 1.0]], "E": [[0.0], [1000.0], [0.0]],
         "observer": {"disturbance_order": 1, "rho": 64.0}}
STEPS = (1e-4, 1e-3, 1e-2, 2e-2, 5e-2)
"""The default communication step of ``harness plant`` (1e-3), a finer and coarser ones."""
X0 = np.array([1.0, -2.0, 0.5])


@pytest.fixture(scope="module")
def motor():
    return design_for_spec(spec_from_dict(MOTOR))


def closed_loop(design):
    """A_cl, -L_lin, B and C of the design's Luenberger observer (the plant's matrices)."""
    plant, L = design.luenberger.plant, design.luenberger.L_lin
    return plant.A + L @ plant.C, -L, plant.B, plant.C


def input_sequences(steps: int, dt: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded y and u held over each step: smooth signals plus a random walk."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps) * dt
    y = (np.sin(3.0 * t) + 0.1 * np.cumsum(rng.standard_normal(steps)) * np.sqrt(dt))[:, None]
    u = (0.2 * np.cos(5.0 * t) + 0.1 * rng.standard_normal(steps))[:, None]
    return y, u


@pytest.mark.parametrize("dt", STEPS)
def test_step_matrix_is_scipys_zero_order_hold(motor, paper_design, dt):
    """``[Phi, Gamma_y, Gamma_u]`` is scipy's ZOH of (A_cl, [-L_lin, B]) (cont2discrete) and
    the first rows of scipy's expm of the augmented matrix."""
    for design in (motor, paper_design):
        A_cl, G, B, _ = closed_loop(design)
        n = A_cl.shape[0]
        M = LuenbergerObserver(design.luenberger, kernel=False).closed_loop_map(dt)
        Ad, Bd, *_ = cont2discrete((A_cl, np.hstack((G, B)), np.eye(n), 0.0), dt, method="zoh")
        assert relative(M, np.hstack((Ad, Bd))) < 1e-11
        size = n + G.shape[1] + B.shape[1]
        aug = np.zeros((size, size))
        aug[:n] = np.hstack((A_cl, G, B))
        assert relative(M, sl.expm(dt * aug)[:n]) < 1e-11


@pytest.mark.parametrize("dt", [1e-3, 2e-2])
def test_steps_follow_the_continuous_observer_with_held_inputs(motor, dt):
    """50 steps with seeded y, u held: the observer's states are those of the continuous
    observer integrated finely (solve_ivp, Radau, tight tolerances) over each step."""
    A_cl, G, B, _ = closed_loop(motor)
    ys, us = input_sequences(50, dt, seed=3)
    obs = LuenbergerObserver(motor.luenberger, z0=X0, kernel=False)
    z = X0.copy()
    worst = 0.0
    for y, u in zip(ys, us, strict=True):
        obs.step(y, u, dt)
        forcing = G @ y + B @ u
        sol = solve_ivp(lambda _t, w, f=forcing: A_cl @ w + f, (0.0, dt), z, method="Radau",
                        rtol=1e-12, atol=1e-14, jac=A_cl)
        z = sol.y[:, -1]
        worst = max(worst, float(np.linalg.norm(obs.z - z) / np.linalg.norm(z)))
    assert worst < 1e-8


def test_held_innovation_map_of_the_motor_is_unstable(motor):
    """Why the motor is the case to test: the held-innovation map ``expm(dt A) + Gamma_L C``
    (scipy) has a spectral radius above 1 at the default step 1e-3, while ``A_cl`` is
    Hurwitz."""
    plant, L = motor.luenberger.plant, motor.luenberger.L_lin
    n = plant.n
    aug = np.zeros((2 * n, 2 * n))
    aug[:n, :n], aug[:n, n:] = plant.A, np.eye(n)
    E = sl.expm(1e-3 * aug)
    radius = max(abs(np.linalg.eigvals(E[:n, :n] + E[:n, n:] @ L @ plant.C)))
    assert radius > 1.01
    assert max(np.linalg.eigvals(plant.A + L @ plant.C).real) < 0.0


def motor_run(design, dt: float, t_end: float, kernel_step: bool) -> dict[str, np.ndarray]:
    """The motor (exact ZOH, u = 0, from X0) and the Luenberger observer from 0: the plant's
    states, the measurements and the observer's states after each step."""
    plant = LTIPlant(design.plant.A, design.plant.B, design.plant.C, x0=X0)
    obs = LuenbergerObserver(design.luenberger, kernel=kernel_step)
    assert obs.compiled == (kernel_step and kernel.library() is not None)
    u = np.zeros(1)
    xs, ys, zs = [], [], []
    for _ in range(round(t_end / dt)):
        y = plant.y
        plant.step(u, None, dt)
        obs.step(y, u, dt)
        xs.append(plant.x)
        ys.append(y)
        zs.append(obs.z)
    return {"x": np.array(xs), "y": np.array(ys), "z": np.array(zs)}


@pytest.mark.parametrize("dt", STEPS[1:])
def test_motor_estimate_converges_at_the_default_and_coarse_steps(motor, dt):
    """The error, |X0| at the start, stays bounded (no growth beyond the observer's own
    transient), falls by 1e3 from t = 1 s to 6 s as the plant comes to rest (the held y lags
    a moving one) and ends below 1e-7 of |X0|, in numpy and in the compiled kernel; the two
    agree to 1e-12 relative."""
    runs = {flag: motor_run(motor, dt, 6.0, flag) for flag in (False, True)}
    for run in runs.values():
        error = np.linalg.norm(run["z"] - run["x"], axis=1)
        assert np.isfinite(error).all()
        assert error.max() < 1e5 * np.linalg.norm(X0)
        assert error[-1] < 1e-3 * error[round(1.0 / dt) - 1]
        assert error[-1] < 1e-7 * np.linalg.norm(X0)
    assert relative(runs[True]["z"], runs[False]["z"]) < 1e-12


@pytest.mark.skipif(sys.platform != "linux" or shutil.which("cc") is None,
                    reason="native FMUs are built for linux64 with cc")
@pytest.mark.parametrize("dt", [1e-3, 2e-2])
def test_native_fmu_is_the_numpy_runtime(motor, tmp_path, dt):
    """The native luenberger.fmu (its plan computed in C) fed the motor's measurements gives
    the numpy runtime's estimates to 1e-12 relative."""
    from fhobs.native.build import build_native_fmus
    from fmpy import extract
    from fmu_fixtures import FmuDriver

    path = build_native_fmus(motor, tmp_path, kinds=["luenberger"])["luenberger"]
    driver = FmuDriver(path, extract(str(path), str(tmp_path / "unzipped")))
    driver.start()
    run = motor_run(motor, dt, 1.0, kernel_step=False)
    estimates = []
    for k, y in enumerate(run["y"]):
        driver.set("y", y)
        driver.set("u", np.zeros(1))
        driver.fmu.doStep(k * dt, dt)
        estimates.append(driver.get("x_hat", (3,)))
    driver.fmu.freeInstance()
    assert relative(np.array(estimates), run["z"][:, :3]) < 1e-12
