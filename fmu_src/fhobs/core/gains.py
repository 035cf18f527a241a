"""The designed observers: the plant, the homogeneous model and one record per estimator.

This module is numpy-only: it is shipped inside the FMUs and read by the runtime.

An :class:`ObserverDesign` holds the plant (:class:`PlantModel`), the homogeneous model
(:class:`HomogeneousModel`) and one record per estimator, each self-contained for the FMU that
runs it and carrying its own certificate report: :class:`FilteringGains` (Theorem 2),
:class:`PrescribedTimeGains` (Theorem 1), :class:`LuenbergerGains` (the linear baseline) and,
optionally, :class:`KalmanGains`. The estimator records hold the design's plant and model
objects (shared, not copies); ``design.json`` holds the plant and the model once and each
estimator's own fields under its name.

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
  model of :mod:`fhobs.core.disturbance` (``A_model``, ``B_model``, ``C_model``, ``n_model``
  states, the plant's first): G0, L0, G_d, L, P_bar, L_pt, P_pt and n_tilde are of that model,
  while the plant and L_lin (the Luenberger baseline) stay the plant's.
- ``kalman``: optional :class:`KalmanGains`, the steady-state discrete Kalman filter baseline
  (designed by :func:`fhobs.design.kalman.design_kalman`, run by :mod:`fhobs.core.kalman_filter`);
  its disturbance model is its own (``kalman.disturbance_order``), on the same plant.
- ``supervised``: optional :class:`SupervisedGains`, the supervised observer of the ``[noise]``
  table (:mod:`fhobs.core.supervisor`): the filtering record and a Kalman filter of the
  homogeneous model, written whole in design.json (its own copies of both).

Examples
--------
>>> plant = PlantModel(np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]]),
...                    np.array([[1.0, 0.0]]))
>>> plant.n, plant.m, plant.k
(2, 1, 1)
>>> luenberger = LuenbergerGains(plant, np.array([[-2.0], [-1.0]]))
>>> LuenbergerGains.from_dict(luenberger.to_dict(), plant=plant).L_lin.tolist()
[[-2.0], [-1.0]]
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np

from .disturbance import extended_model

Record = TypeVar("Record", bound="_Record")
SHARED = ("plant", "model")
"""The fields an estimator record shares with its design: written once, by the design."""


def _loaded(f: dataclasses.Field, value: Any, shared: dict[str, Any]) -> Any:
    """The JSON ``value`` of the field ``f`` as its annotation names it: a nested record (given
    the ``shared`` plant and model it holds), an array (at least ``f.metadata["ndmin"]``
    dimensions, default 2), a number or a string; None stays None."""
    annotation = str(f.type).removesuffix(" | None")
    if value is None:
        return None
    record = _RECORDS.get(annotation)
    if record is not None:
        return record.from_dict(value, **{name: shared[name] for name in shared
                                          if name in record.__dataclass_fields__})
    if annotation == "np.ndarray":
        return np.array(value, dtype=float, ndmin=f.metadata.get("ndmin", 2))
    return {"float": float, "int": int, "str": str}.get(annotation, lambda v: v)(value)


class _Record:
    """The JSON round trip shared by every record: arrays as nested lists, a nested record as
    its own dict, and the shared plant and model (:data:`SHARED`) left to the design."""

    _writes_shared: ClassVar[bool] = False
    """Whether :meth:`to_dict` writes the plant and model (the design does, once)."""

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-ready dict (arrays as lists of rows; the shared plant and model of an
        estimator record are not included: the design writes them once)."""
        out: dict[str, Any] = {}
        for f in fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if isinstance(value, _Record):
                if f.name in SHARED and not self._writes_shared:
                    continue
                value = value.to_dict()
            out[f.name] = value.tolist() if isinstance(value, np.ndarray) else value
        return out

    @classmethod
    def from_dict(cls: type[Record], data: dict[str, Any], **shared: Any) -> Record:
        """Build from :meth:`to_dict` output; ``shared``: the design's plant and model, which
        the record holds (the same objects) instead of reading them from ``data``."""
        kwargs: dict[str, Any] = {}
        for f in fields(cls):  # type: ignore[arg-type]
            if f.name in shared:
                kwargs[f.name] = shared[f.name]
            elif f.name in data:
                kwargs[f.name] = _loaded(f, data[f.name], shared)
                if f.name in SHARED:  # the design's own: its records get these objects
                    shared = shared | {f.name: kwargs[f.name]}
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise KeyError(f"design record lacks the field {f.name!r}")
        return cls(**kwargs)


def _vector() -> Any:
    """A field holding a vector (loaded with one dimension, not as a matrix)."""
    return field(metadata={"ndmin": 1})


@dataclass(frozen=True)
class PlantModel(_Record):
    """The plant dx/dt = A x + B u + E q, y = C x.

    Attributes
    ----------
    A, B, C : numpy.ndarray
        n x n, n x m, k x n.
    E : numpy.ndarray or None
        n x p, the perturbation's input matrix (None: no perturbation input).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    E: np.ndarray | None = None

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

    def extended_model(self, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A_model, B_model, C_model)`` with a disturbance model of ``order``
        (:func:`fhobs.core.disturbance.extended_model`; the plant's own for order 0).

        Examples
        --------
        >>> plant = PlantModel(np.zeros((1, 1)), np.ones((1, 1)), np.ones((1, 1)),
        ...                    E=np.ones((1, 1)))
        >>> plant.extended_model(1)[0].tolist()
        [[0.0, 1.0], [0.0, 0.0]]
        """
        return extended_model(self.A, self.B, self.C, self.E, order)


@dataclass(frozen=True)
class HomogeneousModel(_Record):
    """The homogenisation shared by the filtering and prescribed-time observers, of the
    observer's model (the plant with ``disturbance_order`` blocks of q states; see the module
    docstring). The plant is not held here: the estimator records that hold both give the
    model's matrices and A0 (:class:`HomogeneousGains`).

    Attributes
    ----------
    disturbance_order : int
        r >= 0.
    n_tilde : int
        Observability index of the model.
    nu : float
        Homogeneity degree.
    G0, L0, G_d : numpy.ndarray
        Homogenisation solution, gain (N x k) and dilation generator (N x N) of Theorem 2.
    slow_projector : numpy.ndarray
        Pi_s (N x N), the projector onto the homogenised part of the model along the fast
        stable modes that the observers keep by the model (:mod:`fhobs.design.partial`); the
        identity (the default, also for a ``design.json`` without it) when the whole model is
        homogenised. ``n_tilde`` is then the observability index of the homogenised part, and
        A0 is homogeneous, and nilpotent, on the range of Pi_s only.
    """

    disturbance_order: int
    n_tilde: int
    nu: float
    G0: np.ndarray
    L0: np.ndarray
    G_d: np.ndarray
    slow_projector: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.slow_projector is None:
            object.__setattr__(self, "slow_projector", np.eye(self.G_d.shape[0]))

    @property
    def partial(self) -> bool:
        """Whether fast stable modes are kept by the model (Pi_s is not the identity)."""
        return not np.array_equal(self.slow_projector, np.eye(self.G_d.shape[0]))

    @property
    def n_model(self) -> int:
        """Number of states of the homogeneous observers' model (n if no disturbance model)."""
        return self.G_d.shape[0]


@dataclass(frozen=True)
class HomogeneousGains(_Record):
    """What the two homogeneous observers' records share: the plant, the homogeneous model and
    the model's matrices and A0 derived from both (computed once per record: a frozen record's
    fields do not change; :func:`dataclasses.replace` makes a new record with its own cache)."""

    plant: PlantModel
    model: HomogeneousModel

    @cached_property
    def model_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A_model, B_model, C_model)`` of the observer (the plant's if
        ``model.disturbance_order`` is 0)."""
        return self.plant.extended_model(self.model.disturbance_order)

    @cached_property
    def A0(self) -> np.ndarray:
        """The nilpotent matrix A0 = A_model + L0 C_model."""
        A_model, _, C_model = self.model_matrices
        return A_model + self.model.L0 @ C_model


@dataclass(frozen=True)
class FilteringGains(HomogeneousGains):
    """The filtering homogeneous observer of Theorem 2 (``observer.fmu``).

    Attributes
    ----------
    plant : PlantModel
    model : HomogeneousModel
    rho, gamma : float
        The certified decay parameter and the xi equation's gain (rho > gamma / 2).
    L_tilde, L : numpy.ndarray
        Gains of the output filter psi (k x k) and of the estimate z (N x k).
    P_bar : numpy.ndarray
        Lyapunov matrix of the Theorem 2 LMI ((k+N) x (k+N)).
    certificate : dict
        The design's report on this observer: ``checks`` (the certificate's figures of
        :func:`fhobs.core.certificate.certify_filtering`), ``objective``, ``lmi_margin``,
        ``solver_status`` (the LMI solve's, absent for published gains) and
        ``matched_perturbation_residual`` (Corollary 1's condition; None without E).
    max_communication_step : float
        The longest communication step (s) over which the observer tolerates its inputs held
        (:func:`fhobs.design.settling.communication_step_bracket`: the closed loop on the
        estimate settles within twice the fine step's time); the observer FMUs warn once at a
        longer step. 0: not computed (published gains), no warning.
    """

    rho: float
    gamma: float
    L_tilde: np.ndarray
    L: np.ndarray
    P_bar: np.ndarray
    certificate: dict[str, Any] = field(default_factory=dict)
    max_communication_step: float = 0.0


@dataclass(frozen=True)
class PrescribedTimeGains(HomogeneousGains):
    """The prescribed-time observer of Theorem 1 (``prescribed_time.fmu``), dilation generator
    ``G_d - nu I``.

    Attributes
    ----------
    plant : PlantModel
    model : HomogeneousModel
    rho : float
        Decay parameter of the xi equation (the filtering observer's certified rho).
    L_pt : numpy.ndarray
        Gain of the prescribed-time injection (N x k).
    P_pt : numpy.ndarray
        Lyapunov matrix of the Theorem 1 LMI (N x N).
    certificate : dict
        ``checks`` (:func:`fhobs.core.certificate.certify_prescribed_time`'s figures),
        ``objective``, ``lmi_margin``, ``solver_status``.
    """

    rho: float
    L_pt: np.ndarray
    P_pt: np.ndarray
    certificate: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class LuenbergerGains(_Record):
    """The Luenberger baseline dz/dt = A z + B u + L_lin (C z - y) (``luenberger.fmu``).

    Attributes
    ----------
    plant : PlantModel
    L_lin : numpy.ndarray
        n x k.
    certificate : dict
        ``checks`` (``hurwitz_luenberger``) and, when L_lin was designed by LMI rather than
        given, ``objective``, ``lmi_margin`` and ``solver_status``.
    """

    plant: PlantModel
    L_lin: np.ndarray
    certificate: dict[str, Any] = field(default_factory=dict)

    @cached_property
    def model_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A, B, C)``: the observer runs on the plant's model."""
        return self.plant.A, self.plant.B, self.plant.C


@dataclass(frozen=True)
class KalmanGains(_Record):
    """A steady-state discrete Kalman filter on a plant (``kalman.fmu``).

    The filter runs on ``plant.extended_model(disturbance_order)`` sampled with the exact
    zero-order hold at ``sample_time``; the unknown input ``q^(r)`` (q itself through E for
    r = 0) is continuous white noise of intensity ``process_intensity`` (power spectral
    density, per component of q), the measurement noise is white with standard deviation
    ``measurement_std`` per output.

    Attributes
    ----------
    plant : PlantModel
        The plant it runs on.
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
    certificate : dict
        ``checks`` (:func:`fhobs.core.certificate.certify_kalman`'s figures: ``schur_kalman``);
        the gain solves a Riccati equation, no LMI: no objective, margin or solver status.
    process_covariance : numpy.ndarray or None
        (N x N) covariance Q_d of the process noise over one sample (Van Loan, with any
        regularisation the design added): the Riccati equation's ``Q_d``, which the
        time-varying recursion of the supervised observer's handover needs
        (:mod:`fhobs.core.supervisor`); None in a record written without it.
    """

    plant: PlantModel
    disturbance_order: int
    sample_time: float
    measurement_std: np.ndarray = _vector()
    process_intensity: float
    gain: np.ndarray
    covariance: np.ndarray
    tuning: str = ""
    certificate: dict[str, Any] = field(default_factory=dict)
    process_covariance: np.ndarray | None = None

    @cached_property
    def model_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A_model, B_model, C_model)`` the filter runs on:
        ``plant.extended_model(disturbance_order)``."""
        return self.plant.extended_model(self.disturbance_order)


@dataclass(frozen=True)
class SupervisedGains(_Record):
    """The supervised observer (:mod:`fhobs.core.supervisor`): the filtering observer and a
    Kalman filter of the same extended model, and the innovation test that picks one of them.

    Attributes
    ----------
    plant : PlantModel
    model : HomogeneousModel
    filtering : FilteringGains
        The filtering homogeneous observer (Theorem 2), never reset.
    kalman : KalmanGains
        A steady-state Kalman filter with ``kalman.disturbance_order`` equal to
        ``model.disturbance_order``: its state maps one to one onto the filtering observer's z.
    window : float
        Length, in filter samples, of the exponential window of the statistic (its weight is
        ``1 / window``; at least 1).
    lower, upper : float
        The Kalman estimate is left when the statistic falls below ``lower`` or rises above
        ``upper`` (the band of the false-alarm probability ``false_alarm``).
    lower_return, upper_return : float
        The Kalman estimate is taken again once the statistic is inside
        ``(lower_return, upper_return)``, within ``(lower, upper)`` (the hysteresis).
    ceiling : float
        The statistic is held at most at ``ceiling`` (> upper): a transient's innovations,
        many decades above k, then need a few windows, not dozens, to leave its memory.
    dwell_time : float
        Least time (s) the homogeneous estimate is output before the Kalman estimate is taken
        again.
    false_alarm : float
        Probability per sample, for data the Kalman filter's model explains, that the
        statistic leaves ``(lower, upper)`` (Gaussian innovations; what the thresholds were set
        for).
    handover_covariance : numpy.ndarray
        (N x N, symmetric, positive definite on the states of nonzero variance) error
        covariance of the homogeneous estimate under the ``[noise]`` table's measurement
        noise, at least the Kalman filter's
        steady-state ``covariance``: the Kalman filter's covariance at a handover, from which
        it runs the time-varying recursion back to its steady state.
    certificate : dict
        ``checks``: the figures of both parts' certificates and of the thresholds
        (:func:`fhobs.core.certificate.certify_supervised`).
    """

    plant: PlantModel
    model: HomogeneousModel
    filtering: FilteringGains
    kalman: KalmanGains
    window: float
    lower: float
    upper: float
    lower_return: float
    upper_return: float
    ceiling: float
    dwell_time: float
    false_alarm: float
    handover_covariance: np.ndarray
    certificate: dict[str, Any] = field(default_factory=dict)

    @property
    def model_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A_model, B_model, C_model)``: both parts run on the homogeneous model (the
        filtering record's)."""
        return self.filtering.model_matrices


@dataclass(frozen=True)
class ObserverDesign(_Record):
    """One design: the plant, the homogeneous model and every estimator's record, which hold
    the same plant and model objects.

    Attributes
    ----------
    plant : PlantModel
    model : HomogeneousModel
    filtering : FilteringGains
    prescribed_time : PrescribedTimeGains
    luenberger : LuenbergerGains
    kalman : KalmanGains or None
        The Kalman filter baseline of the spec's ``[noise]`` table.
    settling_tuning : dict or None
        When rho was chosen for the settling time: ``settling_time_requested``,
        ``settling_time_predicted``, ``peaking``, ``peaking_limit``, ``met``.
    noise_tuning : dict or None
        When the design was tuned for noise (:func:`fhobs.design.tuning.design_for_noise`):
        its predictions, window and intensity.
    supervised : SupervisedGains or None
        The supervised observer of the spec's ``[noise]`` table (the filtering observer and
        a Kalman filter of its model, :mod:`fhobs.core.supervisor`); None without the table
        (and in a ``design.json`` written without it).

    Raises
    ------
    ValueError
        If an estimator record does not hold the design's plant or model object.

    Examples
    --------
    >>> import tempfile
    >>> from fhobs.design.observer import paper_gains
    >>> design = paper_gains()
    >>> back = ObserverDesign.load_json(design.save_json(Path(tempfile.mkdtemp()) / "d.json"))
    >>> back.filtering.plant is back.plant and back.prescribed_time.model is back.model
    True
    >>> bool(np.array_equal(back.filtering.L, design.filtering.L))
    True
    """

    plant: PlantModel
    model: HomogeneousModel
    filtering: FilteringGains
    prescribed_time: PrescribedTimeGains
    luenberger: LuenbergerGains
    kalman: KalmanGains | None = None
    settling_tuning: dict[str, Any] | None = None
    noise_tuning: dict[str, Any] | None = None
    supervised: SupervisedGains | None = None

    _writes_shared: ClassVar[bool] = True

    def __post_init__(self) -> None:
        for name in ESTIMATORS:
            record = getattr(self, name)
            for shared in SHARED:
                if hasattr(record, shared) and getattr(record, shared) is not getattr(self, shared):
                    raise ValueError(f"design.{name}.{shared} is not the design's {shared}")

    def save_json(self, path: str | Path) -> Path:
        """Write the design as JSON to ``path`` and return the path."""
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1))
        return path

    @classmethod
    def load_json(cls, path: str | Path) -> ObserverDesign:
        """Read a design written by :meth:`save_json`."""
        return cls.from_dict(json.loads(Path(path).read_text()))


ESTIMATORS = ("filtering", "prescribed_time", "luenberger", "kalman", "supervised")
"""The estimator records of an :class:`ObserverDesign`, by attribute."""
_RECORDS: dict[str, type[_Record]] = {cls.__name__: cls for cls in (
    PlantModel, HomogeneousModel, FilteringGains, PrescribedTimeGains, LuenbergerGains,
    KalmanGains, SupervisedGains, ObserverDesign)}
