"""Which FMI 2.0 co-simulation function an instance accepts in which state, and at which time:
one table for both builds of every FMU kind.

The states are those of the FMI 2.0 co-simulation state machine that a synchronous FMU whose
refused calls leave it unchanged can be in: ``instantiated`` (after fmi2Instantiate or
fmi2Reset), ``initialisation mode`` (after fmi2EnterInitializationMode), ``step mode`` (the
standard's stepComplete: after fmi2ExitInitializationMode and every doStep, also a refused
one, which leaves the state as it was) and ``terminated``. The table :data:`ALLOWED` is the
standard's (section 4.2.4) restricted to these states; functions the FMUs do not provide
(input and output derivatives, asynchronous steps) are refused in every state with
:data:`UNSUPPORTED`'s reason.

The Python slaves ask :func:`call_problem`; the C layers (the native FMUs' ``fmi2_layer.c``,
the pythonfmu FMUs' ``status_wrapper.c``) include the header :func:`c_header` writes from the
same table, so the rules and their messages are written once.

The native FMI 3.0 layer (``fmi3_layer.c``) reads the FMI 3.0 table of the same header
(:data:`ALLOWED3`, :data:`UNSUPPORTED3`, ``FHOBS3_*``): each FMI 3.0 function that has an FMI 2.0
counterpart takes its rule (:data:`FMI2_COUNTERPART`), allowed also in FMI 3.0's event mode
(:data:`STATES3`: the FMU has no events; a host that asks for event mode passes through it)
where the function may be called there; the rest are FMI 3.0's own (event mode's functions) or
refused in every state (clocks, model exchange, scheduled execution, configuration mode,
derivatives), each with its reason.

This module is standard-library only: it runs inside the FMUs and at build time.

Examples
--------
>>> call_problem("fmi2DoStep", "instantiated")
'fmi2DoStep is not allowed in the state instantiated (only in step mode)'
>>> call_problem("fmi2GetReal", "step mode")
''
>>> call_problem3("fmi3DoStep", "event mode")
'fmi3DoStep is not allowed in the state event mode (only in step mode)'
"""

from __future__ import annotations

import math
from collections.abc import Callable

STATES = ("instantiated", "initialisation mode", "step mode", "terminated")
"""The states, in the order of their bits in the C masks (bit i: ``STATES[i]``)."""

_ANY = frozenset(STATES)
_READABLE = frozenset(("initialisation mode", "step mode", "terminated"))
_WRITABLE = frozenset(("instantiated", "initialisation mode", "step mode"))

ALLOWED: dict[str, frozenset[str]] = {
    "fmi2SetDebugLogging": _ANY,
    "fmi2FreeInstance": _ANY,
    "fmi2SetupExperiment": frozenset(("instantiated",)),
    "fmi2EnterInitializationMode": frozenset(("instantiated",)),
    "fmi2ExitInitializationMode": frozenset(("initialisation mode",)),
    "fmi2Terminate": frozenset(("step mode",)),
    "fmi2Reset": _ANY,
    "fmi2GetReal": _READABLE,
    "fmi2GetInteger": _READABLE,
    "fmi2GetBoolean": _READABLE,
    "fmi2GetString": _READABLE,
    "fmi2SetReal": _WRITABLE,
    "fmi2SetInteger": _WRITABLE,
    "fmi2SetBoolean": _WRITABLE,
    "fmi2SetString": _WRITABLE,
    "fmi2GetFMUstate": _ANY,
    "fmi2SetFMUstate": _ANY,
    "fmi2FreeFMUstate": _ANY,
    "fmi2SerializedFMUstateSize": _ANY,
    "fmi2SerializeFMUstate": _ANY,
    "fmi2DeSerializeFMUstate": _ANY,
    "fmi2DoStep": frozenset(("step mode",)),
    "fmi2GetRealStatus": frozenset(("step mode", "terminated")),
    "fmi2GetBooleanStatus": frozenset(("step mode", "terminated")),
}
"""For each function taking an instance: the states in which it is allowed."""

_SYNCHRONOUS = ("this FMU's steps are synchronous: it has no pending step whose status to query "
                "(fmi2GetRealStatus gives the last successful time, fmi2GetBooleanStatus whether "
                "it terminated)")
UNSUPPORTED: dict[str, str] = {
    "fmi2GetDirectionalDerivative": "this FMU provides no directional derivatives "
                                    "(providesDirectionalDerivative = false)",
    "fmi2SetRealInputDerivatives": "this FMU does not interpolate inputs "
                                   "(canInterpolateInputs = false)",
    "fmi2GetRealOutputDerivatives": "this FMU provides no output derivatives "
                                    "(maxOutputDerivativeOrder = 0)",
    "fmi2CancelStep": "this FMU's steps are synchronous (canRunAsynchronuously = false): "
                      "there is no step in progress to cancel",
    "fmi2GetStatus": _SYNCHRONOUS,
    "fmi2GetIntegerStatus": _SYNCHRONOUS,
    "fmi2GetStringStatus": _SYNCHRONOUS,
}
"""Functions refused in every state, with the reason."""

TIME_TOLERANCE = 1e-9
"""doStep's currentCommunicationPoint may differ from the FMU's own time (the start time, then
the end of its last step) by this much relative to the larger of that time and the step size:
far above the round-off of a host that accumulates time (t + h) or forms it as t0 + k h, far
below a step."""


def time_problem(current_time: float, own_time: float, step_size: float) -> str:
    """Why a doStep from ``current_time`` does not continue an FMU whose time is ``own_time``
    ('' if it does; any finite time does when ``own_time`` is NaN: after an FMU state was set).

    Examples
    --------
    >>> time_problem(0.30000000000000004, 0.3, 0.1)
    ''
    >>> time_problem(0.0, 0.3, 0.1)[:44]
    'currentCommunicationPoint 0.0 is not the FMU'
    """
    if not math.isfinite(current_time):
        return f"currentCommunicationPoint {number_text(current_time)} is not finite"
    if math.isnan(own_time) or abs(current_time - own_time) <= TIME_TOLERANCE * max(
            abs(own_time), step_size):
        return ""
    return TIME_MESSAGE % (number_text(current_time), number_text(own_time))


TIME_MESSAGE = ("currentCommunicationPoint %s is not the FMU's time %s (the start time, or the "
                f"end of its last step; a difference of up to {TIME_TOLERANCE:g} relative is "
                "taken as the host's round-off)")
"""The refusal of a time away from the FMU's (``%s``: the two times)."""


ZOH_CONDITION_LIMIT = 1e9
"""Largest ``step ||A||_1`` for which the exact ZOH ``expm(step A)`` is computed: its condition
number is at least ``step ||A||``, so at this limit its relative error can already reach
eps * 1e9 = 2e-7 (entries like 1e300 give finite numbers that mean nothing)."""

ZOH_MESSAGE = ("%s: step * ||A||_1 = %.3g exceeds " f"{ZOH_CONDITION_LIMIT:.0e}"
               ", beyond which expm(step * A) has no correct digit (step = %s); check the "
               "entries of A")
"""The refusal of such a step (``%`` format: the model, step * ||A||_1, the step)."""

COARSE_STEP_TOLERANCE = 1e-9
"""A communication step counts as longer than an observer's ``max_communication_step`` when
it exceeds it by more than this much relative (a host's round-off of a step it was given is
not a longer step)."""

COARSE_STEP_MESSAGE = ("communication step %.3g s is longer than the %.3g s over which this "
                       "design tolerates its inputs held (max_communication_step): the "
                       "estimate may settle more than twice as slowly as designed. Use a "
                       "communication step of at most max_communication_step; this warning is "
                       "given once per instance")
"""The warning of the first step longer than ``max_communication_step`` (``printf`` format,
also for Python's ``%``: the step, the parameter)."""


def coarse_step_problem(step_size: float, max_step: float) -> str:
    """The warning of a communication step ``step_size`` longer than ``max_step`` (an
    observer's ``max_communication_step``; 0 or less: no figure, no warning), '' otherwise.

    Examples
    --------
    >>> coarse_step_problem(0.01, 0.0259)
    ''
    >>> coarse_step_problem(0.05, 0.0259)[:52]
    'communication step 0.05 s is longer than the 0.0259 '
    """
    if max_step > 0.0 and step_size > max_step * (1.0 + COARSE_STEP_TOLERANCE):
        return COARSE_STEP_MESSAGE % (step_size, max_step)
    return ""


MAX_STEP_INDEX = 2**42
"""The plant's step index k (its noise sample) is a whole number in ``[0, MAX_STEP_INDEX)``:
the noise block ``k // 1024`` is a 32-bit seed word in both builds."""


def number_text(value: float) -> str:
    """A number as a message shows it: ``repr`` of a Python float (never ``np.float64(...)``).

    Examples
    --------
    >>> number_text(0.5)
    '0.5'
    """
    return repr(float(value))


ACCESS_MESSAGES: dict[str, str] = {
    "unknown": "%s: value reference %u is not a variable of this FMU (its value references "
               "are 0..%u)",
    "type": "%s: %s (value reference %u) is of type %s, not %s",
    "output": "%s: %s (value reference %u) is an output: the FMU computes it, it cannot be set",
    "local": "%s: %s (value reference %u) is a local variable: it cannot be set",
    "fixed": "%s: %s (value reference %u) is a fixed parameter: it can be set only before "
             "fmi2ExitInitializationMode (the instance is in %s; fmi2Reset returns to the start "
             "values)",
}
"""The refusals of a get/set call (``printf`` formats, also for Python's ``%``): an unknown
value reference (function, reference, last reference), another type (function, variable,
reference, its type, the function's type), a write to an output or to ``status``, a write to a
parameter after initialisation (function, variable, reference, state)."""

HEADER = "fhobs_call_rules.h"
"""The file name of :func:`c_header`'s text where C code includes it."""

FUNCTIONS = (*ALLOWED, *UNSUPPORTED)
"""Every function of the table, in the order of the C header's ``FHOBS_CALL_*`` numbers."""


def _problem(function: str, state: str, allowed: dict[str, frozenset[str]],
             unsupported: dict[str, str], states: tuple[str, ...]) -> str:
    """Why ``function`` may not be called in ``state`` under the table ``allowed`` /
    ``unsupported`` of the state machine ``states`` ('' if it may)."""
    if function in unsupported:
        return f"{function} is not supported: {unsupported[function]}"
    if state in allowed[function]:
        return ""
    where = _where(allowed[function], states)
    return f"{function} is not allowed in the state {state} (only in {where})"


def _where(allowed: frozenset[str], states: tuple[str, ...]) -> str:
    """The states of ``allowed`` in the order of ``states``, joined by 'or'."""
    return " or ".join(s for s in states if s in allowed)


def call_problem(function: str, state: str) -> str:
    """Why ``function`` may not be called in ``state`` ('' if it may).

    Parameters
    ----------
    function : str
        An FMI 2.0 function name of :data:`FUNCTIONS` (``"fmi2DoStep"``...).
    state : str
        One of :data:`STATES`.

    Returns
    -------
    str
        The message an FMU logs with its fmi2Error, or '' when the call is allowed.

    Examples
    --------
    >>> call_problem("fmi2CancelStep", "step mode")[:32]
    'fmi2CancelStep is not supported:'
    """
    return _problem(function, state, ALLOWED, UNSUPPORTED, STATES)


def c_header() -> str:
    """The C header of this table (:data:`HEADER`): ``FHOBS_STATE_*`` bit numbers,
    ``FHOBS_CALL_*`` function numbers, their masks and the refusal messages (with one ``%s``
    for the state's name where the call is merely out of sequence), the get/set refusals
    (``FHOBS_ACCESS_*``, :data:`ACCESS_MESSAGES`), the time check, the ZOH limit and the
    coarse-step warning (:func:`coarse_step_problem`).

    Examples
    --------
    >>> "#define FHOBS_CALL_DOSTEP" in c_header()
    True
    """
    lines = ["/* Generated by fhobs.fmu.call_rules: the FMI 2.0 and FMI 3.0 co-simulation",
             " * functions allowed in each state, and the refusal messages. Do not edit. */",
             "#ifndef FHOBS_CALL_RULES_H", "#define FHOBS_CALL_RULES_H", ""]
    for bit, state in enumerate(STATES):
        lines.append(f"#define FHOBS_STATE_{state.split()[0].upper()} {bit}")
    lines.append(f"#define FHOBS_N_STATES {len(STATES)}")
    lines.append("static const char *const FHOBS_STATE_NAMES[FHOBS_N_STATES] = {"
                 + ", ".join(f'"{state}"' for state in STATES) + "};")
    lines.append("")
    lines += _c_table("FHOBS", FUNCTIONS, ALLOWED, UNSUPPORTED, STATES, call_problem)
    lines += _c_fmi3()
    lines += [f'#define FHOBS_ACCESS_{name.upper()} "{text}"'
              for name, text in ACCESS_MESSAGES.items()]
    lines += ["", f"#define FHOBS_TIME_TOLERANCE {TIME_TOLERANCE!r}",
              f'#define FHOBS_TIME_MESSAGE "{TIME_MESSAGE}"',
              f"#define FHOBS_ZOH_CONDITION_LIMIT {ZOH_CONDITION_LIMIT!r}",
              f'#define FHOBS_ZOH_MESSAGE "{ZOH_MESSAGE}"',
              f"#define FHOBS_COARSE_STEP_TOLERANCE {COARSE_STEP_TOLERANCE!r}",
              f'#define FHOBS_COARSE_STEP_MESSAGE "{COARSE_STEP_MESSAGE}"', "", "#endif", ""]
    return "\n".join(lines)


def _c_table(prefix: str, functions: tuple[str, ...], allowed: dict[str, frozenset[str]],
             unsupported: dict[str, str], states: tuple[str, ...],
             problem: Callable[[str, str], str]) -> list[str]:
    """The C lines of one version's table: ``<prefix>_CALL_<NAME>`` numbers (the name without
    its ``fmi2`` / ``fmi3``), ``<prefix>_CALL_MASKS`` (bit i: ``states[i]``) and
    ``<prefix>_CALL_MESSAGES`` (one ``%s`` for the state's name where the call is merely out of
    sequence)."""
    lines = [f"#define {prefix}_CALL_{function[4:].upper()} {number}"
             for number, function in enumerate(functions)]
    lines.append(f"#define {prefix}_N_CALLS {len(functions)}")
    masks = [sum(1 << states.index(s) for s in allowed.get(f, ())) for f in functions]
    lines.append(f"static const unsigned {prefix}_CALL_MASKS[{prefix}_N_CALLS] = {{"
                 + ", ".join(str(mask) for mask in masks) + "};")
    messages = [problem(function, states[0]) if function in unsupported
                else f"{function} is not allowed in the state %s (only in "
                     f"{_where(allowed[function], states)})" for function in functions]
    lines.append(f"static const char *const {prefix}_CALL_MESSAGES[{prefix}_N_CALLS] = {{")
    lines += [f'    "{message}",' for message in messages]
    lines += ["};", ""]
    return lines


# -- FMI 3.0 ------------------------------------------------------------------------------------
STATES3 = (*STATES, "event mode")
"""The FMI 3.0 co-simulation states of these FMUs: FMI 2.0's (the same bits) and event mode,
which a host that instantiates with ``eventModeUsed`` enters after initialisation and from step
mode (``fmi3EnterEventMode``) and leaves by ``fmi3EnterStepMode``; the FMU has no events, so
``fmi3UpdateDiscreteStates`` there finds nothing to update."""

TYPES3 = ("Float32", "Float64", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64",
          "UInt64", "Boolean", "String", "Binary")
"""The FMI 3.0 variable types with a get and a set function (clocks aside)."""

FMI2_COUNTERPART: dict[str, str] = {
    "fmi3SetDebugLogging": "fmi2SetDebugLogging",
    "fmi3FreeInstance": "fmi2FreeInstance",
    "fmi3EnterInitializationMode": "fmi2EnterInitializationMode",
    "fmi3ExitInitializationMode": "fmi2ExitInitializationMode",
    "fmi3Terminate": "fmi2Terminate",
    "fmi3Reset": "fmi2Reset",
    **{f"fmi3Get{t}": "fmi2GetReal" for t in TYPES3},
    **{f"fmi3Set{t}": "fmi2SetReal" for t in TYPES3},
    "fmi3GetFMUState": "fmi2GetFMUstate",
    "fmi3SetFMUState": "fmi2SetFMUstate",
    "fmi3FreeFMUState": "fmi2FreeFMUstate",
    "fmi3SerializedFMUStateSize": "fmi2SerializedFMUstateSize",
    "fmi3SerializeFMUState": "fmi2SerializeFMUstate",
    "fmi3DeserializeFMUState": "fmi2DeSerializeFMUstate",
    "fmi3DoStep": "fmi2DoStep",
}
"""The FMI 3.0 functions whose rule is their FMI 2.0 counterpart's."""

_IN_EVENT_MODE = frozenset(f for f in FMI2_COUNTERPART
                           if f not in ("fmi3EnterInitializationMode",
                                        "fmi3ExitInitializationMode", "fmi3DoStep"))
"""Functions of :data:`FMI2_COUNTERPART` also allowed in event mode."""

ALLOWED3: dict[str, frozenset[str]] = {
    **{function: ALLOWED[fmi2] | ({"event mode"} if function in _IN_EVENT_MODE else set())
       for function, fmi2 in FMI2_COUNTERPART.items()},
    "fmi3EnterEventMode": frozenset(("step mode",)),
    "fmi3UpdateDiscreteStates": frozenset(("event mode",)),
    "fmi3EnterStepMode": frozenset(("event mode",)),
}
"""For each FMI 3.0 function taking an instance that the FMUs provide: the states in which it
is allowed (``fmi3EnterEventMode`` only for an instance made with ``eventModeUsed``: the layer
checks that)."""

_NO_CLOCKS = "this FMU has no clocks"
_NO_ME = "this FMU supports co-simulation only (no model exchange)"
_NO_CONFIGURATION = ("this FMU has no structural parameters (its array sizes are fixed when it "
                     "is built)")
UNSUPPORTED3: dict[str, str] = {
    "fmi3GetClock": _NO_CLOCKS,
    "fmi3SetClock": _NO_CLOCKS,
    **{f"fmi3{verb}{what}{form}": _NO_CLOCKS for verb in ("Get", "Set")
       for what in ("Interval", "Shift") for form in ("Decimal", "Fraction")},
    "fmi3EvaluateDiscreteStates": "this FMU has no clocks and no discrete states",
    "fmi3ActivateModelPartition": "this FMU supports co-simulation only (no scheduled "
                                  "execution)",
    "fmi3GetNumberOfVariableDependencies": "this FMU declares its dependencies in its "
                                           "modelDescription only (no outputs depend on inputs)",
    "fmi3GetVariableDependencies": "this FMU declares its dependencies in its modelDescription "
                                   "only (no outputs depend on inputs)",
    "fmi3GetDirectionalDerivative": "this FMU provides no directional derivatives "
                                    "(providesDirectionalDerivatives = false)",
    "fmi3GetAdjointDerivative": "this FMU provides no adjoint derivatives "
                                "(providesAdjointDerivatives = false)",
    "fmi3EnterConfigurationMode": _NO_CONFIGURATION,
    "fmi3ExitConfigurationMode": _NO_CONFIGURATION,
    "fmi3GetOutputDerivatives": "this FMU provides no output derivatives "
                                "(maxOutputDerivativeOrder = 0)",
    **{f"fmi3{name}": _NO_ME for name in (
        "EnterContinuousTimeMode", "CompletedIntegratorStep", "SetTime", "SetContinuousStates",
        "GetContinuousStateDerivatives", "GetEventIndicators", "GetContinuousStates",
        "GetNominalsOfContinuousStates", "GetNumberOfEventIndicators",
        "GetNumberOfContinuousStates")},
}
"""FMI 3.0 functions refused in every state, with the reason."""

FUNCTIONS3 = (*ALLOWED3, *UNSUPPORTED3)
"""Every FMI 3.0 function taking an instance, in the order of ``FHOBS3_CALL_*``."""

EXPORTED3 = ("fmi3GetVersion", "fmi3InstantiateModelExchange", "fmi3InstantiateCoSimulation",
             "fmi3InstantiateScheduledExecution", *FUNCTIONS3)
"""Every function of the FMI 3.0 API (75): those without an instance first."""


def call_problem3(function: str, state: str) -> str:
    """Why the FMI 3.0 ``function`` may not be called in ``state`` of :data:`STATES3` ('' if it
    may).

    Examples
    --------
    >>> call_problem3("fmi3GetFloat64", "event mode")
    ''
    >>> call_problem3("fmi3GetClock", "step mode")
    'fmi3GetClock is not supported: this FMU has no clocks'
    """
    return _problem(function, state, ALLOWED3, UNSUPPORTED3, STATES3)


NVALUES_MESSAGE = ("%s: nValues = %u, but the %u value references asked hold %u values (the "
                   "product of each array's dimensions, summed)")
"""The FMI 3.0 refusal of a get/set whose value array has another size than the variables
asked (function, nValues, the number of value references, the values they hold)."""


def _c_fmi3() -> list[str]:
    """The FMI 3.0 part of :func:`c_header`: ``FHOBS3_STATE_EVENT``, ``FHOBS3_N_STATES``,
    ``FHOBS3_STATE_NAMES``, the table and the nValues refusal."""
    return ["#define FHOBS3_STATE_EVENT " + str(STATES3.index("event mode")),
            f"#define FHOBS3_N_STATES {len(STATES3)}",
            "static const char *const FHOBS3_STATE_NAMES[FHOBS3_N_STATES] = {"
            + ", ".join(f'"{state}"' for state in STATES3) + "};", "",
            *_c_table("FHOBS3", FUNCTIONS3, ALLOWED3, UNSUPPORTED3, STATES3, call_problem3),
            f'#define FHOBS3_NVALUES_MESSAGE "{NVALUES_MESSAGE}"', ""]
