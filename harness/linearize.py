"""The user's plant FMU or SSP linearised at an operating point: A, B, C, E of
dx/dt = A x + B u + E q, y = C x, for :mod:`harness.spec_writer` to write as a plant spec
(``python -m harness linearize``).

The model is a composition of Model Exchange FMUs (:class:`harness.me_fmu.MeFmu`): one FMU,
or the components of an SSP's (sub)system (:mod:`harness.ssd`; the enclosing systems are not
read). Its state is the concatenation of the components' states, named ``component.var``
(an FMU's: its variable names). Each component has inputs v_c (those connected) and outputs
w_c (those connected or asked for); the connections are ``v = M w + N u`` with u the ports
(the chosen inputs, then the unknown inputs).

- The operating point: the start values (the SSD's parameter bindings, then ``start``, the
  ``--set`` values), the ports at the start values of the inputs they feed; the couplings
  v = M w(x, v) + N u solved (substitution, then Newton's method with the components'
  feedthrough D when substitution does not settle: an algebraic loop); with ``at``, the
  composed ODE simulated to that time with the ports held, by scipy's LSODA (rtol 1e-10, atol
  1e-10 times each state's nominal value).
- The linearisation: each component's (A_c, B_c, C_c, D_c) (:meth:`MeFmu.jacobian`:
  directional derivatives or central differences) composed by the chain rule: with the block
  diagonals A, B, C, D of all components, w = C x + D v and v = M w + N u give
  (I - D M) w = C x + D N u, so with S = (I - D M)^-1

      A_total = A + B M S C,    B_total = B N + B M S D N,
      C_total = P S C,          D_total = P S D N + Q

  (y = P w + Q u: the outputs asked for). A singular I - D M (an algebraic loop without
  a solution) is refused; so are connected connectors whose units differ (no conversion), and
  a D_total that is not zero: the plant spec has no direct feedthrough.

Examples
--------
>>> import sys, tempfile, harness
>>> sys.path.insert(0, str(Path(harness.__file__).parents[1] / "tests"))
>>> from me_fmus import linear_fmu
>>> fmu = linear_fmu(Path(tempfile.mkdtemp()) / "p.fmu", [[0, 1], [-2, -3]], [[0], [1]],
...                  [[1, 0]])
>>> lin = linearize(fmu, ["u1"], ["y1"])
>>> lin.A.tolist(), lin.B.tolist(), lin.C.tolist(), lin.method
([[0.0, 1.0], [-2.0, -3.0]], [[0.0], [1.0]], [[1.0, 0.0]], 'directional derivatives')
"""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from harness.me_fmu import LinearizeError, MeFmu, closest, model_exchange_description, unit_of
from harness.ssd import Endpoint, SsdError, find_system, read_ssp, wiring

SINGULAR_CONDITION = 1e10
"""I - D M is refused as singular beyond this condition number."""
EQUILIBRIUM_TOLERANCE = 1e-9
"""|dx/dt| below this times the state's scale (max of |x|, nominal) counts as an equilibrium."""
FEEDTHROUGH_TOLERANCE = 1e-8
"""A D entry (scaled by its input's nominal value and its output's typical size) above this,
or above 100 times the linearisation's accuracy, is direct feedthrough."""
COUPLING_TOLERANCE = 1e-13
ODE_TOLERANCE = 1e-10


@dataclass(frozen=True)
class Linearization:
    """The linearised plant and where it comes from (what the spec writer writes)."""

    name: str
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    E: np.ndarray | None
    states: list[str]
    state_units: list[str]
    state_nominal: np.ndarray
    inputs: list[str]
    input_units: list[str]
    outputs: list[str]
    output_units: list[str]
    unknown_inputs: list[str]
    unknown_input_units: list[str]
    x: np.ndarray
    dx: np.ndarray
    time: float
    method: str
    accuracy: float
    model: Path
    system: str | None
    start: dict[str, Any] = field(default_factory=dict)
    u: np.ndarray | None = None
    """The ports at the operating point: the inputs, then the unknown inputs."""
    y: np.ndarray | None = None
    """The outputs at the operating point."""

    @property
    def equilibrium(self) -> bool:
        """Whether dx/dt is zero at the operating point (see EQUILIBRIUM_TOLERANCE)."""
        scale = np.maximum(np.abs(self.x), self.state_nominal)
        return bool(np.all(np.abs(self.dx) <= EQUILIBRIUM_TOLERANCE * scale))


@dataclass
class _Part:
    """A component in the composition: its name ("" for a lone FMU) and instance."""

    name: str
    fmu: MeFmu

    def qualified(self, variable: str) -> str:
        return f"{self.name}.{variable}" if self.name else variable


@dataclass
class Composition:
    """Components and their connections ``v = M w + N u``, outputs ``y = P w + Q u`` (see
    the module)."""

    parts: list[_Part]
    M: np.ndarray
    N: np.ndarray
    P: np.ndarray
    Q: np.ndarray
    u0: np.ndarray

    def __post_init__(self) -> None:
        self._x = np.cumsum([0] + [len(p.fmu.states) for p in self.parts])
        self._v = np.cumsum([0] + [len(p.fmu.inputs) for p in self.parts])
        self._w = np.cumsum([0] + [len(p.fmu.outputs) for p in self.parts])
        self.v = np.concatenate([p.fmu.v0 for p in self.parts])
        self.x0 = np.concatenate([p.fmu.x0 for p in self.parts])

    @property
    def states(self) -> list[str]:
        return [p.qualified(s) for p in self.parts for s in p.fmu.states]

    @property
    def state_units(self) -> list[str]:
        return [unit_of(p.fmu.variables[s]) for p in self.parts for s in p.fmu.states]

    @property
    def state_nominal(self) -> np.ndarray:
        return np.concatenate([p.fmu.nominal_x for p in self.parts])

    def _split(self, z: np.ndarray, bounds: np.ndarray, i: int) -> np.ndarray:
        return z[bounds[i]:bounds[i + 1]]

    def evaluate(self, t: float, x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """dx/dt and w of every component at (t, x, v)."""
        dx, w = [], []
        for i, part in enumerate(self.parts):
            d, o = part.fmu.evaluate(t, self._split(x, self._x, i), self._split(v, self._v, i))
            dx.append(d)
            w.append(o)
        return np.concatenate(dx), np.concatenate(w)

    def couple(self, t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The inputs v solving v = M w(t, x, v) + N u, from the last solution: substitution
        (exact after as many rounds as the longest feedthrough chain), then Newton's method."""
        v = self.v.copy()
        for _ in range(len(self.parts) + 1):
            target = self.M @ self.evaluate(t, x, v)[1] + self.N @ u
            if np.max(np.abs(target - v), initial=0.0) <= COUPLING_TOLERANCE * _size(target):
                self.v = target
                return target
            v = target
        for _ in range(50):
            r = v - self.M @ self.evaluate(t, x, v)[1] - self.N @ u
            if np.max(np.abs(r), initial=0.0) <= COUPLING_TOLERANCE * _size(v):
                self.v = v
                return v
            D = _block_diagonal([j.D for j in self._jacobians(t, x, v, None)])
            v = v - np.linalg.solve(self._loop(D, "the coupling equations"), r)
        raise LinearizeError("the algebraic loop between the components does not converge at "
                             f"t = {t!r} (Newton's method, 50 iterations)")

    def _loop(self, D: np.ndarray, what: str) -> np.ndarray:
        """I - M D (for v); refused when singular, as is I - D M (the same condition)."""
        loop = np.eye(len(self.v)) - self.M @ D
        if loop.size and np.linalg.cond(loop) > SINGULAR_CONDITION:
            raise LinearizeError(f"the algebraic loop between the components is singular at "
                                 f"this point (I - D M has condition {np.linalg.cond(loop):.3g}"
                                 f", in {what}): its outputs are not determined by the states")
        return loop

    def _jacobians(self, t: float, x: np.ndarray, v: np.ndarray, method: str | None) -> list:
        return [part.fmu.jacobian(t, self._split(x, self._x, i), self._split(v, self._v, i),
                                  method) for i, part in enumerate(self.parts)]

    def rhs(self, t: float, x: np.ndarray) -> np.ndarray:
        """dx/dt of the composed model with the ports at u0."""
        return self.evaluate(t, x, self.couple(t, x, self.u0))[0]

    def linear(self, t: float, x: np.ndarray, method: str | None = None) -> tuple:
        """A, B, C, D of the composition at (t, x) with the ports at u0 (the module's chain
        rule), the method used and the accuracy (the largest of the components')."""
        v = self.couple(t, x, self.u0)
        jacobians = self._jacobians(t, x, v, method)
        A, B, C, D = (_block_diagonal([getattr(j, k) for j in jacobians]) for k in "ABCD")
        self._loop(D, "the linearisation")
        S = np.linalg.solve(np.eye(len(self._w) and self._w[-1]) - D @ self.M,
                            np.eye(self._w[-1]))
        A_total = A + B @ self.M @ S @ C
        B_total = B @ self.N + B @ self.M @ S @ D @ self.N
        C_total = self.P @ S @ C
        D_total = self.P @ S @ D @ self.N + self.Q
        methods = {j.method for j in jacobians}
        named = {"directional": "directional derivatives", "differences": "central differences"}
        if len(methods) == 1:
            method_text = named[methods.pop()]
        else:
            pairs = list(zip(self.parts, jacobians, strict=True))
            method_text = "; ".join(
                f"{named[m]} ({', '.join(p.name for p, j in pairs if j.method == m)})"
                for m in ("directional", "differences"))
        accuracy = max((j.accuracy for j in jacobians), default=0.0)
        method_text += "".join(f"; {j.note}" for j in jacobians if j.note)
        return A_total, B_total, C_total, D_total, method_text, accuracy

    def simulate(self, t0: float, t1: float) -> np.ndarray:
        """The state at t1 from x0 at t0, the ports held at u0 (LSODA)."""
        from scipy.integrate import solve_ivp

        if t1 == t0 or len(self.x0) == 0:
            return self.x0.copy()
        atol = ODE_TOLERANCE * self.state_nominal
        solution = solve_ivp(self.rhs, (t0, t1), self.x0, method="LSODA", rtol=ODE_TOLERANCE,
                             atol=atol)
        if not solution.success:
            raise LinearizeError(f"the simulation to --at {t1!r} failed: {solution.message}")
        return solution.y[:, -1]

    def close(self) -> None:
        for part in self.parts:
            part.fmu.close()


def linearize(model: str | Path, inputs: list[str], outputs: list[str],
              unknown_inputs: list[str] = (), *, system: str | None = None,
              at: float | None = None, start: dict[str, Any] | None = None,
              method: str | None = None) -> Linearization:
    """Linearise the plant FMU or SSP ``model`` (see the module).

    Parameters
    ----------
    model
        A ``.fmu`` (FMI 2.0 with Model Exchange) or ``.ssp`` file.
    inputs, outputs, unknown_inputs
        The columns of B, the rows of C, the columns of E: variable names of an FMU; for an
        SSP, connectors of the (sub)system (outputs may also be ``component.output``).
    system
        The SSP's (sub)system whose connectors are the ports (``top.sub``; default the top
        system). Not for an FMU.
    at
        Simulate to this time first (default: linearise at the start time, 0).
    start
        Start values: ``var`` (FMU) or ``component.var`` (SSP) -> value.
    method
        "directional" or "differences" for every component (default: directional
        derivatives where the FMU provides them).

    Returns
    -------
    Linearization

    Raises
    ------
    LinearizeError, harness.ssd.SsdError
        Every bad input: one paragraph naming the item and the reason.
    """
    model = Path(model)
    start = dict(start or {})
    _check_names(inputs, outputs, unknown_inputs)
    if at is not None and not (np.isfinite(at) and at >= 0.0):
        raise LinearizeError(f"--at {at!r}: the operating time must be finite and >= 0")
    with ExitStack() as stack:
        ssp = model.suffix.lower() == ".ssp" or (model.is_file() and _is_ssp(model))
        if ssp:
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="linearize_")))
            composition, units, name = _ssp_composition(model, system, inputs, outputs,
                                                         unknown_inputs, start, folder, stack)
        else:
            if system is not None:
                raise LinearizeError(f"--system {system}: {model} is an FMU; --system picks a "
                                     "system of an SSP")
            composition, units, name = _fmu_composition(model, inputs, outputs,
                                                        unknown_inputs, start, stack)
        t = 0.0 if at is None else float(at)
        x = composition.simulate(0.0, t)
        A, B, C, D, method_text, accuracy = composition.linear(t, x, method)
        dx = composition.rhs(t, x)
        w = composition.evaluate(t, x, composition.couple(t, x, composition.u0))[1]
        _check_feedthrough(D, C, composition, inputs + list(unknown_inputs), outputs, accuracy)
        m = len(inputs)
        return Linearization(
            name=name, A=A, B=B[:, :m], C=C, E=B[:, m:] if unknown_inputs else None,
            states=composition.states, state_units=composition.state_units,
            state_nominal=composition.state_nominal, inputs=list(inputs),
            input_units=units["inputs"], outputs=list(outputs), output_units=units["outputs"],
            unknown_inputs=list(unknown_inputs), unknown_input_units=units["unknown_inputs"],
            x=x, dx=dx, time=t, method=method_text, accuracy=accuracy, model=model,
            system=name if ssp else None, start=start, u=composition.u0.copy(),
            y=composition.P @ w + composition.Q @ composition.u0)


def _check_names(inputs: list[str], outputs: list[str], unknown_inputs: list[str]) -> None:
    if not outputs:
        raise LinearizeError("no --output: the plant spec needs at least one measured output")
    ports = list(inputs) + list(unknown_inputs)
    for names, what in ((ports, "--input/--unknown-input"), (list(outputs), "--output")):
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise LinearizeError(f"{what}: {', '.join(twice)} given twice")


def _is_ssp(path: Path) -> bool:
    return zipfile.is_zipfile(path) and "SystemStructure.ssd" in zipfile.ZipFile(path).namelist()


def _size(z: np.ndarray) -> float:
    return max(float(np.max(np.abs(z), initial=0.0)), 1.0)


def _block_diagonal(blocks: list[np.ndarray]) -> np.ndarray:
    rows = sum(b.shape[0] for b in blocks)
    cols = sum(b.shape[1] for b in blocks)
    out = np.zeros((rows, cols))
    r = c = 0
    for b in blocks:
        out[r:r + b.shape[0], c:c + b.shape[1]] = b
        r, c = r + b.shape[0], c + b.shape[1]
    return out


def _fmu_composition(path: Path, inputs: list[str], outputs: list[str],
                     unknown_inputs: list[str], start: dict[str, Any],
                     stack: ExitStack) -> tuple[Composition, dict, str]:
    md = model_exchange_description(path, str(path))
    fmu = MeFmu(path, md.modelName, start, list(inputs) + list(unknown_inputs), list(outputs))
    stack.callback(fmu.close)
    nu, ny = len(fmu.inputs), len(fmu.outputs)
    composition = Composition([_Part("", fmu)], np.zeros((nu, ny)), np.eye(nu), np.eye(ny),
                              np.zeros((ny, nu)), fmu.v0.copy())
    unit = {name: unit_of(fmu.variables[name]) for name in fmu.inputs + fmu.outputs}
    units = {"inputs": [unit[n] for n in inputs], "outputs": [unit[n] for n in outputs],
             "unknown_inputs": [unit[n] for n in unknown_inputs]}
    return composition, units, md.modelName


def _ssp_composition(path: Path, system_name: str | None, inputs: list[str],
                     outputs: list[str], unknown_inputs: list[str], start: dict[str, Any],
                     folder: Path, stack: ExitStack) -> tuple[Composition, dict, str]:
    structure = read_ssp(path)
    system = find_system(structure, system_name)
    wired = wiring(system)
    label = system_name or system.name
    ports = list(inputs) + list(unknown_inputs)
    for name in ports:
        connector = system.connectors.get(name)
        if connector is None or connector.kind != "input":
            have = [c.name for c in system.connectors.values() if c.kind == "input"]
            what = "no connector" if connector is None else f"a connector of kind {connector.kind}"
            raise LinearizeError(f"{path}: {label} has {what} {name!r} among its inputs "
                                 f"(its input connectors: {', '.join(have) or 'none'})"
                                 f"{closest(name, have) if connector is None else ''}")
    output_ends = [_output_end(name, system, wired, label) for name in outputs]
    feeds = {target: source for target, source in wired.sources.items() if target.component}
    used_sources = {s for t, s in feeds.items()
                    if s.component or s.connector in ports} | set(output_ends)
    per_component = _split_start(start, wired.components, label)
    parts, fmus_at = [], {}
    with zipfile.ZipFile(path) as archive:
        for name, comp in wired.components.items():
            member = comp.source
            if member not in archive.namelist():
                raise SsdError(f"{path}: component {name!r} refers to {member!r}, which the "
                               "zip does not hold")
            target = folder / f"{len(parts)}_{Path(member).name}"
            with archive.open(member) as src, open(target, "wb") as dst:
                shutil.copyfileobj(src, dst)
            fmus_at[name] = target
            v = [t.connector for t, s in feeds.items()
                 if t.component == name and (s.component or s.connector in ports)]
            w = [s.connector for s in used_sources if s.component == name]
            w = sorted(set(w), key=w.index)
            values = {**comp.parameters, **per_component.get(name, {})}
            fmu = MeFmu(target, name, values, v, w)
            stack.callback(fmu.close)
            parts.append(_Part(name, fmu))
    composition = _wire(parts, feeds, ports, output_ends)
    _check_units(structure, system, wired, parts, feeds, output_ends, ports, label)
    units = {"inputs": [_port_unit(n, system, parts, feeds) for n in inputs],
             "unknown_inputs": [_port_unit(n, system, parts, feeds) for n in unknown_inputs],
             "outputs": [_output_unit(name, end, system, parts)
                         for name, end in zip(outputs, output_ends, strict=True)]}
    return composition, units, label


def _output_end(name: str, system: Any, wired: Any, label: str) -> Endpoint:
    """The source of the output ``name``: an output connector of the system, or
    ``component.output``."""
    connector = system.connectors.get(name)
    if connector is not None and connector.kind == "output":
        source = wired.sources.get(Endpoint("", name))
        if source is None:
            raise LinearizeError(f"{label}: the output connector {name!r} is not connected")
        return source
    for comp in sorted(wired.components, key=len, reverse=True):
        if name.startswith(comp + "."):
            return Endpoint(comp, name[len(comp) + 1:])
    have = [c.name for c in system.connectors.values() if c.kind == "output"]
    raise LinearizeError(f"{label}: no output {name!r}: the outputs are the system's output "
                         f"connectors ({', '.join(have) or 'none'}) or component.output"
                         f"{closest(name, have)}")


def _split_start(start: dict[str, Any], components: dict, label: str) -> dict[str, dict]:
    """``component.var = value`` -> {component: {var: value}}."""
    out: dict[str, dict] = {}
    for key, value in start.items():
        owner = next((c for c in sorted(components, key=len, reverse=True)
                      if key.startswith(c + ".")), None)
        if owner is None:
            hint = closest(key.partition(".")[0], list(components))
            raise LinearizeError(f"--set {key}: {label} has no component of that name (an "
                                 "SSP's start values are component.variable=value; "
                                 f"components: {', '.join(components)}){hint}")
        out.setdefault(owner, {})[key[len(owner) + 1:]] = value
    return out


def _wire(parts: list[_Part], feeds: dict[Endpoint, Endpoint], ports: list[str],
          output_ends: list[Endpoint]) -> Composition:
    """M, N, P, Q and u0 of the components' connections."""
    v_index, w_index = {}, {}
    for part in parts:
        for name in part.fmu.inputs:
            v_index[Endpoint(part.name, name)] = len(v_index)
        for name in part.fmu.outputs:
            w_index[Endpoint(part.name, name)] = len(w_index)
    M = np.zeros((len(v_index), len(w_index)))
    N = np.zeros((len(v_index), len(ports)))
    u0 = np.full(len(ports), np.nan)
    v0 = np.concatenate([p.fmu.v0 for p in parts])
    for target, i in v_index.items():
        source = feeds[target]
        if source.component:
            M[i, w_index[source]] = 1.0
        else:
            j = ports.index(source.connector)
            N[i, j] = 1.0
            if np.isnan(u0[j]):
                u0[j] = v0[i]
    P = np.zeros((len(output_ends), len(w_index)))
    Q = np.zeros((len(output_ends), len(ports)))
    for i, end in enumerate(output_ends):
        if end.component:
            P[i, w_index[end]] = 1.0
        else:
            Q[i, ports.index(end.connector)] = 1.0
    return Composition(parts, M, N, P, Q, np.nan_to_num(u0))


def _part(parts: list[_Part], name: str) -> MeFmu:
    return next(p.fmu for p in parts if p.name == name)


def _end_unit(end: Endpoint, system: Any, parts: list[_Part]) -> tuple[str, Any]:
    """The unit of a connection's end (the FMU variable's, else the SSD connector's) and the
    model description that defines it (None for a system connector)."""
    if not end.component:
        connector = system.connectors.get(end.connector)
        return (connector.unit if connector else ""), None
    fmu = _part(parts, end.component)
    unit = unit_of(fmu.variables[end.connector]) if end.connector in fmu.variables else ""
    return unit, fmu.md


def _same_unit(a: tuple[str, Any], b: tuple[str, Any], ssd_units: dict) -> bool:
    if not a[0] or not b[0] or a[0] == b[0]:
        return True
    bases = []
    for unit, md in (a, b):
        base = ssd_units.get(unit)
        if md is not None:
            defined = {u.name: u for u in md.unitDefinitions}
            if unit in defined and defined[unit].baseUnit is not None:
                base = base_unit_of(defined[unit].baseUnit)
        bases.append(base)
    return bases[0] is not None and bases[0] == bases[1]


def base_unit_of(unit: Any) -> tuple:
    """fmpy's BaseUnit as :func:`harness.ssd.base_unit`'s tuple."""
    keys = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
    return (tuple(int(getattr(unit, k) or 0) for k in keys)
            + (float(unit.factor or 1.0), float(unit.offset or 0.0)))


def _check_units(structure: Any, system: Any, wired: Any, parts: list[_Part], feeds: dict,
                 output_ends: list[Endpoint], ports: list[str], label: str) -> None:
    pairs = [(s, t) for t, s in feeds.items() if s.component or s.connector in ports]
    pairs += [(s, t) for t, s in wired.sources.items()
              if not t.component and s in output_ends]
    for source, target in pairs:
        a, b = _end_unit(source, system, parts), _end_unit(target, system, parts)
        if not _same_unit(a, b, structure.units):
            raise LinearizeError(f"{label}: the connection {source} -> {target} joins the "
                                 f"units {a[0]!r} and {b[0]!r}, which differ; linearising "
                                 "converts no units: make them the same in the model")


def _port_unit(name: str, system: Any, parts: list[_Part], feeds: dict) -> str:
    connector = system.connectors[name]
    if connector.unit:
        return connector.unit
    fed = [t for t, s in feeds.items() if not s.component and s.connector == name]
    return _end_unit(fed[0], system, parts)[0] if fed else ""


def _output_unit(name: str, end: Endpoint, system: Any, parts: list[_Part]) -> str:
    connector = system.connectors.get(name)
    if connector is not None and connector.unit:
        return connector.unit
    return _end_unit(end, system, parts)[0]


def _check_feedthrough(D: np.ndarray, C: np.ndarray, composition: Composition,
                       ports: list[str], outputs: list[str], accuracy: float) -> None:
    """Refuse a D that is not zero (see FEEDTHROUGH_TOLERANCE)."""
    if D.size == 0:
        return
    nominal_u = np.concatenate([p.fmu.nominal_v for p in composition.parts])
    nominal_u = np.abs(composition.N.T) @ nominal_u / np.maximum(
        np.abs(composition.N).sum(axis=0), 1.0) if composition.N.size else np.ones(len(ports))
    nominal_u = np.where(nominal_u > 0.0, nominal_u, 1.0)
    scaled = np.abs(D) * nominal_u
    size = np.maximum(np.abs(C) @ composition.state_nominal, scaled.max(axis=1))
    tolerance = max(FEEDTHROUGH_TOLERANCE, 100.0 * accuracy)
    ratio = scaled / np.where(size > 0.0, size, 1.0)[:, None]
    i, j = np.unravel_index(np.argmax(ratio), ratio.shape)
    if ratio[i, j] > tolerance:
        raise LinearizeError(
            f"the output {outputs[i]!r} depends directly on the input {ports[j]!r} (D = "
            f"{D[i, j]:.6g}): the plant spec has no direct feedthrough (y = C x), so choose "
            "outputs that the inputs reach only through the states")
