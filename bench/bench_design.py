"""Design time for n = 4 (the pendulum), 10, 20 and 50 (random observable plants, seeded).

Prints a table: homogenisation time, full design time at a given rho (homogenisation + three
LMIs + numpy certificate; the random plants at rho = 1.5, gamma = 2.75, the pendulum at its
spec's), and the design time when the design chooses rho for the default settling time (one
design and one settling-time prediction per rung of the rho ladder), best of ``--repeat`` runs,
imports excluded, all without the design cache (``FHOBS_NO_DESIGN_CACHE``); and the time of the
given-rho design read from the user's cache (a design made before: read and certified again).
Then the zoo (:func:`harness.zoo.zoo_spec_paths`, default tuning): each plant's automatic design
(rho chosen for the settling time), afresh and from the cache, and the median over the zoo.
Targets: pendulum < 0.3 s, n = 50 < 10 s (at a given rho), zoo median <= 0.3 s (automatic).

Run: ``python bench/bench_design.py [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import os
import time
import tomllib
from unittest import mock

import numpy as np
from fhobs.design.cache import DISABLE_ENV
from fhobs.design.homogenisation import homogenise
from fhobs.design.observer import design_for_spec
from fhobs.design.spec import spec_from_dict
from fhobs.paper import PENDULUM_SPEC

from harness.zoo import load_zoo_spec, zoo_spec_paths


def random_plant(n: int, k: int, seed: int) -> dict:
    """A random observable plant with entries of order one (seeded), as a spec dict."""
    rng = np.random.default_rng(seed)
    return {
        "A": (rng.standard_normal((n, n)) / np.sqrt(n)).tolist(),
        "B": rng.standard_normal((n, 2)).tolist(),
        "C": rng.standard_normal((k, n)).tolist(),
    }


def best_time(func, repeat: int) -> float:
    """Best wall time of ``repeat`` calls."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return min(times)


def fresh_and_cached(spec, repeat: int) -> tuple[float, float]:
    """Best time of ``design_for_spec(spec)`` without the design cache, then read from it."""
    with mock.patch.dict(os.environ, {DISABLE_ENV: "1"}):  # computed afresh
        fresh = best_time(lambda: design_for_spec(spec), repeat)
    design_for_spec(spec)  # into the cache, if it was not there
    return fresh, best_time(lambda: design_for_spec(spec), repeat)


def zoo_table(repeat: int) -> None:
    """Print each zoo plant's automatic design time (afresh, cached) and the median."""
    print(f"\n{'zoo plant':<22} {'n':>3} {'k':>3} {'rho':>5} {'auto s':>8} {'cached s':>9}")
    times = []
    for name, path in zoo_spec_paths().items():
        spec = load_zoo_spec(path)
        fresh, cached = fresh_and_cached(spec, repeat)
        times.append(fresh)
        print(f"{name:<22} {spec.A.shape[0]:>3} {spec.C.shape[0]:>3} "
              f"{design_for_spec(spec).filtering.rho:>5g} {fresh:>8.3f} {cached:>9.3f}")
    print(f"{'median':<22} {'':>3} {'':>3} {'':>5} {np.median(times):>8.3f}")


def main() -> None:
    """Print the design-time tables."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    pendulum = tomllib.loads(PENDULUM_SPEC.read_text())
    automatic = {k: v for k, v in pendulum.items() if k not in ("observer", "noise")}
    cases = [("pendulum", pendulum, automatic)] + [
        (f"random n={n}", data | {"observer": {"rho": 1.5, "gamma": 2.75}}, data)
        for n, k in ((10, 3), (20, 4), (50, 10)) for data in [random_plant(n, k, seed=9)]
    ]
    print(f"{'plant':<14} {'n':>3} {'k':>3} {'n~':>3} {'homogenise s':>13} {'design s':>9} "
          f"{'auto rho s':>11} {'cached s':>9}")
    for name, given, auto in cases:
        spec, spec_auto = spec_from_dict(given, name), spec_from_dict(auto, name)
        t_hom = best_time(lambda s=spec: homogenise(s.A, s.C, s.nu), args.repeat)
        with mock.patch.dict(os.environ, {DISABLE_ENV: "1"}):  # computed afresh
            t_auto = best_time(lambda s=spec_auto: design_for_spec(s), 1)
        t_design, t_cached = fresh_and_cached(spec, args.repeat)
        n, k = spec.A.shape[0], spec.C.shape[0]
        print(f"{name:<14} {n:>3} {k:>3} {spec.n_tilde:>3} {t_hom:>13.3f} {t_design:>9.3f} "
              f"{t_auto:>11.2f} {t_cached:>9.3f}")
    zoo_table(args.repeat)


if __name__ == "__main__":
    main()
