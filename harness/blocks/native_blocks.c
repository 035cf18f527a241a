/*
 * FMI 2.0 co-simulation functions of a native harness block: the sine source and the matrix
 * gain of slaves.py in C (libc and libm only), with the pythonfmu blocks' interface.
 *
 *   sine: y[i] = amplitude[i] sin(omega[i] t + phase[i]) + offset[i], t the start time of
 *         fmi2SetupExperiment, then t + h after fmi2DoStep(t, h);
 *   gain: y = K u, K row-major, evaluated from the current inputs whenever y is read.
 *
 * Outputs are computed when read, as the pythonfmu blocks' getters do, with the same
 * operations in the same order (compiled without contraction into fused multiply-adds), so
 * both give the same doubles. A caller mistake is fmi2Error with a log message and changes
 * nothing: an unknown value reference, a variable of another type (every variable is Real), a
 * write to an output, a non-finite value, a call out of sequence (initialisation once, doStep
 * only between it and fmi2Terminate, nothing set after fmi2Terminate). The parameters are
 * tunable (settable between steps), as in the pythonfmu blocks, and there are no FMU states
 * (canGetAndSetFMUstate = false).
 *
 * Included by the generated fhobs_fmu.c, after native_blocks.h and the block's definitions:
 * BLOCK_KIND, BLOCK_IDENTITY (the GUID), N_VARIABLES, N_OUTPUTS, VR_Y and VARIABLES; the sine
 * also VR_AMPLITUDE, VR_OMEGA, VR_PHASE, VR_OFFSET; the gain N_INPUTS, VR_K, VR_U.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define BLOCK_MAGIC 0x68626c6bu /* "hblk" */
#define MESSAGE_SIZE 512

enum { INSTANTIATED, INITIALISATION, STEP_MODE, TERMINATED, MODE_COUNT };
static const char *const MODE_NAMES[MODE_COUNT] = {
    "instantiated", "initialisation mode", "step mode", "terminated"};

typedef struct {
    unsigned magic;
    fmi2CallbackFunctions callbacks;
    char *name;
    int mode;
    double time;              /* start time, then the end of the last step */
    double real[N_VARIABLES]; /* by value reference (outputs: unused, computed when read) */
} Block;

/* -- the block's outputs -------------------------------------------------------------------- */

#if BLOCK_KIND == BLOCK_SINE
static double output(const Block *b, int i)
{
    const double *p = b->real;
    return p[VR_AMPLITUDE + i] * sin(p[VR_OMEGA + i] * b->time + p[VR_PHASE + i]) +
           p[VR_OFFSET + i];
}
#elif BLOCK_KIND == BLOCK_GAIN
static double output(const Block *b, int i)
{
    double sum = 0.0;
    for (int j = 0; j < N_INPUTS; j++)
        sum += b->real[VR_K + i * N_INPUTS + j] * b->real[VR_U + j];
    return sum;
}
#else
#error "fhobs_fmu.c names no known BLOCK_KIND"
#endif

/* -- memory and messages ---------------------------------------------------------------------- */

static void *allocate(const fmi2CallbackFunctions *f, size_t size)
{
    return f->allocateMemory ? f->allocateMemory(1, size) : calloc(1, size);
}

static void release(const fmi2CallbackFunctions *f, void *p)
{
    if (f->freeMemory)
        f->freeMemory(p);
    else
        free(p);
}

/* Log the message (printf format) as an error of `b` and answer fmi2Error. The message is
 * passed as the logger's format, as hosts that do not forward the variable arguments (fmpy)
 * need: what it prints (numbers, variable names, mode names) holds no '%'. */
static fmi2Status refuse(const Block *b, const char *format, ...)
{
    char message[MESSAGE_SIZE];
    va_list args;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    if (b->callbacks.logger)
        b->callbacks.logger(b->callbacks.componentEnvironment, b->name, fmi2Error,
                            "logStatusError", message);
    return fmi2Error;
}

static Block *block(fmi2Component component)
{
    Block *b = component;
    return b && b->magic == BLOCK_MAGIC ? b : NULL;
}

#define BLOCK_OR_ERROR(component)                                                              \
    Block *b = block(component);                                                               \
    if (!b)                                                                                    \
        return fmi2Error;

static void start_values(Block *b)
{
    b->mode = INSTANTIATED;
    b->time = 0.0;
    for (int i = 0; i < N_VARIABLES; i++)
        b->real[i] = VARIABLES[i].start;
}

/* -- instances and the call sequence ---------------------------------------------------------- */

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
    Block probe;
    memset(&probe, 0, sizeof probe);
    probe.callbacks = *functions;
    probe.name = (char *)(instanceName ? instanceName : "");
    if (fmuType != fmi2CoSimulation) {
        refuse(&probe, "fmi2Instantiate: this FMU supports co-simulation only");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, BLOCK_IDENTITY) != 0) {
        refuse(&probe, "fmi2Instantiate: the GUID is not this FMU's (modelDescription.xml and "
                       "binary of different builds)");
        return NULL;
    }
    Block *b = allocate(functions, sizeof(Block));
    size_t length = strlen(probe.name) + 1;
    char *name = b ? allocate(functions, length) : NULL;
    if (!name) {
        if (b)
            release(functions, b);
        refuse(&probe, "fmi2Instantiate: out of memory");
        return NULL;
    }
    memset(b, 0, sizeof *b);
    memcpy(name, probe.name, length);
    b->magic = BLOCK_MAGIC;
    b->callbacks = *functions;
    b->name = name;
    start_values(b);
    return b;
}

void fmi2FreeInstance(fmi2Component component)
{
    Block *b = block(component);
    if (!b)
        return;
    fmi2CallbackFunctions callbacks = b->callbacks;
    b->magic = 0;
    release(&callbacks, b->name);
    release(&callbacks, b);
}

fmi2Status fmi2SetDebugLogging(fmi2Component component, fmi2Boolean loggingOn,
                               size_t nCategories, const fmi2String categories[])
{
    (void)loggingOn;
    (void)nCategories;
    (void)categories;
    BLOCK_OR_ERROR(component);
    return fmi2OK; /* errors are always logged; there are no other messages */
}

fmi2Status fmi2SetupExperiment(fmi2Component component, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    BLOCK_OR_ERROR(component);
    if (b->mode != INSTANTIATED)
        return refuse(b, "fmi2SetupExperiment called in %s: only before "
                         "fmi2EnterInitializationMode", MODE_NAMES[b->mode]);
    if (!isfinite(startTime))
        return refuse(b, "fmi2SetupExperiment: start time %.17g is not finite", startTime);
    b->time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component component)
{
    BLOCK_OR_ERROR(component);
    if (b->mode != INSTANTIATED)
        return refuse(b, "fmi2EnterInitializationMode called in %s: an instance is initialised "
                         "once (fmi2Reset first to start again)", MODE_NAMES[b->mode]);
    b->mode = INITIALISATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component component)
{
    BLOCK_OR_ERROR(component);
    if (b->mode != INITIALISATION)
        return refuse(b, "fmi2ExitInitializationMode called in %s: it must follow "
                         "fmi2EnterInitializationMode", MODE_NAMES[b->mode]);
    b->mode = STEP_MODE;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component component)
{
    BLOCK_OR_ERROR(component);
    if (b->mode != STEP_MODE)
        return refuse(b, "fmi2Terminate called in %s: it ends a run after "
                         "fmi2ExitInitializationMode", MODE_NAMES[b->mode]);
    b->mode = TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component component)
{
    BLOCK_OR_ERROR(component);
    start_values(b);
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentCommunicationPoint)
{
    (void)noSetFMUStatePriorToCurrentCommunicationPoint;
    BLOCK_OR_ERROR(component);
    if (b->mode != STEP_MODE)
        return refuse(b, "fmi2DoStep at t = %.17g called in %s: doStep runs between "
                         "fmi2ExitInitializationMode and fmi2Terminate",
                      currentCommunicationPoint, MODE_NAMES[b->mode]);
    if (!isfinite(currentCommunicationPoint) ||
        !(isfinite(communicationStepSize) && communicationStepSize > 0.0))
        return refuse(b, "fmi2DoStep(t = %.17g, h = %.17g): t must be finite and h positive "
                         "and finite", currentCommunicationPoint, communicationStepSize);
    b->time = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

/* -- get and set ------------------------------------------------------------------------------- */

/* fmi2Error with the message when `function` cannot access `vr` as a variable of type
 * `type` (every variable is Real), else fmi2OK. */
static fmi2Status reference_problem(const Block *b, const char *function,
                                    const fmi2ValueReference vr[], size_t nvr, const void *values,
                                    const char *type)
{
    if (nvr && (!vr || !values))
        return refuse(b, "%s: NULL value reference or value array", function);
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= N_VARIABLES)
            return refuse(b, "%s: value reference %u is not a variable of this FMU (its value "
                             "references are 0..%d)", function, vr[i], N_VARIABLES - 1);
        if (strcmp(type, "Real") != 0)
            return refuse(b, "%s: %s (value reference %u) is of type Real, not %s", function,
                          VARIABLES[vr[i]].name, vr[i], type);
    }
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[])
{
    BLOCK_OR_ERROR(component);
    if (reference_problem(b, "fmi2GetReal", vr, nvr, value, "Real") != fmi2OK)
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++)
        value[i] = VARIABLES[vr[i]].role == ROLE_OUTPUT ? output(b, (int)vr[i] - VR_Y)
                                                         : b->real[vr[i]];
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[])
{
    BLOCK_OR_ERROR(component);
    if (reference_problem(b, "fmi2SetReal", vr, nvr, value, "Real") != fmi2OK)
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const BlockVariable *var = &VARIABLES[vr[i]];
        if (b->mode == TERMINATED)
            return refuse(b, "fmi2SetReal: %s cannot be set after fmi2Terminate (fmi2Reset "
                             "returns to the start values)", var->name);
        if (var->role == ROLE_OUTPUT)
            return refuse(b, "fmi2SetReal: %s (value reference %u) is an output: the FMU "
                             "computes it, it cannot be set", var->name, vr[i]);
        if (!isfinite(value[i]))
            return refuse(b, "fmi2SetReal: %s %s = %.17g is not finite; nothing was set",
                          var->role == ROLE_INPUT ? "input" : "parameter", var->name, value[i]);
    }
    for (size_t i = 0; i < nvr; i++)
        b->real[vr[i]] = value[i];
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[])
{
    BLOCK_OR_ERROR(c);
    return reference_problem(b, "fmi2GetInteger", vr, nvr, value, "Integer");
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[])
{
    BLOCK_OR_ERROR(c);
    return reference_problem(b, "fmi2SetInteger", vr, nvr, value, "Integer");
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[])
{
    BLOCK_OR_ERROR(c);
    return reference_problem(b, "fmi2GetBoolean", vr, nvr, value, "Boolean");
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[])
{
    BLOCK_OR_ERROR(c);
    return reference_problem(b, "fmi2SetBoolean", vr, nvr, value, "Boolean");
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[])
{
    BLOCK_OR_ERROR(c);
    return reference_problem(b, "fmi2GetString", vr, nvr, value, "String");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[])
{
    BLOCK_OR_ERROR(c);
    return reference_problem(b, "fmi2SetString", vr, nvr, value, "String");
}

/* -- what the block does not provide ----------------------------------------------------------- */

static fmi2Status not_provided(fmi2Component component, const char *function, const char *why)
{
    BLOCK_OR_ERROR(component);
    return refuse(b, "%s: not provided (%s)", function, why);
}

#define NO_STATES "canGetAndSetFMUstate=false"
#define NO_STATUS "doStep never runs asynchronously"

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    (void)state;
    return not_provided(c, "fmi2GetFMUstate", NO_STATES);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state)
{
    (void)state;
    return not_provided(c, "fmi2SetFMUstate", NO_STATES);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    (void)state;
    return not_provided(c, "fmi2FreeFMUstate", NO_STATES);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size)
{
    (void)state;
    (void)size;
    return not_provided(c, "fmi2SerializedFMUstateSize", "canSerializeFMUstate=false");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[],
                                 size_t size)
{
    (void)state;
    (void)bytes;
    (void)size;
    return not_provided(c, "fmi2SerializeFMUstate", "canSerializeFMUstate=false");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size,
                                   fmi2FMUstate *state)
{
    (void)bytes;
    (void)size;
    (void)state;
    return not_provided(c, "fmi2DeSerializeFMUstate", "canSerializeFMUstate=false");
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference unknown[],
                                        size_t nUnknown, const fmi2ValueReference known[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[])
{
    (void)unknown;
    (void)nUnknown;
    (void)known;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return not_provided(c, "fmi2GetDirectionalDerivative", "providesDirectionalDerivative=false");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[])
{
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return not_provided(c, "fmi2SetRealInputDerivatives", "canInterpolateInputs=false");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[], fmi2Real value[])
{
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return not_provided(c, "fmi2GetRealOutputDerivatives", "maxOutputDerivativeOrder=0");
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    return not_provided(c, "fmi2CancelStep", NO_STATUS);
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    (void)s;
    (void)value;
    return not_provided(c, "fmi2GetStatus", NO_STATUS);
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    (void)s;
    (void)value;
    return not_provided(c, "fmi2GetRealStatus", NO_STATUS);
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s;
    (void)value;
    return not_provided(c, "fmi2GetIntegerStatus", NO_STATUS);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    (void)s;
    (void)value;
    return not_provided(c, "fmi2GetBooleanStatus", NO_STATUS);
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)s;
    (void)value;
    return not_provided(c, "fmi2GetStringStatus", NO_STATUS);
}
