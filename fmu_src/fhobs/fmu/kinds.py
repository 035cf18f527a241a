"""The FMU kinds, each declared once: its variables, its output layout, its code in the native FMUs.

A kind (``observer``, ``luenberger``, ``prescribed_time``, ``kalman``, ``supervised``,
``plant``) is one
:class:`Kind`: the variables of its FMU in value-reference order, each with its role and where
its start value comes from. Everything else is derived from it:

- the pythonfmu slave (:mod:`fhobs.fmu.slave_base`) registers the variables of its kind in
  this order (so the value references are these), maps the design parameters back to the
  record it runs at initialisation (:func:`edited_record`) and lays its output buffer out as
  :attr:`Kind.outputs`;
- :mod:`fhobs.build` finds the slave class here, and the build options
  (:mod:`fhobs.fmu.options`) which kinds a design builds (:meth:`Kind.built_when`);
- :mod:`fhobs.native.build` writes the native FMU's modelDescription, its value references
  (``VR_<NAME>``), its variable table, its start values (:meth:`Kind.initial_outputs`: the
  runtime model, no pythonfmu slave) and its kind number (``FHOBS_KIND_<NAME>``,
  :data:`KIND_CODES`, generated from the order below) from the same declaration, and compiles
  the C unit and the plan data of its :attr:`Kind.family`: both builds of a kind have one
  interface;
- the harness labels an estimator's figures with :attr:`Kind.label` and builds the kinds
  :meth:`Kind.built_when` names for its design and its measurement noise;
- the tests enumerate the kinds here (:func:`kinds_where`), so a new kind is covered.

Each kind names its runtime model (:attr:`Kind.model`, made from the record and the setting
parameters, the same in the pythonfmu slave and the native build's start values), its
certificate (:attr:`Kind.certificate`, re-checked by the pythonfmu FMU on edited design
parameters), its family (:data:`FAMILIES`: the native FMU's C model and plan data) and its
build rules (the record present, :attr:`Kind.noise_free`, :attr:`Kind.check_options`).

Each kind runs one record of the design (:attr:`Kind.record`: ``filtering``,
``prescribed_time``, ``luenberger``, ``kalman``, ``supervised`` or ``plant``, an attribute of
:class:`fhobs.core.gains.ObserverDesign`); its variables' shapes, start values and field paths
are of that record.

Roles: ``input`` and ``output`` signals; ``design`` parameters, a field of the kind's record
(:attr:`Variable.field`), re-certified by the pythonfmu FMUs when edited and compiled into the
native FMUs; ``setting`` parameters, per-instance values from the build options
(:attr:`Variable.option`: initial states, internal step, scheme, noise, ``input_bound``),
settable in both builds until fmi2ExitInitializationMode; and the ``local`` Integer ``status``
(value reference 0), the status wrapper's channel.

This module runs inside the pythonfmu FMUs: numpy and the shipped core only.

Examples
--------
>>> [v.name for v in KINDS["luenberger"].variables]
['status', 'A', 'B', 'C', 'L_lin', 'z0', 'h', 'scheme', 'y', 'u', 'x_hat', 'input_bound']
>>> KINDS["plant"].family, KINDS["observer"].label
('plant', 'homogeneous')
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.certificate import (
    certify_filtering,
    certify_kalman,
    certify_luenberger,
    certify_prescribed_time,
    certify_supervised,
)
from ..core.gains import SHARED, ObserverDesign
from ..core.kalman_filter import KalmanObserver
from ..core.plant import PLANT_SCHEMES, LTIPlant
from ..core.runtime import (
    SCHEMES,
    FilteringObserver,
    LuenbergerObserver,
    PrescribedTimeObserver,
    prescribed_xi0,
)
from ..core.supervisor import SupervisedObserver

ROLES = ("local", "input", "output", "design", "setting")
"""The roles of a variable (see the module docstring)."""
FAMILIES = ("filtering", "prescribed_time", "linear", "kalman", "supervised", "plant")
"""The native plan families: the C model (``native/family_<family>.c``) and plan data
(:data:`fhobs.native.build.FAMILIES`) a kind's native FMU is built with. ``linear``: an
observer of a constant gain, dz/dt = A z + B u + L (C z - y) (the Luenberger observer)."""
Setting = Callable[[str], Any]
"""The value of a setting parameter by name: a float, an array, an Integer or, for a choice,
its name (the pythonfmu slave's current values, or the build options)."""


@dataclass(frozen=True)
class Variable:
    """One variable of a kind: a float array (or scalar) or an Integer.

    Attributes
    ----------
    name : str
        Base name; an array's elements are ``name[i]`` / ``name[i,j]``.
    role : str
        One of :data:`ROLES`.
    description : str
        The modelDescription's text.
    field : str
        ``design`` role: the attribute of the kind's record it is (``"L_tilde"``,
        ``"model.L0"``, ``"plant.A"``: a field of a record held by the record).
    option : str
        ``setting`` role: the key of the build options (``fmu_config.json``) holding its start.
    shape : callable, optional
        ``input`` / ``output`` role: the shape from the kind's record (zeros are the start
        value; a shape with no element leaves the variable out).
    choices : tuple of str
        An Integer ``setting`` that selects one of ``choices`` (its start is the index of the
        option's value).
    integer : bool
        An Integer variable (``status``, a choice, ``noise_seed``), else Real.
    signal : str
        ``input`` / ``output`` role: the group of the plant's signals its elements are
        (``"states"``, ``"inputs"``, ``"outputs"``, ``"unknown_inputs"``: the keys of the
        spec's ``[signals]`` table), named in the modelDescription (:meth:`element_text`).
    text : str
        The description of an element with ``{}`` for its signal's name.
    unit : str
        The unit of a variable that is not a signal (``"s"``; a signal's unit is its
        signal's, :meth:`element_text`).
    source : str
        ``output`` role: where its value comes from. ``"state"``: the next elements of the
        runtime model's state vector (``get_state()``; in C the state the model keeps), taken
        in the order of :attr:`Kind.outputs` (:meth:`Kind.output_sources`); anything else: the
        runtime model's attribute of that name, which the C model computes by the same name.
    """

    name: str
    role: str
    description: str
    field: str = ""
    option: str = ""
    shape: Callable[[Any], tuple[int, ...]] | None = None
    choices: tuple[str, ...] = ()
    integer: bool = False
    signal: str = ""
    text: str = ""
    source: str = "state"
    unit: str = ""

    def start(self, record: Any, options: Mapping[str, Any]) -> Any:
        """The start value for the kind's ``record`` and the build ``options`` (None: left
        out).

        Examples
        --------
        >>> from fhobs.design.observer import paper_gains
        >>> KINDS["observer"].variable("L_tilde").start(paper_gains().filtering, {}).shape
        (2, 2)
        """
        if self.role == "local":
            return 0
        if self.role == "design":
            return record_field(record, self.field)
        if self.role == "setting":
            value = options[self.option]
            return self.choices.index(value) if self.choices else value
        shape = self.shape(record)
        return np.zeros(shape) if int(np.prod(shape)) or not shape else None

    def element_text(self, index: int, names: Mapping[str, Sequence[str]]) -> tuple[str, str]:
        """The description and unit (``""``: none) of element ``index`` (0-based) of a signal
        variable (:attr:`signal`) for the plant's signal ``names`` (the keys of the spec's
        ``[signals]`` table, every one present). Past the group's size the elements are its
        derivatives, one block per order (``q_hat``: q, then q', ...; the unit per second).

        Examples
        --------
        >>> names = {"unknown_inputs": ["M_load"], "unknown_input_units": ["N.m"]}
        >>> [KINDS["observer"].variable("q_hat").element_text(i, names) for i in (0, 1)]
        [('estimate of the unknown input M_load', 'N.m'), \
("estimate of the unknown input M_load'", 'N.m/s')]
        """
        labels, units = names[self.signal], names[self.signal[:-1] + "_units"]
        order, i = divmod(index, len(labels))
        return self.text.format(labels[i] + "'" * order), derivative_unit(units[i], order)


def derivative_unit(unit: str, order: int) -> str:
    """The unit of the ``order``-th time derivative of a quantity in ``unit`` (Modelica's unit
    syntax: ``"N.m/s"``, ``"(rad/s)/s2"``; ``""`` stays ``""``).

    Examples
    --------
    >>> derivative_unit("N.m", 1), derivative_unit("rad/s", 2), derivative_unit("", 3)
    ('N.m/s', '(rad/s)/s2', '')
    """
    if not unit or not order:
        return unit
    base = f"({unit})" if "/" in unit else unit
    return f"{base}/s" if order == 1 else f"{base}/s{order}"


@dataclass(frozen=True)
class Kind:
    """One FMU kind.

    Attributes
    ----------
    name : str
        The kind (and the FMU's file name without ``.fmu``).
    slave : str
        The pythonfmu slave class: in ``fhobs.fmu.<name>`` for a kind with checks of its own
        (:attr:`slave_module`), else the generic :class:`~fhobs.fmu.slave_base.ObserverSlave`
        under this name.
    description : str
        The modelDescription's description.
    label : str
        The estimator's label in the harness's figures ('' for the plant).
    record : str
        The attribute of the design (:class:`~fhobs.core.gains.ObserverDesign`) holding the
        record the kind runs.
    variables : tuple of Variable
        In value-reference order.
    outputs : tuple of str
        The output arrays in the order the runtime model gives them (the slave's buffer).
    family : str
        One of :data:`FAMILIES`.
    model : callable
        ``model(record, setting)``: the runtime model of ``record`` with the setting
        parameters ``setting`` (:data:`Setting`).
    certificate : callable or None
        ``certificate(record)``: raises CertificateError if the (edited) record is not
        certified (None: the plant, nothing to certify).
    noise_free : bool
        Not run on noisy measurements (its gain grows without bound: noise, amplified).
    check_options : callable, optional
        ``check_options(record, options)``: ValueError naming a build option the kind cannot
        start from (beyond each option's own check, :mod:`fhobs.fmu.options`).
    slave_module : str
        The module of ``fhobs.fmu`` holding :attr:`slave` ('': the generic slave).
    """

    name: str
    slave: str
    description: str
    label: str
    record: str
    variables: tuple[Variable, ...]
    outputs: tuple[str, ...]
    family: str
    model: Callable[[Any, Setting], Any]
    certificate: Callable[[Any], Any] | None
    noise_free: bool = False
    check_options: Callable[[Any, Mapping[str, Any]], None] | None = None
    slave_module: str = ""

    @property
    def code(self) -> int:
        """``FHOBS_KIND_<NAME>``, the kind's code in the native FMUs' C sources
        (:data:`KIND_CODES`)."""
        return KIND_CODES[self.name]

    def built_when(self, design: ObserverDesign, noise: bool = False) -> bool:
        """Whether the kind is built (and run) for ``design`` with measurement ``noise``: the
        design has its record and, with noise, the kind is not :attr:`noise_free`.

        Examples
        --------
        >>> from fhobs.design.observer import paper_gains
        >>> [name for name, kind in KINDS.items() if kind.built_when(paper_gains(), True)]
        ['observer', 'luenberger', 'plant']
        """
        return getattr(design, self.record) is not None and not (noise and self.noise_free)

    def initial_outputs(self, record: Any, setting: Setting) -> dict[str, np.ndarray]:
        """The outputs present at the start (what the FMU publishes when instantiated): the
        runtime model's (:attr:`model`) at its initial state, from where
        :meth:`output_sources` says, each in its variable's shape.

        Examples
        --------
        >>> from fhobs.design.observer import paper_gains
        >>> settings = {"z0": [1.0, 0, 0, 0], "psi0": [0.0, 0.0], "xi0": 4.0, "h": 5e-5,
        ...             "scheme": "split"}
        >>> out = KINDS["observer"].initial_outputs(paper_gains().filtering, settings.get)
        >>> out["x_hat"].tolist(), float(out["sigma"])
        ([1.0, 0.0, 0.0, 0.0], 2.0)
        """
        shapes = {v.name: v.shape(record) for v in self.variables if v.role == "output"}
        sizes = {name: int(np.prod(shape)) for name, shape in shapes.items()
                 if int(np.prod(shape)) or not shape}
        model = self.model(record, setting)
        state = model.get_state()
        return {name: np.reshape(state[offset:offset + size] if source == "state"
                                 else np.ravel(getattr(model, source)), shapes[name])
                for name, source, offset, size in self.output_sources(sizes)}

    def variable(self, name: str) -> Variable:
        """The variable called ``name`` (KeyError if the kind has none)."""
        for variable in self.variables:
            if variable.name == name:
                return variable
        raise KeyError(f"the {self.name} FMU has no variable {name!r}")

    def output_sources(self, sizes: Mapping[str, int]) -> list[tuple[str, str, int, int]]:
        """Where each output present comes from, in the order of :attr:`outputs`:
        ``(name, source, offset, size)``, the offset counted in the model's state for a
        ``"state"`` source (the state outputs are its first elements, in this order), 0 for an
        attribute. ``sizes``: the number of elements of each output present.

        Examples
        --------
        >>> KINDS["observer"].output_sources({"x_hat": 4, "psi": 2, "xi": 1, "sigma": 1})
        [('x_hat', 'state', 0, 4), ('psi', 'state', 4, 2), ('xi', 'state', 6, 1), \
('sigma', 'sigma', 0, 1)]
        """
        sources, offset = [], 0
        for name in self.outputs:
            if name not in sizes:
                continue
            source = self.variable(name).source
            sources.append((name, source, offset if source == "state" else 0, sizes[name]))
            offset += sizes[name] if source == "state" else 0
        return sources

    def runs(self, design: ObserverDesign) -> Any:
        """The record of ``design`` that the kind runs (its :attr:`record`).

        Examples
        --------
        >>> from fhobs.design.observer import paper_gains
        >>> design = paper_gains()
        >>> KINDS["luenberger"].runs(design) is design.luenberger
        True
        """
        record = getattr(design, self.record)
        if record is None:
            raise ValueError(f"the design has no {self.record} record (it is null)")
        return record

    def starts(self, record: Any, options: Mapping[str, Any]) -> list[tuple[Variable, Any]]:
        """The variables present for the kind's ``record`` with their start values, in
        value-reference order (a variable whose start is None, such as ``q_hat`` without a
        disturbance model or ``E`` of a plant without one, is left out).

        Examples
        --------
        >>> from fhobs.design.observer import paper_gains
        >>> options = {"x0": [0.0] * 4, "noise_amplitude": 0.0, "noise_seed": 0,
        ...            "plant_scheme": "zoh", "input_bound": 1e8}
        >>> [v.name for v, _ in KINDS["plant"].starts(paper_gains().plant, options)][:6]
        ['status', 'A', 'B', 'C', 'E', 'x0']
        """
        present = []
        for variable in self.variables:
            value = variable.start(record, options)
            if value is not None:
                present.append((variable, value))
        return present


def record_field(record: Any, path: str) -> Any:
    """The attribute ``path`` of a record (``"L_tilde"``, ``"model.L0"``, ``"plant.A"``).

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> filtering = paper_gains().filtering
    >>> record_field(filtering, "model.nu") == filtering.model.nu
    True
    """
    value = record
    for part in path.split("."):
        value = getattr(value, part)
    return value


def edited_record(record: Any, values: Mapping[str, Any]) -> Any:
    """``record`` with the fields of ``values`` (``{path: value}`` as :attr:`Variable.field`)
    replaced: a new record (with new nested records where a path goes into one), ``record``
    unchanged. An edited plant or model of ``record`` (:data:`fhobs.core.gains.SHARED`) is
    also the plant or model of the records it holds (they share them: the supervised
    record's filtering and Kalman parts, a design's estimators).

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> filtering = paper_gains().filtering
    >>> edited = edited_record(filtering, {"rho": 3.0, "model.nu": -0.2})
    >>> edited.rho, edited.model.nu, round(filtering.model.nu, 4)
    (3.0, -0.2, -0.3333)
    >>> design = paper_gains()
    >>> edited_record(design, {"model.nu": -0.2}).prescribed_time.model.nu
    -0.2
    """
    changes: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for path, value in values.items():
        head, _, rest = path.partition(".")
        if rest:
            nested.setdefault(head, {})[rest] = value
        else:
            changes[head] = value
    for head, inner in nested.items():
        changes[head] = edited_record(getattr(record, head), inner)
    shared = {name: changes[name] for name in SHARED if name in changes}
    for f in dataclasses.fields(record):
        part = changes.get(f.name, getattr(record, f.name))
        held = {name: value for name, value in shared.items() if hasattr(part, name)}
        if f.name not in SHARED and held and dataclasses.is_dataclass(part):
            changes[f.name] = dataclasses.replace(part, **held)
    return dataclasses.replace(record, **changes)


def _disturbance_states(record: Any) -> tuple[int, ...]:
    return (record.model.n_model - record.plant.n,)


def _kalman_disturbance_states(kalman: Any) -> tuple[int, ...]:
    return (kalman.gain.shape[0] - kalman.plant.n,)


def _perturbations(plant: Any) -> tuple[int, ...]:
    return (0 if plant.E is None else plant.E.shape[1],)


STATUS = Variable("status", "local",
                  "status of the last call the slave answered (0 ok, 1 warning, 3 error)",
                  integer=True)
INPUT_BOUND = Variable("input_bound", "setting",
                       "inputs of larger magnitude are rejected as absurd", option="input_bound")
PLANT_MATRICES = (
    Variable("A", "design", "plant state matrix (n x n)", field="plant.A"),
    Variable("B", "design", "plant input matrix (n x m)", field="plant.B"),
    Variable("C", "design", "plant output matrix (k x n)", field="plant.C"),
)
ESTIMATOR_SIGNALS = (
    Variable("y", "input", "measured plant output", shape=lambda r: (r.plant.k,),
             signal="outputs", text="measured {}"),
    Variable("u", "input", "plant input", shape=lambda r: (r.plant.m,), signal="inputs",
             text="input {}"),
    Variable("x_hat", "output", "state estimate z", shape=lambda r: (r.plant.n,),
             signal="states", text="estimate of {}"),
)
Z0 = Variable("z0", "setting", "initial state estimate", option="z0")
TIMING = (
    Variable("h", "setting", "internal integration step (s)", option="h"),
    Variable("scheme", "setting", "integration scheme: "
             + ", ".join(f"{i} = {s}" for i, s in enumerate(SCHEMES)),
             option="scheme", choices=SCHEMES, integer=True),
)
MAX_COMMUNICATION_STEP = Variable(
    "max_communication_step", "setting", "longest communication step (s) over which the "
    "design tolerates its inputs held (fhobs.design.settling.communication_step_bracket); a "
    "longer step is answered once with fmi2Warning; 0: no check", option="max_communication_step",
    unit="s")
Q_HAT = Variable("q_hat", "output", "disturbance-model estimates: q, then its derivatives",
                 shape=_disturbance_states, signal="unknown_inputs",
                 text="estimate of the unknown input {}")


def _estimator(name: str, slave: str, description: str, label: str, record: str,
               gains: tuple[Variable, ...], outputs: tuple[str, ...],
               timing: tuple[Variable, ...] = TIMING,
               appended: tuple[Variable, ...] = (),
               signals: tuple[Variable, ...] = ESTIMATOR_SIGNALS, **rules: Any) -> Kind:
    """An estimator kind: the plant's matrices, its gains, z0, its timing, y, u, x_hat (the
    ``signals``), then ``appended`` (variables added after the others, so that no value
    reference moves); ``rules``: the other fields of :class:`Kind` (family, model,
    certificate, ...)."""
    variables = (STATUS, *PLANT_MATRICES, *gains, Z0, *timing, *signals, INPUT_BOUND,
                 *appended)
    return Kind(name, slave, description, label, record, variables, outputs, **rules)


# -- the runtime models: record + setting parameters -> the model the FMU steps ----------------
def _initial_z(record: Any, setting: Setting, disturbance_states: Callable) -> np.ndarray:
    """The model's initial state: z0 (the plant's states), then zeros (the disturbance
    states)."""
    return np.concatenate((np.asarray(setting("z0"), dtype=float),
                           np.zeros(disturbance_states(record))))


def _filtering_model(record: Any, setting: Setting) -> FilteringObserver:
    return FilteringObserver(record, h=float(setting("h")), scheme=setting("scheme"),
                             z0=_initial_z(record, setting, _disturbance_states),
                             psi0=np.asarray(setting("psi0"), dtype=float),
                             xi0=float(setting("xi0")))


def _prescribed_time_model(record: Any, setting: Setting) -> PrescribedTimeObserver:
    return PrescribedTimeObserver(record, h=float(setting("h")), scheme=setting("scheme"),
                                  z0=_initial_z(record, setting, _disturbance_states),
                                  xi0=prescribed_xi0(float(setting("T0")), record.model.nu,
                                                     record.rho))


def _prescribed_time_options(record: Any, options: Mapping[str, Any]) -> None:
    """ValueError naming T0 if it gives no initial xi."""
    prescribed_xi0(options["T0"], record.model.nu, record.rho)


def _luenberger_model(record: Any, setting: Setting) -> LuenbergerObserver:
    return LuenbergerObserver(record, h=float(setting("h")), scheme=setting("scheme"),
                              z0=np.asarray(setting("z0"), dtype=float))


def _kalman_model(record: Any, setting: Setting) -> KalmanObserver:
    return KalmanObserver(record, z0=_initial_z(record, setting, _kalman_disturbance_states))


def _supervised_model(record: Any, setting: Setting) -> SupervisedObserver:
    return SupervisedObserver(record, h=float(setting("h")), scheme=setting("scheme"),
                              z0=_initial_z(record, setting, _disturbance_states))


def _plant_model(record: Any, setting: Setting) -> LTIPlant:
    return LTIPlant(record.A, record.B, record.C, E=record.E,
                    x0=np.asarray(setting("x0"), dtype=float),
                    noise_amplitude=float(setting("noise_amplitude")),
                    seed=int(setting("noise_seed")), scheme=setting("scheme"))


# N below: states of the observer's model (n, or n + r q-states with a disturbance model)
_HOMOGENISATION = (
    Variable("L0", "design", "homogenisation gain, A0 = A_model + L0 C_model nilpotent on the "
             "range of slow_projector (N x k)", field="model.L0"),
)
_SLOW_PROJECTOR = (
    Variable("slow_projector", "design", "projector onto the homogenised part of the model, "
             "along the fast stable modes kept by the model; I when all is homogenised (N x N)",
             field="model.slow_projector"),
)


def _theorem2_gains(prefix: str) -> tuple[Variable, ...]:
    """The filtering observer's design parameters (Theorem 2: G_d, L_tilde, L, P_bar, nu, gamma,
    rho), read from the record at ``prefix`` (``""`` for a FilteringGains, ``"filtering."`` for
    the supervised record holding one)."""
    return (
        Variable("G_d", "design", "dilation generator of Theorem 2 (N x N)", field="model.G_d"),
        Variable("L_tilde", "design", "gain of the output filter psi (k x k)",
                 field=f"{prefix}L_tilde"),
        Variable("L", "design", "gain of the estimate z (N x k)", field=f"{prefix}L"),
        Variable("P_bar", "design", "Lyapunov matrix of the Theorem 2 LMI ((k+N) x (k+N))",
                 field=f"{prefix}P_bar"),
        Variable("nu", "design", "homogeneity degree", field="model.nu"),
        Variable("gamma", "design", "gain of the xi equation", field=f"{prefix}gamma"),
        Variable("rho", "design", "LMI decay parameter, rho > gamma/2", field=f"{prefix}rho"),
    )


KINDS: dict[str, Kind] = {kind.name: kind for kind in (
    _estimator(
        "observer", "FhobsObserver",
        "Filtering homogeneous observer (Ping, Zimenko, Polyakov, Efimov), Theorem 2",
        "homogeneous", "filtering",
        gains=(
            *_HOMOGENISATION,
            *_theorem2_gains(""),
            Variable("psi0", "setting", "initial output-filter state", option="psi0"),
            Variable("xi0", "setting", "initial xi", option="xi0"),
            Variable("psi", "output", "output-filter state psi", shape=lambda r: (r.plant.k,)),
            Variable("xi", "output", "scalar gain state xi", shape=lambda r: ()),
            Variable("sigma", "output", "sigma = sqrt(max(xi, |psi|^2 / 2))",
                     shape=lambda r: (), source="sigma"),
            Q_HAT,
        ),
        outputs=("x_hat", "q_hat", "psi", "xi", "sigma"),
        appended=(*_SLOW_PROJECTOR, MAX_COMMUNICATION_STEP),
        family="filtering", model=_filtering_model, certificate=certify_filtering,
    ),
    _estimator(
        "prescribed_time", "FhobsPrescribedTime",
        "Prescribed-time observer (Ping, Zimenko, Polyakov, Efimov), Theorem 1: nominal "
        "convergence at T0", "prescribed_time", "prescribed_time",
        gains=(
            *_HOMOGENISATION,
            Variable("G_d", "design", "dilation generator of Theorem 2; Theorem 1 uses "
                     "G_d - nu I (N x N)", field="model.G_d"),
            Variable("L_pt", "design", "gain of the prescribed-time injection (N x k)",
                     field="L_pt"),
            Variable("P_pt", "design", "Lyapunov matrix of the Theorem 1 LMI (N x N)",
                     field="P_pt"),
            Variable("nu", "design", "homogeneity degree", field="model.nu"),
            Variable("rho", "design", "decay parameter of the xi equation", field="rho"),
            Variable("T0", "setting", "prescribed convergence time (s); "
                     "xi0 = (-nu rho T0)^(-1/nu)", option="T0"),
            Variable("xi", "output", "scalar gain state xi (0 from T0 on)", shape=lambda r: ()),
            Q_HAT,
        ),
        outputs=("x_hat", "q_hat", "xi"),
        appended=(*_SLOW_PROJECTOR, MAX_COMMUNICATION_STEP),
        family="prescribed_time", model=_prescribed_time_model,
        certificate=certify_prescribed_time, noise_free=True,
        check_options=_prescribed_time_options, slave_module="prescribed_time",
    ),
    _estimator(
        "luenberger", "FhobsLuenberger",
        "Luenberger observer dz/dt = A z + B u + L_lin (C z - y)", "linear", "luenberger",
        gains=(Variable("L_lin", "design", "observer gain (n x k)", field="L_lin"),),
        outputs=("x_hat",),
        family="linear", model=_luenberger_model, certificate=certify_luenberger,
    ),
    _estimator(
        "kalman", "FhobsKalman",
        "Steady-state discrete Kalman filter (exact ZOH model, disturbance model)", "kalman",
        "kalman",
        gains=(
            Variable("kalman_gain", "design",
                     "measurement-update gain M = P C^T (C P C^T + R)^-1 (N x k)",
                     field="gain"),
            dataclasses.replace(Q_HAT, shape=_kalman_disturbance_states),
        ),
        timing=(Variable("Ts", "design", "sample time of the filter (s): one cycle per sample "
                         "instant inside a step", field="sample_time"),),
        outputs=("x_hat", "q_hat"),
        family="kalman", model=_kalman_model, certificate=certify_kalman, slave_module="kalman",
    ),
    _estimator(
        "supervised", "FhobsSupervised",
        "Supervised observer: the filtering homogeneous observer (Theorem 2) and a Kalman "
        "filter of its model; an innovation test with hysteresis and dwell picks the output, "
        "the homogeneous estimate handed over to the Kalman filter", "supervised", "supervised",
        gains=(
            *_HOMOGENISATION,
            *_theorem2_gains("filtering."),
            *_SLOW_PROJECTOR,
            Variable("kalman_gain", "design", "the Kalman filter's measurement-update gain "
                     "M = P C^T (C P C^T + R)^-1 (N x k)", field="kalman.gain"),
            Variable("kalman_covariance", "design", "the Kalman filter's a-priori error "
                     "covariance P (N x N): the innovation covariance S = C P C^T + R",
                     field="kalman.covariance"),
            Variable("measurement_std", "design", "standard deviation of the measurement "
                     "noise per output (R = diag(measurement_std^2))",
                     field="kalman.measurement_std"),
            Variable("Ts", "design", "sample time of the Kalman filter (s); the communication "
                     "step must be a whole multiple of it", field="kalman.sample_time"),
            Variable("window", "design", "length of the statistic's exponential window "
                     "(samples)", field="window"),
            Variable("lower", "design", "the Kalman estimate is left below this statistic",
                     field="lower"),
            Variable("upper", "design", "the Kalman estimate is left above this statistic",
                     field="upper"),
            Variable("lower_return", "design", "lower end of the return band",
                     field="lower_return"),
            Variable("upper_return", "design", "upper end of the return band; also the "
                     "homogeneous statistic's bound for the handover", field="upper_return"),
            Variable("ceiling", "design", "the statistic is held at most at this value",
                     field="ceiling"),
            Variable("dwell_time", "design", "least time (s) the homogeneous estimate is "
                     "output before the Kalman estimate is taken again", field="dwell_time"),
            Variable("false_alarm", "design", "probability per sample of leaving the Kalman "
                     "estimate on data its model explains (what the band was set for)",
                     field="false_alarm"),
            Variable("statistic", "output", "exponentially weighted mean of the Kalman "
                     "filter's normalised innovation squared", shape=lambda r: ()),
            Variable("mode", "output", "the estimate output: 0 = Kalman filter, "
                     "1 = homogeneous observer", shape=lambda r: ()),
            dataclasses.replace(Q_HAT, source="q_hat"),
        ),
        outputs=("statistic", "mode", "x_hat", "q_hat"),
        appended=(MAX_COMMUNICATION_STEP,),
        signals=(*ESTIMATOR_SIGNALS[:2],
                 dataclasses.replace(ESTIMATOR_SIGNALS[2], source="x_hat",
                                     description="state estimate of the mode's estimator",
                                     text="estimate of {} (by the mode's estimator)")),
        family="supervised", model=_supervised_model, certificate=certify_supervised,
        slave_module="supervised",
    ),
    Kind(
        "plant", "FhobsPlant", "LTI plant dx/dt = A x + B u + E q, y = C x + noise", "",
        "plant",
        variables=(
            STATUS,
            Variable("A", "design", "state matrix (n x n)", field="A"),
            Variable("B", "design", "input matrix (n x m)", field="B"),
            Variable("C", "design", "output matrix (k x n)", field="C"),
            Variable("E", "design", "perturbation matrix (n x r)", field="E"),
            Variable("x0", "setting", "initial state", option="x0"),
            Variable("noise_amplitude", "setting",
                     "measurement noise is uniform in [-noise_amplitude, noise_amplitude]",
                     option="noise_amplitude"),
            Variable("noise_seed", "setting", "seed of the measurement noise",
                     option="noise_seed", integer=True),
            Variable("scheme", "setting", "plant step: "
                     + ", ".join(f"{i} = {s}" for i, s in enumerate(PLANT_SCHEMES)),
                     option="plant_scheme", choices=PLANT_SCHEMES, integer=True),
            Variable("u", "input", "control input", shape=lambda p: (p.m,), signal="inputs",
                     text="input {}"),
            Variable("q", "input", "perturbation (through E)", shape=_perturbations,
                     signal="unknown_inputs", text="unknown input {} (through E)"),
            Variable("y", "output", "measured output C x + noise", shape=lambda p: (p.k,),
                     source="y", signal="outputs", text="measured {} (C x + noise)"),
            Variable("x", "output", "true state", shape=lambda p: (p.n,), signal="states",
                     text="true value of {}"),
            INPUT_BOUND,
        ),
        outputs=("y", "x"),
        family="plant", model=_plant_model, certificate=None, slave_module="plant",
    ),

)}
"""Every FMU kind, by name: the estimators in the order of the harness's tables, then
the plant."""

KIND_CODES = {name: number for number, name in enumerate(KINDS, start=1)}
"""FMU kind -> its code in the native FMUs' C sources (``FHOBS_KIND_<NAME>``): its place in
:data:`KINDS`, unique by construction."""
LABELS = {name: kind.label for name, kind in KINDS.items() if kind.label}
"""FMU kind -> the estimator's label in the harness's figures (the kinds that run an estimator
record)."""


def kinds_where(condition: Callable[[Kind], bool] = lambda kind: True, *,
                family: str | None = None, variable: str | None = None,
                estimator: bool | None = None) -> tuple[str, ...]:
    """The kinds of :data:`KINDS`, in order, that meet every condition given: ``condition``
    (of the :class:`Kind`), its ``family``, a ``variable`` it declares, whether it is an
    ``estimator`` (a kind with a label, not the plant).

    Examples
    --------
    >>> kinds_where(variable="psi0"), kinds_where(estimator=False)
    (('observer',), ('plant',))
    >>> kinds_where(lambda kind: kind.noise_free)
    ('prescribed_time',)
    """
    names = {v.name for kind in KINDS.values() for v in kind.variables}
    if variable is not None and variable not in names:
        raise KeyError(f"no kind declares a variable {variable!r}")
    return tuple(name for name, kind in KINDS.items()
                 if condition(kind)
                 and (family is None or kind.family == family)
                 and (variable is None or any(v.name == variable for v in kind.variables))
                 and (estimator is None or bool(kind.label) == estimator))


def _check_declaration() -> None:
    """Every kind's name a C identifier (its ``FHOBS_KIND_<NAME>``, its ``VR_<NAME>``s), its
    family one of :data:`FAMILIES`, its variables' names unique."""
    for name, kind in KINDS.items():
        if not name.isidentifier() or name != name.lower() or kind.family not in FAMILIES:
            raise ValueError(f"kind {name!r}: a lower-case identifier of a family of {FAMILIES}")
        counts = {v.name: [w.name for w in kind.variables].count(v.name) for v in kind.variables}
        if max(counts.values()) > 1:
            raise ValueError(f"kind {name!r} declares a variable twice: {counts}")


_check_declaration()
