/*
 * FMI 2.0 co-simulation interface of a native fhobs FMU: instances, the call sequence, the
 * get/set rules, doStep with its checks, FMU states (in memory and serialized).
 *
 * It behaves as the pythonfmu FMUs with the status wrapper (fmu/slave_base.py): a caller
 * mistake is answered with fmi2Error and a log message, the instance unchanged and usable
 * (never fmi2Fatal); the Integer variable `status` holds the status of the last call (0 ok,
 * 3 error). Rules:
 *   - fmi2EnterInitializationMode once after fmi2Instantiate (or fmi2Reset), then
 *     fmi2ExitInitializationMode, which checks the parameters and sets the initial state;
 *     fmi2DoStep between it and fmi2Terminate;
 *   - unknown value references, variables of another type, writes to outputs and `status`,
 *     and writes to parameters after fmi2ExitInitializationMode are refused; a parameter
 *     compiled into the binary (the design) accepts only its built value, bit for bit;
 *   - doStep refuses a step size that is not positive and finite or not one of the built
 *     ones, and inputs that are not finite or exceed input_bound;
 *   - an FMU state (in memory or serialized) carries the FMU's identity (its GUID) and the
 *     last successful time, and is checked completely before any of it is used (every field
 *     of the model state that is a count or an index: a whole number in its range);
 *   - doStep refuses a step whose exact ZOH has no correct digit (step * ||A||_1 > 1e9);
 *   - the first step of an instance longer than its max_communication_step (the observers)
 *     is carried out and answered with fmi2Warning and the call rules' message.
 * Every instance owns all its data (no globals but constant ones): many instances of one or
 * several native FMUs run in one process. The values, the checks, the step, the coarse-step
 * warning and FMU states are instance.c's (shared with the FMI 3.0 layer), the model
 * (family_<family>.c, the generated model_data.c) is model.h's; the fmi2 functions are the only symbols
 * the library exports.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fhobs_call_rules.h"
#include "fmi2Functions.h"
#include "instance.h"
#include "model.h"

#define INSTANCE_MAGIC 0x6668696eu /* "fhin" */

/* the FMI states, numbered as in fhobs.fmu.call_rules.STATES */
enum {
    INSTANTIATED = FHOBS_STATE_INSTANTIATED,
    INITIALISATION = FHOBS_STATE_INITIALISATION,
    STEP_MODE = FHOBS_STATE_STEP,
    TERMINATED = FHOBS_STATE_TERMINATED
};
static const char *const TYPE_NAMES[] = {"Real", "Integer", "Boolean", "String"};
#define TYPE_BOOLEAN 2
#define TYPE_STRING 3

typedef struct {
    uint32_t magic;
    fmi2CallbackFunctions callbacks;
    char *name;
    Core core;
} Instance;

/* -- memory and messages ------------------------------------------------------------------ */

/* `size` bytes, zeroed, from the host's allocator of `callbacks` (instance.h's Allocate). */
static void *allocate(void *callbacks, size_t size)
{
    const fmi2CallbackFunctions *f = callbacks;
    return f->allocateMemory ? f->allocateMemory(1, size) : calloc(1, size);
}

static void release(const fmi2CallbackFunctions *f, void *p)
{
    if (!p)
        return;
    if (f->freeMemory)
        f->freeMemory(p);
    else
        free(p);
}

static void log_message(const Instance *c, fmi2Status status, const char *category,
                        const char *message)
{
    if (c->callbacks.logger)
        c->callbacks.logger(c->callbacks.componentEnvironment, c->name, status, category,
                            message);
}

/* A call's end: its status into `status`, a message logged unless the call was fine. */
static fmi2Status report(Instance *c, int status, const char *message)
{
    c->core.values.integer[VR_STATUS] = status;
    if (status == FHOBS_STATUS_WARNING)
        log_message(c, fmi2Warning, "logStatusWarning", message);
    else if (status != FHOBS_STATUS_OK)
        log_message(c, fmi2Error, "logStatusError", message);
    return (fmi2Status)status;
}

static fmi2Status ok(Instance *c)
{
    return report(c, FHOBS_STATUS_OK, NULL);
}

static fmi2Status fail(Instance *c, const char *message)
{
    return report(c, FHOBS_STATUS_ERROR, message);
}

/* The instance behind a component, or NULL when it is not one of this FMU's. */
static Instance *instance(fmi2Component component)
{
    Instance *c = component;
    return c && c->magic == INSTANCE_MAGIC ? c : NULL;
}

#define INSTANCE_OR_ERROR(component)                                                           \
    Instance *c = instance(component);                                                         \
    if (!c)                                                                                    \
        return fmi2Error;

/* Whether `call` (FHOBS_CALL_*) is refused in the instance's state (fhobs.fmu.call_rules), the
 * message then logged; functions these FMUs do not provide are refused in every state. */
static int refused(Instance *c, int call)
{
    char msg[FHOBS_MESSAGE_SIZE];
    int mode = c->core.values.mode;
    if (FHOBS_CALL_MASKS[call] >> mode & 1u)
        return 0;
    snprintf(msg, sizeof msg, FHOBS_CALL_MESSAGES[call], FHOBS_STATE_NAMES[mode]);
    fail(c, msg);
    return 1;
}

/* The start of every function of an instance: a component that is not one, or a call out of
 * sequence, is fmi2Error. */
#define CHECK_CALL(component, call)                                                            \
    INSTANCE_OR_ERROR(component)                                                               \
    if (refused(c, call))                                                                      \
        return fmi2Error;

/* Why `v` is not a state of this FMU an instance can take (1, message) or 0: a known FMI
 * state, then instance_values_problem. */
static int values_problem(const Values *v, char *msg, size_t len)
{
    if (v->mode < 0 || v->mode >= FHOBS_N_STATES) {
        snprintf(msg, len, "unknown FMI state %d", v->mode);
        return 1;
    }
    return instance_values_problem(v, v->mode == STEP_MODE || v->mode == TERMINATED, msg, len);
}

/* -- instances ----------------------------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void)
{
    return fmi2TypesPlatform;
}

const char *fmi2GetVersion(void)
{
    return fmi2Version;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    (void)fmuResourceLocation;
    (void)visible;
    (void)loggingOn;
    if (!functions)
        return NULL;
    Instance probe = {.callbacks = *functions, .name = (char *)(instanceName ? instanceName : "")};
    if (fmuType != fmi2CoSimulation) {
        log_message(&probe, fmi2Error, "logStatusError",
                    "fmi2Instantiate: this FMU supports co-simulation only");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, FHOBS_IDENTITY) != 0) {
        log_message(&probe, fmi2Error, "logStatusError",
                    "fmi2Instantiate: the GUID is not this FMU's (modelDescription.xml and "
                    "binary of different builds)");
        return NULL;
    }
    Instance *c = allocate((void *)functions, sizeof(Instance));
    if (!c)
        return NULL;
    memset(c, 0, sizeof *c);
    c->callbacks = *functions;
    size_t length = strlen(probe.name) + 1;
    c->name = allocate((void *)functions, length);
    if (!c->name) {
        release(functions, c);
        return NULL;
    }
    memcpy(c->name, probe.name, length);
    c->core.work = allocate((void *)functions, model_work_size());
    if (!c->core.work) {
        release(functions, c->name);
        release(functions, c);
        return NULL;
    }
    memset(c->core.work, 0, model_work_size());
    c->magic = INSTANCE_MAGIC;
    instance_reset(&c->core);
    return c;
}

void fmi2FreeInstance(fmi2Component component)
{
    Instance *c = instance(component);
    if (!c)
        return;
    fmi2CallbackFunctions callbacks = c->callbacks;
    c->magic = 0;
    release(&callbacks, c->core.work);
    release(&callbacks, c->name);
    release(&callbacks, c);
}

fmi2Status fmi2SetDebugLogging(fmi2Component component, fmi2Boolean loggingOn,
                               size_t nCategories, const fmi2String categories[])
{
    (void)loggingOn;
    (void)nCategories;
    (void)categories;
    CHECK_CALL(component, FHOBS_CALL_SETDEBUGLOGGING);
    return ok(c); /* errors are always logged; there are no other messages */
}

fmi2Status fmi2SetupExperiment(fmi2Component component, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_SETUPEXPERIMENT);
    if (instance_set_start_time(&c->core, startTime, "fmi2SetupExperiment", msg, sizeof msg))
        return fail(c, msg);
    return ok(c);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component component)
{
    CHECK_CALL(component, FHOBS_CALL_ENTERINITIALIZATIONMODE);
    c->core.values.mode = INITIALISATION;
    return ok(c);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component component)
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_EXITINITIALIZATIONMODE);
    if (instance_exit_initialisation(&c->core, STEP_MODE, msg, sizeof msg))
        return fail(c, msg);
    return ok(c);
}

fmi2Status fmi2Terminate(fmi2Component component)
{
    CHECK_CALL(component, FHOBS_CALL_TERMINATE);
    c->core.values.mode = TERMINATED;
    return ok(c);
}

fmi2Status fmi2Reset(fmi2Component component)
{
    CHECK_CALL(component, FHOBS_CALL_RESET);
    instance_reset(&c->core);
    return ok(c);
}

/* -- get and set ----------------------------------------------------------------------------- */

/* Why `function` may not access `vr` (type `type`; `write`: a set of `values`) now: 1 and
 * the message, or 0. */
static int access_problem(const Instance *c, const char *function, const fmi2ValueReference vr[],
                          size_t nvr, int type, int write, const double *values, char *msg,
                          size_t len)
{
    if (nvr && (!vr || !values)) {
        snprintf(msg, len, "%s: NULL value reference or value array", function);
        return 1;
    }
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= FHOBS_N_VARIABLES) {
            snprintf(msg, len, FHOBS_ACCESS_UNKNOWN, function, vr[i],
                     (unsigned)(FHOBS_N_VARIABLES - 1));
            return 1;
        }
        const FhobsVariable *var = &VARIABLES[vr[i]];
        if (var->type != type) {
            snprintf(msg, len, FHOBS_ACCESS_TYPE, function, var->name, vr[i],
                     TYPE_NAMES[var->type], TYPE_NAMES[type]);
            return 1;
        }
        if (!write)
            continue;
        int mode = c->core.values.mode;
        if (instance_write_problem(vr[i], type == FHOBS_REAL ? values[i] : 0.0,
                                   mode != INSTANTIATED && mode != INITIALISATION, function,
                                   FHOBS_ACCESS_FIXED, FHOBS_STATE_NAMES[mode], msg, len))
            return 1;
    }
    return 0;
}

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[])
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_GETREAL);
    if (access_problem(c, "fmi2GetReal", vr, nvr, FHOBS_REAL, 0, value, msg, sizeof msg))
        return fail(c, msg);
    for (size_t i = 0; i < nvr; i++)
        value[i] = c->core.values.real[vr[i]];
    return ok(c);
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[])
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_SETREAL);
    if (access_problem(c, "fmi2SetReal", vr, nvr, FHOBS_REAL, 1, value, msg, sizeof msg))
        return fail(c, msg);
    for (size_t i = 0; i < nvr; i++)
        c->core.values.real[vr[i]] = value[i];
    return ok(c);
}

fmi2Status fmi2GetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[])
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_GETINTEGER);
    static const double any = 0.0;
    if (access_problem(c, "fmi2GetInteger", vr, nvr, FHOBS_INTEGER, 0, value ? &any : NULL, msg,
                       sizeof msg))
        return fail(c, msg);
    int status = c->core.values.integer[VR_STATUS];
    ok(c);
    for (size_t i = 0; i < nvr; i++) /* `status`: the status of the call before this one */
        value[i] = vr[i] == VR_STATUS ? status : c->core.values.integer[vr[i]];
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[])
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_SETINTEGER);
    static const double any = 0.0;
    if (access_problem(c, "fmi2SetInteger", vr, nvr, FHOBS_INTEGER, 1, value ? &any : NULL, msg,
                       sizeof msg))
        return fail(c, msg);
    for (size_t i = 0; i < nvr; i++)
        c->core.values.integer[vr[i]] = value[i];
    return ok(c);
}

/* No Boolean or String variables: any reference is unknown or of another type. */
static fmi2Status no_variables_of_type(fmi2Component component, int call, const char *function,
                                       const fmi2ValueReference vr[], size_t nvr, int type,
                                       const void *value)
{
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(component, call);
    static const double any = 0.0;
    if (access_problem(c, function, vr, nvr, type, 0, value ? &any : NULL, msg, sizeof msg))
        return fail(c, msg);
    return ok(c);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[])
{
    return no_variables_of_type(c, FHOBS_CALL_GETBOOLEAN, "fmi2GetBoolean", vr, nvr, TYPE_BOOLEAN,
                                value);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[])
{
    return no_variables_of_type(c, FHOBS_CALL_SETBOOLEAN, "fmi2SetBoolean", vr, nvr, TYPE_BOOLEAN,
                                value);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[])
{
    return no_variables_of_type(c, FHOBS_CALL_GETSTRING, "fmi2GetString", vr, nvr, TYPE_STRING,
                                value);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[])
{
    return no_variables_of_type(c, FHOBS_CALL_SETSTRING, "fmi2SetString", vr, nvr, TYPE_STRING,
                                value);
}

/* -- stepping ------------------------------------------------------------------------------- */

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentCommunicationPoint)
{
    (void)noSetFMUStatePriorToCurrentCommunicationPoint;
    char msg[FHOBS_MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_DOSTEP);
    int status = instance_do_step(&c->core, currentCommunicationPoint, communicationStepSize,
                                  msg, sizeof msg);
    return report(c, status, msg);
}

/* A function these FMUs do not provide: fmi2Error with the call rules' reason. */
static fmi2Status unsupported(fmi2Component component, int call)
{
    INSTANCE_OR_ERROR(component);
    refused(c, call); /* allowed in no state: refused with its reason */
    return fmi2Error;
}

fmi2Status fmi2CancelStep(fmi2Component component)
{
    return unsupported(component, FHOBS_CALL_CANCELSTEP);
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    (void)s;
    (void)value;
    return unsupported(c, FHOBS_CALL_GETSTATUS);
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s;
    (void)value;
    return unsupported(c, FHOBS_CALL_GETINTEGERSTATUS);
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)s;
    (void)value;
    return unsupported(c, FHOBS_CALL_GETSTRINGSTATUS);
}

/* fmi2LastSuccessfulTime: the end of the last step (the start time before one; the time of a
 * restored FMU state). */
fmi2Status fmi2GetRealStatus(fmi2Component component, const fmi2StatusKind s, fmi2Real *value)
{
    CHECK_CALL(component, FHOBS_CALL_GETREALSTATUS);
    if (s != fmi2LastSuccessfulTime || !value)
        return fail(c, "fmi2GetRealStatus: only fmi2LastSuccessfulTime, into a non-NULL value");
    *value = c->core.values.time;
    return ok(c);
}

/* fmi2Terminated: whether the FMU asks to end the run (never). */
fmi2Status fmi2GetBooleanStatus(fmi2Component component, const fmi2StatusKind s,
                                fmi2Boolean *value)
{
    CHECK_CALL(component, FHOBS_CALL_GETBOOLEANSTATUS);
    if (s != fmi2Terminated || !value)
        return fail(c, "fmi2GetBooleanStatus: only fmi2Terminated, into a non-NULL value");
    *value = fmi2False;
    return ok(c);
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component component, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[])
{
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return unsupported(component, FHOBS_CALL_SETREALINPUTDERIVATIVES);
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component component, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[], fmi2Real value[])
{
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return unsupported(component, FHOBS_CALL_GETREALOUTPUTDERIVATIVES);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component component,
                                        const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return unsupported(component, FHOBS_CALL_GETDIRECTIONALDERIVATIVE);
}

/* -- FMU states ------------------------------------------------------------------------------ */

/* A snapshot of `values` into *state (a new one when *state is NULL). */
static fmi2Status store(Instance *c, const Values *values, fmi2FMUstate *state,
                        const char *function)
{
    char msg[FHOBS_MESSAGE_SIZE];
    if (instance_store(state, values, allocate, &c->callbacks, function, msg, sizeof msg))
        return fail(c, msg);
    return ok(c);
}

fmi2Status fmi2GetFMUstate(fmi2Component component, fmi2FMUstate *state)
{
    CHECK_CALL(component, FHOBS_CALL_GETFMUSTATE);
    if (!state)
        return fail(c, "fmi2GetFMUstate: NULL state pointer");
    return store(c, &c->core.values, state, "fmi2GetFMUstate");
}

fmi2Status fmi2SetFMUstate(fmi2Component component, fmi2FMUstate state)
{
    char msg[FHOBS_MESSAGE_SIZE], reason[FHOBS_MESSAGE_SIZE - 64];
    CHECK_CALL(component, FHOBS_CALL_SETFMUSTATE);
    const Values *values = instance_snapshot(state);
    if (!values)
        return fail(c, "fmi2SetFMUstate rejected the state: not an FMU state of this FMU");
    if (values_problem(values, reason, sizeof reason)) {
        snprintf(msg, sizeof msg, "fmi2SetFMUstate rejected the state: %s", reason);
        return fail(c, msg);
    }
    instance_take(&c->core, values);
    return ok(c);
}

fmi2Status fmi2FreeFMUstate(fmi2Component component, fmi2FMUstate *state)
{
    CHECK_CALL(component, FHOBS_CALL_FREEFMUSTATE);
    if (!state || !*state)
        return ok(c);
    if (!instance_snapshot(*state))
        return fail(c, "fmi2FreeFMUstate: not an FMU state of this FMU");
    instance_forget(*state);
    release(&c->callbacks, *state);
    *state = NULL;
    return ok(c);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component component, fmi2FMUstate state, size_t *size)
{
    CHECK_CALL(component, FHOBS_CALL_SERIALIZEDFMUSTATESIZE);
    if (!instance_snapshot(state) || !size)
        return fail(c, "fmi2SerializedFMUstateSize: not an FMU state of this FMU");
    *size = instance_serialized_size();
    return ok(c);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component component, fmi2FMUstate state,
                                 fmi2Byte serializedState[], size_t size)
{
    CHECK_CALL(component, FHOBS_CALL_SERIALIZEFMUSTATE);
    const Values *values = instance_snapshot(state);
    if (!values || !serializedState || size != instance_serialized_size())
        return fail(c, "fmi2SerializeFMUstate: not an FMU state of this FMU, or a buffer of "
                       "another size than fmi2SerializedFMUstateSize's");
    instance_serialize(values, (unsigned char *)serializedState);
    return ok(c);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component component, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *state)
{
    char msg[FHOBS_MESSAGE_SIZE], reason[FHOBS_MESSAGE_SIZE - 64];
    CHECK_CALL(component, FHOBS_CALL_DESERIALIZEFMUSTATE);
    Values values;
    if (!state)
        return fail(c, "fmi2DeSerializeFMUstate: NULL state pointer");
    if (instance_deserialize((const unsigned char *)serializedState, size, &values, reason,
                             sizeof reason) ||
        values_problem(&values, reason, sizeof reason)) {
        snprintf(msg, sizeof msg, "fmi2DeSerializeFMUstate rejected the bytes: %s", reason);
        return fail(c, msg);
    }
    return store(c, &values, state, "fmi2DeSerializeFMUstate");
}
