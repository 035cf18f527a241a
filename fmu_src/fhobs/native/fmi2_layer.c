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
 * several native FMUs run in one process. The model (models.c, the generated model_data.c)
 * is reached through model.h; the fmi2 functions are the only symbols the library exports.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fhobs_call_rules.h"
#include "fmi2Functions.h"
#include "kernel.h"
#include "model.h"

#define INSTANCE_MAGIC 0x6668696eu /* "fhin" */
#define SNAPSHOT_MAGIC 0x66687374u /* "fhst" */
#define STATE_HEADER "FHOBSNAT"
#define STATE_FORMAT 3u
#define IDENTITY_FIELD 48
#define MESSAGE_SIZE 1024
#define STATUS_OK 0      /* fhobs.fmu.modes.STATUS_OK */
#define STATUS_WARNING 1 /* fhobs.fmu.modes.STATUS_WARNING */
#define STATUS_ERROR 3   /* fhobs.fmu.modes.STATUS_ERROR */

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
    int mode;
    double time; /* the last successful time: the start time, then the end of the last step */
    double real[FHOBS_N_VARIABLES]; /* by value reference (Integer variables: unused) */
    int integer[FHOBS_N_VARIABLES]; /* by value reference (Real variables: unused) */
    double state[FHOBS_STATE_SIZE]; /* the model's state */
} Values;

typedef struct {
    uint32_t magic;
    fmi2CallbackFunctions callbacks;
    char *name;
    Values values;
    double start_time; /* fmi2SetupExperiment's */
    double time;       /* the end of the last step (the start time before one); NaN after an
                          FMU state was set: the next doStep's time is taken as it comes */
    Work *work;        /* the model's plans and scratch (model_work_size() bytes) */
    int warned_coarse_step; /* a step longer than max_communication_step was warned of */
} Instance;

typedef struct {
    uint32_t magic;
    char identity[IDENTITY_FIELD]; /* the GUID of the FMU that made it (kept inline: a state
                                      may outlive the library of another FMU) */
    Values values;
} Snapshot;

/* serialized: header, format, identity, the Values' fields, then a 64-bit FNV-1a checksum of
 * everything before it */
#define SERIALIZED_SIZE                                                                        \
    (8 + 4 + IDENTITY_FIELD + 4 + 8 + 8 * FHOBS_N_VARIABLES + 4 * FHOBS_N_VARIABLES +          \
     8 * FHOBS_STATE_SIZE + 8)

/* -- memory and messages ------------------------------------------------------------------ */

static void *allocate(const fmi2CallbackFunctions *f, size_t size)
{
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

static fmi2Status ok(Instance *c)
{
    c->values.integer[VR_STATUS] = STATUS_OK;
    return fmi2OK;
}

/* The instance's max_communication_step (0, no figure, for a kind without it). */
static double max_communication_step(const Instance *c)
{
#if VR_MAX_COMMUNICATION_STEP >= 0
    return c->values.real[VR_MAX_COMMUNICATION_STEP];
#else
    (void)c;
    return 0.0;
#endif
}

/* Whether a successful step of size dt is the instance's first longer than its
 * max_communication_step (the rule of fhobs.fmu.call_rules.coarse_step_problem). */
static int coarse_step(const Instance *c, double dt)
{
    double max_step = max_communication_step(c);
    return !c->warned_coarse_step && max_step > 0.0 &&
           dt > max_step * (1.0 + FHOBS_COARSE_STEP_TOLERANCE);
}

/* The coarse step's warning, once per instance: fmi2Warning and the message. */
static fmi2Status warn(Instance *c, double dt)
{
    char message[MESSAGE_SIZE];
    snprintf(message, sizeof message, FHOBS_COARSE_STEP_MESSAGE, dt, max_communication_step(c));
    c->warned_coarse_step = 1;
    c->values.integer[VR_STATUS] = STATUS_WARNING;
    log_message(c, fmi2Warning, "logStatusWarning", message);
    return fmi2Warning;
}

static fmi2Status fail(Instance *c, const char *message)
{
    c->values.integer[VR_STATUS] = STATUS_ERROR;
    log_message(c, fmi2Error, "logStatusError", message);
    return fmi2Error;
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
    char msg[MESSAGE_SIZE];
    int mode = c->values.mode;
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

/* -- the model's values -------------------------------------------------------------------- */

static void publish(Instance *c)
{
    model_outputs(c->work, c->values.real, c->values.integer, c->values.state);
}

/* The start values, the initial state of the start parameters and its outputs. */
static void start_values(Instance *c)
{
    char msg[MESSAGE_SIZE];
    Values *v = &c->values;
    v->mode = INSTANTIATED;
    v->time = 0.0;
    for (int i = 0; i < FHOBS_N_VARIABLES; i++) {
        v->real[i] = VARIABLES[i].type == FHOBS_REAL ? VARIABLES[i].start : 0.0;
        v->integer[i] = VARIABLES[i].type == FHOBS_INTEGER ? (int)VARIABLES[i].start : 0;
    }
    model_initial_state(v->real, v->state, msg, sizeof msg); /* the built starts are valid */
    publish(c);
}

/* Why the parameters of `v` cannot start a run (1, message) or 0: a non-finite parameter,
 * input_bound <= 0, or what the model refuses. */
static int parameters_problem(const Values *v, char *msg, size_t len)
{
    char a[32];
    for (int i = 0; i < FHOBS_N_VARIABLES; i++) {
        if (VARIABLES[i].role == FHOBS_SETTABLE && VARIABLES[i].type == FHOBS_REAL &&
            !isfinite(v->real[i])) {
            snprintf(msg, len, "parameter %s = %s is not finite", VARIABLES[i].name,
                     fhobs_number(v->real[i], a, sizeof a));
            return 1;
        }
    }
    if (!(v->real[VR_INPUT_BOUND] > 0.0)) {
        snprintf(msg, len, "parameter input_bound = %s must be > 0",
                 fhobs_number(v->real[VR_INPUT_BOUND], a, sizeof a));
        return 1;
    }
    return model_parameters_problem(v->real, v->integer, msg, len);
}

/* Why `v` is not a state of this FMU an instance can take ('' / 0 if it is): compiled
 * parameters with their built values, finite values (inputs may hold anything: doStep checks
 * them), a known mode, and for an initialised state parameters that pass the initialisation
 * checks. */
static int values_problem(const Values *v, char *msg, size_t len)
{
    char a[32];
    if (v->mode < 0 || v->mode >= FHOBS_N_STATES) {
        snprintf(msg, len, "unknown FMI state %d", v->mode);
        return 1;
    }
    for (int i = 0; i < FHOBS_N_VARIABLES; i++) {
        const FhobsVariable *var = &VARIABLES[i];
        if (var->type != FHOBS_REAL)
            continue;
        if (var->role == FHOBS_COMPILED && memcmp(&v->real[i], &var->start, sizeof(double))) {
            snprintf(msg, len, "its parameter %s = %s is not the value compiled into this FMU",
                     var->name, fhobs_number(v->real[i], a, sizeof a));
            return 1;
        }
        if (var->role == FHOBS_OUTPUT && !isfinite(v->real[i])) {
            snprintf(msg, len, "its output %s is not finite", var->name);
            return 1;
        }
    }
    if (!isfinite(v->time)) {
        snprintf(msg, len, "its time %s is not a finite number", fhobs_number(v->time, a, sizeof a));
        return 1;
    }
    if (!all_finite(v->state, FHOBS_STATE_SIZE)) {
        snprintf(msg, len, "its model state is not finite");
        return 1;
    }
    if (model_state_problem(v->state, msg, len))
        return 1;
    if (v->mode == STEP_MODE || v->mode == TERMINATED)
        return parameters_problem(v, msg, len);
    double state[FHOBS_STATE_SIZE]; /* before initialisation: the initial state must be one */
    return model_initial_state(v->real, state, msg, len);
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
    Instance *c = allocate(functions, sizeof(Instance));
    if (!c)
        return NULL;
    memset(c, 0, sizeof *c);
    c->callbacks = *functions;
    size_t length = strlen(probe.name) + 1;
    c->name = allocate(functions, length);
    if (!c->name) {
        release(functions, c);
        return NULL;
    }
    memcpy(c->name, probe.name, length);
    c->work = allocate(functions, model_work_size());
    if (!c->work) {
        release(functions, c->name);
        release(functions, c);
        return NULL;
    }
    memset(c->work, 0, model_work_size());
    c->magic = INSTANCE_MAGIC;
    work_init(c->work);
    start_values(c);
    return c;
}

void fmi2FreeInstance(fmi2Component component)
{
    Instance *c = instance(component);
    if (!c)
        return;
    fmi2CallbackFunctions callbacks = c->callbacks;
    c->magic = 0;
    release(&callbacks, c->work);
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
    char msg[MESSAGE_SIZE], a[32];
    CHECK_CALL(component, FHOBS_CALL_SETUPEXPERIMENT);
    if (!isfinite(startTime)) {
        snprintf(msg, sizeof msg, "fmi2SetupExperiment: startTime %s is not finite",
                 fhobs_number(startTime, a, sizeof a));
        return fail(c, msg);
    }
    c->start_time = c->values.time = startTime;
    return ok(c);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component component)
{
    CHECK_CALL(component, FHOBS_CALL_ENTERINITIALIZATIONMODE);
    c->values.mode = INITIALISATION;
    return ok(c);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component component)
{
    char msg[MESSAGE_SIZE], reason[MESSAGE_SIZE - 64];
    CHECK_CALL(component, FHOBS_CALL_EXITINITIALIZATIONMODE);
    Values *v = &c->values;
    double state[FHOBS_STATE_SIZE];
    if (parameters_problem(v, reason, sizeof reason) ||
        model_initial_state(v->real, state, reason, sizeof reason)) {
        snprintf(msg, sizeof msg, "initialisation rejected the parameters: %s", reason);
        return fail(c, msg);
    }
    memcpy(v->state, state, sizeof state);
    publish(c);
    v->mode = STEP_MODE;
    c->time = v->time = c->start_time;
    return ok(c);
}

fmi2Status fmi2Terminate(fmi2Component component)
{
    CHECK_CALL(component, FHOBS_CALL_TERMINATE);
    c->values.mode = TERMINATED;
    return ok(c);
}

fmi2Status fmi2Reset(fmi2Component component)
{
    CHECK_CALL(component, FHOBS_CALL_RESET);
    c->start_time = c->time = 0.0;
    c->warned_coarse_step = 0;
    work_init(c->work);
    start_values(c);
    return ok(c);
}

/* -- get and set ----------------------------------------------------------------------------- */

/* Why `function` may not access `vr` (type `type`; `write`: a set of `values`) now: 1 and
 * the message, or 0. */
static int access_problem(const Instance *c, const char *function, const fmi2ValueReference vr[],
                          size_t nvr, int type, int write, const double *values, char *msg,
                          size_t len)
{
    char a[32], b[32];
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
        if (var->role == FHOBS_OUTPUT) {
            snprintf(msg, len, FHOBS_ACCESS_OUTPUT, function, var->name, vr[i]);
            return 1;
        }
        if (var->role == FHOBS_LOCAL) {
            snprintf(msg, len, FHOBS_ACCESS_LOCAL, function, var->name, vr[i]);
            return 1;
        }
        int parameter = var->role == FHOBS_COMPILED || var->role == FHOBS_SETTABLE;
        if (parameter && c->values.mode != INSTANTIATED && c->values.mode != INITIALISATION) {
            snprintf(msg, len, FHOBS_ACCESS_FIXED, function, var->name, vr[i],
                     FHOBS_STATE_NAMES[c->values.mode]);
            return 1;
        }
        if (var->role == FHOBS_COMPILED && memcmp(&values[i], &var->start, sizeof(double))) {
            snprintf(msg, len, "%s: parameter %s = %s is compiled into the native FMU (its value "
                     "is %s); rebuild with build_fmu.py to change it", function, var->name,
                     fhobs_number(values[i], a, sizeof a), fhobs_number(var->start, b, sizeof b));
            return 1;
        }
    }
    return 0;
}

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[])
{
    char msg[MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_GETREAL);
    if (access_problem(c, "fmi2GetReal", vr, nvr, FHOBS_REAL, 0, value, msg, sizeof msg))
        return fail(c, msg);
    for (size_t i = 0; i < nvr; i++)
        value[i] = c->values.real[vr[i]];
    return ok(c);
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[])
{
    char msg[MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_SETREAL);
    if (access_problem(c, "fmi2SetReal", vr, nvr, FHOBS_REAL, 1, value, msg, sizeof msg))
        return fail(c, msg);
    for (size_t i = 0; i < nvr; i++)
        c->values.real[vr[i]] = value[i];
    return ok(c);
}

fmi2Status fmi2GetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[])
{
    char msg[MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_GETINTEGER);
    static const double any = 0.0;
    if (access_problem(c, "fmi2GetInteger", vr, nvr, FHOBS_INTEGER, 0, value ? &any : NULL, msg,
                       sizeof msg))
        return fail(c, msg);
    int status = c->values.integer[VR_STATUS];
    ok(c);
    for (size_t i = 0; i < nvr; i++) /* `status`: the status of the call before this one */
        value[i] = vr[i] == VR_STATUS ? status : c->values.integer[vr[i]];
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[])
{
    char msg[MESSAGE_SIZE];
    CHECK_CALL(component, FHOBS_CALL_SETINTEGER);
    static const double any = 0.0;
    if (access_problem(c, "fmi2SetInteger", vr, nvr, FHOBS_INTEGER, 1, value ? &any : NULL, msg,
                       sizeof msg))
        return fail(c, msg);
    for (size_t i = 0; i < nvr; i++)
        c->values.integer[vr[i]] = value[i];
    return ok(c);
}

/* No Boolean or String variables: any reference is unknown or of another type. */
static fmi2Status no_variables_of_type(fmi2Component component, int call, const char *function,
                                       const fmi2ValueReference vr[], size_t nvr, int type,
                                       const void *value)
{
    char msg[MESSAGE_SIZE];
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

/* Why the inputs cannot be stepped with (1 and the message) or 0. */
static int input_problem(const Instance *c, char *msg, size_t len)
{
    char a[32], b[32];
    double bound = c->values.real[VR_INPUT_BOUND];
    for (int i = 0; i < FHOBS_N_VARIABLES; i++) {
        if (VARIABLES[i].role != FHOBS_INPUT)
            continue;
        double value = c->values.real[i];
        if (!isfinite(value)) {
            snprintf(msg, len, "input %s = %s is not finite", VARIABLES[i].name,
                     fhobs_number(value, a, sizeof a));
            return 1;
        }
        if (fabs(value) > bound) {
            snprintf(msg, len, "input %s = %s exceeds input_bound = %s", VARIABLES[i].name,
                     fhobs_number(value, a, sizeof a), fhobs_number(bound, b, sizeof b));
            return 1;
        }
    }
    return 0;
}

/* Why a doStep from time t does not continue the instance (1 and the message) or 0
 * (fhobs.fmu.call_rules.time_problem). */
static int time_problem(const Instance *c, double t, double dt, char *msg, size_t len)
{
    char a[32], b[32];
    if (!isfinite(t)) {
        snprintf(msg, len, "currentCommunicationPoint %s is not finite", fhobs_number(t, a, sizeof a));
        return 1;
    }
    double scale = fabs(c->time) > dt ? fabs(c->time) : dt;
    if (isnan(c->time) || fabs(t - c->time) <= FHOBS_TIME_TOLERANCE * scale)
        return 0;
    snprintf(msg, len, FHOBS_TIME_MESSAGE, fhobs_number(t, a, sizeof a), fhobs_number(c->time, b, sizeof b));
    return 1;
}

/* Why the exact ZOH of the model over dt has no correct digit (1 and the message) or 0
 * (fhobs.fmu.slave_base.zoh_problem). */
static int zoh_problem(double dt, char *msg, size_t len)
{
    char a[32];
    double scale = dt * FHOBS_MODEL_NORM1;
    if (!(scale > FHOBS_ZOH_CONDITION_LIMIT))
        return 0;
    snprintf(msg, len, FHOBS_ZOH_MESSAGE,
             FHOBS_KIND == FHOBS_KIND_PLANT ? "the plant" : "the observer's model", scale,
             fhobs_number(dt, a, sizeof a));
    return 1;
}

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentCommunicationPoint)
{
    (void)noSetFMUStatePriorToCurrentCommunicationPoint;
    char msg[MESSAGE_SIZE], reason[MESSAGE_SIZE - 64], t[32];
    CHECK_CALL(component, FHOBS_CALL_DOSTEP);
    Values *v = &c->values;
    double dt = communicationStepSize;
    double next[FHOBS_STATE_SIZE];
    int problem = 0;
    if (!(isfinite(dt) && dt > 0.0)) {
        char a[32];
        snprintf(reason, sizeof reason, "communication step size %s is not a positive finite "
                 "number", fhobs_number(dt, a, sizeof a));
        problem = 1;
    }
    problem = problem || time_problem(c, currentCommunicationPoint, dt, reason, sizeof reason);
    problem = problem || zoh_problem(dt, reason, sizeof reason);
    problem = problem || input_problem(c, reason, sizeof reason) ||
              model_step(c->work, v->real, v->integer, v->state, next, dt, reason,
                         sizeof reason);
    if (problem) {
        snprintf(msg, sizeof msg, "doStep at t = %s rejected: %s",
                 fhobs_number(currentCommunicationPoint, t, sizeof t), reason);
        return fail(c, msg);
    }
    memcpy(v->state, next, sizeof next);
    publish(c);
    c->time = v->time = currentCommunicationPoint + dt;
    return coarse_step(c, dt) ? warn(c, dt) : ok(c);
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
    *value = c->values.time;
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

static Snapshot *snapshot(fmi2FMUstate state)
{
    Snapshot *s = state;
    return s && s->magic == SNAPSHOT_MAGIC &&
                   strncmp(s->identity, FHOBS_IDENTITY, IDENTITY_FIELD) == 0
               ? s
               : NULL;
}

fmi2Status fmi2GetFMUstate(fmi2Component component, fmi2FMUstate *state)
{
    CHECK_CALL(component, FHOBS_CALL_GETFMUSTATE);
    if (!state)
        return fail(c, "fmi2GetFMUstate: NULL state pointer");
    Snapshot *s = *state ? snapshot(*state) : allocate(&c->callbacks, sizeof(Snapshot));
    if (!s)
        return fail(c, *state ? "fmi2GetFMUstate: the state to overwrite is not one of this FMU"
                              : "fmi2GetFMUstate: out of memory");
    s->magic = SNAPSHOT_MAGIC;
    memset(s->identity, 0, IDENTITY_FIELD);
    strncpy(s->identity, FHOBS_IDENTITY, IDENTITY_FIELD - 1);
    s->values = c->values;
    *state = s;
    return ok(c);
}

fmi2Status fmi2SetFMUstate(fmi2Component component, fmi2FMUstate state)
{
    char msg[MESSAGE_SIZE], reason[MESSAGE_SIZE - 64];
    CHECK_CALL(component, FHOBS_CALL_SETFMUSTATE);
    Snapshot *s = snapshot(state);
    if (!s)
        return fail(c, "fmi2SetFMUstate rejected the state: not an FMU state of this FMU");
    if (values_problem(&s->values, reason, sizeof reason)) {
        snprintf(msg, sizeof msg, "fmi2SetFMUstate rejected the state: %s", reason);
        return fail(c, msg);
    }
    c->values = s->values;
    c->time = NAN;
    return ok(c);
}

fmi2Status fmi2FreeFMUstate(fmi2Component component, fmi2FMUstate *state)
{
    CHECK_CALL(component, FHOBS_CALL_FREEFMUSTATE);
    if (!state || !*state)
        return ok(c);
    Snapshot *s = snapshot(*state);
    if (!s)
        return fail(c, "fmi2FreeFMUstate: not an FMU state of this FMU");
    s->magic = 0;
    release(&c->callbacks, s);
    *state = NULL;
    return ok(c);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component component, fmi2FMUstate state, size_t *size)
{
    CHECK_CALL(component, FHOBS_CALL_SERIALIZEDFMUSTATESIZE);
    if (!snapshot(state) || !size)
        return fail(c, "fmi2SerializedFMUstateSize: not an FMU state of this FMU");
    *size = SERIALIZED_SIZE;
    return ok(c);
}

static unsigned char *put(unsigned char *p, const void *data, size_t size)
{
    memcpy(p, data, size);
    return p + size;
}

static const unsigned char *get(const unsigned char *p, void *data, size_t size)
{
    memcpy(data, p, size);
    return p + size;
}

/* 64-bit FNV-1a of n bytes (the serialized state's checksum) */
static uint64_t fnv1a(const unsigned char *bytes, size_t n)
{
    uint64_t hash = 14695981039346656037u;
    for (size_t i = 0; i < n; i++) {
        hash ^= bytes[i];
        hash *= 1099511628211u;
    }
    return hash;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component component, fmi2FMUstate state,
                                 fmi2Byte serializedState[], size_t size)
{
    CHECK_CALL(component, FHOBS_CALL_SERIALIZEFMUSTATE);
    Snapshot *s = snapshot(state);
    if (!s || !serializedState || size != SERIALIZED_SIZE)
        return fail(c, "fmi2SerializeFMUstate: not an FMU state of this FMU, or a buffer of "
                       "another size than fmi2SerializedFMUstateSize's");
    char identity[IDENTITY_FIELD] = {0};
    strncpy(identity, FHOBS_IDENTITY, IDENTITY_FIELD - 1);
    uint32_t format = STATE_FORMAT;
    int32_t mode = s->values.mode;
    unsigned char *p = (unsigned char *)serializedState;
    p = put(p, STATE_HEADER, 8);
    p = put(p, &format, 4);
    p = put(p, identity, IDENTITY_FIELD);
    p = put(p, &mode, 4);
    p = put(p, &s->values.time, 8);
    p = put(p, s->values.real, sizeof s->values.real);
    p = put(p, s->values.integer, sizeof s->values.integer);
    p = put(p, s->values.state, sizeof s->values.state);
    uint64_t checksum = fnv1a((const unsigned char *)serializedState, SERIALIZED_SIZE - 8);
    put(p, &checksum, 8);
    return ok(c);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component component, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *state)
{
    char msg[MESSAGE_SIZE], reason[MESSAGE_SIZE - 64];
    CHECK_CALL(component, FHOBS_CALL_DESERIALIZEFMUSTATE);
    char identity[IDENTITY_FIELD] = {0}, expected[IDENTITY_FIELD] = {0};
    strncpy(expected, FHOBS_IDENTITY, IDENTITY_FIELD - 1);
    const unsigned char *p = (const unsigned char *)serializedState;
    if (!state || !serializedState || size < 8 + 4 + IDENTITY_FIELD || memcmp(p, STATE_HEADER, 8))
        return fail(c, "fmi2DeSerializeFMUstate rejected the bytes: they are not a serialized "
                       "FMU state of this FMU (its header is missing)");
    uint32_t format;
    int32_t mode;
    Values values;
    p = get(p + 8, &format, 4);
    p = get(p, identity, IDENTITY_FIELD);
    if (format != STATE_FORMAT || memcmp(identity, expected, IDENTITY_FIELD))
        return fail(c, "fmi2DeSerializeFMUstate rejected the bytes: they are a state of another "
                       "FMU or format (its GUID differs)");
    if (size != SERIALIZED_SIZE)
        return fail(c, "fmi2DeSerializeFMUstate rejected the bytes: they are not a serialized "
                       "FMU state of this FMU (wrong size)");
    uint64_t checksum;
    memcpy(&checksum, serializedState + SERIALIZED_SIZE - 8, 8);
    if (checksum != fnv1a((const unsigned char *)serializedState, SERIALIZED_SIZE - 8))
        return fail(c, "fmi2DeSerializeFMUstate rejected the bytes: their checksum does not "
                       "match (the bytes were changed after fmi2SerializeFMUstate)");
    p = get(p, &mode, 4);
    values.mode = mode;
    p = get(p, &values.time, 8);
    p = get(p, values.real, sizeof values.real);
    p = get(p, values.integer, sizeof values.integer);
    get(p, values.state, sizeof values.state);
    if (values_problem(&values, reason, sizeof reason)) {
        snprintf(msg, sizeof msg, "fmi2DeSerializeFMUstate rejected the bytes: %s", reason);
        return fail(c, msg);
    }
    Snapshot *s = *state ? snapshot(*state) : allocate(&c->callbacks, sizeof(Snapshot));
    if (!s)
        return fail(c, "fmi2DeSerializeFMUstate: the state to overwrite is not one of this FMU, "
                       "or out of memory");
    s->magic = SNAPSHOT_MAGIC;
    memset(s->identity, 0, IDENTITY_FIELD);
    strncpy(s->identity, FHOBS_IDENTITY, IDENTITY_FIELD - 1);
    s->values = values;
    *state = s;
    return ok(c);
}
