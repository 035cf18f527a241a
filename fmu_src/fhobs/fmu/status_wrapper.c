/*
 * FMI 2.0 wrapper placed in front of pythonfmu's binary (linux64) by fhobs.build.
 *
 * pythonfmu 0.7.0 answers a Python exception with fmi2Fatal and a rejected do_step with
 * fmi2Discard; it has no way to return fmi2Error. The fhobs slaves record the status of
 * their last doStep / exitInitializationMode in the Integer variable of value reference
 * FHOBS_STATUS_VR. This library forwards every FMI function to pythonfmu's library (the
 * file next to it whose name ends in IMPL_SUFFIX) and, after fmi2DoStep and
 * fmi2ExitInitializationMode, returns that recorded status when it is worse.
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

/* The status recorded by the slave, if worse than the one returned. */
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

#define FORWARD(name, params, args) \
    fmi2Status name params { IMPL(name) return name##_impl args; }

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
    return ((fmi2InstantiateTYPE *)impl("fmi2Instantiate"))(
        instanceName, fmuType, guid, resources, functions, visible, loggingOn);
}

void fmi2FreeInstance(fmi2Component c)
{
    ((fmi2FreeInstanceTYPE *)impl("fmi2FreeInstance"))(c);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    IMPL(fmi2ExitInitializationMode)
    return recorded(c, fmi2ExitInitializationMode_impl(c));
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior)
{
    /* The slaves' do_step returns True (fmi2OK) only on success: no status to read then. */
    IMPL(fmi2DoStep)
    fmi2Status returned = fmi2DoStep_impl(c, t, h, noSetPrior);
    return returned == fmi2OK ? returned : recorded(c, returned);
}

FORWARD(fmi2SetDebugLogging, (fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]),
    (c, on, n, cat))
FORWARD(fmi2SetupExperiment, (fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real t0,
    fmi2Boolean stopDef, fmi2Real t1), (c, tolDef, tol, t0, stopDef, t1))
FORWARD(fmi2EnterInitializationMode, (fmi2Component c), (c))
FORWARD(fmi2Terminate, (fmi2Component c), (c))
FORWARD(fmi2Reset, (fmi2Component c), (c))
FORWARD(fmi2GetReal, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]),
    (c, vr, n, v))
FORWARD(fmi2GetInteger, (fmi2Component c, const fmi2ValueReference vr[], size_t n,
    fmi2Integer v[]), (c, vr, n, v))
FORWARD(fmi2GetBoolean, (fmi2Component c, const fmi2ValueReference vr[], size_t n,
    fmi2Boolean v[]), (c, vr, n, v))
FORWARD(fmi2GetString, (fmi2Component c, const fmi2ValueReference vr[], size_t n,
    fmi2String v[]), (c, vr, n, v))
FORWARD(fmi2SetReal, (fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2Real v[]), (c, vr, n, v))
FORWARD(fmi2SetInteger, (fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer v[]), (c, vr, n, v))
FORWARD(fmi2SetBoolean, (fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2Boolean v[]), (c, vr, n, v))
FORWARD(fmi2SetString, (fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2String v[]), (c, vr, n, v))
FORWARD(fmi2GetFMUstate, (fmi2Component c, fmi2FMUstate *s), (c, s))
FORWARD(fmi2SetFMUstate, (fmi2Component c, fmi2FMUstate s), (c, s))
FORWARD(fmi2FreeFMUstate, (fmi2Component c, fmi2FMUstate *s), (c, s))
FORWARD(fmi2SerializedFMUstateSize, (fmi2Component c, fmi2FMUstate s, size_t *size),
    (c, s, size))
FORWARD(fmi2SerializeFMUstate, (fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size),
    (c, s, b, size))
FORWARD(fmi2DeSerializeFMUstate, (fmi2Component c, const fmi2Byte b[], size_t size,
    fmi2FMUstate *s), (c, b, size, s))
FORWARD(fmi2GetDirectionalDerivative, (fmi2Component c, const fmi2ValueReference u[], size_t nu,
    const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]),
    (c, u, nu, z, nz, du, dz))
FORWARD(fmi2SetRealInputDerivatives, (fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer order[], const fmi2Real v[]), (c, vr, n, order, v))
FORWARD(fmi2GetRealOutputDerivatives, (fmi2Component c, const fmi2ValueReference vr[], size_t n,
    const fmi2Integer order[], fmi2Real v[]), (c, vr, n, order, v))
FORWARD(fmi2CancelStep, (fmi2Component c), (c))
FORWARD(fmi2GetStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Status *v), (c, k, v))
FORWARD(fmi2GetRealStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Real *v), (c, k, v))
FORWARD(fmi2GetIntegerStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Integer *v),
    (c, k, v))
FORWARD(fmi2GetBooleanStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v),
    (c, k, v))
FORWARD(fmi2GetStringStatus, (fmi2Component c, const fmi2StatusKind k, fmi2String *v),
    (c, k, v))
