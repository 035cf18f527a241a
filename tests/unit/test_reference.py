"""The in-process reference closed loop: Jacobi sequence, the paper's Euler runs, and the
accuracy figures of the runtime on the paper's three scenarios.

The figures are asserted for the default configuration of the pendulum example (our tuned
gains with the disturbance model of order 1, default scheme), with the Kalman filter of its
[noise] table on the same data; the paper's gains are run beside them in the same runs."""

import dataclasses

import numpy as np
import pytest
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver, LuenbergerObserver
from fhobs.design.kalman import with_kalman
from fhobs.design.observer import design_for_spec
from fhobs.paper import K_PAPER, PAPER_SCENARIOS, X0_PAPER

from harness.figures import plot_errors
from harness.reference import accuracy_metrics, replay, simulate

pytestmark = pytest.mark.slow  # full-length closed loops of the paper (5 seeds)

KALMAN_INTENSITY = {1: 10**-2.5, 2: 10**-0.5}
"""The tuned process intensities of the Kalman filters of order 1 and 2 (bench_noise_tradeoff:
the least noisy RMS of the grid 10^(j/2), on a separate seed 10 as on the seeds 0..4)."""
SEEDS = range(5)


def scenario_runs(gains) -> dict:
    """Default scheme, paper's step h = 5e-5, the three scenarios (noise: 5 seeds)."""
    return {
        "nominal": [simulate(gains, "nominal", t_end=1.6)],
        "perturbed": [simulate(gains, "perturbed", t_end=3.0)],
        "perturbed_noisy": [simulate(gains, "perturbed_noisy", t_end=3.0, seed=s)
                            for s in SEEDS],
    }


@pytest.fixture(scope="module")
def tuned_runs(tuned_design, pendulum_spec):
    """The default design with the Kalman filter of the [noise] table (order 1, as ours),
    which runs on the same recorded (y, u)."""
    return scenario_runs(with_kalman(tuned_design, pendulum_spec.noise))


@pytest.fixture(scope="module")
def paper_runs(paper_design):
    return scenario_runs(paper_design)


@pytest.mark.parametrize("kernel", [True, False])
@pytest.mark.parametrize("K", [np.zeros((1, 2)), np.zeros((2, 4)), K_PAPER * np.nan],
                         ids=["too_few_states", "too_many_inputs", "not_finite"])
def test_a_feedback_gain_of_another_plant_is_refused(paper_design, K, kernel):
    """The loop checks K once (it then advances the models without their per-step checks): a
    gain of the wrong shape or not finite is a ValueError naming K, before any step."""
    with pytest.raises(ValueError, match=r"K must be a finite 1 x 4 matrix"):
        simulate(paper_design, "nominal", t_end=0.01, K=K, kernel=kernel)


def test_jacobi_sequence(paper_design):
    """simulate() is: y_k, u_k = K z_k, q_k from t_k = k dt; then every block steps. The C loop
    forms K z with its own sums, numpy's BLAS with others, so the two agree to round-off
    (1e-12 of the state's size; measured 1e-15), not bit for bit; the sequence the docstring
    names matters far more (y_k taken after the plant's step: 3e-3)."""
    g, dt, steps = paper_design, 1e-3, 30
    result = simulate(g, "perturbed_noisy", t_end=steps * dt, dt=dt, seed=3)
    q = PAPER_SCENARIOS["perturbed_noisy"]
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, g.plant.B, x0=X0_PAPER,
                     noise_amplitude=q.noise_amplitude, seed=3)
    obs, lin = FilteringObserver(g.filtering, h=dt), LuenbergerObserver(g.luenberger, h=dt)
    for k in range(steps):
        y, u = plant.y, K_PAPER @ obs.z
        plant.step(u, [q.q_amplitude * np.sin(q.q_frequency * k * dt)], dt)
        obs.step(y, u, dt)
        lin.step(y, u, dt)
    for recorded, stepped in ((result.x[-1], plant.x), (result.z[-1], obs.z),
                              (result.z_lin[-1], lin.z)):
        assert np.max(np.abs(recorded - stepped)) <= 1e-12 * np.max(np.abs(stepped))
    assert np.array_equal(result.t, np.arange(steps + 1) * dt)


def test_paper_explicit_euler_is_reproduced(paper_design):
    """All-Euler transcription (plant too), h = 5e-5: about 6e-9 at t = 1.0, then the gain blows
    up and the error degrades to about 1e-3 at t = 1.5 (as measured with the paper's scheme)."""
    metrics = accuracy_metrics(
        [simulate(paper_design, "nominal", t_end=1.5, scheme="euler", plant_scheme="euler")],
        "nominal")
    assert 2e-9 < metrics["error_1_0"] < 2e-8
    assert 3e-4 < metrics["error_1_5"] < 3e-3


@pytest.mark.parametrize("runs", ["tuned_runs", "paper_runs"])
@pytest.mark.xdist_group("unit/test_reference.py")  # the runs' worker (see tests/conftest.py)
def test_nominal_reaches_precision_floor(runs, request):
    """Target: norm(x - z) at t = 1.5 <= 1e-9; the error is at round-off from then on."""
    result = request.getfixturevalue(runs)["nominal"][0]
    assert accuracy_metrics([result], "nominal")["error_1_5"] <= 1e-9
    assert np.max(result.error[result.window(1.5, 1.6)]) <= 1e-9
    assert result.error[result.at(0.5)] > 0.1  # finite-time, not instantaneous


def test_observer_trajectories_stay_finite(tuned_runs, paper_runs):
    for runs in [*tuned_runs.values(), *paper_runs.values()]:
        for r in runs:
            assert all(np.all(np.isfinite(a)) for a in (r.x, r.z, r.z_lin, r.psi, r.xi, r.sigma))


def test_perturbed_target_and_the_kalman_filter(tuned_runs, paper_runs):
    """Target: max of norm(x - z) over [1, 3] <= 1e-6 (measured 2.4e-7); the Kalman filter of
    the same disturbance order on the same data reaches 6.8e-3, 1e4 times more. The paper's
    gains are still converging at t = 1.0 (about 3.7e-2)."""
    ours = accuracy_metrics(tuned_runs["perturbed"], "perturbed")
    assert ours["max_1_3"] <= 1e-6
    assert ours["max_1_3_kalman"] >= 1e3 * ours["max_1_3"]
    assert accuracy_metrics(paper_runs["perturbed"], "perturbed")["max_1_3"] > 1e-2


def test_perturbation_is_rejected_after_convergence(paper_runs):  # the paper's gains
    """Matched perturbation (E = B): after convergence the error stays at the sampling floor
    (O(h) in the velocities), far below the linear observer's."""
    r = paper_runs["perturbed"][0]
    mask = r.window(1.2, 3.0)
    assert np.max(r.error[mask]) < 1e-3 < 1e-1 < np.max(r.error_lin[mask])


def test_noisy_figure_beats_paper_not_kalman(tuned_runs, paper_runs):
    """Mean over 5 seeds of the RMS of norm(x - z) over [1, 3]: measured 8.44e-3, 51x below the
    linear observer in the same runs; the paper's gains reach 3.6e-2 (12x). The Kalman filter
    of the same disturbance order wins on noise (6.61e-3; ours is 1.28x)."""
    ours = accuracy_metrics(tuned_runs["perturbed_noisy"], "perturbed_noisy")
    paper = accuracy_metrics(paper_runs["perturbed_noisy"], "perturbed_noisy")
    assert ours["rms_1_3"] <= 9e-3 and ours["ratio"] >= 25.0
    assert ours["rms_1_3"] < 0.5 * paper["rms_1_3"] and paper["ratio"] > 10.0
    assert ours["rms_1_3_kalman"] < ours["rms_1_3"] <= 1.35 * ours["rms_1_3_kalman"]


@pytest.mark.slow
def test_least_noisy_design_of_the_search(pendulum_spec):
    """The least noisy certified design the noise search found (disturbance order 2,
    nu = -0.18, rho = gamma = 8, filter_scale = 1.5; its own closed loop, Kalman filters on the
    same data): nominal at round-off, perturbed max 7.4e-9, noisy RMS 5.4e-3 over seeds 0..4:
    below the order-1 Kalman filter's 6.61e-3, above the order-2 one's 3.56e-3 (the filter of
    the same model wins on noise, ours on the perturbation by five orders of magnitude)."""
    spec = dataclasses.replace(pendulum_spec, disturbance_order=2, nu=-0.18, rho=8.0,
                               gamma=8.0, filter_scale=1.5)
    gains = design_for_spec(spec)
    kalman = {order: with_kalman(gains, dataclasses.replace(
        pendulum_spec.noise, disturbance_order=order, process_intensity=KALMAN_INTENSITY[order]))
        for order in (1, 2)}
    perturbed = accuracy_metrics([simulate(kalman[1], "perturbed")], "perturbed")
    noisy = [simulate(kalman[1], "perturbed_noisy", seed=s) for s in SEEDS]
    noisy_1 = accuracy_metrics(noisy, "perturbed_noisy")
    # the loop is closed through the homogeneous observer alone: the order-2 filter on the
    # same data is a replay of the recorded (y, u)
    replayed = [dataclasses.replace(r, z_kalman=replay(KalmanObserver(kalman[2].kalman), r))
                for r in noisy]
    noisy_2 = accuracy_metrics(replayed, "perturbed_noisy")
    nominal = accuracy_metrics([simulate(gains, "nominal", t_end=1.5)], "nominal")
    assert nominal["error_1_5"] <= 1e-9
    assert perturbed["max_1_3"] <= 1e-7 and perturbed["max_1_3_kalman"] >= 1e4 * 1e-7
    assert noisy_2["rms_1_3_kalman"] < noisy_1["rms_1_3"] < noisy_1["rms_1_3_kalman"]


def test_disturbance_estimate_tracks_the_perturbation(tuned_runs):
    """The model's q state estimates q = 0.1 sin(5 t): max error < 1e-3 over [1, 3] without
    noise (measured 8.8e-5), rms error < 20 % of the amplitude with noise (measured 12 %)."""
    r = tuned_runs["perturbed"][0]
    mask = r.window(1.0, 3.0)
    perturbation = PAPER_SCENARIOS["perturbed"]
    q = perturbation.q_amplitude * np.sin(perturbation.q_frequency * r.t[mask])
    assert np.max(np.abs(r.q_hat[mask, 0] - q)) < 1e-3
    noisy = tuned_runs["perturbed_noisy"][0]
    assert np.sqrt(np.mean((noisy.q_hat[mask, 0] - q) ** 2)) < 0.02


def test_long_noisy_run_stays_finite_and_bounded(paper_design):
    """15 s of perturbation and noise at dt = h = 1e-3: no NaN/Inf, no drift, no reset."""
    r = simulate(paper_design, "perturbed_noisy", t_end=15.0, dt=1e-3, seed=11)
    assert all(np.all(np.isfinite(a)) for a in (r.x, r.z, r.psi, r.xi, r.sigma))
    late = r.window(5.0, 15.0)
    assert np.max(r.error[late]) < 0.5 and np.min(r.sigma[late]) > 0.0


def test_coarse_communication_step_keeps_nominal_floor(paper_design):
    """dt = 1e-3 with internal substeps of 5e-5: the error still converges to round-off, since
    the substeps propagate the innovation with the model (the sampled error is autonomous)."""
    r = simulate(paper_design, "nominal", t_end=1.5, dt=1e-3, h=5e-5)
    assert r.error[r.at(1.5)] <= 1e-9


def test_plots_are_written(tuned_runs, tmp_path):
    for scenario, runs in tuned_runs.items():
        path = plot_errors(runs[0], scenario, tmp_path / f"{scenario}.png")
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
