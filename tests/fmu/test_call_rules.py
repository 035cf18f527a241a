"""Every FMI 2.0 co-simulation function in every state, on the pythonfmu and the native FMUs,
against the table of :mod:`fhobs.fmu.call_rules` (the standard's state machine): allowed calls
answer fmi2OK, the others fmi2Error with the table's message logged, and a refused call leaves
the instance in its state (a doStep after it still behaves as in that state).

The calls go straight to the FMUs' binaries through ctypes (fmpy's wrappers would raise), with
empty value-reference lists for get/set (so only the state decides) and valid arguments
otherwise."""

from __future__ import annotations

import ctypes

import pytest
from fhobs.fmu.call_rules import ALLOWED, STATES, UNSUPPORTED, call_problem
from fmpy import extract
from fmu_fixtures import FmuDriver

OK, ERROR = 0, 3
KINDS = ("observer", "plant", "prescribed_time")
CHANGES_STATE = {"fmi2FreeInstance", "fmi2SetupExperiment", "fmi2EnterInitializationMode",
                 "fmi2ExitInitializationMode", "fmi2Terminate", "fmi2Reset", "fmi2DoStep"}
"""Called on an instance of their own (the others share one instance per state)."""
STEP = 5e-5


@pytest.fixture(scope="module")
def builds(pendulum_fmus, native_fmus):
    """Both builds of each kind with the options of ``pendulum_fmus`` (the plant's start values
    do not change which calls a state allows)."""
    native = native_fmus
    return {("pythonfmu", kind): (pendulum_fmus[kind], extract(str(pendulum_fmus[kind])))
            for kind in KINDS} | {("native", kind): (native[kind], extract(str(native[kind])))
                                  for kind in KINDS}


def in_state(path_dir, state: str) -> FmuDriver:
    """A fresh instance brought into ``state`` by the allowed calls."""
    driver = FmuDriver(*path_dir)
    fmu = driver.fmu
    if state != "instantiated":
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
    if state in ("step mode", "terminated"):
        fmu.exitInitializationMode()
    if state == "terminated":
        fmu.terminate()
    return driver


def raw(driver: FmuDriver, function: str):
    """The binary's ``function`` as a new ctypes object (fmpy's own stays as it is)."""
    f = driver.fmu.dll[function]
    f.restype = ctypes.c_int
    return f


def call(driver: FmuDriver, function: str) -> int:
    """``function`` with valid arguments; its status."""
    c = ctypes.c_void_p(driver.fmu.component)
    null = ctypes.c_void_p(None)
    size = ctypes.c_size_t(0)
    if function.startswith(("fmi2GetReal", "fmi2GetInteger", "fmi2GetBoolean", "fmi2GetString",
                            "fmi2SetReal", "fmi2SetInteger", "fmi2SetBoolean", "fmi2SetString")) \
            and not function.endswith("Status"):
        return raw(driver, function)(c, null, size, null)
    if function in ("fmi2SetFMUstate", "fmi2FreeFMUstate", "fmi2SerializedFMUstateSize",
                    "fmi2SerializeFMUstate", "fmi2DeSerializeFMUstate"):
        return _state_call(driver, function, c)
    arguments = {
        "fmi2SetDebugLogging": (ctypes.c_int(1), size, null),
        "fmi2SetupExperiment": (ctypes.c_int(0), ctypes.c_double(0.0), ctypes.c_double(0.0),
                                ctypes.c_int(0), ctypes.c_double(0.0)),
        "fmi2EnterInitializationMode": (), "fmi2ExitInitializationMode": (),
        "fmi2Terminate": (), "fmi2Reset": (), "fmi2CancelStep": (),
        "fmi2GetFMUstate": (ctypes.byref(ctypes.c_void_p()),),
        "fmi2DoStep": (ctypes.c_double(0.0), ctypes.c_double(STEP), ctypes.c_int(1)),
        "fmi2GetStatus": (ctypes.c_int(0), ctypes.byref(ctypes.c_int())),
        "fmi2GetRealStatus": (ctypes.c_int(2), ctypes.byref(ctypes.c_double())),
        "fmi2GetIntegerStatus": (ctypes.c_int(0), ctypes.byref(ctypes.c_int())),
        "fmi2GetBooleanStatus": (ctypes.c_int(3), ctypes.byref(ctypes.c_int())),
        "fmi2GetStringStatus": (ctypes.c_int(1), ctypes.byref(ctypes.c_char_p())),
        "fmi2GetDirectionalDerivative": (null, size, null, size, null, null),
        "fmi2SetRealInputDerivatives": (null, size, null, null),
        "fmi2GetRealOutputDerivatives": (null, size, null, null),
    }[function]
    return raw(driver, function)(c, *arguments)


def _state_call(driver: FmuDriver, function: str, c: ctypes.c_void_p) -> int:
    """A state function on a state taken from the instance in its current state (taken with
    the FMU state calls allowed in every state)."""
    state = ctypes.c_void_p()
    assert raw(driver, "fmi2GetFMUstate")(c, ctypes.byref(state)) == OK
    size = ctypes.c_size_t()
    try:
        if function == "fmi2SetFMUstate":
            return raw(driver, function)(c, state)
        if function == "fmi2SerializedFMUstateSize":
            return raw(driver, function)(c, state, ctypes.byref(size))
        assert raw(driver, "fmi2SerializedFMUstateSize")(c, state, ctypes.byref(size)) == OK
        data = ctypes.create_string_buffer(size.value)
        if function == "fmi2SerializeFMUstate":
            return raw(driver, function)(c, state, data, size)
        if function == "fmi2DeSerializeFMUstate":
            assert raw(driver, "fmi2SerializeFMUstate")(c, state, data, size) == OK
            back = ctypes.c_void_p()
            status = raw(driver, function)(c, data, size, ctypes.byref(back))
            if status == OK:
                raw(driver, "fmi2FreeFMUstate")(c, ctypes.byref(back))
            return status
        status = raw(driver, function)(c, ctypes.byref(state))  # fmi2FreeFMUstate
        state = ctypes.c_void_p()
        return status
    finally:
        if state.value:
            raw(driver, "fmi2FreeFMUstate")(c, ctypes.byref(state))


def checked_functions() -> list[str]:
    return [f for f in (*ALLOWED, *UNSUPPORTED) if f != "fmi2FreeInstance"]


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("state", STATES)
def test_every_function_in_every_state_follows_the_table(builds, build, kind, state):
    path_dir = builds[(build, kind)]
    shared = in_state(path_dir, state)
    wrong = []
    try:
        for function in checked_functions():
            driver = in_state(path_dir, state) if function in CHANGES_STATE else shared
            messages_before = len(driver.messages)
            try:
                status = call(driver, function)
                problem = call_problem(function, state)
                expected = ERROR if problem else OK
                logged = " | ".join(m for _, m in driver.messages[messages_before:])
                if status != expected or (problem and problem not in logged):
                    wrong.append(f"{function}: status {status}, expected {expected}"
                                 + (f" with '{problem}' logged (got '{logged}')" if problem
                                    else ""))
            finally:
                if driver is not shared:
                    driver.fmu.freeInstance()
        # refused calls left the shared instance in its state
        status = call(shared, "fmi2DoStep")
        expected = OK if state == "step mode" else ERROR
        if status != expected:
            wrong.append(f"doStep after the calls: status {status}, expected {expected}")
    finally:
        shared.fmu.freeInstance()
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
def test_a_state_of_a_failed_initialisation_is_refused_whole(builds, build):
    """A state taken in initialisation mode after a rejected initialisation (xi0 = NaN) is
    refused by a healthy stepping instance, set or deserialized; that instance steps on as an
    untouched twin does."""
    path_dir = builds[(build, "observer")]
    failed = in_state(path_dir, "initialisation mode")
    failed.set("xi0", float("nan"))
    assert call(failed, "fmi2ExitInitializationMode") == ERROR
    state = failed.fmu.getFMUstate()
    data = failed.fmu.serializeFMUstate(state)
    healthy, twin = in_state(path_dir, "step mode"), in_state(path_dir, "step mode")
    try:
        for driver in (healthy, twin):
            driver.fmu.doStep(0.0, STEP)
        with pytest.raises(Exception, match="status 3"):
            healthy.fmu.setFMUstate(state)
        assert "xi0" in healthy.messages[-1][1], healthy.messages[-1][1]
        with pytest.raises(Exception, match="status 3"):
            healthy.fmu.deSerializeFMUstate(data)
        assert "xi0" in healthy.messages[-1][1], healthy.messages[-1][1]
        for driver in (healthy, twin):
            driver.fmu.doStep(STEP, STEP)
        assert healthy.get("x_hat", (4,)).tolist() == twin.get("x_hat", (4,)).tolist()
    finally:
        failed.fmu.freeFMUstate(state)
        for driver in (failed, healthy, twin):
            driver.fmu.freeInstance()
