"""The pendulum FMUs built with and without the compiled step kernel (the numpy fallback):
the kernel is shipped only when asked, and both builds give the numpy runtime's results (the
fallback bit for bit, the kernel to round-off, ``RTOL``) on a representative part of test_fmu's
behaviour."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from fhobs.build import build_fmus
from fhobs.core import kernel
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver
from fmpy import extract
from fmu_fixtures import (
    NOISE_AMPLITUDE,
    NOISE_SEED,
    PENDULUM_X0,
    FmuDriver,
    H,
    assert_error,
    plant_measurements,
    random_walk,
    steps_until_error,
)
from reference_math import relative

if kernel.library() is None:
    pytest.skip("no compiled kernel on this machine (needs Linux and cc)",
                allow_module_level=True)

RTOL = 1e-12
"""Largest relative difference of the kernel's results from numpy's (round-off)."""


@pytest.fixture(scope="module")
def fmu_pair(tmp_path_factory, tuned_design, pendulum_fmus):
    """The pendulum FMUs built with and without the kernel: kind -> (path, unzip dir). With the
    kernel: those of ``pendulum_fmus`` (same options, the kernel shipped by default where it
    compiles, as this module requires; its Kalman filter changes only kalman.fmu, not taken)."""
    fmus = build_fmus(tuned_design, tmp_path_factory.mktemp("kernel_False"), x0=PENDULUM_X0,
                      noise_amplitude=NOISE_AMPLITUDE, noise_seed=NOISE_SEED, h=H, kernel=False)
    return {False: {kind: (path, extract(str(path))) for kind, path in fmus.items()},
            True: {kind: (pendulum_fmus[kind], extract(str(pendulum_fmus[kind])))
                   for kind in fmus}}


@pytest.fixture
def open_pair(fmu_pair):
    opened = []

    def factory(with_kernel: bool, kind: str, name: str = "instance") -> FmuDriver:
        path, folder = fmu_pair[with_kernel][kind]
        opened.append(FmuDriver(path, folder, name))
        return opened[-1]

    yield factory
    for driver in opened:
        driver.fmu.freeInstance()


def test_kernel_is_shipped_only_when_asked(fmu_pair):
    for with_kernel, fmus in fmu_pair.items():
        for path, _ in fmus.values():
            with zipfile.ZipFile(path) as z:
                shipped = [n for n in z.namelist() if n.endswith(kernel.SHIPPED.name)]
            assert len(shipped) == (1 if with_kernel else 0)


def test_fallback_fmus_equal_the_numpy_runtime_and_the_kernel_fmus(open_pair, tuned_design):
    g, dt = tuned_design, 1e-3
    ys, us = plant_measurements(g, 8, 120, dt)
    runtime = FilteringObserver(g.filtering, h=H, kernel=False)
    drivers = [open_pair(False, "observer"), open_pair(True, "observer", "k")]
    for driver in drivers:
        driver.start()
    for step, (y, u) in enumerate(zip(ys, us, strict=True)):
        runtime.step(y, u, dt)
        outputs = []
        for driver in drivers:
            driver.set("y", y)
            driver.set("u", u)
            driver.fmu.doStep(step * dt, dt)
            outputs.append(np.concatenate([driver.get("x_hat", (g.plant.n,)),
                                           driver.get("psi", (g.plant.k,)),
                                           driver.get("xi", ()).ravel()]))
        expected = np.concatenate([runtime.x_hat, runtime.diagnostics()["psi"],
                                   [runtime.diagnostics()["xi"]]])
        np.testing.assert_array_equal(outputs[0], expected)
        assert relative(outputs[1], expected) <= RTOL


@pytest.mark.parametrize("with_kernel", [False, True])
def test_fmu_plant_equals_runtime_and_replays_bit_identically(open_pair, tuned_design,
                                                             with_kernel):
    g, dt = tuned_design, 1e-3
    us, qs = random_walk(9, 40, g.plant.m, 0.1), random_walk(10, 40, g.plant.E.shape[1], 0.1)
    driver = open_pair(with_kernel, "plant")
    driver.start()
    plant = LTIPlant(g.plant.A, g.plant.B, g.plant.C, g.plant.E, x0=PENDULUM_X0,
                     noise_amplitude=NOISE_AMPLITUDE,
                     seed=NOISE_SEED, kernel=with_kernel)

    def run(steps):
        rows = []
        for k in steps:
            driver.set("u", us[k])
            driver.set("q", qs[k])
            driver.fmu.doStep(k * dt, dt)
            rows.append(np.concatenate([driver.get("x", (g.plant.n,)),
                                        driver.get("y", (g.plant.k,))]))
        return np.array(rows)

    for k, row in zip(range(20), run(range(20)), strict=True):
        plant.step(us[k], qs[k], dt)
        np.testing.assert_array_equal(row, np.concatenate([plant.x, plant.y]))
    state = driver.fmu.getFMUstate()
    first = run(range(20, 40))
    driver.fmu.setFMUstate(state)
    np.testing.assert_array_equal(run(range(20, 40)), first)
    driver.fmu.freeFMUstate(state)


@pytest.mark.parametrize("with_kernel", [False, True])
def test_fmu_bad_input_and_overflow_are_errors_state_kept(open_pair, tuned_design, with_kernel):
    g = tuned_design
    observer = open_pair(with_kernel, "observer")
    observer.start()
    observer.set("y", [np.nan, 0.0])
    assert_error(observer, observer.fmu.doStep, 0.0, 1e-3, words="y[1]")
    observer.set("y", [0.1, 0.2])
    observer.fmu.doStep(0.0, 1e-3)  # still usable
    C = g.plant.C.copy()
    C[0, 0] = 1.7e308
    plant = open_pair(with_kernel, "plant", "p")
    plant.start({"C": C, "x0": np.ones(g.plant.n)})
    refs = [plant.vr[f"x[{i + 1}]"] for i in range(g.plant.n)]
    with np.errstate(over="ignore"):
        k, before = steps_until_error(plant, 1e-2, lambda: plant.fmu.getReal(refs))
    assert k > 0
    assert plant.fmu.getReal(refs) == before
