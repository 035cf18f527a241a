"""The steady-state Kalman filter baseline: design against python-control and a Riccati iteration,
the numpy runtime against the filter's equations written out here, and the filter's behaviour on
the paper's scenarios (kalman.fmu: tests/fmu/test_kalman_fmu.py)."""

from __future__ import annotations

import dataclasses

import control
import numpy as np
import pytest
import scipy.linalg as sl
from fhobs.core.disturbance import extended_model
from fhobs.core.gains import ObserverDesign, PlantModel
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.plant import LTIPlant
from fhobs.design.kalman import RADIUS_MARGIN, REGULARISATION, design_kalman, van_loan
from fhobs.design.spec import spec_from_dict
from fhobs.errors import KalmanDesignError, SpecError
from fhobs.paper import K_PAPER, X0_PAPER
from fmu_fixtures import random_walk
from mimo_plants import BALL_BEAM, BALL_BEAM_NOISE
from reference_math import zoh
from scipy.integrate import quad_vec

from harness.reference import accuracy_metrics, replay, simulate

STD = np.full(2, 1e-3 / np.sqrt(3.0))
TS = 5e-5


def model(gains, order):
    """(A_model, B_model, C_model) and the noise input G written out here (not fhobs')."""
    A, B, C = extended_model(gains.plant.A, gains.plant.B, gains.plant.C, gains.plant.E, order)
    G = np.zeros((A.shape[0], 1))
    if order == 0:
        G = gains.plant.E
    else:
        G[-1, 0] = 1.0
    return A, B, C, G


# -- design ------------------------------------------------------------------------------------
@pytest.mark.parametrize("order", [0, 1, 2, 3])
def test_gain_equals_python_control_dlqe(tuned_design, order):
    g = tuned_design
    kf = design_kalman(g.plant, order, STD, 10.0, TS)
    A, _, C, G = model(g, order)
    Phi, Qd = van_loan(A, 10.0 * G @ G.T, TS)
    L, P, _ = control.dlqe(Phi, np.eye(A.shape[0]), C, Qd, np.diag(STD**2))
    np.testing.assert_allclose(Phi @ kf.gain, L, rtol=1e-8, atol=1e-12 * np.abs(L).max())
    np.testing.assert_allclose(kf.covariance, P, rtol=1e-8, atol=1e-12 * np.abs(P).max())
    assert kf.gain.shape == (g.plant.n + order, g.plant.k) and kf.disturbance_order == order


def test_van_loan_equals_quadrature(tuned_design):
    A, _, _, G = model(tuned_design, 2)
    Ts, W = 1e-2, 3.0
    Phi, Qd = van_loan(A, W * G @ G.T, Ts)
    integral, _ = quad_vec(lambda t: sl.expm(t * A) @ (W * G @ G.T) @ sl.expm(t * A).T, 0, Ts,
                           epsabs=1e-16, epsrel=1e-12)
    np.testing.assert_allclose(Qd, integral, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(Phi, sl.expm(Ts * A), rtol=1e-12, atol=1e-14)


def test_gain_is_the_limit_of_the_riccati_recursion(tuned_design):
    """Independent of any Riccati solver: the covariance recursion iterated to convergence."""
    g = tuned_design
    Ts, W = 1e-2, 1.0
    kf = design_kalman(g.plant, 1, STD, W, Ts)
    A, _, C, G = model(g, 1)
    Phi = sl.expm(Ts * A)
    Qd, _ = quad_vec(lambda t: sl.expm(t * A) @ (W * G @ G.T) @ sl.expm(t * A).T, 0, Ts,
                     epsabs=1e-16, epsrel=1e-12)
    R = np.diag(STD**2)
    P = np.eye(A.shape[0])
    for _ in range(3000):
        S = C @ P @ C.T + R
        P = Phi @ (P - P @ C.T @ np.linalg.solve(S, C @ P)) @ Phi.T + Qd
    M = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    np.testing.assert_allclose(kf.gain, M, rtol=1e-6, atol=1e-9 * np.abs(M).max())


@pytest.mark.parametrize(
    ("change", "words"),
    [({"E": None}, "needs E"), ({"measurement_std": [1e-3, 0.0]}, "measurement_std"),
     ({"measurement_std": [1e-3]}, "measurement_std"),
     ({"process_intensity": -1.0}, "process_intensity"), ({"sample_time": np.nan}, "sample_time")],
)
def test_design_rejects_bad_arguments(tuned_design, change, words):
    g = tuned_design
    plant = dataclasses.replace(g.plant, **{k: v for k, v in change.items() if k == "E"})
    args = dict(order=1, measurement_std=STD, process_intensity=1.0, sample_time=TS) | {
        k: v for k, v in change.items() if k != "E"}
    with pytest.raises(KalmanDesignError, match=words):
        design_kalman(plant, **args)


def test_inaccurate_riccati_solution_is_refused(tuned_design):
    """Order 0 with an intensity 1e6: scipy returns a P with an O(1) residual (or, in other
    scipy versions, fails to reorder the pencil); not a filter either way."""
    g = tuned_design
    with pytest.raises(KalmanDesignError, match="inaccurate|no stabilising solution"):
        design_kalman(g.plant, 0, STD, 1e6, TS)


def test_design_record_round_trips(kalman_design, pendulum_spec, tmp_path):
    path = kalman_design.save_json(tmp_path / "design.json")
    back = ObserverDesign.load_json(path)
    for field in dataclasses.fields(kalman_design.kalman):
        if field.name == "plant":
            continue
        a, b = getattr(back.kalman, field.name), getattr(kalman_design.kalman, field.name)
        assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b
    assert back.kalman.plant is back.plant  # the design's plant, written once
    assert back.kalman.process_intensity == pendulum_spec.noise.process_intensity
    assert back.kalman.disturbance_order == 1 and back.kalman.sample_time == 5e-5
    without = dataclasses.replace(kalman_design, kalman=None)
    assert ObserverDesign.load_json(without.save_json(tmp_path / "plain.json")).kalman is None


# -- runtime -----------------------------------------------------------------------------------
def written_out(gains, ys, us, cycles):
    """The filter's two equations, written out: update with M, exact-ZOH prediction."""
    kf = gains.kalman
    A, B, C, _ = model(gains, kf.disturbance_order)
    Phi, Gamma = zoh(A, B, kf.sample_time)
    z = np.zeros(A.shape[0])
    rows = []
    for y, u in zip(ys, us, strict=True):
        for _ in range(cycles):
            z_filtered = z + kf.gain @ (y - C @ z)
            z = Phi @ z_filtered + Gamma @ u
        rows.append(z)
    return np.array(rows)


@pytest.mark.parametrize("cycles", [1, 3])
def test_runtime_equals_the_equations_written_out(kalman_design, cycles):
    g = kalman_design
    ys, us = random_walk(1, 200, g.plant.k, 0.05), random_walk(2, 200, g.plant.m, 0.1)
    obs = KalmanObserver(g.kalman)
    rows = []
    for y, u in zip(ys, us, strict=True):
        obs.step(y, u, cycles * TS)
        rows.append(obs.z)
        np.testing.assert_array_equal(obs.x_hat, obs.z[:g.plant.n])
    expected = written_out(g, ys, us, cycles)
    np.testing.assert_allclose(np.array(rows), expected, rtol=0,
                               atol=1e-10 * np.abs(expected).max())


def test_state_round_trip_and_bad_inputs(kalman_design):
    g = kalman_design
    obs = KalmanObserver(g.kalman, z0=np.arange(1.0, g.plant.n + 1))
    assert obs.z.size == g.plant.n + 1 and obs.z[-1] == 0.0
    ys, us = random_walk(5, 20, g.plant.k, 0.05), random_walk(6, 20, g.plant.m, 0.1)
    for y, u in zip(ys[:10], us[:10], strict=True):
        obs.step(y, u, TS)
    state = obs.get_state()
    first = [obs.step(y, u, TS) or obs.z for y, u in zip(ys[10:], us[10:], strict=True)]
    obs.set_state(state)
    again = [obs.step(y, u, TS) or obs.z for y, u in zip(ys[10:], us[10:], strict=True)]
    np.testing.assert_array_equal(np.array(first), np.array(again))
    with pytest.raises(ValueError, match="y"):
        obs.step(np.array([np.nan, 0.0]), us[0], TS)
    with pytest.raises(ValueError, match="Kalman gain has shape"):
        KalmanObserver(dataclasses.replace(g.kalman, gain=g.kalman.gain[1:]))


def test_unbiased_on_a_constant_perturbation_with_a_disturbance_model(tuned_design):
    """Constant q, no noise, the plant stabilised by state feedback: with a disturbance model
    (order >= 1) the error vanishes; without one (order 0) a bias remains."""
    g, Ts, steps = tuned_design, 1e-3, 3000
    errors = {}
    for order in (0, 1, 2):
        kf = design_kalman(g.plant, order, STD, 1.0, Ts)
        obs = KalmanObserver(kf)
        plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, g.plant.E, x0=X0_PAPER)
        for _ in range(steps):
            u = K_PAPER @ plant.x
            y = plant.y
            plant.step(u, np.array([0.5]), Ts)
            obs.step(y, u, Ts)
        errors[order] = np.linalg.norm(plant.x - obs.x_hat)
        if order:
            np.testing.assert_allclose(obs.q_hat[0], 0.5, rtol=1e-6)
    assert errors[1] < 1e-6 and errors[2] < 1e-6
    assert errors[0] > 1e-3


def test_noisy_scenario_kalman_beats_the_luenberger_baseline(kalman_design):
    """The paper's noisy scenario (short run, seed 2): the Kalman filter's RMS over [0.8, 1.2]
    is far below the paper's Luenberger observer's, on the same data; the reference's Kalman
    estimate equals an open-loop replay on the recorded (y, u)."""
    r = simulate(kalman_design, "perturbed_noisy", t_end=1.2, seed=2)
    np.testing.assert_array_equal(replay(KalmanObserver(kalman_design.kalman), r), r.z_kalman)
    mask = r.window(0.8, 1.2)
    rms_kalman = np.sqrt(np.mean(r.error_kalman[mask] ** 2))
    rms_lin = np.sqrt(np.mean(r.error_lin[mask] ** 2))
    assert rms_kalman < 0.05 * rms_lin
    assert rms_kalman < 2e-2
    metrics = accuracy_metrics([r], "perturbed_noisy")  # the window [1, 3] cut at 1.2
    tail = r.error_kalman[r.window(1.0, 3.0)]
    assert metrics["rms_1_3_kalman"] == pytest.approx(np.sqrt(np.mean(tail**2)), rel=1e-12)


# -- a filter that the specified noise leaves unstable -----------------------------------------
def ball_beam_model(order):
    """(A_model, C_model, G) of the ball and beam, written out here."""
    A, C, E = (np.array(BALL_BEAM[key], dtype=float) for key in ("A", "C", "E"))
    N = 4 + order
    A_model = np.zeros((N, N))
    A_model[:4, :4] = A
    A_model[:4, 4:5] = E if order else 0.0
    A_model[4:N - 1, 5:] = np.eye(order - 1) if order > 1 else 0.0
    G = E if order == 0 else np.eye(N)[:, -1:]
    return A_model, np.hstack([C, np.zeros((2, order))]), G


def test_ball_and_beam_filter_as_specified_is_not_asymptotically_stable():
    """The reason for the regularisation: with the table's noise alone the steady-state filter
    of order 0 has spectral radius 1 (python-control's dlqe), and with a disturbance model the
    Riccati equation has no stabilising solution."""
    W, Ts, R = 1e-2, 1e-3, np.diag(np.square(BALL_BEAM_NOISE["measurement_std"]))
    A, C, G = ball_beam_model(0)
    Phi, Qd = van_loan(A, W * G @ G.T, Ts)
    L, _, _ = control.dlqe(Phi, np.eye(4), C, Qd, R)
    assert np.max(np.abs(np.linalg.eigvals(Phi - L @ C))) > 1 - 1e-9
    A, C, G = ball_beam_model(1)
    Phi, Qd = van_loan(A, W * G @ G.T, Ts)
    with pytest.raises((ValueError, np.linalg.LinAlgError)):
        sl.solve_discrete_are(Phi.T, C.T, Qd, R)


@pytest.mark.parametrize("order", [0, 1, 2, 3])
def test_unreached_states_get_a_small_documented_process_noise(order):
    """The filter is python-control's for the table's noise plus REGULARISATION times its
    intensity on every state, asymptotically stable, and its record says so and names the
    states the table's noise does not reach (the beam's theta and theta')."""
    W, Ts = BALL_BEAM_NOISE["process_intensity"], BALL_BEAM_NOISE["sample_time"]
    std = np.array(BALL_BEAM_NOISE["measurement_std"])
    plant = PlantModel(*(np.array(BALL_BEAM[key], dtype=float) for key in "ABCE"))
    kf = design_kalman(plant, order, std, W, Ts, "from the test")
    A, C, G = ball_beam_model(order)
    Phi, Qd = van_loan(A, W * G @ G.T + REGULARISATION * W * np.eye(A.shape[0]), Ts)
    L, P, _ = control.dlqe(Phi, np.eye(A.shape[0]), C, Qd, np.diag(std**2))
    np.testing.assert_allclose(Phi @ kf.gain, L, rtol=1e-7, atol=1e-10 * np.abs(L).max())
    np.testing.assert_allclose(kf.covariance, P, rtol=1e-7, atol=1e-10 * np.abs(P).max())
    Phi = sl.expm(Ts * A)
    radius = np.max(np.abs(np.linalg.eigvals(Phi - Phi @ kf.gain @ C)))
    assert radius < 1 - RADIUS_MARGIN
    assert kf.tuning.startswith("from the test; process noise of intensity 1e-08")
    assert "does not reach x[3], x[4]" in kf.tuning and f"{radius:.9g}" in kf.tuning


@pytest.mark.parametrize("order", [0, 1, 2, 3])
def test_stable_filter_is_left_as_specified(tuned_design, order):
    """The pendulum's noise reaches every state: no process noise is added."""
    g = tuned_design
    kf = design_kalman(g.plant, order, STD, 10.0, TS, "as given")
    assert kf.tuning == "as given"


def test_noise_that_cannot_be_regularised_names_the_states():
    """A filter that stays within RADIUS_MARGIN of instability with a process noise on every
    state up to the table's own intensity is a KalmanDesignError naming the unreached states:
    a double integrator whose velocity the noise does not reach, measured through a noise of
    std 1e3 against a process intensity of 1e-12."""
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    C = np.array([[1.0, 0.0]])
    E = np.array([[1.0], [0.0]])
    with pytest.raises(KalmanDesignError, match=r"does not reach x\[2\]"):
        design_kalman(PlantModel(A, E, C, E), 0, [1e3], 1e-12, 1e-3)


# -- the spec's [noise] table ------------------------------------------------------------------
NOISE_PLANT = {
    "A": [[0.0, 1.0], [-2.0, -3.0]], "B": [[0.0], [1.0]], "C": [[1.0, 0.0]], "E": [[0.0], [1.0]],
    "observer": {"disturbance_order": 1},
}
NOISE = {"measurement_amplitude": [3e-3], "sample_time": 1e-3, "process_intensity": 2.0}


def test_noise_table_is_read_and_designs_the_filter():
    spec = spec_from_dict(NOISE_PLANT | {"noise": NOISE})
    assert spec.noise.measurement_std == pytest.approx([3e-3 / np.sqrt(3.0)], rel=1e-15)
    assert spec.noise.disturbance_order == 1  # the observer's by default
    assert spec_from_dict(NOISE_PLANT).noise is None
    given = spec_from_dict(NOISE_PLANT | {"noise": {
        "measurement_std": [1e-3], "sample_time": 1e-3, "process_intensity": 2.0,
        "disturbance_order": 2}}).noise
    assert given.measurement_std.tolist() == [1e-3] and given.disturbance_order == 2


@pytest.mark.parametrize(
    ("noise", "plant_change", "words"),
    [
        (NOISE | {"colour": "white"}, {}, "unknown key noise.colour"),
        (NOISE | {"measurement_std": [1e-3]}, {}, "exactly one of"),
        ({k: v for k, v in NOISE.items() if k != "measurement_amplitude"}, {}, "exactly one of"),
        (NOISE | {"measurement_amplitude": [1e-3, 1e-3]}, {}, "list of 1 numbers"),
        (NOISE | {"measurement_amplitude": [-1e-3]}, {}, r"measurement_amplitude\[1\]"),
        (NOISE | {"measurement_amplitude": ["a"]}, {}, "not a number"),
        ({k: v for k, v in NOISE.items() if k != "sample_time"}, {}, "noise.sample_time is "
         "missing"),
        (NOISE | {"process_intensity": 0.0}, {}, "noise.process_intensity = 0.0 must be > 0"),
        (NOISE | {"disturbance_order": 4}, {}, "noise.disturbance_order = 4 is outside"),
        (NOISE | {"disturbance_order": 1.0}, {}, "not an integer"),
        (NOISE, {"E": None, "observer": {}}, "needs E"),
        (NOISE | {"disturbance_order": 1}, {"E": [[1.0], [0.0]], "A": [[0.0, 1.0], [0.0, 0.0]],
                                            "observer": {}},
         "Kalman filter's disturbance model .* not observable"),
        ("white", {}, "noise must be a table"),
    ],
)
def test_noise_table_errors_name_the_field(noise, plant_change, words):
    data = NOISE_PLANT | {"noise": noise}
    for key, value in plant_change.items():
        if value is None:
            del data[key]
        else:
            data[key] = value
    with pytest.raises(SpecError, match=words):
        spec_from_dict(data)
