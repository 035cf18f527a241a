"""The plans of the homogeneous observers' step sizes under a new size at every step: the tau
scan made once per bin of sizes (``fhobs.core.runtime.size_bin``) and checked at each size,
in the numpy runtime and the native planner (``fhobs.native.planner``) alike, with at most
``BIN_CACHE_SIZE`` bins' scans kept (docs/theory.md, "Variable communication steps").
"""

from __future__ import annotations

import math
import shutil
import sys
from collections import OrderedDict

import numpy as np
import pytest
from fhobs.core.runtime import (
    BIN_CACHE_SIZE,
    SIZE_BINS_PER_OCTAVE,
    TAU_GRID,
    FilteringObserver,
    PrescribedTimeObserver,
    size_bin,
)

RTOL = 1e-12
LOW, HIGH = 1e-6, 1e-3
"""The new sizes' range: 10 octaves, 80 bins, more than the caches keep."""


def new_sizes(seed: int, count: int) -> list[float]:
    """``count`` distinct step sizes, log-uniform in [LOW, HIGH] (seeded)."""
    sizes = np.exp(np.random.default_rng(seed).uniform(np.log(LOW), np.log(HIGH), count))
    assert np.unique(sizes).size == count
    return sizes.tolist()


def lru_misses(keys: list[float], capacity: int) -> int:
    """How often a least-recently-used cache of ``capacity`` keys misses over ``keys``."""
    cache: OrderedDict[float, None] = OrderedDict()
    misses = 0
    for key in keys:
        if key in cache:
            cache.move_to_end(key)
            continue
        misses += 1
        if len(cache) >= capacity:
            cache.popitem(last=False)
        cache[key] = None
    return misses


def test_size_bins_cut_each_octave_into_equal_parts():
    """The representatives are the upper ends ``(j / 16) 2^e`` (j = 9..16) of the octave's
    parts, and each size lies in its representative's part ``[(j - 1) / 16, j / 16) 2^e``."""
    parts = 2 * SIZE_BINS_PER_OCTAVE
    for dt in np.exp(np.random.default_rng(3).uniform(np.log(1e-9), np.log(1e3), 2000)):
        representative = size_bin(float(dt))
        fraction, exponent = math.frexp(representative)
        if fraction == 0.5:  # the octave's top part ends at the next power of two
            fraction, exponent = 1.0, exponent - 1
        j = fraction * parts
        assert j == int(j) and SIZE_BINS_PER_OCTAVE < j <= parts
        assert (j - 1) / j * representative <= dt < representative


def test_sizes_of_one_bin_share_a_representative():
    edges = [math.ldexp(0.5 + j / (2 * SIZE_BINS_PER_OCTAVE), -10) for j in range(9)]
    for lower, upper in zip(edges[:-1], edges[1:], strict=True):
        inside = np.linspace(lower, upper, 50, endpoint=False).tolist()
        assert {size_bin(dt) for dt in inside} == {upper}


def runtime_models(design, kernel: bool = True) -> dict[str, object]:
    return {"observer": FilteringObserver(design.filtering, kernel=kernel),
            "prescribed_time": PrescribedTimeObserver(design.prescribed_time, kernel=kernel)}


@pytest.mark.parametrize("kind", ["observer", "prescribed_time"])
def test_new_sizes_scan_once_per_bin_within_the_bound(kind, kalman_design):
    """200 distinct sizes over 80 bins: the scans are the misses of a least-recently-used
    cache of BIN_CACHE_SIZE bins, plus the few sizes whose own check refuses their bin's
    taus; at most BIN_CACHE_SIZE bins are kept."""
    model = runtime_models(kalman_design, kernel=False)[kind]
    sizes = new_sizes(6, 200)
    for dt in sizes:
        model.cap(dt)
    info = model.plan_cache_info()
    misses = lru_misses([size_bin(dt) for dt in sizes], BIN_CACHE_SIZE)
    assert len({size_bin(dt) for dt in sizes}) > BIN_CACHE_SIZE  # the cache overflows
    assert info.bins == info.max_bins == BIN_CACHE_SIZE
    assert misses <= info.scans <= misses + len(sizes) // 10, (info, misses)


@pytest.mark.parametrize("kind", ["observer", "prescribed_time"])
def test_every_level_in_use_contracts_at_its_own_size(kind, kalman_design):
    """The floor, the (finite) ceiling and the grid's levels between them that the scan
    trusts contract at each size (the spectral radius of the dilated error map, computed
    again here by scipy): the plan checks the first two at the size itself, the others only
    at the bin's representative size."""
    scipy_linalg = pytest.importorskip("scipy.linalg")
    model = runtime_models(kalman_design, kernel=False)[kind]
    for dt in new_sizes(7, 30):
        floor, ceiling = model._floor(dt), model._ceiling(dt)
        low, high = model._trusted_levels
        grid = [(tau / dt) ** (1.0 / model._nu) for tau in TAU_GRID.tolist()]
        levels = {floor, *(level for level in grid
                           if floor <= level <= ceiling and low <= level <= high)}
        if math.isfinite(ceiling):
            levels.add(ceiling)
        for level in levels:
            radius = max(abs(scipy_linalg.eigvals(model.error_map(level, dt))))
            assert radius < 1.0, (dt, level, radius)


@pytest.mark.skipif(sys.platform != "linux" or shutil.which("cc") is None,
                    reason="the planner is compiled with cc on linux")
@pytest.mark.slow
@pytest.mark.parametrize("kind", ["observer", "prescribed_time"])
def test_native_planner_makes_the_same_plans_and_scans(kind, kalman_design):
    """The C planner with one bin cache over the 200 sizes: the same floors and ceilings as
    the numpy runtime's kernel plans (to 1e-12), the same scans and bins kept."""
    from fhobs.native.build import captured_plan
    from fhobs.native.planner import BinScans, c_plan

    model, bins = runtime_models(kalman_design)[kind], BinScans()
    for dt in new_sizes(6, 200):
        reference, plan = captured_plan(model, dt), c_plan(kind, model, dt, bins)
        for name in ("floor_level", "ceiling"):
            assert plan[name] == pytest.approx(reference[name], rel=RTOL), (dt, name)
    assert bins.info() == model.plan_cache_info()
