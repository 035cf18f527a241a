/*
 * Types of a native harness block FMU (harness/blocks/native.py): its generated unit
 * fhobs_fmu.c defines the block's kind, sizes, value references and variable table (read from
 * the pythonfmu block's modelDescription) and then includes native_blocks.c.
 */
#ifndef NATIVE_BLOCKS_H
#define NATIVE_BLOCKS_H

/* block kinds (BLOCK_KIND) */
#define BLOCK_SINE 1
#define BLOCK_CONSTANT 2
#define BLOCK_GAIN 3
#define BLOCK_SUM 4
#define BLOCK_SIGNAL 5
#define BLOCK_NOISE 6

/* causalities and variabilities */
#define ROLE_TUNABLE 0 /* parameter settable in every mode but terminated */
#define ROLE_FIXED 1   /* parameter settable before fmi2ExitInitializationMode only */
#define ROLE_INPUT 2
#define ROLE_OUTPUT 3  /* computed when read */

/* types */
#define TYPE_REAL 0
#define TYPE_INTEGER 1

typedef struct {
    const char *name;
    int role;
    int type;
    double start; /* an Integer's exactly */
} BlockVariable;

#endif
