"""``harness plant`` against the user's own plant model: the spec's ``[plant_model]`` FMU or
SSP instead of the generated ``plant.fmu``.

The model runs through its Co-Simulation interface: a single FMU as the system's FMU
``model``; an SSP's chosen (sub)system as its FMU components (extracted into ``DIR/fmus``,
named by their path in the system, dots made underscores), coupled as the SSD's connections
say (:mod:`harness.ssd`), their parameter bindings and the spec's ``plant_model.start`` as
start values, inputs that nothing feeds held at their start values. The enclosing systems'
other elements are not run.

The spec's A, B, C, E are Jacobians at the operating point (x_op, u_op, q_op, y_op) of the
model (:func:`operating_point`, recomputed by :func:`harness.linearize.linearize`), so the
estimators work in deviation coordinates (connections with offsets, :mod:`harness.system`):

- the model's input ``u = u_op + K (x - x_op)``, K the LQR of the spec's (A, B)
  (:func:`fhobs.design.feedback.state_feedback`) on the model's true state (its state
  variables, read from the FMUs: locals or outputs);
- its unknown inputs ``q_op + q(t)``, q(t) the spec's ``[disturbance]`` (a ``signal`` block);
- every estimator gets ``u - u_op`` and ``y - y_op`` plus the spec's ``[noise]``: a Gaussian
  draw of std ``measurement_std`` that the master adds on the connection (one per output and
  communication step, seeded by the run's seed, the same for every estimator);
- ``deviation.x = x - x_op`` (a derived signal) is what the estimates are compared with;
- the initial error has the size of ``state_scale``: the model's states start at
  ``x_op + state_scale`` when every state variable accepts a start value (a local or
  parameter with ``initial`` exact or approx), otherwise the estimators start at
  ``z0 = -state_scale`` and the model at its own start (:data:`INITIAL_ERRORS`);
- every FMU gets the run's tolerance in ``fmi2SetupExperiment``, by default
  :data:`MODEL_TOLERANCE`: a modelling tool's Co-Simulation FMU integrates over each
  communication step with its own solver at that relative tolerance (given none, the FMU
  takes its own default: on the README's Dymola motor the steady errors then differ by up to
  19 %), so the run, and an engine running its exported SSP with the same tolerance, see the
  model solved tightly rather than its solver's error.
"""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from fhobs.core.gains import ObserverDesign
from fhobs.design.feedback import state_feedback
from fhobs.design.plant_model import PlantModelSpec
from fhobs.design.spec import DisturbanceSpec
from fhobs.errors import FhobsError

from harness.fmu_files import description
from harness.me_fmu import closest
from harness.own_plant import (
    DISTURBANCE_BLOCK,
    estimator_kinds,
    q_hat_kinds,
    signal_start,
)
from harness.system import ConnectionSpec, Evaluation, FmuSpec, SystemSpec

MODEL = "model"
"""The system's name of a single-FMU model."""
DEVIATION = "deviation.x"
"""The derived signal x - x_op the estimates are compared with."""
INITIAL_ERRORS = {
    "model": "the model's states started at x_op + state_scale",
    "estimators": "the estimators started at z0 = -state_scale (the model's state variables "
                  "accept no start value)",
}
"""How the initial error of the size of state_scale is made, as the summary says it."""
MODEL_TOLERANCE = 1e-10
"""The relative tolerance a ``[plant_model]`` run passes to the FMUs by default (``harness
plant --tolerance``)."""


class PlantModelError(FhobsError, ValueError):
    """A ``[plant_model]`` that cannot be run: the message names the item and the reason."""


@dataclass(frozen=True)
class ModelPorts:
    """The model as the system's FMUs and where the spec's signals are in them.

    Attributes
    ----------
    fmus : dict
        FMU name -> file.
    start : dict
        FMU name -> start values (bindings, ``plant_model.start``, held inputs).
    couplings : tuple of ConnectionSpec
        The SSD's connections between the components.
    inputs, unknown_inputs : list of list of str
        Per u (q) entry, the ``"fmu.var"`` inputs it feeds.
    outputs, states : list of str
        The ``"fmu.var"`` of each y and x entry.
    settable : bool
        Whether every state variable accepts a start value.
    """

    fmus: dict[str, Path]
    start: dict[str, dict[str, Any]]
    couplings: tuple[ConnectionSpec, ...]
    inputs: list[list[str]]
    unknown_inputs: list[list[str]]
    outputs: list[str]
    states: list[str]
    settable: bool


@dataclass(frozen=True)
class OperatingPoint:
    """x_op, u_op, q_op, y_op: the point the spec's matrices are the Jacobians at."""

    x: np.ndarray
    u: np.ndarray
    q: np.ndarray
    y: np.ndarray


def model_ports(model: PlantModelSpec, folder: Path) -> ModelPorts:
    """Read the model's FMU or SSP (an SSP's component FMUs extracted into ``folder``) and
    find the spec's inputs, outputs, unknown inputs and states in it.

    Raises
    ------
    PlantModelError
        A missing or unreadable file, a Model-Exchange-only FMU, an unknown name (with the
        closest names), an SSP without the system.

    Examples
    --------
    >>> import sys, tempfile, harness
    >>> from fhobs.design.plant_model import plant_model_spec
    >>> sys.path.insert(0, str(Path(harness.__file__).parents[1] / "tests"))
    >>> from me_fmus import linear_fmu
    >>> fmu = linear_fmu(Path(tempfile.mkdtemp()) / "p.fmu", [[0, 1], [-2, -3]], [[0], [1]],
    ...                  [[1, 0]])
    >>> sizes = {"states": 2, "inputs": 1, "outputs": 1, "unknown_inputs": 0}
    >>> spec = plant_model_spec({"path": str(fmu), "inputs": ["u1"], "outputs": ["y1"],
    ...                          "states": ["x1", "x2"]}, sizes)
    >>> ports = model_ports(spec, fmu.parent)
    >>> ports.states, ports.inputs, ports.settable
    (['model.x1', 'model.x2'], [['model.u1']], True)
    """
    if not model.path.is_file():
        raise PlantModelError(f"plant_model.path: no such file {model.path}")
    if model.path.suffix.lower() == ".ssp":
        return _ssp_ports(model, folder)
    variables = _variables(MODEL, model.path)
    start = {MODEL: dict(model.start)}
    for name in model.start:
        _find(variables, name, MODEL, "plant_model.start")
    ports = {group: [f"{MODEL}.{_find(variables, name, MODEL, f'plant_model.{group}')}"
                     for name in getattr(model, group)]
             for group in ("inputs", "unknown_inputs", "outputs", "states")}
    return ModelPorts({MODEL: model.path}, start, (), [[p] for p in ports["inputs"]],
                      [[p] for p in ports["unknown_inputs"]], ports["outputs"],
                      ports["states"], _settable({MODEL: variables}, ports["states"]))


def operating_point(model: PlantModelSpec) -> OperatingPoint:
    """x_op, u_op, q_op, y_op of the model (its start values and ``plant_model.start``,
    simulated to ``plant_model.at``), by :func:`harness.linearize.linearize`, the states in
    the spec's order.

    Raises
    ------
    PlantModelError
        The linearisation's refusal (a LinearizeError or SsdError), or a state the
        linearisation does not name.
    """
    from harness.linearize import linearize

    m = len(model.inputs)
    try:
        lin = linearize(model.path, list(model.inputs), list(model.outputs),
                        list(model.unknown_inputs), system=model.system, at=model.at,
                        start=dict(model.start))
    except FhobsError as err:
        raise PlantModelError(f"the operating point of {model.path.name}: {err}") from None
    missing = [name for name in model.states if name not in lin.states]
    if missing:
        raise PlantModelError(f"plant_model.states names {missing[0]!r}, which is no state of "
                              f"the model (its states: {', '.join(lin.states)})")
    x = np.array([lin.x[lin.states.index(name)] for name in model.states])
    return OperatingPoint(x, np.asarray(lin.u[:m]), np.asarray(lin.u[m:]), np.asarray(lin.y))


def plant_model_system(design: ObserverDesign, fmus: dict[str, Path], ports: ModelPorts,
                       point: OperatingPoint, state_scale: np.ndarray, stop_time: float,
                       step: float, *, measurement_std: np.ndarray | None = None,
                       disturbance: DisturbanceSpec | None = None, settled: float | None = None,
                       name: str = "plant_model") -> tuple[SystemSpec, str]:
    """The closed loop of the model and the estimators (module docstring).

    Parameters
    ----------
    design : ObserverDesign
        The design the estimator FMUs were built from (its plant: the spec's A, B, C, E).
    fmus : dict
        ``{kind: path}`` of the estimator FMUs (a ``plant`` entry is not used).
    ports : ModelPorts
        The model (:func:`model_ports`).
    point : OperatingPoint
        Its operating point (:func:`operating_point`).
    state_scale : numpy.ndarray
        The initial error's size (n).
    stop_time, step : float
        Run length and communication step (s).
    measurement_std : numpy.ndarray, optional
        Noise added to the measured outputs (k); none without.
    disturbance : DisturbanceSpec, optional
        q(t) added to q_op.
    settled : float, optional
        ``T_s``: the evaluation's windows ``[0, T_s]`` and ``[T_s, stop_time]``.
    name : str
        The system's name (the plant's).

    Returns
    -------
    tuple
        The system and the key of :data:`INITIAL_ERRORS` it uses.
    """
    A, B = np.asarray(design.plant.A, dtype=float), np.asarray(design.plant.B, dtype=float)
    K = state_feedback(A, B)
    n = A.shape[0]
    initial = "model" if ports.settable else "estimators"
    start = {fmu: dict(values) for fmu, values in ports.start.items()}
    for target in (*(t for ts in ports.inputs for t in ts),
                   *(t for ts in ports.unknown_inputs for t in ts)):
        fmu, _, var = target.partition(".")  # their start values set the operating point
        start[fmu].pop(var, None)
    if initial == "model":
        for signal, value in zip(ports.states, point.x + state_scale, strict=True):
            fmu, _, var = signal.partition(".")
            start[fmu][var] = float(value)
    noisy = measurement_std is not None and bool(np.any(np.asarray(measurement_std) > 0.0))
    kinds = estimator_kinds(design, fmus, step, noisy)
    specs = {fmu: FmuSpec(fmu, path, start[fmu]) for fmu, path in ports.fmus.items()}
    z0 = {} if initial == "model" else {f"z0[{i + 1}]": float(-s)
                                        for i, s in enumerate(state_scale)}
    specs |= {kind: FmuSpec(kind, fmus[kind], dict(z0)) for kind in kinds}
    states = tuple(ports.states)
    connections = list(ports.couplings)
    for i, targets in enumerate(ports.inputs):
        connections += [ConnectionSpec(states, target, K[i:i + 1], point.x,
                                       np.array([point.u[i]])) for target in targets]
    r = len(ports.unknown_inputs)
    for j, targets in enumerate(ports.unknown_inputs):
        for target in targets:
            if disturbance is None:
                fmu, _, var = target.partition(".")
                specs[fmu].start[var] = float(point.q[j])
            else:
                connections.append(ConnectionSpec(f"{DISTURBANCE_BLOCK}.y", target,
                                                  np.eye(r)[j:j + 1], None,
                                                  np.array([point.q[j]])))
    if disturbance is not None and r:
        specs[DISTURBANCE_BLOCK] = FmuSpec(DISTURBANCE_BLOCK, None, signal_start(disturbance),
                                           block=("signal", (r,)))
    std = np.asarray(measurement_std, dtype=float) if noisy else None
    for kind in kinds:
        connections += [ConnectionSpec(tuple(ports.outputs), f"{kind}.y", None, point.y,
                                       noise=std),
                        ConnectionSpec(states, f"{kind}.u", K, point.x)]
    with_q = q_hat_kinds(design)
    record = (DEVIATION, *states, *(f"{kind}.x_hat" for kind in kinds),
              *(f"{kind}.q_hat" for kind in kinds if kind in with_q))
    windows = ((stop_time / 2, stop_time),)
    if settled is not None:
        windows = ((0.0, settled),) + (((settled, stop_time),) if settled < stop_time else ())
    system = SystemSpec(
        name=name, fmus=specs, connections=tuple(connections), step=step, stop_time=stop_time,
        record=record, derived=(ConnectionSpec(states, DEVIATION, np.eye(n), point.x),),
        evaluation=Evaluation(windows=windows, errors={
            label: (DEVIATION, f"{kind}.x_hat") for kind, label in kinds.items()}))
    return system, initial


def run_plant_model(spec: Any, design: ObserverDesign, out: Path, *, step: float,
                    stop_time: float, settled: float, seed: int | None = None,
                    plots: bool = True, csv_every: int = 1, native: bool = False,
                    block_cache: Path | None = None,
                    export: Callable[[SystemSpec], None] | None = None,
                    tolerance: float | None = MODEL_TOLERANCE) -> dict[str, Any]:
    """``harness plant`` with a ``[plant_model]``: the model checked and its operating point
    found (nothing written before), the estimator FMUs built into ``out/fmus`` (native ones
    too with ``native``), the model's FMUs beside them in ``out/fmus/model`` (an SSP's), the
    loop run and written (:func:`harness.own_plant.run_own_plant`).

    Parameters
    ----------
    spec : fhobs.design.spec.PlantSpec
        The loaded spec (with ``plant_model``; no ``[mismatch]``).
    design : ObserverDesign
        Its design.
    out : Path
        The results folder.
    step, stop_time, settled : float
        Communication step, run length and the end of the transient window (s).
    seed : int, optional
        The noise seed (default 0).
    plots, csv_every, native, block_cache
        As for the plant command.
    export : callable, optional
        Called with the run's system (blocks built, the run's seed set) before the run
        (``--export-ssp``).
    tolerance : float, optional
        The relative tolerance of every FMU's ``fmi2SetupExperiment`` (None: none given).

    Returns
    -------
    dict
        The summary, its ``plant_model`` item from :func:`about_model`.
    """
    from fhobs.build import build_fmus

    from harness.own_plant import run_own_plant
    from harness.system import build_blocks

    model = spec.plant_model
    if spec.mismatch is not None:
        raise PlantModelError("[mismatch] (or --mismatch) perturbs the generated plant.fmu; "
                              "with a [plant_model] the model is the plant: remove one of them")
    ports, scratch = checked_ports(model)
    with scratch:
        point = operating_point(model)
        std = None if spec.noise is None else np.asarray(spec.noise.measurement_std)
        kinds = [kind for kind in estimator_kinds(design, {k: None for k in _built(design)},
                                                  step, std is not None)]
        options = {"h": step, "T0": spec.settling_time}
        names = {"names": spec.names, "plant_name": spec.name}
        fmus = build_fmus(design, out / "fmus", kinds=kinds, **names, **options)
        if native:
            from fhobs.native.build import build_native_fmus

            fmus |= build_native_fmus(design, out / "fmus" / "native", steps=(step,),
                                      kinds=kinds, **names, **options)
        ports = install_fmus(ports, out / "fmus" / "model")
    system, initial = plant_model_system(
        design, fmus, ports, point, np.asarray(spec.state_scale, dtype=float), stop_time, step,
        measurement_std=std, disturbance=spec.disturbance, settled=settled,
        name=spec.name or model.path.stem)
    system = replace(system, tolerance=tolerance)
    about = {"plant_model": about_model(model, spec.names, point, initial),
             "tolerance": tolerance}
    if spec.disturbance is not None:
        about["disturbance"] = {**vars(spec.disturbance), "size": spec.disturbance.size.tolist()}
    seed = (0 if seed is None else seed) if std is not None else None
    system = build_blocks(system, block_cache)
    if export is not None:
        export(system if seed is None else system.with_seed(seed))
    return run_own_plant(system, out, settled=settled, channels=len(model.unknown_inputs),
                         seed=seed, plots=plots, csv_every=csv_every, about=about, names=spec.names)


def state_table(data: dict[str, Any]) -> str:
    """The per-state table of a model run: one row per estimator, the steady-window RMS
    error of each state (``x_rms_states``), the columns named from the model.

    Examples
    --------
    >>> data = {"plant_model": {"states": ["inductor.i [A]", "phi [rad]"]},
    ...         "homogeneous": {"x_rms_states": [1e-3, 2e-5]}}
    >>> print(state_table(data))
    RMS error, steady  inductor.i [A]  phi [rad]
    homogeneous        1.000e-03       2.000e-05
    """
    names = data["plant_model"]["states"]
    rows = [["RMS error, steady", *names]] + [
        [label, *(f"{v:.3e}" for v in figures["x_rms_states"])]
        for label, figures in data.items()
        if isinstance(figures, dict) and "x_rms_states" in figures]
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
                     for row in rows)


def _built(design: ObserverDesign) -> tuple[str, ...]:
    from fhobs.build import default_kinds

    return tuple(kind for kind in default_kinds(design) if kind != "plant")


def install_fmus(ports: ModelPorts, folder: Path) -> ModelPorts:
    """``ports`` with its extracted FMUs (an SSP's) copied into ``folder`` (``DIR/fmus``);
    a single FMU stays where it is."""
    if set(ports.fmus) == {MODEL}:
        return ports
    folder.mkdir(parents=True, exist_ok=True)
    fmus = {}
    for fmu, path in ports.fmus.items():
        fmus[fmu] = folder / path.name
        shutil.copyfile(path, fmus[fmu])
    return ModelPorts(fmus, ports.start, ports.couplings, ports.inputs, ports.unknown_inputs,
                      ports.outputs, ports.states, ports.settable)


def checked_ports(model: PlantModelSpec) -> tuple[ModelPorts, tempfile.TemporaryDirectory]:
    """:func:`model_ports` into a temporary folder (nothing written in the results folder
    before the model is known to run); the folder is removed when the returned handle is
    cleaned up or collected."""
    folder = tempfile.TemporaryDirectory(prefix="plant_model_")
    try:
        return model_ports(model, Path(folder.name)), folder
    except BaseException:
        folder.cleanup()
        raise


def about_model(model: PlantModelSpec, names: Any, point: OperatingPoint,
                initial: str) -> dict[str, Any]:
    """The summary's ``plant_model`` item: the model, the names and the operating point."""
    return {"path": str(model.path), "system": model.system,
            "states": [names.label("states", i) for i in range(len(model.states))],
            "inputs": [names.label("inputs", i) for i in range(len(model.inputs))],
            "outputs": [names.label("outputs", i) for i in range(len(model.outputs))],
            "unknown_inputs": [names.label("unknown_inputs", i)
                               for i in range(len(model.unknown_inputs))],
            "model_states": list(model.states), "at": model.at,
            "operating_point": {"x": point.x.tolist(), "u": point.u.tolist(),
                                "q": point.q.tolist(), "y": point.y.tolist()},
            "initial_error": INITIAL_ERRORS[initial]}


def _variables(fmu: str, path: Path) -> dict[str, Any]:
    """The variables of the FMU at ``path``; PlantModelError unless it is an FMI 2.0 FMU
    with a Co-Simulation interface."""
    try:
        md = description(path)
    except Exception as err:  # noqa: BLE001 - any unreadable file is reported the same way
        raise PlantModelError(f"plant_model: {fmu} ({path.name}) is not a readable FMU "
                              f"({type(err).__name__}: {err})") from None
    if md.fmiVersion != "2.0":
        raise PlantModelError(f"plant_model: {fmu} ({path.name}) is an FMI {md.fmiVersion} "
                              "FMU; harness plant runs FMI 2.0 FMUs")
    if md.coSimulation is None:
        raise PlantModelError(
            f"plant_model: {fmu} ({path.name}) is a Model-Exchange-only FMU, and harness plant "
            "runs the model through its Co-Simulation interface: export the model with "
            "Co-Simulation as well (most tools write both), or give the spec no [plant_model] "
            "to run the estimators against the generated plant.fmu")
    return {v.name: v for v in md.modelVariables}


def _find(variables: dict[str, Any], name: str, fmu: str, key: str) -> str:
    if name not in variables:
        raise PlantModelError(f"{key} names {name!r}, which {fmu} does not have"
                              f"{closest(name, list(variables))}")
    return name


def _start_value(variable: Any) -> float | int | bool:
    """A variable's declared start value as a number (0 when it declares none)."""
    text = variable.start
    if variable.type == "Boolean":
        return str(text).strip() in ("true", "1", "True")
    if variable.type in ("Integer", "Enumeration"):
        return int(text or 0)
    return float(text or 0.0)


def _settable(variables: dict[str, dict[str, Any]], signals: list[str]) -> bool:
    for signal in signals:
        fmu, _, var = signal.partition(".")
        v = variables[fmu][var]
        if v.variability == "constant" or v.causality not in ("local", "parameter") or (
                v.initial not in ("exact", "approx") and v.causality == "local"):
            return False
    return True


def _ssp_ports(model: PlantModelSpec, folder: Path) -> ModelPorts:
    from harness.ssd import Endpoint, SsdError, find_system, read_ssp, wiring

    try:
        structure = read_ssp(model.path)
        system = find_system(structure, model.system)
        wired = wiring(system)
    except SsdError as err:
        raise PlantModelError(f"plant_model: {err}") from None
    names = {path: path.replace(".", "_") for path in wired.components}
    variables = {}
    with zipfile.ZipFile(model.path) as archive:
        for path, comp in wired.components.items():
            target = folder / f"{names[path]}.fmu"
            try:
                with archive.open(comp.source) as src, open(target, "wb") as dst:
                    shutil.copyfileobj(src, dst)
            except KeyError:
                raise PlantModelError(f"plant_model: {model.path.name}: component {path!r} "
                                      f"refers to {comp.source!r}, which the SSP does not "
                                      "hold") from None
            variables[names[path]] = _variables(path, target)
    start = {names[p]: dict(comp.parameters) for p, comp in wired.components.items()}

    def scalar(key: str, signal: str) -> str:
        owner = next((p for p in sorted(wired.components, key=len, reverse=True)
                      if signal.startswith(p + ".")), None)
        if owner is None:
            raise PlantModelError(f"{key} names {signal!r}: the system has no such component "
                                  f"(its components: {', '.join(wired.components)})"
                                  f"{closest(signal.partition('.')[0], list(wired.components))}")
        fmu = names[owner]
        return f"{fmu}.{_find(variables[fmu], signal[len(owner) + 1:], owner, key)}"

    for key, value in model.start.items():
        fmu, _, var = scalar("plant_model.start", key).partition(".")
        start[fmu][var] = value
    feeds = {target: source for target, source in wired.sources.items() if target.component}
    ports = {group: [[f"{names[t.component]}.{t.connector}" for t, s in feeds.items()
                      if not s.component and s.connector == port]
                     for port in getattr(model, group)]
             for group in ("inputs", "unknown_inputs")}
    for group, targets in ports.items():
        for port, fed in zip(getattr(model, group), targets, strict=True):
            connector = system.connectors.get(port)
            if connector is None or connector.kind != "input" or not fed:
                have = [c.name for c in system.connectors.values() if c.kind == "input"]
                raise PlantModelError(f"plant_model.{group} names {port!r}, which is no input "
                                      f"connector of {system.name} feeding a component (its "
                                      f"inputs: {', '.join(have) or 'none'})"
                                      f"{closest(port, have)}")
    couplings = tuple(ConnectionSpec(f"{names[s.component]}.{s.connector}",
                                     f"{names[t.component]}.{t.connector}")
                      for t, s in feeds.items() if s.component)
    fed = {f"{names[t.component]}.{t.connector}" for t, s in feeds.items()
           if s.component or s.connector in (*model.inputs, *model.unknown_inputs)}
    for fmu, table in variables.items():
        for var, v in table.items():
            if v.causality == "input" and f"{fmu}.{var}" not in fed and var not in start[fmu]:
                start[fmu][var] = _start_value(v)
    outputs = []
    for name in model.outputs:
        source = wired.sources.get(Endpoint("", name))
        outputs.append(scalar("plant_model.outputs",
                              f"{source.component}.{source.connector}"
                              if source is not None and source.component else name))
    states = [scalar("plant_model.states", name) for name in model.states]
    return ModelPorts({names[p]: folder / f"{names[p]}.fmu" for p in wired.components}, start,
                      couplings, ports["inputs"], ports["unknown_inputs"], outputs, states,
                      _settable(variables, states))
