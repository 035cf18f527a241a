"""What the design can handle: size, magnitude and degree limits, checked before it starts.

A spec that passes :func:`fhobs.design.spec.load_spec` can still be beyond the design's numerics;
these limits refuse it at once, with a message naming the item, instead of a solver failure, an
overflow or a memory exhaustion deep inside the design. They were measured:

- ``MAX_CHAIN``: the longest observability chain, ``n_tilde``. The LMIs are solved in blocks of
  size ``n_tilde + 1`` (:mod:`fhobs.design.lmi`); a single-output integrator chain designs up to
  ``n_tilde = 11`` and fails from 12 on (Clarabel: infeasible or numerical failure), and the
  solver's memory grows as ``n_tilde^4`` (about 33 GB at ``n_tilde = 300``).
- ``MAX_STATES``: the model's state count ``n + k * disturbance_order``. With chains of 10,
  300 states design in about 3 s and 600 in about 50 s (0.24 GB); the time grows as n^4,
  dominated by the powers of A0 that build the chain basis (:func:`fhobs.design.lmi.chain_basis`).
- ``MAX_MAGNITUDE``: matrix entries, rho, gamma, filter_scale, state_scale (its entries and
  their spread) and the ``[noise]`` table's numbers (within its inverse and itself). The design
  squares and multiplies them (A0^n_tilde, P (A + rho G)); a double integrator scaled by 1e12
  is already infeasible for the solver, and 1e200 overflows to inf.
- ``MIN_ABS_NU``: the dilation's weights ``1 + nu + j nu`` must be told apart by an eigenspace
  rank test; from ``|nu| = 1e-5`` on the eigenspaces are found wrong.
"""

from __future__ import annotations

import numpy as np

from ..errors import SpecError
from .spec import PlantSpec

MAX_CHAIN = 11
MAX_STATES = 600
MAX_MAGNITUDE = 1e12
MIN_ABS_NU = 1e-4


def check_design_limits(spec: PlantSpec) -> None:
    """Refuse a spec beyond the design's limits (module docstring) before designing it.

    Parameters
    ----------
    spec : PlantSpec
        A spec validated by :func:`fhobs.design.spec.load_spec` or
        :func:`fhobs.design.spec.spec_from_dict`.

    Raises
    ------
    SpecError
        Naming the size, entry or parameter and the limit it exceeds.

    Examples
    --------
    >>> from fhobs.design.spec import spec_from_dict
    >>> spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]],
    ...                        "observer": {"rho": 1e300, "gamma": 1.0}})
    >>> check_design_limits(spec)
    Traceback (most recent call last):
    ...
    fhobs.errors.SpecError: <dict>: observer.rho = 1e+300 is beyond the design's range ...
    """
    _check_size(spec)
    for name in ("A", "B", "C", "E", "L_lin"):
        matrix = getattr(spec, name)
        if matrix is not None:
            _check_matrix(matrix, name, spec.source)
    for name in ("rho", "gamma", "filter_scale", "settling_time"):
        value = getattr(spec, name)
        if value is not None and not abs(value) <= MAX_MAGNITUDE:
            raise SpecError(
                f"{spec.source}: observer.{name} = {value!r} is beyond the design's range "
                f"(|value| <= {MAX_MAGNITUDE:g}); rescale time so the rates are moderate"
            )
    scale = spec.state_scale
    if scale is not None and not (scale.max() <= MAX_MAGNITUDE * scale.min()
                                  and 1.0 / MAX_MAGNITUDE <= scale.max() <= MAX_MAGNITUDE):
        raise SpecError(
            f"{spec.source}: observer.state_scale from {scale.min():g} to {scale.max():g} is "
            f"beyond the design's range (entries within [{1 / MAX_MAGNITUDE:g}, "
            f"{MAX_MAGNITUDE:g}], spanning at most a factor {MAX_MAGNITUDE:g}); rescale the "
            "plant's units"
        )
    _check_noise(spec)
    if abs(spec.nu) < MIN_ABS_NU:
        raise SpecError(
            f"{spec.source}: observer.nu = {spec.nu!r} is too close to 0: the dilation weights "
            f"1 + nu + j nu cannot be told apart; use |nu| >= {MIN_ABS_NU:g}"
        )


def _check_noise(spec: PlantSpec) -> None:
    """The ``[noise]`` table's numbers within the design's range: the Kalman filter's Riccati
    equation squares and multiplies them (a std of 1e300 or a sample time of 1e-300 overflow)."""
    if spec.noise is None:
        return
    values = {"sample_time": spec.noise.sample_time,
              "process_intensity": spec.noise.process_intensity}
    values |= {f"measurement_std[{i + 1}]": float(v)
               for i, v in enumerate(spec.noise.measurement_std)}
    for name, value in values.items():
        if not 1.0 / MAX_MAGNITUDE <= value <= MAX_MAGNITUDE:
            raise SpecError(
                f"{spec.source}: noise.{name} = {value!r} is beyond the design's range "
                f"([{1 / MAX_MAGNITUDE:g}, {MAX_MAGNITUDE:g}]); rescale the plant's units or time"
            )


def _check_size(spec: PlantSpec) -> None:
    n = spec.A.shape[0]
    states = n + spec.C.shape[0] * spec.disturbance_order
    if spec.n_tilde > MAX_CHAIN:
        raise SpecError(
            f"{spec.source}: the observability index n_tilde = {spec.n_tilde} (n = {n}, "
            f"{spec.C.shape[0]} output(s)) exceeds the design's limit n_tilde <= {MAX_CHAIN}: "
            "longer observability chains make the LMIs numerically infeasible (measure more "
            "outputs to shorten the chains)"
        )
    if states > MAX_STATES:
        raise SpecError(
            f"{spec.source}: the observer's model has {states} states, beyond the design's "
            f"limit of {MAX_STATES}"
        )


def _check_matrix(matrix: np.ndarray, name: str, source: str) -> None:
    i, j = np.unravel_index(int(np.argmax(np.abs(matrix))), matrix.shape)
    if not abs(matrix[i, j]) <= MAX_MAGNITUDE:
        raise SpecError(
            f"{source}: {name}[{i + 1},{j + 1}] = {float(matrix[i, j])!r} is beyond the design's "
            f"range (|entry| <= {MAX_MAGNITUDE:g}); rescale the plant's units or time"
        )
