"""results.csv files compared as numbers: two builds of the same FMUs (native and pythonfmu)
round differently (C sums against numpy's BLAS kernels, which differ between machines), so
their columns agree to a tolerance relative to each signal's size, not digit for digit."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

BUILDS_RTOL = 1e-11
"""Native against pythonfmu FMUs: the largest difference of a column over its largest
magnitude. Measured on the paper's scenarios: 0 with OpenBLAS's Haswell kernels (their sums
happen to run in the C code's order), up to 7.2e-13 with its AVX-512 ones (the disturbance
estimate of the perturbed scenario); the tolerance leaves a factor 14 for other machines."""


def read_results(path: Path) -> tuple[list[str], np.ndarray]:
    """The header and the rows (floats) of a results.csv."""
    with open(path, newline="") as file:
        header = next(csv.reader(file))
    return header, np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def column_differences(path: Path, reference: Path) -> np.ndarray:
    """Per column of ``path``, its largest difference from ``reference``'s over the largest
    magnitude of ``reference``'s column (0 for equal columns, also all-zero ones).

    Examples
    --------
    >>> bool(column_differences(native_csv, python_csv).max() <= BUILDS_RTOL)  # doctest: +SKIP
    True
    """
    names, values = read_results(path)
    reference_names, reference_values = read_results(reference)
    assert names == reference_names and values.shape == reference_values.shape
    scale = np.max(np.abs(reference_values), axis=0)
    difference = np.max(np.abs(values - reference_values), axis=0)
    return np.divide(difference, scale, out=np.where(difference > 0, np.inf, 0.0),
                     where=scale > 0)
