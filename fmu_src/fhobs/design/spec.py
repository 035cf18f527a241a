"""Plant specification: a TOML file describing dx/dt = A x + B u + E q, y = C x.

Format::

    name = "motor"            # optional: the plant's name (default: the file's stem)
    A = [[...], ...]          # n x n, arrays of rows
    B = [[...], ...]          # n x m
    C = [[...], ...]          # k x n
    E = [[...], ...]          # optional, n x r: perturbation input matrix
    L_lin = [[...], ...]      # optional, n x k: a given Luenberger baseline gain

    [observer]                # optional table, every key optional
    nu = -0.25                # homogeneity degree in [-1/(n_tilde+1), 0); default -1/(n_tilde+1)
    settling_time = 2.0       # seconds for an initial error of the size of state_scale to fall
                              # to 1e-3 of itself; default 2 (used when rho is not given)
    state_scale = [1, 1]      # typical size of each state (or one number for all); default 1
    rho = 1.5                 # LMI decay parameter; default: the smallest rho of the climb
                              # that meets settling_time (fhobs.design.observer)
    gamma = 2.75              # xi-equation gain, 0 < gamma < 2 rho; default: rho
    objective = "min_cond"    # LMI objective, see fhobs.design.spec.OBJECTIVES
    filter_scale = 1.0        # >= 1: L_tilde multiplied after the LMI, see fhobs.design.observer;
    default 1
    disturbance_order = 0     # >= 0: model q as a polynomial of degree order-1 (needs E), see
                              # fhobs.core.disturbance; default 0 (no disturbance model)
    fast_mode_rate = 25.0     # 1/s: stable modes decaying faster than this (and than
                              # 2 rho (1 + nu)) are kept by the model, not homogenised
                              # (fhobs.design.partial); default 50 / settling_time; inf: none

    [noise]                   # optional table: the Kalman filter baseline (fhobs.design.kalman);
    needs E
    measurement_amplitude = [1e-3, 1e-3]  # uniform noise amplitude per output (std = a/sqrt(3)),
    # measurement_std = [...]             # or its standard deviation (exactly one of the two)
    sample_time = 5e-5        # the filter's sample time Ts (s)
    process_intensity = 3e-3  # intensity of the white noise driving q^(r) (q itself for r = 0)
    disturbance_order = 1     # r in 0..3; default: observer.disturbance_order

    [disturbance]             # optional table: the unknown input q that `harness plant` feeds
                              # the plant FMU (needs E); the design uses it with --tune-noise
    shape = "step"            # "step", "ramp", "sine" or "random_walk"; q = 0 before start
    size = [0.5]              # per q channel (r entries) or one number for all: the step's
                              # height, the ramp's slope (per s), the sine's amplitude, the
                              # random walk's intensity (q units per sqrt(s), >= 0)
    start = 0.5               # s, when q starts (default 0)
    frequency = 2.0           # Hz, shape = "sine" only (required there):
                              # q = size sin(2 pi frequency (t - start))
    seed = 0                  # shape = "random_walk" only (default 0): the increments
                              # size sqrt(h) w_k, w_k ~ N(0, I) (Box-Muller of the product's
                              # seeded uniforms, as the plant's noise), one per step h from start on

    [mismatch]                # optional table: `harness plant`'s plant FMU gets A and B
                              # perturbed entry by entry; the observers keep the nominal model
    size = 0.1                # relative size s >= 0: A_ij (1 + s w_ij), B_ij (1 + s w_ij)
    distribution = "gaussian" # w ~ N(0, 1) ("gaussian", the default) or U(-1, 1) ("uniform"),
                              # drawn for A (row by row), then B, from numpy's default_rng(seed)
    seed = 0                  # default 0

    [signals]                 # optional: names and units of x, u, y, q (fhobs.design.signals)
    [plant_model]             # optional: the user's FMU or SSP that `harness plant` runs
                              # against (fhobs.design.plant_model); the design ignores it

Every defect raises :class:`SpecError` naming the field and the reason.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..core.certificate import tuning_problem
from ..core.disturbance import describe_direction, extended_model, model_state_names
from ..errors import SpecError
from .homogenisation import observability_index, unobservable_directions
from .plant_model import PLANT_MODEL_KEYS, PlantModelSpec, plant_model_spec
from .signals import SIGNAL_KEYS, SignalNames, signal_names

DEFAULT_SETTLING_TIME = 2.0
OBJECTIVES = ("min_cond", "min_gain")
"""The LMI objectives a design accepts (:mod:`fhobs.design.lmi` implements them)."""
DEFAULT_OBJECTIVE = "min_cond"
TOP_KEYS = ("name", "A", "B", "C", "E", "L_lin", "observer", "noise", "disturbance", "mismatch",
            "signals", "plant_model")
OBSERVER_KEYS = (
    "nu", "rho", "gamma", "objective", "filter_scale", "disturbance_order", "settling_time",
    "state_scale", "fast_mode_rate",
)
NOISE_KEYS = ("measurement_std", "measurement_amplitude", "sample_time", "process_intensity",
              "disturbance_order")
MAX_DISTURBANCE_ORDER = 3
DISTURBANCE_KEYS = ("shape", "size", "start", "frequency", "seed")
DISTURBANCE_SHAPES = ("step", "ramp", "sine", "random_walk")
"""The shapes of the ``[disturbance]`` table (``harness.blocks``' signal block draws them)."""
MISMATCH_KEYS = ("size", "distribution", "seed")
MISMATCH_DISTRIBUTIONS = ("gaussian", "uniform")


@dataclass(frozen=True)
class NoiseSpec:
    """The ``[noise]`` table: what the Kalman filter baseline is designed for.

    Attributes
    ----------
    measurement_std : numpy.ndarray
        (k,) standard deviation of the measurement noise per output (from
        ``measurement_amplitude`` a of uniform noise: a / sqrt(3)).
    sample_time : float
        The filter's sample time Ts.
    process_intensity : float
        Intensity of the white noise driving ``q^(r)``.
    disturbance_order : int
        The filter's disturbance-model order r.
    """

    measurement_std: np.ndarray
    sample_time: float
    process_intensity: float
    disturbance_order: int


@dataclass(frozen=True)
class DisturbanceSpec:
    """The ``[disturbance]`` table: the unknown input q fed to the plant in ``harness plant``.

    Attributes
    ----------
    shape : str
        One of :data:`DISTURBANCE_SHAPES`.
    size : numpy.ndarray
        (r,) per q channel: step height, ramp slope, sine amplitude or random-walk intensity.
    start : float
        Time (s) from which q is nonzero.
    frequency : float or None
        Hz, for the sine (None otherwise).
    seed : int
        Seed of the random walk's increments (0 for the other shapes).
    """

    shape: str
    size: np.ndarray
    start: float = 0.0
    frequency: float | None = None
    seed: int = 0


@dataclass(frozen=True)
class MismatchSpec:
    """The ``[mismatch]`` table: how the plant FMU's A and B differ from the design's.

    Attributes
    ----------
    size : float
        Relative size s >= 0: each entry M_ij becomes M_ij (1 + s w_ij).
    distribution : str
        ``"gaussian"`` (w ~ N(0, 1)) or ``"uniform"`` (w ~ U(-1, 1)).
    seed : int
        Seed of numpy's ``default_rng`` that draws w for A (row by row), then for B.
    """

    size: float
    distribution: str = "gaussian"
    seed: int = 0

    def perturb(self, A: Any, B: Any) -> tuple[np.ndarray, np.ndarray]:
        """The perturbed ``(A, B)``: ``M * (1 + size * W)`` entry by entry, W drawn for A
        then for B (zero entries stay zero).

        Parameters
        ----------
        A, B : array_like
            The nominal matrices (n x n, n x m).

        Returns
        -------
        tuple of numpy.ndarray

        Examples
        --------
        >>> A, B = np.array([[0.0, 1.0], [-2.0, -3.0]]), np.array([[0.0], [1.0]])
        >>> A_p, B_p = MismatchSpec(0.1, "uniform", seed=1).perturb(A, B)
        >>> bool(A_p[0, 0] == 0.0 and abs(A_p[1, 0] / A[1, 0] - 1.0) <= 0.1)
        True
        >>> W = np.random.default_rng(1).uniform(-1.0, 1.0, size=6)
        >>> bool(np.allclose(B_p.ravel(), B.ravel() * (1 + 0.1 * W[4:])))
        True
        """
        A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
        rng = np.random.default_rng(self.seed)
        draw = rng.standard_normal if self.distribution == "gaussian" else (
            lambda size: rng.uniform(-1.0, 1.0, size=size))
        W_A, W_B = draw(A.shape), draw(B.shape)
        return A * (1.0 + self.size * W_A), B * (1.0 + self.size * W_B)


@dataclass(frozen=True)
class PlantSpec:
    """A validated plant and the observer's tuning parameters.

    Attributes
    ----------
    A, B, C : numpy.ndarray
        Plant matrices (n x n, n x m, k x n).
    E : numpy.ndarray or None
        Perturbation input matrix (n x r), if given.
    L_lin : numpy.ndarray or None
        A given Luenberger baseline gain (n x k); designed by LMI when None.
    nu : float
        Homogeneity degree.
    rho, gamma : float or None
        LMI decay parameter and xi-equation gain; None: chosen by the design to meet
        ``settling_time`` (gamma = rho).
    n_tilde : int
        Observability index of the observer's model (``(A, C)`` without a disturbance model).
    objective : str
        LMI objective (one of :data:`OBJECTIVES`).
    source : str
        Where the spec came from (file name), for messages.
    filter_scale : float
        Factor (>= 1) applied to the LMI's L_tilde (fast output filter); see
        :func:`fhobs.design.observer.design_for_spec`.
    disturbance_order : int
        Order of the disturbance model (0: none), see :mod:`fhobs.core.disturbance`.
    settling_time : float
        Requested time (s) for an initial error of the size of ``state_scale`` to fall to 1e-3
        of itself.
    state_scale : numpy.ndarray
        Typical size of each plant state (n entries).
    noise : NoiseSpec or None
        The ``[noise]`` table (the Kalman filter baseline), if given.
    disturbance : DisturbanceSpec or None
        The ``[disturbance]`` table (the q that ``harness plant`` feeds the plant), if given.
    mismatch : MismatchSpec or None
        The ``[mismatch]`` table (the plant FMU's perturbed A, B in ``harness plant``), if given.
    fast_mode_rate : float or None
        Decay rate (1/s) beyond which a stable mode is kept by the observers' model rather than
        homogenised (:mod:`fhobs.design.partial`); None: ``50 / settling_time``; inf: none.
    name : str
        The plant's name (the spec's ``name``, else the file's stem; ``"plant"`` for a dict).
    signals : SignalNames or None
        The ``[signals]`` table (:mod:`fhobs.design.signals`); None: see :attr:`names`.
    plant_model : PlantModelSpec or None
        The ``[plant_model]`` table (:mod:`fhobs.design.plant_model`), if given.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    E: np.ndarray | None
    L_lin: np.ndarray | None
    nu: float
    rho: float | None
    gamma: float | None
    n_tilde: int
    objective: str
    source: str = "<dict>"
    filter_scale: float = 1.0
    disturbance_order: int = 0
    settling_time: float = DEFAULT_SETTLING_TIME
    state_scale: np.ndarray | None = None
    noise: NoiseSpec | None = None
    disturbance: DisturbanceSpec | None = None
    mismatch: MismatchSpec | None = None
    fast_mode_rate: float | None = None
    name: str = "plant"
    signals: SignalNames | None = None
    plant_model: PlantModelSpec | None = None

    @property
    def sizes(self) -> dict[str, int]:
        """The number of states, inputs, outputs and unknown inputs, by signal group."""
        return {"states": self.A.shape[0], "inputs": self.B.shape[1],
                "outputs": self.C.shape[0],
                "unknown_inputs": 0 if self.E is None else self.E.shape[1]}

    @property
    def names(self) -> SignalNames:
        """The signals' names and units: the ``[signals]`` table's, or ``x[i]``, ``u[i]``,
        ``y[i]``, ``q[i]`` without units.

        Examples
        --------
        >>> spec = spec_from_dict({"A": [[0, 1], [0, 0]], "B": [[0], [1]], "C": [[1, 0]]})
        >>> spec.names.states, spec.name
        (('x[1]', 'x[2]'), 'plant')
        """
        return self.signals or signal_names({}, self.sizes, self.source)


def load_spec(path: str | Path, overrides: dict[str, Any] | None = None) -> PlantSpec:
    """Read and validate a plant spec TOML file.

    Parameters
    ----------
    path : str or Path
        The TOML file.
    overrides : dict, optional
        ``[observer]`` keys set on top of the file's (e.g. from the command line), validated
        like the file's.

    Returns
    -------
    PlantSpec

    Raises
    ------
    SpecError
        If the file is missing, not TOML, or any field is invalid.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "double_integrator.toml"
    >>> _ = path.write_text("A = [[0, 1], [0, 0]]\\nB = [[0], [1]]\\nC = [[1, 0]]\\n"
    ...                     "[observer]\\nrho = 2.0\\n")
    >>> spec = load_spec(path)
    >>> spec.n_tilde, spec.rho, spec.gamma
    (2, 2.0, None)
    >>> load_spec(path, overrides={"rho": -1.0})
    Traceback (most recent call last):
    ...
    fhobs.errors.SpecError: ...observer.rho = -1.0 must be > 0...
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        raise SpecError(f"{path}: not a regular file (a spec is a TOML file; folders, FIFOs "
                        "and devices are refused)")
    try:
        text = path.read_text()
    except OSError as exc:
        raise SpecError(f"{path}: cannot read the spec file ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise SpecError(
            f"{path}: not UTF-8 text (byte {exc.object[exc.start]:#04x} at offset {exc.start}); "
            "TOML files are UTF-8"
        ) from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML ({exc})") from exc
    source = str(path)
    if isinstance(data, dict):
        data.setdefault("name", path.stem)
    if overrides:
        observer = data.setdefault("observer", {})
        if isinstance(observer, dict):
            observer.update(overrides)
        source += f" (with {', '.join(sorted(overrides))} from the command line)"
    return spec_from_dict(data, source=source, base=path.parent)


def spec_from_dict(data: dict[str, Any], source: str = "<dict>",
                   base: Path | None = None) -> PlantSpec:
    """Validate a spec given as a dict (the parsed TOML).

    The tables are unpacked and handed to :func:`plant_spec`, the validation that
    :func:`fhobs.design.observer.design_observer` makes of its arguments; then the ``[noise]``
    table.

    Parameters
    ----------
    data : dict
        Keys ``A``, ``B``, ``C``, optional ``E``, ``L_lin``, ``observer`` and ``noise``; the
        matrices as lists of rows or 2-D numpy arrays.
    source : str
        Name used in error messages.
    base : pathlib.Path, optional
        The spec file's folder, against which ``[plant_model] path`` is resolved and checked.

    Returns
    -------
    PlantSpec

    Examples
    --------
    >>> import numpy as np
    >>> spec = spec_from_dict({"A": np.array([[0.0, 1.0], [0.0, 0.0]]), "B": [[0], [1]],
    ...                        "C": [[1, 0]], "observer": {"settling_time": 1.0}})
    >>> spec.n_tilde, round(spec.nu, 4), spec.rho
    (2, -0.3333, None)
    """
    _reject_unknown(data, TOP_KEYS, source, "")
    for name in ("A", "B", "C"):
        if name not in data:
            raise SpecError(f"{source}: {name} is missing (a matrix given as a list of rows)")
    obs = data.get("observer", {})
    if not isinstance(obs, dict):
        raise SpecError(f"{source}: observer must be a table, got {type(obs).__name__}")
    _reject_unknown(obs, OBSERVER_KEYS, source, "observer.")
    spec = plant_spec(data["A"], data["B"], data["C"], E=data.get("E"), L_lin=data.get("L_lin"),
                      source=source, prefix="observer.", **obs)
    if "noise" in data:
        spec = replace(spec, noise=_noise(data, spec.A, spec.B, spec.C, spec.E,
                                          spec.disturbance_order, source))
    if "disturbance" in data:
        spec = replace(spec, disturbance=_disturbance(data["disturbance"], spec.E, source))
    if "mismatch" in data:
        table = _table(data["mismatch"], "mismatch", source)
        _reject_unknown(table, MISMATCH_KEYS, source, "mismatch.")
        if "size" not in table:
            raise SpecError(f"{source}: mismatch.size is missing (the relative size of the "
                            "perturbation of A and B, e.g. 0.1)")
        spec = replace(spec, mismatch=mismatch_spec(
            table["size"], table.get("distribution", "gaussian"), table.get("seed", 0),
            source, "mismatch."))
    return _named(spec, data, base)


def _named(spec: PlantSpec, data: dict[str, Any], base: Path | None) -> PlantSpec:
    """``spec`` with the ``name``, ``[signals]`` and ``[plant_model]`` of ``data``."""
    name = data.get("name", spec.name)
    if not isinstance(name, str) or not name.strip() or not name.isprintable() or len(name) > 200:
        raise SpecError(f"{spec.source}: name = {name!r:.80} must be a non-empty line of text "
                        "(the plant's name, at most 200 characters)")
    signals = None
    if "signals" in data:
        table = _table(data["signals"], "signals", spec.source)
        _reject_unknown(table, SIGNAL_KEYS, spec.source, "signals.")
        signals = signal_names(table, spec.sizes, spec.source)
    plant_model = None
    if "plant_model" in data:
        table = _table(data["plant_model"], "plant_model", spec.source)
        _reject_unknown(table, PLANT_MODEL_KEYS, spec.source, "plant_model.")
        plant_model = plant_model_spec(table, spec.sizes, base, spec.source)
    return replace(spec, name=name, signals=signals, plant_model=plant_model)


def plant_spec(
    A: Any, B: Any, C: Any, *,
    E: Any = None,
    L_lin: Any = None,
    disturbance_order: int = 0,
    nu: float | None = None,
    rho: float | None = None,
    gamma: float | None = None,
    settling_time: float = DEFAULT_SETTLING_TIME,
    state_scale: Any = 1.0,
    filter_scale: float = 1.0,
    objective: str = DEFAULT_OBJECTIVE,
    fast_mode_rate: float | None = None,
    source: str = "design_observer",
    prefix: str = "",
) -> PlantSpec:
    """Validate a plant and the observer's tuning: the checks of every design.

    Parameters
    ----------
    A, B, C : array_like
        Plant matrices (n x n, n x m, k x n).
    E : array_like, optional
        Perturbation input matrix (n x r).
    L_lin : array_like, optional
        A given Luenberger baseline gain (n x k).
    disturbance_order, nu, rho, gamma, settling_time, state_scale, filter_scale, objective
        The tuning (:func:`fhobs.design.observer.design_observer`; ``nu`` None: -1/(n_tilde + 1)).
    fast_mode_rate : float, optional
        Stable modes decaying faster (1/s) are kept by the model (:mod:`fhobs.design.partial`);
        None: ``50 / settling_time``; ``math.inf``: every mode is homogenised.
    source : str
        Name used in error messages (the file, or the calling function).
    prefix : str
        Prefix of the tuning names in error messages (``"observer."`` for a spec file).

    Returns
    -------
    PlantSpec

    Raises
    ------
    SpecError
        Naming the argument and the reason.

    Examples
    --------
    >>> spec = plant_spec([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], rho=2.0)
    >>> spec.n_tilde, spec.gamma
    (2, None)
    >>> plant_spec([[0, 1], [0, 0]], [[0], [1]], [[1, 0, 0]])
    Traceback (most recent call last):
    ...
    fhobs.errors.SpecError: design_observer: C has 3 columns, expected 2 (the size of A)
    """
    A = _matrix(A, "A", source)
    n = _check_square(A, source)
    B = _matrix(B, "B", source, rows=n)
    C = _matrix(C, "C", source, cols=n)
    E = None if E is None else _matrix(E, "E", source, rows=n)
    L_lin = None if L_lin is None else _matrix(L_lin, "L_lin", source, rows=n)
    if L_lin is not None and L_lin.shape[1] != C.shape[0]:
        raise SpecError(
            f"{source}: L_lin has {L_lin.shape[1]} columns, but C has {C.shape[0]} rows (k)"
        )
    order = _disturbance_order(disturbance_order, E, source, prefix + "disturbance_order")
    A_model, _, C_model = extended_model(A, B, C, E, order)
    n_tilde, rank = observability_index(A_model, C_model)
    if n_tilde is None:
        what = "(A, C)" if order == 0 else f"the disturbance model of order {order} (A, E, C)"
        raise SpecError(
            f"{source}: {what} is not observable: the observability matrix has rank {rank}, "
            f"n = {A_model.shape[0]}; "
            + unobservable_text(A_model, C_model, n, 0 if E is None else E.shape[1], order)
        )
    nu = -1.0 / (n_tilde + 1) if nu is None else _scalar(nu, prefix + "nu", source)
    rho = None if rho is None else _scalar(rho, prefix + "rho", source)
    gamma = None if gamma is None else _scalar(gamma, prefix + "gamma", source)
    _check_tuning(nu, rho, gamma, n_tilde, source, prefix)
    settling_time = _scalar(settling_time, prefix + "settling_time", source)
    if not settling_time > 0.0:
        raise SpecError(
            f"{source}: {prefix}settling_time = {settling_time!r} must be > 0 (s)"
        )
    state_scale = _state_scale(state_scale, n, source, prefix + "state_scale")
    if objective not in OBJECTIVES:
        raise SpecError(
            f"{source}: {prefix}objective = {objective!r} is not one of {sorted(OBJECTIVES)}"
        )
    filter_scale = _scalar(filter_scale, prefix + "filter_scale", source)
    if filter_scale < 1.0:
        raise SpecError(f"{source}: {prefix}filter_scale = {filter_scale!r} must be >= 1")
    if fast_mode_rate is not None:
        label = prefix + "fast_mode_rate"
        if isinstance(fast_mode_rate, bool) or not isinstance(fast_mode_rate, (int, float)):
            raise SpecError(f"{source}: {label} = {fast_mode_rate!r} must be a number (1/s)")
        fast_mode_rate = float(fast_mode_rate)
        if not fast_mode_rate > 0.0:
            raise SpecError(f"{source}: {label} = {fast_mode_rate!r} must be > 0 (1/s; inf "
                            "homogenises every mode)")
    return PlantSpec(
        A, B, C, E, L_lin, nu, rho, gamma, n_tilde, objective, source, filter_scale, order,
        settling_time, state_scale, None, fast_mode_rate=fast_mode_rate,
    )


MAX_LISTED_DIRECTIONS = 3
"""An unobservable subspace is described by at most this many of its directions."""
MAX_LISTED_ENTRIES = 12
"""A direction's vector is printed only up to this many entries (its named terms always)."""


def unobservable_text(A_model: np.ndarray, C_model: np.ndarray, n: int, p: int,
                      order: int) -> str:
    """The unobservable directions of an observer's model, for an error message: each as a
    combination of named states (:func:`fhobs.core.disturbance.model_state_names`) and as a
    rounded vector.

    Parameters
    ----------
    A_model, C_model : numpy.ndarray
        The model (:func:`fhobs.core.disturbance.extended_model`).
    n, p, order : int
        Plant states, columns of E and disturbance order (to name the states).

    Returns
    -------
    str
        One sentence, '' if the model is observable.

    Examples
    --------
    Two integrators, q entering the second, only the first measured, q constant:

    >>> A_model, _, C_model = extended_model(np.zeros((2, 2)), np.eye(2)[:, :1],
    ...     np.array([[1.0, 0.0]]), np.array([[0.0], [1.0]]), 1)
    >>> unobservable_text(A_model, C_model, 2, 1, 1)
    'the outputs cannot see the directions x[2] (vector [0, 1, 0]) and q[1] (vector [0, 0, 1])'
    """
    directions = unobservable_directions(A_model, C_model).T
    if not directions.size:
        return ""
    names = model_state_names(n, p, order)
    shown = [
        f"{describe_direction(v, names)}" + (
            f" (vector [{', '.join(f'{x:.3g}' for x in v / v[np.argmax(np.abs(v))])}])"
            if len(v) <= MAX_LISTED_ENTRIES else "")
        for v in directions[:MAX_LISTED_DIRECTIONS]
    ]
    more = len(directions) - len(shown)
    if more:
        shown.append(f"{more} more")
    if len(shown) == 1:
        return f"the outputs cannot see the direction {shown[0]}"
    return f"the outputs cannot see the directions {', '.join(shown[:-1])} and {shown[-1]}"


def _state_scale(value: Any, n: int, source: str, label: str) -> np.ndarray:
    """``state_scale``: one positive number, or n of them."""
    if isinstance(value, np.ndarray | tuple):
        value = np.asarray(value).tolist()
    entries = value if isinstance(value, list) else [value]
    for i, entry in enumerate(entries, start=1):
        _check_entry(entry, f"{label}[{i}]", source)
        if not entry > 0:
            raise SpecError(f"{source}: {label}[{i}] = {entry!r} must be > 0")
    if len(entries) not in (1, n):
        raise SpecError(
            f"{source}: {label} has {len(entries)} entries, expected 1 or {n} "
            "(the number of states)"
        )
    return np.broadcast_to(np.array(entries, dtype=float), (n,)).copy()


def _disturbance_order(order: Any, E: np.ndarray | None, source: str, label: str) -> int:
    """A disturbance-model order: an integer in 0..MAX_DISTURBANCE_ORDER, > 0 only with E."""
    if isinstance(order, bool) or not isinstance(order, int | np.integer):
        raise SpecError(f"{source}: {label} = {order!r} is not an integer")
    order = int(order)
    if not 0 <= order <= MAX_DISTURBANCE_ORDER:
        raise SpecError(
            f"{source}: {label} = {order} is outside 0..{MAX_DISTURBANCE_ORDER}"
        )
    if order and E is None:
        raise SpecError(
            f"{source}: {label} = {order} needs E (where q enters the plant)"
        )
    return order


def _noise(data: dict[str, Any], A: np.ndarray, B: np.ndarray, C: np.ndarray,
           E: np.ndarray | None, observer_order: int, source: str) -> NoiseSpec:
    """The ``[noise]`` table (module docstring): validated, the amplitude turned into a std."""
    table = data["noise"]
    if not isinstance(table, dict):
        raise SpecError(f"{source}: noise must be a table, got {type(table).__name__}")
    _reject_unknown(table, NOISE_KEYS, source, "noise.")
    if E is None:
        raise SpecError(f"{source}: the [noise] table needs E (the Kalman filter's process noise "
                        "enters through it)")
    given = [key for key in ("measurement_std", "measurement_amplitude") if key in table]
    if len(given) != 1:
        raise SpecError(f"{source}: the [noise] table needs exactly one of "
                        f"noise.measurement_std and noise.measurement_amplitude, got {given}")
    key = given[0]
    values = table[key]
    k = C.shape[0]
    if not isinstance(values, list) or len(values) != k:
        raise SpecError(f"{source}: noise.{key} must be a list of {k} numbers (one per output)")
    for i, entry in enumerate(values, start=1):
        _check_entry(entry, f"noise.{key}[{i}]", source)
        if entry <= 0:
            raise SpecError(f"{source}: noise.{key}[{i}] = {entry!r} must be > 0")
    std = np.array(values, dtype=float) / (math.sqrt(3.0) if key == "measurement_amplitude" else 1)
    positive = {}
    for name in ("sample_time", "process_intensity"):
        if name not in table:
            raise SpecError(f"{source}: noise.{name} is missing (a positive number)")
        _check_entry(table[name], f"noise.{name}", source)
        if table[name] <= 0:
            raise SpecError(f"{source}: noise.{name} = {table[name]!r} must be > 0")
        positive[name] = float(table[name])
    order = _disturbance_order(table.get("disturbance_order", observer_order), E, source,
                               "noise.disturbance_order")
    A_model, _, C_model = extended_model(A, B, C, E, order)
    if observability_index(A_model, C_model)[0] is None:
        raise SpecError(f"{source}: noise.disturbance_order = {order}: the Kalman filter's "
                        "disturbance model (A, E, C) is not observable; "
                        + unobservable_text(A_model, C_model, A.shape[0], E.shape[1], order))
    return NoiseSpec(std, positive["sample_time"], positive["process_intensity"], order)


def mismatch_spec(size: Any, distribution: Any = "gaussian", seed: Any = 0,
                  source: str = "mismatch", prefix: str = "") -> MismatchSpec:
    """Validate a model mismatch (the ``[mismatch]`` table, or ``harness plant --mismatch``).

    Parameters
    ----------
    size : float
        Relative size, finite and >= 0.
    distribution : str
        One of :data:`MISMATCH_DISTRIBUTIONS`.
    seed : int
        Non-negative seed.
    source, prefix : str
        Named in error messages (``prefix`` before each field name).

    Returns
    -------
    MismatchSpec

    Raises
    ------
    SpecError
        Naming the field and the reason.

    Examples
    --------
    >>> mismatch_spec(0.05, seed=3)
    MismatchSpec(size=0.05, distribution='gaussian', seed=3)
    >>> mismatch_spec(-0.1, source="--mismatch")
    Traceback (most recent call last):
    ...
    fhobs.errors.SpecError: --mismatch: size = -0.1 must be >= 0 (a relative size, 0.1 = 10 %)
    """
    _check_entry(size, f"{prefix}size", source)
    if size < 0:
        raise SpecError(f"{source}: {prefix}size = {size!r} must be >= 0 (a relative size, "
                        "0.1 = 10 %)")
    if distribution not in MISMATCH_DISTRIBUTIONS:
        raise SpecError(f"{source}: {prefix}distribution = {distribution!r} is not one of "
                        f"{', '.join(MISMATCH_DISTRIBUTIONS)}")
    return MismatchSpec(float(size), distribution, _seed(seed, f"{prefix}seed", source))


def _table(value: Any, name: str, source: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise SpecError(f"{source}: {name} must be a table ([{name}]), got {type(value).__name__}")
    return value


def _seed(value: Any, label: str, source: str) -> int:
    """A seed: an integer >= 0."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise SpecError(f"{source}: {label} = {value!r} must be an integer >= 0")
    return int(value)


def _disturbance(table: Any, E: np.ndarray | None, source: str) -> DisturbanceSpec:
    """The ``[disturbance]`` table (module docstring), validated against E."""
    table = _table(table, "disturbance", source)
    _reject_unknown(table, DISTURBANCE_KEYS, source, "disturbance.")
    if E is None:
        raise SpecError(f"{source}: the [disturbance] table needs E (the unknown input q "
                        "enters the plant through it)")
    shape = table.get("shape")
    if shape not in DISTURBANCE_SHAPES:
        what = "is missing" if shape is None else f"= {shape!r} is not one of"
        raise SpecError(f"{source}: disturbance.shape {what} "
                        f"{', '.join(DISTURBANCE_SHAPES)}")
    if "size" not in table:
        raise SpecError(f"{source}: disturbance.size is missing (one number, or one per q "
                        f"channel: {E.shape[1]})")
    size = _disturbance_size(table["size"], E.shape[1], shape, source)
    start = table.get("start", 0.0)
    _check_entry(start, "disturbance.start", source)
    if start < 0:
        raise SpecError(f"{source}: disturbance.start = {start!r} must be >= 0 (s)")
    frequency = table.get("frequency")
    if shape == "sine":
        if frequency is None:
            raise SpecError(f"{source}: disturbance.frequency is missing (Hz; shape = 'sine' "
                            "needs it)")
        _check_entry(frequency, "disturbance.frequency", source)
        if frequency <= 0:
            raise SpecError(f"{source}: disturbance.frequency = {frequency!r} must be > 0 (Hz)")
        frequency = float(frequency)
    elif frequency is not None:
        raise SpecError(f"{source}: disturbance.frequency applies to shape = 'sine' only, "
                        f"not {shape!r}")
    if "seed" in table and shape != "random_walk":
        raise SpecError(f"{source}: disturbance.seed applies to shape = 'random_walk' only, "
                        f"not {shape!r}")
    seed = _seed(table.get("seed", 0), "disturbance.seed", source)
    return DisturbanceSpec(shape, size, float(start), frequency, seed)


def _disturbance_size(value: Any, r: int, shape: str, source: str) -> np.ndarray:
    """``disturbance.size``: one finite number or r of them (>= 0 for a random walk)."""
    entries = value if isinstance(value, list) else [value]
    if len(entries) not in (1, r):
        raise SpecError(f"{source}: disturbance.size has {len(entries)} entries, expected 1 or "
                        f"{r} (the columns of E, one per q channel)")
    for i, entry in enumerate(entries, start=1):
        label = f"disturbance.size[{i}]" if isinstance(value, list) else "disturbance.size"
        _check_entry(entry, label, source)
        if shape == "random_walk" and entry < 0:
            raise SpecError(f"{source}: {label} = {entry!r} must be >= 0 (the random walk's "
                            "intensity)")
    return np.broadcast_to(np.array(entries, dtype=float), (r,)).copy()


def unknown_key_text(key: str, allowed: tuple[str, ...], prefix: str = "",
                     quote: bool = False) -> str:
    """The message of an unknown key: its name (``repr`` with ``quote``), the closest allowed
    key if one is close, and the allowed keys.

    Examples
    --------
    >>> unknown_key_text("setling_time", ("settling_time", "rho"), "observer.")
    'unknown key observer.setling_time (did you mean settling_time? allowed: settling_time, rho)'
    """
    close = difflib.get_close_matches(key, allowed, n=1)
    show = (lambda name: repr(name)) if quote else (lambda name: name)  # noqa: E731
    hint = f"did you mean {show(close[0])}? " if close else ""
    return f"unknown key {show(prefix + key)} ({hint}allowed: {', '.join(allowed)})"


def _reject_unknown(table: dict[str, Any], allowed: tuple[str, ...], source: str, prefix: str):
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise SpecError(f"{source}: {unknown_key_text(unknown[0], allowed, prefix)}")


def _matrix(
    value: Any, name: str, source: str, rows: int | None = None, cols: int | None = None
) -> np.ndarray:
    """``value`` as a finite real matrix: a list of rows, or a 2-D array_like (taken as its
    rows)."""
    if isinstance(value, np.ndarray | tuple):
        value = np.asarray(value, dtype=object).tolist()
    if not isinstance(value, list) or not value or not all(isinstance(r, list) for r in value):
        raise SpecError(f"{source}: {name} must be a non-empty list of rows, e.g. [[1, 0], [0, 1]]")
    width = len(value[0])
    if width == 0:
        raise SpecError(f"{source}: {name} row 1 is empty")
    for i, row in enumerate(value, start=1):
        if len(row) != width:
            raise SpecError(
                f"{source}: {name} is ragged: row {i} has {len(row)} entries, row 1 has {width}"
            )
        for j, entry in enumerate(row, start=1):
            _check_entry(entry, f"{name}[{i},{j}]", source)
    matrix = np.array(value, dtype=float)
    if rows is not None and matrix.shape[0] != rows:
        raise SpecError(
            f"{source}: {name} has {matrix.shape[0]} rows, expected {rows} (the size of A)"
        )
    if cols is not None and matrix.shape[1] != cols:
        raise SpecError(
            f"{source}: {name} has {matrix.shape[1]} columns, expected {cols} (the size of A)"
        )
    return matrix


def _check_entry(entry: Any, label: str, source: str) -> None:
    if isinstance(entry, bool | np.bool_) or not isinstance(entry, int | float | np.number):
        raise SpecError(f"{source}: {label} = {entry!r} is not a number")
    if isinstance(entry, complex | np.complexfloating) or not math.isfinite(entry):
        raise SpecError(f"{source}: {label} = {entry!r} is not finite")


def _check_square(A: np.ndarray, source: str) -> int:
    n, cols = A.shape
    if n != cols:
        raise SpecError(f"{source}: A must be square, got {n} x {cols}")
    return n


def _scalar(value: Any, label: str, source: str) -> float:
    _check_entry(value, label, source)
    return float(value)


def _check_tuning(
    nu: float, rho: float | None, gamma: float | None, n_tilde: int, source: str, prefix: str
) -> None:
    """Enforce Theorem 2's ranges (:func:`fhobs.core.certificate.tuning_problem`, the check the
    FMUs make too) for the ones given."""
    problem = tuning_problem(nu, rho, gamma, n_tilde, prefix=prefix)
    if problem:
        raise SpecError(f"{source}: {problem}")
