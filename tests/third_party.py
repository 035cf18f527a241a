"""Run an exported SSP file in third-party engines: fmpy's SSP simulator and libcosim.

Both return a :class:`EngineResult` with the same row convention as the harness
(:class:`harness.master.CoSimResult`): row ``k`` holds the outputs at ``t_k = t0 + k h``.

Observed behaviour that the comparison has to account for:

- ``fmpy.ssp.simulation.simulate_ssp`` starts every connector at 0.0 and only transfers values
  after the first step, so during the first step every connected input is 0 instead of the
  outputs at ``t0``; it records after each step (no row for ``t0``) and labels the row with the
  time at the *start* of the step; it accumulates ``time += h`` (and loops while that is below
  the stop time, so it can take one step too many); and it does not apply the SSD's
  parameter bindings itself (they are passed here as its ``parameter_set``).
- libcosim exchanges the outputs at ``t0`` during initialisation (as the harness does) and
  steps with an integer nanosecond clock.

Both results hold rows for ``t_1 .. t_N`` only.
"""

from __future__ import annotations

import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class EngineResult:
    """``values[k, j]``: signal ``names[j]`` (``"fmu.var"``) at ``time[k]``."""

    time: np.ndarray
    names: tuple[str, ...]
    values: np.ndarray

    def signal(self, name: str) -> np.ndarray:
        """Column of the scalar signal ``"fmu.var"``."""
        return self.values[:, self.names.index(name)]


def run_fmpy_ssp(ssp: str | Path, step: float, stop_time: float) -> EngineResult:
    """Run ``ssp`` in ``fmpy.ssp.simulation.simulate_ssp`` with the SSD's start values.

    Returns rows for ``t_1 .. t_N`` (fmpy records no row at ``t0``), relabelled with the time at
    the end of each step.
    """
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import Parameter, ParameterSet, find_components, read_ssd

    ssd = read_ssd(str(ssp))
    start = ParameterSet(name="start_values")
    for comp in find_components(ssd.system):
        for binding in comp.parameterBindings:
            for pset in binding.parameterValues:
                start.parameters += [
                    Parameter(name=f"{comp.name}.{p.name}", type=p.type, value=p.value)
                    for p in pset.parameters
                ]
    # fmpy loops "while time < stop_time" on an accumulated time: stop half a step early so
    # that rounding cannot add a step
    rows = simulate_ssp(
        str(ssp), stop_time=stop_time - 0.5 * step, step_size=step, parameter_set=start
    )
    names = tuple(n for n in rows.dtype.names if n != "time")
    values = np.column_stack([rows[n] for n in names])
    return EngineResult(rows["time"] + step, names, values)


def run_libcosim(
    ssp: str | Path, step: float, stop_time: float, signals: list[str]
) -> EngineResult:
    """Run ``ssp`` in libcosim (libcosimpy) with a fixed step and record ``signals``.

    Parameters
    ----------
    ssp
        The SSP file (unpacked to a temporary directory for libcosim).
    step, stop_time
        Communication step and end time (converted to libcosim's nanosecond clock).
    signals
        Scalar ``"fmu.var"`` Real variables to record.

    Returns
    -------
    EngineResult
        Rows for ``t_1 .. t_N``: libcosimpy 0.0.6 trims a sample off the end for every step
        number 0 it returns, so the sample at ``t0`` (step 0) cannot be fetched with the others.
    """
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.WARNING)
    step_ns = int(round(step * 1e9))
    steps = int(round(stop_time / step))
    with tempfile.TemporaryDirectory() as tmp:
        with zipfile.ZipFile(ssp) as zf:
            zf.extractall(tmp)
        execution = CosimExecution.from_ssp_file(tmp, step_size=step_ns)
        observer = CosimObserver.create_time_series(buffer_size=steps + 2)
        execution.add_observer(observer)
        refs = _libcosim_refs(execution, signals)
        for index, vr in refs:
            observer.start_time_series(index, vr, CosimVariableType.REAL)
        execution.step(steps)
        columns, times = [], None
        for index, vr in refs:
            t_ns, _, samples = observer.time_series_real_samples(index, vr, 1, steps)
            columns.append(samples)
            times = t_ns
        execution.stop()
    return EngineResult(np.asarray(times) * 1e-9, tuple(signals), np.column_stack(columns))


def _libcosim_refs(execution, signals: list[str]) -> list[tuple[int, int]]:
    """(slave index, value reference) of every ``"fmu.var"``."""
    out = []
    for signal in signals:
        fmu, _, var = signal.partition(".")
        index = execution.slave_index_from_instance_name(fmu)
        vrs = {v.name.decode(): v.reference for v in execution.slave_variables(index)}
        out.append((index, vrs[var]))
    return out
