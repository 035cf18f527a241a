"""The prescribed-time observer's split step in the compiled kernel (``fhobs_prescribed_step``)
against the numpy runtime (``kernel=False``, the reference): the pendulum's nominal closed loop
and seeded inputs on bundled designs, fixed and variable steps, to 1e-12 relative."""

from __future__ import annotations

import numpy as np
import pytest
from designs import zoo_design
from fhobs.core import kernel
from fhobs.core.runtime import PrescribedTimeObserver, prescribed_xi0
from fhobs.paper import K_PAPER, X0_PAPER
from reference_math import zoh

pytestmark = pytest.mark.skipif(kernel.library() is None, reason="no compiled kernel")

RTOL = 1e-12


def pair(gains, T0: float = 1.0, **options):
    xi0 = prescribed_xi0(T0, gains.model.nu, gains.filtering.rho)
    compiled = PrescribedTimeObserver(gains.prescribed_time, xi0=xi0, **options)
    reference = PrescribedTimeObserver(gains.prescribed_time, xi0=xi0, kernel=False, **options)
    assert compiled.compiled and not reference.compiled
    return compiled, reference


def relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


def test_pendulum_closed_loop_to_after_T0(paper_design):
    gains = paper_design
    compiled, reference = pair(gains)
    x, t = X0_PAPER.copy(), 0.0
    worst = 0.0
    # the plant's, per step size
    holds = {dt: zoh(gains.plant.A, gains.plant.B, dt) for dt in (1e-3, 4e-4)}
    for k in range(1500):
        # variable steps before T0 only: after it, the capped observer switching between
        # the floors of two step sizes is not contractive (numpy's runtime too)
        dt = 1e-3 if k % 5 or t > 0.8 else 4e-4
        t += dt
        y, u = gains.plant.C @ x, K_PAPER @ x
        compiled.step(y, u, dt)
        reference.step(y, u, dt)
        worst = max(worst, relative(compiled.get_state(), reference.get_state()))
        Phi, Gamma = holds[dt]
        x = Phi @ x + Gamma @ u
    assert worst <= RTOL, worst
    assert compiled.diagnostics()["xi"] == 0.0
    assert np.abs(compiled.x_hat - x).max() < 1e-8 * np.abs(x).max()


@pytest.mark.parametrize("name", [
    "maglev", *(pytest.param(name, marks=pytest.mark.slow)
                for name in ("pendulum", "triple_integrator"))])
def test_bundled_designs_with_seeded_inputs(name):
    gains = zoo_design(name)
    compiled, reference = pair(gains, T0=0.5, z0=np.ones(gains.plant.n))
    rng = np.random.default_rng(1)
    worst = 0.0
    for k in range(400):
        y, u = rng.standard_normal(gains.plant.k) * 0.1, rng.standard_normal(gains.plant.m) * 0.1
        dt = (2e-4, 5e-4, 1e-3)[k % 3]
        compiled.step(y, u, dt)
        reference.step(y, u, dt)
        worst = max(worst, relative(compiled.get_state(), reference.get_state()))
    assert worst <= RTOL, worst


def test_a_step_size_without_a_contractive_level_is_refused_with_the_state_kept(paper_design):
    compiled, reference = pair(paper_design)
    before = compiled.get_state()
    for model in (compiled, reference):
        with pytest.raises(ValueError, match="no gain level makes the split step"):
            model.step([0.0, 0.0], [0.0], 0.1)
    assert np.array_equal(compiled.get_state(), before)


def test_no_kernel_for_the_euler_scheme_or_when_disabled(monkeypatch, paper_design):
    gains = paper_design
    assert not PrescribedTimeObserver(gains.prescribed_time, scheme="euler").compiled
    monkeypatch.setenv(kernel.DISABLE_ENV, "1")
    assert not PrescribedTimeObserver(gains.prescribed_time).compiled
