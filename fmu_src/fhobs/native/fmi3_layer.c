/*
 * FMI 3.0 co-simulation interface of a native fhobs FMU: instances, the call sequence (the FMI
 * 3.0 table of fhobs_call_rules.h), typed get/set of array variables, doStep, event mode
 * passed through, FMU states (in memory and serialized). The values, the checks, the step and
 * a state's bytes are instance.c's (shared with the FMI 2.0 layer), the model is model.h's:
 * the FMU behaves as the FMI 2.0 build of the same design, value for value, and warns as it
 * does of the first step longer than max_communication_step (fmi3Warning, the same message).
 *
 * Variables: every array of the kind's declaration is one FMI 3.0 variable with fixed
 * dimensions, row-major; its value reference is the FMI 2.0 value reference of its first
 * element, so FHOBS3_SIZE (fhobs_fmi3.h, generated) gives each value reference's element count
 * (0: not a variable's), and `time` (FHOBS3_TIME_VR) is the independent variable. Real
 * variables are Float64, Integer ones Int32; there are no Boolean, String, Binary or clock
 * variables.
 *
 * A caller mistake is fmi3Error with a log message, the instance unchanged and usable (never
 * fmi3Fatal): a call out of sequence, an unknown value reference, another type, nValues not the
 * number of values the value references hold, a NULL argument, a write to an output, to
 * `status`, to `time`, to a parameter after initialisation or of another value than the
 * compiled one. Functions these FMUs do not provide (clocks, model exchange, scheduled
 * execution, configuration mode, derivatives) are fmi3Error with the reason. The Int32
 * variable `status` holds the status of the last call (0 ok, 3 error). Only the fmi3 functions
 * are exported.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fhobs_call_rules.h"
#include "fhobs_fmi3.h"
#include "fmi3Functions.h"
#include "instance.h"
#include "model.h"

#define INSTANCE_MAGIC 0x66683369u /* "fh3i" */
#define FIXED_MESSAGE                                                                          \
    "%s: %s (value reference %u) is a fixed parameter: it can be set only before "          \
    "fmi3ExitInitializationMode (the instance is in %s; fmi3Reset returns to the start values)"

enum {
    INSTANTIATED = FHOBS_STATE_INSTANTIATED,
    INITIALISATION = FHOBS_STATE_INITIALISATION,
    STEP_MODE = FHOBS_STATE_STEP,
    TERMINATED = FHOBS_STATE_TERMINATED,
    EVENT_MODE = FHOBS3_STATE_EVENT
};

typedef struct {
    uint32_t magic;
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback logger;
    int event_mode_used;
    Core core;
} Instance;

/* -- messages and calls ------------------------------------------------------------------------ */

static void log_message(const Instance *c, fmi3Status status, const char *category,
                        const char *message)
{
    if (c->logger)
        c->logger(c->environment, status, category, message);
}

/* A call's end: its status into `status`, a message logged unless the call was fine. */
static fmi3Status report(Instance *c, int status, const char *message)
{
    c->core.values.integer[VR_STATUS] = status;
    if (status == FHOBS_STATUS_WARNING)
        log_message(c, fmi3Warning, "logStatusWarning", message);
    else if (status != FHOBS_STATUS_OK)
        log_message(c, fmi3Error, "logStatusError", message);
    return (fmi3Status)status;
}

static fmi3Status ok(Instance *c)
{
    return report(c, FHOBS_STATUS_OK, NULL);
}

static fmi3Status fail(Instance *c, const char *message)
{
    return report(c, FHOBS_STATUS_ERROR, message);
}

/* `size` bytes, zeroed (instance.h's Allocate; FMI 3.0 has no host allocator). */
static void *zeroed(void *context, size_t size)
{
    (void)context;
    return calloc(1, size);
}

/* The instance behind a pointer, or NULL when it is not one of this FMU's. */
static Instance *instance(fmi3Instance pointer)
{
    Instance *c = pointer;
    return c && c->magic == INSTANCE_MAGIC ? c : NULL;
}

/* Whether `call` (FHOBS3_CALL_*) is refused in the instance's state, the message then logged;
 * functions these FMUs do not provide are refused in every state. */
static int refused(Instance *c, int call)
{
    char msg[FHOBS_MESSAGE_SIZE];
    int mode = c->core.values.mode;
    if (FHOBS3_CALL_MASKS[call] >> mode & 1u)
        return 0;
    snprintf(msg, sizeof msg, FHOBS3_CALL_MESSAGES[call], FHOBS3_STATE_NAMES[mode]);
    fail(c, msg);
    return 1;
}

#define INSTANCE_OR_ERROR(pointer)                                                             \
    Instance *c = instance(pointer);                                                           \
    if (!c)                                                                                    \
        return fmi3Error;

#define CHECK_CALL(pointer, call)                                                              \
    INSTANCE_OR_ERROR(pointer)                                                                 \
    if (refused(c, call))                                                                      \
        return fmi3Error;

/* A function these FMUs do not provide: fmi3Error with the call rules' reason. */
static fmi3Status unsupported(fmi3Instance pointer, int call)
{
    INSTANCE_OR_ERROR(pointer);
    refused(c, call); /* allowed in no state: refused with its reason */
    return fmi3Error;
}

/* -- instances --------------------------------------------------------------------------------- */

const char *fmi3GetVersion(void)
{
    return fmi3Version;
}

static fmi3Instance other_interface(fmi3InstanceEnvironment environment,
                                    fmi3LogMessageCallback logger, const char *function)
{
    char msg[FHOBS_MESSAGE_SIZE];
    snprintf(msg, sizeof msg, "%s: this FMU supports co-simulation only "
             "(fmi3InstantiateCoSimulation)", function);
    if (logger)
        logger(environment, fmi3Error, "logStatusError", msg);
    return NULL;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName,
                                          fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    return other_interface(instanceEnvironment, logMessage, "fmi3InstantiateModelExchange");
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    return other_interface(instanceEnvironment, logMessage,
                           "fmi3InstantiateScheduledExecution");
}

/* eventModeUsed: the host enters event mode after the initialisation and may from step mode;
 * earlyReturnAllowed is accepted (the FMU never returns early); intermediate updates are not
 * made (providesIntermediateUpdate = false). */
fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate)
{
    (void)instanceName;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    Instance probe = {.environment = instanceEnvironment, .logger = logMessage};
    if (nRequiredIntermediateVariables) {
        log_message(&probe, fmi3Error, "logStatusError",
                    "fmi3InstantiateCoSimulation: this FMU has no intermediate variables "
                    "(providesIntermediateUpdate = false)");
        return NULL;
    }
    if (!instantiationToken || strcmp(instantiationToken, FHOBS_IDENTITY) != 0) {
        log_message(&probe, fmi3Error, "logStatusError",
                    "fmi3InstantiateCoSimulation: the instantiationToken is not this FMU's "
                    "(modelDescription.xml and binary of different builds)");
        return NULL;
    }
    Instance *c = calloc(1, sizeof(Instance));
    if (!c)
        return NULL;
    c->core.work = calloc(1, model_work_size());
    if (!c->core.work) {
        free(c);
        return NULL;
    }
    c->magic = INSTANCE_MAGIC;
    c->environment = instanceEnvironment;
    c->logger = logMessage;
    c->event_mode_used = eventModeUsed ? 1 : 0;
    instance_reset(&c->core);
    return c;
}

void fmi3FreeInstance(fmi3Instance pointer)
{
    Instance *c = instance(pointer);
    if (!c)
        return;
    c->magic = 0;
    free(c->core.work);
    free(c);
}

fmi3Status fmi3SetDebugLogging(fmi3Instance pointer, fmi3Boolean loggingOn,
                               size_t nCategories, const fmi3String categories[])
{
    (void)loggingOn;
    (void)nCategories;
    (void)categories;
    CHECK_CALL(pointer, FHOBS3_CALL_SETDEBUGLOGGING);
    return ok(c); /* errors are always logged; there are no other messages */
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance pointer, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    char msg[FHOBS_MESSAGE_SIZE], a[32], b[32];
    CHECK_CALL(pointer, FHOBS3_CALL_ENTERINITIALIZATIONMODE);
    if (isfinite(startTime) && stopTimeDefined && !(stopTime >= startTime)) {
        snprintf(msg, sizeof msg, "fmi3EnterInitializationMode: stopTime %s is not a time at "
                 "or after startTime %s", fhobs_number(stopTime, a, sizeof a),
                 fhobs_number(startTime, b, sizeof b));
        return fail(c, msg);
    }
    if (instance_set_start_time(&c->core, startTime, "fmi3EnterInitializationMode", msg,
                                sizeof msg))
        return fail(c, msg);
    c->core.values.mode = INITIALISATION;
    return ok(c);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance pointer)
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(pointer, FHOBS3_CALL_EXITINITIALIZATIONMODE);
    if (instance_exit_initialisation(&c->core, c->event_mode_used ? EVENT_MODE : STEP_MODE, msg,
                                     sizeof msg))
        return fail(c, msg);
    return ok(c);
}

fmi3Status fmi3EnterEventMode(fmi3Instance pointer)
{
    CHECK_CALL(pointer, FHOBS3_CALL_ENTEREVENTMODE);
    if (!c->event_mode_used)
        return fail(c, "fmi3EnterEventMode: the instance was made with eventModeUsed = false");
    c->core.values.mode = EVENT_MODE;
    return ok(c);
}

/* Event mode: the FMU has no events, so nothing to update and no next event. */
fmi3Status fmi3UpdateDiscreteStates(fmi3Instance pointer, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime)
{
    CHECK_CALL(pointer, FHOBS3_CALL_UPDATEDISCRETESTATES);
    if (!discreteStatesNeedUpdate || !terminateSimulation ||
        !nominalsOfContinuousStatesChanged || !valuesOfContinuousStatesChanged ||
        !nextEventTimeDefined || !nextEventTime)
        return fail(c, "fmi3UpdateDiscreteStates: NULL output argument");
    *discreteStatesNeedUpdate = fmi3False;
    *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = fmi3False;
    *valuesOfContinuousStatesChanged = fmi3False;
    *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    return ok(c);
}

fmi3Status fmi3EnterStepMode(fmi3Instance pointer)
{
    CHECK_CALL(pointer, FHOBS3_CALL_ENTERSTEPMODE);
    c->core.values.mode = STEP_MODE;
    return ok(c);
}

fmi3Status fmi3Terminate(fmi3Instance pointer)
{
    CHECK_CALL(pointer, FHOBS3_CALL_TERMINATE);
    c->core.values.mode = TERMINATED;
    return ok(c);
}

fmi3Status fmi3Reset(fmi3Instance pointer)
{
    CHECK_CALL(pointer, FHOBS3_CALL_RESET);
    instance_reset(&c->core);
    return ok(c);
}

/* -- get and set ------------------------------------------------------------------------------- */

static const char *type_name(int type)
{
    return type == FHOBS_REAL ? "Float64" : "Int32";
}

/* The name of the variable whose value reference is vr (its first element's name up to '['). */
static int name_length(unsigned vr)
{
    return (int)strcspn(VARIABLES[vr].name, "[");
}

/* Why `function` (of the FMI 3.0 type `type`: "Float64", "Int32", "Boolean"...) may not access
 * the variables vr[0..nvr) with nValues values now (`write`: a set of the doubles `values`,
 * NULL for another type): 1 and the message, or 0. */
static int access_problem(const Instance *c, const char *function, const char *type,
                          const fmi3ValueReference vr[], size_t nvr, size_t nValues, int write,
                          const double *values, const void *buffer, char *msg, size_t len)
{
    if (nvr && (!vr || !buffer)) {
        snprintf(msg, len, "%s: NULL value reference or value array", function);
        return 1;
    }
    size_t held = 0;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] == FHOBS3_TIME_VR) {
            if (strcmp(type, "Float64")) {
                snprintf(msg, len, "%s: time (value reference %u) is of type Float64, not %s",
                         function, (unsigned)vr[i], type);
                return 1;
            }
            if (write) {
                snprintf(msg, len, "%s: time (value reference %u) is the independent variable: "
                         "the FMU keeps it, it cannot be set", function, (unsigned)vr[i]);
                return 1;
            }
            held += 1;
            continue;
        }
        if (vr[i] >= FHOBS_N_VARIABLES || !FHOBS3_SIZE[vr[i]]) {
            snprintf(msg, len, "%s: value reference %u is not a variable of this FMU (see its "
                     "modelDescription.xml: an array's value reference is that of its first "
                     "element)", function, (unsigned)vr[i]);
            return 1;
        }
        if (strcmp(type, type_name(VARIABLES[vr[i]].type))) {
            snprintf(msg, len, "%s: %.*s (value reference %u) is of type %s, not %s", function,
                     name_length(vr[i]), VARIABLES[vr[i]].name, (unsigned)vr[i],
                     type_name(VARIABLES[vr[i]].type), type);
            return 1;
        }
        held += FHOBS3_SIZE[vr[i]];
    }
    if (held != nValues) {
        snprintf(msg, len, FHOBS3_NVALUES_MESSAGE, function, (unsigned)nValues, (unsigned)nvr,
                 (unsigned)held);
        return 1;
    }
    if (!write)
        return 0;
    int fixed = c->core.values.mode != INSTANTIATED && c->core.values.mode != INITIALISATION;
    size_t k = 0;
    for (size_t i = 0; i < nvr; i++) {
        for (unsigned j = 0; j < FHOBS3_SIZE[vr[i]]; j++, k++) {
            if (instance_write_problem(vr[i] + j, values ? values[k] : 0.0, fixed, function,
                                       FIXED_MESSAGE, FHOBS3_STATE_NAMES[c->core.values.mode], msg,
                                       len))
                return 1;
        }
    }
    return 0;
}

fmi3Status fmi3GetFloat64(fmi3Instance pointer, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues)
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(pointer, FHOBS3_CALL_GETFLOAT64);
    if (access_problem(c, "fmi3GetFloat64", "Float64", vr, nvr, nValues, 0, NULL, values, msg,
                       sizeof msg))
        return fail(c, msg);
    size_t k = 0;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] == FHOBS3_TIME_VR) {
            values[k++] = c->core.values.time;
            continue;
        }
        memcpy(values + k, c->core.values.real + vr[i], sizeof(double) * FHOBS3_SIZE[vr[i]]);
        k += FHOBS3_SIZE[vr[i]];
    }
    return ok(c);
}

fmi3Status fmi3SetFloat64(fmi3Instance pointer, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues)
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(pointer, FHOBS3_CALL_SETFLOAT64);
    if (access_problem(c, "fmi3SetFloat64", "Float64", vr, nvr, nValues, 1, values, values, msg,
                       sizeof msg))
        return fail(c, msg);
    size_t k = 0;
    for (size_t i = 0; i < nvr; i++) {
        memcpy(c->core.values.real + vr[i], values + k, sizeof(double) * FHOBS3_SIZE[vr[i]]);
        k += FHOBS3_SIZE[vr[i]];
    }
    return ok(c);
}

fmi3Status fmi3GetInt32(fmi3Instance pointer, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Int32 values[], size_t nValues)
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(pointer, FHOBS3_CALL_GETINT32);
    if (access_problem(c, "fmi3GetInt32", "Int32", vr, nvr, nValues, 0, NULL, values, msg,
                       sizeof msg))
        return fail(c, msg);
    int status = c->core.values.integer[VR_STATUS];
    ok(c);
    size_t k = 0; /* `status`: the status of the call before this one */
    for (size_t i = 0; i < nvr; i++)
        for (unsigned j = 0; j < FHOBS3_SIZE[vr[i]]; j++)
            values[k++] = vr[i] + j == VR_STATUS ? status : c->core.values.integer[vr[i] + j];
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance pointer, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Int32 values[], size_t nValues)
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(pointer, FHOBS3_CALL_SETINT32);
    if (access_problem(c, "fmi3SetInt32", "Int32", vr, nvr, nValues, 1, NULL, values, msg,
                       sizeof msg))
        return fail(c, msg);
    size_t k = 0;
    for (size_t i = 0; i < nvr; i++)
        for (unsigned j = 0; j < FHOBS3_SIZE[vr[i]]; j++)
            c->core.values.integer[vr[i] + j] = values[k++];
    return ok(c);
}

/* A type these FMUs have no variable of: any value reference is unknown or of another type. */
static fmi3Status no_variables_of_type(fmi3Instance pointer, int call, const char *function,
                                       const char *type, const fmi3ValueReference vr[],
                                       size_t nvr, const void *values, size_t nValues)
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(pointer, call);
    if (access_problem(c, function, type, vr, nvr, nValues, 0, NULL, values, msg, sizeof msg))
        return fail(c, msg);
    return ok(c);
}

#define NO_VARIABLES(TYPE, CTYPE, CALLNAME)                                                    \
    fmi3Status fmi3Get##TYPE(fmi3Instance pointer, const fmi3ValueReference vr[], size_t nvr,  \
                             CTYPE values[], size_t nValues)                                   \
    {                                                                                          \
        return no_variables_of_type(pointer, FHOBS3_CALL_GET##CALLNAME, "fmi3Get" #TYPE, #TYPE, \
                                    vr, nvr, values, nValues);                                 \
    }                                                                                          \
    fmi3Status fmi3Set##TYPE(fmi3Instance pointer, const fmi3ValueReference vr[], size_t nvr,  \
                             const CTYPE values[], size_t nValues)                             \
    {                                                                                          \
        return no_variables_of_type(pointer, FHOBS3_CALL_SET##CALLNAME, "fmi3Set" #TYPE, #TYPE, \
                                    vr, nvr, values, nValues);                                 \
    }

NO_VARIABLES(Float32, fmi3Float32, FLOAT32)
NO_VARIABLES(Int8, fmi3Int8, INT8)
NO_VARIABLES(UInt8, fmi3UInt8, UINT8)
NO_VARIABLES(Int16, fmi3Int16, INT16)
NO_VARIABLES(UInt16, fmi3UInt16, UINT16)
NO_VARIABLES(UInt32, fmi3UInt32, UINT32)
NO_VARIABLES(Int64, fmi3Int64, INT64)
NO_VARIABLES(UInt64, fmi3UInt64, UINT64)
NO_VARIABLES(Boolean, fmi3Boolean, BOOLEAN)
NO_VARIABLES(String, fmi3String, STRING)

fmi3Status fmi3GetBinary(fmi3Instance pointer, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues)
{
    (void)valueSizes;
    return no_variables_of_type(pointer, FHOBS3_CALL_GETBINARY, "fmi3GetBinary", "Binary", vr,
                                nvr, values, nValues);
}

fmi3Status fmi3SetBinary(fmi3Instance pointer, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
{
    (void)valueSizes;
    return no_variables_of_type(pointer, FHOBS3_CALL_SETBINARY, "fmi3SetBinary", "Binary", vr,
                                nvr, values, nValues);
}

/* -- stepping ---------------------------------------------------------------------------------- */

/* The FMU has no events and never returns early: eventHandlingNeeded, terminateSimulation and
 * earlyReturn are false, lastSuccessfulTime the end of the step (of a refused step: the time
 * before it). The first step longer than max_communication_step is made and answered with
 * fmi3Warning. */
fmi3Status fmi3DoStep(fmi3Instance pointer, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(pointer, FHOBS3_CALL_DOSTEP);
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime)
        return fail(c, "fmi3DoStep: NULL output argument");
    *eventHandlingNeeded = *terminateSimulation = *earlyReturn = fmi3False;
    int status = instance_do_step(&c->core, currentCommunicationPoint, communicationStepSize,
                                  msg, sizeof msg);
    *lastSuccessfulTime = c->core.values.time;
    return report(c, status, msg);
}

/* -- FMU states -------------------------------------------------------------------------------- */

/* Why `v` is not a state this instance can take (1, message) or 0. */
static int state_problem(const Instance *c, const Values *v, char *msg, size_t len)
{
    if (v->mode < 0 || v->mode >= FHOBS3_N_STATES) {
        snprintf(msg, len, "unknown FMI state %d", v->mode);
        return 1;
    }
    if (v->mode == EVENT_MODE && !c->event_mode_used) {
        snprintf(msg, len, "it is in event mode, and this instance was made with eventModeUsed "
                 "= false");
        return 1;
    }
    int initialised = v->mode == STEP_MODE || v->mode == TERMINATED || v->mode == EVENT_MODE;
    return instance_values_problem(v, initialised, msg, len);
}

/* A snapshot of `values` into *state (a new one when *state is NULL). */
static fmi3Status store(Instance *c, const Values *values, fmi3FMUState *state,
                        const char *function)
{
    char msg[FHOBS_MESSAGE_SIZE];
    if (instance_store(state, values, zeroed, NULL, function, msg, sizeof msg))
        return fail(c, msg);
    return ok(c);
}

fmi3Status fmi3GetFMUState(fmi3Instance pointer, fmi3FMUState *state)
{
    CHECK_CALL(pointer, FHOBS3_CALL_GETFMUSTATE);
    if (!state)
        return fail(c, "fmi3GetFMUState: NULL state pointer");
    return store(c, &c->core.values, state, "fmi3GetFMUState");
}

fmi3Status fmi3SetFMUState(fmi3Instance pointer, fmi3FMUState state)
{
    char msg[FHOBS_MESSAGE_SIZE], reason[FHOBS_MESSAGE_SIZE - 64];
    CHECK_CALL(pointer, FHOBS3_CALL_SETFMUSTATE);
    const Values *values = instance_snapshot(state);
    if (!values)
        return fail(c, "fmi3SetFMUState rejected the state: not an FMU state of this FMU");
    if (state_problem(c, values, reason, sizeof reason)) {
        snprintf(msg, sizeof msg, "fmi3SetFMUState rejected the state: %s", reason);
        return fail(c, msg);
    }
    instance_take(&c->core, values);
    return ok(c);
}

fmi3Status fmi3FreeFMUState(fmi3Instance pointer, fmi3FMUState *state)
{
    CHECK_CALL(pointer, FHOBS3_CALL_FREEFMUSTATE);
    if (!state || !*state)
        return ok(c);
    if (!instance_snapshot(*state))
        return fail(c, "fmi3FreeFMUState: not an FMU state of this FMU");
    instance_forget(*state);
    free(*state);
    *state = NULL;
    return ok(c);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance pointer, fmi3FMUState state, size_t *size)
{
    CHECK_CALL(pointer, FHOBS3_CALL_SERIALIZEDFMUSTATESIZE);
    if (!instance_snapshot(state) || !size)
        return fail(c, "fmi3SerializedFMUStateSize: not an FMU state of this FMU");
    *size = instance_serialized_size();
    return ok(c);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance pointer, fmi3FMUState state,
                                 fmi3Byte serializedState[], size_t size)
{
    CHECK_CALL(pointer, FHOBS3_CALL_SERIALIZEFMUSTATE);
    const Values *values = instance_snapshot(state);
    if (!values || !serializedState || size != instance_serialized_size())
        return fail(c, "fmi3SerializeFMUState: not an FMU state of this FMU, or a buffer of "
                       "another size than fmi3SerializedFMUStateSize's");
    instance_serialize(values, serializedState);
    return ok(c);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance pointer, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *state)
{
    char msg[FHOBS_MESSAGE_SIZE], reason[FHOBS_MESSAGE_SIZE - 64];
    CHECK_CALL(pointer, FHOBS3_CALL_DESERIALIZEFMUSTATE);
    Values values;
    if (!state)
        return fail(c, "fmi3DeserializeFMUState: NULL state pointer");
    if (instance_deserialize(serializedState, size, &values, reason, sizeof reason) ||
        state_problem(c, &values, reason, sizeof reason)) {
        snprintf(msg, sizeof msg, "fmi3DeserializeFMUState rejected the bytes: %s", reason);
        return fail(c, msg);
    }
    return store(c, &values, state, "fmi3DeserializeFMUState");
}

/* -- what these FMUs do not provide ------------------------------------------------------------ */

fmi3Status fmi3GetClock(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[])
{
    (void)vr, (void)nvr, (void)values;
    return unsupported(p, FHOBS3_CALL_GETCLOCK);
}

fmi3Status fmi3SetClock(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[])
{
    (void)vr, (void)nvr, (void)values;
    return unsupported(p, FHOBS3_CALL_SETCLOCK);
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
{
    (void)vr, (void)nvr, (void)intervals, (void)qualifiers;
    return unsupported(p, FHOBS3_CALL_GETINTERVALDECIMAL);
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[])
{
    (void)vr, (void)nvr, (void)counters, (void)resolutions, (void)qualifiers;
    return unsupported(p, FHOBS3_CALL_GETINTERVALFRACTION);
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                               fmi3Float64 shifts[])
{
    (void)vr, (void)nvr, (void)shifts;
    return unsupported(p, FHOBS3_CALL_GETSHIFTDECIMAL);
}

fmi3Status fmi3GetShiftFraction(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[])
{
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    return unsupported(p, FHOBS3_CALL_GETSHIFTFRACTION);
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[])
{
    (void)vr, (void)nvr, (void)intervals;
    return unsupported(p, FHOBS3_CALL_SETINTERVALDECIMAL);
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    return unsupported(p, FHOBS3_CALL_SETINTERVALFRACTION);
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[])
{
    (void)vr, (void)nvr, (void)shifts;
    return unsupported(p, FHOBS3_CALL_SETSHIFTDECIMAL);
}

fmi3Status fmi3SetShiftFraction(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    return unsupported(p, FHOBS3_CALL_SETSHIFTFRACTION);
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance p)
{
    return unsupported(p, FHOBS3_CALL_EVALUATEDISCRETESTATES);
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance p, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime)
{
    (void)clockReference, (void)activationTime;
    return unsupported(p, FHOBS3_CALL_ACTIVATEMODELPARTITION);
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance p, fmi3ValueReference vr,
                                               size_t *nDependencies)
{
    (void)vr, (void)nDependencies;
    return unsupported(p, FHOBS3_CALL_GETNUMBEROFVARIABLEDEPENDENCIES);
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance p, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies)
{
    (void)dependent, (void)elementIndicesOfDependent, (void)independents;
    (void)elementIndicesOfIndependents, (void)dependencyKinds, (void)nDependencies;
    return unsupported(p, FHOBS3_CALL_GETVARIABLEDEPENDENCIES);
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance p, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns, (void)nUnknowns, (void)knowns, (void)nKnowns, (void)seed, (void)nSeed;
    (void)sensitivity, (void)nSensitivity;
    return unsupported(p, FHOBS3_CALL_GETDIRECTIONALDERIVATIVE);
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance p, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns, (void)nUnknowns, (void)knowns, (void)nKnowns, (void)seed, (void)nSeed;
    (void)sensitivity, (void)nSensitivity;
    return unsupported(p, FHOBS3_CALL_GETADJOINTDERIVATIVE);
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance p)
{
    return unsupported(p, FHOBS3_CALL_ENTERCONFIGURATIONMODE);
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance p)
{
    return unsupported(p, FHOBS3_CALL_EXITCONFIGURATIONMODE);
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance p, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues)
{
    (void)vr, (void)nvr, (void)orders, (void)values, (void)nValues;
    return unsupported(p, FHOBS3_CALL_GETOUTPUTDERIVATIVES);
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance p)
{
    return unsupported(p, FHOBS3_CALL_ENTERCONTINUOUSTIMEMODE);
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance p,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint, (void)enterEventMode, (void)terminateSimulation;
    return unsupported(p, FHOBS3_CALL_COMPLETEDINTEGRATORSTEP);
}

fmi3Status fmi3SetTime(fmi3Instance p, fmi3Float64 time)
{
    (void)time;
    return unsupported(p, FHOBS3_CALL_SETTIME);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance p, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates)
{
    (void)continuousStates, (void)nContinuousStates;
    return unsupported(p, FHOBS3_CALL_SETCONTINUOUSSTATES);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance p, fmi3Float64 derivatives[],
                                             size_t nContinuousStates)
{
    (void)derivatives, (void)nContinuousStates;
    return unsupported(p, FHOBS3_CALL_GETCONTINUOUSSTATEDERIVATIVES);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance p, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators)
{
    (void)eventIndicators, (void)nEventIndicators;
    return unsupported(p, FHOBS3_CALL_GETEVENTINDICATORS);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance p, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates)
{
    (void)continuousStates, (void)nContinuousStates;
    return unsupported(p, FHOBS3_CALL_GETCONTINUOUSSTATES);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance p, fmi3Float64 nominals[],
                                             size_t nContinuousStates)
{
    (void)nominals, (void)nContinuousStates;
    return unsupported(p, FHOBS3_CALL_GETNOMINALSOFCONTINUOUSSTATES);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance p, size_t *nEventIndicators)
{
    (void)nEventIndicators;
    return unsupported(p, FHOBS3_CALL_GETNUMBEROFEVENTINDICATORS);
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance p, size_t *nContinuousStates)
{
    (void)nContinuousStates;
    return unsupported(p, FHOBS3_CALL_GETNUMBEROFCONTINUOUSSTATES);
}
