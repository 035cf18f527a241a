"""Caller mistakes against the FMUs: each is answered with fmi2Error and a readable log message,
the instance stays usable with its state untouched, and the host process survives.

Calls that reached pythonfmu's exception path (fmi2Fatal, then a crash of the host after a few
repetitions) run in a child process, which reports what each call returned; everything else runs
in process. The native-host case loads the status wrapper from a small C program without
libpython. Expected values come from the FMI rules and from clean runs of the same FMU.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fhobs.core.runtime import SCHEMES, FilteringObserver
from fhobs.fmu.fmu_state import state_from_bytes, state_to_bytes
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmu_fixtures import FMI_ERROR, UNREADABLE, assert_error, names, serialized

DT = 1e-3
REPEAT = 5

pytestmark = pytest.mark.skipif(
    sys.platform != "linux" or shutil.which("cc") is None,
    reason="fmi2Error answers need the status wrapper (linux64, built with cc)",
)

# -- calls that reached pythonfmu's exception path: in a child process ------------------------
CHILD = """
import json, os, sys
import numpy as np
sys.path.insert(0, {tests!r})
from fmu_fixtures import FmuDriver
from fmpy.fmi1 import FMICallException

paths, dirs = json.loads({paths!r}), json.loads({dirs!r})
Y, U = np.array([0.3, -0.2]), np.array([0.1])

def opened(kind, name):
    driver = FmuDriver(paths[kind], dirs[kind], name)
    driver.start()
    return driver

def run(driver):
    out = []
    for k in range(3):
        driver.set("y", Y)
        driver.set("u", U)
        driver.fmu.doStep(k * {dt!r}, {dt!r})
        out.append(driver.get("x_hat", (4,)).tolist())
    return out

clean = opened("observer", "clean")
reference = run(clean)
plant = opened("plant", "plant")
plant_state = plant.fmu.getFMUstate()
plant_bytes = bytes(plant.fmu.serializeFMUstate(plant_state))

def freed_state(driver):
    state = driver.fmu.getFMUstate()
    dangling = type(state)(state.value)
    driver.fmu.freeFMUstate(state)
    return dangling

def truncated(driver):
    state = driver.fmu.getFMUstate()
    data = bytes(driver.fmu.serializeFMUstate(state))
    driver.fmu.freeFMUstate(state)
    return data[: len(data) // 2]

CASES = {{
    "getReal unknown vr": lambda d: d.fmu.getReal([99999]),
    "setReal unknown vr": lambda d: d.fmu.setReal([4294967295], [1.0]),
    "setReal on an Integer": lambda d: d.fmu.setReal([d.vr["scheme"]], [1.0]),
    "getInteger on a Real": lambda d: d.fmu.getInteger([d.vr["A[1,1]"]]),
    "setInteger on status": lambda d: d.fmu.setInteger([d.vr["status"]], [0]),
    "getBoolean": lambda d: d.fmu.getBoolean([d.vr["status"]]),
    "deserialize garbage": lambda d: d.fmu.deSerializeFMUstate(b"\\x00garbage\\xff" * 3),
    "deserialize truncated": lambda d: d.fmu.deSerializeFMUstate(truncated(d)),
    "deserialize another FMU's state": lambda d: d.fmu.deSerializeFMUstate(plant_bytes),
    "setFMUstate of another FMU": lambda d: d.fmu.setFMUstate(plant_state),
    "setFMUstate of a freed state": lambda d: d.fmu.setFMUstate(freed_state(d)),
}}
results = {{}}
for case, call in CASES.items():
    driver = opened("observer", case)
    statuses = []
    for _ in range({repeat}):
        try:
            call(driver)
            statuses.append(0)
        except FMICallException as err:
            statuses.append(int(err.status))
    results[case] = {{"statuses": statuses, "messages": [m for _, m in driver.messages],
                      "usable": run(driver) == reference}}
    driver.fmu.terminate()
    driver.fmu.freeInstance()
print("RESULTS " + json.dumps(results), flush=True)
"""

CHILD_EXPECTED = {
    "getReal unknown vr": "fmi2GetReal: value reference 99999 is not a variable of this FMU",
    "setReal unknown vr": "fmi2SetReal: value reference 4294967295 is not a variable",
    "setReal on an Integer": "scheme (value reference",
    "getInteger on a Real": "A[1,1] (value reference 1) is of type Real, not Integer",
    "setInteger on status": "status (value reference 0) is a local variable",
    "getBoolean": "is of type Integer, not Boolean",
    "deserialize garbage": "not a serialized FMU state of this FMU",
    "deserialize truncated": "not a serialized FMU state of this FMU",
    "deserialize another FMU's state": "it is a state of 'FhobsPlant_",
    "setFMUstate of another FMU": "was not made by this FMU",
    "setFMUstate of a freed state": "was not made by this FMU",
}


@pytest.fixture(scope="module")
def child_run(pendulum_fmus, unzipped):
    """Run every crash-class mistake REPEAT times in a child process; its exit and results."""
    code = CHILD.format(
        tests=str(Path(__file__).resolve().parents[1]),
        paths=json.dumps({k: str(v) for k, v in pendulum_fmus.items()}),
        dirs=json.dumps({k: str(v) for k, v in unzipped.items()}), dt=DT, repeat=REPEAT,
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULTS ")]
    results = json.loads(lines[0][len("RESULTS "):]) if lines else {}
    return done, results


# The child process (~4 s) is slow. The fast tests keep these answers in process: test_native_fmu
# repeats the native FMUs' mistakes (unknown vr, wrong types, foreign and truncated states),
# test_host_safety the pythonfmu states' refusals, test_prescribed_time_fmu an unknown vr.
@pytest.mark.slow
def test_repeated_mistakes_leave_the_host_running(child_run):
    done, results = child_run
    assert done.returncode == 0, done.stderr[-2000:]
    assert set(results) == set(CHILD_EXPECTED)


@pytest.mark.slow  # the child process: see test_repeated_mistakes_leave_the_host_running
@pytest.mark.parametrize("case", list(CHILD_EXPECTED))
def test_mistake_is_an_error_with_a_message_instance_usable(child_run, case):
    _, results = child_run
    assert case in results, "the child process did not report (crashed?)"
    result = results[case]
    assert result["statuses"] == [FMI_ERROR] * REPEAT
    assert CHILD_EXPECTED[case] in result["messages"][-1]
    assert result["usable"]  # the same steps give the same estimates as a clean instance
    for message in result["messages"]:
        assert not any(word in message for word in UNREADABLE), message


# -- tunability and FMU states ----------------------------------------------------------------
def run_steps(driver, steps: int = 3) -> list[float]:
    """A few steps with fixed inputs, from where the driver's last run_steps ended (0 at
    first); the final x_hat."""
    t0 = getattr(driver, "time", 0.0)
    for k in range(steps):
        driver.set("y", np.array([0.3, -0.2]))
        driver.set("u", np.array([0.1]))
        driver.fmu.doStep(t0 + k * DT, DT)
    driver.time = t0 + steps * DT
    return driver.get("x_hat", (4,)).tolist()


def test_parameters_are_fixed_after_initialisation(open_fmu):
    """A parameter written in step mode (L[1,1] = 0, which the certificate rejects) is refused;
    the run continues exactly as a run without the write."""
    clean = open_fmu("observer", "clean")
    clean.start()
    driver = open_fmu("observer")
    driver.start()
    vr = driver.vr["L[1,1]"]
    before = driver.fmu.getReal([vr])
    assert_error(driver, driver.fmu.setReal, [vr], [0.0], words="L[1,1] (value reference")
    assert "fixed parameter" in driver.messages[-1][1]
    assert_error(driver, driver.fmu.setInteger, [driver.vr["scheme"]], [1], words="scheme")
    assert driver.fmu.getReal([vr]) == before
    assert run_steps(driver) == run_steps(clean)
    driver.fmu.reset()  # writable again before the next initialisation
    driver.fmu.setReal([vr], [before[0]])


def edited_state(driver, edit) -> bytes:
    """The driver's serialized state, parsed, changed by ``edit`` and serialized again with a
    valid checksum (a changed byte without one is refused at the checksum: test_host_safety)."""
    state = state_from_bytes(serialized(driver))
    edit(state)
    return state_to_bytes(state)


STATE_EDITS = {
    "uncertified gain": (lambda s: s["arrays"]["L"][0].__setitem__(0, 0.0),
                         "hurwitz_filtering"),
    "wrong shape": (lambda s: (s["arrays"]["A"][0].__setitem__(0, 123.0),
                               s["arrays"].__setitem__("z0", [1.0])),
                    "z0 has shape (1,), expected (4,)"),
    "non-finite model state": (lambda s: s["model"].__setitem__(0, math.nan),
                               "model state has non-finite entries"),
    "other format version": (lambda s: s.__setitem__("format", 1), "state format 1"),
    "other FMU of the same size": (lambda s: s.__setitem__("fmu", "FhobsObserver_000000000000"),
                                   "it is a state of 'FhobsObserver_000000000000'"),
    "string entries": (lambda s: s["arrays"].__setitem__("h", "0.1"), "h is not an array"),
}


@pytest.mark.parametrize("case", list(STATE_EDITS))
def test_foreign_or_edited_state_is_refused_whole(open_fmu, case):
    """A hand-edited or foreign state is refused with fmi2Error (at fmi2DeSerializeFMUstate, or
    for a well-formed state with uncertified gains at fmi2SetFMUstate) and nothing of it is
    written: the instance's serialized state is unchanged and it steps on as before."""
    edit, words = STATE_EDITS[case]
    clean = open_fmu("observer", "clean")
    clean.start()
    driver = open_fmu("observer")
    driver.start()
    before = serialized(driver)
    data = edited_state(driver, edit)
    try:
        state = driver.fmu.deSerializeFMUstate(data)
    except FMICallException as err:
        assert err.status == FMI_ERROR
    else:
        assert_error(driver, driver.fmu.setFMUstate, state, words=words)
        driver.fmu.freeFMUstate(state)
    assert words in driver.messages[-1][1]
    assert serialized(driver) == before
    assert run_steps(driver) == run_steps(clean)


def test_valid_state_of_another_instance_still_restores(open_fmu):
    """The checks accept a genuine state: instance b takes a's serialized state and continues
    exactly as a does."""
    a, b = open_fmu("observer", "a"), open_fmu("observer", "b")
    a.start({"xi0": 0.4})
    b.start()
    run_steps(a, 2)
    state = b.fmu.deSerializeFMUstate(serialized(a))
    b.fmu.setFMUstate(state)
    b.fmu.freeFMUstate(state)
    assert run_steps(b) == run_steps(a)


def test_serialize_into_a_buffer_of_the_wrong_size_is_an_error(open_fmu):
    """fmi2SerializeFMUstate copies exactly the size fmi2SerializedFMUstateSize reported; any
    other size is refused (pythonfmu read past its bytes or truncated them)."""
    import ctypes

    driver = open_fmu("observer")
    driver.start()
    state = driver.fmu.getFMUstate()
    size = ctypes.c_size_t()
    driver.fmu.fmi2SerializedFMUstateSize(driver.fmu.component, state, ctypes.byref(size))
    for wrong in (size.value - 1, size.value + 64):
        buffer = (ctypes.c_char * wrong)()
        assert_error(driver, driver.fmu.fmi2SerializeFMUstate, driver.fmu.component, state,
                     buffer, wrong, words=f"needs {size.value}")
    assert json.loads(bytes(driver.fmu.serializeFMUstate(state)))["fmu"].startswith("FhobsObs")
    driver.fmu.freeFMUstate(state)


# -- checks that match the spec loader --------------------------------------------------------
@pytest.mark.parametrize(
    ("edit", "words"),
    [
        ({"gamma": -5.0}, "gamma = -5.0 must be > 0"),
        ({"gamma": 0.0}, "gamma = 0.0 must be > 0"),
        ({"rho": 3.0}, "rho = 3.0 must be > gamma/2 = 3.0"),
        ({"nu": -0.9}, "nu = -0.9 is outside [-1/(n_tilde+1), 0)"),
        ({"input_bound": 0.0}, "input_bound = 0.0 must be > 0"),
        ({"input_bound": -1.0}, "input_bound = -1.0 must be > 0"),
    ],
)
def test_tuning_out_of_range_fails_initialisation(open_fmu, edit, words):
    driver = open_fmu("observer")
    driver.fmu.setupExperiment(startTime=0.0)
    for name, value in edit.items():
        driver.fmu.setReal([driver.vr[name]], [value])
    driver.fmu.enterInitializationMode()
    assert_error(driver, driver.fmu.exitInitializationMode, words=words)
    assert_error(driver, driver.fmu.doStep, 0.0, DT,
                 words="fmi2DoStep is not allowed in the state initialisation mode")


@pytest.mark.parametrize("entry", [1e300, -1e300, -1e13])
def test_plant_whose_zoh_has_no_correct_digit_is_an_error(open_fmu, entry):
    """A[1,1] = -1e300 gave finite garbage (expm of the scaled matrix loses every other entry);
    any step with step * ||A||_1 beyond 1e9 is refused, the state kept; a smaller step that
    brings it within the limit is accepted."""
    driver = open_fmu("plant")
    driver.start({"A[1,1]": entry})
    x0 = driver.get("x", (4,))
    assert_error(driver, driver.fmu.doStep, 0.0, DT, words="step * ||A||_1 =")
    np.testing.assert_array_equal(driver.get("x", (4,)), x0)
    if abs(entry) < 1e14:
        driver.fmu.doStep(0.0, 1e-5)


def test_internal_step_larger_than_the_communication_step_is_the_step(open_fmu, tuned_design):
    """h = 0.1 at dt = 1e-3: the runtime steps by min(h, dt), so it gives exactly what h = dt
    gives (and the runtime's step)."""
    y, u = np.array([0.3, -0.2]), np.array([0.1])
    runs = []
    for name, h in (("large", 0.1), ("equal", DT)):
        driver = open_fmu("observer", name)
        driver.start({"h": h})
        driver.set("y", y)
        driver.set("u", u)
        driver.fmu.doStep(0.0, DT)
        runs.append(driver.get("x_hat", (tuned_design.plant.n,)))
    runtime = FilteringObserver(tuned_design.filtering, h=DT, scheme=SCHEMES[0])
    runtime.step(y, u, DT)
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_allclose(runs[1], runtime.x_hat, rtol=0, atol=1e-12)


def test_step_size_the_observer_cannot_follow_is_an_error(open_fmu, tuned_design):
    """At dt = 0.2 no gain level makes the pendulum's sampled observer contract: doStep says so
    (fmi2Error and the reason in the log) instead of running a diverging observer; the state is
    kept and a step the observer can follow still works."""
    driver = open_fmu("observer")
    driver.start()
    assert_error(driver, driver.fmu.doStep, 0.0, 0.2,
                 words="no gain level makes the split step of size 0.2 contractive")
    n = tuned_design.plant.n
    np.testing.assert_array_equal(driver.get("x_hat", (n,)), np.zeros(n))
    driver.fmu.doStep(0.0, DT)


# -- call sequence and messages ---------------------------------------------------------------
def test_call_sequence_is_enforced(open_fmu):
    """A second initialisation mid-run and doStep after fmi2Terminate are refused; the run is
    not disturbed by the refused initialisation."""
    clean = open_fmu("observer", "clean")
    clean.start()
    driver = open_fmu("observer")
    driver.start()
    first = run_steps(driver, 2)
    assert first == run_steps(clean, 2)
    assert_error(driver, driver.fmu.enterInitializationMode,
                 words="fmi2EnterInitializationMode is not allowed in the state step mode")
    assert_error(driver, driver.fmu.exitInitializationMode,
                 words="fmi2ExitInitializationMode is not allowed in the state step mode")
    driver.set("y", np.array([0.3, -0.2]))
    driver.set("u", np.array([0.1]))
    clean.set("y", np.array([0.3, -0.2]))
    clean.set("u", np.array([0.1]))
    driver.fmu.doStep(2 * DT, DT)
    clean.fmu.doStep(2 * DT, DT)
    assert driver.get("x_hat", (4,)).tolist() == clean.get("x_hat", (4,)).tolist()
    driver.fmu.terminate()
    assert_error(driver, driver.fmu.doStep, 3 * DT, DT,
                 words="fmi2DoStep is not allowed in the state terminated")
    driver.fmu.reset()
    driver.start()
    driver.time = 0.0
    assert run_steps(driver, 2) == first


def test_outputs_cannot_be_set(open_fmu):
    driver = open_fmu("observer")
    driver.start()
    vr = driver.vr["x_hat[1]"]
    before = driver.fmu.getReal([vr])
    assert_error(driver, driver.fmu.setReal, [vr], [5.0], words="x_hat[1] (value reference")
    assert "is an output" in driver.messages[-1][1]
    assert driver.fmu.getReal([vr]) == before


def test_messages_are_readable(open_fmu, tuned_design):
    """Numbers appear as Python floats, an uncomputable certificate figure says why."""
    driver = open_fmu("observer")
    driver.start()
    driver.set("y", np.array([np.nan, 0.0]))
    assert_error(driver, driver.fmu.doStep, 0.0, DT, words="input y[1] = nan is not finite")
    other = open_fmu("observer", "p_bar")
    other.fmu.setupExperiment(startTime=0.0)
    for name in names("P_bar", tuned_design.filtering.P_bar.shape):
        other.fmu.setReal([other.vr[name]], [0.0])
    other.fmu.enterInitializationMode()
    assert_error(other, other.fmu.exitInitializationMode,
                 words="lmi_filtering not computable: P_bar is not positive definite")
    assert not re.search(r"\bnan\b", other.messages[-1][1])


# -- declared dependencies --------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["observer", "luenberger", "plant"])
def test_outputs_declare_no_input_dependency(pendulum_fmus, kind):
    description = read_model_description(str(pendulum_fmus[kind]))
    assert description.outputs
    assert all(unknown.dependencies == [] for unknown in description.outputs)


GAIN_LOOP = """
name = "gain loop"
[run]
step = 0.01
stop_time = 0.05
[fmus.a]
block = "gain"
outputs = 1
inputs = 1
start = {{ K = [[0.5]] }}
[fmus.b]
block = "gain"
outputs = 1
inputs = 1
start = {{ K = [[0.5]] }}
[[connections]]
from = "a.y[1]"
to = "b.u[1]"
[[connections]]
from = "b.y[1]"
to = "a.u[1]"
gain = [[{k}]]
"""


def test_loop_of_two_gain_blocks_is_rejected_the_papers_loop_accepted(
    pendulum_fmus, tmp_path
):
    """The gain block declares its feedthrough: a loop through two of them is an algebraic loop
    (a zero gain cuts it). The paper's plant-observer loop, with its gains as gain blocks as in
    the SSP export, is still accepted: the FMUs' outputs depend on no input."""
    from harness.blocks import block_fmu
    from harness.ssp import lower_gains
    from harness.system import DescriptionError, build_blocks, load_system, resolve_system

    cache = tmp_path / "blocks"
    description = read_model_description(str(block_fmu("gain", (2, 3), cache)))
    inputs = [v for v in description.modelVariables if v.causality == "input"]
    assert all(sorted(u.dependencies, key=lambda v: v.name) == inputs
               for u in description.outputs)
    path = tmp_path / "loop.toml"
    path.write_text(GAIN_LOOP.format(k=1.0))
    with pytest.raises(DescriptionError, match=r"algebraic loop.*a\.y\[1\] -> b\.u\[1\]"):
        resolve_system(build_blocks(load_system(path), cache))
    path.write_text(GAIN_LOOP.format(k=0.0))
    resolve_system(build_blocks(load_system(path), cache))
    from harness.cli import SCENARIO_DIR as scenario

    spec = load_system(scenario / "pendulum_perturbed.toml",
                       {"fmu_dir": str(pendulum_fmus["observer"].parent)})
    lowered = build_blocks(lower_gains(spec), cache)
    assert any(fmu.block and fmu.block[0] == "gain" for fmu in lowered.fmus.values())
    assert set(resolve_system(lowered).fmus) >= {"plant", "observer"}
