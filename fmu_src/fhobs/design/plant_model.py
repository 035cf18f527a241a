"""The user's own plant model: the spec's ``[plant_model]`` table.

``python -m harness linearize`` writes it next to the matrices it took from a plant FMU or SSP;
``python -m harness plant`` then runs the estimators against that model instead of the
generated ``plant.fmu``. The design never reads it::

    [plant_model]
    path = "dcmotor.ssp"          # an FMU (.fmu) or an SSP (.ssp), relative to the spec's folder
    system = "DC-Motor.SuT"       # SSP only: the (sub)system whose connectors are the ports;
                                  # default: the SSD's top-level system
    inputs = ["U"]                # the model's variables (FMU) or connectors (SSP), in the
    outputs = ["phiB"]            # order of B's columns, C's rows, E's columns and A's rows
    unknown_inputs = ["M_load"]   # (SSP states: "component.variable")
    states = ["emachine_model.inductor.i", "edrive_mass.inertia.phi", "edrive_mass.inertia.w"]
    start = { "edrive_mass.inertia.J" = 0.01 }   # start values set before initialisation
    at = 0.0                      # s: the operating time the model was linearised at
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import SpecError

PLANT_MODEL_KEYS = ("path", "system", "inputs", "outputs", "unknown_inputs", "states", "start",
                    "at")
"""The keys of the ``[plant_model]`` table."""
MODEL_SUFFIXES = (".fmu", ".ssp")
"""The model files a ``[plant_model]`` may name."""


@dataclass(frozen=True)
class PlantModelSpec:
    """Where the plant's own model is and how its variables map onto the spec's matrices.

    Attributes
    ----------
    path : pathlib.Path
        The FMU or SSP (resolved against the spec's folder when loaded from a file).
    system : str or None
        SSP only: the dotted path of the (sub)system whose connectors are the ports.
    inputs, outputs, unknown_inputs, states : tuple of str
        The model's names of u (B's columns), y (C's rows), q (E's columns) and x (A's rows).
    start : dict
        Start values (name -> number, bool or string) set before initialisation.
    at : float
        The operating time (s) of the linearisation.
    """

    path: Path
    system: str | None
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    unknown_inputs: tuple[str, ...]
    states: tuple[str, ...]
    start: dict[str, float | int | bool | str] = field(default_factory=dict)
    at: float = 0.0


def plant_model_spec(table: Any, sizes: dict[str, int], base: Path | None = None,
                     source: str = "<dict>") -> PlantModelSpec:
    """Validate a ``[plant_model]`` table against the plant's sizes.

    Parameters
    ----------
    table : dict
        The table (module docstring; its keys checked by the spec loader against
        :data:`PLANT_MODEL_KEYS`).
    sizes : dict
        ``{"states": n, "inputs": m, "outputs": k, "unknown_inputs": r}``.
    base : pathlib.Path, optional
        The spec file's folder: a relative ``path`` is taken from there and must exist. None
        (a spec given as a dict): the path is kept as given and not checked.
    source : str
        Name used in error messages.

    Returns
    -------
    PlantModelSpec

    Raises
    ------
    SpecError
        Naming the key and the reason.

    Examples
    --------
    >>> sizes = {"states": 2, "inputs": 1, "outputs": 1, "unknown_inputs": 0}
    >>> model = plant_model_spec({"path": "plant.fmu", "inputs": ["u"], "outputs": ["y"],
    ...                           "states": ["x1", "x2"]}, sizes)
    >>> model.path.name, model.system, model.at
    ('plant.fmu', None, 0.0)
    >>> plant_model_spec({"path": "plant.fmu", "inputs": [], "outputs": ["y"],
    ...                   "states": ["x1", "x2"]}, sizes)
    Traceback (most recent call last):
    ...
    fhobs.errors.SpecError: <dict>: plant_model.inputs has 0 entries, expected 1 (the inputs ...
    """
    for key in ("path", "inputs", "outputs", "states"):
        if key not in table:
            raise SpecError(f"{source}: plant_model.{key} is missing (the model file and the "
                            "names of its inputs, outputs and states: `python -m harness "
                            "linearize` writes them)")
    path = _path(table["path"], base, source)
    system = table.get("system")
    if system is not None and (not isinstance(system, str) or not system.strip()):
        raise SpecError(f"{source}: plant_model.system = {system!r} must be a non-empty string "
                        "(the dotted path of an SSP's system, e.g. \"DC-Motor.SuT\")")
    if system is not None and path.suffix.lower() != ".ssp":
        raise SpecError(f"{source}: plant_model.system is given but {path.name} is not an SSP "
                        "(an FMU has no systems: remove the key)")
    names = {group: _names(table.get(group, []), sizes[group], f"plant_model.{group}", group,
                           source) for group in sizes}
    return PlantModelSpec(path=path, system=system, start=_start(table.get("start", {}), source),
                          at=_time(table.get("at", 0.0), source), **names)


def _path(value: Any, base: Path | None, source: str) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise SpecError(f"{source}: plant_model.path = {value!r} must be a file name (an FMU "
                        "or an SSP)")
    path = Path(value)
    if path.suffix.lower() not in MODEL_SUFFIXES:
        raise SpecError(f"{source}: plant_model.path = {value!r} is neither an FMU (.fmu) nor "
                        "an SSP (.ssp)")
    if base is None:
        return path
    path = path if path.is_absolute() else base / path
    if not path.is_file():
        raise SpecError(f"{source}: plant_model.path = {value!r}: no such file ({path})")
    return path


def _names(value: Any, count: int, label: str, group: str, source: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) and v.strip() for v in value):
        raise SpecError(f"{source}: {label} must be a list of the model's variable names, got "
                        f"{value!r:.80}")
    if len(value) != count:
        plural = "entry" if len(value) == 1 else "entries"
        raise SpecError(f"{source}: {label} has {len(value)} {plural}, expected {count} (the "
                        f"{group.replace('_', ' ')} of the plant)")
    repeated = sorted({name for name in value if value.count(name) > 1})
    if repeated:
        raise SpecError(f"{source}: {label} names {repeated[0]!r} more than once")
    return tuple(value)


def _start(value: Any, source: str) -> dict[str, float | int | bool | str]:
    if not isinstance(value, dict):
        raise SpecError(f"{source}: plant_model.start must be a table of start values "
                        f"(name = value), got {type(value).__name__}")
    for name, item in value.items():
        if not isinstance(item, bool | int | float | str) or (
                isinstance(item, float) and not math.isfinite(item)):
            raise SpecError(f"{source}: plant_model.start.{name} = {item!r} must be a finite "
                            "number, a boolean or a string")
    return dict(value)


def _time(value: Any, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
            0.0 <= value < math.inf):
        raise SpecError(f"{source}: plant_model.at = {value!r} must be a finite time >= 0 (s)")
    return float(value)
