/*
 * A native fhobs FMU instance whatever its FMI version: its values, the start values, the
 * initialisation, a communication step with its checks and the coarse-step warning, the checks
 * of a write, the checks of a state handed back, FMU states in memory and as bytes (with the
 * FNV-1a checksum). The FMI 2.0 layer (fmi2_layer.c) and the FMI 3.0 layer (fmi3_layer.c) are
 * built on it and keep only their calls, arguments and messages; the model is reached through
 * model.h.
 */
#ifndef FHOBS_INSTANCE_H
#define FHOBS_INSTANCE_H

#include <stddef.h>

#include "model.h"

#define FHOBS_MESSAGE_SIZE 1024
#define FHOBS_IDENTITY_FIELD 48

/* The status of a call as the Integer/Int32 variable `status` holds it (fhobs.fmu.modes) and as
 * fmi2Status and fmi3Status number it. */
#define FHOBS_STATUS_OK 0
#define FHOBS_STATUS_WARNING 1
#define FHOBS_STATUS_ERROR 3

typedef struct {
    int mode;    /* the FMI state (fhobs_call_rules.h's FHOBS_STATE_* / FHOBS3_STATE_*) */
    double time; /* the last successful time: the start time, then the end of the last step */
    double real[FHOBS_N_VARIABLES]; /* by FMI 2.0 value reference (Integer variables: unused) */
    int integer[FHOBS_N_VARIABLES]; /* by FMI 2.0 value reference (Real variables: unused) */
    double state[FHOBS_STATE_SIZE]; /* the model's state */
} Values;

/* What an instance holds whatever its FMI version. */
typedef struct {
    Values values;
    Work *work;        /* the model's plans and scratch (model_work_size() bytes, the layer's) */
    double start_time; /* the host's start time */
    double time;       /* the end of the last step (the start time before one); NaN after an
                          FMU state was set: the next doStep's time is taken as it comes */
    int warned_coarse_step; /* a step longer than max_communication_step was warned of */
} Core;

/* `size` bytes of memory, zeroed, from a layer's allocator (`context`: its own), or NULL. */
typedef void *Allocate(void *context, size_t size);

/* A new instance (its work allocated by the layer) or a reset one: the start values and the
 * initial state of the start parameters, time 0, no plans, no warning given. */
FHOBS_HIDDEN void instance_reset(Core *c);
/* The host's start time (1 and the message naming `function` if it is not finite). */
FHOBS_HIDDEN int instance_set_start_time(Core *c, double start_time, const char *function,
                                         char *msg, size_t len);
/* The initialisation: the initial state of the parameters, the outputs, FMI state `mode`, the
 * time the start time (1 and the message if the parameters cannot start a run). */
FHOBS_HIDDEN int instance_exit_initialisation(Core *c, int mode, char *msg, size_t len);
/* A communication step of dt from t: FHOBS_STATUS_ERROR and the message (nothing changed),
 * FHOBS_STATUS_WARNING with the step made and the coarse-step warning in msg (the first step
 * of the instance longer than its max_communication_step), or FHOBS_STATUS_OK. */
FHOBS_HIDDEN int instance_do_step(Core *c, double t, double dt, char *msg, size_t len);
/* The values of an FMU state checked by instance_values_problem, taken. */
FHOBS_HIDDEN void instance_take(Core *c, const Values *v);
/* Why v is not a state of this FMU an instance can take (1, message) or 0; `initialised`:
 * whether its FMI state is after the initialisation (its parameters then checked as there). */
FHOBS_HIDDEN int instance_values_problem(const Values *v, int initialised, char *msg,
                                         size_t len);
/* Why the scalar variable `index` may not be given `value` (1, message) or 0: an output, the
 * local status, a parameter once `fixed` (its name and the format `fixed_format` with the
 * function, the variable, its index and `state`), a compiled parameter's other value. */
FHOBS_HIDDEN int instance_write_problem(unsigned index, double value, int fixed,
                                        const char *function, const char *fixed_format,
                                        const char *state, char *msg, size_t len);
/* Bytes of a serialized state. */
FHOBS_HIDDEN size_t instance_serialized_size(void);
/* v as instance_serialized_size() bytes: header, format, identity, the fields, checksum. */
FHOBS_HIDDEN void instance_serialize(const Values *v, unsigned char *bytes);
/* The values of serialized bytes (1 and why they are not a state of this FMU, or 0): header,
 * format, identity, size and checksum; the values themselves are checked by
 * instance_values_problem. */
FHOBS_HIDDEN int instance_deserialize(const unsigned char *bytes, size_t size, Values *v,
                                      char *msg, size_t len);

/* The values of an FMU state of this FMU (a pointer a layer handed out), or NULL. */
FHOBS_HIDDEN const Values *instance_snapshot(const void *state);
/* 0 and *state a snapshot of v (the one *state points to, else a new one from allocate), or 1
 * and why not naming `function`. */
FHOBS_HIDDEN int instance_store(void **state, const Values *v, Allocate *allocate,
                                void *context, const char *function, char *msg, size_t len);
/* The snapshot `state` (of this FMU: instance_snapshot) marked as no longer one. */
FHOBS_HIDDEN void instance_forget(void *state);

#endif
