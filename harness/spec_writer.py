"""A linearised plant (:class:`harness.linearize.Linearization`) written as a plant spec TOML
file that ``build_fmu.py`` and ``python -m harness plant`` read: A, B, C (E with unknown
inputs), an ``[observer]`` table, the plant's ``name``, its ``[signals]`` (names and units
of the states, inputs, outputs and unknown inputs) and its ``[plant_model]`` (the model file,
relative to the spec's folder, and how it was linearised), with comments saying how the
matrices were obtained and how accurate they are.

The ``[observer]`` defaults:

- ``settling_time`` = 3 / (the decay rate of the plant's slowest stable mode): the observer
  settles in the time the plant's own slowest stable mode falls to e^-3 (5 %); without a
  stable mode it is left to the design's default;
- ``state_scale``: the larger of each state's ``nominal`` value (1 where the model declares
  none) and how far the state moves within that settling time (2 s without one) after a step
  of every input by its size at the operating point (at least 1): a state's typical size in
  its own unit, which the nominal values alone may not give (a solver's scale, e.g. 1e-4 rad).

Only the small subset of TOML the spec needs is written (no TOML writer is installed):
numbers as ``repr(float)`` (which reads back to the same double), strings with JSON's escapes
(valid TOML basic strings), arrays, inline tables.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import scipy.linalg

from harness.linearize import Linearization
from harness.writing import write_text

SETTLING_MODES = 3.0
"""settling_time = SETTLING_MODES / the slowest stable decay rate."""
DEFAULT_HORIZON = 2.0
"""The horizon (s) of :func:`state_scale` for a plant without a stable mode."""


def toml_value(value: Any) -> str:
    """One TOML value: a float (``repr``), an int, a bool, a string, a list or a dict
    (inline table).

    Examples
    --------
    >>> toml_value([[1.0, -2.5e-07], [float("inf"), 3]])
    '[[1.0, -2.5e-07], [inf, 3]]'
    >>> toml_value({"edrive.J": 0.01, "on": True, "tag": 'a"b'})
    '{ "edrive.J" = 0.01, "on" = true, "tag" = "a\\\\"b" }'
    """
    if isinstance(value, bool | np.bool_):
        return "true" if value else "false"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        number = float(value)
        if math.isnan(number):
            return "nan"
        return repr(number)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, dict):
        items = ", ".join(f"{json.dumps(str(k))} = {toml_value(v)}" for k, v in value.items())
        return "{ " + items + " }" if items else "{}"
    if isinstance(value, list | tuple | np.ndarray):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {type(value).__name__}")


def matrix_lines(name: str, M: np.ndarray) -> list[str]:
    """``NAME = [[...], ...]``, one row per line.

    Examples
    --------
    >>> print("\\n".join(matrix_lines("B", np.array([[0.0], [1.0]]))))
    B = [
      [0.0],
      [1.0],
    ]
    """
    return [f"{name} = ["] + [f"  {toml_value(list(map(float, row)))}," for row in M] + ["]"]


def state_scale(A: np.ndarray, B: np.ndarray, nominal: np.ndarray, input_size: np.ndarray,
                horizon: float) -> np.ndarray:
    """Each state's typical size: the larger of its ``nominal`` value and the largest move
    ``|x_i(t)|``, t in [0, horizon], of the linear plant from rest after a step of each input by
    ``input_size`` (inputs taken one at a time, moves added), sampled at 50 instants.

    Examples
    --------
    A current i' = (u - 0.5 i) / 1e-3 and an angle integrating it, 1 V for 1 s:

    >>> A, B = np.array([[-500.0, 0.0], [1.0, 0.0]]), np.array([[1000.0], [0.0]])
    >>> [round(float(v), 3) for v in state_scale(A, B, np.array([1e-4, 1e-4]), np.ones(1), 1.0)]
    [2.0, 1.996]
    """
    n, m = B.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n], big[:n, n:] = A, B * input_size
    moves = np.zeros(n)
    for t in np.linspace(0.0, horizon, 51)[1:]:
        step = scipy.linalg.expm(big * t)[:n, n:]  # x(t) after unit steps of each input
        moves = np.maximum(moves, np.abs(step).sum(axis=1))
    return np.maximum(np.asarray(nominal, dtype=float), moves)


def _input_size(lin: Linearization) -> np.ndarray:
    """max(|u at the operating point|, 1) per input."""
    m = lin.B.shape[1]
    u_op = np.zeros(m) if lin.u is None else np.abs(np.asarray(lin.u, dtype=float)[:m])
    return np.maximum(u_op, 1.0)


def settling_time(A: np.ndarray) -> float | None:
    """:data:`SETTLING_MODES` over the decay rate of A's slowest stable mode (None without a
    stable mode).

    Examples
    --------
    >>> settling_time(np.array([[-2.0, 0.0], [0.0, -50.0]]))
    1.5
    >>> settling_time(np.array([[0.0, 1.0], [0.0, 0.0]])) is None
    True
    """
    rates = -np.linalg.eigvals(A).real
    scale = max(float(np.max(np.abs(rates), initial=0.0)), 1.0)
    stable = rates[rates > 1e-9 * scale]
    return float(SETTLING_MODES / np.min(stable)) if stable.size else None


def spec_text(lin: Linearization, spec_path: Path) -> str:
    """The spec file's text for ``lin`` written at ``spec_path`` (see the module)."""
    model_path = os.path.relpath(Path(lin.model).resolve(), Path(spec_path).resolve().parent)
    lines = [f"# {lin.name}: linearised from {Path(lin.model).name} by python -m harness "
             "linearize",
             f"# at t = {lin.time!r}, x = {toml_value(list(map(float, lin.x)))}",
             f"# method: {lin.method}; accuracy: {_accuracy_text(lin)}"]
    if not lin.equilibrium:
        lines.append(f"# dx/dt = {toml_value(list(map(float, lin.dx)))} there: not an "
                     "equilibrium, the matrices linearise the model about this point of a "
                     "trajectory")
    lines += [f"name = {toml_value(lin.name)}", ""]
    for name in ("A", "B", "C"):
        lines += matrix_lines(name, getattr(lin, name))
    if lin.E is not None:
        lines += matrix_lines("E", lin.E)
    settle = settling_time(lin.A)
    lines += ["", "[observer]"]
    if settle is None:
        lines.append("# settling_time: the design's default (the plant has no stable mode "
                     "to take it from)")
    else:
        lines += ["# 3 / the decay rate of the plant's slowest stable mode",
                  f"settling_time = {settle!r}"]
    scale = state_scale(lin.A, lin.B, lin.state_nominal, _input_size(lin),
                        DEFAULT_HORIZON if settle is None else settle)
    lines += ["# the larger of each state's nominal value and its move within the settling time "
              "after a step of every input by max(|u_op|, 1)",
              f"state_scale = {toml_value(list(map(float, scale)))}", "",
              "[signals]",
              f"states = {toml_value(lin.states)}",
              f"state_units = {toml_value(lin.state_units)}",
              f"inputs = {toml_value(lin.inputs)}",
              f"input_units = {toml_value(lin.input_units)}",
              f"outputs = {toml_value(lin.outputs)}",
              f"output_units = {toml_value(lin.output_units)}"]
    if lin.unknown_inputs:
        lines += [f"unknown_inputs = {toml_value(lin.unknown_inputs)}",
                  f"unknown_input_units = {toml_value(lin.unknown_input_units)}"]
    lines += ["", "[plant_model]", f"path = {toml_value(Path(model_path).as_posix())}"]
    if lin.system is not None:
        lines.append(f"system = {toml_value(lin.system)}")
    lines += [f"inputs = {toml_value(lin.inputs)}", f"outputs = {toml_value(lin.outputs)}"]
    if lin.unknown_inputs:
        lines.append(f"unknown_inputs = {toml_value(lin.unknown_inputs)}")
    lines += [f"states = {toml_value(lin.states)}", f"start = {toml_value(lin.start)}",
              f"at = {float(lin.time)!r}"]
    return "\n".join(lines) + "\n"


def summary_lines(lin: Linearization) -> list[str]:
    """What the command prints: the model, its size, the method and accuracy, the operating
    point."""
    lines = [f"{lin.name}: n = {len(lin.states)} states ({', '.join(lin.states)}), "
             f"{len(lin.inputs)} inputs, {len(lin.outputs)} outputs, "
             f"{len(lin.unknown_inputs)} unknown inputs",
             f"method: {lin.method}; accuracy: {_accuracy_text(lin)}",
             f"operating point: t = {lin.time!r}, x = {toml_value(list(map(float, lin.x)))}"]
    if not lin.equilibrium:
        lines.append(f"note: dx/dt = {toml_value(list(map(float, lin.dx)))} there: not an "
                     "equilibrium (the linearisation about a trajectory point)")
    return lines


def write_spec(lin: Linearization, path: str | Path) -> Path:
    """Write :func:`spec_text` to ``path`` whole (a temporary file renamed into place)."""
    path = Path(path)
    return write_text(path, spec_text(lin, path))


def _accuracy_text(lin: Linearization) -> str:
    return (f"{lin.accuracy:.2g} relative to the largest entry (directional derivatives: their "
            "difference from central differences; central differences: the difference between "
            "steps h and 2 h)")
