"""One FMI 2.0 FMU through its Model Exchange interface: its state at an operating point, its
right-hand side and its Jacobians there.

An :class:`MeFmu` is instantiated (fmpy's ``FMU2Model``), its start values overridden
(parameters, inputs, state start values), initialised (``setupExperiment``, enter and exit
initialization mode, the event iteration) and put in continuous-time mode. Then, for a time t,
states x and the values v of its chosen inputs, :meth:`MeFmu.evaluate` gives dx/dt and its
chosen outputs w, and :meth:`MeFmu.jacobian` the matrices of

    dx/dt ~ A dx + B dv,   dw ~ C dx + D dv

from ``fmi2GetDirectionalDerivative`` when the FMU provides it (and every chosen output is an
output of its model structure, the unknowns the standard allows), otherwise from central
differences.

Central differences: the step of each state or input z_j is ``h_j = eps^(1/3) max(|z_j|,
nominal_j)`` (``nominal_j`` the variable's ``nominal`` attribute, 1 when it declares none): the
truncation error of a central difference is O(h^2) and its rounding error O(eps / h), balanced
at h ~ eps^(1/3) ~ 6e-6 relative, both then ~ eps^(2/3) ~ 4e-11 relative. The accuracy
reported is the largest difference between the Jacobians at h and at 2 h, relative to the
largest entry (an estimate of the error at 2 h, three times the truncation error at h); for
directional derivatives, their largest difference from the central differences, which checks
the FMU's derivatives: beyond :data:`DISAGREEMENT` they are taken as wrong and the central
differences are used (Reference-FMUs' VanDerPol answers 0 for d x0 / d x0, its output x0
being its state).
"""

from __future__ import annotations

import ctypes
import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from fhobs.errors import FhobsError
from fmpy.fmi2 import FMU2Model

from harness.fmu_files import description, unzipped

STEP = float(np.finfo(float).eps) ** (1.0 / 3.0)
"""The central differences' relative step, eps^(1/3)."""
DISAGREEMENT = 1e-4
"""Directional derivatives that differ from central differences by more than this (relative
to the largest entry) are not used: the differences are (unless asked for by name)."""
TIME_VARYING = ("continuous", "discrete")
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)


class LinearizeError(FhobsError, ValueError):
    """A model that cannot be linearised as asked; the message names the model, the item and
    the reason, and what to do."""


@dataclass(frozen=True)
class Jacobian:
    """The matrices of one linearisation (:meth:`MeFmu.jacobian`): ``method``
    ``"directional"`` or ``"differences"``, ``accuracy`` as the module describes, ``note``
    why the FMU's directional derivatives were not used ("" when they were or it has none)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    method: str
    accuracy: float
    note: str = ""


def closest(name: str, names: list[str]) -> str:
    """`` (closest: a, b)`` for the names like ``name``, or "".

    Examples
    --------
    >>> closest("phib", ["phiB", "wB", "phiA"])
    ' (closest: phiB, phiA)'
    """
    close = difflib.get_close_matches(name, names, n=3, cutoff=0.5)
    if not close:
        lowered = {n.lower(): n for n in names}
        close = [lowered[c] for c in difflib.get_close_matches(name.lower(), list(lowered), n=3,
                                                                cutoff=0.5)]
    return f" (closest: {', '.join(close)})" if close else ""


def unit_of(variable: Any) -> str:
    """A variable's unit: its own ``unit`` or its declared type's; "" when neither."""
    if getattr(variable, "unit", None):
        return variable.unit
    declared = getattr(variable, "declaredType", None)
    return getattr(declared, "unit", None) or ""


def model_exchange_description(path: Path, label: str) -> Any:
    """fmpy's model description of the FMU at ``path``; LinearizeError for a missing file, a
    file that is no FMU, another FMI version than 2.0 or an FMU without Model Exchange."""
    if not path.is_file():
        raise LinearizeError(f"{label}: no such FMU file {path}")
    try:
        md = description(path)
    except Exception as err:  # noqa: BLE001 - fmpy raises many kinds for a bad file
        raise LinearizeError(f"{label}: {path} is not an FMU ({type(err).__name__}: {err})"
                             ) from None
    if md.fmiVersion != "2.0":
        raise LinearizeError(f"{label}: {path} is an FMI {md.fmiVersion} FMU; linearising "
                             "reads FMI 2.0 FMUs")
    if md.modelExchange is None:
        raise LinearizeError(
            f"{label}: {path} is a Co-Simulation-only FMU: it has no Model Exchange interface, "
            "and linearising needs its state access (fmi2GetContinuousStates, "
            "fmi2GetDerivatives, fmi2SetContinuousStates); export the model with Model "
            "Exchange, or write A, B, C by hand in a plant spec")
    return md


class MeFmu:
    """An FMU instantiated through Model Exchange at its start values (see the module).

    Parameters
    ----------
    path
        The ``.fmu`` file.
    label
        The FMU's name in messages and its instance name (an SSP component's name).
    start
        Start values to set before initialisation, by variable name (parameters, inputs,
        states): Real, Integer, Boolean or String by the variable's type.
    inputs, outputs
        The inputs v and outputs w that :meth:`evaluate` and :meth:`jacobian` deal with
        (names of Real input variables, names of Real time-varying variables).
    start_time
        The time of the experiment's start.

    Examples
    --------
    >>> import sys, tempfile, harness
    >>> sys.path.insert(0, str(Path(harness.__file__).parents[1] / "tests"))
    >>> from me_fmus import vanderpol_fmu
    >>> fmu = MeFmu(vanderpol_fmu(Path(tempfile.mkdtemp()) / "vdp.fmu"), "vdp",
    ...             {"mu": 2.0, "x1": 1.5}, ["u"], ["y"])
    >>> fmu.states, fmu.x0.tolist()
    (['x1', 'x2'], [1.5, 0.0])
    >>> jac = fmu.jacobian(0.0, fmu.x0, np.zeros(1))
    >>> jac.method, jac.A.tolist()
    ('directional', [[0.0, 1.0], [-1.0, -2.5]])
    >>> fmu.close()
    """

    def __init__(self, path: str | Path, label: str, start: dict[str, Any],
                 inputs: list[str], outputs: list[str], start_time: float = 0.0) -> None:
        path = Path(path)
        self.label = label
        self.md = model_exchange_description(path, label)
        self.variables = {v.name: v for v in self.md.modelVariables}
        state_variables = [d.variable.derivative for d in self.md.derivatives]
        self.states = [v.name for v in state_variables]
        self._state_vrs = [v.valueReference for v in state_variables]
        self._derivative_vrs = [d.variable.valueReference for d in self.md.derivatives]
        self.inputs, self.outputs = list(inputs), list(outputs)
        self._input_vrs = [self.input(name).valueReference for name in self.inputs]
        self._output_vrs = [self.output(name).valueReference for name in self.outputs]
        structure_outputs = {o.variable.name for o in self.md.outputs}
        self.directional = bool(self.md.modelExchange.providesDirectionalDerivative) and all(
            name in structure_outputs for name in self.outputs)
        self._start = {name: self.variable(name, "--set") for name in start}
        self._fmu = FMU2Model(guid=self.md.guid, unzipDirectory=unzipped(path),
                              modelIdentifier=self.md.modelExchange.modelIdentifier,
                              instanceName=label)
        self._fmu.instantiate()
        try:
            self._initialise(start, start_time)
        except Exception:
            self.close()
            raise
        self.x0 = self.states_now()
        self.v0 = np.array(self._fmu.getReal(self._input_vrs)) if self.inputs else np.zeros(0)
        self.nominal_x = np.array([_nominal(v) for v in state_variables])
        self.nominal_v = np.array([_nominal(self.variables[n]) for n in self.inputs])

    def variable(self, name: str, what: str) -> Any:
        """The model variable ``name``; LinearizeError naming the closest names."""
        if name not in self.variables:
            raise LinearizeError(f"{self.label}: {what} {name!r}: the model has no such "
                                 f"variable{closest(name, list(self.variables))}")
        return self.variables[name]

    def input(self, name: str) -> Any:
        """The Real input variable ``name`` (LinearizeError for any other variable)."""
        variable = self.variable(name, "input")
        if variable.causality != "input":
            inputs = [v.name for v in self.md.modelVariables if v.causality == "input"]
            hint = ("; set a parameter's value with --set NAME=VALUE"
                    if variable.causality in ("parameter", "calculatedParameter") else "")
            raise LinearizeError(f"{self.label}: {name!r} is a {variable.causality} "
                                 f"{variable.variability} variable, not an input (the inputs: "
                                 f"{', '.join(inputs) or 'none'}){hint}")
        if variable.type != "Real":
            raise LinearizeError(f"{self.label}: input {name!r} is {variable.type}, not Real")
        return variable

    def output(self, name: str) -> Any:
        """The Real time-varying variable ``name`` (an output, a state, a local...)."""
        variable = self.variable(name, "output")
        if variable.type != "Real":
            raise LinearizeError(f"{self.label}: output {name!r} is {variable.type}, not "
                                 "Real: the plant's outputs are Real variables")
        if variable.variability not in TIME_VARYING or variable.causality in (
                "parameter", "calculatedParameter"):
            raise LinearizeError(f"{self.label}: output {name!r} is a {variable.causality} "
                                 f"{variable.variability} variable: it does not change with "
                                 "the state; choose an output, a state or a local variable")
        return variable

    def _initialise(self, start: dict[str, Any], start_time: float) -> None:
        fmu = self._fmu
        fmu.setupExperiment(startTime=start_time)
        setters = {"Real": (fmu.setReal, float), "Integer": (fmu.setInteger, int),
                   "Enumeration": (fmu.setInteger, int), "Boolean": (fmu.setBoolean, bool),
                   "String": (fmu.setString, str)}
        for name, value in start.items():
            variable = self._start[name]
            setter, convert = setters[variable.type]
            try:
                setter([variable.valueReference], [convert(value)])
            except Exception as err:  # noqa: BLE001 - the FMU's refusal, said in one line
                raise LinearizeError(f"{self.label}: the FMU refuses {name} = {value!r} "
                                     f"({err})") from None
        try:
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
            more = True
            while more:
                more, terminate, *_ = fmu.newDiscreteStates()
                if terminate:
                    raise LinearizeError(f"{self.label}: the FMU asks to terminate during its "
                                         "initialisation")
            fmu.enterContinuousTimeMode()
        except LinearizeError:
            raise
        except Exception as err:  # noqa: BLE001
            raise LinearizeError(f"{self.label}: the FMU fails to initialise at these start "
                                 f"values ({err})") from None

    def states_now(self) -> np.ndarray:
        """The FMU's continuous states."""
        x = np.zeros(len(self.states))
        if len(x):
            self._fmu.getContinuousStates(x.ctypes.data_as(_DOUBLE_P), len(x))
        return x

    def set_point(self, t: float, x: np.ndarray, v: np.ndarray) -> None:
        """Set the time, the states and the chosen inputs."""
        self._fmu.setTime(float(t))
        x = np.ascontiguousarray(x, dtype=float)
        if len(x):
            self._fmu.setContinuousStates(x.ctypes.data_as(_DOUBLE_P), len(x))
        if len(v):
            self._fmu.setReal(self._input_vrs, [float(a) for a in v])

    def evaluate(self, t: float, x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """dx/dt and the chosen outputs w at (t, x, v)."""
        self.set_point(t, x, v)
        dx = np.zeros(len(self.states))
        if len(dx):
            self._fmu.getDerivatives(dx.ctypes.data_as(_DOUBLE_P), len(dx))
        w = np.array(self._fmu.getReal(self._output_vrs)) if self.outputs else np.zeros(0)
        return dx, w

    def jacobian(self, t: float, x: np.ndarray, v: np.ndarray,
                 method: str | None = None) -> Jacobian:
        """A, B, C, D at (t, x, v) (see the module); ``method`` "directional" or
        "differences" (default: directional derivatives when the FMU provides them)."""
        chosen = method or ("directional" if self.directional else "differences")
        n = len(self.states)
        note = ""
        if chosen == "directional":
            J = self._directional(t, x, v)
            differences = self._differences(t, x, v, 1.0)
            accuracy = _relative(J, differences)
            if method is None and accuracy > DISAGREEMENT:
                note = (f"{self.label}'s directional derivatives differ from central "
                        f"differences by {accuracy:.2g} relative: not used")
                chosen, J = "differences", differences
                accuracy = _relative(J, self._differences(t, x, v, 2.0))
        else:
            J = self._differences(t, x, v, 1.0)
            accuracy = _relative(J, self._differences(t, x, v, 2.0))
        return Jacobian(J[:n, :n], J[:n, n:], J[n:, :n], J[n:, n:], chosen, accuracy, note)

    def _directional(self, t: float, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        self.set_point(t, x, v)
        unknowns = self._derivative_vrs + self._output_vrs
        knowns = self._state_vrs + self._input_vrs
        J = np.zeros((len(unknowns), len(knowns)))
        for j in range(len(knowns)):
            seed = np.zeros(len(knowns))
            seed[j] = 1.0
            J[:, j] = self._fmu.getDirectionalDerivative(unknowns, knowns, list(seed))
        return J

    def _differences(self, t: float, x: np.ndarray, v: np.ndarray, factor: float) -> np.ndarray:
        z = np.concatenate([x, v])
        nominal = np.concatenate([self.nominal_x, self.nominal_v])
        n = len(x)
        columns = []
        for j in range(len(z)):
            h = factor * STEP * max(abs(z[j]), nominal[j])
            values = []
            for sign in (1.0, -1.0):
                zj = z.copy()
                zj[j] += sign * h
                values.append(np.concatenate(self.evaluate(t, zj[:n], zj[n:])))
            columns.append((values[0] - values[1]) / (2.0 * h))
        self.set_point(t, x, v)
        size = n + len(self.outputs)
        return np.column_stack(columns) if columns else np.zeros((size, 0))

    def close(self) -> None:
        """Terminate and free the instance."""
        fmu, self._fmu = getattr(self, "_fmu", None), None
        if fmu is None:
            return
        try:
            fmu.terminate()
        except Exception:  # noqa: BLE001, S110 - freed below whatever terminate says
            pass
        fmu.freeInstance()


def _nominal(variable: Any) -> float:
    nominal = getattr(variable, "nominal", None)
    return abs(float(nominal)) if nominal not in (None, "") and float(nominal) != 0.0 else 1.0


def _relative(J: np.ndarray, other: np.ndarray) -> float:
    """max |J - other| / max |J| (0 for an empty or zero J)."""
    scale = float(np.max(np.abs(J))) if J.size else 0.0
    return float(np.max(np.abs(J - other))) / scale if scale > 0.0 else 0.0


