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
 *   reference goes to pythonfmu unchanged;
 * - fmi2DoStep calls the callback, which runs the slave's do_step and answers FHOBS_STEP_OK,
 *   FHOBS_STEP_OK_LOGGED (messages are waiting in the slave's log queue), FHOBS_STEP_REJECTED
 *   (do_step returned False: pythonfmu's fmi2Discard, made fmi2Error by the recorded status)
 *   or FHOBS_STEP_RAISED (do_step raised: the slave re-raises the exception in pythonfmu's
 *   fmi2DoStep, called next, which answers fmi2Fatal and logs it as it always did). Waiting
 *   messages are handed to the importer's logger by any pythonfmu call: the status read.
 *   The last successful time that pythonfmu's fmi2GetRealStatus reports is kept here for
 *   those steps (t + h after a step, t after a rejected one, as pythonfmu sets it).
 * - any other fmi2Get/Set call is first put to the slave's access callback, which answers
 *   whether it may go ahead; a refusal (unknown value reference, another type, a write to an
 *   output or, after initialisation, to a parameter) is answered with fmi2Error and the
 *   slave's message, without reaching pythonfmu;
 * - bytes handed to fmi2DeSerializeFMUstate are first put to the slave's state callback.
 * Without a registration every call goes to pythonfmu.
 *
 * Caller mistakes never reach pythonfmu's exception path (fmi2Fatal, after which pythonfmu has
 * released the slave and further calls can crash the host): besides the callbacks above, FMU
 * states are this library's own objects, recorded in a list: a state pointer that this library
 * did not hand out (of another FMU, freed, or garbage) is refused with fmi2Error and never
 * dereferenced. After fmi2EnterInitializationMode, fmi2Terminate and fmi2SetFMUstate the
 * slave's recorded status is returned as after fmi2ExitInitializationMode (call sequence and
 * state checks of the slave).
 *
 * If pythonfmu's library cannot be loaded (a native host without libpython in the process),
 * fmi2Instantiate hands the loader's message to the host's logger and returns NULL, and every
 * other function returns fmi2Error: nothing aborts the host. Messages of this library go to
 * the host's logger whatever loggingOn says (they are errors, not debug logging).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#ifndef FHOBS_STATUS_VR
#error "compile with -DFHOBS_STATUS_VR=<value reference of the status variable>"
#endif
#define IMPL_SUFFIX "_pythonfmu.so"

static void *impl_handle = NULL;
static char load_error[1024] = "pythonfmu's library was not loaded";

/* Answers of the slave's doStep callback (0: the callback itself failed). */
#define FHOBS_STEP_OK 1
#define FHOBS_STEP_OK_LOGGED 2
#define FHOBS_STEP_REJECTED 3
#define FHOBS_STEP_RAISED 4

/* Codes of the get/set functions for the access callback (ACCESS_FUNCTIONS in slave_base). */
enum { FHOBS_GET_REAL, FHOBS_SET_REAL, FHOBS_GET_INTEGER, FHOBS_SET_INTEGER, FHOBS_GET_BOOLEAN,
    FHOBS_SET_BOOLEAN, FHOBS_GET_STRING, FHOBS_SET_STRING };

typedef int fhobs_step_fn(double t, double h);
typedef int fhobs_access_fn(int function, const fmi2ValueReference *vr, size_t n);
typedef int fhobs_state_fn(const void *bytes, size_t size);

/* The component returned to the importer. */
typedef struct {
    fmi2Component impl;      /* pythonfmu's component */
    double *values;          /* the slave's flat Real buffer; NULL: nothing registered */
    long long *position;     /* position[vr]: buffer index of Real variable vr, or -1 */
    const unsigned char *writable; /* writable[vr]: fmi2SetReal may write vr now (slave's) */
    size_t n_position;
    fhobs_step_fn *step;     /* the slave's doStep */
    fhobs_access_fn *access; /* the slave's check of a get/set call */
    fhobs_state_fn *check_state; /* the slave's check of a serialized state */
    int own_time;            /* whether the last doStep went through step */
    double last_time;        /* then: the last successful time */
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment environment;
    char *name;              /* instance name */
} Instance;

/* An FMU state handed to the importer: pythonfmu's state, in the list of live states. */
typedef struct State {
    fmi2FMUstate impl;
    struct State *next;
} State;

static State *states = NULL;
static pthread_mutex_t states_lock = PTHREAD_MUTEX_INITIALIZER;

/* The instance whose Python slave is being constructed by this thread (fmi2Instantiate,
 * fmi2Reset), for fhobs_register. */
static __thread Instance *registering = NULL;

#define INNER(c) ((c) == NULL ? NULL : ((Instance *)(c))->impl)

/* Hand a message to the host's logger ('%' doubled: the logger takes a format string). */
static void say(fmi2CallbackLogger logger, fmi2ComponentEnvironment environment,
    const char *name, fmi2Status status, const char *format, ...)
{
    if (logger == NULL) {
        return;
    }
    char text[2048], escaped[4096];
    va_list args;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    size_t j = 0;
    for (size_t i = 0; text[i] != '\0' && j + 2 < sizeof escaped; i++) {
        if (text[i] == '%') {
            escaped[j++] = '%';
        }
        escaped[j++] = text[i];
    }
    escaped[j] = '\0';
    logger(environment, name != NULL ? name : "", status,
        status == fmi2Error ? "logStatusError" : "logAll", escaped);
}

#define REFUSE(w, ...) \
    (say((w)->logger, (w)->environment, (w)->name, fmi2Error, __VA_ARGS__), fmi2Error)

static void *impl(const char *name)
{
    return impl_handle ? dlsym(impl_handle, name) : NULL;
}

/* The entry point ``name`` of pythonfmu's library, looked up once (a benign race: every thread
 * that looks it up stores the same pointer); ``failed`` is returned when there is none. */
#define IMPL(name, failed) \
    static name##TYPE *name##_impl = NULL; \
    if (name##_impl == NULL) { \
        name##_impl = (name##TYPE *)impl(#name); \
        if (name##_impl == NULL) { \
            return failed; \
        } \
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
        const char *why = dlerror();
        snprintf(load_error, sizeof load_error, "cannot load pythonfmu's library: %s%s",
            why != NULL ? why : path,
            " (a native host needs libpython in the process, e.g. LD_PRELOAD of "
            "libpython3.11.so, and numpy importable by that interpreter)");
        fprintf(stderr, "fhobs status wrapper: %s\n", load_error);
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
 * never moved by the slave), ``position[vr]`` being the index of Real variable vr or -1 and
 * ``writable[vr]`` whether fmi2SetReal may write it now (the slave keeps it up to date), and
 * give the wrapper the slave's ``step``, ``access`` and ``check_state`` (kept alive by the
 * slave). Returns 1 if registered, 0 if no instance is being created by this thread or the
 * arguments are inconsistent (then every call goes through pythonfmu). */
int fhobs_register(double *values, size_t n_values, const long long *position,
    const unsigned char *writable, size_t n_position, fhobs_step_fn *step,
    fhobs_access_fn *access, fhobs_state_fn *check_state)
{
    Instance *w = registering;
    if (w == NULL || values == NULL || position == NULL || writable == NULL || n_position == 0
        || step == NULL || access == NULL || check_state == NULL) {
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
    w->writable = writable;
    w->n_position = n_position;
    w->values = values;
    w->step = step;
    w->access = access;
    w->check_state = check_state;
    return 1;
}

static void unregister(Instance *w)
{
    w->values = NULL;
    w->step = NULL;
    w->access = NULL;
    w->check_state = NULL;
    w->writable = NULL;
    free(w->position);
    w->position = NULL;
    w->n_position = 0;
}

/* Whether every value reference is a registered Real variable, writable now if ``write``
 * (then the buffer is used). */
static int direct(const Instance *w, const fmi2ValueReference vr[], size_t n, int write)
{
    if (w == NULL || w->values == NULL || vr == NULL || n == 0) {
        return 0;
    }
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= w->n_position || w->position[vr[i]] < 0 || (write && !w->writable[vr[i]])) {
            return 0;
        }
    }
    return 1;
}

/* The status recorded by the slave (pythonfmu's component c), if worse than the one returned;
 * reading it is a pythonfmu call, which hands the slave's waiting messages to the logger. */
static fmi2Status recorded(fmi2Component c, fmi2Status returned)
{
    if (returned == fmi2Fatal || c == NULL) {
        return returned;
    }
    const fmi2ValueReference vr = FHOBS_STATUS_VR;
    fmi2Integer status = fmi2OK;
    IMPL(fmi2GetInteger, returned)
    if (fmi2GetInteger_impl(c, &vr, 1, &status) != fmi2OK) {
        return returned;
    }
    return status > (fmi2Integer)returned ? (fmi2Status)status : returned;
}

/* Whether a get/set call may go to pythonfmu: its arrays are there, and the slave (if
 * registered) accepts it; otherwise the answer to return is left in *answer. */
static int allowed(Instance *w, int function, const fmi2ValueReference vr[], size_t n,
    const void *v, fmi2Status *answer)
{
    static const char *names[] = { "fmi2GetReal", "fmi2SetReal", "fmi2GetInteger",
        "fmi2SetInteger", "fmi2GetBoolean", "fmi2SetBoolean", "fmi2GetString",
        "fmi2SetString" };
    if (w == NULL) {
        *answer = fmi2Error;
        return 0;
    }
    if (n > 0 && (vr == NULL || v == NULL)) {
        *answer = REFUSE(w, "%s: NULL array of value references or values for %zu variables",
            names[function], n);
        return 0;
    }
    if (n > 0 && w->access != NULL && !w->access(function, vr, n)) {
        *answer = recorded(w->impl, fmi2Error); /* hands the slave's message over */
        return 0;
    }
    return 1;
}

/* Put a new state of pythonfmu into the list; NULL if out of memory. */
static State *issue(fmi2FMUstate inner)
{
    State *s = malloc(sizeof *s);
    if (s == NULL) {
        return NULL;
    }
    s->impl = inner;
    pthread_mutex_lock(&states_lock);
    s->next = states;
    states = s;
    pthread_mutex_unlock(&states_lock);
    return s;
}

/* Whether ``state`` is a live state handed out by this library (not dereferenced otherwise). */
static int issued(const void *state)
{
    int found = 0;
    pthread_mutex_lock(&states_lock);
    for (const State *s = states; s != NULL && !found; s = s->next) {
        found = (const void *)s == state;
    }
    pthread_mutex_unlock(&states_lock);
    return found;
}

static void withdraw(State *state)
{
    pthread_mutex_lock(&states_lock);
    for (State **s = &states; *s != NULL; s = &(*s)->next) {
        if (*s == state) {
            *s = state->next;
            break;
        }
    }
    pthread_mutex_unlock(&states_lock);
    free(state);
}

#define FOREIGN_STATE "%s: the FMU state %p was not made by this FMU (fmi2GetFMUstate or " \
    "fmi2DeSerializeFMUstate of an instance of it), or was freed"

/* Forward ``name`` to pythonfmu's library with pythonfmu's component in place of ours. */
#define FORWARD(name, params, args) \
    fmi2Status name params { IMPL(name, fmi2Error) fmi2Component c = INNER(w); return name##_impl args; }

/* Forward a get/set call once the slave accepts it. */
#define FORWARD_ACCESS(name, code, params, args) \
    fmi2Status name params \
    { \
        IMPL(name, fmi2Error) \
        fmi2Status answer; \
        if (!allowed(w, code, vr, n, v, &answer)) { \
            return answer; \
        } \
        fmi2Component c = INNER(w); \
        return name##_impl args; \
    }

const char *fmi2GetTypesPlatform(void)
{
    return fmi2TypesPlatform;
}

const char *fmi2GetVersion(void)
{
    return fmi2Version;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String guid,
    fmi2String resources, const fmi2CallbackFunctions *functions, fmi2Boolean visible,
    fmi2Boolean loggingOn)
{
    fmi2CallbackLogger logger = functions != NULL ? functions->logger : NULL;
    fmi2ComponentEnvironment environment = functions != NULL ? functions->componentEnvironment
                                                             : NULL;
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)impl("fmi2Instantiate");
    if (instantiate == NULL) {
        say(logger, environment, instanceName, fmi2Error, "fhobs status wrapper: %s",
            load_error);
        return NULL;
    }
    Instance *w = calloc(1, sizeof *w);
    if (w == NULL) {
        return NULL;
    }
    w->logger = logger;
    w->environment = environment;
    w->name = strdup(instanceName != NULL ? instanceName : "");
    Instance *outer = registering; /* restored: instantiations may nest */
    registering = w;
    w->impl = instantiate(instanceName, fmuType, guid, resources, functions, visible, loggingOn);
    registering = outer;
    if (w->impl == NULL) {
        unregister(w);
        free(w->name);
        free(w);
        return NULL;
    }
    return w;
}

void fmi2FreeInstance(fmi2Component w)
{
    fmi2FreeInstanceTYPE *free_instance = (fmi2FreeInstanceTYPE *)impl("fmi2FreeInstance");
    if (free_instance != NULL) {
        free_instance(INNER(w));
    }
    if (w != NULL) {
        unregister((Instance *)w);
        free(((Instance *)w)->name);
        free(w);
    }
}

fmi2Status fmi2Reset(fmi2Component w)
{
    /* pythonfmu replaces the Python slave: its new constructor registers its own buffer. */
    IMPL(fmi2Reset, fmi2Error)
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

fmi2Status fmi2EnterInitializationMode(fmi2Component w)
{
    IMPL(fmi2EnterInitializationMode, fmi2Error)
    return recorded(INNER(w), fmi2EnterInitializationMode_impl(INNER(w)));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component w)
{
    IMPL(fmi2ExitInitializationMode, fmi2Error)
    return recorded(INNER(w), fmi2ExitInitializationMode_impl(INNER(w)));
}

fmi2Status fmi2Terminate(fmi2Component w)
{
    IMPL(fmi2Terminate, fmi2Error)
    return recorded(INNER(w), fmi2Terminate_impl(INNER(w)));
}

fmi2Status fmi2DoStep(fmi2Component w, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior)
{
    Instance *self = w;
    IMPL(fmi2DoStep, fmi2Error)
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
    IMPL(fmi2GetRealStatus, fmi2Error)
    return fmi2GetRealStatus_impl(INNER(w), k, v);
}

fmi2Status fmi2GetReal(fmi2Component w, const fmi2ValueReference vr[], size_t n, fmi2Real v[])
{
    const Instance *self = w;
    if (v != NULL && direct(self, vr, n, 0)) {
        for (size_t i = 0; i < n; i++) {
            v[i] = self->values[self->position[vr[i]]];
        }
        return fmi2OK;
    }
    IMPL(fmi2GetReal, fmi2Error)
    fmi2Status answer;
    if (!allowed(w, FHOBS_GET_REAL, vr, n, v, &answer)) {
        return answer;
    }
    return fmi2GetReal_impl(INNER(w), vr, n, v);
}

fmi2Status fmi2SetReal(fmi2Component w, const fmi2ValueReference vr[], size_t n,
    const fmi2Real v[])
{
    Instance *self = w;
    if (v != NULL && direct(self, vr, n, 1)) {
        for (size_t i = 0; i < n; i++) {
            self->values[self->position[vr[i]]] = v[i];
        }
        return fmi2OK;
    }
    IMPL(fmi2SetReal, fmi2Error)
    fmi2Status answer;
    if (!allowed(w, FHOBS_SET_REAL, vr, n, v, &answer)) {
        return answer;
    }
    return fmi2SetReal_impl(INNER(w), vr, n, v);
}

FORWARD_ACCESS(fmi2GetInteger, FHOBS_GET_INTEGER, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, fmi2Integer v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2GetBoolean, FHOBS_GET_BOOLEAN, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2GetString, FHOBS_GET_STRING, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, fmi2String v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2SetInteger, FHOBS_SET_INTEGER, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2SetBoolean, FHOBS_SET_BOOLEAN, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2SetString, FHOBS_SET_STRING, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, const fmi2String v[]), (c, vr, n, v))

fmi2Status fmi2GetFMUstate(fmi2Component w, fmi2FMUstate *s)
{
    IMPL(fmi2GetFMUstate, fmi2Error)
    IMPL(fmi2FreeFMUstate, fmi2Error)
    Instance *self = w;
    if (self == NULL) {
        return fmi2Error;
    }
    if (s == NULL) {
        return REFUSE(self, "fmi2GetFMUstate: NULL pointer for the state");
    }
    if (*s != NULL && !issued(*s)) {
        return REFUSE(self, FOREIGN_STATE, "fmi2GetFMUstate", *s);
    }
    fmi2FMUstate inner = NULL;
    fmi2Status status = fmi2GetFMUstate_impl(self->impl, &inner);
    if (status > fmi2Warning) {
        return status;
    }
    if (*s != NULL) { /* overwrite the given state */
        State *old = *s;
        fmi2FreeFMUstate_impl(self->impl, &old->impl);
        old->impl = inner;
        return status;
    }
    State *made = issue(inner);
    if (made == NULL) {
        fmi2FreeFMUstate_impl(self->impl, &inner);
        return REFUSE(self, "fmi2GetFMUstate: out of memory");
    }
    *s = made;
    return status;
}

fmi2Status fmi2SetFMUstate(fmi2Component w, fmi2FMUstate s)
{
    IMPL(fmi2SetFMUstate, fmi2Error)
    Instance *self = w;
    if (self == NULL) {
        return fmi2Error;
    }
    if (!issued(s)) {
        return REFUSE(self, FOREIGN_STATE, "fmi2SetFMUstate", s);
    }
    return recorded(self->impl, fmi2SetFMUstate_impl(self->impl, ((State *)s)->impl));
}

fmi2Status fmi2FreeFMUstate(fmi2Component w, fmi2FMUstate *s)
{
    IMPL(fmi2FreeFMUstate, fmi2Error)
    Instance *self = w;
    if (self == NULL) {
        return fmi2Error;
    }
    if (s == NULL || *s == NULL) {
        return fmi2OK;
    }
    if (!issued(*s)) {
        return REFUSE(self, FOREIGN_STATE, "fmi2FreeFMUstate", *s);
    }
    State *state = *s;
    fmi2Status status = fmi2FreeFMUstate_impl(self->impl, &state->impl);
    withdraw(state);
    *s = NULL;
    return status;
}

/* pythonfmu's serialized size of the state ``s`` (checked to be one of ours), for ``function``. */
static fmi2Status state_size(Instance *self, fmi2FMUstate s, size_t *size, const char *function)
{
    IMPL(fmi2SerializedFMUstateSize, fmi2Error)
    if (!issued(s)) {
        return REFUSE(self, FOREIGN_STATE, function, s);
    }
    if (size == NULL) {
        return REFUSE(self, "%s: NULL pointer for the size", function);
    }
    return fmi2SerializedFMUstateSize_impl(self->impl, ((State *)s)->impl, size);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component w, fmi2FMUstate s, size_t *size)
{
    return w == NULL ? fmi2Error : state_size(w, s, size, "fmi2SerializedFMUstateSize");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component w, fmi2FMUstate s, fmi2Byte b[], size_t size)
{
    IMPL(fmi2SerializeFMUstate, fmi2Error)
    Instance *self = w;
    if (self == NULL) {
        return fmi2Error;
    }
    size_t needed = 0;
    fmi2Status status = state_size(self, s, &needed, "fmi2SerializeFMUstate");
    if (status > fmi2Warning) {
        return status;
    }
    if (b == NULL || size != needed) {
        return REFUSE(self, "fmi2SerializeFMUstate: a buffer of %zu bytes was given, the state "
            "needs %zu (fmi2SerializedFMUstateSize)", b == NULL ? (size_t)0 : size, needed);
    }
    return fmi2SerializeFMUstate_impl(self->impl, ((State *)s)->impl, b, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component w, const fmi2Byte b[], size_t size,
    fmi2FMUstate *s)
{
    IMPL(fmi2DeSerializeFMUstate, fmi2Error)
    IMPL(fmi2FreeFMUstate, fmi2Error)
    Instance *self = w;
    if (self == NULL) {
        return fmi2Error;
    }
    if (s == NULL || (b == NULL && size > 0)) {
        return REFUSE(self, "fmi2DeSerializeFMUstate: NULL pointer for the bytes or the state");
    }
    if (self->check_state != NULL && !self->check_state(b, size)) {
        return recorded(self->impl, fmi2Error); /* hands the slave's message over */
    }
    fmi2FMUstate inner = NULL;
    fmi2Status status = fmi2DeSerializeFMUstate_impl(self->impl, b, size, &inner);
    if (status > fmi2Warning) {
        return status;
    }
    State *made = issue(inner);
    if (made == NULL) {
        fmi2FreeFMUstate_impl(self->impl, &inner);
        return REFUSE(self, "fmi2DeSerializeFMUstate: out of memory");
    }
    *s = made;
    return status;
}

FORWARD(fmi2SetDebugLogging, (fmi2Component w, fmi2Boolean on, size_t n, const fmi2String cat[]),
    (c, on, n, cat))
FORWARD(fmi2SetupExperiment, (fmi2Component w, fmi2Boolean tolDef, fmi2Real tol, fmi2Real t0,
    fmi2Boolean stopDef, fmi2Real t1), (c, tolDef, tol, t0, stopDef, t1))
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
