"""The designed observer: plant, homogenisation and LMI gains, as one serialisable record.

This module is numpy-only: it is shipped inside the FMUs and read by the runtime.

Notation (Ping, Zimenko, Polyakov, Efimov, "Filtering homogeneous observer for MIMO system"):

- ``A, B, C, E``: the plant dx/dt = A x + B u + E q, y = C x (n states, m inputs, k outputs).
- ``nu``: homogeneity degree, in [-1/(n_tilde+1), 0); ``nu = -1/(n_tilde+1)`` is the HOSM case.
- ``n_tilde``: observability index, the least j with rank [C; CA; ...; CA^(j-1)] = n.
- ``G0``: solution of the homogenisation equation A G0 - G0 A + Y0 C = A, C G0 = 0.
- ``L0``: homogenisation gain, L0 = -(I + G0)^-1 Y0; A0 = A + L0 C is nilpotent.
- ``G_d``: generator of the dilation d(s) = expm(s G_d), in the form of Theorem 2,
  G_d = I + nu (G0 + I), so that A0 G_d = (G_d + nu I) A0 and C G_d = (1 + nu) C.
- ``L_tilde`` (k x k), ``L`` (n x k): gains of the output filter psi and of the state
  estimate z, from the LMI of Theorem 2, (L_tilde; L) = P_bar^-1 Y_bar.
- ``P_bar``: the LMI's Lyapunov matrix, kept so that the certificate can be re-checked.
- ``rho``, ``gamma``: LMI decay parameter and the xi-equation gain, with rho > gamma / 2.
- ``L_pt``, ``P_pt``: the prescribed-time observer of Theorem 1 (dilation generator
  G_d - nu I, for which C G = C).
- ``L_lin``: gain of the Luenberger baseline dz/dt = A z + B u + L_lin (C z - y).
- ``xi``, ``sigma``: the observer's scalar gain state and sigma = sqrt(max(xi, |psi|^2 / 2)).
- ``disturbance_order``: r >= 0; with r >= 1 the homogeneous observers work on the extended
  model of :mod:`fhobs.core.disturbance` (``A_model``, ``B_model``, ``C_model``, ``n_model`` states,
  the plant's first): G0, L0, G_d, L, P_bar, L_pt, P_pt and n_tilde are of that model, while
  A, B, C, E and L_lin (the Luenberger baseline) stay the plant's.
- ``kalman``: optional :class:`KalmanGains`, the steady-state discrete Kalman filter baseline
  (designed by :func:`fhobs.design.kalman.design_kalman`, run by :mod:`fhobs.core.kalman_filter`);
  its disturbance model is its own (``kalman.disturbance_order``), on the same plant A, B, C, E.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from .disturbance import extended_model

MATRIX_FIELDS = (
    "A", "B", "C", "E", "G0", "L0", "G_d", "L_tilde", "L", "P_bar", "L_pt", "P_pt", "L_lin",
)
SCALAR_FIELDS = ("nu", "rho", "gamma")


@dataclass(frozen=True)
class KalmanGains:
    """A steady-state discrete Kalman filter on the plant of an :class:`ObserverGains`.

    The filter runs on ``extended_model(A, B, C, E, disturbance_order)`` sampled with the
    exact zero-order hold at ``sample_time``; the unknown input ``q^(r)`` (q itself through E
    for r = 0) is continuous white noise of intensity ``process_intensity`` (power spectral
    density, per component of q), the measurement noise is white with standard deviation
    ``measurement_std`` per output.

    Attributes
    ----------
    disturbance_order : int
        r in 0..3 (see :mod:`fhobs.core.disturbance`).
    sample_time : float
        Ts, the filter's sampling period (s).
    measurement_std : numpy.ndarray
        (k,) standard deviations of the measurement noise.
    process_intensity : float
        Intensity W of the white noise driving ``q^(r)``.
    gain : numpy.ndarray
        (N x k) measurement-update gain M = P C^T (C P C^T + R)^-1, N the model's states.
    covariance : numpy.ndarray
        (N x N) steady-state a-priori error covariance P (one step ahead).
    tuning : str
        How ``process_intensity`` was chosen (free text, for the record).
    """

    disturbance_order: int
    sample_time: float
    measurement_std: np.ndarray
    process_intensity: float
    gain: np.ndarray
    covariance: np.ndarray
    tuning: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (arrays as lists)."""
        return {f.name: (v.tolist() if isinstance(v := getattr(self, f.name), np.ndarray) else v)
                for f in fields(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> KalmanGains:
        """Build from :meth:`to_dict` output."""
        return cls(
            disturbance_order=int(data["disturbance_order"]),
            sample_time=float(data["sample_time"]),
            measurement_std=np.array(data["measurement_std"], dtype=float, ndmin=1),
            process_intensity=float(data["process_intensity"]),
            gain=np.array(data["gain"], dtype=float, ndmin=2),
            covariance=np.array(data["covariance"], dtype=float, ndmin=2),
            tuning=str(data.get("tuning", "")),
        )


@dataclass(frozen=True)
class ObserverGains:
    """Plant matrices and every observer gain of one design (see the module docstring)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    E: np.ndarray | None
    nu: float
    rho: float
    gamma: float
    n_tilde: int
    G0: np.ndarray
    L0: np.ndarray
    G_d: np.ndarray
    L_tilde: np.ndarray
    L: np.ndarray
    P_bar: np.ndarray
    L_pt: np.ndarray
    P_pt: np.ndarray
    L_lin: np.ndarray
    disturbance_order: int = 0
    certificate: dict[str, Any] = field(default_factory=dict)
    kalman: KalmanGains | None = None

    @property
    def n(self) -> int:
        """Number of plant states."""
        return self.A.shape[0]

    @property
    def m(self) -> int:
        """Number of plant inputs."""
        return self.B.shape[1]

    @property
    def k(self) -> int:
        """Number of measured outputs."""
        return self.C.shape[0]

    @cached_property
    def model(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A_model, B_model, C_model)`` of the homogeneous observers (the plant's if
        ``disturbance_order`` is 0); built once per record (a frozen record's fields do not
        change; :func:`dataclasses.replace` makes a new record with its own cache)."""
        return extended_model(self.A, self.B, self.C, self.E, self.disturbance_order)

    @property
    def n_model(self) -> int:
        """Number of states of the homogeneous observers' model (n if no disturbance model)."""
        return self.G_d.shape[0]

    @cached_property
    def A0(self) -> np.ndarray:
        """The nilpotent matrix A0 = A_model + L0 C_model (computed once per record)."""
        A_model, _, C_model = self.model
        return A_model + self.L0 @ C_model

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-ready dict (matrices as lists of rows, ``E`` may be None)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, KalmanGains):
                value = value.to_dict()
            out[f.name] = value.tolist() if isinstance(value, np.ndarray) else value
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ObserverGains:
        """Build from :meth:`to_dict` output (or a ``design.json`` file's content)."""
        kwargs: dict[str, Any] = {}
        for f in fields(cls):
            if f.name not in data:
                if f.name in ("E", "disturbance_order", "certificate", "kalman"):
                    continue
                raise KeyError(f"design record lacks the field {f.name!r}")
            value = data[f.name]
            if f.name in MATRIX_FIELDS and value is not None:
                value = np.array(value, dtype=float, ndmin=2)
            elif f.name in SCALAR_FIELDS:
                value = float(value)
            elif f.name in ("n_tilde", "disturbance_order"):
                value = int(value)
            elif f.name == "kalman" and value is not None:
                value = KalmanGains.from_dict(value)
            kwargs[f.name] = value
        return cls(**kwargs)

    def save_json(self, path: str | Path) -> Path:
        """Write the record as JSON to ``path`` and return the path."""
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1))
        return path

    @classmethod
    def load_json(cls, path: str | Path) -> ObserverGains:
        """Read a record written by :meth:`save_json`."""
        return cls.from_dict(json.loads(Path(path).read_text()))
