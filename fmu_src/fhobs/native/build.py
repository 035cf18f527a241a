"""Build native FMUs: FMI 2.0 co-simulation FMUs of compiled C, no Python at run time.

Each native FMU (``observer.fmu``, ``luenberger.fmu``, ``plant.fmu``, ``kalman.fmu``,
``supervised.fmu``, ``prescribed_time.fmu``) has the interface of the pythonfmu FMU of the same kind
(:mod:`fhobs.build`): both are written from the kind's declaration
(:mod:`fhobs.fmu.kinds`), so they have the same variable names, value references,
causalities, variabilities and start values (exact: hexadecimal in the C data). Its binary
``binaries/linux64/<modelIdentifier>.so`` is the runtime's step kernel (``kernel.c``) with the
step planner (``planner.c``), an FMI layer (``fmi2_layer.c``), the C model of the kind's plan
family (``family_<family>.c``, :data:`FAMILIES`, with ``model_common.c``) and the generated
``model_data.h`` and ``model_data.c``: the design and what the planner needs that does not
depend on the step size (the injection flow's and the dilation's eigen data, the tau
grid, the gain level's round-off floor; :mod:`fhobs.native.planner`). Every positive finite
communication step is taken: the plan of a step size (ZOH matrices, the filtering observer's
gain-level floor and ceiling) is computed in C at its first use by the numpy runtime's
algorithms, to 1e-12 relative of the numpy runtime's plan, and kept per instance for the 8
step sizes used last. A step size the filtering observer cannot follow (no gain level
contracts) is refused with fmi2Error, as the numpy runtime refuses it. ``sources/`` holds
every C file and the FMI headers; each ``.c`` file is a translation unit of its own (C99, no
variable-length arrays), all listed in the modelDescription's ``<SourceFiles>``, so an
importer can compile the FMU for another platform (``cc -O2 -shared -fPIC -ffp-contract=off
-Isources -o <id>.so sources/*.c -lm``). The library exports the fmi2 functions only.

Design parameters (the plant matrices, the gains, nu, gamma, rho, Ts...) are compiled in: they
keep their names and value references, and writing a value bit-equal to the built one is
accepted (importers write start values), any other value is refused with fmi2Error. The
per-instance values (initial states, ``h``, ``scheme``, ``input_bound``, the plant's noise
amplitude and seed: the declaration's ``setting`` role) are parameters as in the pythonfmu
FMUs. The design is certified here, before anything is built; since it cannot change, the FMU
does not re-check it.

Examples
--------
>>> built = build_native_fmus(design, Path("build/native"))  # doctest: +SKIP
>>> sorted(built)                                          # doctest: +SKIP
['kalman', 'luenberger', 'observer', 'plant']
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import uuid
import xml.etree.ElementTree as ET
import zipfile
from collections import Counter
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..build import cache_copy
from ..core import kernel
from ..core.cache_files import cache_unusable, is_elf, trusted
from ..core.certificate import certify
from ..core.gains import ObserverDesign, PlantModel, SupervisedGains
from ..core.kalman_filter import KalmanObserver
from ..core.plant import LTIPlant
from ..core.runtime import FilteringObserver, PrescribedTimeObserver
from ..core.supervisor import HEAD_SIZE, SupervisedObserver, sample_count
from ..design.signals import SignalNames
from ..errors import BuildError
from ..fmu import call_rules
from ..fmu.kinds import KINDS, Kind
from ..fmu.options import default_kinds, fmu_options
from ..fmu.variables import element_names
from ..model_description import describe, naming_options
from . import fmi3, planner

HERE = Path(__file__).resolve().parent
C_ROLES = {"local": "LOCAL", "input": "INPUT", "output": "OUTPUT", "design": "COMPILED",
           "setting": "SETTABLE"}
"""The C role (``FHOBS_<ROLE>`` of fhobs_native.h) of each role of :mod:`fhobs.fmu.kinds`:
design parameters are compiled in, settings stay per-instance values."""
LAYOUT = tuple(dict.fromkeys(variable.name for kind in KINDS.values()
                             for variable in kind.variables if variable.role != "design"))
"""Variables whose first value reference model_data.h names (``VR_<NAME>``, -1 if absent):
every signal and setting of every kind (the C model reads them by these names)."""
C_SOURCES = ("fhobs_native.h", "planner.h", "planner.c", "gain_levels.c", "model.h",
             "model_common.h", "model_common.c", "instance.h", "instance.c", "fmi2_layer.c")
"""Sources of every native FMU from this folder (with the kernel's, :data:`KERNEL_SOURCES`,
the generated model_data.h, model_data.c and fhobs_call_rules.h, and the C model of the kind's
family, :attr:`Family.units`)."""
KERNEL_SOURCES = (kernel.SOURCE, kernel.HEADER)
"""The step kernel (``core/kernel.c``, ``core/kernel.h``), copied into every native FMU."""
NOISE_SOURCES = ("noise.c", "noise.h")
"""The plant's measurement noise (numpy's generator in C)."""
FILTER_PLANS = ("filter_plans.h", "filter_plans.c")
"""The filtering observer's split plans, of the filtering and supervised families."""
SHARED_UNITS = ("kernel.c", "planner.c", "gain_levels.c", "noise.c")
"""Translation units that do not include the generated model data: compiled once per machine
(:func:`cached_object`) and linked into the binary of every FMU that has them."""
GENERATED_HEADERS = ("model_data.h", "model.h", "model_common.h", "filter_plans.h")
"""The headers with the design of one FMU (the others include ``model_data.h``)."""
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
SUPERVISOR_THRESHOLDS = ("ceiling", "lower", "upper", "lower_return", "upper_return",
                         "dwell_time")
"""The supervised observer's fields compiled in as ``SUPERVISOR_<NAME>``, beside its model's
C, both statistics' S^-1, the weight and the time-varying recursion's matrices."""
SCRATCH_FIELDS = {"factors", "last_tau", "work", "cwork"}
"""Plan fields that point to per-instance scratch memory (set by each instance)."""
COMPILE_FLAGS = (*kernel.COMPILE_FLAGS, "-fvisibility=hidden", "-std=c99")
"""``-fvisibility=hidden`` only confirms what the sources say (kernel.h's FHOBS_HIDDEN): the
library exports the fmi2 functions alone either way."""
UNIT_FLAGS = {"fmi2_layer.c": ("-O1",), "fmi3_layer.c": ("-O1",)}
"""Flags added for one translation unit (after :data:`COMPILE_FLAGS`, so they win). The FMI
layer is compiled once per FMU kind and design (ten times in the main job's first run) and
holds argument checks and copies, no arithmetic a step repeats: at -O1 it compiles in 0.18 s
instead of 0.42 s, its results the same (no floating-point contraction either way)."""


def unit_flags(name: str) -> tuple[str, ...]:
    """The compiler flags of the translation unit ``name``: :data:`COMPILE_FLAGS` and its own
    (:data:`UNIT_FLAGS`).

    Examples
    --------
    >>> unit_flags("fmi2_layer.c")[-1], unit_flags("kernel.c") == COMPILE_FLAGS
    ('-O1', True)
    """
    return (*COMPILE_FLAGS, *UNIT_FLAGS.get(name, ()))


def build_native_fmus(
    design: ObserverDesign,
    out_dir: Path,
    *,
    steps: Iterable[float] | None = None,
    kinds: Iterable[str] | None = None,
    names: SignalNames | None = None,
    plant_name: str | None = None,
    fmi_version: int = 2,
    **options: Any,
) -> dict[str, Path]:
    """Build native FMUs into ``out_dir`` and return ``{kind: path}``.

    Parameters
    ----------
    design : ObserverDesign
        The design; certified here first.
    out_dir : Path
        Created if missing; the FMUs are written as ``<kind>.fmu``.
    steps : iterable of float, optional
        Communication step sizes checked at build time: the numpy runtime must be able to
        step each of them (the filtering observer: a contractive gain level), else
        :class:`BuildError`. The FMUs take every step size either way; this makes sure before
        they are shipped that those a user means to run are followed. Default: none.
    kinds : iterable of str, optional
        As for :func:`fhobs.build.build_fmus` (default: observer, luenberger, plant, kalman
        when the design has a Kalman filter, and prescribed_time when its correction has an
        eigen path, :attr:`~fhobs.core.runtime.PrescribedTimeObserver.eigen`).
    names, plant_name : optional
        The plant's signal names and name in the modelDescriptions, as for
        :func:`fhobs.build.build_fmus` (the same descriptions and units).
    fmi_version : int
        2 (default): FMI 2.0 co-simulation FMUs; 3: FMI 3.0 ones (:mod:`fhobs.native.fmi3`:
        the same model and results, array variables).
    **options
        Start values of the setting parameters, as for :func:`fhobs.fmu.options.fmu_options`
        (``h``, ``scheme``, ``z0``, ``psi0``, ``xi0``, ``x0``, ``noise_amplitude``,
        ``noise_seed``, ``plant_scheme``, ``input_bound``, ``T0``).

    Returns
    -------
    dict of str to Path

    Raises
    ------
    CertificateError
        Before anything else, if the design fails :func:`fhobs.core.certificate.certify`
        (every record's certificate, the checks its pythonfmu FMU makes at initialisation:
        the native FMUs compile the design in and do not check it again).
    BuildError
        Without a C compiler or the compiled kernel, for a design the native
        observer cannot run (no eigen path of its injection flow; the prescribed-time
        observer: of ``C L_pt``'s exponential or of the dilation), or for a step size of
        ``steps`` that the numpy runtime refuses.

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> design = paper_gains()
    >>> build_native_fmus(design, Path("out"), steps=[1e-3], kinds=["observer"])  # doctest: +SKIP
    {'observer': PosixPath('out/observer.fmu')}
    """
    certify(design)  # first: the native FMUs do not check their design again
    if fmi_version not in (2, 3):
        raise BuildError(f"fmi_version {fmi_version!r}: native FMUs are FMI 2.0 or 3.0 (2 or 3)")
    if kinds is None:
        kinds = tuple(kind for kind in default_kinds(design)
                      if FAMILIES[KINDS[kind].family].runs(KINDS[kind].runs(design)))
    kinds = tuple(kinds)
    unknown = sorted(set(kinds) - set(KINDS))
    if unknown:
        raise BuildError(f"no native FMU of kind {', '.join(unknown)}: native FMUs are built for "
                         f"{', '.join(KINDS)}")
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None or sys.platform != "linux" or kernel.library() is None:
        raise BuildError("native FMUs need Linux, a C compiler (cc or gcc) on PATH and the "
                         "compiled step kernel (FHOBS_NO_KERNEL unset)")
    steps = tuple(float(dt) for dt in (steps or ()))
    for dt in steps:
        if not (np.isfinite(dt) and dt > 0.0):
            raise BuildError(f"native step size {dt!r} is not a positive finite number")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    built = {}
    config = fmu_options(design, kinds, **options)
    naming = naming_options(design, names, plant_name)
    with tempfile.TemporaryDirectory(prefix="fhobs_native_") as tmp:
        stage = Path(tmp)
        staged = {}
        for kind in kinds:
            record, family = KINDS[kind].runs(design), FAMILIES[KINDS[kind].family]
            variables = _variables(KINDS[kind], design, config)
            data = family.data(kind, record, steps, config)
            data["norm1"] = _zoh_norm(record)
            staged[kind] = _stage(kind, variables, data, _sizes(kind, design.plant, data),
                                  stage / kind, naming, fmi_version)
        binaries = _compile_all(staged, stage / "shared", compiler)
        for kind, fmu in staged.items():
            built[kind] = _package(fmu, binaries[kind], out_dir / f"{kind}.fmu")
    return built


# -- the design data of the planner, per family ------------------------------------------------
def _stepped_data(kind: str, model: Any, steps: tuple[float, ...]) -> dict[str, Any]:
    """What the native FMU of a model with a split (or ZOH) step compiles in: the planner's
    design data (:func:`fhobs.native.planner.design_data`). Each step size of ``steps`` must
    have a plan in the numpy runtime (:class:`BuildError` otherwise)."""
    if not model.compiled:
        raise BuildError(f"the {kind}'s split step does not run in the compiled kernel for this "
                         "design (the injection flow has no eigen path): no native FMU")
    for dt in steps:
        try:
            captured_plan(model, dt)
        except ValueError as err:
            raise BuildError(f"--native-step {dt!r}: {err}") from err
    return planner.design_data(kind, model)


def _euler_plan(model: Any, h: float) -> dict[str, Any] | None:
    """The euler scheme's plan of ``model`` at h (None when it does not run in the kernel)."""
    return captured_plan(model, h) if model.compiled else None


def _filtering_data(kind: str, record: Any, steps: tuple[float, ...],
                    config: dict[str, Any]) -> dict[str, Any]:
    h = config["h"]
    return {**_stepped_data(kind, FilteringObserver(record, h=h), steps),
            "euler": _euler_plan(FilteringObserver(record, h=h, scheme="euler"), h)}


def _linear_data(kind: str, record: Any, steps: tuple[float, ...],
                 config: dict[str, Any]) -> dict[str, Any]:
    """The kind's runtime model (:attr:`fhobs.fmu.kinds.Kind.model`, a
    :class:`~fhobs.core.runtime.LuenbergerObserver` of the gain it runs) of each scheme."""
    def model(scheme: str) -> Any:
        options = {**config, "scheme": scheme}
        return KINDS[kind].model(record, lambda name: options[KINDS[kind].variable(name).option])

    return {**_stepped_data(kind, model("split"), steps),
            "euler": _euler_plan(model("euler"), config["h"])}


def _prescribed_time_data(kind: str, record: Any, steps: tuple[float, ...],
                          config: dict[str, Any]) -> dict[str, Any]:
    """Split only: the euler scheme's gain level needs the tau scan."""
    model = PrescribedTimeObserver(record, h=config["h"])
    if not model.eigen:
        raise BuildError(f"the {kind}'s split step does not run in the compiled kernel "
                         "for this design (C L_pt's exponential or the dilation of G_d has no "
                         "eigen path: ill-conditioned eigenvectors): no native FMU")
    return {**_stepped_data(kind, model, steps), "euler": None}


def _plant_data(kind: str, record: Any, steps: tuple[float, ...],
                config: dict[str, Any]) -> dict[str, Any]:
    model = LTIPlant(record.A, record.B, record.C, E=record.E)
    return {**_stepped_data(kind, model, steps),
            "A": model.A, "B": model.B, "C": model.C, "E": model.E}


def _kalman_data(kind: str, record: Any, steps: tuple[float, ...],
                 config: dict[str, Any]) -> dict[str, Any]:
    return {"kalman": captured_plan(KalmanObserver(record), 1.0),  # one cycle; doStep sets
            "Ts": float(record.sample_time)}                          # the count


def _zoh_norm(record: Any) -> float:
    """``||A||_1`` of the state matrix whose exact ZOH the FMU of ``record`` computes (the
    plant's A, an estimator's model matrix), for doStep's check of a step whose ZOH has no
    correct digit (:func:`fhobs.fmu.slave_base.zoh_problem`)."""
    matrix = record.A if isinstance(record, PlantModel) else record.model_matrices[0]
    return float(np.linalg.norm(matrix, 1))


def _supervised_data(kind: str, record: SupervisedGains, steps: tuple[float, ...],
                     config: dict[str, Any]) -> dict[str, Any]:
    """The supervised observer's data: its filtering observer's (:func:`_filtering_data`), its
    Kalman filter's one-cycle plan and Ts, and the statistics' and the handover's data from
    the numpy runtime's model (``supervisor``: C of the model, the Kalman filter's and the
    homogeneous statistic's S^-1, the weight, the thresholds, and for the time-varying
    recursion Phi, Gamma, R, Q_d, the steady-state and the handover covariances). Each step
    size of ``steps`` must also be a whole number of samples Ts (:class:`BuildError`
    otherwise)."""
    model = SupervisedObserver(record, h=config["h"])
    for dt in steps:
        try:
            sample_count(dt, model.sample_time)
        except ValueError as err:
            raise BuildError(f"--native-step {dt!r}: {err}") from err
    data = _filtering_data("observer", record.filtering, steps, config)
    data.update(kalman=captured_plan(model.kalman, 1.0), Ts=float(model.sample_time))
    data["supervisor"] = {
        "C": model._C, "S_inv": model._S_inv, "S_homogeneous_inv": model._S_homogeneous_inv,
        "weight": model._weight, "Phi": model._Phi, "Gamma": model._Gamma, "R": model._R,
        "Q_d": record.kalman.process_covariance, "P_steady": record.kalman.covariance,
        "P_handover": record.handover_covariance,
        **{name: float(getattr(record, name)) for name in SUPERVISOR_THRESHOLDS}}
    return data


def captured_plan(model: Any, dt: float) -> dict[str, Any]:
    """The fields of the kernel plan that ``model`` (a runtime model with a kernel stepper)
    registers for the step size dt: numbers as Python numbers, pointers as the arrays they
    point into (None for a NULL pointer).

    Raises
    ------
    ValueError
        If the runtime refuses the step size (as its step would).
    """
    plan, arrays = model._stepper.plan(dt)
    by_address = {array.ctypes.data: array for array in arrays}
    fields: dict[str, Any] = {}
    for name, ctype in plan._fields_:
        value = getattr(plan, name)
        if issubclass(ctype, ctypes._Pointer):
            address = ctypes.cast(value, ctypes.c_void_p).value
            fields[name] = None if address is None else by_address[address]
        else:
            fields[name] = value
    return fields


# -- the generated C data -----------------------------------------------------------------------
def c_number(value: float) -> str:
    """A double as a C literal that reads back exactly (hexadecimal, or INFINITY).

    Examples
    --------
    >>> c_number(0.1), c_number(float("inf"))
    ('0x1.999999999999ap-4', 'INFINITY')
    """
    value = float(value)
    if np.isinf(value):
        return "INFINITY" if value > 0 else "-INFINITY"
    if np.isnan(value):
        raise BuildError("a NaN in the data of a native FMU")
    return value.hex()


class _Arrays:
    """The constant arrays of model_data.c, each distinct one written once."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.types: dict[str, tuple[str, int]] = {}
        self._names: dict[tuple[str, bytes], str] = {}

    def name(self, array: np.ndarray) -> str:
        """The C name of ``array`` (a float64 or complex128 array), defined at first use."""
        array = np.ascontiguousarray(array)
        key = (array.dtype.str, array.tobytes())
        if key not in self._names:
            name = self._names[key] = f"DATA_{len(self._names)}"
            if np.iscomplexobj(array):
                items = [f"{{{c_number(v.real)}, {c_number(v.imag)}}}" for v in array.ravel()]
                ctype = "cplx"
            else:
                items = [c_number(v) for v in array.ravel()] or ["0.0"]
                ctype = "double"
            self.lines.append(f"static const {ctype} {name}[{max(array.size, 1)}] = "
                              f"{{{', '.join(items)}}};")
            self.types[name] = (ctype, max(array.size, 1))
        return self._names[key]


def _plan_initializer(plan: dict[str, Any], arrays: _Arrays) -> str:
    """A C designated initializer of a kernel plan (scratch pointers left NULL)."""
    items = []
    for field, value in plan.items():
        if field in SCRATCH_FIELDS or value is None:
            continue
        if isinstance(value, np.ndarray):
            items.append(f".{field} = {arrays.name(value)}")
        elif isinstance(value, int):
            items.append(f".{field} = {value}")
        else:
            items.append(f".{field} = {c_number(value)}")
    return "{" + ", ".join(items) + "}"


def _model_data(kind: str, variables: list[dict[str, Any]], data: dict[str, Any],
               sizes: dict[str, int]) -> tuple[str, str]:
    """The texts of model_data.h and model_data.c (without their comments and identity): sizes,
    value references, the variable table and the design data of the kind's family
    (:data:`FAMILIES`). The header has the ``#define``s and declares the named data, which
    the source defines (hidden: not exported by the FMU's library)."""
    arrays = _Arrays()
    first_vr = {}
    for var in variables:
        first_vr.setdefault(var["name"].split("[")[0], var["vr"])
    lines = [f"#define FHOBS_KIND_{other.upper()} {KINDS[other].code}" for other in KINDS]
    lines += [f"#define FHOBS_KIND FHOBS_KIND_{kind.upper()}",
             f"#define FHOBS_N_VARIABLES {len(variables)}"]
    lines += [f"#define FHOBS_{name.upper()} {value}" for name, value in sizes.items()]
    lines += [f"#define VR_{name.upper()} {first_vr.get(name, -1)}" for name in LAYOUT]
    lines += [f"#define FHOBS_MODEL_NORM1 {c_number(data['norm1'])}",
              f"#define FHOBS_MAX_STEP_INDEX {c_number(call_rules.MAX_STEP_INDEX)}"]
    lines += _state_outputs(kind, variables, first_vr)
    rows = [f'    {{"{var["name"]}", FHOBS_{var["type"].upper()}, FHOBS_{var["role"].upper()}, '
            f'{c_number(var["start"])}}},' for var in variables]
    table = ["static const FhobsVariable VARIABLES[FHOBS_N_VARIABLES] = {", *rows, "};"]
    body = [line for lines_of in FAMILIES[KINDS[kind].family].data_lines
            for line in lines_of(data, arrays)]
    return _split_data([*lines, "", *table, "", *arrays.lines, "", *body], arrays.types)


# -- the generated data of each family ------------------------------------------------------------
def _kalman_lines(data: dict[str, Any], arrays: _Arrays) -> list[str]:
    return [f"static const LinearPlan KALMAN_PLAN = {_plan_initializer(data['kalman'], arrays)};",
            f"static const double KALMAN_TS = {c_number(data['Ts'])};"]


def _supervisor_lines(data: dict[str, Any], arrays: _Arrays) -> list[str]:
    return [f"#define SUPERVISOR_{name.upper()} {arrays.name(value)}"
            if isinstance(value, np.ndarray) else
            f"static const double SUPERVISOR_{name.upper()} = {c_number(value)};"
            for name, value in data["supervisor"].items()]


def _zoh_lines(data: dict[str, Any], arrays: _Arrays) -> list[str]:
    scan = data.get("scan")
    return [f"#define FHOBS_ZOH_SIZE {data['top'].shape[1]}",
            f"#define FHOBS_N_TAU {0 if scan is None else scan['tau_grid'].size}",
            f"#define ZOH_TOP {arrays.name(data['top'])}"]


def _level_scan_line(data: dict[str, Any], arrays: _Arrays) -> str:
    fields = {**data["scan"], "n_tau": data["scan"]["tau_grid"].size}
    return f"static const LevelScan LEVEL_SCAN = {_plan_initializer(fields, arrays)};"


def _filter_lines(data: dict[str, Any], arrays: _Arrays) -> list[str]:
    return [f"static const FilterPlan FILTER_BASE = {_plan_initializer(data['base'], arrays)};",
            _level_scan_line(data, arrays)]


def _prescribed_lines(data: dict[str, Any], arrays: _Arrays) -> list[str]:
    return [f"static const PrescribedPlan PRESCRIBED_BASE = "
            f"{_plan_initializer(data['base'], arrays)};", _level_scan_line(data, arrays)]


def _linear_lines(data: dict[str, Any], arrays: _Arrays) -> list[str]:
    return [f"static const LinearPlan LINEAR_BASE = {_plan_initializer(data['base'], arrays)};",
            f"static const HeldInnovation HELD_INNOVATION = "
            f"{_plan_initializer(data['held'], arrays)};"]


def _euler_lines(data: dict[str, Any], arrays: _Arrays) -> list[str]:
    lines = [f"#define FHOBS_HAS_EULER {int(data['euler'] is not None)}"]
    if data["euler"] is not None:
        lines.append(f"static const EulerPlan EULER_PLAN = "
                     f"{_plan_initializer(data['euler'], arrays)};")
    return lines


def _plant_lines(data: dict[str, Any], arrays: _Arrays) -> list[str]:
    return [f"#define PLANT_{name} {arrays.name(data[name])}" for name in ("A", "B", "E", "C")]


_SCANNED_STEPS = (" A step size for which no gain level makes the split step contractive is "
                  "refused with fmi2Error (the log names the smallest spectral radius), the "
                  "state unchanged: use a smaller communication step.")


def _any_step(scanned: bool) -> Callable[[dict[str, Any]], str]:
    """The documentation's paragraph on the step sizes of a family with plans per step size
    (``scanned``: a gain level's floor and ceiling among them)."""
    def text(data: dict[str, Any]) -> str:
        return ("Any positive finite communication step, fixed or variable "
                "(canHandleVariableCommunicationStepSize). The plan of a step size (the "
                "exact zero-order-hold matrices" + (
                    ", the gain level's floor and ceiling from the scan of the dilated error "
                    "map's spectral radius" if scanned else "") +
                ") is computed at the first step of that size, by the algorithms of the numpy "
                "runtime (to 1e-12 relative of its plan), and kept for the 8 step sizes used "
                "last; a step size is matched exactly, so a host that forms t_k+1 - t_k gets "
                "the plan of the step it asked for." + (_SCANNED_STEPS if scanned else ""))
    return text


def _kalman_steps(data: dict[str, Any]) -> str:
    return (f"Any communication step: one filter cycle for every sample instant (a "
            f"multiple of Ts = {data['Ts']!r} from the start) inside the step, the "
            "estimate held between samples.")


def _supervised_steps(data: dict[str, Any]) -> str:
    return (f"Communication steps that are whole multiples of the Kalman filter's sample "
            f"time Ts = {data['Ts']!r} (within 1e-6 Ts; any other step is refused with "
            "fmi2Error, the state unchanged): the homogeneous observer's step, its plan "
            "computed at the first step of that size, and one Kalman cycle per sample, "
            "each adding one innovation to the statistic; the mode is decided once per "
            "step.")


@dataclass(frozen=True)
class Family:
    """How the native FMUs of a plan family (:data:`fhobs.fmu.kinds.FAMILIES`) are made.

    Attributes
    ----------
    data : callable
        ``data(kind, record, steps, options)``: what the FMU compiles in (``options``: the
        build options, :func:`fhobs.fmu.options.fmu_options`), from the numpy runtime's
        model of the ``record`` the kind runs (the planner's design data, the euler plan, the
        plant's matrices, the Kalman filter's cycle plan and Ts...); :class:`BuildError` for a
        step size of ``steps`` the numpy runtime refuses.
    data_lines : tuple of callable
        ``lines(data, arrays)``: the family's lines of model_data (its C model,
        ``family_<name>.c``, reads them by name), in this order.
    state_size : callable
        ``state_size(n_model, plant)``: the length of the state the C model keeps.
    n_model : callable
        ``n_model(data)``: the states of the model the plan steps.
    steps : callable
        ``steps(data)``: the documentation's paragraph on the step sizes the FMU takes.
    units : tuple of str
        The family's C model: its files of this folder (``family_<name>.c``, behind
        ``model.h``, and the units it calls), added to :data:`C_SOURCES`.
    runs : callable
        ``runs(record)``: whether a native FMU of the record is built by default (the
        prescribed-time observer's: when its correction has an eigen path).
    """

    data: Callable[[str, Any, tuple[float, ...], dict[str, Any]], dict[str, Any]]
    data_lines: tuple[Callable[[dict[str, Any], _Arrays], list[str]], ...]
    state_size: Callable[[int, PlantModel], int]
    steps: Callable[[dict[str, Any]], str]
    units: tuple[str, ...]
    n_model: Callable[[dict[str, Any]], int] = lambda data: data["top"].shape[0]
    runs: Callable[[Any], bool] = lambda record: True


FAMILIES: dict[str, Family] = {
    "filtering": Family(_filtering_data, (_zoh_lines, _filter_lines, _euler_lines),
                        lambda n_model, plant: n_model + plant.k + 1, _any_step(True),
                        FILTER_PLANS + ("family_filtering.c",)),
    "prescribed_time": Family(_prescribed_time_data,
                              (_zoh_lines, _prescribed_lines, _euler_lines),
                              lambda n_model, plant: n_model + 2, _any_step(True),
                              ("family_prescribed_time.c",),
                              runs=lambda record: PrescribedTimeObserver(record).eigen),
    "linear": Family(_linear_data, (_zoh_lines, _linear_lines, _euler_lines),
                     lambda n_model, plant: n_model, _any_step(False), ("family_linear.c",)),
    "kalman": Family(_kalman_data, (_kalman_lines,), lambda n_model, plant: n_model + 1,
                     _kalman_steps, ("family_kalman.c",), lambda data: data["kalman"]["n"]),
    "supervised": Family(_supervised_data, (_kalman_lines, _supervisor_lines, _zoh_lines,
                                            _filter_lines, _euler_lines),
                         lambda n_model, plant: HEAD_SIZE + (n_model + plant.k + 1)
                         + (n_model + 1) + n_model * n_model + 1, _supervised_steps,
                         FILTER_PLANS + ("family_supervised.c",)),
    "plant": Family(_plant_data, (_zoh_lines, _plant_lines), lambda n_model, plant: plant.n + 1,
                    _any_step(False), ("family_plant.c", *NOISE_SOURCES)),
}
"""Plan family -> how its native FMUs are made; the C model of each is ``family_<name>.c``."""


def _state_outputs(kind: str, variables: list[dict[str, Any]],
                   first_vr: dict[str, int]) -> list[str]:
    """The outputs that are elements of the model's state, as the declaration places them
    (:meth:`fhobs.fmu.kinds.Kind.output_sources`): ``STATE_OUTPUTS``, (value reference, state
    offset, count) triples, which model_common.c copies; the other outputs it computes by name."""
    sizes = Counter(var["name"].split("[")[0] for var in variables
                    if var["causality"] == "output")
    triples = [(first_vr[name], offset, size) for name, source, offset, size
               in KINDS[kind].output_sources(sizes) if source == "state"]
    flat = ", ".join(str(value) for triple in triples for value in triple)
    return [f"#define FHOBS_N_STATE_OUTPUTS {len(triples)}",
            f"static const int STATE_OUTPUTS[{3 * len(triples)}] = {{{flat}}};"]


def _split_data(lines: list[str], types: dict[str, tuple[str, int]]) -> tuple[str, str]:
    """model_data.h and model_data.c of the generated lines: ``#define``s to the header, named
    constants (``static const T NAME = ...;``) defined in the source and declared in the
    header, a ``#define NAME DATA_i`` of an array as a named pointer to it."""
    header, source = [], []
    for line in lines:
        array = re.fullmatch(r"#define (\w+) (DATA_\d+)", line)
        named = re.match(r"static const (\w+) (\w+)(\[\w*\])? = ", line)
        if array:
            ctype = types[array.group(2)][0]
            header.append(f"FHOBS_HIDDEN extern const {ctype} *const {array.group(1)};")
            source.append(f"const {ctype} *const {array.group(1)} = {array.group(2)};")
        elif line.startswith("#define"):
            header.append(line)
        elif named and not named.group(2).startswith("DATA_"):
            header.append(f"FHOBS_HIDDEN extern const {named.group(1)} {named.group(2)}"
                          f"{named.group(3) or ''};")
            source.append(line[len("static "):])
        else:
            source.append(line)
    return "\n".join(header) + "\n", "\n".join(source).strip("\n") + "\n"


# -- one FMU ------------------------------------------------------------------------------------
def _variables(kind: Kind, design: ObserverDesign,
               options: dict[str, Any]) -> list[dict[str, Any]]:
    """Every scalar variable of the FMU of ``kind`` for ``design`` and the build ``options``,
    in value-reference order (:meth:`fhobs.fmu.kinds.Kind.starts`): name, value reference,
    type, C role, causality, the FMI attributes of its causality (:func:`_fmi_attributes`),
    description and exact start value (of an output: the model's output at its initial state,
    :func:`_start_outputs`)."""
    variables = []
    outputs = _start_outputs(kind, design, options)
    for variable, start in kind.starts(kind.runs(design), options):
        start = outputs.get(variable.name, start)
        values = np.asarray(start, dtype=float)
        causality = variable.role if variable.role in ("local", "input", "output") else (
            "parameter")
        for name, value in zip(element_names(variable.name, values.shape), values.flat,
                               strict=True):
            variables.append({"name": name, "vr": len(variables),
                              "type": "integer" if variable.integer else "real",
                              "role": C_ROLES[variable.role], "causality": causality,
                              "attributes": _fmi_attributes(causality),
                              "description": variable.description,
                              "start": int(value) if variable.integer else float(value)})
    return variables


def _fmi_attributes(causality: str) -> dict[str, str]:
    """A native FMU variable's attributes in either FMI version's modelDescription: its
    causality, its variability (states discrete, signals continuous, parameters fixed: compiled
    in or set before the initialisation) and, of a state or an output, ``initial="exact"``."""
    attributes = {"causality": causality,
                  "variability": {"local": "discrete", "input": "continuous",
                                  "output": "continuous"}.get(causality, "fixed")}
    if causality in ("local", "output"):
        attributes["initial"] = "exact"
    return attributes


def _start_outputs(kind: Kind, design: ObserverDesign,
                   options: dict[str, Any]) -> dict[str, np.ndarray]:
    """The start values of the outputs: what the pythonfmu FMU of ``kind`` publishes when it
    is instantiated, the kind's runtime model's outputs at its initial state
    (:meth:`fhobs.fmu.kinds.Kind.initial_outputs`) from the build ``options``."""
    def setting(name: str) -> Any:
        return options[kind.variable(name).option]

    return kind.initial_outputs(kind.runs(design), setting)


def _sizes(kind: str, plant: PlantModel, data: dict[str, Any]) -> dict[str, int]:
    """The sizes model_data.c defines (``FHOBS_<NAME>``): the plant's states n, the model's
    states (the plan's n), outputs k, inputs m, perturbations r, the state kept (its
    family's, :class:`Family`)."""
    family = FAMILIES[KINDS[kind].family]
    n_model = family.n_model(data)
    r = 0 if plant.E is None else plant.E.shape[1]
    return {"n": plant.n, "n_model": n_model, "k": plant.k, "m": plant.m, "r": r,
            "state_size": family.state_size(n_model, plant)}


@dataclass(frozen=True)
class _Staged:
    """The files of one native FMU before its binary: the folder ``root`` (sources/,
    modelDescription.xml, documentation/), its identity and the C files to compile."""

    root: Path
    identifier: str
    files: tuple[str, ...]
    platform: str = "linux64"

    @property
    def sources(self) -> Path:
        return self.root / "sources"


def _stage(kind: str, variables: list[dict[str, Any]], native: dict[str, Any],
           sizes: dict[str, int], stage: Path, naming: dict[str, Any],
           fmi_version: int = 2) -> _Staged:
    """Generate the sources of one native FMU, its modelDescription (its signals named by
    ``naming``, :func:`fhobs.model_description.naming_options`, part of its GUID) and
    documentation into ``stage/fmu``; of FMI 3.0 (``fmi_version`` 3) with the layer and the
    descriptions of :mod:`fhobs.native.fmi3`."""
    header, data = _model_data(kind, variables, native, sizes)
    units = FAMILIES[KINDS[kind].family].units
    sources = {name: (HERE / name).read_text() for name in (*C_SOURCES, *units)}
    if fmi_version == 3:
        del sources["fmi2_layer.c"]
        sources.update(fmi3.layer_sources(variables))
    sources.update({path.name: path.read_text() for path in KERNEL_SOURCES})
    sources[call_rules.HEADER] = call_rules.c_header()
    digest = hashlib.sha256(header.encode() + data.encode())
    digest.update(json.dumps(naming, sort_keys=True).encode())
    for name in sorted(sources):
        digest.update(name.encode() + sources[name].encode())
    guid = str(uuid.UUID(bytes=digest.digest()[:16]))
    identifier = f"fhobs_{kind}_{digest.hexdigest()[:12]}"
    sources["model_data.h"] = (
        f"/* Generated by fhobs.native.build for a {kind} FMU: its sizes, value references and\n"
        " * the declarations of its design data (model_data.c). Do not edit (rebuild with\n"
        " * build_fmu.py --native). */\n"
        "#ifndef FHOBS_MODEL_DATA_H\n#define FHOBS_MODEL_DATA_H\n\n"
        '#include "fhobs_native.h"\n#include "kernel.h"\n#include "planner.h"\n\n'
        f'#define FHOBS_IDENTITY "{guid}"\n' + header + "\n#endif\n")
    sources["model_data.c"] = (
        f"/* Generated by fhobs.native.build for a {kind} FMU: its design data and what its\n"
        " * step planner needs, from the numpy runtime, doubles in hexadecimal (exact). Do not\n"
        " * edit (rebuild with build_fmu.py --native). */\n"
        '#include <math.h>\n\n#include "model_data.h"\n\n' + data)
    root = stage / "fmu"
    (root / "sources").mkdir(parents=True)
    for name, text in sources.items():
        (root / "sources" / name).write_text(text)
    for name in FMI_HEADERS if fmi_version == 2 else fmi3.FMI_HEADERS:
        shutil.copy(_fmi_headers() / name, root / "sources" / name)
    files = tuple(sorted(name for name in sources if name.endswith(".c")))
    documentation = _documentation(kind, variables, native)
    if fmi_version == 3:
        tree = fmi3.model_description(KINDS[kind], variables, identifier, guid, naming)
        fmi3.build_description(identifier, files).write(
            root / "sources" / "buildDescription.xml", encoding="UTF-8", xml_declaration=True)
        documentation = fmi3.documentation(documentation)
    else:
        tree = _model_description(KINDS[kind], variables, identifier, guid, list(files))
        describe(tree.getroot(), KINDS[kind], naming["signals"], naming["plant_name"])
    ET.indent(tree, "\t")
    tree.write(root / "modelDescription.xml", encoding="UTF-8", xml_declaration=True)
    (root / "documentation").mkdir()
    (root / "documentation" / "index.html").write_text(documentation)
    return _Staged(root, identifier, files, "linux64" if fmi_version == 2 else fmi3.BINARY_FOLDER)


def _compile_all(staged: dict[str, _Staged], shared: Path, compiler: str) -> dict[str, Path]:
    """Compile every staged FMU's binary, ``{kind: path}``: each translation unit through the
    object cache (:func:`cached_object`: those of :data:`SHARED_UNITS` once per machine, the
    others once per design), as many compilers at a time as there are cores; then link each
    binary."""
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        common = {}
        for fmu in staged.values():
            for name in fmu.files:
                if name in SHARED_UNITS and name not in common:
                    common[name] = pool.submit(cached_object, fmu.sources, name, shared,
                                               compiler)
        own = {kind: [pool.submit(cached_object, fmu.sources, name, fmu.root / "objects",
                                  compiler)
                      for name in fmu.files if name not in SHARED_UNITS]
               for kind, fmu in staged.items()}
        binaries = {}
        for kind, fmu in staged.items():
            objects = [job.result() for job in own[kind]]
            objects += [common[name].result() for name in fmu.files if name in SHARED_UNITS]
            binaries[kind] = fmu.root / "binaries" / fmu.platform / f"{fmu.identifier}.so"
            link_binary(objects, binaries[kind], compiler)
    return binaries


def _package(fmu: _Staged, binary: Path, dest: Path) -> Path:
    """Zip the staged FMU with its ``binary`` (already in place) into ``dest``; the object
    files stay out."""
    dest.unlink(missing_ok=True)
    with zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as archive:
        for path in sorted(fmu.root.rglob("*")):
            relative = path.relative_to(fmu.root).as_posix()
            if path.is_file() and not relative.startswith("objects/"):
                archive.write(path, relative)
    return dest


def _fmi_headers() -> Path:
    """The FMI 2.0 headers (fmpy's copy)."""
    import fmpy

    return Path(fmpy.__file__).parent / "c-code"


def compile_binary(sources: Path, target: Path, compiler: str,
                   files: Iterable[str] = ("fhobs_fmu.c",)) -> None:
    """Compile the C files ``files`` of the folder ``sources`` (translation units linked
    together) into the shared library ``target``. The default is the one generated unit of a
    native harness block (:mod:`harness.blocks.native`).

    Raises
    ------
    BuildError
        If the compiler fails.

    Examples
    --------
    >>> compile_binary(Path("sources"), Path("binaries/linux64/id.so"), "cc",
    ...                ["kernel.c", "model_common.c"])  # doctest: +SKIP
    """
    objects = target.parent / "objects"
    link_binary([compile_object(sources, name, objects, compiler) for name in files], target,
                compiler)
    shutil.rmtree(objects)


def compile_object(sources: Path, name: str, out: Path, compiler: str) -> Path:
    """Compile the translation unit ``name`` of the folder ``sources`` into ``out/<stem>.o``
    (position-independent, :func:`unit_flags`) and return its path.

    Raises
    ------
    BuildError
        If the compiler fails (its messages quoted).
    """
    out.mkdir(parents=True, exist_ok=True)
    target = out / f"{Path(name).stem}.o"
    _run_compiler([compiler, *unit_flags(name), f"-I{sources}", "-c", "-o", str(target),
                   str(sources / name)])
    return target


def cached_object(sources: Path, name: str, out: Path, compiler: str) -> Path:
    """The object file of the translation unit ``name`` of ``sources`` from the user's cache
    (:func:`fhobs.core.kernel.cache_dir`), compiled there first if it is not yet: its name
    hashes the unit, the headers of ``sources`` it may include, the flags and the compiler. A
    unit that includes no generated header (:data:`SHARED_UNITS`) is hashed without them, so
    one object serves every design; the others with them, so that rebuilding an unchanged
    design compiles nothing. Into ``out`` (:func:`compile_object`) when the cache cannot be
    written.

    Raises
    ------
    BuildError
        If the compiler fails (its messages quoted).
    """
    text = (sources / name).read_text()
    generated = any(f'"{header}"' in text for header in GENERATED_HEADERS)
    if name in SHARED_UNITS and generated:
        raise BuildError(f"{name} includes the generated model data: it cannot be shared")
    digest = hashlib.sha256(" ".join((compiler, *unit_flags(name))).encode())
    for path in (sources / name, *sorted(sources.glob("*.h"))):
        if generated or path.name not in GENERATED_HEADERS:
            digest.update(path.name.encode() + path.read_bytes())
    try:
        cache = kernel.cache_dir() / "objects"
        cache.mkdir(mode=0o700, exist_ok=True)
    except OSError:
        return compile_object(sources, name, out, compiler)
    target = cache / f"{Path(name).stem}_{digest.hexdigest()[:16]}.o"
    if trusted(target, is_elf):
        return target
    compiled = compile_object(sources, name, out, compiler)
    try:
        cache_copy(compiled, target)
    except OSError as err:
        cache_unusable(cache, err)
        return compiled
    return target


def link_binary(objects: Iterable[Path], target: Path, compiler: str) -> None:
    """Link ``objects`` into the shared library ``target`` (with libm).

    Raises
    ------
    BuildError
        If the linker fails.
    """
    target.parent.mkdir(parents=True, exist_ok=True)
    _run_compiler([compiler, *COMPILE_FLAGS, "-o", str(target), *map(str, objects), "-lm"])


def _run_compiler(command: list[str]) -> None:
    result = subprocess.run(command, capture_output=True, text=True, check=False, timeout=300)
    if result.returncode != 0:
        raise BuildError(f"compiling the native FMU failed:\n{result.stderr}")


LOG_CATEGORIES = ("logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal",
                  "logAll")
"""The log categories the modelDescription lists (those of the pythonfmu FMUs)."""
CAPABILITIES = (("needsExecutionTool", "false"),
                ("canHandleVariableCommunicationStepSize", "true"),
                ("canInterpolateInputs", "false"),
                ("canBeInstantiatedOnlyOncePerProcess", "false"),
                ("canNotUseMemoryManagementFunctions", "false"),
                ("canGetAndSetFMUstate", "true"), ("canSerializeFMUstate", "true"),
                ("providesDirectionalDerivative", "false"))


def _model_description(kind: Kind, variables: list[dict[str, Any]], identifier: str,
                       guid: str, compiled_files: list[str]) -> ET.ElementTree:
    """The modelDescription of the native FMU of ``kind``: its identity, capabilities, source
    files and variables (exact start values; every output depends on no input)."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": identifier, "guid": guid,
        "generationTool": "fhobs.native.build (compiled C, no Python at run time)",
        "variableNamingConvention": "structured",
        "description": f"{kind.description} -- native FMU", "author": "fhobs", "license": "MIT"})
    cosim = ET.SubElement(root, "CoSimulation", {"modelIdentifier": identifier,
                                                 **dict(CAPABILITIES)})
    files = ET.SubElement(cosim, "SourceFiles")
    for name in compiled_files:
        ET.SubElement(files, "File", name=name)
    categories = ET.SubElement(root, "LogCategories")
    for name in LOG_CATEGORIES:
        ET.SubElement(categories, "Category", name=name)
    model_variables = ET.SubElement(root, "ModelVariables")
    for var in variables:
        attributes = {"name": var["name"], "valueReference": str(var["vr"]),
                      "description": var["description"], **var["attributes"]}
        element = ET.SubElement(model_variables, "ScalarVariable", attributes)
        if var["type"] == "real":
            ET.SubElement(element, "Real", start=repr(var["start"]))
        else:
            ET.SubElement(element, "Integer", start=str(var["start"]))
    outputs = ET.SubElement(ET.SubElement(root, "ModelStructure"), "Outputs")
    for var in variables:
        if var["causality"] == "output":
            ET.SubElement(outputs, "Unknown", index=str(var["vr"] + 1), dependencies="")
    tree = ET.ElementTree(root)
    ET.indent(tree, "\t")
    return tree


def _documentation(kind: str, variables: list[dict[str, Any]], data: dict[str, Any]) -> str:
    """documentation/index.html: what the FMU runs, its step sizes and its parameters."""
    compiled = sorted({v["name"].split("[")[0] for v in variables if v["role"] == "COMPILED"})
    settable = sorted({v["name"].split("[")[0] for v in variables if v["role"] == "SETTABLE"})
    steps = FAMILIES[KINDS[kind].family].steps(data)
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>fhobs native {kind} FMU</title></head><body>
<h1>fhobs native {kind} FMU</h1>
<p>FMI 2.0 co-simulation FMU of compiled C (the fhobs step kernel, its step planner and an
FMI layer); no Python
is needed to run it. It has the interface of the pythonfmu {kind}.fmu built from the same
design (names, value references, causalities, start values).</p>
<p>{steps}</p>
<p>Parameters compiled in (writing their built value is accepted, any other value is refused
with fmi2Error: rebuild with <code>python build_fmu.py SPEC --native</code> to change them):
{", ".join(compiled) or "none"}.</p>
<p>Per-instance parameters (settable until fmi2ExitInitializationMode): {", ".join(settable)}.</p>
<p>The design was certified when the FMU was built; it cannot change, so it is not checked
again at run time. Caller mistakes (unknown value references, wrong types, non-finite or
too large inputs, calls out of sequence, foreign FMU states) are answered with fmi2Error and a
log message, the instance unchanged.</p>
<p>sources/ holds every C file (C99, each a translation unit of its own) and the FMI
headers; the modelDescription lists the files to compile (SourceFiles), e.g. <code>cc -O2
-shared -fPIC -ffp-contract=off -Isources -o binaries/linux64/&lt;modelIdentifier&gt;.so
sources/*.c -lm</code>.</p>
</body></html>
"""
