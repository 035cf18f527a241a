"""Names and units of a plant's signals: the spec's ``name`` and ``[signals]`` table.

A spec may name its plant and its states, inputs, outputs and unknown inputs, and give their
units (``python -m harness linearize`` fills them in from the model)::

    name = "DC-Motor.SuT"                 # the plant's name: plot titles, FMU descriptions
    [signals]                             # every key optional; each list as long as its matrix
    states = ["inductor.i", "inertia.phi", "inertia.w"]       # n: the rows of A
    state_units = ["A", "rad", "rad/s"]                       # "" for none
    inputs = ["U"]                        # m: the columns of B
    input_units = ["V"]
    outputs = ["phiB"]                    # k: the rows of C
    output_units = ["rad"]
    unknown_inputs = ["M_load"]           # r: the columns of E
    unknown_input_units = ["N.m"]

Unnamed signals are ``x[i]``, ``u[i]``, ``y[i]`` and ``q[i]`` (1-based), without unit. Names are
unique within a group; units are free text (FMI's unit names, e.g. ``"N.m"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..errors import SpecError

GROUPS = {"states": "x", "inputs": "u", "outputs": "y", "unknown_inputs": "q"}
"""The signal groups and the symbol of their default names."""
SIGNAL_KEYS = tuple(key for group in GROUPS for key in (group, group[:-1] + "_units"))
"""The keys of the ``[signals]`` table."""
MAX_NAME_LENGTH = 200
"""The longest name or unit accepted (FMI tools write long structured names, not essays)."""


@dataclass(frozen=True)
class SignalNames:
    """Names and units of a plant's states, inputs, outputs and unknown inputs.

    Attributes
    ----------
    states, inputs, outputs, unknown_inputs : tuple of str
        One name per state (n), input (m), output (k) and unknown input (r).
    state_units, input_units, output_units, unknown_input_units : tuple of str
        The unit of each, ``""`` for none.
    """

    states: tuple[str, ...]
    state_units: tuple[str, ...]
    inputs: tuple[str, ...]
    input_units: tuple[str, ...]
    outputs: tuple[str, ...]
    output_units: tuple[str, ...]
    unknown_inputs: tuple[str, ...] = ()
    unknown_input_units: tuple[str, ...] = ()

    @classmethod
    def default(cls, n: int, m: int, k: int, r: int = 0) -> SignalNames:
        """The names of an unnamed plant: ``x[i]``, ``u[i]``, ``y[i]``, ``q[i]``, no units.

        Examples
        --------
        >>> SignalNames.default(2, 1, 1).states
        ('x[1]', 'x[2]')
        """
        return signal_names({}, {"states": n, "inputs": m, "outputs": k,
                                 "unknown_inputs": r})

    def label(self, group: str, i: int) -> str:
        """Signal ``i`` (0-based) of ``group`` with its unit, for an axis or a table.

        Examples
        --------
        >>> names = signal_names({"states": ["inductor.i", "w"], "state_units": ["A", ""]},
        ...                      {"states": 2, "inputs": 1, "outputs": 1, "unknown_inputs": 0})
        >>> names.label("states", 0), names.label("states", 1)
        ('inductor.i [A]', 'w')
        """
        name = getattr(self, group)[i]
        unit = getattr(self, group[:-1] + "_units")[i]
        return f"{name} [{unit}]" if unit else name


def signal_names(table: Any, sizes: dict[str, int], source: str = "<dict>") -> SignalNames:
    """Validate a ``[signals]`` table against the plant's sizes, filling in the defaults.

    Parameters
    ----------
    table : dict
        The table (module docstring; its keys checked by the spec loader against
        :data:`SIGNAL_KEYS`); ``{}`` for an unnamed plant.
    sizes : dict
        ``{"states": n, "inputs": m, "outputs": k, "unknown_inputs": r}``.
    source : str
        Name used in error messages.

    Returns
    -------
    SignalNames

    Raises
    ------
    SpecError
        Naming the key and the reason (not a list of strings, wrong length, a repeated name).

    Examples
    --------
    >>> sizes = {"states": 2, "inputs": 1, "outputs": 1, "unknown_inputs": 0}
    >>> signal_names({"outputs": ["angle"], "output_units": ["rad"]}, sizes).label("outputs", 0)
    'angle [rad]'
    >>> signal_names({"states": ["a"]}, sizes)
    Traceback (most recent call last):
    ...
    fhobs.errors.SpecError: <dict>: signals.states has 1 entry, expected 2 (the states of the plant)
    """
    if not isinstance(table, dict):
        raise SpecError(f"{source}: signals must be a table ([signals]), "
                        f"got {type(table).__name__}")
    values: dict[str, tuple[str, ...]] = {}
    for group, symbol in GROUPS.items():
        count = sizes[group]
        units_key = group[:-1] + "_units"
        names = _strings(table.get(group), count, f"signals.{group}", group, source)
        values[group] = names or tuple(f"{symbol}[{i + 1}]" for i in range(count))
        repeated = sorted({name for name in values[group] if values[group].count(name) > 1})
        if repeated:
            raise SpecError(f"{source}: signals.{group} names {repeated[0]!r} more than once "
                            "(each signal needs its own name)")
        values[units_key] = (_strings(table.get(units_key), count, f"signals.{units_key}",
                                      group, source, empty=True) or ("",) * count)
    return SignalNames(**values)


def _strings(value: Any, count: int, label: str, group: str, source: str,
             empty: bool = False) -> tuple[str, ...]:
    """A list of ``count`` strings (``()`` when absent)."""
    if value is None:
        return ()
    what = "strings" if empty else "non-empty strings"
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise SpecError(f"{source}: {label} must be a list of {what}, got {value!r:.80}")
    if len(value) != count:
        plural = "entry" if len(value) == 1 else "entries"
        raise SpecError(f"{source}: {label} has {len(value)} {plural}, expected {count} "
                        f"(the {group.replace('_', ' ')} of the plant)")
    for text in value:
        if (not text.strip() and not empty) or len(text) > MAX_NAME_LENGTH or (
                not text.isprintable()):
            raise SpecError(f"{source}: {label} entry {text!r:.80} must be {what[:-1]} of "
                            f"printable characters, at most {MAX_NAME_LENGTH} long")
    return tuple(value)
