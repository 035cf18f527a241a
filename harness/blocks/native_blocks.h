/*
 * Types of a native harness block FMU (harness/blocks/native.py): its generated unit
 * fhobs_fmu.c defines the block's kind, sizes, value references and variable table (read from
 * the pythonfmu block's modelDescription) and then includes native_blocks.c.
 */
#ifndef NATIVE_BLOCKS_H
#define NATIVE_BLOCKS_H

/* block kinds (BLOCK_KIND) */
#define BLOCK_SINE 1
#define BLOCK_GAIN 2

/* causalities */
#define ROLE_PARAMETER 0 /* tunable: settable in every mode but terminated */
#define ROLE_INPUT 1
#define ROLE_OUTPUT 2    /* computed when read */

typedef struct {
    const char *name;
    int role;
    double start;
} BlockVariable;

#endif
