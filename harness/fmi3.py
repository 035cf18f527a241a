"""FMI 3.0 co-simulation FMUs in the harness: their array variables as the scalar signals the
systems name, and an instance the master drives as it drives an FMI 2.0 one.

A system names the elements of an FMI 3.0 array variable as it names an FMI 2.0 FMU's scalars
(``observer.x_hat[2]``, ``plant.y``: all of ``y[1]``, ``y[2]``), so scenarios and comparisons
are the same for both versions and an FMI 3.0 FMU mixes with FMI 2.0 ones in one system:

- :func:`element_variables`: one fmpy ``ScalarVariable`` per element (``x_hat[2]``; a scalar
  keeps its name), its type the FMI 2.0 one (Float64 -> Real, Int32 and the other integers ->
  Integer, Boolean), its ``valueReference`` the element's number in :class:`ElementSpace`
  (every variable's elements numbered in turn, row-major), its start value the element's;
- :class:`Fmi3Slave`: fmpy's ``FMU3Slave`` behind the three calls of the master's step loop
  (``fmi2SetReal``, ``fmi2DoStep``, ``fmi2GetReal`` of ``fmi3_shim.c`` with the shim as the
  component), so the master's Python and C loops run it unchanged: a set writes whole arrays
  (the elements not connected keep their start values), a get reads whole arrays and picks the
  elements, a doStep that asks for event handling, to terminate or returned early is an
  error. Instantiated without event mode and without early return; the start and stop times go
  to ``fmi3EnterInitializationMode``.

The shim is compiled on first use (:func:`shim_library`); without a C compiler FMI 3.0 FMUs
cannot be run by the harness.
"""

from __future__ import annotations

import ctypes
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fhobs.core.kernel import cached_library
from fmpy.fmi3 import FMU3Slave, fmi3LogMessageCallback
from fmpy.model_description import ModelDescription, ScalarVariable

SOURCE = Path(__file__).resolve().parent / "fmi3_shim.c"
FLAGS = ("-shared", "-fPIC", "-O2", "-std=c99")
TYPES = {"Float64": "Real", "Float32": "Real", "Boolean": "Boolean"}
"""The FMI 2.0 type of an FMI 3.0 variable's type (any other: Integer)."""


@dataclass(frozen=True)
class ElementSpace:
    """The elements of an FMI 3.0 model description, numbered: every variable's in turn.

    Attributes
    ----------
    variables : tuple of ScalarVariable
        The model description's variables (``time`` and every other).
    starts : tuple of int
        The number of each variable's first element.
    sizes : tuple of int
        Each variable's number of elements (the product of its fixed dimensions).
    """

    variables: tuple[ScalarVariable, ...]
    starts: tuple[int, ...]
    sizes: tuple[int, ...]

    @classmethod
    def of(cls, md: ModelDescription) -> ElementSpace:
        """The element space of ``md``.

        Examples
        --------
        >>> a = ScalarVariable("a", 7, "Float64", dimensions=[])
        >>> ElementSpace.of(ModelDescription(modelVariables=[a])).sizes
        (1,)
        """
        sizes = tuple(math.prod(int(d.start) for d in v.dimensions) for v in md.modelVariables)
        starts = tuple(int(s) for s in np.cumsum((0, *sizes))[:-1])
        return cls(tuple(md.modelVariables), starts, sizes)

    @property
    def size(self) -> int:
        return sum(self.sizes)

    def start_values(self) -> np.ndarray:
        """Every element's start value (0 where a variable has none), in element order."""
        values = np.zeros(self.size)
        for v, start, size in zip(self.variables, self.starts, self.sizes, strict=True):
            if v.start is not None and v.type != "String":
                text = v.start.replace("true", "1").replace("false", "0")
                values[start:start + size] = np.array(text.split(), dtype=float)
        return values


def element_variables(md: ModelDescription) -> dict[str, ScalarVariable]:
    """The scalar variables (by name) of the FMI 3.0 model description ``md``: see the module
    docstring (``time`` left out).

    Examples
    --------
    >>> from fmpy.model_description import Dimension
    >>> y = ScalarVariable("y", 4, "Float64", causality="input", start="1.0 2.0",
    ...                    dimensions=[Dimension(start=2)])
    >>> [(v.name, v.valueReference, v.type, v.start)
    ...  for v in element_variables(ModelDescription(modelVariables=[y])).values()]
    [('y[1]', 0, 'Real', '1.0'), ('y[2]', 1, 'Real', '2.0')]
    """
    space = ElementSpace.of(md)
    values = space.start_values()
    out = {}
    for v, first in zip(space.variables, space.starts, strict=True):
        if v.causality == "independent":
            continue
        shape = tuple(int(d.start) for d in v.dimensions)
        for offset, index in enumerate(np.ndindex(*shape) if shape else [()]):
            name = f"{v.name}[{','.join(str(i + 1) for i in index)}]" if shape else v.name
            start = None if v.start is None else repr(float(values[first + offset]))
            if start is not None and TYPES.get(v.type, "Integer") != "Real":
                start = str(int(values[first + offset]))
            out[name] = ScalarVariable(
                name, first + offset, TYPES.get(v.type, "Integer"), description=v.description,
                causality=v.causality, variability=v.variability, initial=v.initial,
                start=start, unit=v.unit)
    return out


class Shim(ctypes.Structure):
    """``Shim`` of fmi3_shim.c."""

    _fields_ = [(name, ctypes.c_void_p) for name in (
        "instance", "set_float64", "get_float64", "do_step", "array_vr", "array_start",
        "array_size", "values", "stamp")] + [("calls", ctypes.c_long)]


@functools.cache
def shim_library() -> ctypes.CDLL | None:
    """The compiled fmi3_shim.c, or None without a C compiler."""

    def load(path: Path) -> ctypes.CDLL | None:
        try:
            library = ctypes.PyDLL(str(path))
        except OSError:
            return None
        for name in ("fmi2SetReal", "fmi2GetReal"):
            entry = getattr(library, name)
            entry.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint), ctypes.c_size_t,
                              ctypes.POINTER(ctypes.c_double)]
            entry.restype = ctypes.c_int
        library.fmi2DoStep.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                       ctypes.c_int]
        library.fmi2DoStep.restype = ctypes.c_int
        return library

    return cached_library(SOURCE, "harness_fmi3_shim", FLAGS, (), load)


class Fmi3Slave:
    """An FMI 3.0 co-simulation FMU with the interface of fmpy's ``FMU2Slave`` that the master
    uses (see the module docstring): ``dll`` (the shim's library), ``component`` (the shim),
    ``instantiate``, ``setReal``, ``setInteger``, ``setBoolean``,
    ``enterInitializationMode``, ``exitInitializationMode``, ``terminate``, ``freeInstance``.

    Parameters
    ----------
    md : ModelDescription
        The FMU's model description (FMI 3.0, co-simulation).
    unzip_dir : str
        The extracted FMU.
    name : str
        The instance name.
    start_time, stop_time : float
        For ``fmi3EnterInitializationMode``.
    log : callable
        Called with each message the FMU logs.
    """

    def __init__(self, md: ModelDescription, unzip_dir: str, name: str, start_time: float,
                 stop_time: float, log: Callable[[str], None]) -> None:
        library = shim_library()
        if library is None:
            raise RuntimeError("FMI 3.0 FMUs need a C compiler (cc or gcc) for the harness's "
                               "shim (harness/fmi3_shim.c)")
        self.dll = library
        self.space = ElementSpace.of(md)
        self.times = (start_time, stop_time)
        self.fmu = FMU3Slave(guid=md.guid, unzipDirectory=unzip_dir, instanceName=name,
                             modelIdentifier=md.coSimulation.modelIdentifier)

        def logger(env, status, category, message) -> None:  # noqa: ANN001
            log(message.decode("utf-8", "replace") if message else "")

        self._logger = fmi3LogMessageCallback(logger)
        space = self.space
        self._array_vr = np.repeat([v.valueReference for v in space.variables],
                                   space.sizes).astype(np.uintc)
        self._array_start = np.repeat(space.starts, space.sizes).astype(np.int_)
        self._array_size = np.repeat(space.sizes, space.sizes).astype(np.int_)
        self._values = space.start_values()
        self._stamp = np.zeros(space.size, dtype=np.int_)
        self._shim = Shim()
        self.component: int | None = None

    def instantiate(self) -> None:
        """fmi3InstantiateCoSimulation (no event mode, no early return) and the shim."""
        self.fmu.instantiate(loggingOn=True, logMessage=self._logger)
        entry = self.fmu.dll
        shim = self._shim
        shim.instance = self.fmu.component
        for field, function in (("set_float64", "fmi3SetFloat64"),
                                ("get_float64", "fmi3GetFloat64"), ("do_step", "fmi3DoStep")):
            setattr(shim, field, ctypes.cast(getattr(entry, function), ctypes.c_void_p).value)
        for field in ("array_vr", "array_start", "array_size", "values", "stamp"):
            setattr(shim, field, getattr(self, f"_{field}").ctypes.data)
        self.component = ctypes.addressof(shim)

    def setReal(self, vr: list[int], values: list[float]) -> None:  # noqa: N802 - fmpy's name
        """Set elements (numbers of the element space) through the shim."""
        refs = (ctypes.c_uint * len(vr))(*vr)
        data = (ctypes.c_double * len(values))(*values)
        status = self.dll.fmi2SetReal(self.component, refs, len(vr), data)
        if status > 1:
            raise _StatusError(status)

    def _set_whole(self, vr: list[int], values: list, setter: Callable) -> None:
        for element, value in zip(vr, values, strict=True):
            index = int(np.searchsorted(self.space.starts, element, side="right")) - 1
            first, size = self.space.starts[index], self.space.sizes[index]
            self._values[element] = value
            whole = self._values[first:first + size]
            setter([self.space.variables[index].valueReference], [type(value)(x) for x in whole])

    def setInteger(self, vr: list[int], values: list[int]) -> None:  # noqa: N802
        """Set integer elements: their arrays whole (fmi3SetInt32)."""
        self._set_whole(vr, [int(v) for v in values], self.fmu.setInt32)

    def setBoolean(self, vr: list[int], values: list[bool]) -> None:  # noqa: N802
        """Set Boolean elements: their arrays whole (fmi3SetBoolean)."""
        self._set_whole(vr, [bool(v) for v in values], self.fmu.setBoolean)

    def enterInitializationMode(self) -> None:  # noqa: N802
        self.fmu.enterInitializationMode(startTime=self.times[0], stopTime=self.times[1])

    def exitInitializationMode(self) -> None:  # noqa: N802
        self.fmu.exitInitializationMode()

    def terminate(self) -> None:
        self.fmu.terminate()

    def freeInstance(self) -> None:  # noqa: N802
        self.fmu.freeInstance()
        self.component = None


class _StatusError(Exception):
    """A status worse than warning (``status``), as fmpy's FMICallException carries it."""

    def __init__(self, status: int) -> None:
        super().__init__(f"status {status}")
        self.status = status
