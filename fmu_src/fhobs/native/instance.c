/*
 * A native fhobs FMU instance whatever its FMI version (instance.h): start values, checks, the
 * step and the coarse-step warning, FMU states and their bytes. Each function checks
 * completely before it changes anything, so a refused call leaves the instance as it was.
 */
#include "instance.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "fhobs_call_rules.h"
#include "kernel.h"
#include "model.h"

#define STATE_HEADER "FHOBSNAT"
#define STATE_FORMAT 3u
#define SNAPSHOT_MAGIC 0x66687374u /* "fhst" */

/* An FMU state in memory (the pointer a layer hands out as fmi2FMUstate / fmi3FMUState). */
typedef struct {
    uint32_t magic;
    char identity[FHOBS_IDENTITY_FIELD]; /* the GUID of the FMU that made it (kept inline: a
                                            state may outlive the library of another FMU) */
    Values values;
} Snapshot;

/* serialized: header, format, identity, the Values' fields, then a 64-bit FNV-1a checksum of
 * everything before it */
#define SERIALIZED_SIZE                                                                        \
    (8 + 4 + FHOBS_IDENTITY_FIELD + 4 + 8 + 8 * FHOBS_N_VARIABLES + 4 * FHOBS_N_VARIABLES +    \
     8 * FHOBS_STATE_SIZE + 8)

/* The outputs of the model's state into the variables. */
static void publish(Values *v, Work *w)
{
    model_outputs(w, v->real, v->integer, v->state);
}

/* The start values (state instantiated, time 0), the initial state and its outputs. */
static void start_values(Values *v, Work *w)
{
    char msg[FHOBS_MESSAGE_SIZE];
    v->mode = FHOBS_STATE_INSTANTIATED;
    v->time = 0.0;
    for (int i = 0; i < FHOBS_N_VARIABLES; i++) {
        v->real[i] = VARIABLES[i].type == FHOBS_REAL ? VARIABLES[i].start : 0.0;
        v->integer[i] = VARIABLES[i].type == FHOBS_INTEGER ? (int)VARIABLES[i].start : 0;
    }
    model_initial_state(v->real, v->state, msg, sizeof msg); /* the built starts are valid */
    publish(v, w);
}

/* Why the parameters of v cannot start a run (1, message) or 0: a non-finite parameter,
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

/* The initial state of the parameters (1 and the message if they cannot start a run). */
static int initialise(Values *v, Work *w, char *msg, size_t len)
{
    char reason[FHOBS_MESSAGE_SIZE - 64];
    double state[FHOBS_STATE_SIZE];
    if (parameters_problem(v, reason, sizeof reason) ||
        model_initial_state(v->real, state, reason, sizeof reason)) {
        snprintf(msg, len, "initialisation rejected the parameters: %s", reason);
        return 1;
    }
    memcpy(v->state, state, sizeof state);
    publish(v, w);
    return 0;
}

int instance_values_problem(const Values *v, int initialised, char *msg, size_t len)
{
    char a[32];
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
        snprintf(msg, len, "its time %s is not a finite number",
                 fhobs_number(v->time, a, sizeof a));
        return 1;
    }
    if (!all_finite(v->state, FHOBS_STATE_SIZE)) {
        snprintf(msg, len, "its model state is not finite");
        return 1;
    }
    if (model_state_problem(v->state, msg, len))
        return 1;
    if (initialised)
        return parameters_problem(v, msg, len);
    double state[FHOBS_STATE_SIZE]; /* before initialisation: the initial state must be one */
    return model_initial_state(v->real, state, msg, len);
}

int instance_write_problem(unsigned index, double value, int fixed, const char *function,
                           const char *fixed_format, const char *state, char *msg, size_t len)
{
    char a[32], b[32];
    const FhobsVariable *var = &VARIABLES[index];
    if (var->role == FHOBS_OUTPUT) {
        snprintf(msg, len, FHOBS_ACCESS_OUTPUT, function, var->name, index);
        return 1;
    }
    if (var->role == FHOBS_LOCAL) {
        snprintf(msg, len, FHOBS_ACCESS_LOCAL, function, var->name, index);
        return 1;
    }
    int parameter = var->role == FHOBS_COMPILED || var->role == FHOBS_SETTABLE;
    if (parameter && fixed) {
        snprintf(msg, len, fixed_format, function, var->name, index, state);
        return 1;
    }
    if (var->role == FHOBS_COMPILED && memcmp(&value, &var->start, sizeof(double))) {
        snprintf(msg, len, "%s: parameter %s = %s is compiled into the native FMU (its value "
                 "is %s); rebuild with build_fmu.py to change it", function, var->name,
                 fhobs_number(value, a, sizeof a), fhobs_number(var->start, b, sizeof b));
        return 1;
    }
    return 0;
}

/* -- an instance ----------------------------------------------------------------------------- */

void instance_reset(Core *c)
{
    c->start_time = c->time = 0.0;
    c->warned_coarse_step = 0;
    work_init(c->work);
    start_values(&c->values, c->work);
}

int instance_set_start_time(Core *c, double start_time, const char *function, char *msg,
                            size_t len)
{
    char a[32];
    if (!isfinite(start_time)) {
        snprintf(msg, len, "%s: startTime %s is not finite", function,
                 fhobs_number(start_time, a, sizeof a));
        return 1;
    }
    c->start_time = c->values.time = start_time;
    return 0;
}

int instance_exit_initialisation(Core *c, int mode, char *msg, size_t len)
{
    if (initialise(&c->values, c->work, msg, len))
        return 1;
    c->values.mode = mode;
    c->time = c->values.time = c->start_time;
    return 0;
}

void instance_take(Core *c, const Values *v)
{
    c->values = *v;
    c->time = NAN;
}

/* -- the step -------------------------------------------------------------------------------- */

/* Why the inputs cannot be stepped with (1 and the message) or 0. */
static int input_problem(const Values *v, char *msg, size_t len)
{
    char a[32], b[32];
    double bound = v->real[VR_INPUT_BOUND];
    for (int i = 0; i < FHOBS_N_VARIABLES; i++) {
        if (VARIABLES[i].role != FHOBS_INPUT)
            continue;
        double value = v->real[i];
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

/* Why a step from time t does not continue an instance whose time is own (1 and the message)
 * or 0 (fhobs.fmu.call_rules.time_problem). */
static int time_problem(double own, double t, double dt, char *msg, size_t len)
{
    char a[32], b[32];
    if (!isfinite(t)) {
        snprintf(msg, len, "currentCommunicationPoint %s is not finite",
                 fhobs_number(t, a, sizeof a));
        return 1;
    }
    double scale = fabs(own) > dt ? fabs(own) : dt;
    if (isnan(own) || fabs(t - own) <= FHOBS_TIME_TOLERANCE * scale)
        return 0;
    snprintf(msg, len, FHOBS_TIME_MESSAGE, fhobs_number(t, a, sizeof a),
             fhobs_number(own, b, sizeof b));
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

/* A communication step of dt from t of an instance whose own time is own_time (NaN: any):
 * 1 and the message (the values unchanged), or 0 with the step made and v->time = t + dt. */
static int step(Values *v, Work *w, double own_time, double t, double dt, char *msg, size_t len)
{
    char reason[FHOBS_MESSAGE_SIZE - 64], a[32];
    double next[FHOBS_STATE_SIZE];
    int problem = 0;
    if (!(isfinite(dt) && dt > 0.0)) {
        snprintf(reason, sizeof reason, "communication step size %s is not a positive finite "
                 "number", fhobs_number(dt, a, sizeof a));
        problem = 1;
    }
    problem = problem || time_problem(own_time, t, dt, reason, sizeof reason);
    problem = problem || zoh_problem(dt, reason, sizeof reason);
    problem = problem || input_problem(v, reason, sizeof reason) ||
              model_step(w, v->real, v->integer, v->state, next, dt, reason, sizeof reason);
    if (problem) {
        snprintf(msg, len, "doStep at t = %s rejected: %s", fhobs_number(t, a, sizeof a),
                 reason);
        return 1;
    }
    memcpy(v->state, next, sizeof next);
    publish(v, w);
    v->time = t + dt;
    return 0;
}

/* The instance's max_communication_step (0, no figure, for a kind without it). */
static double max_communication_step(const Values *v)
{
#if VR_MAX_COMMUNICATION_STEP >= 0
    return v->real[VR_MAX_COMMUNICATION_STEP];
#else
    (void)v;
    return 0.0;
#endif
}

/* Whether a successful step of size dt is the instance's first longer than its
 * max_communication_step (the rule of fhobs.fmu.call_rules.coarse_step_problem). */
static int coarse_step(const Core *c, double dt)
{
    double max_step = max_communication_step(&c->values);
    return !c->warned_coarse_step && max_step > 0.0 &&
           dt > max_step * (1.0 + FHOBS_COARSE_STEP_TOLERANCE);
}

int instance_do_step(Core *c, double t, double dt, char *msg, size_t len)
{
    if (step(&c->values, c->work, c->time, t, dt, msg, len))
        return FHOBS_STATUS_ERROR;
    c->time = c->values.time;
    if (!coarse_step(c, dt))
        return FHOBS_STATUS_OK;
    snprintf(msg, len, FHOBS_COARSE_STEP_MESSAGE, dt, max_communication_step(&c->values));
    c->warned_coarse_step = 1;
    return FHOBS_STATUS_WARNING;
}

/* -- FMU states ------------------------------------------------------------------------------ */

const Values *instance_snapshot(const void *state)
{
    const Snapshot *s = state;
    return s && s->magic == SNAPSHOT_MAGIC &&
                   strncmp(s->identity, FHOBS_IDENTITY, FHOBS_IDENTITY_FIELD) == 0
               ? &s->values
               : NULL;
}

int instance_store(void **state, const Values *v, Allocate *allocate, void *context,
                   const char *function, char *msg, size_t len)
{
    Snapshot *s = *state ? (instance_snapshot(*state) ? *state : NULL)
                         : allocate(context, sizeof(Snapshot));
    if (!s) {
        snprintf(msg, len, "%s: %s", function,
                 *state ? "the state to overwrite is not one of this FMU" : "out of memory");
        return 1;
    }
    s->magic = SNAPSHOT_MAGIC;
    memset(s->identity, 0, FHOBS_IDENTITY_FIELD);
    strncpy(s->identity, FHOBS_IDENTITY, FHOBS_IDENTITY_FIELD - 1);
    s->values = *v;
    *state = s;
    return 0;
}

void instance_forget(void *state)
{
    ((Snapshot *)state)->magic = 0;
}

/* -- a state's bytes ------------------------------------------------------------------------- */

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

size_t instance_serialized_size(void)
{
    return SERIALIZED_SIZE;
}

void instance_serialize(const Values *v, unsigned char *bytes)
{
    char identity[FHOBS_IDENTITY_FIELD] = {0};
    strncpy(identity, FHOBS_IDENTITY, FHOBS_IDENTITY_FIELD - 1);
    uint32_t format = STATE_FORMAT;
    int32_t mode = v->mode;
    unsigned char *p = bytes;
    p = put(p, STATE_HEADER, 8);
    p = put(p, &format, 4);
    p = put(p, identity, FHOBS_IDENTITY_FIELD);
    p = put(p, &mode, 4);
    p = put(p, &v->time, 8);
    p = put(p, v->real, sizeof v->real);
    p = put(p, v->integer, sizeof v->integer);
    p = put(p, v->state, sizeof v->state);
    uint64_t checksum = fnv1a(bytes, SERIALIZED_SIZE - 8);
    put(p, &checksum, 8);
}

int instance_deserialize(const unsigned char *bytes, size_t size, Values *v, char *msg,
                         size_t len)
{
    char identity[FHOBS_IDENTITY_FIELD] = {0}, expected[FHOBS_IDENTITY_FIELD] = {0};
    strncpy(expected, FHOBS_IDENTITY, FHOBS_IDENTITY_FIELD - 1);
    if (!bytes || size < 8 + 4 + FHOBS_IDENTITY_FIELD || memcmp(bytes, STATE_HEADER, 8)) {
        snprintf(msg, len, "they are not a serialized FMU state of this FMU (its header is "
                 "missing)");
        return 1;
    }
    uint32_t format;
    int32_t mode;
    const unsigned char *p = get(bytes + 8, &format, 4);
    p = get(p, identity, FHOBS_IDENTITY_FIELD);
    if (format != STATE_FORMAT || memcmp(identity, expected, FHOBS_IDENTITY_FIELD)) {
        snprintf(msg, len, "they are a state of another FMU or format (its GUID differs)");
        return 1;
    }
    if (size != SERIALIZED_SIZE) {
        snprintf(msg, len, "they are not a serialized FMU state of this FMU (wrong size)");
        return 1;
    }
    uint64_t checksum;
    memcpy(&checksum, bytes + SERIALIZED_SIZE - 8, 8);
    if (checksum != fnv1a(bytes, SERIALIZED_SIZE - 8)) {
        snprintf(msg, len, "their checksum does not match (the bytes were changed after they "
                 "were serialized)");
        return 1;
    }
    p = get(p, &mode, 4);
    v->mode = mode;
    p = get(p, &v->time, 8);
    p = get(p, v->real, sizeof v->real);
    p = get(p, v->integer, sizeof v->integer);
    get(p, v->state, sizeof v->state);
    return 0;
}
