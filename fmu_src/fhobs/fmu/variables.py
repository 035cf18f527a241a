"""The slave's variables: arrays as consecutive row-major scalars in one flat float buffer.

Every Real variable lives in one flat buffer (each array variable is a view of its slice; the
inputs first, then the outputs, then the parameters), so ``fmi2GetReal`` / ``fmi2SetReal`` are
one fancy-indexing operation on it (the index array of a list of value references is cached).
Element labels are ``A[1,1]``, ``A[1,2]``, ..., ``y[1]``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Variability, Integer, Real

CAUSALITIES: dict[str, dict[str, Any]] = {
    "parameter": {"causality": Fmi2Causality.parameter, "variability": Fmi2Variability.fixed},
    "input": {"causality": Fmi2Causality.input, "variability": Fmi2Variability.continuous},
    "output": {
        "causality": Fmi2Causality.output,
        "variability": Fmi2Variability.continuous,
        "initial": Fmi2Initial.exact,
    },
}
"""pythonfmu's attributes of an array element by its causality."""

INDEX_CACHE_SIZE = 64
"""Cached index arrays of lists of value references (cleared when it holds this many)."""


def element_names(name: str, shape: tuple[int, ...]) -> list[str]:
    """FMI names of the elements of an array, row-major, 1-based (``A[1,1]``, ``A[1,2]``...).

    Parameters
    ----------
    name : str
        Base name of the array.
    shape : tuple of int
        ``()`` for a scalar (the name is returned unchanged), ``(n,)`` or ``(n, m)``.

    Returns
    -------
    list of str
    """
    if not shape:
        return [name]
    return [f"{name}[{','.join(str(i + 1) for i in idx)}]" for idx in np.ndindex(*shape)]


def _as_slice(index: np.ndarray) -> np.ndarray | slice:
    """Buffer positions ``index`` as a slice when they are consecutive (indexing with it is a
    view, cheaper than fancy indexing), else unchanged."""
    if index.size and np.array_equal(index, np.arange(index[0], index[0] + index.size)):
        return slice(int(index[0]), int(index[0]) + index.size)
    return index


class Variables:
    """Declaration of array and Integer variables and their get/set (a mixin of
    :class:`fhobs.fmu.slave_base.FhobsSlave`, whose other parts it uses: ``_output_layout``,
    ``_model_step_arguments``, ``_checked_access``)."""

    def add_array(self, name: str, value: Any, causality: str, description: str) -> None:
        """Register a float array (or scalar) as consecutive row-major scalar variables.

        Parameters
        ----------
        name : str
            Base name (``A``, ``y``, ``nu``...).
        value : array_like
            Start value; its shape fixes the variables.
        causality : {"parameter", "input", "output"}
        description : str
        """
        array = np.array(value, dtype=float)
        self._arrays[name] = array
        self._first_vr[name] = len(self.vars)
        self._causal[causality].append(name)
        labels = element_names(name, array.shape)
        for index, label in zip(np.ndindex(*array.shape), labels, strict=True):
            self.register_variable(
                Real(
                    label,
                    description=description,
                    getter=lambda n=name, i=index: float(self._arrays[n][i]),
                    setter=lambda v, n=name, i=index: self._arrays[n].__setitem__(i, v),
                    **CAUSALITIES[causality],
                )
            )

    def _pack_arrays(self) -> None:
        """Move every array variable into one flat buffer (each array becomes a view of it):
        the inputs in declaration order, the outputs in the order of :meth:`_output_layout`,
        then the parameters. Precompute the value-reference -> buffer-position map, the views
        of all inputs and of all outputs, and the model step's arguments."""
        self._output_names = self._output_layout()
        if sorted(self._output_names) != sorted(self._causal["output"]):
            raise ValueError(f"output layout {self._output_names} is not a permutation of the "
                             f"outputs {self._causal['output']}")
        self._values = np.zeros(sum(a.size for a in self._arrays.values()))
        self._position: dict[int, int] = {}
        start = 0
        for name in (*self._causal["input"], *self._output_names, *self._causal["parameter"]):
            array = self._arrays[name]
            view = self._values[start:start + array.size].reshape(array.shape)
            view[...] = array
            self._arrays[name] = view
            first = self._first_vr[name]
            self._position.update({first + i: start + i for i in range(array.size)})
            start += array.size
        n_inputs = sum(self._arrays[name].size for name in self._causal["input"])
        n_outputs = sum(self._arrays[name].size for name in self._causal["output"])
        self._inputs = self._values[:n_inputs]
        self._outputs = self._values[n_inputs:n_inputs + n_outputs]
        self._bound = self._arrays["input_bound"]
        self._step_arguments = self._model_step_arguments()
        # buffer positions of lists of value references checked for reading / for writing now
        self._index_cache: dict[tuple[int, ...], np.ndarray | slice] = {}
        self._write_cache: dict[tuple[int, ...], np.ndarray | slice] = {}
        size = max(self._position, default=-1) + 1
        # 1 where fmi2SetReal may write now (kept up to date by _set_mode; read by the wrapper)
        self._writable = np.zeros(size, dtype=np.uint8)
        self._input_vrs = [vr for name in self._causal["input"] for vr in self._vrs(name)]
        self._parameter_vrs = [vr for name in self._causal["parameter"] for vr in self._vrs(name)]
        self._writable[self._input_vrs] = 1
        self._accepted_step = math.nan  # the step size whose checks passed last (none yet)
        self._certified: tuple | None = None  # the parameters of the last initialisation

    def _vrs(self, name: str) -> range:
        """Value references of the elements of array variable ``name``."""
        return range(self._first_vr[name], self._first_vr[name] + self._arrays[name].size)

    def get_real(self, vrs: list[int]) -> list[float]:
        """Values of the Real variables ``vrs`` (one read of the flat buffer)."""
        index = self._index_cache.get(tuple(vrs))
        if index is None:
            self._checked_access("fmi2GetReal", vrs)
            index = self._index(self._index_cache, vrs)
        return self._values[index].tolist()

    def set_real(self, vrs: list[int], values: list[float]) -> None:
        """Set the Real variables ``vrs`` (one write into the flat buffer)."""
        index = self._write_cache.get(tuple(vrs))
        if index is None:
            self._checked_access("fmi2SetReal", vrs)
            index = self._index(self._write_cache, vrs)
        self._values[index] = values

    def get_integer(self, vrs: list[int]) -> list[int]:
        self._checked_access("fmi2GetInteger", vrs)
        return super().get_integer(vrs)

    def set_integer(self, vrs: list[int], values: list[int]) -> None:
        self._checked_access("fmi2SetInteger", vrs)
        super().set_integer(vrs, values)

    def get_boolean(self, vrs: list[int]) -> list[bool]:
        self._checked_access("fmi2GetBoolean", vrs)
        return super().get_boolean(vrs)

    def set_boolean(self, vrs: list[int], values: list[bool]) -> None:
        self._checked_access("fmi2SetBoolean", vrs)
        super().set_boolean(vrs, values)

    def get_string(self, vrs: list[int]) -> list[str]:
        self._checked_access("fmi2GetString", vrs)
        return super().get_string(vrs)

    def set_string(self, vrs: list[int], values: list[str]) -> None:
        self._checked_access("fmi2SetString", vrs)
        super().set_string(vrs, values)

    def _index(self, cache: dict, vrs: list[int]) -> np.ndarray | slice:
        """Buffer positions of the Real variables ``vrs``, which the caller has checked, kept
        in ``cache`` (per list of references; a slice when they are consecutive, as a
        master's inputs and outputs usually are)."""
        if len(cache) >= INDEX_CACHE_SIZE:
            cache.clear()
        positions = np.array([self._position[vr] for vr in vrs], dtype=np.intp)
        index = cache[tuple(vrs)] = _as_slice(positions)
        return index

    def add_integer(self, name: str, value: int, description: str) -> None:
        """Register an Integer parameter."""
        self._integers[name] = int(value)
        self.register_variable(
            Integer(
                name,
                description=description,
                getter=lambda n=name: self._integers[n],
                setter=lambda v, n=name: self._integers.__setitem__(n, int(v)),
                **CAUSALITIES["parameter"],
            )
        )

    def has(self, name: str) -> bool:
        """Whether the slave has the variable ``name`` (an optional one may be absent)."""
        return name in self._arrays or name in self._integers

    def array(self, name: str) -> np.ndarray:
        """Current value of an array variable (a copy)."""
        return self._arrays[name].copy()

    def _elements(self, name: str) -> Iterator[tuple[str, float]]:
        """(FMI name, value) of each element of an array variable, row-major."""
        values = self._arrays[name]
        return zip(element_names(name, values.shape), values.flat, strict=True)

    def integer(self, name: str) -> int:
        """Current value of an Integer parameter."""
        return self._integers[name]

    def choice(self, name: str, choices: Sequence[str]) -> str:
        """The entry of ``choices`` that the Integer parameter ``name`` selects; ValueError if
        the index is out of range."""
        index = self.integer(name)
        if not 0 <= index < len(choices):
            raise ValueError(f"{name} = {index} is not in 0..{len(choices) - 1} ({choices})")
        return choices[index]
