"""A default designed for the user's noise and disturbance.

:func:`design_for_noise` picks, among certified designs of the filtering observer, the one whose
error is predicted to be the least under the measurement noise and the disturbance the user
describes (a spec's ``[noise]`` and ``[disturbance]`` tables), and predicts, on the same data, the
error of the steady-state Kalman filter of the same disturbance-model order (its process intensity
tuned on these data too). :func:`design_for_noise_spec` does the same for a loaded spec.

Prediction. The estimation error does not depend on the plant's motion (the observers know u and
the model is exact: the runtime's split step and the Kalman filter's prediction are the plant's
own zero-order hold), so it is predicted on the loop that ``python -m harness plant`` runs: the
plant from ``x(0) = state_scale`` (an initial error of that size, the observers at zero) under the
LQR feedback ``u = K x`` on its true state (:func:`harness.zoo.state_feedback`), the
disturbance q fed through E as the harness's signal block gives it (held over each step), the
communication step the noise's sample time, and uniform measurement noise of the given standard
deviation per output (the plant FMU's noise is uniform), drawn from numpy's
``default_rng([seed, draw])`` for ``noise_draws`` draws. The plant's data are recorded once and
every estimator is replayed on them (:mod:`fhobs.core.runtime`, :mod:`fhobs.core.kalman_filter`,
numpy with the compiled kernel), so all candidates see the same noise (common random numbers).
Figures, over the window ``[settling_time, 3 settling_time]`` (the harness's steady window when
the design meets its settling time): the RMS of ``||x - x_hat||`` under noise and disturbance
(mean over the draws), and the max of ``||x - x_hat||`` under the disturbance without noise.

Selection. The Kalman filter is tuned first: its process intensity is the one of the grid
``10^(j/2)`` with the least predicted noisy RMS. Then the candidates (certified designs, below)
are predicted, and the chosen design is the one with the least predicted noisy RMS among those
whose noise-free error is at least ``rejection`` times below the Kalman filter's (the
homogeneous observer's strength: it rejects a matched disturbance exactly). If none is, the
candidate with the least noise-free error is chosen and ``met`` is False. Either way a
candidate is chosen only if it converges, in the noise-free replay and in every noisy one (and
again once designed with its keys): finite throughout, the RMS of its error over the window's
last quarter at least :data:`DECAY` times below its initial error and not growing
(:data:`GROWTH`); the next in the order is tried otherwise, and LMIError says when none
converges. :func:`poor_design_lines` compares a design with its Kalman filter by the same
prediction.

Candidates. Relative to the automatic design of the plant
(:func:`fhobs.design.observer.design_for_spec`
with the free keys left out: its rho ``rho_auto``, ``nu_hosm = -1/(n_tilde + 1)``), a fixed grid
and a seeded refinement:

- grid: ``nu = f nu_hosm`` with f in :data:`NU_FRACTIONS`, ``rho = r rho_auto`` with r in
  :data:`RHO_FACTORS`, ``filter_scale`` in :data:`FILTER_SCALES`, and for each of these designs
  ``gamma = c rho_cert`` with c in :data:`GAMMA_RATIOS` (rho_cert: the design's certified rho;
  the certificate needs ``gamma < 2 rho_cert``); plus the automatic design itself;
- refinement: ``refine`` designs drawn from ``numpy.random.default_rng(seed)`` in the rounds of
  :data:`REFINE_SPREADS`, each around the best candidate so far (f, r, filter_scale and c
  multiplied by random factors).

The keys given in ``fixed`` (nu, rho, gamma, filter_scale, objective) are kept in every
candidate. The chosen design is designed again with its keys
(:func:`fhobs.design.observer.design_for_spec`)
and certified; its record carries the tuned Kalman filter (``design.kalman``) and the predictions
(``design.noise_tuning``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..core.certificate import certify, certify_filtering
from ..core.gains import FilteringGains, KalmanGains, ObserverDesign, PlantModel
from ..core.kalman_filter import KalmanObserver
from ..core.linalg import zoh_blocks
from ..core.plant import noise_samples
from ..core.runtime import FilteringObserver
from ..errors import CertificateError, KalmanDesignError, LMIError, SpecError
from .cache import cached
from .feedback import state_feedback
from .kalman import design_kalman
from .limits import check_design_limits
from .observer import design_for_spec
from .spec import (
    DEFAULT_SETTLING_TIME,
    DisturbanceSpec,
    PlantSpec,
    spec_from_dict,
)

NU_FRACTIONS = (1.0, 0.84)
"""Grid of ``nu / nu_hosm``: the HOSM degree and a less homogeneous one."""
RHO_FACTORS = (0.5, 0.75, 1.0, 1.8)
"""Grid of ``rho / rho_auto``."""
FILTER_SCALES = (1.0, 2.0, 3.0)
"""Grid of ``filter_scale`` (L_tilde multiplied after the LMI, :mod:`fhobs.design.observer`)."""
GAMMA_RATIOS = (0.5, 1.0, 1.9)
"""Grid of ``gamma / rho_cert`` (the certificate needs < 2)."""
MAX_GAMMA_RATIO = 1.95
"""Largest ``gamma / rho_cert`` tried: the design's bisection of rho_cert starts at
``1.02 gamma / 2`` (:mod:`fhobs.design.observer`), so the chosen gamma designs again."""
DESIGN_GAMMA_RATIO = 0.1
"""A candidate is designed with ``gamma = 0.1 rho`` (any gamma below its certified rho gives the
same gains); its gammas are then set and certified one by one."""
REFINE_SPREADS = (0.15, 0.06)
"""The refinement's rounds: each draws its share of ``refine`` candidates around the best so far,
f, r, filter_scale and c multiplied by ``exp(U(-s, s))`` with s its spread."""
REJECTION = 1e4
"""Default ``rejection``: the noise-free error must be this many times below the Kalman
filter's."""
KALMAN_DECADES = (-12, 12)
"""Range of the Kalman filter's process intensities, ``10^(j/2)`` (coarse pass: whole decades)."""
NOISE_DRAWS = 3
"""Default number of noise draws of the prediction."""
TUNED_KEYS = ("nu", "rho", "gamma", "filter_scale", "objective")
"""The ``[observer]`` keys the tuning chooses (unless fixed)."""
DECAY = 10.0
"""A candidate converges only if the RMS of its error over the last quarter of the window, in
the noise-free replay and in every noisy one, is at least this many times below its initial
error."""
GROWTH = 4.0
"""... and at most this many times the RMS over the quarter before (checked where that RMS is
above :data:`SETTLED` times the initial error and the disturbance has started by then)."""
SETTLED = 1e-3
"""The settled error, relative to the initial one (the settling time's criterion)."""
SELECTIONS = {
    True: "the least predicted noisy RMS among the candidates that meet the rejection and "
          "converge",
    False: "no candidate meets the rejection: the strongest rejection among the candidates "
           "that converge",
}
"""The rule that chose the design (design.json's ``noise_tuning['selection']``), by whether
a candidate met the rejection."""
POOR_RATIO = 2.0
"""The homogeneous design is called poor when its predicted noisy RMS or peaking is more than
this many times the Kalman filter's."""


@dataclass(frozen=True)
class ErrorPrediction:
    """The predicted error of one estimator over the window.

    Attributes
    ----------
    noisy_rms : float
        RMS of ``||x - x_hat||`` with noise and disturbance, mean over the noise draws.
    noisy_rms_draws : tuple of float
        The same per draw.
    noise_free_max : float
        Max of ``||x - x_hat||`` with the disturbance and no noise.
    noise_free_rms : float
        RMS of ``||x - x_hat||`` with the disturbance and no noise.
    peaking : float
        Max of ``||x - x_hat||`` over the whole noise-free replay over its initial value.
    final_ratio : float
        RMS of ``||x - x_hat||`` over the last quarter of the window over its initial value,
        the largest of the noise-free and the noisy replays (a converging design's is at most
        ``1 / DECAY``).
    """

    noisy_rms: float
    noisy_rms_draws: tuple[float, ...]
    noise_free_max: float
    noise_free_rms: float
    peaking: float = math.nan
    final_ratio: float = math.nan


@dataclass(frozen=True)
class NoiseDesign:
    """The result of :func:`design_for_noise`.

    Attributes
    ----------
    design : ObserverDesign
        The chosen certified design, with the tuned Kalman filter (``design.kalman``) and
        ``design.noise_tuning`` (the predictions, the window, the intensity).
    parameters : dict
        Its ``[observer]`` keys: ``nu``, ``rho``, ``gamma``, ``filter_scale``, ``objective``
        (``rho`` as given to the LMI; ``design.filtering.rho`` is the certified one).
    predicted : ErrorPrediction
        The filtering observer's predicted error.
    kalman : ErrorPrediction
        The tuned Kalman filter's predicted error on the same data.
    kalman_intensity : float
        Its process intensity.
    window : tuple of float
        ``(t0, t1)`` of the figures (s).
    met : bool
        Whether the chosen design's noise-free error is ``rejection`` times below the Kalman
        filter's.
    candidates : tuple of dict
        Every candidate: its parameters, ``noise_free_max``, ``noisy_rms`` (absent when it was
        not run under noise: it missed the rejection bound and another was chosen) or
        ``failed`` (the reason: not certified, not run, or not converging).
    seconds : float
        Wall time of the search.
    cached : bool
        Whether the result came from the user's cache (:mod:`fhobs.design.cache`: the same
        inputs searched before by the same code; the design certified again when read).
    """

    design: ObserverDesign
    parameters: dict[str, Any]
    predicted: ErrorPrediction
    kalman: ErrorPrediction
    kalman_intensity: float
    window: tuple[float, float]
    met: bool
    candidates: tuple[dict[str, Any], ...]
    seconds: float
    cached: bool = False

    @property
    def ratio(self) -> float:
        """Predicted noisy RMS, ours over the Kalman filter's."""
        return self.predicted.noisy_rms / self.kalman.noisy_rms

    @property
    def rejection(self) -> float:
        """Predicted noise-free max, the Kalman filter's over ours."""
        return self.kalman.noise_free_max / max(self.predicted.noise_free_max, 1e-300)

    def summary(self) -> list[str]:
        """The lines a command prints: the chosen keys, both predictions, the ratios, and a
        warning line when no candidate met the rejection asked for."""
        p, k = self.predicted, self.kalman
        keys = ", ".join(f"{key} = {_short(value)}" for key, value in self.parameters.items())
        lines = [
            f"noise tuning: {keys} (certified rho {self.design.filtering.rho:.4g}); "
            f"{len(self.candidates)} candidates in {self.seconds:.1f} s"
            + (" (from the cache)" if self.cached else ""),
            f"predicted over [{self.window[0]:g}, {self.window[1]:g}] s: homogeneous noisy RMS "
            f"{p.noisy_rms:.3e}, noise-free max {p.noise_free_max:.3e}; Kalman filter "
            f"(intensity {self.kalman_intensity:.3g}) noisy RMS {k.noisy_rms:.3e}, noise-free max "
            f"{k.noise_free_max:.3e}; ratio {self.ratio:.3f} in noise, {self.rejection:.3g}x "
            "rejection",
        ]
        if not self.met:
            asked = (self.design.noise_tuning or {}).get("rejection_requested", REJECTION)
            lines.append(
                f"warning: no certified candidate rejects the disturbance {asked:g}x better than "
                f"the Kalman filter and converges; this is the converging candidate of the "
                f"strongest rejection ({self.rejection:.3g}x; its error over the window's last "
                f"quarter is {p.final_ratio:.2g} of the initial one)")
        return lines


def design_for_noise(
    A: ArrayLike,
    B: ArrayLike,
    C: ArrayLike,
    E: ArrayLike,
    *,
    measurement_std: ArrayLike,
    sample_time: float,
    disturbance: DisturbanceSpec | Mapping[str, Any],
    disturbance_order: int = 1,
    kalman_order: int | None = None,
    settling_time: float = DEFAULT_SETTLING_TIME,
    state_scale: ArrayLike = 1.0,
    L_lin: ArrayLike | None = None,
    fixed: Mapping[str, Any] | None = None,
    rejection: float = REJECTION,
    noise_draws: int = NOISE_DRAWS,
    seed: int = 0,
    refine: int = 8,
) -> NoiseDesign:
    """The certified filtering observer with the least predicted error under the given noise and
    disturbance, and the same-order Kalman filter's prediction (module docstring).

    Parameters
    ----------
    A, B, C, E : array_like
        Plant ``dx/dt = A x + B u + E q``, ``y = C x`` (n x n, n x m, k x n, n x p).
    measurement_std : array_like
        (k,) standard deviation of the measurement noise per output (uniform noise of amplitude
        a has std ``a / sqrt(3)``).
    sample_time : float
        The measurement's sample time (s): the communication step of the prediction.
    disturbance : DisturbanceSpec or mapping
        The disturbance q, as a ``[disturbance]`` table (:mod:`fhobs.design.spec`): ``shape``,
        ``size``, ``start``, ``frequency``, ``seed``.
    disturbance_order : int
        The observer's disturbance model (>= 1 to estimate q).
    kalman_order : int, optional
        The Kalman filter's disturbance model; default ``disturbance_order``.
    settling_time : float
        The requested settling time (s); the window is ``[settling_time, 3 settling_time]``.
    state_scale : float or array_like
        Typical size of each state: the plant's initial state (the initial error).
    L_lin : array_like, optional
        The Luenberger baseline's gain (kept in the record).
    fixed : mapping, optional
        ``[observer]`` keys kept in every candidate (of ``nu``, ``rho``, ``gamma``,
        ``filter_scale``, ``objective``).
    rejection : float
        Required ratio of the Kalman filter's noise-free max error to ours (>= 1).
    noise_draws : int
        Noise draws of the prediction (>= 1).
    seed : int
        Seed of the noise draws and of the refinement's candidates (>= 0).
    refine : int
        Number of refinement candidates (>= 0).

    Returns
    -------
    NoiseDesign

    Raises
    ------
    fhobs.errors.SpecError
        If an argument is invalid (the message names it).
    fhobs.errors.LMIError, fhobs.errors.CertificateError
        If the automatic design fails, or no candidate is certified.
    fhobs.errors.KalmanDesignError
        If no process intensity gives a Kalman filter.

    Examples
    --------
    A double integrator measured in position, a step force from 0.5 s, noise of std 1e-3
    sampled at 10 ms:

    >>> result = design_for_noise(
    ...     [[0, 1], [0, 0]], [[0], [1]], [[1, 0]], [[0], [1]],
    ...     measurement_std=[1e-3], sample_time=1e-2,
    ...     disturbance={"shape": "step", "size": 0.2, "start": 0.5})
    >>> result.design.model.disturbance_order, result.design.kalman is not None
    (1, True)
    >>> result.predicted.noisy_rms > 0 and result.window
    (2.0, 6.0)
    """
    spec = _validated_spec(A, B, C, E, measurement_std, sample_time, disturbance,
                           disturbance_order, settling_time, state_scale, L_lin, fixed)
    for name, value, low in (("rejection", rejection, 1.0), ("noise_draws", noise_draws, 1),
                             ("seed", seed, 0), ("refine", refine, 0)):
        integer = name != "rejection"
        if (isinstance(value, bool) or not isinstance(value, int | float | np.number)
                or (integer and int(value) != value) or not math.isfinite(value) or value < low):
            kind = "an integer" if integer else "a number"
            raise SpecError(f"design_for_noise: {name} = {value!r} must be {kind} >= {low}")
    order = disturbance_order if kalman_order is None else kalman_order
    arguments = (np.asarray(measurement_std, dtype=float).ravel(), float(sample_time), int(order),
                 dict(fixed or {}), float(rejection), int(noise_draws), int(seed), int(refine))
    result, hit = cached("noise_tuning", (dataclasses.replace(spec, source=""), arguments),
                         lambda: _search(spec, *arguments), _certified)
    return dataclasses.replace(result, cached=True) if hit else result


def _certified(result: NoiseDesign) -> None:
    """Raise CertificateError unless ``result`` is a search's result whose design certifies."""
    if not isinstance(result, NoiseDesign):
        raise CertificateError(f"not a noise tuning's result: {type(result).__name__}")
    certify(result.design)


def design_for_noise_spec(spec: PlantSpec, what: str | None = None,
                          **options: Any) -> NoiseDesign:
    """:func:`design_for_noise` for a loaded spec with ``[noise]`` and ``[disturbance]`` tables.

    The spec's ``[observer]`` keys of :data:`TUNED_KEYS` that it sets are kept (pass
    ``fixed={}`` to tune them all); its noise's ``measurement_std``, ``sample_time`` and
    ``disturbance_order``, its ``settling_time``, ``state_scale``, ``disturbance_order`` and
    ``L_lin`` are used.

    Parameters
    ----------
    spec : PlantSpec
        From :func:`fhobs.design.spec.load_spec`.
    what : str, optional
        How a missing table's message starts (:func:`check_noise_tables`; default
        ``"<spec file>: the noise tuning"``, a command line names its option).
    **options
        ``fixed``, ``rejection``, ``noise_draws``, ``seed``, ``refine`` of
        :func:`design_for_noise`.

    Returns
    -------
    NoiseDesign

    Raises
    ------
    fhobs.errors.SpecError
        If the spec lacks E, the ``[noise]`` or the ``[disturbance]`` table.
    """
    check_noise_tables(spec, what or f"{spec.source}: the noise tuning")
    if "fixed" not in options:
        options["fixed"] = {key: value for key, value in (
            ("rho", spec.rho), ("gamma", spec.gamma)) if value is not None}
    return design_for_noise(
        spec.A, spec.B, spec.C, spec.E, measurement_std=spec.noise.measurement_std,
        sample_time=spec.noise.sample_time, disturbance=spec.disturbance,
        disturbance_order=spec.disturbance_order, kalman_order=spec.noise.disturbance_order,
        settling_time=spec.settling_time, state_scale=spec.state_scale, L_lin=spec.L_lin,
        **options)


def check_noise_tables(spec: PlantSpec, what: str) -> None:
    """Raise SpecError naming what the noise tuning of ``spec`` lacks (E, the ``[noise]`` or
    the ``[disturbance]`` table), the message starting with ``what``.

    Examples
    --------
    >>> from fhobs.design.spec import spec_from_dict
    >>> try:
    ...     check_noise_tables(spec_from_dict({"A": [[0.0]], "B": [[1.0]], "C": [[1.0]]}),
    ...                        "--tune-noise")
    ... except SpecError as err:
    ...     print(err)
    --tune-noise needs E, a [noise] table and a [disturbance] table; the spec has none of them
    """
    missing = [name for name, value in (("E", spec.E), ("a [noise] table", spec.noise),
                                         ("a [disturbance] table", spec.disturbance))
               if value is None]
    if missing:
        have = "none of them" if len(missing) == 3 else "no " + " and no ".join(
            name.removeprefix("a ") for name in missing)
        raise SpecError(f"{what} needs E, a [noise] table and a [disturbance] table; the spec "
                        f"has {have}")


def predict_error(design: ObserverDesign, *, measurement_std: ArrayLike, sample_time: float,
                  disturbance: DisturbanceSpec | Mapping[str, Any], settling_time: float,
                  state_scale: ArrayLike, estimator: str = "homogeneous",
                  noise_draws: int = NOISE_DRAWS, seed: int = 0) -> ErrorPrediction:
    """The predicted error of one design's filtering observer (``estimator="homogeneous"``) or
    Kalman filter (``"kalman"``, needs ``design.kalman``) under the given noise and disturbance,
    by the prediction of the module docstring.

    Returns
    -------
    ErrorPrediction

    Examples
    --------
    >>> from fhobs.design.observer import design_observer
    >>> design = design_observer([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], E=[[0], [1]],
    ...                          disturbance_order=1, rho=3.0)
    >>> p = predict_error(design, measurement_std=[1e-3], sample_time=1e-2,
    ...                   disturbance={"shape": "step", "size": 0.2, "start": 0.5},
    ...                   settling_time=2.0, state_scale=1.0)
    >>> bool(p.noise_free_max < 1e-6 < p.noisy_rms)
    True
    """
    if estimator not in ("homogeneous", "kalman") or (estimator == "kalman"
                                                       and design.kalman is None):
        raise SpecError(f"predict_error: estimator = {estimator!r} must be 'homogeneous' or "
                        "'kalman' (the latter with design.kalman)")
    data = _design_scenario(design, measurement_std, sample_time, disturbance, settling_time,
                            state_scale, noise_draws, seed)
    record = design.kalman if estimator == "kalman" else design.filtering
    prediction = data.predict(record, estimator, checked=False)
    if isinstance(prediction, str):
        raise ValueError(prediction)
    return prediction


def poor_design_lines(spec: PlantSpec, design: ObserverDesign, seed: int = 0) -> list[str]:
    """One warning line when the spec has a ``[noise]`` table and its homogeneous design is
    predicted to do more than :data:`POOR_RATIO` times worse than its Kalman filter, in noisy
    RMS or in peaking (:class:`ErrorPrediction`); no line otherwise.

    The predictions are the noise tuning's when the design has them (``design.noise_tuning``),
    else one of each estimator on one noise draw of ``seed`` (the module docstring's, with the
    spec's ``[disturbance]``, or none).

    Parameters
    ----------
    spec : PlantSpec
        The spec the design was made for.
    design : ObserverDesign
        Its design (with the Kalman filter of its ``[noise]`` table).
    seed : int
        Seed of the noise draw.

    Returns
    -------
    list of str

    Examples
    --------
    >>> from pathlib import Path
    >>> import fhobs
    >>> from fhobs.design.observer import design_for_spec
    >>> from fhobs.design.spec import load_spec
    >>> spec = load_spec(Path(fhobs.__file__).parent / "examples" / "pendulum.toml")
    >>> poor_design_lines(spec, design_for_spec(spec))
    []
    """
    if spec.noise is None or design.kalman is None:
        return []
    tuning = design.noise_tuning
    if tuning:
        window = tuning["window"]
        ours: tuple[float, float] | str = (tuning["predicted_noisy_rms"],
                                           tuning["predicted_peaking"])
        kalman = (tuning["kalman_predicted_noisy_rms"], tuning["kalman_predicted_peaking"])
    else:
        disturbance = spec.disturbance or DisturbanceSpec("step", np.zeros(spec.E.shape[1]))
        try:
            data = _design_scenario(design, spec.noise.measurement_std, spec.noise.sample_time,
                                    disturbance, spec.settling_time, spec.state_scale, 1, seed)
        except SpecError as err:
            return [f"note: the design was not compared with the Kalman filter: {err}"]
        window = data.window
        made = [data.predict(record, name, checked=False)
                for record, name in ((design.filtering, "homogeneous"),
                                     (design.kalman, "kalman"))]
        if isinstance(made[1], str):
            return [f"note: the design was not compared with the Kalman filter: {made[1]}"]
        ours = made[0] if isinstance(made[0], str) else (made[0].noisy_rms, made[0].peaking)
        kalman = (made[1].noisy_rms, made[1].peaking)
    where = f"the [noise] table's noise over [{window[0]:g}, {window[1]:g}] s"
    advice = ("the supervised estimator (supervised.fmu: the Kalman filter in noise, the "
              "homogeneous observer in transients) is the estimator for this spec's measurements"
              if design.supervised is not None else
              "the Kalman filter (kalman.fmu) is the estimator for this spec's measurements")
    if isinstance(ours, str):
        return [f"warning: the homogeneous observer fails under {where} ({ours}); {advice}"]
    ratios = [a / b for a, b in zip(ours, kalman, strict=True)]
    if max(ratios) <= POOR_RATIO:
        return []
    return [f"warning: poor design for {where}: homogeneous noisy RMS {ours[0]:.3e}, peaking "
            f"{ours[1]:.3g}x against the Kalman filter's {kalman[0]:.3e}, {kalman[1]:.3g}x "
            f"({ratios[0]:.3g} and {ratios[1]:.3g} times, more than {POOR_RATIO:g}); {advice}"]


def _design_scenario(design: ObserverDesign, measurement_std: Any, sample_time: Any,
                     disturbance: Any, settling_time: Any, state_scale: Any, noise_draws: int,
                     seed: int) -> _Scenario:
    """The prediction's data for the plant of ``design`` (SpecError naming a bad argument)."""
    plant = design.plant
    spec = _validated_spec(plant.A, plant.B, plant.C, plant.E, measurement_std, sample_time,
                           disturbance, design.model.disturbance_order, settling_time,
                           state_scale, None, None)
    return _Scenario(spec, np.asarray(measurement_std, dtype=float).ravel(),
                     float(sample_time), int(noise_draws), int(seed))


# -- validation ------------------------------------------------------------------------------

def _validated_spec(A: Any, B: Any, C: Any, E: Any, measurement_std: Any, sample_time: Any,
                    disturbance: Any, disturbance_order: Any, settling_time: Any,
                    state_scale: Any, L_lin: Any, fixed: Any) -> PlantSpec:
    """The plant, the disturbance and the fixed keys validated as a spec would be (SpecError
    naming the argument); the noise's std and sample time checked here."""
    source = "design_for_noise"
    if E is None:
        raise SpecError(f"{source}: E is required (the disturbance q enters through it)")
    if fixed is not None:
        if not isinstance(fixed, Mapping):
            raise SpecError(f"{source}: fixed must be a mapping of [observer] keys")
        unknown = sorted(set(fixed) - set(TUNED_KEYS))
        if unknown:
            raise SpecError(f"{source}: fixed has {unknown[0]!r}, not one of {TUNED_KEYS}")
    if isinstance(disturbance, DisturbanceSpec):
        table: dict[str, Any] = {"shape": disturbance.shape,
                                 "size": np.asarray(disturbance.size, dtype=float).tolist(),
                                 "start": float(disturbance.start)}
        if disturbance.shape == "sine":
            table["frequency"] = disturbance.frequency
        if disturbance.shape == "random_walk":
            table["seed"] = disturbance.seed
    elif isinstance(disturbance, Mapping):
        table = dict(disturbance)
    else:
        raise SpecError(f"{source}: disturbance must be a DisturbanceSpec or a [disturbance] "
                        f"table (a mapping), got {type(disturbance).__name__}")
    observer = {"disturbance_order": disturbance_order, "settling_time": settling_time,
                "state_scale": _listed(state_scale), **dict(fixed or {})}
    data: dict[str, Any] = {"A": A, "B": B, "C": C, "E": E, "observer": observer,
                            "disturbance": table}
    if L_lin is not None:
        data["L_lin"] = L_lin
    spec = spec_from_dict(data, source=source)
    std = np.asarray(measurement_std, dtype=float).ravel() if _numeric(measurement_std) else None
    if std is None or std.size != spec.C.shape[0] or not np.all(np.isfinite(std)) \
            or not np.all(std > 0):
        raise SpecError(f"{source}: measurement_std must be {spec.C.shape[0]} positive finite "
                        f"numbers (one per output), got {measurement_std!r}")
    if isinstance(sample_time, bool) or not isinstance(sample_time, int | float | np.number) \
            or not (math.isfinite(sample_time) and 0.0 < sample_time <= spec.settling_time / 10):
        raise SpecError(f"{source}: sample_time = {sample_time!r} must be a positive number of "
                        f"at most settling_time / 10 = {spec.settling_time / 10:g} s")
    return spec


def _numeric(value: Any) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def _listed(value: Any) -> Any:
    """An array_like as nested lists (the spec's form), a scalar as it is."""
    return np.asarray(value).tolist() if isinstance(value, np.ndarray | tuple | list) else value


def _short(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


# -- prediction ------------------------------------------------------------------------------

def disturbance_samples(disturbance: DisturbanceSpec, channels: int, step: float,
                        steps: int) -> np.ndarray:
    """q at ``t_k = k step``, k = 0 .. steps - 1, as the harness's signal block gives it
    (:mod:`harness.blocks.signal_source`: zero before ``start``; the random walk
    ``q(t_k+1) = q(t_k) + size sqrt(step) w_j`` for ``t_k >= start``, w_j the Box-Muller
    Gaussians of draw j of the product's noise generator, :func:`fhobs.core.plant.noise_samples`
    of the seed, j counting the steps from ``start`` on).

    Examples
    --------
    >>> q = disturbance_samples(DisturbanceSpec("ramp", np.array([2.0]), 0.1), 1, 0.05, 4)
    >>> np.round(q.ravel(), 12).tolist()
    [0.0, 0.0, 0.0, 0.1]
    """
    q = np.zeros((steps, channels))
    t = np.arange(steps) * step
    started = t >= disturbance.start - 1e-9 * max(1.0, abs(disturbance.start))
    size = np.broadcast_to(np.asarray(disturbance.size, dtype=float), (channels,))
    elapsed = t[started] - disturbance.start
    if disturbance.shape == "step":
        q[started] = size
    elif disturbance.shape == "ramp":
        q[started] = np.outer(elapsed, size)
    elif disturbance.shape == "sine":
        q[started] = np.outer(np.sin(2.0 * np.pi * disturbance.frequency * elapsed), size)
    else:
        draws = noise_samples(disturbance.seed, steps, 1.0, 2 * channels)
        v, u = draws[:, :channels], draws[:, channels:]
        w = np.sqrt(-2.0 * np.log(0.5 * (1.0 - v))) * np.cos(np.pi * u)
        walk, j = np.zeros(channels), 0
        for i in range(steps - 1):
            if started[i]:
                walk = walk + size * math.sqrt(step) * w[j]
                j += 1
            q[i + 1] = walk
    return q


Estimator = FilteringGains | KalmanGains
"""The record of an estimator whose error the tuning predicts."""


class _Scenario:
    """The recorded plant data (noise-free, then each noise draw) and the replays.

    A checked replay is one of a candidate: besides running and staying finite, its error must
    converge (:data:`DECAY`, :data:`GROWTH`); the Kalman filter's and the comparison's replays
    are not checked (their figures are what is asked for)."""

    def __init__(self, spec: PlantSpec, std: np.ndarray, step: float, draws: int,
                 seed: int) -> None:
        self.step = step
        self.window = (spec.settling_time, 3.0 * spec.settling_time)
        steps = int(round(self.window[1] / step))
        A, B, C, E = spec.A, spec.B, spec.C, spec.E
        K = state_feedback(A, B)
        Phi, Gamma_B, Gamma_E = zoh_blocks(A, [B, E], step)
        closed, pushed = Phi + Gamma_B @ K, disturbance_samples(
            spec.disturbance, E.shape[1], step, steps) @ Gamma_E.T
        x = np.empty((steps + 1, A.shape[0]))
        x[0] = spec.state_scale
        for i in range(steps):
            x[i + 1] = closed @ x[i] + pushed[i]
        self.x, self.u = x, x[:-1] @ K.T
        clean = x[:-1] @ C.T
        self.y = [clean] + [
            clean + np.random.default_rng([seed, draw]).uniform(-1.0, 1.0, clean.shape)
            * (math.sqrt(3.0) * std) for draw in range(draws)]
        t = np.arange(steps + 1) * step
        t0, t1 = self.window
        tol, quarter = 1e-9 * max(1.0, t1), (t1 - t0) / 4.0
        self.mask = (t >= t0 - tol) & (t <= t1 + tol)
        self.final = t >= t1 - quarter - tol
        self.before = (t >= t1 - 2.0 * quarter - tol) & ~self.final
        self.growth_checked = spec.disturbance.start <= t1 - 2.0 * quarter + tol

    def _errors(self, estimator: Any, y: np.ndarray) -> np.ndarray:
        """``||x - x_hat||`` over the whole replay."""
        out = np.empty_like(self.x)
        out[0] = estimator.x_hat
        advance, u, step = estimator.advance, self.u, self.step
        for i in range(len(y)):
            advance(y[i], u[i], step)
            out[i + 1] = estimator.x_hat
        return np.linalg.norm(self.x - out, axis=1)

    def _make(self, record: Estimator) -> Any:
        if isinstance(record, KalmanGains):
            return KalmanObserver(record)
        return FilteringObserver(record, h=self.step)

    def rms(self, e: np.ndarray, where: np.ndarray | None = None) -> float:
        """RMS of a replay's error over the window (or over ``where``)."""
        return float(np.sqrt(np.mean(e[self.mask if where is None else where] ** 2)))

    def final_ratio(self, e: np.ndarray) -> float:
        """RMS over the window's last quarter over the initial error."""
        return self.rms(e, self.final) / max(float(e[0]), 1e-300)

    def convergence_problem(self, e: np.ndarray) -> str | None:
        """Why a finite replay's error ``e`` does not converge, or None."""
        a, b = self.window[1] - (self.window[1] - self.window[0]) / 4.0, self.window[1]
        ratio = self.final_ratio(e)
        if ratio * DECAY > 1.0:
            return (f"does not converge: its error over [{a:g}, {b:g}] s is {ratio:.3g} of its "
                    f"initial error (at most 1/{DECAY:g})")
        final, before = self.rms(e, self.final), self.rms(e, self.before)
        if self.growth_checked and final > GROWTH * max(before, SETTLED * float(e[0])):
            return (f"does not converge: its error grows {final / before:.3g}x from the quarter "
                    f"of the window before [{a:g}, {b:g}] s to it")
        return None

    def replay(self, record: Estimator, estimator: str, y: np.ndarray,
               checked: bool, where: str = "") -> np.ndarray | str:
        """``||x - x_hat||`` of ``record`` (the estimator named ``estimator``) replayed on
        ``y``, or the reason it failed (``where`` names the data in it)."""
        try:
            e = self._errors(self._make(record), y)
        except ValueError as err:
            return f"the {estimator} replay{where} failed: {err}"
        if not np.all(np.isfinite(e)):
            return f"the {estimator} replay{where} diverged"
        problem = self.convergence_problem(e) if checked else None
        return f"the {estimator} replay{where} {problem}" if problem else e

    def noise_free(self, record: Estimator, estimator: str,
                   checked: bool = True) -> np.ndarray | str:
        """The error without noise, or the reason of a failed replay."""
        return self.replay(record, estimator, self.y[0], checked)

    def noisy(self, record: Estimator, estimator: str, draws: int | None = None,
              checked: bool = True) -> list[np.ndarray] | str:
        """The error of each noise draw (the first ``draws``), or the reason of a failure."""
        out = []
        for y in self.y[1:] if draws is None else self.y[1:1 + draws]:
            e = self.replay(record, estimator, y, checked, " under noise")
            if isinstance(e, str):
                return e
            out.append(e)
        return out

    def predict(self, record: Estimator, estimator: str,
                checked: bool = True) -> ErrorPrediction | str:
        """The prediction of ``record``, or the reason of a failed replay."""
        clean = self.noise_free(record, estimator, checked)
        if isinstance(clean, str):
            return clean
        noisy = self.noisy(record, estimator, checked=checked)
        if isinstance(noisy, str):
            return noisy
        draws = tuple(self.rms(e) for e in noisy)
        return ErrorPrediction(
            float(np.mean(draws)), draws, float(np.max(clean[self.mask])), self.rms(clean),
            float(np.max(clean)) / max(float(clean[0]), 1e-300),
            max(self.final_ratio(e) for e in [clean, *noisy]))


# -- search ----------------------------------------------------------------------------------

def _tuned_kalman(
    spec: PlantSpec, data: _Scenario, std: np.ndarray, step: float, order: int,
) -> tuple[KalmanGains, float, ErrorPrediction]:
    """The Kalman filter of the least predicted noisy RMS over intensities 10^(j/2): whole
    decades on the first draw, then the half-decades around the best on every draw."""
    plant = PlantModel(spec.A, spec.B, spec.C, spec.E)

    def attempt(exponent: float) -> tuple[float, KalmanGains] | None:
        intensity = 10.0 ** exponent
        try:
            return intensity, design_kalman(plant, order, std, intensity, step,
                                            "process_intensity tuned by fhobs.design.tuning "
                                            "(least predicted noisy RMS)")
        except KalmanDesignError:
            return None

    coarse = []
    for j in range(KALMAN_DECADES[0], KALMAN_DECADES[1] + 1):
        made = attempt(float(j))
        if made is not None:
            noisy = data.noisy(made[1], "kalman", draws=1, checked=False)
            if not isinstance(noisy, str):
                coarse.append((data.rms(noisy[0]), float(j)))
    if not coarse:
        raise KalmanDesignError("design_for_noise: no process intensity of 1e-12..1e12 gives a "
                                "stable Kalman filter that runs on the predicted data")
    centre = min(coarse)[1]
    best: tuple[float, float, KalmanGains, ErrorPrediction] | None = None
    for exponent in (centre - 0.5, centre, centre + 0.5):
        made = attempt(exponent)
        if made is None:
            continue
        prediction = data.predict(made[1], "kalman", checked=False)
        if not isinstance(prediction, str) and (best is None
                                                or prediction.noisy_rms < best[0]):
            best = (prediction.noisy_rms, made[0], made[1], prediction)
    if best is None:
        raise KalmanDesignError("design_for_noise: the tuned Kalman filter failed on the data")
    return best[2], best[1], best[3]


def _design(spec: PlantSpec, keys: dict[str, Any]) -> ObserverDesign:
    """One design of the spec with ``keys`` set in its [observer] table."""
    return design_for_spec(dataclasses.replace(spec, **keys))


def _candidate_keys(fixed: dict[str, Any], nu_hosm: float, rho_auto: float, f: float,
                    r: float, fs: float, objective: str) -> dict[str, Any]:
    keys = {"nu": nu_hosm * min(f, 1.0), "rho": rho_auto * r, "filter_scale": max(fs, 1.0),
            "objective": objective}
    return keys | {k: v for k, v in fixed.items() if k != "gamma"}


def _search(spec: PlantSpec, std: np.ndarray, step: float, kalman_order: int,
            fixed: dict[str, Any], rejection: float, draws: int, seed: int,
            refine: int) -> NoiseDesign:
    check_design_limits(spec)  # before any work, as design_for_spec does
    start = time.perf_counter()
    data = _Scenario(spec, std, step, draws, seed)
    auto = design_for_spec(spec)  # the automatic design (the spec holds the fixed keys)
    nu_hosm = -1.0 / (auto.model.n_tilde + 1)
    kalman_gains, intensity, kalman = _tuned_kalman(spec, data, std, step, kalman_order)
    bound = kalman.noise_free_max / rejection
    candidates: list[dict[str, Any]] = []
    records: dict[int, FilteringGains] = {}  # the record of each candidate that converges
    designs: dict[tuple, ObserverDesign | str] = {}

    seen: set[tuple] = set()

    def evaluate(keys: dict[str, Any], ratios: Sequence[float],
                 prebuilt: ObserverDesign | None = None) -> None:
        label = tuple(sorted(keys.items()))
        if label not in designs:
            try:
                designs[label] = prebuilt or _design(
                    spec, {**keys, "gamma": DESIGN_GAMMA_RATIO * keys["rho"]})
            except (LMIError, CertificateError, SpecError) as err:
                designs[label] = f"{type(err).__name__}: {err}"
        design = designs[label]
        gammas = ([fixed["gamma"]] if "gamma" in fixed else
                  [min(c, MAX_GAMMA_RATIO) * design.filtering.rho for c in ratios]
                  if not isinstance(design, str) else [math.nan])
        for gamma in gammas:
            if (label, round(float(gamma), 12)) in seen:
                continue
            seen.add((label, round(float(gamma), 12)))
            row: dict[str, Any] = {**keys, "gamma": float(gamma)}
            if isinstance(design, str):
                candidates.append(row | {"failed": design})
                continue
            filtering = dataclasses.replace(design.filtering, gamma=float(gamma))
            try:
                certify_filtering(filtering)
            except CertificateError as err:
                candidates.append(row | {"failed": f"CertificateError: {err}"})
                continue
            row["rho_certified"] = filtering.rho
            clean = data.noise_free(filtering, "homogeneous")
            if isinstance(clean, str):
                candidates.append(row | {"failed": clean})
                continue
            row["noise_free_max"], row["noise_free_rms"] = float(np.max(clean[data.mask])), \
                data.rms(clean)
            records[len(candidates)] = filtering
            if row["noise_free_max"] <= bound:
                _run_under_noise(row, filtering, data)
            candidates.append(row)

    if spec.filter_scale == 1.0:  # the automatic design as it is (today's default)
        evaluate({"nu": auto.model.nu, "rho": auto.filtering.rho, "filter_scale": 1.0,
                  "objective": spec.objective}, [auto.filtering.gamma / auto.filtering.rho],
                 auto)
    for f in NU_FRACTIONS:
        for r in RHO_FACTORS:
            for fs in FILTER_SCALES:
                evaluate(_candidate_keys(fixed, nu_hosm, auto.filtering.rho, f, r, fs,
                                         spec.objective), GAMMA_RATIOS)
    rng = np.random.default_rng(seed)
    for round_, spread in enumerate(REFINE_SPREADS):
        best = _best(candidates)
        if best is None:
            break
        f0, r0 = best["nu"] / nu_hosm, best["rho"] / auto.filtering.rho
        fs0, c0 = best["filter_scale"], best["gamma"] / best["rho_certified"]
        share = refine // len(REFINE_SPREADS) + (round_ < refine % len(REFINE_SPREADS))
        for _ in range(share):
            f, r, fs, c = (v * math.exp(rng.uniform(-spread, spread))
                           for v in (f0, r0, fs0, c0))
            evaluate(_candidate_keys(fixed, nu_hosm, auto.filtering.rho, f, r, fs,
                                     spec.objective), [c])
    parameters, design, predicted, met = _chosen(spec, data, candidates, records)
    seconds = time.perf_counter() - start
    tuning = {
        "window": list(data.window), "noise_draws": draws, "seed": seed,
        "rejection_requested": rejection, "met": met,
        "selection": SELECTIONS[met], "decay_required": DECAY,
        "predicted_noisy_rms": predicted.noisy_rms,
        "predicted_noise_free_max": predicted.noise_free_max,
        "predicted_peaking": predicted.peaking,
        "predicted_final_ratio": predicted.final_ratio,
        "kalman_process_intensity": intensity,
        "kalman_predicted_noisy_rms": kalman.noisy_rms,
        "kalman_predicted_noise_free_max": kalman.noise_free_max,
        "kalman_predicted_peaking": kalman.peaking,
        "candidates": len(candidates),
    }
    design = dataclasses.replace(
        design, kalman=dataclasses.replace(kalman_gains, plant=design.plant), noise_tuning=tuning)
    return NoiseDesign(design, parameters, predicted, kalman, intensity, data.window, met,
                       tuple(candidates), seconds)


def _best(candidates: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The candidate of the least noisy RMS among those run under noise (they met the bound)."""
    ok = [row for row in candidates if "noisy_rms" in row]
    return min(ok, key=lambda row: row["noisy_rms"]) if ok else None


def _run_under_noise(row: dict[str, Any], filtering: FilteringGains, data: _Scenario) -> bool:
    """Replay a candidate under noise: its ``noisy_rms`` (and per draw) in ``row``, or why it
    fails or does not converge as ``failed``; whether it converged."""
    noisy = data.noisy(filtering, "homogeneous")
    if isinstance(noisy, str):
        row["failed"] = noisy
        return False
    draws = tuple(data.rms(e) for e in noisy)
    row["noisy_rms"], row["noisy_rms_draws"] = float(np.mean(draws)), draws
    return True


def _chosen(spec: PlantSpec, data: _Scenario, candidates: list[dict[str, Any]],
            records: dict[int, FilteringGains],
            ) -> tuple[dict[str, Any], ObserverDesign, ErrorPrediction, bool]:
    """The chosen candidate's keys, its design (designed again), its prediction and whether it
    met the rejection: the first in the order of :data:`SELECTIONS` that converges, also when
    designed again (a candidate that fails is marked ``failed`` in ``candidates``)."""
    met = sorted((i for i in records if "noisy_rms" in candidates[i]),
                 key=lambda i: candidates[i]["noisy_rms"])
    rest = sorted((i for i in records if "noisy_rms" not in candidates[i]
                   and "failed" not in candidates[i]),
                  key=lambda i: candidates[i]["noise_free_max"])
    if not records:
        raise LMIError("design_for_noise: no candidate design is certified and runs: "
                       + "; ".join(sorted({row["failed"][:120] for row in candidates})))
    for i in met + rest:
        row = candidates[i]
        if "noisy_rms" not in row and not _run_under_noise(row, records[i], data):
            continue
        parameters = {key: row[key] for key in TUNED_KEYS}
        try:
            design = _design(spec, parameters)
        except (LMIError, CertificateError, SpecError) as err:
            row["failed"] = f"designed again: {type(err).__name__}: {err}"
            continue
        predicted = data.predict(design.filtering, "homogeneous")
        if isinstance(predicted, str):
            row["failed"] = f"designed again: {predicted}"
            continue
        return parameters, design, predicted, i in met
    strongest = candidates[min(records, key=lambda i: candidates[i]["noise_free_max"])]
    certified = sum("rho_certified" in row for row in candidates)
    raise LMIError(
        f"design_for_noise: none of the {certified} certified candidates converges on the "
        f"predicted data (with and without noise, its error over the last quarter of the "
        f"window at least {DECAY:g} times below the initial one); the one of the strongest "
        f"rejection: {strongest['failed']}; the Kalman filter (kalman.fmu, built without "
        "--tune-noise) is the estimator for this noise")
