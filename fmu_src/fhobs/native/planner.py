"""The native FMUs' step planner (``planner.c``): its design data and a ctypes entry to it.

A native FMU computes the plan of a communication step size in C at the first step of that
size (``planner.c``, ``gain_levels.c``): the ZOH matrices, and for the filtering observer the
gain-level floor and ceiling of the tau scan. What the planner needs that does not depend on
the step size is taken here from the numpy runtime's models and compiled into the FMU
(:mod:`fhobs.native.build`): :func:`design_data`. :func:`c_plan` runs the same C planner
through ctypes (``planner_api.c`` compiled with ``kernel.c``, ``planner.c`` and
``gain_levels.c``), so the tests compare its plans with the numpy runtime's
(``kernel.Stepper.plan``).

Examples
--------
>>> from fhobs.design.observer import paper_gains
>>> from fhobs.core.runtime import FilteringObserver
>>> observer = FilteringObserver(paper_gains().filtering)
>>> sorted(c_plan("observer", observer, 1e-3))  # doctest: +SKIP
['F', 'M', 'ceiling', 'floor_level']
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core import kernel
from ..core.dilation import Dilation
from ..core.linalg import PHI1_SERIES
from ..core.runtime import (
    BIN_CACHE_SIZE,
    CONTRACTION_LIMIT,
    HELD_INNOVATION_LIMIT,
    LEVEL_MISMATCH,
    RADIUS_TIE,
    TAU_GRID,
    PlanCacheInfo,
)
from ..fmu.kinds import KINDS

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "planner.c"
LEVELS_SOURCE = HERE / "gain_levels.c"
API_SOURCE = HERE / "planner_api.c"
HEADERS = (kernel.HEADER, HERE / "planner.h")
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)


class LevelScan(ctypes.Structure):
    """``LevelScan`` of planner.c (complex arrays as interleaved doubles)."""

    _fields_ = [("tau_grid", _DOUBLE_P), ("n_tau", ctypes.c_int), ("Vg_inv", _DOUBLE_P),
                ("roundoff", ctypes.c_double), ("contraction", ctypes.c_double),
                ("tie", ctypes.c_double), ("trusted_low", ctypes.c_double),
                ("trusted_high", ctypes.c_double)]


class HeldInnovation(ctypes.Structure):
    """``HeldInnovation`` of planner.h."""

    _fields_ = [("held_top", _DOUBLE_P), ("C", _DOUBLE_P), ("limit", ctypes.c_double)]


class BinScans:
    """The C planner's cache of the tau scans per bin of step sizes (``BinCache`` of
    planner.h), as a native FMU instance keeps it: pass one to :func:`c_plan` for a sequence
    of step sizes.

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> from fhobs.core.runtime import FilteringObserver
    >>> observer, bins = FilteringObserver(paper_gains().filtering), BinScans()
    >>> for dt in (1.00e-3, 1.01e-3):  # doctest: +SKIP
    ...     _ = c_plan("observer", observer, dt, bins)
    >>> bins.info()  # doctest: +SKIP
    PlanCacheInfo(scans=1, bins=1, max_bins=64)
    """

    def __init__(self) -> None:
        lib = library()
        if lib is None:
            raise RuntimeError("the planner library needs a C compiler (cc or gcc)")
        self._lib = lib
        self._buffer = np.zeros(lib.fhobs_bin_cache_bytes(), dtype=np.uint8)
        lib.fhobs_bin_cache_init(self.pointer)

    @property
    def pointer(self) -> ctypes.c_void_p:
        """The address of the C structure."""
        return ctypes.c_void_p(self._buffer.ctypes.data)

    def info(self) -> PlanCacheInfo:
        """The tau scans made so far and the bins kept, as the numpy runtime's
        :meth:`~fhobs.core.runtime.FilteringObserver.plan_cache_info`."""
        scans = ctypes.c_longlong()
        kept = self._lib.fhobs_bin_cache_info(self.pointer, ctypes.byref(scans))
        return PlanCacheInfo(scans.value, kept, BIN_CACHE_SIZE)


def design_data(kind: str, model: Any) -> dict[str, Any]:
    """What the planner of ``kind`` needs beyond the step size, from a runtime model of it:
    its family's (:data:`fhobs.fmu.kinds.FAMILIES`, :data:`DESIGN_DATA`).

    Parameters
    ----------
    kind : str
        A kind of the ``filtering`` family (a
        :class:`~fhobs.core.runtime.FilteringObserver`), ``linear`` (a
        :class:`~fhobs.core.runtime.LuenbergerObserver`), ``prescribed_time`` (a
        :class:`~fhobs.core.runtime.PrescribedTimeObserver`) or ``plant`` (an
        :class:`~fhobs.core.plant.LTIPlant`).
    model : object
        The model, split (or zoh) scheme.

    Returns
    -------
    dict
        ``top``: the first rows ``[A, B, L_inj]`` (plant: ``[A, B, E]``; Luenberger: its
        closed loop's ``[A + L_lin C, -L_lin, B]``) of the ZOH's augmented matrix; observer
        and prescribed_time: ``base`` (the plan's fields that do not depend on the step size,
        as the model's ``_kernel_plan`` sets them) and ``scan`` (the :class:`LevelScan`
        fields); Luenberger: ``base`` (``LinearPlan`` fields) and ``held`` (the
        :class:`HeldInnovation` fields: ``[A, B, L_lin]``, C and the limit).

    Examples
    --------
    >>> from fhobs.design.observer import paper_gains
    >>> from fhobs.core.runtime import PrescribedTimeObserver
    >>> data = design_data("prescribed_time", PrescribedTimeObserver(paper_gains().prescribed_time))
    >>> sorted(data), data["top"].shape
    (['base', 'scan', 'top'], (4, 7))
    """
    return DESIGN_DATA[KINDS[kind].family](model)


def _plant_data(model: Any) -> dict[str, Any]:
    return {"top": np.hstack((model.A, model.B, model.E))}


def _linear_data(model: Any) -> dict[str, Any]:
    n, k, m = model._z.size, model._k, model._m
    held = {"held_top": np.hstack((model._A, model._B, model._L_inj)),
            "C": np.ascontiguousarray(model._C, dtype=float),
            "limit": HELD_INNOVATION_LIMIT}
    return {"top": model.zoh_top, "base": {"n": n, "k": k, "m": m, "cycles": 1},
            "held": held}


def _level_scan(model: Any) -> dict[str, Any]:
    """The :class:`LevelScan` fields of a model with a gain level (filtering,
    prescribed-time)."""
    dilation = Dilation(model.gains.model.G_d)
    trusted_low, trusted_high = model._scaling_band()
    return {"tau_grid": np.ascontiguousarray(TAU_GRID, dtype=float),
            "Vg_inv": np.ascontiguousarray(dilation.inverse_right, dtype=complex),
            "roundoff": float(model._amplification_level()),
            "contraction": CONTRACTION_LIMIT, "tie": RADIUS_TIE, "trusted_low": trusted_low,
            "trusted_high": trusted_high}


def _prescribed_time_data(model: Any) -> dict[str, Any]:
    n, k, m = model._z.size, model._k, model._m
    data = model.kernel_arrays()
    base = {"n": n, "k": k, "m": m, "real_lam": data["real_lam"],
            "nu": float(model.gains.model.nu), "rho": float(model.gains.rho),
            "tiny": data["tiny"], "series": PHI1_SERIES,
            "C": np.ascontiguousarray(model._C, dtype=float),
            **{name: data[name] for name in ("Q_inv", "Q_V", "lam", "V_g", "g", "inverse_L")}}
    return {"top": np.hstack((model._A, model._B, model._L_inj)), "base": base,
            "scan": _level_scan(model)}


def _filtering_data(model: Any) -> dict[str, Any]:
    n, k, m = model._z.size, model._k, model._m
    flow = model._flow.kernel_arrays()
    base = {"n": n, "k": k, "m": m, "real_lam": int(flow["real_lam"]),
            "nu": float(model.gains.model.nu), "gamma": float(model.gains.gamma),
            "p": model._p, "mismatch": LEVEL_MISMATCH, "tiny": flow["tiny"],
            "series": PHI1_SERIES, "C": np.ascontiguousarray(model._C, dtype=float),
            **{name: flow[name] for name in ("V_inv", "V_k", "WL", "V_g", "g", "lam")}}
    return {"top": np.hstack((model._A, model._B, model._L_inj)), "base": base,
            "scan": _level_scan(model)}


DESIGN_DATA: dict[str, Callable[[Any], dict[str, Any]]] = {
    "filtering": _filtering_data, "supervised": _filtering_data,
    "prescribed_time": _prescribed_time_data, "linear": _linear_data, "plant": _plant_data}
"""Plan family -> its planner's design data from a runtime model (the supervised family's:
of its filtering observer; the Kalman filter's plan does not depend on the step size)."""


@functools.cache
def library() -> ctypes.CDLL | None:
    """The planner compiled for the tests (cached as the kernel is), or None without a C
    compiler."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        return None
    sources = (kernel.SOURCE, SOURCE, LEVELS_SOURCE, API_SOURCE)
    flags = (*kernel.COMPILE_FLAGS, f"-I{kernel.SOURCE.parent}", f"-I{HERE}")
    tag = hashlib.sha256(b"".join(path.read_bytes() for path in (*sources, *HEADERS))
                         + " ".join(flags[:4]).encode() + compiler.encode()).hexdigest()
    target = kernel.cache_dir() / f"fhobs_planner_{tag[:16]}.so"
    if not target.exists():
        try:
            kernel.compile_source(sources, target, compiler, flags, ("-lm",))
        except (OSError, subprocess.SubprocessError):
            return None
    lib = ctypes.CDLL(str(target))
    lib.fhobs_plan_work_size.restype = ctypes.c_int
    lib.fhobs_plan_filter.restype = ctypes.c_int
    lib.fhobs_plan_prescribed.restype = ctypes.c_int
    lib.fhobs_plan_zoh.restype = None
    lib.fhobs_plan_luenberger.restype = ctypes.c_double
    lib.fhobs_bin_cache_bytes.restype = ctypes.c_int
    lib.fhobs_bin_cache_init.restype = None
    lib.fhobs_bin_cache_info.restype = ctypes.c_int
    return lib


def _structure(cls: type[ctypes.Structure], fields: dict[str, Any],
               keep: list[np.ndarray]) -> ctypes.Structure:
    """A ctypes structure of ``fields`` (arrays as pointers, kept alive in ``keep``)."""
    values = {}
    for name, value in fields.items():
        if isinstance(value, np.ndarray):
            array = np.ascontiguousarray(value)
            keep.append(array)
            values[name] = kernel.pointer(array)
        else:
            values[name] = value
    return cls(**values)


def c_plan(kind: str, model: Any, dt: float, bins: BinScans | None = None) -> dict[str, Any]:
    """The C planner's plan of ``kind`` for the step size dt, as the native FMU makes it
    (the filtering and prescribed-time families: with the tau scans of ``bins``, which it
    updates; None: a fresh cache), by its family (:data:`C_PLANS`).

    Returns
    -------
    dict
        filtering, prescribed_time: ``M``, ``F``, ``floor_level``, ``ceiling``; linear:
        ``M`` and ``radius`` (of the held innovation's error map, which chose M); plant:
        ``Phi``, ``Gamma_B``, ``Gamma_E``.

    Raises
    ------
    ValueError
        If the observer cannot follow dt (the numpy runtime's refusal), the smallest spectral
        radius of the tau scan named.
    RuntimeError
        Without a C compiler.
    """
    lib = library()
    if lib is None:
        raise RuntimeError("the planner library needs a C compiler (cc or gcc)")
    data = design_data(kind, model)
    top = np.ascontiguousarray(data["top"], dtype=float)
    n, size = top.shape
    k = data["base"]["k"] if "base" in data else 0
    m = data["base"]["m"] if "base" in data else 0
    work = np.zeros(lib.fhobs_plan_work_size(n, k, m, size, TAU_GRID.size))
    return C_PLANS[KINDS[kind].family](_PlanCall(lib, model, data, top, dt, work, bins))


class _PlanCall:
    """One call of the C planner: its library, the model, its design data, the ZOH's top rows,
    the step size, the scratch and the bins of tau scans."""

    def __init__(self, lib: ctypes.CDLL, model: Any, data: dict[str, Any], top: np.ndarray,
                 dt: float, work: np.ndarray, bins: BinScans | None) -> None:
        self.lib, self.model, self.data, self.top, self.dt = lib, model, data, top, dt
        self.work, self.bins = work, bins
        self.M = np.zeros(top.shape)
        self.keep: list[np.ndarray] = []


def _linear_plan(call: _PlanCall) -> dict[str, Any]:
    base = _structure(kernel.LinearPlan, call.data["base"], call.keep)
    held = _structure(HeldInnovation, call.data["held"], call.keep)
    radius = call.lib.fhobs_plan_luenberger(
        ctypes.byref(kernel.LinearPlan()), ctypes.byref(base), ctypes.byref(held),
        kernel.pointer(call.top), ctypes.c_double(call.dt), kernel.pointer(call.M),
        kernel.pointer(call.work))
    return {"M": call.M, "radius": radius}


def _plant_plan(call: _PlanCall) -> dict[str, Any]:
    n, size = call.top.shape
    call.lib.fhobs_plan_zoh(kernel.pointer(call.top), n, size, ctypes.c_double(call.dt),
                            kernel.pointer(call.M), kernel.pointer(call.work))
    widths = np.cumsum([n, call.model.B.shape[1]])
    Phi, Gamma_B, Gamma_E = np.split(call.M, widths, axis=1)
    return {"Phi": Phi, "Gamma_B": Gamma_B, "Gamma_E": Gamma_E}


def _filter_plan(call: _PlanCall) -> dict[str, Any]:
    n, k = call.data["base"]["n"], call.data["base"]["k"]
    base = _structure(kernel.FilterPlan, call.data["base"], call.keep)
    factors, last_tau = np.zeros(4 * k, dtype=complex), np.zeros(1)
    work_size, cwork_size = kernel.filter_work_size(n, k)
    scratch, cscratch = np.zeros(work_size), np.zeros(cwork_size, dtype=complex)
    call.keep += [factors, last_tau, scratch, cscratch]
    plan = kernel.FilterPlan(factors=kernel.pointer(factors), last_tau=kernel.pointer(last_tau),
                             work=kernel.pointer(scratch), cwork=kernel.pointer(cscratch))
    return _scanned_plan(call, call.lib.fhobs_plan_filter, plan, base)


def _prescribed_plan(call: _PlanCall) -> dict[str, Any]:
    n, k = call.data["base"]["n"], call.data["base"]["k"]
    base = _structure(kernel.PrescribedPlan, call.data["base"], call.keep)
    factors, last_tau = np.zeros(2 * k, dtype=complex), np.zeros(1)
    scratch = np.zeros(kernel.prescribed_work_size(n, k))
    call.keep += [factors, last_tau, scratch]
    plan = kernel.PrescribedPlan(factors=kernel.pointer(factors),
                                 last_tau=kernel.pointer(last_tau), work=kernel.pointer(scratch))
    return _scanned_plan(call, call.lib.fhobs_plan_prescribed, plan, base)


def _scanned_plan(call: _PlanCall, function: Any, plan: ctypes.Structure,
                  base: ctypes.Structure) -> dict[str, Any]:
    """A plan with a gain level: the tau scan (of the call's bins), then the plan."""
    n = call.top.shape[0]
    scan = _structure(LevelScan, {**call.data["scan"], "n_tau": TAU_GRID.size}, call.keep)
    F, best = np.zeros((n, n)), ctypes.c_double()
    bins = BinScans() if call.bins is None else call.bins
    refused = function(ctypes.byref(plan), ctypes.byref(base), ctypes.byref(scan), bins.pointer,
                       kernel.pointer(call.top), ctypes.c_double(call.dt), kernel.pointer(call.M),
                       kernel.pointer(F), ctypes.byref(best), kernel.pointer(call.work))
    if refused:
        raise ValueError(f"no gain level makes the split step of size {call.dt!r} contractive "
                         f"(smallest spectral radius {best.value:.6g})")
    return {"M": call.M, "F": F, "floor_level": plan.floor_level, "ceiling": plan.ceiling}


C_PLANS: dict[str, Callable[[_PlanCall], dict[str, Any]]] = {
    "filtering": _filter_plan, "supervised": _filter_plan,
    "prescribed_time": _prescribed_plan, "linear": _linear_plan, "plant": _plant_plan}
"""Plan family -> the C planner's call (the supervised family's: its filtering observer's)."""
