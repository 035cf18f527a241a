"""doStep's currentCommunicationPoint, on the pythonfmu and the native FMUs: a non-finite time
and a time away from the FMU's own (the end of its last step, or the start time) are fmi2Error
naming both times, the state unchanged (compared with an untouched twin); hosts that form time
as t0 + k h or accumulate it (t += h, as OMSimulator does) are accepted over many steps; after
an FMU state is set, the next doStep's time is taken as it comes."""

from __future__ import annotations

import numpy as np
import pytest
from fhobs.fmu.call_rules import TIME_TOLERANCE
from fmpy import extract
from fmu_fixtures import FmuDriver, assert_error

DT = 1e-3


@pytest.fixture(scope="module")
def observers(pendulum_fmus, native_fmus):
    native = native_fmus["observer"]
    python = pendulum_fmus["observer"]
    return {"pythonfmu": (python, extract(str(python))),
            "native": (native, extract(str(native)))}


@pytest.fixture
def pair(observers):
    """factory(build, start_time=0.0) -> (driver, twin), both started."""
    opened = []

    def factory(build: str, start_time: float = 0.0):
        drivers = [FmuDriver(*observers[build], name) for name in ("driver", "twin")]
        for d in drivers:
            d.fmu.setupExperiment(startTime=start_time)
            d.fmu.enterInitializationMode()
            d.fmu.exitInitializationMode()
        opened.extend(drivers)
        return drivers

    yield factory
    for d in opened:
        d.fmu.freeInstance()


def step(driver: FmuDriver, t: float, k: int) -> None:
    driver.set("y", np.array([0.3 * np.sin(k * 0.01), -0.2]))
    driver.set("u", np.array([0.1]))
    driver.fmu.doStep(t, DT)


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
@pytest.mark.parametrize("bad", ["nan", "inf", "-1", "three back", "ten ahead"])
def test_a_wrong_time_is_an_error_state_unchanged(pair, build, bad):
    driver, twin = pair(build)
    for k in range(5):
        step(driver, k * DT, k)
        step(twin, k * DT, k)
    t = 5 * DT
    wrong = {"nan": float("nan"), "inf": float("inf"), "-1": -1.0,
             "three back": t - 3 * DT, "ten ahead": t + 10 * DT}[bad]
    driver.set("y", np.array([0.3, -0.2]))
    for _ in range(3):
        message = assert_error(driver, driver.fmu.doStep, wrong, DT,
                               words="currentCommunicationPoint")
        if bad in ("three back", "ten ahead", "-1"):
            assert repr(t) in message or f"{t:g}" in message, message
    for k in range(5, 8):
        step(driver, k * DT, k)
        step(twin, k * DT, k)
    assert driver.get("x_hat", (4,)).tolist() == twin.get("x_hat", (4,)).tolist()


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
def test_hosts_that_accumulate_or_multiply_time_are_accepted(pair, build):
    """2000 steps: t += h (OMSimulator) for one, t0 + k h (fmpy, the harness) for the other,
    from a start time that is not a multiple of h; the two runs agree."""
    t0 = 0.3
    driver, twin = pair(build, start_time=t0)
    t = t0
    for k in range(2000):
        step(driver, t, k)
        step(twin, t0 + k * DT, k)
        t += DT
    assert abs(t - (t0 + 2000 * DT)) > 0.0  # the two hosts' times did drift apart
    assert driver.get("x_hat", (4,)).tolist() == twin.get("x_hat", (4,)).tolist()


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
def test_the_start_time_is_the_first_time(pair, build):
    driver, _ = pair(build, start_time=0.3)
    assert_error(driver, driver.fmu.doStep, 0.0, DT, words="currentCommunicationPoint 0.0")
    step(driver, 0.3 * (1 + 0.5 * TIME_TOLERANCE), 0)


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
def test_after_a_state_is_set_the_next_time_is_taken(pair, build):
    driver, twin = pair(build)
    for k in range(5):
        step(driver, k * DT, k)
    state = driver.fmu.getFMUstate()
    step(driver, 5 * DT, 5)
    twin.fmu.setFMUstate(twin.fmu.deSerializeFMUstate(driver.fmu.serializeFMUstate(state)))
    driver.fmu.setFMUstate(state)
    driver.fmu.freeFMUstate(state)
    step(driver, 40 * DT, 5)  # a rollback host may restart from its own clock
    step(twin, 5 * DT, 5)
    assert driver.get("x_hat", (4,)).tolist() == twin.get("x_hat", (4,)).tolist()
    assert_error(driver, driver.fmu.doStep, 5 * DT, DT, words="currentCommunicationPoint")
    step(driver, 41 * DT, 6)
