"""kalman.fmu of a multi-output plant whose [noise] table reaches some states only: the ball
and beam with q on the ball and no disturbance model. The design adds a small process noise on
every state (fhobs.design.kalman), so the FMU accepts its own parameters at initialisation (its
check: spectral radius of Phi (I - M C) < 1) and tracks the plant through fmpy, step for step as the
in-process filter."""

from __future__ import annotations

import numpy as np
import pytest
from fhobs.build import build_fmus
from fhobs.cli import design_summary
from fhobs.core.kalman_filter import KalmanObserver
from fhobs.core.plant import LTIPlant
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import spec_from_dict
from fmpy import extract
from fmu_fixtures import FmuDriver
from mimo_plants import BALL_BEAM, BALL_BEAM_NOISE


@pytest.mark.slow
def test_ball_and_beam_kalman_fmu_initialises_and_converges(tmp_path):
    """Order 0 with a [noise] table: kalman.fmu accepts its own parameters at initialisation
    (its check: spectral radius of Phi (I - M C) < 1) and tracks the plant through fmpy; the
    build's summary states the added process noise."""
    spec = spec_from_dict(BALL_BEAM | {"observer": {"disturbance_order": 0, "rho": 2.0},
                                       "noise": BALL_BEAM_NOISE})
    gains = design_for_spec(spec)
    assert any("process noise of intensity 1e-08" in line for line in design_summary(gains))
    path = build_fmus(gains, tmp_path, kinds=["kalman"])["kalman"]
    driver = FmuDriver(path, extract(str(path)))
    try:
        driver.start()
        assert not any(status >= 3 for status, _ in driver.messages), driver.messages
        Ts = gains.kalman.sample_time
        plant = LTIPlant(gains.plant.A, gains.plant.B, gains.plant.C,
                         x0=np.array([1.0, 0.0, 0.1, 0.0]),
                         kernel=False)
        obs = KalmanObserver(gains.kalman, kernel=False)
        errors = []
        for k in range(5000):
            y, u = plant.y, np.zeros(1)
            driver.set("y", y)
            driver.set("u", u)
            driver.fmu.doStep(k * Ts, Ts)
            obs.step(y, u, Ts)
            plant.step(u, None, Ts)
            errors.append(np.linalg.norm(driver.get("x_hat", (4,)) - plant.x))
        np.testing.assert_allclose(driver.get("x_hat", (4,)), obs.x_hat, rtol=1e-9,
                                   atol=1e-12)
        assert errors[-1] < 2e-2 * errors[0], (errors[0], errors[-1])
    finally:
        driver.fmu.terminate()
        driver.fmu.freeInstance()
