"""The native FMUs' step planner (fhobs/native/planner.c, gain_levels.c) against the numpy
runtime's plans (``kernel.Stepper.plan``, read by :func:`fhobs.native.build.captured_plan`),
for the paper's pendulum, the bundled examples and seeded random designs, step sizes
log-spaced from 1e-6 to 1e-1:

- the ZOH matrices (M, F; the plant's Phi, Gamma_B, Gamma_E) agree to 1e-12 relative
  (norm-wise per matrix), or, where numpy's own result is further than that from the exact
  exponential (scaling and squaring multiplies the rounding of the Pade step by up to
  2^squarings: stiff designs at large steps), to ``ULP_FACTOR`` times numpy's own error or
  eps times the exponential's condition number (maglev's Luenberger hold at dt = 0.03:
  condition 1.1e6, numpy 7.9e-13 and C 7.0e-12 from the 30-digit exponential);
- the gain-level floor and ceiling are equal (to 1e-12 relative), and the C planner refuses a
  step size exactly when the numpy runtime does. Both read the tau scan's radii only where
  double precision can decide them (the levels the observer uses, within the dilation's
  conditioning band); elsewhere the radii are round-off (numpy itself finds 1.12 and 0.999998
  for one of quarter_car's with two BLAS kernels), so the ceilings agree on any machine; the
  ceiling is never below the floor.
"""

from __future__ import annotations

import math
import shutil
import sys

import numpy as np
import pytest
import scipy.linalg
from designs import ZOO, random_design, zoo_design
from fhobs.core.gains import ObserverDesign
from fhobs.core.plant import LTIPlant
from fhobs.core.runtime import FilteringObserver, LuenbergerObserver, PrescribedTimeObserver
from fhobs.native.build import captured_plan
from fhobs.native.planner import c_plan, design_data

pytestmark = pytest.mark.skipif(
    sys.platform != "linux" or shutil.which("cc") is None,
    reason="the planner is compiled with cc on linux",
)

RTOL = 1e-12
ULP_FACTOR = 4
EPS = float(np.finfo(float).eps)
STEPS = tuple(float(dt) for dt in np.geomspace(1e-6, 1e-1, 11))
"""Communication step sizes, log-spaced (none of them a step size the FMUs used to be built
for)."""
FIELDS = {"observer": ("M", "F", "floor_level", "ceiling"),
          "prescribed_time": ("M", "F", "floor_level", "ceiling"), "luenberger": ("M",),
          "plant": ("Phi", "Gamma_B", "Gamma_E")}
RANDOM_CASES = [(0, 4, 2, 0), (1, 6, 3, 0), (2, 8, 2, 1), (4, 10, 3, 1), (7, 6, 2, 0)]
"""(seed, n, k, disturbance order) of :func:`random_design`."""
def models(gains: ObserverDesign) -> dict[str, object]:
    """The runtime models whose plans the native FMUs compute."""
    return {"observer": FilteringObserver(gains.filtering),
            "luenberger": LuenbergerObserver(gains.luenberger),
            "plant": LTIPlant(gains.plant.A, gains.plant.B, gains.plant.C, E=gains.plant.E),
            "prescribed_time": PrescribedTimeObserver(gains.prescribed_time)}


def relative(a: np.ndarray | float, b: np.ndarray | float) -> float:
    """``||a - b|| / ||b||`` (Frobenius; 0 for equal entries, also infinite or empty ones)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        return math.inf
    same = (a == b) | (np.isnan(a) & np.isnan(b))
    if same.all():
        return 0.0
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return math.inf
    scale = np.linalg.norm(b)
    return float(np.linalg.norm(a - b) / scale) if scale else math.inf


def exact_zoh(kind: str, model: object, dt: float) -> np.ndarray:
    """The first rows of the exponential of the ZOH's augmented matrix, to 30 digits
    (mpmath), rounded to doubles."""
    mpmath = pytest.importorskip("mpmath")
    top = np.asarray(design_data(kind, model)["top"], dtype=float)
    n, size = top.shape
    aug = np.zeros((size, size))
    aug[:n] = dt * top
    with mpmath.workdps(30):
        exact = mpmath.expm(mpmath.matrix(aug.tolist()))
        return np.array(exact.tolist(), dtype=float)[:n]


def zoh_error(kind: str, model: object, dt: float, plan: dict, reference: dict) -> float:
    """The C plan's largest relative difference from numpy's ZOH matrices, divided by
    ``RTOL`` or, where numpy's own rounding error (against the 30-digit exponential) is
    larger, by ``ULP_FACTOR`` times that error."""
    names = [name for name in FIELDS[kind] if name not in ("floor_level", "ceiling")]
    error = max(relative(plan[name], reference[name]) for name in names)
    if error <= RTOL:
        return error / RTOL
    first = "M" if kind != "plant" else None
    numpy_rows = reference[first] if first else np.hstack([reference[name] for name in names])
    own = relative(numpy_rows, exact_zoh(kind, model, dt))
    return error / max(RTOL, ULP_FACTOR * own, EPS * exponential_condition(kind, model, dt))


def exponential_condition(kind: str, model: object, dt: float) -> float:
    """The relative condition number of the ZOH's augmented exponential (scipy's
    ``expm_cond``): two correctly rounded-off computations of it may differ by eps times it."""
    top = np.asarray(design_data(kind, model)["top"], dtype=float)
    n, size = top.shape
    aug = np.zeros((size, size))
    aug[:n] = dt * top
    return float(scipy.linalg.expm_cond(aug))


def plan_errors(gains: ObserverDesign) -> dict[tuple[str, float], float]:
    """Per kind and step size, the largest relative difference of the C plan's fields from the
    numpy runtime's, divided by its tolerance (module docstring): at most 1 where they agree
    (0 where both refuse the step size, inf where only one does)."""
    errors = {}
    for kind, model in models(gains).items():
        for dt in STEPS:
            try:
                reference = captured_plan(model, dt)
            except ValueError as err:
                assert "no gain level makes the split step" in str(err)
                reference = None
            try:
                plan = c_plan(kind, model, dt)
            except ValueError as err:
                assert f"of size {dt!r} contractive (smallest spectral radius" in str(err)
                plan = None
            if plan is None or reference is None:
                errors[kind, dt] = 0.0 if plan is reference else math.inf
                continue
            error = zoh_error(kind, model, dt, plan, reference)
            if kind in ("observer", "prescribed_time"):
                assert 0.0 < plan["floor_level"] <= plan["ceiling"], (kind, dt)
                error = max([error] + [relative(plan[name], reference[name]) / RTOL
                                       for name in ("floor_level", "ceiling")])
            errors[kind, dt] = error
    return errors


def assert_plans_agree(gains: ObserverDesign) -> None:
    errors = plan_errors(gains)
    worst = max(errors, key=errors.get)
    assert errors[worst] <= 1.0, (worst, errors[worst])


def test_pendulum_paper_gains(paper_design):
    assert_plans_agree(paper_design)


def test_pendulum_plans_are_followed_at_every_step_size(paper_design):
    """The pendulum's observer follows every step size of the scan (none refused), so the
    comparison above covers the floor and the ceiling at each of them."""
    observer = FilteringObserver(paper_design.filtering)
    for dt in STEPS:
        plan = c_plan("observer", observer, dt)
        assert 0.0 < plan["floor_level"] <= plan["ceiling"]


def test_prescribed_time_refuses_what_the_runtime_refuses(paper_design):
    """dt = 0.1 for the paper's pendulum: the prescribed-time observer's scan finds no
    contractive level in C as in numpy, and names the same smallest spectral radius."""
    observer = PrescribedTimeObserver(paper_design.prescribed_time)
    with pytest.raises(ValueError) as numpy_error:
        captured_plan(observer, 0.1)
    with pytest.raises(ValueError) as c_error:
        c_plan("prescribed_time", observer, 0.1)
    assert str(c_error.value) == str(numpy_error.value).split("; use")[0]


@pytest.mark.parametrize("name", [
    "maglev", *(pytest.param(name, marks=pytest.mark.slow)
                for name in ("pendulum", "triple_integrator"))])
def test_bundled_examples(name):
    assert_plans_agree(zoo_design(name))


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(ZOO) - {"pendulum", "triple_integrator",
                                                     "maglev"}))
def test_bundled_examples_all(name):
    assert_plans_agree(zoo_design(name))


@pytest.mark.parametrize("case", [
    RANDOM_CASES[0], pytest.param(RANDOM_CASES[1], marks=pytest.mark.slow)])
def test_random_designs(case):
    assert_plans_agree(random_design(*case))


@pytest.mark.slow
@pytest.mark.parametrize("case", RANDOM_CASES[2:])
def test_random_designs_all(case):
    assert_plans_agree(random_design(*case))


def test_a_step_the_observer_cannot_follow_is_refused_by_both():
    """dt = 0.5 for the tuned pendulum: no gain level contracts; the C planner names the
    same smallest spectral radius as the numpy runtime (to its 6 digits)."""
    observer = FilteringObserver(zoo_design("pendulum").filtering)
    with pytest.raises(ValueError) as numpy_error:
        captured_plan(observer, 0.5)
    with pytest.raises(ValueError) as c_error:
        c_plan("observer", observer, 0.5)
    assert str(c_error.value) == str(numpy_error.value).split("; use")[0]
