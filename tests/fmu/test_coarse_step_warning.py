"""An observer FMU whose communication step is longer than its design's max_communication_step
(fhobs.design.settling.communication_step_bracket, recorded in the design) answers that step
once with fmi2Warning and a message naming both steps, in both builds; and a host replaying a
fine-step closed loop into the FMU with fmpy.simulate_fmu (inputs y, u held over each
communication step) gets the fine loop's estimate at the fine step and an estimate settling
within the design's factor at 0.01 s, without a warning.

The fine loop is written out here: the plant stepped by scipy's matrix exponential, the runtime
fed y and u of each step's start, u = K x_hat with the paper's K."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import fmpy
import numpy as np
import pytest
import scipy.linalg
from fhobs.core.gains import ObserverDesign
from fhobs.core.runtime import FilteringObserver
from fhobs.design.settling import HELD_SLOWDOWN, SETTLED
from fhobs.paper import EXAMPLES, H_PAPER, K_PAPER, X0_PAPER
from fmpy import extract
from fmpy.fmi2 import fmi2OK, fmi2Warning
from fmu_fixtures import FmuDriver

FINE = 1e-3
"""The recorded loop's step (s)."""
STOP = 3.0
COARSE = 0.05
"""A communication step above the pendulum's figure (0.0259 s)."""


def _native_available() -> bool:
    return shutil.which("cc") is not None


@pytest.fixture(scope="module")
def recorded(kalman_design: ObserverDesign) -> dict[str, np.ndarray]:
    """The fine closed loop of the paper's scenario: t, y, u, x and the estimate, every 1 ms."""
    gains = kalman_design.filtering
    A, B, C = gains.plant.A, gains.plant.B, gains.plant.C
    n, m = B.shape
    block = scipy.linalg.expm(np.block([[A, B], [np.zeros((m, n + m))]]) * FINE)
    Phi, Gamma = block[:n, :n], block[:n, n:]
    observer = FilteringObserver(gains, h=H_PAPER)
    steps = round(STOP / FINE)
    x = X0_PAPER.copy()
    rows = {name: [] for name in ("y", "u", "x", "x_hat")}
    for _ in range(steps + 1):
        u = K_PAPER @ observer.x_hat
        rows["y"].append(C @ x)
        rows["u"].append(u)
        rows["x"].append(x)
        rows["x_hat"].append(observer.x_hat.copy())
        observer.step(C @ x, u, FINE)
        x = Phi @ x + Gamma @ u
    return {"t": np.arange(steps + 1) * FINE, **{k: np.array(v) for k, v in rows.items()}}


def replay(path: Path, data: dict[str, np.ndarray],
           step: float) -> tuple[np.ndarray, list[tuple[int, str]], np.ndarray]:
    """fmpy.simulate_fmu of the observer FMU at ``step`` on the recorded y and u: the
    estimation error at every communication point, the FMU's log messages (status, text) and
    the communication points."""
    names = ["y[1]", "y[2]", "u[1]"]
    signals = np.zeros(data["t"].size, dtype=[("time", float)] + [(n, float) for n in names])
    signals["time"] = data["t"]
    for i, name in enumerate(names):
        signals[name] = np.hstack([data["y"], data["u"]])[:, i]
    messages: list[tuple[int, str]] = []
    result = fmpy.simulate_fmu(
        str(path), input=signals, output_interval=step, stop_time=STOP,
        output=[f"x_hat[{i}]" for i in range(1, 5)],
        logger=lambda env, name, status, category, text: messages.append(
            (int(status), text.decode())))
    x_hat = np.column_stack([result[f"x_hat[{i}]"] for i in range(1, 5)])
    rows = np.rint(result["time"] / FINE).astype(int)
    return x_hat - data["x"][rows], messages, result["time"]


def settling(times: np.ndarray, errors: np.ndarray) -> float:
    """Time after which |e| stays below SETTLED |x(0)| (inf if it is above at the end)."""
    above = np.nonzero(np.linalg.norm(errors, axis=1) > SETTLED * np.linalg.norm(X0_PAPER))[0]
    if above.size and above[-1] == times.size - 1:
        return math.inf
    return float(times[above[-1] + 1]) if above.size else 0.0


def warnings_of(messages: list[tuple[int, str]]) -> list[str]:
    return [text for status, text in messages if status == fmi2Warning]


def test_the_figure_is_written_into_the_observer_fmus(kalman_design, pendulum_fmus):
    figure = kalman_design.filtering.max_communication_step
    assert FINE < 0.01 < figure < COARSE
    description = fmpy.read_model_description(str(pendulum_fmus["observer"]))
    variable = {v.name: v for v in description.modelVariables}["max_communication_step"]
    assert float(variable.start) == pytest.approx(figure, rel=1e-15)
    assert (variable.causality, variable.variability, variable.unit) == ("parameter", "fixed",
                                                                          "s")
    assert variable.valueReference == max(v.valueReference for v in description.modelVariables)


def test_fmpy_feeds_each_steps_start_inputs(recorded, pendulum_fmus):
    """At the recorded loop's own step the replay is the loop's estimate: fmpy sets y and u of
    the step's start (no lead, no interpolation within the step)."""
    errors, messages, times = replay(pendulum_fmus["observer"], recorded, FINE)
    rows = np.rint(times / FINE).astype(int)
    expected = recorded["x_hat"][rows] - recorded["x"][rows]
    np.testing.assert_allclose(errors, expected, rtol=1e-9, atol=1e-9 * np.abs(X0_PAPER).max())
    assert warnings_of(messages) == []


def test_the_users_replay_at_10_ms_settles_within_the_designs_factor(recorded, pendulum_fmus):
    fine_errors, _, fine_times = replay(pendulum_fmus["observer"], recorded, FINE)
    errors, messages, times = replay(pendulum_fmus["observer"], recorded, 0.01)
    fine = settling(fine_times, fine_errors)
    assert 0.0 < fine < 1.0
    assert settling(times, errors) <= HELD_SLOWDOWN * fine
    assert warnings_of(messages) == []


def test_the_replay_above_the_figure_warns_once_and_settles_later(recorded, pendulum_fmus):
    fine_errors, _, fine_times = replay(pendulum_fmus["observer"], recorded, FINE)
    errors, messages, times = replay(pendulum_fmus["observer"], recorded, COARSE)
    assert settling(times, errors) > settling(fine_times, fine_errors)
    assert len(warnings_of(messages)) == 1


def _drive(path: Path, tmp_path: Path, step: float, steps: int,
           parameters: dict | None = None) -> tuple[list[int], list[str]]:
    """Step a fresh instance ``steps`` times at ``step``: the statuses and the warnings."""
    driver = FmuDriver(path, extract(str(path), str(tmp_path / f"unzip_{step}")))
    driver.start(parameters)
    fmu = driver.fmu
    statuses = [fmu.fmi2DoStep(fmu.component, k * step, step, 1) for k in range(steps)]
    fmu.terminate()
    fmu.freeInstance()
    return statuses, warnings_of(driver.messages)


def _builds(pendulum_fmus, request) -> dict[str, Path]:
    builds = {"pythonfmu": pendulum_fmus["observer"]}
    if _native_available():
        builds["native"] = request.getfixturevalue("native_fmus")["observer"]
    return builds


def test_a_coarse_step_is_warned_of_once_in_both_builds(kalman_design, pendulum_fmus, request,
                                                        tmp_path):
    figure = kalman_design.filtering.max_communication_step
    texts = {}
    for build, path in _builds(pendulum_fmus, request).items():
        statuses, warnings = _drive(path, tmp_path / build, COARSE, 6)
        assert statuses == [fmi2Warning] + [fmi2OK] * 5, build
        assert len(warnings) == 1, build
        texts[build] = warnings[0]
    for text in texts.values():
        assert text.startswith(f"communication step {COARSE:.3g} s is longer than the "
                               f"{figure:.3g} s")
        assert "max_communication_step" in text
    assert len(set(texts.values())) == 1  # the same message in both builds


def test_no_warning_at_the_fine_step_or_with_the_check_off(pendulum_fmus, request, tmp_path):
    for build, path in _builds(pendulum_fmus, request).items():
        statuses, warnings = _drive(path, tmp_path / build, FINE, 20)
        assert statuses == [fmi2OK] * 20 and warnings == [], build
        statuses, warnings = _drive(path, tmp_path / f"{build}_off", COARSE, 3,
                                    {"max_communication_step": 0.0})
        assert statuses == [fmi2OK] * 3 and warnings == [], build


def test_the_harness_default_steps_are_within_every_bundled_designs_figure():
    """harness plant steps at the spec's [noise] sample time, else 1 ms; the paper's scenarios
    at H_PAPER: none of the bundled examples' FMUs warns there."""
    from fhobs.design.observer import design_for_spec
    from fhobs.design.spec import load_spec

    for path in sorted(Path(EXAMPLES).glob("**/*.toml")):
        spec = load_spec(path)
        step = spec.noise.sample_time if spec.noise is not None else 1e-3
        figure = design_for_spec(spec).filtering.max_communication_step
        assert max(step, H_PAPER) <= figure, path.name
