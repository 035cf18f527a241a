"""Small FMI 2.0 FMUs with both Model Exchange and Co-Simulation interfaces, generated from
our own C source and compiled with the system's C compiler, for the linearisation's tests
(``harness linearize``) and for ``harness plant`` runs of a linearised plant.

- :func:`me_fmu`: the generator. A model is given as its variables and C expressions of them
  (``"({U} - {R} * {i}) / {L}"``: ``{name}`` stands for the variable ``name``), the
  derivatives of its states, its outputs and, optionally, the analytic partial derivatives
  that ``fmi2GetDirectionalDerivative`` returns. The Co-Simulation interface integrates the
  same equations with RK4 on an internal substep of ``min(1e-5, step / 100)``.
- :func:`linear_fmu`: dx/dt = A x + scale B u + E q, y = C x + D u (A, B, C, D, E compiled in;
  the tunable parameter ``scale``, default 1).
- :func:`vanderpol_fmu`: dx1/dt = x2, dx2/dt = mu (1 - x1^2) x2 - x1 + u, y = x1.
- :func:`dc_motor_ssp`: an SSP mirroring OMSimulator's Dymola DC motor: an electrical FMU
  (state i; inputs U, w; outputs M = k i, I = i; parameters R, L, k), a mechanical FMU (states
  phi, w; inputs M_A, M_B; outputs wB = w, phiB = phi, wA = w; parameters J, d) and a gear
  FMU with feedthrough only (w_out = ratio w_in) between the mechanical wA and the electrical
  w, in a subsystem ``SuT`` of a system ``DC-Motor``, parameter bindings overriding the FMUs'
  defaults (inline, and an ``.ssv`` file for the gear). :func:`dc_motor_matrices` gives its
  A, B, C, E derived by hand.

Examples
--------
>>> import tempfile, numpy as np
>>> from fmpy import read_model_description
>>> fmu = linear_fmu(Path(tempfile.mkdtemp()) / "lin.fmu", [[-1.0]], [[1.0]], [[2.0]])
>>> md = read_model_description(str(fmu))
>>> md.modelExchange is not None and md.coSimulation is not None
True
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree as ET

import fmpy
import numpy as np

FMI_INCLUDE = Path(fmpy.__file__).parent / "c-code"
"""fmpy's copy of the FMI 2.0 headers."""


@dataclass(frozen=True)
class Variable:
    """One Real variable of a generated FMU.

    ``role``: ``"state"``, ``"input"``, ``"output"``, ``"parameter"`` (the derivatives are
    added by :func:`me_fmu`); ``start`` for states, inputs and parameters; ``unit`` declared
    on the variable, or through a declared type when ``unit_type``; ``nominal`` if given.
    """

    name: str
    role: str
    start: float = 0.0
    unit: str = ""
    nominal: float | None = None
    unit_type: bool = False


@dataclass
class _Layout:
    variables: list[Variable]
    derivatives: dict[str, str]
    outputs: dict[str, str]
    vr: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        order = [v for v in self.variables if v.role == "state"]
        self.vr = {v.name: i for i, v in enumerate(self.variables)}
        for i, state in enumerate(order):
            self.vr[f"der({state.name})"] = len(self.variables) + i

    def c(self, expression: str) -> str:
        """An expression with ``{name}`` replaced by ``r[vr]``."""
        return re.sub(r"\{([^{}]+)\}", lambda m: f"r[{self.vr[m.group(1)]}]", expression)


def me_fmu(path: str | Path, name: str, variables: Sequence[Variable],
           derivatives: dict[str, str], outputs: dict[str, str],
           jacobian: dict[tuple[str, str], str] | None = None, *,
           model_exchange: bool = True) -> Path:
    """Write an FMI 2.0 FMU (Model Exchange and Co-Simulation, linux64) of the given equations.

    Parameters
    ----------
    path
        The ``.fmu`` file to write.
    name
        Model name and model identifier (a C identifier).
    variables
        The model's variables (:class:`Variable`), in value-reference order; the
        derivatives ``der(state)`` follow them.
    derivatives
        ``{state: C expression}`` for every state.
    outputs
        ``{output: C expression}`` for every output.
    jacobian
        ``{(unknown, known): C expression}``: the partial derivatives of the derivatives
        (``"der(x)"``) and outputs with respect to the states and inputs, zero where absent;
        the FMU then declares ``providesDirectionalDerivative``. None: it does not (the C
        function answers fmi2Error).
    model_exchange
        False: a Co-Simulation-only FMU (no ``<ModelExchange>`` element).

    Returns
    -------
    Path
        ``path``.
    """
    layout = _Layout(list(variables), derivatives, outputs)
    states = [v.name for v in variables if v.role == "state"]
    missing = set(states) - set(derivatives)
    if missing or set(outputs) != {v.name for v in variables if v.role == "output"}:
        raise ValueError(f"every state needs a derivative and every output an expression "
                         f"(missing: {sorted(missing)})")
    guid = str(uuid.uuid5(uuid.NAMESPACE_URL, f"{name}:{derivatives}:{outputs}:{jacobian}"))
    path = Path(path)
    with tempfile.TemporaryDirectory() as tmp:
        stage = Path(tmp)
        source = stage / "sources" / f"{name}.c"
        source.parent.mkdir()
        source.write_text(_c_source(layout, jacobian))
        binary = stage / "binaries" / "linux64" / f"{name}.so"
        binary.parent.mkdir(parents=True)
        compiler = shutil.which("cc") or shutil.which("gcc")
        done = subprocess.run([compiler, "-O1", "-shared", "-fPIC", f"-I{FMI_INCLUDE}", "-o",
                               str(binary), str(source), "-lm"], capture_output=True, text=True)
        if done.returncode:
            raise RuntimeError(f"compiling {name}.c failed:\n{done.stderr}")
        xml = _model_description(layout, name, guid, jacobian is not None, model_exchange)
        ET.ElementTree(xml).write(stage / "modelDescription.xml", encoding="UTF-8",
                                  xml_declaration=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
            for item in sorted(stage.rglob("*")):
                if item.is_file():
                    archive.write(item, item.relative_to(stage).as_posix())
    return path


def _names(prefix: str, count: int, given: Sequence[str] | None) -> list[str]:
    return list(given) if given is not None else [f"{prefix}{i + 1}" for i in range(count)]


def _units(count: int, given: Sequence[str] | None) -> list[str]:
    return list(given) if given is not None else [""] * count


def _linear_sum(terms: list[tuple[float, str]]) -> str:
    parts = [f"({float(c)!r}) * {{{v}}}" for c, v in terms if c != 0.0]
    return " + ".join(parts) if parts else "0.0"


def linear_fmu(path: str | Path, A, B, C, D=None, *, E=None, name: str = "linear",
               states: Sequence[str] | None = None, inputs: Sequence[str] | None = None,
               outputs: Sequence[str] | None = None,
               unknown_inputs: Sequence[str] | None = None,
               state_units: Sequence[str] | None = None,
               input_units: Sequence[str] | None = None,
               output_units: Sequence[str] | None = None,
               unknown_input_units: Sequence[str] | None = None,
               nominals: Sequence[float] | None = None, x0: Sequence[float] | None = None,
               directional: bool = True, model_exchange: bool = True) -> Path:
    """An FMU of dx/dt = A x + scale B u + E q, y = C x + D u, the matrices compiled in.

    Parameters
    ----------
    path
        The ``.fmu`` file to write.
    A, B, C, D, E
        n x n, n x m, p x n, p x m (default zero), n x r (default none: no q inputs).
    name
        Model name and identifier.
    states, inputs, outputs, unknown_inputs
        Variable names (default ``x1..``, ``u1..``, ``y1..``, ``q1..``); the FMU's inputs are
        the inputs, then the unknown inputs.
    state_units, input_units, output_units, unknown_input_units
        Units (default none).
    nominals
        The states' ``nominal`` attributes (default none declared).
    x0
        The states' start values (default 0).
    directional
        Whether the FMU provides ``fmi2GetDirectionalDerivative``.
    model_exchange
        False: a Co-Simulation-only FMU.

    Returns
    -------
    Path
        ``path``. Its parameter ``scale`` (default 1) multiplies B.

    Examples
    --------
    >>> import tempfile
    >>> from fmpy import simulate_fmu
    >>> fmu = linear_fmu(Path(tempfile.mkdtemp()) / "decay.fmu", [[-1.0]], [[0.0]], [[1.0]],
    ...                  x0=[1.0])
    >>> out = simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=1.0, output_interval=0.5)
    >>> bool(abs(out["y1"][-1] - np.exp(-1.0)) < 1e-12)
    True
    """
    A, B, C = (np.atleast_2d(np.asarray(M, dtype=float)) for M in (A, B, C))
    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    D = np.zeros((p, m)) if D is None else np.atleast_2d(np.asarray(D, dtype=float))
    E = np.zeros((n, 0)) if E is None else np.atleast_2d(np.asarray(E, dtype=float))
    x_names, u_names = _names("x", n, states), _names("u", m, inputs)
    y_names, q_names = _names("y", p, outputs), _names("q", E.shape[1], unknown_inputs)
    start = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
    nominal = [None] * n if nominals is None else [float(v) for v in nominals]
    variables = [Variable(x, "state", float(start[i]), unit, nominal[i])
                 for i, (x, unit) in enumerate(zip(x_names, _units(n, state_units), strict=True))]
    variables += [Variable(u, "input", 0.0, unit)
                  for u, unit in zip(u_names, _units(m, input_units), strict=True)]
    variables += [Variable(q, "input", 0.0, unit)
                  for q, unit in zip(q_names, _units(len(q_names), unknown_input_units),
                                     strict=True)]
    variables += [Variable(y, "output", 0.0, unit)
                  for y, unit in zip(y_names, _units(p, output_units), strict=True)]
    variables.append(Variable("scale", "parameter", 1.0))
    derivatives = {}
    for i, x in enumerate(x_names):
        drive = _linear_sum([(B[i, j], u) for j, u in enumerate(u_names)])
        derivatives[x] = " + ".join([
            _linear_sum([(A[i, j], s) for j, s in enumerate(x_names)]),
            f"{{scale}} * ({drive})",
            _linear_sum([(E[i, j], q) for j, q in enumerate(q_names)])])
    out = {y: _linear_sum([(C[i, j], s) for j, s in enumerate(x_names)]
                          + [(D[i, j], u) for j, u in enumerate(u_names)])
           for i, y in enumerate(y_names)}
    jacobian = None
    if directional:
        jacobian = {}
        for i, x in enumerate(x_names):
            jacobian |= {(f"der({x})", s): repr(float(A[i, j])) for j, s in enumerate(x_names)}
            jacobian |= {(f"der({x})", u): f"{{scale}} * ({float(B[i, j])!r})"
                         for j, u in enumerate(u_names)}
            jacobian |= {(f"der({x})", q): repr(float(E[i, j])) for j, q in enumerate(q_names)}
        for i, y in enumerate(y_names):
            jacobian |= {(y, s): repr(float(C[i, j])) for j, s in enumerate(x_names)}
            jacobian |= {(y, u): repr(float(D[i, j])) for j, u in enumerate(u_names)}
    return me_fmu(path, name, variables, derivatives, out, jacobian,
                  model_exchange=model_exchange)


def vanderpol_fmu(path: str | Path, mu: float = 1.0, x0: Sequence[float] = (2.0, 0.0), *,
                  directional: bool = True) -> Path:
    """Van der Pol's oscillator with an input: dx1/dt = x2, dx2/dt = mu (1 - x1^2) x2 - x1 + u,
    y = x1; parameter ``mu``; the states' units through a declared type.

    Its Jacobian at (x1, x2): A = [[0, 1], [-2 mu x1 x2 - 1, mu (1 - x1^2)]], B = [[0], [1]],
    C = [[1, 0]].
    """
    variables = [Variable("x1", "state", float(x0[0]), "m", unit_type=True),
                 Variable("x2", "state", float(x0[1]), "m/s", unit_type=True),
                 Variable("u", "input", 0.0, "m/s2"), Variable("y", "output", 0.0, "m"),
                 Variable("mu", "parameter", float(mu))]
    derivatives = {"x1": "{x2}", "x2": "{mu} * (1.0 - {x1} * {x1}) * {x2} - {x1} + {u}"}
    jacobian = None
    if directional:
        jacobian = {("der(x1)", "x2"): "1.0",
                    ("der(x2)", "x1"): "-2.0 * {mu} * {x1} * {x2} - 1.0",
                    ("der(x2)", "x2"): "{mu} * (1.0 - {x1} * {x1})",
                    ("der(x2)", "u"): "1.0", ("y", "x1"): "1.0"}
    return me_fmu(path, "vanderpol", variables, derivatives, {"y": "{x1}"}, jacobian)


def vanderpol_jacobian(x1: float, x2: float, mu: float) -> tuple[np.ndarray, ...]:
    """A, B, C of :func:`vanderpol_fmu` at (x1, x2), derived by hand."""
    A = np.array([[0.0, 1.0], [-2.0 * mu * x1 * x2 - 1.0, mu * (1.0 - x1 * x1)]])
    return A, np.array([[0.0], [1.0]]), np.array([[1.0, 0.0]])


DC_MOTOR_DEFAULTS = {"R": 1.0, "L": 1e-3, "k": 0.01, "J": 1.0, "d": 0.0, "ratio": 1.0}
"""The FMUs' own parameter values, which the SSP's bindings override."""
DC_MOTOR_BOUND = {"R": 0.5, "L": 1e-3, "k": 0.1, "J": 0.002, "d": 0.001, "ratio": 2.0}
"""The values :func:`dc_motor_ssp` binds by default (R, k, J, d inline; ratio in an .ssv)."""


def electrical_fmu(path: str | Path, *, w_unit: str = "rad/s", directional: bool = True) -> Path:
    """L di/dt = U - R i - k w; M = k i, I = i (the state's unit through a declared type)."""
    p = DC_MOTOR_DEFAULTS
    variables = [Variable("i", "state", 0.0, "A", unit_type=True),
                 Variable("U", "input", 0.0, "V"), Variable("w", "input", 0.0, w_unit),
                 Variable("M", "output", 0.0, "N.m"), Variable("I", "output", 0.0, "A"),
                 Variable("R", "parameter", p["R"], "Ohm"), Variable("L", "parameter", p["L"], "H"),
                 Variable("k", "parameter", p["k"], "N.m/A")]
    derivatives = {"i": "({U} - {R} * {i} - {k} * {w}) / {L}"}
    jacobian = None
    if directional:
        jacobian = {("der(i)", "i"): "-{R} / {L}", ("der(i)", "U"): "1.0 / {L}",
                    ("der(i)", "w"): "-{k} / {L}", ("M", "i"): "{k}", ("I", "i"): "1.0"}
    return me_fmu(path, "electrical", variables, derivatives, {"M": "{k} * {i}", "I": "{i}"},
                  jacobian)


def mechanical_fmu(path: str | Path, *, directional: bool = True) -> Path:
    """dphi/dt = w, J dw/dt = M_A + M_B - d w; wB = wA = w, phiB = phi."""
    p = DC_MOTOR_DEFAULTS
    variables = [Variable("phi", "state", 0.0, "rad", nominal=1.0),
                 Variable("w", "state", 0.0, "rad/s", nominal=100.0),
                 Variable("M_A", "input", 0.0, "N.m"), Variable("M_B", "input", 0.0, "N.m"),
                 Variable("wB", "output", 0.0, "rad/s"), Variable("phiB", "output", 0.0, "rad"),
                 Variable("wA", "output", 0.0, "rad/s"),
                 Variable("J", "parameter", p["J"], "kg.m2"),
                 Variable("d", "parameter", p["d"], "N.m.s/rad")]
    derivatives = {"phi": "{w}", "w": "({M_A} + {M_B} - {d} * {w}) / {J}"}
    jacobian = None
    if directional:
        jacobian = {("der(phi)", "w"): "1.0", ("der(w)", "w"): "-{d} / {J}",
                    ("der(w)", "M_A"): "1.0 / {J}", ("der(w)", "M_B"): "1.0 / {J}",
                    ("wB", "w"): "1.0", ("phiB", "phi"): "1.0", ("wA", "w"): "1.0"}
    outputs = {"wB": "{w}", "phiB": "{phi}", "wA": "{w}"}
    return me_fmu(path, "mechanical", variables, derivatives, outputs, jacobian)


def gear_fmu(path: str | Path, *, directional: bool = True) -> Path:
    """No state: w_out = ratio w_in (direct feedthrough)."""
    variables = [Variable("w_in", "input", 0.0, "rad/s"), Variable("w_out", "output", 0.0, "rad/s"),
                 Variable("ratio", "parameter", DC_MOTOR_DEFAULTS["ratio"])]
    jacobian = {("w_out", "w_in"): "{ratio}"} if directional else None
    return me_fmu(path, "gear", variables, {}, {"w_out": "{ratio} * {w_in}"}, jacobian)


def dc_motor_matrices(R: float, L: float, k: float, J: float, d: float,
                      ratio: float) -> dict[str, np.ndarray]:
    """A, B, C, E of :func:`dc_motor_ssp`'s SuT derived by hand (states i, phi, w; input U;
    unknown input M_load; output phiB): L di/dt = U - R i - k ratio w, dphi/dt = w,
    J dw/dt = k i + M_load - d w."""
    A = np.array([[-R / L, 0.0, -k * ratio / L], [0.0, 0.0, 1.0], [k / J, 0.0, -d / J]])
    return {"A": A, "B": np.array([[1.0 / L], [0.0], [0.0]]), "C": np.array([[0.0, 1.0, 0.0]]),
            "E": np.array([[0.0], [0.0], [1.0 / J]])}


def _ssd_element(parent: ET.Element, tag: str, **attrib: str) -> ET.Element:
    return ET.SubElement(parent, f"{{{SSD}}}{tag}", attrib)


SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"


def _connector(parent: ET.Element, name: str, kind: str, unit: str = "") -> None:
    conn = _ssd_element(parent, "Connector", name=name, kind=kind)
    ET.SubElement(conn, f"{{{SSC}}}Real", {"unit": unit} if unit else {})


def _parameter_set(values: dict[str, float]) -> ET.Element:
    pset = ET.Element(f"{{{SSV}}}ParameterSet", version="1.0", name="parameters")
    params = ET.SubElement(pset, f"{{{SSV}}}Parameters")
    for name, value in values.items():
        param = ET.SubElement(params, f"{{{SSV}}}Parameter", name=name)
        ET.SubElement(param, f"{{{SSV}}}Real", value=repr(float(value)))
    return pset


def _component(parent: ET.Element, name: str, source: str,
               connectors: list[tuple[str, str, str]], bindings: dict[str, float] | None = None,
               ssv: str | None = None) -> None:
    comp = _ssd_element(parent, "Component", name=name, source=source,
                        type="application/x-fmu-sharedlibrary")
    conns = _ssd_element(comp, "Connectors")
    for connector in connectors:
        _connector(conns, *connector)
    if bindings or ssv:
        binding = _ssd_element(_ssd_element(comp, "ParameterBindings"), "ParameterBinding",
                               **({"source": ssv} if ssv else {}))
        if bindings:
            _ssd_element(binding, "ParameterValues").append(_parameter_set(bindings))


def dc_motor_ssp(path: str | Path, *, R: float = 0.5, k: float = 0.1, J: float = 0.002,
                 d: float = 0.001, ratio: float = 2.0, w_unit: str = "rad/s",
                 directional: bool = True) -> Path:
    """The DC motor SSP: system ``DC-Motor`` (connectors and a stimuli FMU that the
    linearisation of ``DC-Motor.SuT`` ignores) holding the subsystem ``SuT`` (inputs U,
    M_load; outputs phiB, wB, I, M_mot) of the electrical, mechanical and gear FMUs.

    R, k (electrical), J, d (mechanical) are bound inline, ratio (gear) in
    ``resources/gear.ssv``; L keeps the FMU's default. ``w_unit``: the electrical FMU's unit
    of w (another than rad/s makes a unit mismatch).
    """
    path = Path(path)
    with tempfile.TemporaryDirectory() as tmp:
        res = Path(tmp)
        electrical_fmu(res / "electrical.fmu", w_unit=w_unit, directional=directional)
        mechanical_fmu(res / "mechanical.fmu", directional=directional)
        gear_fmu(res / "gear.fmu", directional=directional)
        linear_fmu(res / "stimuli.fmu", [[0.0]], [[0.0]], [[1.0]], name="stimuli",
                   outputs=["U"])
        ET.register_namespace("ssd", SSD)
        ET.register_namespace("ssc", SSC)
        ET.register_namespace("ssv", SSV)
        root = ET.Element(f"{{{SSD}}}SystemStructureDescription", version="1.0",
                          name="DC-Motor")
        top = _ssd_element(root, "System", name="DC-Motor")
        _connector(_ssd_element(top, "Connectors"), "phiB", "output", "rad")
        top_elements = _ssd_element(top, "Elements")
        sut = _ssd_element(top_elements, "System", name="SuT")
        _component(top_elements, "stimuli", "resources/stimuli.fmu", [("U", "output", "V")])
        sut_connectors = _ssd_element(sut, "Connectors")
        for name, kind, unit in [("U", "input", "V"), ("M_load", "input", "Nm"),
                                 ("phiB", "output", "rad"), ("wB", "output", "rad/s"),
                                 ("I", "output", "A"), ("M_mot", "output", "N.m")]:
            _connector(sut_connectors, name, kind, unit)
        elements = _ssd_element(sut, "Elements")
        _component(elements, "emachine", "resources/electrical.fmu",
                   [("U", "input", "V"), ("w", "input", w_unit), ("M", "output", "N.m"),
                    ("I", "output", "A")], {"R": R, "k": k})
        _component(elements, "edrive", "resources/mechanical.fmu",
                   [("M_A", "input", "N.m"), ("M_B", "input", "N.m"), ("wB", "output", "rad/s"),
                    ("phiB", "output", "rad"), ("wA", "output", "rad/s")], {"J": J, "d": d})
        _component(elements, "gear", "resources/gear.fmu",
                   [("w_in", "input", "rad/s"), ("w_out", "output", "rad/s")],
                   ssv="resources/gear.ssv")
        connections = _ssd_element(sut, "Connections")
        for start, end in [(("", "U"), ("emachine", "U")), (("", "M_load"), ("edrive", "M_B")),
                           (("emachine", "M"), ("edrive", "M_A")),
                           (("edrive", "wA"), ("gear", "w_in")),
                           (("gear", "w_out"), ("emachine", "w")),
                           (("edrive", "phiB"), ("", "phiB")), (("edrive", "wB"), ("", "wB")),
                           (("emachine", "I"), ("", "I")), (("emachine", "M"), ("", "M_mot"))]:
            attrib = {"startConnector": start[1], "endConnector": end[1]}
            attrib |= {"startElement": start[0]} if start[0] else {}
            attrib |= {"endElement": end[0]} if end[0] else {}
            _ssd_element(connections, "Connection", **attrib)
        top_connections = _ssd_element(top, "Connections")
        _ssd_element(top_connections, "Connection", startElement="stimuli", startConnector="U",
                     endElement="SuT", endConnector="U")
        _ssd_element(top_connections, "Connection", startElement="SuT", startConnector="phiB",
                     endConnector="phiB")
        _ssd_element(root, "Units").append(_unit("Nm"))
        ET.ElementTree(root).write(res / "SystemStructure.ssd", encoding="UTF-8",
                                   xml_declaration=True)
        ET.ElementTree(_parameter_set({"ratio": ratio})).write(res / "gear.ssv",
                                                               encoding="UTF-8",
                                                               xml_declaration=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.write(res / "SystemStructure.ssd", "SystemStructure.ssd")
            for name in ("electrical.fmu", "mechanical.fmu", "gear.fmu", "stimuli.fmu",
                         "gear.ssv"):
                archive.write(res / name, f"resources/{name}")
    return path


def _unit(name: str) -> ET.Element:
    """An SSD unit of torque (kg m^2 s^-2), the base unit of the FMUs' N.m."""
    unit = ET.Element(f"{{{SSC}}}Unit", name=name)
    ET.SubElement(unit, f"{{{SSC}}}BaseUnit", kg="1", m="2", s="-2")
    return unit


BASE_UNITS = {"N.m": {"kg": "1", "m": "2", "s": "-2"}, "rad/s": {"rad": "1", "s": "-1"},
              "rpm": {"rad": "1", "s": "-1", "factor": "0.10471975511965977"}}
"""The base units the generated FMUs declare for their units (others: the name only)."""


def _model_description(layout: _Layout, name: str, guid: str, directional: bool,
                       model_exchange: bool) -> ET.Element:
    root = ET.Element("fmiModelDescription", fmiVersion="2.0", modelName=name, guid=guid,
                      variableNamingConvention="structured", numberOfEventIndicators="0")
    flags = {"modelIdentifier": name, "canNotUseMemoryManagementFunctions": "true",
             "canGetAndSetFMUstate": "true",
             "providesDirectionalDerivative": "true" if directional else "false"}
    if model_exchange:
        ET.SubElement(root, "ModelExchange", flags | {"completedIntegratorStepNotNeeded": "true"})
    ET.SubElement(root, "CoSimulation", flags | {"canHandleVariableCommunicationStepSize": "true"})
    units = sorted({v.unit for v in layout.variables if v.unit})
    if units:
        definitions = ET.SubElement(root, "UnitDefinitions")
        for unit in units:
            element = ET.SubElement(definitions, "Unit", name=unit)
            if unit in BASE_UNITS:
                ET.SubElement(element, "BaseUnit", BASE_UNITS[unit])
    typed = sorted({v.unit for v in layout.variables if v.unit_type})
    if typed:
        types = ET.SubElement(root, "TypeDefinitions")
        for unit in typed:
            simple = ET.SubElement(types, "SimpleType", name=f"Type_{unit}")
            ET.SubElement(simple, "Real", unit=unit)
    ET.SubElement(root, "DefaultExperiment", startTime="0.0", stopTime="1.0")
    variables = ET.SubElement(root, "ModelVariables")
    states = [v for v in layout.variables if v.role == "state"]
    for v in layout.variables:
        attrib = {"name": v.name, "valueReference": str(layout.vr[v.name])}
        real = {}
        if v.role == "state":
            attrib |= {"causality": "local", "variability": "continuous", "initial": "exact"}
            real["start"] = repr(v.start)
        elif v.role == "input":
            attrib |= {"causality": "input", "variability": "continuous"}
            real["start"] = repr(v.start)
        elif v.role == "output":
            attrib |= {"causality": "output", "variability": "continuous",
                       "initial": "calculated"}
        else:
            attrib |= {"causality": "parameter", "variability": "tunable", "initial": "exact"}
            real["start"] = repr(v.start)
        if v.unit_type:
            real["declaredType"] = f"Type_{v.unit}"
        elif v.unit:
            real["unit"] = v.unit
        if v.nominal is not None:
            real["nominal"] = repr(v.nominal)
        ET.SubElement(ET.SubElement(variables, "ScalarVariable", attrib), "Real", real)
    for state in states:
        der = f"der({state.name})"
        attrib = {"name": der, "valueReference": str(layout.vr[der]), "causality": "local",
                  "variability": "continuous", "initial": "calculated"}
        index = layout.variables.index(state) + 1
        ET.SubElement(ET.SubElement(variables, "ScalarVariable", attrib), "Real",
                      derivative=str(index))
    structure = ET.SubElement(root, "ModelStructure")
    index = {v.name: i + 1 for i, v in enumerate(layout.variables)}
    index |= {f"der({s.name})": len(layout.variables) + i + 1 for i, s in enumerate(states)}
    outputs = [v.name for v in layout.variables if v.role == "output"]
    if outputs:
        section = ET.SubElement(structure, "Outputs")
        for out in outputs:
            ET.SubElement(section, "Unknown", index=str(index[out]))
    if states:
        section = ET.SubElement(structure, "Derivatives")
        for s in states:
            ET.SubElement(section, "Unknown", index=str(index[f"der({s.name})"]))
    if outputs or states:
        section = ET.SubElement(structure, "InitialUnknowns")
        for unknown in outputs + [f"der({s.name})" for s in states]:
            ET.SubElement(section, "Unknown", index=str(index[unknown]))
    return root


def _c_array(values: Sequence, kind: str = "double") -> str:
    items = ", ".join(repr(float(v)) if kind == "double" else str(v) for v in values)
    return "{" + (items or "0") + "}"


def _c_source(layout: _Layout, jacobian: dict[tuple[str, str], str] | None) -> str:
    variables = layout.variables
    states = [v for v in variables if v.role == "state"]
    nr = len(variables) + len(states)
    settable = [1 if v.role in ("state", "input", "parameter") else 0 for v in variables]
    settable += [0] * len(states)
    start = [v.start for v in variables] + [0.0] * len(states)
    nominal = [v.nominal if v.nominal is not None else 1.0 for v in states]
    der_vr = [layout.vr[f"der({s.name})"] for s in states]
    evaluate = [f"    r[{vr}] = {layout.c(layout.derivatives[s.name])};"
                for vr, s in zip(der_vr, states, strict=True)]
    evaluate += [f"    r[{layout.vr[y]}] = {layout.c(e)};" for y, e in layout.outputs.items()]
    partial = ["    switch (unknown * NR + known) {"]
    for (unknown, known), expression in (jacobian or {}).items():
        partial.append(f"    case {layout.vr[unknown] * nr + layout.vr[known]}: "
                       f"return {layout.c(expression)};")
    partial += ["    default: return 0.0;", "    }"]
    constants = f"""
#define NR {nr}
#define NX {len(states)}
#define DIRECTIONAL {1 if jacobian is not None else 0}
static const double START[NR] = {_c_array(start)};
static const int SETTABLE[NR] = {_c_array(settable, "int")};
static const int STATE_VR[NX ? NX : 1] = {_c_array([layout.vr[s.name] for s in states], "int")};
static const int DER_VR[NX ? NX : 1] = {_c_array(der_vr, "int")};
static const double NOMINAL[NX ? NX : 1] = {_c_array(nominal)};

static void evaluate(double *r) {{
    (void)r;
{chr(10).join(evaluate)}
}}

static double partial(int unknown, int known, const double *r) {{
    (void)r;
{chr(10).join(partial)}
}}
"""
    return C_HEADER + constants + C_BODY


C_HEADER = """\
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"
"""

C_BODY = r"""
typedef struct {
    double r[NR];
    double time;
    int initialising;
    fmi2CallbackFunctions cb;
    char name[128];
} Model;

static fmi2Status fail(Model *m, const char *message) {
    if (m && m->cb.logger) m->cb.logger(m->cb.componentEnvironment, m->name, fmi2Error, "error",
                                        "%s", message);
    return fmi2Error;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) {
    (void)c; (void)on; (void)n; (void)cat; return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                              fmi2String resources, const fmi2CallbackFunctions *cb,
                              fmi2Boolean visible, fmi2Boolean logging) {
    (void)type; (void)guid; (void)resources; (void)visible; (void)logging;
    Model *m = calloc(1, sizeof(Model));
    if (!m) return NULL;
    memcpy(m->r, START, sizeof(START));
    if (cb) m->cb = *cb;
    snprintf(m->name, sizeof(m->name), "%s", name ? name : "");
    return m;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol,
                               fmi2Real start, fmi2Boolean stopDefined, fmi2Real stop) {
    (void)tolDefined; (void)tol; (void)stopDefined; (void)stop;
    ((Model *)c)->time = start;
    return fmi2OK;
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ((Model *)c)->initialising = 1; return fmi2OK;
}
fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    ((Model *)c)->initialising = 0; evaluate(((Model *)c)->r); return fmi2OK;
}
fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) {
    Model *m = c; memcpy(m->r, START, sizeof(START)); m->time = 0.0; return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Model *m = c;
    evaluate(m->r);
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= NR) return fail(m, "unknown value reference");
        v[i] = m->r[vr[i]];
    }
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                       const fmi2Real v[]) {
    Model *m = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= NR || !SETTABLE[vr[i]]) return fail(m, "variable cannot be set");
        m->r[vr[i]] = v[i];
    }
    return fmi2OK;
}
#define NO_VALUES(T, F) \
    fmi2Status F(fmi2Component c, const fmi2ValueReference vr[], size_t n, T v[]) { \
        (void)vr; (void)v; return n ? fail(c, "no such variable") : fmi2OK; }
NO_VALUES(fmi2Integer, fmi2GetInteger)
NO_VALUES(fmi2Boolean, fmi2GetBoolean)
NO_VALUES(fmi2String, fmi2GetString)
NO_VALUES(const fmi2Integer, fmi2SetInteger)
NO_VALUES(const fmi2Boolean, fmi2SetBoolean)
NO_VALUES(const fmi2String, fmi2SetString)

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Model *copy = *state ? *state : malloc(sizeof(Model));
    if (!copy) return fail(c, "out of memory");
    memcpy(copy, c, sizeof(Model));
    *state = copy;
    return fmi2OK;
}
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    memcpy(c, state, sizeof(Model)); return fmi2OK;
}
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c; free(*state); *state = NULL; return fmi2OK;
}
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size) {
    (void)s; (void)size; return fail(c, "no serialisation");
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    (void)s; (void)b; (void)n; return fail(c, "no serialisation");
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n,
                                   fmi2FMUstate *s) {
    (void)s; (void)b; (void)n; return fail(c, "no serialisation");
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference unknown[],
                                        size_t nu, const fmi2ValueReference known[], size_t nk,
                                        const fmi2Real dk[], fmi2Real du[]) {
    Model *m = c;
    if (!DIRECTIONAL) return fail(m, "no directional derivatives");
    for (size_t i = 0; i < nu; i++) {
        du[i] = 0.0;
        for (size_t j = 0; j < nk; j++) du[i] += partial(unknown[i], known[j], m->r) * dk[j];
    }
    return fmi2OK;
}

/* Model Exchange */
fmi2Status fmi2EnterEventMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    (void)c;
    memset(info, 0, sizeof(*info));
    return fmi2OK;
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSet,
                                       fmi2Boolean *event, fmi2Boolean *stop) {
    (void)c; (void)noSet; *event = fmi2False; *stop = fmi2False; return fmi2OK;
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((Model *)c)->time = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    Model *m = c;
    if (nx != NX) return fail(m, "wrong number of states");
    for (size_t i = 0; i < nx; i++) m->r[STATE_VR[i]] = x[i];
    return fmi2OK;
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t nx) {
    Model *m = c;
    if (nx != NX) return fail(m, "wrong number of states");
    evaluate(m->r);
    for (size_t i = 0; i < nx; i++) dx[i] = m->r[DER_VR[i]];
    return fmi2OK;
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t nz) {
    (void)z; return nz ? fail(c, "no event indicators") : fmi2OK;
}
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    Model *m = c;
    if (nx != NX) return fail(m, "wrong number of states");
    for (size_t i = 0; i < nx; i++) x[i] = m->r[STATE_VR[i]];
    return fmi2OK;
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    if (nx != NX) return fail(c, "wrong number of states");
    for (size_t i = 0; i < nx; i++) x[i] = NOMINAL[i];
    return fmi2OK;
}

/* Co-Simulation: RK4 on a substep of min(1e-5, step / 100), inputs held */
static void derivatives(Model *m, const double *x, double *dx) {
    for (int i = 0; i < NX; i++) m->r[STATE_VR[i]] = x[i];
    evaluate(m->r);
    for (int i = 0; i < NX; i++) dx[i] = m->r[DER_VR[i]];
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real step, fmi2Boolean noSet) {
    Model *m = c;
    (void)noSet;
    if (!(step > 0.0) || fabs(t - m->time) > 1e-9 * (1.0 + fabs(t)))
        return fail(m, "doStep: bad time or step");
    double h_max = step / 100.0 < 1e-5 ? step / 100.0 : 1e-5;
    long count = (long)ceil(step / h_max - 1e-9);
    double h = step / (double)count;
    double x[NX + 1], k1[NX + 1], k2[NX + 1], k3[NX + 1], k4[NX + 1], s[NX + 1];
    for (int i = 0; i < NX; i++) x[i] = m->r[STATE_VR[i]];
    for (long n = 0; n < count && NX > 0; n++) {
        derivatives(m, x, k1);
        for (int i = 0; i < NX; i++) s[i] = x[i] + 0.5 * h * k1[i];
        derivatives(m, s, k2);
        for (int i = 0; i < NX; i++) s[i] = x[i] + 0.5 * h * k2[i];
        derivatives(m, s, k3);
        for (int i = 0; i < NX; i++) s[i] = x[i] + h * k3[i];
        derivatives(m, s, k4);
        for (int i = 0; i < NX; i++) x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
    for (int i = 0; i < NX; i++) m->r[STATE_VR[i]] = x[i];
    evaluate(m->r);
    m->time = t + step;
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { return fail(c, "cannot cancel"); }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[]) {
    (void)vr; (void)order; (void)v; return n ? fail(c, "no input derivatives") : fmi2OK;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[]) {
    (void)vr; (void)order; (void)v; return n ? fail(c, "no output derivatives") : fmi2OK;
}
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) {
    (void)k; (void)v; return fail(c, "no status");
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) {
    (void)k; (void)v; return fail(c, "no status");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) {
    (void)k; (void)v; return fail(c, "no status");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) {
    (void)k; (void)v; return fail(c, "no status");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) {
    (void)k; (void)v; return fail(c, "no status");
}
"""
