/*
 * The values of a native fhobs FMU instance and what an FMI layer does with them whatever its
 * FMI version: the start values, the initialisation checks, a communication step with its
 * checks, the checks of a write, the checks of a state handed back, and a state's bytes (with
 * the FNV-1a checksum). The FMI 3.0 layer (fmi3_layer.c) is built on it; the model is reached
 * through model.h.
 */
#ifndef FHOBS_INSTANCE_H
#define FHOBS_INSTANCE_H

#include <stddef.h>

#include "model.h"

#define FHOBS_MESSAGE_SIZE 1024
#define FHOBS_IDENTITY_FIELD 48

typedef struct {
    int mode;    /* the FMI state (fhobs_call_rules.h's FHOBS_STATE_* / FHOBS3_STATE_*) */
    double time; /* the last successful time: the start time, then the end of the last step */
    double real[FHOBS_N_VARIABLES]; /* by FMI 2.0 value reference (Integer variables: unused) */
    int integer[FHOBS_N_VARIABLES]; /* by FMI 2.0 value reference (Real variables: unused) */
    double state[FHOBS_STATE_SIZE]; /* the model's state */
} Values;

/* The start values (state instantiated, time 0), the initial state and its outputs. */
FHOBS_HIDDEN void instance_start(Values *v, Work *w);
/* The outputs of the model's state into the variables. */
FHOBS_HIDDEN void instance_publish(Values *v, Work *w);
/* Why the parameters of v cannot start a run (1, message) or 0. */
FHOBS_HIDDEN int instance_parameters_problem(const Values *v, char *msg, size_t len);
/* The initial state of the parameters (1 and the message if they cannot start a run). */
FHOBS_HIDDEN int instance_initialise(Values *v, Work *w, char *msg, size_t len);
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
/* A communication step of dt from t of an instance whose own time is own_time (NaN: any):
 * 1 and the message (the values unchanged), or 0 with the step made and v->time = t + dt. */
FHOBS_HIDDEN int instance_step(Values *v, Work *w, double own_time, double t, double dt,
                               char *msg, size_t len);
/* Bytes of a serialized state. */
FHOBS_HIDDEN size_t instance_serialized_size(void);
/* v as instance_serialized_size() bytes: header, format, identity, the fields, checksum. */
FHOBS_HIDDEN void instance_serialize(const Values *v, unsigned char *bytes);
/* The values of serialized bytes (1 and why they are not a state of this FMU, or 0): header,
 * format, identity, size and checksum; the values themselves are checked by
 * instance_values_problem. */
FHOBS_HIDDEN int instance_deserialize(const unsigned char *bytes, size_t size, Values *v,
                                      char *msg, size_t len);

#endif
