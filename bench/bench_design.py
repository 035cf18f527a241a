"""Design time for n = 4 (the pendulum), 10, 20 and 50 (random observable plants, seeded).

Prints a table: homogenisation time, full design time (homogenisation + three LMIs + numpy
certificate), best of ``--repeat`` runs, imports excluded. Targets: pendulum < 0.3 s,
n = 50 < 10 s.

Run: ``python bench/bench_design.py [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from fhobs.design import design_observer
from fhobs.homogenisation import homogenise
from fhobs.spec import PlantSpec, load_spec, spec_from_dict

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def random_plant(n: int, k: int, seed: int) -> PlantSpec:
    """A random observable plant with entries of order one (seeded)."""
    rng = np.random.default_rng(seed)
    data = {
        "A": (rng.standard_normal((n, n)) / np.sqrt(n)).tolist(),
        "B": rng.standard_normal((n, 2)).tolist(),
        "C": rng.standard_normal((k, n)).tolist(),
    }
    return spec_from_dict(data, source=f"random n={n} k={k} seed={seed}")


def best_time(func, repeat: int) -> float:
    """Best wall time of ``repeat`` calls."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    """Print the design-time table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    cases = [("pendulum", load_spec(EXAMPLES / "pendulum.toml"))] + [
        (f"random n={n}", random_plant(n, k, seed=9)) for n, k in ((10, 3), (20, 4), (50, 10))
    ]
    print(f"{'plant':<14} {'n':>3} {'k':>3} {'n~':>3} {'homogenise s':>13} {'design s':>9}")
    for name, spec in cases:
        t_hom = best_time(lambda s=spec: homogenise(s.A, s.C, s.nu), args.repeat)
        t_design = best_time(lambda s=spec: design_observer(s), args.repeat)
        n, k = spec.A.shape[0], spec.C.shape[0]
        print(f"{name:<14} {n:>3} {k:>3} {spec.n_tilde:>3} {t_hom:>13.3f} {t_design:>9.3f}")


if __name__ == "__main__":
    main()
