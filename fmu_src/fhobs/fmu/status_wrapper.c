/*
 * FMI 2.0 wrapper placed in front of pythonfmu's binary (linux64) by fhobs.build.
 *
 * pythonfmu 0.7.0 answers a Python exception with fmi2Fatal and a rejected do_step with
 * fmi2Discard; it has no way to return fmi2Error. The fhobs slaves record the status of
 * their last doStep / exitInitializationMode in the Integer variable of value reference
 * FHOBS_STATUS_VR. This library forwards every FMI function to pythonfmu's library (the
 * file next to it whose name ends in IMPL_SUFFIX) and, after fmi2DoStep and
 * fmi2ExitInitializationMode, returns that recorded status when it is worse.
 *
 * Calls that do not go through pythonfmu's C++ layer. The component handed to the importer
 * is this library's own Instance, which holds pythonfmu's component. While pythonfmu's
 * fmi2Instantiate (or fmi2Reset) runs, the slave's constructor calls fhobs_register (through
 * ctypes) with the address of its flat float buffer of Real variables (which it never
 * reallocates), the buffer position of each value reference and a C callback of its doStep.
 * From then on:
 * - fmi2GetReal / fmi2SetReal whose value references are all Real variables read and write
 *   that buffer directly (exactly what the slave's get_real / set_real do); any other value
 *   reference goes to pythonfmu as before;
 * - fmi2DoStep calls the callback, which runs the slave's do_step and answers FHOBS_STEP_OK,
 *   FHOBS_STEP_OK_LOGGED (messages are waiting in the slave's log queue), FHOBS_STEP_REJECTED
 *   (do_step returned False: pythonfmu's fmi2Discard, made fmi2Error by the recorded status)
 *   or FHOBS_STEP_RAISED (do_step raised: the slave re-raises the exception in pythonfmu's
 *   fmi2DoStep, called next, which answers fmi2Fatal and logs it as it always did). Waiting
 *   messages are handed to the importer's logger by any pythonfmu call: the status read.
 *   The last successful time that pythonfmu's fmi2GetRealStatus reports is kept here for
 *   those steps (t + h after a step, t after a rejected one, as pythonfmu sets it).
 * Without a registration every call goes to pythonfmu.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#ifndef FHOBS_STATUS_VR
#error "compile with -DFHOBS_STATUS_VR=<value reference of the status variable>"
#endif
#define IMPL_SUFFIX "_pythonfmu.so"

static void *impl_handle = NULL;

/* Answers of the slave's doStep callback (0: the callback itself failed). */
#define FHOBS_STEP_OK 1
#define FHOBS_STEP_OK_LOGGED 2
#define FHOBS_STEP_REJECTED 3
#define FHOBS_STEP_RAISED 4

typedef int fhobs_step_fn(double t, double h);

/* The component returned to the importer. */
typedef struct {
    fmi2Component impl;      /* pythonfmu's component */
    double *values;          /* the slave's flat Real buffer; NULL: nothing registered */
    long long *position;     /* position[vr]: buffer index of Real variable vr, or -1 */
    size_t n_position;
    fhobs_step_fn *step;     /* the slave's doStep */
    int own_time;            /* whether the last doStep went through step */
    double last_time;        /* then: the last successful time */
} Instance;

/* The instance whose Python slave is being constructed by this thread (fmi2Instantiate,
 * fmi2Reset), for fhobs_register. */
static __thread Instance *registering = NULL;

#define INNER(c) ((c) == NULL ? NULL : ((Instance *)(c))->impl)

static void *impl(const char *name)
{
    void *f = impl_handle ? dlsym(impl_handle, name) : NULL;
    if (f == NULL) {
        fprintf(stderr, "fhobs status wrapper: cannot resolve %s: %s\n", name, dlerror());
        abort();
    }
    return f;
}

/* The entry point ``name`` of pythonfmu's library, looked up once (a benign race: every thread
 * that looks it up stores the same pointer). */
#define IMPL(name) \
    static name##TYPE *name##_impl = NULL; \
    if (name##_impl == NULL) { \
        name##_impl = (name##TYPE *)impl(#name); \
    }

__attribute__((constructor)) static void load_impl(void)
{
    Dl_info info;
    if (dladdr((void *)&load_impl, &info) == 0 || info.dli_fname == NULL) {
        return;
    }
    size_t len = strlen(info.dli_fname);
    char *path = malloc(len + sizeof(IMPL_SUFFIX));
    if (path == NULL || len < 3) {
        free(path);
        return;
    }
    memcpy(path, info.dli_fname, len - 3); /* drop ".so" */
    strcpy(path + len - 3, IMPL_SUFFIX);
    impl_handle = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (impl_handle == NULL) {
        fprintf(stderr, "fhobs status wrapper: %s\n", dlerror());
    }
    free(path);
}

__attribute__((destructor)) static void unload_impl(void)
{
    if (impl_handle != NULL) {
        dlclose(impl_handle);
    }
}

/* Called by the slave's constructor (through ctypes) while its instance is created: give
 * fmi2GetReal / fmi2SetReal direct access to ``values`` (``n_values`` doubles, kept alive and
 * never moved by the slave), ``position[vr]`` being the index of Real variable vr or -1, and
 * fmi2DoStep the slave's ``step`` (kept alive by the slave). Returns 1 if registered, 0 if no
 * instance is being created by this thread or the arguments are inconsistent (then every call
 * goes through pythonfmu). */
int fhobs_register(double *values, size_t n_values, const long long *position,
    size_t n_position, fhobs_step_fn *step)
{
    Instance *w = registering;
    if (w == NULL || values == NULL || position == NULL || n_position == 0 || step == NULL) {
        return 0;
    }
    for (size_t i = 0; i < n_position; i++) {
        if (position[i] < -1 || (position[i] >= 0 && (size_t)position[i] >= n_values)) {
            return 0;
        }
    }
    long long *copy = malloc(n_position * sizeof *copy);
    if (copy == NULL) {
        return 0;
    }
    memcpy(copy, position, n_position * sizeof *copy);
    free(w->position);
    w->position = copy;
    w->n_position = n_position;
    w->values = values;
    w->step = step;
    return 1;
}

static void unregister(Instance *w)
{
    w->values = NULL;
    w->step = NULL;
    free(w->position);
    w->position = NULL;
    w->n_position = 0;
}

/* Whether every value reference is a registered Real variable (then the buffer is used). */
static int direct(const Instance *w, const fmi2ValueReference vr[], size_t n)
{
    if (w == NULL || w->values == NULL || vr == NULL || n == 0) {
        return 0;
    }
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= w->n_position || w->position[vr[i]] < 0) {
            return 0;
        }
    }
    return 1;
}

/* The status recorded by the slave (pythonfmu's component c), if worse than the one returned. */
static fmi2Status recorded(fmi2Component c, fmi2Status returned)
{
    if (returned == fmi2Fatal || returned == fmi2Error || c == NULL) {
        return returned;
    }
    const fmi2ValueReference vr = FHOBS_STATUS_VR;
    fmi2Integer status = fmi2OK;
    IMPL(fmi2GetInteger)
    if (fmi2GetInteger_impl(c, &vr, 1, &status) != fmi2OK) {
        return returned;
    }
    return status > (fmi2Integer)returned ? (fmi2Status)status : returned;
}

/* Forward ``name`` to pythonfmu's library with pythonfmu's component in place of ours. */
#define FORWARD(name, params, args) \
    fmi2Status name params { IMPL(name) fmi2Component c = INNER(w); return name##_impl args; }

const char *fmi2GetTypesPlatform(void)
{
    return ((fmi2GetTypesPlatformTYPE *)impl("fmi2GetTypesPlatform"))();
}

const char *fmi2GetVersion(void)
{
    return ((fmi2GetVersionTYPE *)impl("fmi2GetVersion"))();
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String guid,
    fmi2String resources, const fmi2CallbackFunctions *functions, fmi2Boolean visible,
    fmi2Boolean loggingOn)
{
    Instance *w = calloc(1, sizeof *w);
    if (w == NULL) {
        return NULL;
    }
    Instance *outer = registering; /* restored: instantiations may nest */
    registering = w;
    w->impl = ((fmi2InstantiateTYPE *)impl("fmi2Instantiate"))(
        instanceName, fmuType, guid, resources, functions, visible, loggingOn);
    registering = outer;
    if (w->impl == NULL) {
        unregister(w);
        free(w);
        return NULL;
    }
    return w;
}

void fmi2FreeInstance(fmi2Component w)
{
    ((fmi2FreeInstanceTYPE *)impl("fmi2FreeInstance"))(INNER(w));
    if (w != NULL) {
        unregister((Instance *)w);
        free(w);
    }
}

fmi2Status fmi2Reset(fmi2Component w)
{
    /* pythonfmu replaces the Python slave: its new constructor registers its own buffer. */
    IMPL(fmi2Reset)
    if (w == NULL) {
        return fmi2Reset_impl(NULL);
    }
    Instance *self = w, *outer = registering;
    unregister(self);
    registering = self;
    fmi2Status status = fmi2Reset_impl(self->impl);
    registering = outer;
    return status;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component w)
{
    IMPL(fmi2ExitInitializationMode)
    return recorded(INNER(w), fmi2ExitInitializationMode_impl(INNER(w)));
}

fmi2Status fmi2DoStep(fmi2Component w, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior)
{
    Instance *self = w;
    IMPL(fmi2DoStep)
    if (self != NULL && self->step != NULL) {
        switch (self->step(t, h)) {
        case FHOBS_STEP_OK:
            self->own_time = 1;
            self->last_time = t + h;
            return fmi2OK;
        case FHOBS_STEP_OK_LOGGED:
            self->own_time = 1;
            self->last_time = t + h;
            recorded(self->impl, fmi2OK); /* a pythonfmu call: hands the messages over */
            return fmi2OK;
        case FHOBS_STEP_REJECTED:
            self->own_time = 1;
            self->last_time = t;
            return recorded(self->impl, fmi2Discard);
        case FHOBS_STEP_RAISED:
            return fmi2DoStep_impl(self->impl, t, h, noSetPrior); /* re-raised there: fatal */
        default:
            return fmi2Fatal;
        }
    }
    /* The slaves' do_step returns True (fmi2OK) only on success: no status to read then. */
    fmi2Status returned = fmi2DoStep_impl(INNER(w), t, h, noSetPrior);
    if (self != NULL && (returned == fmi2OK || returned == fmi2Discard)) {
        self->own_time = 0; /* pythonfmu set its last successful time (not after an exception) */
    }
    return returned == fmi2OK ? returned : recorded(INNER(w), returned);
}

fmi2Status fmi2GetRealStatus(fmi2Component w, const fmi2StatusKind k, fmi2Real *v)
{
    const Instance *self = w;
    if (self != NULL && self->own_time && k == fmi2LastSuccessfulTime && v != NULL) {
        *v = self->last_time;
        return fmi2OK;
    }
    IMPL(fmi2GetRealStatus)
    return fmi2GetRealStatus_impl(INNER(w), k, v);
}

fmi2Status fmi2GetReal(fmi2Component w, const fmi2ValueReference vr[], size_t n, fmi2Real v[])
{
    const Instance *self = w;
    if (v != NULL && direct(self, vr, n)) {
        for (size_t i = 0; i < n; i++) {
            v[i] = self->values[self->position[vr[i]]];
        }
        return fmi2OK;
    }
    IMPL(fmi2GetReal)
    return fmi2GetReal_impl(INNER(w), vr, n, v);
}

fmi2Status fmi2SetReal(fmi2Component w, const fmi2ValueReference vr[], size_t n,
    const fmi2Real v[])
{
    Instance *self = w;
    if (v != NULL && direct(self, vr, n)) {
        for (size_t i = 0; i < n; i++) {
            self->values[self->position[vr[i]]] = v[i];
        }
        return fmi2OK;
    }
    IMPL(fmi2SetReal)
    return fmi2SetReal_impl(INNER(w), vr, n, v);
}

FORWARD(fmi2SetDebugLogging, (fmi2Component w, fmi2Boolean on, size_t n, const fmi2String cat[]),
    (c, on, n, cat))
FORWARD(fmi2SetupExperiment, (fmi2Component w, fmi2Boolean tolDef, fmi2Real tol, fmi2Real t0,
    fmi2Boolean stopDef, fmi2Real t1), (c, tolDef, tol, t0, stopDef, t1))
FORWARD(fmi2EnterInitializationMode, (fmi2Component w), (c))
FORWARD(fmi2Terminate, (fmi2Component w), (c))
FORWARD(fmi2GetInteger, (fmi2Component w, const fmi2ValueReference vr[], size_t n,
    fmi2Integer v[]), (c, vr, n, v))
FORWARD(fmi2GetBoolean, (fmi2Component w, const fmi2ValueReference vr[], size_t n,
    fmi2Boolean v[]), (c, vr, n, v))
FORWARD(fmi2GetString, (fmi2Component w, const fmi2ValueReference vr[], size_t n,
    fmi2String v[]), (c, vr, n, v))
FORWARD(fmi2SetInteger, (fmi2Component w, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer v[]), (c, vr, n, v))
FORWARD(fmi2SetBoolean, (fmi2Component w, const fmi2ValueReference vr[], size_t n,
    const fmi2Boolean v[]), (c, vr, n, v))
FORWARD(fmi2SetString, (fmi2Component w, const fmi2ValueReference vr[], size_t n,
    const fmi2String v[]), (c, vr, n, v))
FORWARD(fmi2GetFMUstate, (fmi2Component w, fmi2FMUstate *s), (c, s))
FORWARD(fmi2SetFMUstate, (fmi2Component w, fmi2FMUstate s), (c, s))
FORWARD(fmi2FreeFMUstate, (fmi2Component w, fmi2FMUstate *s), (c, s))
FORWARD(fmi2SerializedFMUstateSize, (fmi2Component w, fmi2FMUstate s, size_t *size),
    (c, s, size))
FORWARD(fmi2SerializeFMUstate, (fmi2Component w, fmi2FMUstate s, fmi2Byte b[], size_t size),
    (c, s, b, size))
FORWARD(fmi2DeSerializeFMUstate, (fmi2Component w, const fmi2Byte b[], size_t size,
    fmi2FMUstate *s), (c, b, size, s))
FORWARD(fmi2GetDirectionalDerivative, (fmi2Component w, const fmi2ValueReference u[], size_t nu,
    const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]),
    (c, u, nu, z, nz, du, dz))
FORWARD(fmi2SetRealInputDerivatives, (fmi2Component w, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer order[], const fmi2Real v[]), (c, vr, n, order, v))
FORWARD(fmi2GetRealOutputDerivatives, (fmi2Component w, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer order[], fmi2Real v[]), (c, vr, n, order, v))
FORWARD(fmi2CancelStep, (fmi2Component w), (c))
FORWARD(fmi2GetStatus, (fmi2Component w, const fmi2StatusKind k, fmi2Status *v), (c, k, v))
FORWARD(fmi2GetIntegerStatus, (fmi2Component w, const fmi2StatusKind k, fmi2Integer *v),
    (c, k, v))
FORWARD(fmi2GetBooleanStatus, (fmi2Component w, const fmi2StatusKind k, fmi2Boolean *v),
    (c, k, v))
FORWARD(fmi2GetStringStatus, (fmi2Component w, const fmi2StatusKind k, fmi2String *v),
    (c, k, v))
