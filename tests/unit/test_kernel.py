"""The compiled step kernel (fhobs.core.kernel) against the numpy runtime, its reference.

The kernel's arithmetic is numpy's formula by formula but its matrix-vector sums are added in
another order than numpy's BLAS, so the two agree to round-off, not bit for bit: every
comparison here is relative, ``max |kernel - numpy| / max |numpy|`` over the compared run.
The FMUs built with and without the kernel: tests/fmu/test_kernel_fmu.py.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from designs import random_design
from fhobs.build import build_fmus
from fhobs.core import kernel
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver, LuenbergerObserver, PrescribedTimeObserver
from fhobs.design.kalman import with_kalman
from fhobs.design.spec import NoiseSpec
from fhobs.errors import BuildError
from fmu_fixtures import (
    plant_measurements,
    random_walk,
)
from reference_math import relative

import harness.reference as reference

if kernel.library() is None:
    pytest.skip("no compiled kernel on this machine (needs Linux and cc)",
                allow_module_level=True)

RTOL = 1e-12


def run_pair(make, ys, us, dt):
    """States of the kernel model and of the numpy model after each step, and how many steps
    the kernel's model made in numpy (none: the kernel makes the level search too)."""
    fast, slow = make(True), make(False)
    assert fast.compiled and not slow.compiled
    numpy_steps = []
    own_level = fast._correct_own_level  # the numpy split step's (not the gain cap search's)

    def counted(*args):
        numpy_steps.append(1)
        return own_level(*args)

    fast._correct_own_level = counted
    a, b = [], []
    for y, u in zip(ys, us, strict=True):
        fast.step(y, u, dt)
        slow.step(y, u, dt)
        a.append(fast.get_state())
        b.append(slow.get_state())
    return np.array(a), np.array(b), len(numpy_steps)


def tolerance(make, ys, us, dt) -> float:
    """``RTOL``, or more where the design amplifies round-off beyond it: ``ULP_FACTOR`` times
    how far a one-ulp change of every measurement moves the numpy run (relative)."""
    runs = []
    for y_run in (ys, np.nextafter(ys, np.inf)):
        model = make(False)
        states = []
        for y, u in zip(y_run, us, strict=True):
            model.step(y, u, dt)
            states.append(model.get_state())
        runs.append(np.array(states))
    return max(RTOL, ULP_FACTOR * relative(runs[1], runs[0]))


ULP_FACTOR = 4

RANDOM_CASES = [(0, 4, 2, 0), (1, 6, 3, 0), (2, 8, 2, 1), (3, 12, 4, 0), (4, 10, 3, 1),
                (9, 20, 4, 0), (7, 6, 2, 0), (6, 16, 4, 2)]
"""(seed, n, k, disturbance order) of :func:`random_design`."""
STEP_CASES = [(case, dt) for case in RANDOM_CASES for dt in (5e-5, 1e-3)]


FAST_STEP_CASES = {(RANDOM_CASES[0], 5e-5), (RANDOM_CASES[4], 1e-3), (RANDOM_CASES[7], 1e-3)}
"""The fast subset's cases: both step sizes, the three disturbance orders."""


@pytest.mark.parametrize(("case", "dt"), [
    c if c in FAST_STEP_CASES else pytest.param(*c, marks=pytest.mark.slow) for c in STEP_CASES])
def test_filtering_observer_matches_numpy_on_random_designs(case, dt):
    """From the all-zero start (sigma = 0: the level search in the first step) to
    convergence, every step in C."""
    g = random_design(*case)
    ys, us = plant_measurements(g, case[0], 300, dt)
    make = lambda c: FilteringObserver(g.filtering, kernel=c)  # noqa: E731
    a, b, numpy_steps = run_pair(make, ys, us, dt)
    assert relative(a, b) <= tolerance(make, ys, us, dt)  # RTOL but for seed 2 (3.5e-12)
    assert numpy_steps == 0


@pytest.mark.parametrize("case", [
    c if c in (RANDOM_CASES[0], RANDOM_CASES[7]) else pytest.param(c, marks=pytest.mark.slow)
    for c in RANDOM_CASES])
@pytest.mark.parametrize(("dt", "h"), [(5e-5, 5e-5), (2e-4, 5e-5)])
def test_euler_scheme_matches_numpy_on_random_designs(case, dt, h):
    """The explicit Euler substeps (one, or four per communication step) of both observers."""
    g = random_design(*case)
    ys, us = plant_measurements(g, 1, 300, dt)
    for cls, record in ((FilteringObserver, g.filtering), (LuenbergerObserver, g.luenberger)):
        a, b, _ = run_pair(lambda c, cls=cls, record=record: cls(record, h=h, scheme="euler",
                                                                  kernel=c), ys, us, dt)
        assert relative(a, b) <= RTOL


def test_filtering_observer_matches_numpy_for_huge_errors():
    """Errors of 1e10: the level at its ceiling, where the level search ends at once (in C)."""
    g, dt = random_design(4, 10, 3, 1), 1e-3
    ys, us = plant_measurements(g, 2, 200, dt, scale=1e10)
    make = lambda c: FilteringObserver(g.filtering, kernel=c)  # noqa: E731
    a, b, numpy_steps = run_pair(make, ys, us, dt)
    ceiling = make(False)._ceiling(dt)
    assert np.all(np.sqrt(0.5 * np.sum(b[1:, g.model.n_model:-1] ** 2, axis=1)) > ceiling)
    assert relative(a, b) <= RTOL
    assert numpy_steps == 0


@pytest.mark.parametrize("scale", [1e-9, 1e-14])
def test_filtering_observer_matches_numpy_for_tiny_errors(scale):
    """Errors of 1e-9 and 1e-14: the level at its floor, where the gain amplifies round-off
    of y by up to 1e6 (the runtime's round-off floor): the two agree to what one ulp of y
    changes in the numpy run (about 5e-11 relative here), not to 1e-12."""
    g, dt = random_design(4, 10, 3, 1), 1e-3
    ys, us = plant_measurements(g, 2, 200, dt, scale=scale)
    make = lambda c: FilteringObserver(g.filtering, kernel=c)  # noqa: E731
    a, b, numpy_steps = run_pair(make, ys, us, dt)
    assert relative(a, b) <= tolerance(make, ys, us, dt)
    assert numpy_steps == 0


def test_filtering_observer_matches_numpy_near_convergence(tuned_design):
    """Started next to the plant's state with sigma = 0: tiny errors, the level at its floor
    (the capped spectral factors reused)."""
    g, dt = tuned_design, 5e-5
    ys, us = plant_measurements(g, 3, 400, dt)
    ys = ys * 0 + ys[0]  # a plant at rest at x with y = C x: the observer at z0 = x errs by 1e-9
    us = us * 0
    x = np.linalg.lstsq(g.plant.C, ys[0], rcond=None)[0]
    z0 = np.concatenate((x + 1e-9, np.zeros(g.model.n_model - g.plant.n)))
    a, b, numpy_steps = run_pair(lambda c: FilteringObserver(g.filtering, z0=z0, kernel=c),
                                 ys, us, dt)
    assert relative(a, b) <= RTOL
    assert numpy_steps == 0  # the first steps' level search (psi grows from sigma = 0) in C


def test_real_spectrum_of_the_injection_flow(chain_gains_for_kernel):
    """R = [[L_tilde, 1], [C L, 0]] with real eigenvalues (real spectral factors in numpy)."""
    g = chain_gains_for_kernel
    filtering = dataclasses.replace(g.filtering, L_tilde=np.array([[-40.0]]))
    obs = FilteringObserver(filtering)
    assert obs._flow.kernel_arrays()["real_lam"]
    ys, us = plant_measurements(g, 4, 200, 1e-3)
    a, b, _ = run_pair(lambda c: FilteringObserver(filtering, kernel=c), ys, us, 1e-3)
    assert relative(a, b) <= RTOL


@pytest.fixture(scope="module")
def chain_gains_for_kernel():
    return random_design(5, 3, 1, 0)


@pytest.mark.parametrize(("seed", "n", "k", "order"), RANDOM_CASES[:6])
def test_linear_models_match_numpy(seed, n, k, order):
    """Luenberger observer, plant (ZOH, with noise and q) and Kalman filter (2 cycles per
    step)."""
    g, dt = random_design(seed, n, k, order), 1e-3
    ys, us = plant_measurements(g, seed, 200, dt)
    a, b, _ = run_pair(lambda c: LuenbergerObserver(g.luenberger, kernel=c), ys, us, dt)
    assert relative(a, b) <= RTOL
    E = np.ones((n, 1)) if g.plant.E is None else g.plant.E
    plants = [LTIPlant(g.plant.A, g.plant.B, g.plant.C, E, x0=np.ones(n), noise_amplitude=1e-3,
                       seed=1, kernel=c) for c in (True, False)]
    qs = random_walk(seed, 200, 1, 1.0)
    for u, q in zip(us, qs, strict=True):
        for plant in plants:
            plant.step(u, q, dt)
        assert relative(plants[0].get_state(), plants[1].get_state()) <= RTOL
        assert relative(plants[0].y, plants[1].y) <= RTOL
    noise = NoiseSpec(measurement_std=np.full(k, 1e-3), sample_time=dt / 2,
                      process_intensity=1e-2, disturbance_order=order)
    plant = dataclasses.replace(g.plant, E=E)
    design = dataclasses.replace(
        g, plant=plant, **{name: dataclasses.replace(getattr(g, name), plant=plant)
                           for name in ("filtering", "prescribed_time", "luenberger")})
    kalman = with_kalman(design, noise).kalman
    filters = [KalmanObserver(kalman, kernel=c) for c in (True, False)]
    for y, u in zip(ys, us, strict=True):
        for kf in filters:
            kf.step(y, u, dt)
        assert relative(filters[0].get_state(), filters[1].get_state()) <= RTOL


def test_state_restore_and_rollback(tuned_design):
    """A step leaves the arrays of the state before it untouched (it writes the other buffer),
    so the FMU slaves' rollback (their attributes as before the step) and set_state continue
    exactly as the uninterrupted run."""
    g, dt = tuned_design, 1e-3
    ys, us = plant_measurements(g, 6, 60, dt)
    obs = FilteringObserver(g.filtering)
    for y, u in zip(ys[:20], us[:20], strict=True):
        obs.step(y, u, dt)
    state = obs.get_state()
    first = []
    for step, (y, u) in enumerate(zip(ys[20:], us[20:], strict=True)):
        saved = obs.__dict__.copy()
        before = [saved["_z"].copy(), saved["_aux"].copy()]
        obs.step(y, u, dt)
        np.testing.assert_array_equal(saved["_z"], before[0])
        np.testing.assert_array_equal(saved["_aux"], before[1])
        if step % 3 == 0:  # roll back and make the step again
            obs.__dict__.clear()
            obs.__dict__.update(saved)
            np.testing.assert_array_equal(obs.get_state(), np.concatenate(before))
            obs.step(y, u, dt)
        first.append(obs.get_state())
    other = FilteringObserver(g.filtering)
    other.set_state(state)
    restored = []
    for y, u in zip(ys[20:], us[20:], strict=True):
        other.step(y, u, dt)
        restored.append(other.get_state())
    np.testing.assert_array_equal(restored, first)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_non_finite_step_is_refused_state_kept():
    plant = LTIPlant(np.array([[1e300]]), np.ones((1, 1)), np.ones((1, 1)), x0=[1e10])
    assert plant.compiled
    with pytest.raises(ValueError, match="overflowed"):
        plant.step([0.0], None, 1.0)
    np.testing.assert_array_equal(plant.x, [1e10])


def test_environment_variable_and_option_turn_the_kernel_off(monkeypatch, tuned_design):
    assert FilteringObserver(tuned_design.filtering).compiled
    assert FilteringObserver(tuned_design.filtering, scheme="euler").compiled
    assert PrescribedTimeObserver(tuned_design.prescribed_time).compiled
    # the prescribed-time observer: split step only
    assert not PrescribedTimeObserver(tuned_design.prescribed_time, scheme="euler").compiled
    assert not FilteringObserver(tuned_design.filtering, kernel=False).compiled
    assert not PrescribedTimeObserver(tuned_design.prescribed_time, kernel=False).compiled
    monkeypatch.setenv(kernel.DISABLE_ENV, "1")
    assert not FilteringObserver(tuned_design.filtering).compiled
    assert not PrescribedTimeObserver(tuned_design.prescribed_time).compiled
    assert not LTIPlant(tuned_design.plant.A, tuned_design.plant.B, tuned_design.plant.C).compiled


def test_without_a_compiler_the_models_run_numpy(monkeypatch, tuned_design, tmp_path):
    """No cc/gcc: the runtime falls back to numpy silently; build_fmus(kernel=True) refuses."""
    with monkeypatch.context() as patch:
        patch.setattr(kernel.shutil, "which", lambda name: None)
        kernel._load.cache_clear()
        try:
            assert kernel.library() is None
            assert not FilteringObserver(tuned_design.filtering).compiled
            with pytest.raises(BuildError, match="kernel=True needs Linux and a C compiler"):
                build_fmus(tuned_design, tmp_path / "fmus", kinds=("plant",), kernel=True)
        finally:
            kernel._load.cache_clear()  # found again below, the compiler back
    assert kernel.library() is not None


# -- the paper's scenarios end to end ---------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["nominal", "perturbed", "perturbed_noisy"])
def test_paper_scenarios_with_and_without_kernel(kalman_design, scenario):
    """Every state of the closed loop (u = K z follows from z: K's cancellations make its
    relative difference 1.1e-12 where z's is 7e-13 on the nominal run)."""
    fast = reference.simulate(kalman_design, scenario, t_end=1.5)
    slow = reference.simulate(kalman_design, scenario, t_end=1.5, kernel=False)
    for name in ("x", "z", "z_lin", "z_kalman", "psi", "xi"):
        assert relative(getattr(fast, name), getattr(slow, name)) <= RTOL, name


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_paper_scenario_with_the_euler_scheme(kalman_design):
    """The noisy scenario with both observers on the explicit Euler scheme. (Not the nominal
    one: there Euler's sigma collapses to 1e-14, where its gain sigma^(nu-1) is about 1e17 and
    any round-off, in numpy as in C, moves the estimate by 1e-10 or more.)"""
    fast = reference.simulate(kalman_design, "perturbed_noisy", t_end=1.5, scheme="euler")
    slow = reference.simulate(kalman_design, "perturbed_noisy", t_end=1.5, scheme="euler",
                              kernel=False)
    for name in ("x", "z", "z_lin", "psi", "xi"):
        assert relative(getattr(fast, name), getattr(slow, name)) <= RTOL, name

@pytest.mark.slow

def test_paper_gains_differ_by_no_more_than_one_ulp_of_y_makes(paper_design, monkeypatch):
    """With the paper's gains the observer amplifies round-off of y by up to 1e6 (its
    round-off floor): a one-ulp change of every measurement already moves the numpy run's
    estimate by ~7e-13 relative. The kernel's difference stays within a few such ulps."""
    slow = reference.simulate(paper_design, "perturbed", t_end=1.5, kernel=False)
    fast = reference.simulate(paper_design, "perturbed", t_end=1.5)

    class OneUlpPlant(LTIPlant):
        @property
        def y(self) -> np.ndarray:
            return np.nextafter(LTIPlant.y.fget(self), np.inf)

    monkeypatch.setattr(reference, "LTIPlant", OneUlpPlant)
    nudged = reference.simulate(paper_design, "perturbed", t_end=1.5, kernel=False)
    ulp_effect = relative(nudged.z, slow.z)
    assert 0.0 < ulp_effect
    assert relative(fast.z, slow.z) <= max(4 * ulp_effect, RTOL)
    for name in ("x", "z_lin", "psi", "xi"):
        assert relative(getattr(fast, name), getattr(slow, name)) <= RTOL, name
