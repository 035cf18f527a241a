"""The Luenberger observer's split step: per step size, the held innovation or the closed
loop's hold.

With the innovation ``C z - y`` held over a step, the error obeys ``e+ = F e``, ``F =
expm(dt A) + Gamma_L C``, exactly: the step used where F's spectral radius is below
``HELD_INNOVATION_LIMIT``. Elsewhere ``dz/dt = A z + B u + L_lin (C z - y)`` with y and u
held, the linear system ``A_cl = A + L_lin C`` with inputs (y, u). Both holds are checked
against scipy's ZOH (``cont2discrete`` and ``expm`` of the augmented matrices) and a fine
``solve_ivp`` of the continuous observer with the held inputs; the choice against scipy's
radius of F. The stiff motor below (a fast mode at -500, an integrator, a disturbance model;
rho = 64 given) holds the innovation at dt = 1e-4, where its error falls to round-off, and
holds y at 1e-3 and coarser steps, where F is unstable (checked here with scipy) and the
closed-loop hold converges, in numpy, in the compiled kernel and in the native FMU, whose C
planner makes the numpy runtime's choice on the zoo, the stiff examples and the paper's
pendulum.
"""

from __future__ import annotations

import dataclasses
import shutil
import sys

import numpy as np
import pytest
import scipy.linalg as sl
from designs import ZOO, zoo_design
from fhobs.core import kernel
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import HELD_INNOVATION_LIMIT, LuenbergerObserver
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import load_spec, spec_from_dict
from fhobs.paper import EXAMPLES, K_PAPER, X0_PAPER
from reference_math import relative
from scipy.integrate import solve_ivp
from scipy.signal import cont2discrete

MOTOR = {"A": [[-500.0, -50.0, 0.0], [50.0, -1.0, 0.0], [0.0, 1.0, 0.0]],
         "B": [[1000.0], [0.0], [0.0]], "C": [[0.0, 0.0, 1.0]], "E": [[0.0], [1000.0], [0.0]],
         "observer": {"disturbance_order": 1, "rho": 64.0}}
STEPS = (1e-4, 1e-3, 1e-2, 2e-2, 5e-2)
"""The default communication step of ``harness plant`` (1e-3), a finer and coarser ones."""
PLAN_STEPS = (1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
"""The step sizes at which the C planner's choice is compared with the numpy runtime's."""
X0 = np.array([1.0, -2.0, 0.5])


@pytest.fixture(scope="module")
def motor():
    return design_for_spec(spec_from_dict(MOTOR))


def closed_loop(design):
    """A_cl, -L_lin, B and C of the design's Luenberger observer (the plant's matrices)."""
    plant, L = design.luenberger.plant, design.luenberger.L_lin
    return plant.A + L @ plant.C, -L, plant.B, plant.C


def held_innovation(design, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """F = expm(dt A) + Gamma_L C and the held innovation's step ``[F, -Gamma_L, Gamma_B]``
    of ``M (z, y, u)``, from scipy's expm of ``[[A, B, L_lin], [0, 0, 0]]``."""
    plant, L = design.luenberger.plant, design.luenberger.L_lin
    n, m, k = plant.n, plant.m, plant.k
    aug = np.zeros((n + m + k, n + m + k))
    aug[:n] = np.hstack((plant.A, plant.B, L))
    rows = sl.expm(dt * aug)[:n]
    Phi, Gamma_B, Gamma_L = rows[:, :n], rows[:, n:n + m], rows[:, n + m:]
    F = Phi + Gamma_L @ plant.C
    return F, np.hstack((F, -Gamma_L, Gamma_B))


def radius(F: np.ndarray) -> float:
    """Spectral radius by scipy."""
    return float(max(abs(sl.eigvals(F))))


def input_sequences(steps: int, dt: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded y and u held over each step: smooth signals plus a random walk."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps) * dt
    y = (np.sin(3.0 * t) + 0.1 * np.cumsum(rng.standard_normal(steps)) * np.sqrt(dt))[:, None]
    u = (0.2 * np.cos(5.0 * t) + 0.1 * rng.standard_normal(steps))[:, None]
    return y, u


@pytest.mark.parametrize("dt", STEPS)
def test_closed_loop_map_is_scipys_zero_order_hold(motor, paper_design, dt):
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


@pytest.mark.parametrize("dt", STEPS)
def test_step_holds_the_innovation_where_its_error_map_contracts(motor, paper_design, dt):
    """Per step size: F's spectral radius is scipy's (1e-9 relative: the expm's rounding at
    coarse steps of the stiff motor), and the step is scipy's hold of the innovation where
    that radius is below ``HELD_INNOVATION_LIMIT``, else the closed loop's hold. The motor
    holds the innovation at 1e-4 only, the pendulum at every step of STEPS."""
    holds = {}
    for name, design in (("motor", motor), ("pendulum", paper_design)):
        obs = LuenbergerObserver(design.luenberger, kernel=False)
        F, M_held = held_innovation(design, dt)
        assert obs.held_innovation_radius(dt) == pytest.approx(radius(F), rel=1e-9)
        holds[name] = radius(F) < HELD_INNOVATION_LIMIT
        assert obs.holds_innovation(dt) == holds[name]
        expected = M_held if holds[name] else obs.closed_loop_map(dt)
        assert relative(obs.step_map(dt), expected) < 1e-11
    assert holds == {"motor": dt == 1e-4, "pendulum": True}


@pytest.mark.parametrize("dt", [1e-4, pytest.param(1e-3, marks=pytest.mark.slow),
                                pytest.param(2e-2, marks=pytest.mark.slow)])
def test_steps_follow_the_continuous_observer_with_held_inputs(motor, dt):
    """50 steps with seeded y, u held: the observer's states are those of the continuous
    observer integrated finely (solve_ivp, Radau, tight tolerances) over each step, with the
    innovation ``C z - y`` held where the step holds it (1e-4), else y."""
    A_cl, G, B, C = closed_loop(motor)
    A, L = motor.plant.A, -G
    ys, us = input_sequences(50, dt, seed=3)
    obs = LuenbergerObserver(motor.luenberger, z0=X0, kernel=False)
    assert obs.holds_innovation(dt) == (dt == 1e-4)
    z = X0.copy()
    worst = 0.0
    for y, u in zip(ys, us, strict=True):
        obs.step(y, u, dt)
        if obs.holds_innovation(dt):
            matrix, forcing = A, B @ u + L @ (C @ z - y)
        else:
            matrix, forcing = A_cl, G @ y + B @ u
        sol = solve_ivp(lambda _t, w, a=matrix, f=forcing: a @ w + f, (0.0, dt), z,
                        method="Radau", rtol=1e-12, atol=1e-14, jac=matrix)
        z = sol.y[:, -1]
        worst = max(worst, float(np.linalg.norm(obs.z - z) / np.linalg.norm(z)))
    assert worst < 1e-8


def test_held_innovation_map_of_the_motor_is_unstable(motor):
    """Why the motor is the case to test: the held-innovation map ``expm(dt A) + Gamma_L C``
    (scipy) has a spectral radius above 1 at the default step 1e-3, while ``A_cl`` is
    Hurwitz; the step there holds y."""
    F, _ = held_innovation(motor, 1e-3)
    assert radius(F) > 1.01
    assert max(np.linalg.eigvals(closed_loop(motor)[0]).real) < 0.0
    assert not LuenbergerObserver(motor.luenberger, kernel=False).holds_innovation(1e-3)


def observer_run(design, x0: np.ndarray, dt: float, t_end: float, kernel_step: bool,
                 K: np.ndarray | None = None, amplitude: float = 0.0,
                 frequency: float = 0.0) -> dict[str, np.ndarray]:
    """The plant (exact ZOH, from x0) under ``u = K x + amplitude sin(frequency t)`` (K None:
    no feedback) and the Luenberger observer from 0: the plant's states, the measurements,
    the inputs and the observer's states after each step."""
    plant = LTIPlant(design.plant.A, design.plant.B, design.plant.C, x0=x0)
    obs = LuenbergerObserver(design.luenberger, kernel=kernel_step)
    assert obs.compiled == (kernel_step and kernel.library() is not None)
    xs, ys, us, zs = [], [], [], []
    for i in range(round(t_end / dt)):
        u = np.full(design.plant.m, amplitude * np.sin(frequency * i * dt))
        if K is not None:
            u = u + K @ plant.x
        y = plant.y
        plant.step(u, None, dt)
        obs.step(y, u, dt)
        xs.append(plant.x)
        ys.append(y)
        us.append(u)
        zs.append(obs.z)
    return {"x": np.array(xs), "y": np.array(ys), "u": np.array(us), "z": np.array(zs)}


@pytest.mark.parametrize("dt", STEPS[1:])
def test_motor_estimate_converges_at_the_default_and_coarse_steps(motor, dt):
    """The error, |X0| at the start, stays bounded (no growth beyond the observer's own
    transient), falls by 1e3 from t = 1 s to 6 s as the plant comes to rest (the held y lags
    a moving one) and ends below 1e-7 of |X0|, in numpy and in the compiled kernel; the two
    agree to 1e-12 relative."""
    runs = {flag: observer_run(motor, X0, dt, 6.0, flag) for flag in (False, True)}
    for run in runs.values():
        error = np.linalg.norm(run["z"] - run["x"], axis=1)
        assert np.isfinite(error).all()
        assert error.max() < 1e5 * np.linalg.norm(X0)
        assert error[-1] < 1e-3 * error[round(1.0 / dt) - 1]
        assert error[-1] < 1e-7 * np.linalg.norm(X0)
    assert relative(runs[True]["z"], runs[False]["z"]) < 1e-12


FINE_CASES = {"motor-1e-4": ("motor", 1e-4, 1.5), "pendulum-1e-4": ("pendulum", 1e-4, 9.0),
              "pendulum-1e-3": ("pendulum", 1e-3, 9.0)}
"""Design, step size and run time of the fine-step runs: the last third is the steady window
(the observer's own transient decayed below 1e-14 of the initial error)."""


@pytest.mark.slow
@pytest.mark.parametrize("case", FINE_CASES)
def test_error_falls_to_roundoff_at_fine_steps(motor, paper_design, case):
    """A moving plant (the motor driven by 0.5 sin(2 pi t); the pendulum under the paper's K
    plus 0.5 sin(5 t)): the error is the exact recursion ``F^k e_0`` (scipy) up to the
    round-off a step can add, ``eps sum_j ||F^j|| ||M|| max |(x, y, u)|``, which bounds the
    steady error too; the closed loop's hold of the same measurements (scipy's ZOH) lags by
    more than 1e3 times that. Numpy and the compiled kernel agree to 1e-12 relative."""
    name, dt, t_end = FINE_CASES[case]
    design, x0, K, frequency = {"motor": (motor, X0, None, 2.0 * np.pi),
                                "pendulum": (paper_design, X0_PAPER, K_PAPER, 5.0)}[name]
    runs = {flag: observer_run(design, x0, dt, t_end, flag, K, 0.5, frequency)
            for flag in (False, True)}
    assert relative(runs[True]["z"], runs[False]["z"]) < 1e-12
    run = runs[False]
    F, M_held = held_innovation(design, dt)
    sums, power = 0.0, np.eye(F.shape[0])
    while sums < 1.0 or np.linalg.norm(power, np.inf) > 1e-6:
        sums += np.linalg.norm(power, np.inf)
        power = F @ power
    size = np.abs(np.hstack((run["x"], run["y"], run["u"]))).max()
    roundoff = np.finfo(float).eps * sums * np.linalg.norm(M_held, np.inf) * size
    error = run["z"] - run["x"]
    exact = [-x0]
    for _ in range(len(error)):
        exact.append(F @ exact[-1])
    assert np.abs(error - np.array(exact[1:])).max() < roundoff
    steady = slice(2 * len(error) // 3, None)
    held_steady = np.abs(error[steady]).max()
    assert held_steady < roundoff
    A_cl, G, B, _ = closed_loop(design)
    n = A_cl.shape[0]
    Ad, Bd, *_ = cont2discrete((A_cl, np.hstack((G, B)), np.eye(n), 0.0), dt, method="zoh")
    z, lagged = np.zeros(n), []
    for y, u in zip(run["y"], run["u"], strict=True):
        z = Ad @ z + Bd @ np.concatenate((y, u))
        lagged.append(z)
    assert np.abs(np.array(lagged)[steady] - run["x"][steady]).max() > 1e3 * roundoff


def plan_designs() -> dict[str, object]:
    """The zoo's default designs, the stiff examples' (their [noise] tables left out: the
    Luenberger gain does not depend on them) and the paper's pendulum."""
    from fhobs.design.observer import paper_gains

    designs = {name: zoo_design(name) for name in ZOO}
    for path in sorted((EXAMPLES / "stiff").glob("*.toml")):
        spec = dataclasses.replace(load_spec(path), noise=None)
        designs[f"stiff/{path.stem}"] = design_for_spec(spec)
    designs["pendulum-paper"] = paper_gains()
    return designs


@pytest.mark.skipif(sys.platform != "linux" or shutil.which("cc") is None,
                    reason="the planner is compiled with cc on linux")
def test_native_planner_makes_the_runtimes_choice():
    """On the zoo, the stiff examples and the paper's pendulum at step sizes from 1e-5 to 0.1:
    the C planner's spectral radius of F is numpy's to 1e-12 relative, every radius is
    further from the limit than 1e3 times their difference (round-off cannot flip the
    choice), both choose the same hold, and where it is the held innovation their M agree to
    1e-12 relative; both holds occur."""
    from fhobs.native.planner import c_plan

    chosen = set()
    for name, design in plan_designs().items():
        obs = LuenbergerObserver(design.luenberger, kernel=False)
        for dt in PLAN_STEPS:
            plan = c_plan("luenberger", obs, dt)
            numpy_radius = obs.held_innovation_radius(dt)
            gap = abs(plan["radius"] - numpy_radius)
            assert gap <= 1e-12 * numpy_radius, (name, dt)
            assert abs(numpy_radius - HELD_INNOVATION_LIMIT) > 1e3 * gap, (name, dt)
            holds = plan["radius"] < HELD_INNOVATION_LIMIT
            assert holds == obs.holds_innovation(dt), (name, dt)
            if holds:
                assert relative(plan["M"], obs.step_map(dt)) < 1e-12, (name, dt)
            chosen.add(holds)
    assert chosen == {True, False}


@pytest.mark.skipif(sys.platform != "linux" or shutil.which("cc") is None,
                    reason="native FMUs are built for linux64 with cc")
@pytest.mark.parametrize("dt", [1e-4, 1e-3, 2e-2])
def test_native_fmu_is_the_numpy_runtime(motor, tmp_path, dt):
    """The native luenberger.fmu (its plan computed in C) fed the motor's measurements gives
    the numpy runtime's estimates to 1e-12 relative, with the innovation held (1e-4) and y
    held (1e-3, 2e-2)."""
    from fhobs.native.build import build_native_fmus
    from fmpy import extract
    from fmu_fixtures import FmuDriver

    path = build_native_fmus(motor, tmp_path, kinds=["luenberger"])["luenberger"]
    driver = FmuDriver(path, extract(str(path), str(tmp_path / "unzipped")))
    driver.start()
    run = observer_run(motor, X0, dt, 1.0, kernel_step=False)
    estimates = []
    for k, y in enumerate(run["y"]):
        driver.set("y", y)
        driver.set("u", np.zeros(1))
        driver.fmu.doStep(k * dt, dt)
        estimates.append(driver.get("x_hat", (3,)))
    driver.fmu.freeInstance()
    assert relative(np.array(estimates), run["z"][:, :3]) < 1e-12
