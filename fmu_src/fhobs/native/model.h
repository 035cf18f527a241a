/*
 * The model of a native fhobs FMU as its instance core (instance.c) and FMI layer see it: the
 * sizes, value references and variable table of the generated model_data.h / model_data.c,
 * and the functions of the C model of the kind's plan family (family_<family>.c, one compiled
 * into each FMU, chosen by the generated source list; model_common.c beside it). The model's
 * per-instance data (Work: its plan cache and scratch memory) is opaque here: the layer
 * allocates model_work_size() bytes.
 */
#ifndef FHOBS_MODEL_H
#define FHOBS_MODEL_H

#include <stddef.h>

#include "fhobs_native.h"
#include "model_data.h"

typedef struct Work Work;

/* Bytes of a Work (allocated by the layer, zeroed, then work_init). */
FHOBS_HIDDEN size_t model_work_size(void);
/* An empty plan cache, the plans' scratch pointers set. */
FHOBS_HIDDEN void work_init(Work *w);
/* Why the per-instance parameters cannot start a run (1, message) or 0. */
FHOBS_HIDDEN int model_parameters_problem(const double *real, const int *integer, char *msg,
                                          size_t len);
/* The initial state from the parameters into state (FHOBS_STATE_SIZE); 1 with a message. */
FHOBS_HIDDEN int model_initial_state(const double *real, double *state, char *msg, size_t len);
/* One communication step dt from src into dst (FHOBS_STATE_SIZE each); 1 with a message, dst
 * then unspecified. */
FHOBS_HIDDEN int model_step(Work *w, const double *real, const int *integer, const double *src,
                            double *dst, double dt, char *msg, size_t len);
/* Why a finite model state is not one the model can continue from (1, message) or 0: a field
 * that is a count, an index or a mode not a whole number in its range, an offset or a time
 * outside its range. */
FHOBS_HIDDEN int model_state_problem(const double *state, char *msg, size_t len);
/* The outputs of the state into the variables. */
FHOBS_HIDDEN void model_outputs(Work *w, double *real, const int *integer, const double *state);

/* A number as the pythonfmu FMUs' messages show it (Python's repr, for most numbers). */
FHOBS_HIDDEN const char *fhobs_number(double x, char *buf, size_t len);

#endif
