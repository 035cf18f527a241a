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

This module is standard-library only: it runs inside the FMUs and at build time.

Examples
--------
>>> call_problem("fmi2DoStep", "instantiated")
'fmi2DoStep is not allowed in the state instantiated (only in step mode)'
>>> call_problem("fmi2GetReal", "step mode")
''
"""

from __future__ import annotations

import math

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
    if function in UNSUPPORTED:
        return f"{function} is not supported: {UNSUPPORTED[function]}"
    allowed = ALLOWED[function]
    if state in allowed:
        return ""
    where = " or ".join(s for s in STATES if s in allowed)
    return f"{function} is not allowed in the state {state} (only in {where})"


def c_header() -> str:
    """The C header of this table (:data:`HEADER`): ``FHOBS_STATE_*`` bit numbers,
    ``FHOBS_CALL_*`` function numbers, their masks and the refusal messages (with one ``%s``
    for the state's name where the call is merely out of sequence), the get/set refusals
    (``FHOBS_ACCESS_*``, :data:`ACCESS_MESSAGES`), the time check and the ZOH limit.

    Examples
    --------
    >>> "#define FHOBS_CALL_DOSTEP" in c_header()
    True
    """
    lines = ["/* Generated by fhobs.fmu.call_rules: the FMI 2.0 co-simulation functions allowed",
             " * in each state, and the refusal messages. Do not edit. */",
             "#ifndef FHOBS_CALL_RULES_H", "#define FHOBS_CALL_RULES_H", ""]
    for bit, state in enumerate(STATES):
        lines.append(f"#define FHOBS_STATE_{state.split()[0].upper()} {bit}")
    lines.append(f"#define FHOBS_N_STATES {len(STATES)}")
    lines.append("static const char *const FHOBS_STATE_NAMES[FHOBS_N_STATES] = {"
                 + ", ".join(f'"{state}"' for state in STATES) + "};")
    lines.append("")
    for number, function in enumerate(FUNCTIONS):
        lines.append(f"#define FHOBS_CALL_{function[4:].upper()} {number}")
    lines.append(f"#define FHOBS_N_CALLS {len(FUNCTIONS)}")
    masks = [sum(1 << STATES.index(s) for s in ALLOWED.get(f, ())) for f in FUNCTIONS]
    lines.append("static const unsigned FHOBS_CALL_MASKS[FHOBS_N_CALLS] = {"
                 + ", ".join(str(mask) for mask in masks) + "};")
    messages = []
    for function in FUNCTIONS:
        if function in UNSUPPORTED:
            messages.append(call_problem(function, STATES[0]))
        else:
            where = " or ".join(s for s in STATES if s in ALLOWED[function])
            messages.append(f"{function} is not allowed in the state %s (only in {where})")
    lines.append("static const char *const FHOBS_CALL_MESSAGES[FHOBS_N_CALLS] = {")
    lines += [f'    "{message}",' for message in messages]
    lines += ["};", ""]
    lines += [f'#define FHOBS_ACCESS_{name.upper()} "{text}"'
              for name, text in ACCESS_MESSAGES.items()]
    lines += ["", f"#define FHOBS_TIME_TOLERANCE {TIME_TOLERANCE!r}",
              f'#define FHOBS_TIME_MESSAGE "{TIME_MESSAGE}"',
              f"#define FHOBS_ZOH_CONDITION_LIMIT {ZOH_CONDITION_LIMIT!r}",
              f'#define FHOBS_ZOH_MESSAGE "{ZOH_MESSAGE}"', "", "#endif", ""]
    return "\n".join(lines)
