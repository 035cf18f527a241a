"""Partial homogenisation (fhobs.design.partial): stiff plants design with the defaults, the fast
modes' error is autonomous in the runtime, and the certificate refuses a broken split.

The references are independent of the design: scipy's matrix exponential of the model for the
fast modes' error, eigenvalues of the model, and the paper's identities checked here in numpy.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg
from fhobs.core.certificate import certify_filtering
from fhobs.core.runtime import FilteringObserver
from fhobs.design.observer import design_observer
from fhobs.design.spec import plant_spec
from fhobs.errors import CertificateError, SpecError

pytestmark = pytest.mark.unit

# The textbook DC motor a new user writes: x = (i, w, phi), the angle measured, the load torque
# through E; electrical pole -495 1/s, mechanical -6.1 1/s.
R, L_IND, K_M, J, D = 0.5, 1e-3, 0.05, 1e-3, 1e-3
MOTOR_A = [[-R / L_IND, -K_M / L_IND, 0.0], [K_M / J, -D / J, 0.0], [0.0, 1.0, 0.0]]
MOTOR_B = [[1.0 / L_IND], [0.0], [0.0]]
MOTOR_C = [[0.0, 0.0, 1.0]]
MOTOR_E = [[0.0], [1.0 / J], [0.0]]
MOTOR_SCALE = [12.0, 50.0, 25.0]


def motor_design(**tuning):
    return design_observer(MOTOR_A, MOTOR_B, MOTOR_C, E=MOTOR_E, disturbance_order=1,
                           settling_time=0.5, state_scale=MOTOR_SCALE, **tuning)


@pytest.fixture(scope="module")
def motor():
    return motor_design()


def test_stiff_motor_designs_with_the_defaults(motor):
    tuning = motor.settling_tuning
    assert tuning["met"], tuning
    assert tuning["settling_time_predicted"] <= 0.5
    assert motor.model.partial
    # the electrical pole (-495 1/s) is kept: the gains stay far below the 1e8 of a design
    # that cancels it through the angle
    assert np.max(np.abs(motor.filtering.L)) < 1e5
    assert np.max(np.abs(motor.model.L0)) < 1e3


def test_the_kept_mode_is_the_fast_one(motor):
    A_model, _, _ = motor.filtering.model_matrices
    Pi = motor.model.slow_projector
    kept = np.linalg.eigvals((np.eye(4) - Pi) @ A_model @ (np.eye(4) - Pi))
    fast = [lam for lam in np.linalg.eigvals(A_model) if lam.real < -100.0]
    assert len(fast) == 1
    assert np.min(np.abs(kept - fast[0])) < 1e-6 * abs(fast[0])
    assert np.linalg.matrix_rank(Pi) == 3


def test_identities_on_the_homogenised_part(motor):
    """The paper's identities, checked here in numpy on the range of Pi (not the whole model)."""
    A_model, _, C_model = motor.filtering.model_matrices
    model = motor.model
    A0, G_d, Pi, nu = A_model + model.L0 @ C_model, model.G_d, model.slow_projector, model.nu
    residual = (A0 @ G_d - (G_d + nu * np.eye(4)) @ A0) @ Pi
    assert np.linalg.norm(residual) < 1e-8 * np.linalg.norm(A0) * np.linalg.norm(G_d)
    np.testing.assert_allclose(C_model @ G_d, (1 + nu) * C_model, atol=1e-10)
    assert np.linalg.norm(np.linalg.matrix_power(A0, model.n_tilde) @ Pi) < (
        1e-8 * np.linalg.norm(A0) ** model.n_tilde)
    # and not on the whole model: the fast mode is not cancelled
    assert np.max(np.abs(np.linalg.eigvals(A0))) > 100.0


def test_fast_error_is_autonomous_in_the_runtime(motor):
    """The error's component along the kept mode evolves by the model alone (scipy's expm),
    whatever the observer injects: the cascade of the theory, in the runtime's split step."""
    A_model, _, _ = motor.filtering.model_matrices
    Pi = motor.model.slow_projector
    rest = np.eye(4) - Pi
    dt = 1e-4
    step = scipy.linalg.expm(dt * rest @ A_model @ rest)
    observer = FilteringObserver(motor.filtering)
    e0 = np.array([12.0, -50.0, 25.0, 0.3])
    state = observer.get_state()
    state[:4] = -e0
    observer.set_state(state)
    fast = rest @ -e0
    for _ in range(200):
        observer.step(np.zeros(1), np.zeros(1), dt)
        fast = step @ fast
        np.testing.assert_allclose(rest @ observer.z, fast, rtol=0,
                                   atol=1e-9 * np.linalg.norm(e0))
    assert np.linalg.norm(fast) < 1e-3 * np.linalg.norm(rest @ e0)  # it did decay


def test_error_converges_to_round_off(motor):
    observer = FilteringObserver(motor.filtering)
    scale = np.array(MOTOR_SCALE)
    state = observer.get_state()
    state[:3] = -scale
    observer.set_state(state)
    dt = 1e-4
    for _ in range(int(1.5 / dt)):
        observer.step(np.zeros(1), np.zeros(1), dt)
    assert np.linalg.norm(observer.x_hat / scale) < 1e-9


@pytest.mark.parametrize("field", ["identity", "fast_gain"])
def test_certificate_refuses_a_broken_split(motor, field):
    filtering = motor.filtering
    if field == "identity":  # the partial gains claimed as a whole-model homogenisation
        model = dataclasses.replace(motor.model, slow_projector=np.eye(4))
        edited = dataclasses.replace(filtering, model=model)
        words = "homogenisation_residual"
    else:  # a gain that injects along the kept mode
        Pi = motor.model.slow_projector
        v = (np.eye(4) - Pi)[:, [0]] / np.linalg.norm((np.eye(4) - Pi)[:, 0])
        edited = dataclasses.replace(filtering, L=filtering.L + 1e-3 * np.linalg.norm(
            filtering.L) * v)
        words = "injection_partition"
    with pytest.raises(CertificateError, match=words):
        certify_filtering(edited)


def test_fast_mode_rate_inf_homogenises_everything():
    design = design_observer([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -50.0]],
                             [[0.0], [0.0], [1.0]], [[1.0, 0.0, 0.0]], rho=2.0,
                             fast_mode_rate=math.inf)
    assert not design.model.partial
    np.testing.assert_array_equal(design.model.slow_projector, np.eye(3))
    kept = design_observer([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -50.0]],
                           [[0.0], [0.0], [1.0]], [[1.0, 0.0, 0.0]], rho=2.0)
    assert kept.model.partial  # -50 1/s is faster than 50 / 2 s and 2 rho (1 + nu)


def test_pendulum_is_homogenised_whole():
    from fhobs.design.observer import design_for_spec
    from fhobs.design.spec import load_spec
    from fhobs.paper import EXAMPLES

    design = design_for_spec(load_spec(EXAMPLES / "pendulum.toml"))
    np.testing.assert_array_equal(design.model.slow_projector, np.eye(design.model.n_model))


@pytest.mark.parametrize("value", [0.0, -1.0, "fast", True])
def test_fast_mode_rate_is_validated(value):
    with pytest.raises(SpecError, match="fast_mode_rate"):
        plant_spec([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], fast_mode_rate=value)
