/*
 * Types shared by the generated data (model_data.h, model_data.c), the model (family_*.c),
 * the instance core (instance.c) and the FMI layer (fmi2_layer.c or fmi3_layer.c) of a native
 * fhobs FMU. Each .c file of the FMU's sources is a translation unit of its own (kernel.c,
 * planner.c, gain_levels.c, model_data.c, model_common.c, the family's units, instance.c, the
 * layer, and noise.c for the plant), linked into one library that exports only the layer's
 * fmi2 or fmi3 functions.
 */
#ifndef FHOBS_NATIVE_H
#define FHOBS_NATIVE_H

#include <stddef.h>
#include <stdint.h>

#include "kernel.h"

/* variable types */
#define FHOBS_REAL 0
#define FHOBS_INTEGER 1

/* variable roles */
#define FHOBS_LOCAL 0     /* status: written by the FMU only */
#define FHOBS_INPUT 1
#define FHOBS_OUTPUT 2
#define FHOBS_COMPILED 3  /* design parameter compiled into the binary: only its value accepted */
#define FHOBS_SETTABLE 4  /* per-instance parameter: settable until fmi2ExitInitializationMode */

typedef struct {
    const char *name;
    int type, role;
    double start; /* exact start value (Integer variables: an exact integer) */
} FhobsVariable;

#endif
