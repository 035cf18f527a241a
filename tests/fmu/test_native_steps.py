"""Native FMUs under the steps real hosts send: any positive finite step, computed plans.

The C test host (``tests/native_host.c``, no Python in its process) drives the native observer,
Luenberger observer and plant with host-like step patterns: time accumulated in floating point
(t += 2e-4 for 1 s, the last step cut to the stop time, 7.7e-14 s, as OMSimulator does),
seeded variable steps, and step sizes the FMU never saw before. Its outputs must equal, to
1e-12 relative, the pythonfmu FMU's under fmpy and the numpy runtime's (the models of
fhobs.core stepped with the same steps, without the compiled kernel). fmpy's own master
(``simulate_fmu``) runs the native observer with other output intervals, without one and with
a start time of 0.3, as it runs the pythonfmu observer.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import fmu_fixtures
import numpy as np
import pytest
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver, LuenbergerObserver
from fmpy import extract, simulate_fmu
from fmu_fixtures import NOISE_AMPLITUDE, NOISE_SEED, PENDULUM_X0, FmuDriver, H, random_walk
from host_runner import read_outputs
from reference_math import relative

pytestmark = pytest.mark.skipif(
    sys.platform != "linux" or shutil.which("cc") is None,
    reason="native FMUs are built for linux64 with cc",
)

KINDS = ("observer", "luenberger", "plant")
RTOL = 1e-12


def accumulated_steps(step: float, stop: float) -> np.ndarray:
    """A host's steps: t += step in floating point, the last step cut to the stop time."""
    steps, t = [], 0.0
    while t < stop:
        dt = min(step, stop - t)
        steps.append(dt)
        t += dt
    return np.array(steps)


def variable_steps(seed: int, count: int) -> np.ndarray:
    """Seeded step sizes, log-uniform in [1e-5, 3e-3] (each one new), and a 3e-13 s step."""
    steps = np.exp(np.random.default_rng(seed).uniform(np.log(1e-5), np.log(3e-3), count))
    steps[count // 2] = 3e-13
    return steps


PATTERNS = {"accumulated 2e-4 to 1 s": accumulated_steps(2e-4, 1.0),
            "variable": variable_steps(5, 80)}


def signals(kind: str, steps: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Seeded random-walk inputs: the observers' (y, u), the plant's (u, q)."""
    if kind == "plant":
        return {"u": random_walk(seed, steps, 1, 0.3), "q": random_walk(seed + 1, steps, 1, 0.1)}
    return {"y": 1.0 + random_walk(seed, steps, 2, 0.05),
            "u": random_walk(seed + 1, steps, 1, 0.3)}


def host_rows(host: Path, fmu: Path, names: list[str], inputs: np.ndarray, steps: np.ndarray,
              tmp_path: Path) -> tuple[list[str], np.ndarray]:
    """The outputs (after initialisation and each step) of the native FMU run by the C host
    with an empty environment, its steps from the input rows (STEP '-')."""
    folder = tmp_path / "fmu"
    with zipfile.ZipFile(fmu) as archive:
        archive.extractall(folder)
    rows = np.column_stack([np.zeros(len(inputs)), np.append(steps, 0.0), inputs])
    with (tmp_path / "in.csv").open("w") as f:
        f.write(",".join(["time", "step", *names]) + "\n")
        for row in rows:
            f.write(",".join(repr(float(v)) for v in row) + "\n")
    done = subprocess.run([str(host), str(folder), str(tmp_path / "in.csv"),
                           str(tmp_path / "out.csv"), "-"], env={}, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    columns, out = read_outputs(tmp_path / "out.csv")
    assert np.array_equal(out[:, 0], np.concatenate(([0.0], np.cumsum(steps))))
    return columns, out[:, 1:]


def fmpy_rows(fmu: Path, columns: list[str], names: list[str], inputs: np.ndarray,
              steps: np.ndarray, tmp_path: Path) -> np.ndarray:
    """The same run of the pythonfmu FMU under fmpy (the host's communication points)."""
    driver = FmuDriver(fmu, extract(str(fmu), str(tmp_path / "pythonfmu")), "pythonfmu")
    driver.start()
    ins = [driver.vr[name] for name in names]
    outs = [driver.vr[name] for name in columns]
    rows, t = [driver.fmu.getReal(outs)], 0.0
    for values, dt in zip(inputs, steps, strict=False):
        driver.fmu.setReal(ins, values.tolist())
        driver.fmu.doStep(t, dt)
        t += dt
        rows.append(driver.fmu.getReal(outs))
    driver.fmu.freeInstance()
    return np.array(rows)


def named(values: dict[str, np.ndarray | float]) -> dict[str, float]:
    """Scalar variable names (``x_hat[1]``, ``xi``) of array values."""
    out = {}
    for base, value in values.items():
        value = np.atleast_1d(value)
        if np.ndim(values[base]) == 0:
            out[base] = float(value[0])
        else:
            out.update({f"{base}[{i + 1}]": float(v) for i, v in enumerate(value)})
    return out


def runtime_rows(kind: str, gains, columns: list[str], inputs: dict[str, np.ndarray],
                 steps: np.ndarray) -> np.ndarray:
    """The same run of the numpy runtime (no compiled kernel): the FMU's outputs ``columns``."""
    if kind == "plant":
        model = LTIPlant(gains.plant.A, gains.plant.B, gains.plant.C, E=gains.plant.E,
                         x0=PENDULUM_X0, noise_amplitude=NOISE_AMPLITUDE, seed=NOISE_SEED,
                         kernel=False)
        pairs = zip(inputs["u"], inputs["q"], strict=True)

        def outputs() -> dict[str, float]:
            return named({"y": model.y, "x": model.x})
    else:
        if kind == "observer":
            model = FilteringObserver(gains.filtering, h=H, kernel=False)
        else:
            model = LuenbergerObserver(gains.luenberger, h=H, kernel=False)
        pairs = zip(inputs["y"], inputs["u"], strict=True)

        def outputs() -> dict[str, float]:
            values = {"x_hat": model.x_hat}
            if kind == "observer":
                d = model.diagnostics()
                values.update(q_hat=model.z[gains.plant.n:], psi=d["psi"], xi=d["xi"],
                              sigma=d["sigma"])
            return named(values)

    rows = [outputs()]
    for (a, b), dt in zip(pairs, steps, strict=False):
        model.step(a, b, dt)
        rows.append(outputs())
    return np.array([[row[name] for name in columns] for row in rows])


@pytest.mark.parametrize(("kind", "pattern"), [
    # the observer's 80 new step sizes, ~7 s: slow; the fast tests keep the observer under the
    # accumulated steps (its last step 7.7e-14 s) and under simulate_fmu's several step sizes,
    # and the Luenberger observer and the plant under these variable steps
    pytest.param(kind, pattern, marks=pytest.mark.slow if
                 (kind, pattern) == ("observer", "variable") else ())
    for kind in KINDS for pattern in sorted(PATTERNS)])
def test_c_host_steps_agree_with_pythonfmu_and_the_runtime(native_host, native_fmus,
                                                            pendulum_fmus, kalman_design, kind,
                                                            pattern, tmp_path):
    steps = PATTERNS[pattern]
    inputs = signals(kind, len(steps) + 1, seed=12)
    names = [label for name, values in inputs.items()
             for label in fmu_fixtures.names(name, values.shape[1:])]
    table = np.hstack(list(inputs.values()))
    columns, native = host_rows(native_host, native_fmus[kind], names, table, steps, tmp_path)
    python = fmpy_rows(pendulum_fmus[kind], columns, names, table, steps, tmp_path)
    numpy_runtime = runtime_rows(kind, kalman_design, columns, inputs, steps)
    assert relative(native, python) <= RTOL
    assert relative(native, numpy_runtime) <= RTOL
    assert native.shape == (len(steps) + 1, len(columns))


def observer_input(start: float, stop: float) -> np.ndarray:
    """A measured signal for simulate_fmu (fmpy interpolates it): a decaying swing."""
    time = np.linspace(start, stop, 401)
    signal = np.zeros(time.size, dtype=[("time", float), ("y[1]", float), ("y[2]", float),
                                        ("u[1]", float)])
    signal["time"] = time
    signal["y[1]"] = 0.5 * np.exp(-time) * np.cos(6.0 * time)
    signal["y[2]"] = -3.0 * np.exp(-time) * np.sin(6.0 * time)
    signal["u[1]"] = 0.2 * np.sin(2.0 * time)
    return signal


@pytest.mark.parametrize("call", [
    # 5000 and 14 286 steps (1.7 s, 3 s): slow; the default and the start-0.3 grids give the
    # observer other new step sizes in the fast tests
    pytest.param({"stop_time": 1.0, "output_interval": 2e-4}, marks=pytest.mark.slow),
    pytest.param({"stop_time": 1.0, "output_interval": 7e-5}, marks=pytest.mark.slow),
    {"stop_time": 1.0},
    {"start_time": 0.3, "stop_time": 1.3, "output_interval": 1e-3},
], ids=["2e-4", "7e-5", "default-interval", "start-0.3"])
def test_fmpy_simulate_fmu_runs_the_native_observer_as_the_pythonfmu_one(native_fmus,
                                                                         pendulum_fmus, call):
    """fmpy's own master forms its steps from its own time grid (t_k+1 - t_k in floating
    point, several distinct sizes); the native observer takes them all."""
    signal = observer_input(call.get("start_time", 0.0), call["stop_time"])
    results = [simulate_fmu(str(fmus["observer"]), input=signal,
                            start_values={"z0[1]": 0.4, "z0[3]": -1.0}, **call)
               for fmus in (native_fmus, pendulum_fmus)]
    native, python = (np.column_stack([r[name] for name in r.dtype.names]) for r in results)
    assert native.shape == python.shape and native.shape[0] > 100
    assert relative(native, python) <= RTOL
