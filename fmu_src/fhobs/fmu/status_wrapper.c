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
 *   fmi2GetRealStatus(fmi2LastSuccessfulTime) reads the slave's own last successful time
 *   (registered with the buffer: the end of its last step, the time of a restored FMU state).
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
 * A NULL component is answered with fmi2Error by every function (fmi2FreeInstance: nothing).
 *
 * The interpreter. pythonfmu's library needs libpython's symbols in the process. The first
 * fmi2Instantiate looks for them, then loads pythonfmu's library (RTLD_LOCAL, RTLD_NODELETE):
 * - Python already in the process (a Python host; LD_PRELOAD of libpython) is used as it is;
 * - otherwise the candidates, in order: the Python that built the FMU, as recorded in
 *   resources/fhobs_python.txt (lines key=value: version, library, home = sys.base_prefix,
 *   executable = sys.executable, site = the directory holding numpy; found next to this
 *   library in the extracted FMU, or in the resource folder the importer gives);
 *   python<version> and python3 on PATH (the libpython of their prefix, the site-packages of
 *   their virtual environment); libpython<version>.so.1.0 in LD_LIBRARY_PATH, /usr/local/lib,
 *   /usr/lib/x86_64-linux-gnu, /usr/lib64, /usr/lib. A candidate is taken if its library
 *   exists, its prefix (the nearest directory above the library, or the recorded home, with
 *   lib/python<version>/encodings) holds the standard library and numpy is found (recorded
 *   site, PYTHONPATH, the prefix's site-packages / dist-packages); its library is then loaded
 *   with RTLD_GLOBAL.
 * Before pythonfmu starts the interpreter, Py_SetProgramName is given the candidate's
 * executable (or <prefix>/bin/python<version>): the interpreter starts as that python would,
 * with its prefix and virtual environment (pythonfmu gives no program name, and the default
 * one is looked up on PATH, so the first python3 there would decide). The process environment
 * is changed in one case only: when numpy's directory is not one the interpreter puts on
 * sys.path itself, it is appended to PYTHONPATH (after the user's entries). PYTHONHOME and
 * PYTHONPATH the user set are kept; a PYTHONHOME without lib/python<version>/encodings (a
 * virtual environment), on which Py_Initialize would abort the host, is refused.
 * Then this library starts the interpreter itself (PyConfig: Py_InitializeFromConfig, which
 * answers a failure with a status where Py_Initialize ends the process, "Fatal Python error";
 * a PYTHONHOME whose standard library is broken), with the candidate's executable as program
 * name, and releases the GIL; pythonfmu finds it running and uses it as a Python host's. A
 * failure is fmi2Instantiate's NULL with a message naming PYTHONHOME and what failed. Only an
 * interpreter of the version of the headers this library was compiled with (the build's
 * Python) is started so; another one (preloaded) is left for pythonfmu to start. The
 * interpreter started here is not finalised at exit (pythonfmu's instances may still hold its
 * objects): the process ends with it.
 * Where no candidate fits, or pythonfmu's library does not load, fmi2Instantiate hands the
 * reason and every place tried to the host's logger and returns NULL, and every other function
 * returns fmi2Error: nothing aborts the host. Messages of this library go to the host's logger
 * whatever loggingOn says (they are errors, not debug logging); with loggingOn the first
 * instance also logs which interpreter was loaded.
 *
 * Exit. pythonfmu keeps its interpreter state in a static std::shared_ptr and resets it from
 * its destructor function; at exit() the C++ static destructor runs first (an atexit entry)
 * and the destructor function then resets a destroyed object (a double free: the host dies
 * with SIGABRT at exit, or its heap is corrupted). Once pythonfmu's library is loaded, this library is made
 * resident (RTLD_NODELETE) and registers an atexit handler, which exit() runs before the
 * static destructors registered earlier: it calls pythonfmu's finalizePythonInterpreter, which
 * releases the state (and finalises the interpreter pythonfmu started, once no instance is
 * left); the static destructor and the destructor function then find it released.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h> /* the types of PyConfig and PyStatus; every Python function through dlsym */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <dlfcn.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "fmi2Functions.h"
#include "fhobs_call_rules.h"

/* snprintf into buf (size bytes); 1 when the text was cut to fit (a path too long for the buffer
 * then names no file, a message is shortened), else 0. */
static int bounded_format(char *buf, size_t size, const char *format, ...)
{
    va_list args;
    va_start(args, format);
    int written = vsnprintf(buf, size, format, args);
    va_end(args);
    return written < 0 || (size_t)written >= size;
}

#ifndef FHOBS_STATUS_VR
#error "compile with -DFHOBS_STATUS_VR=<value reference of the status variable>"
#endif
#define IMPL_SUFFIX "_pythonfmu.so"

#define PYTHON_RECORD "fhobs_python.txt"
#define DEFAULT_PYTHON_VERSION "3.11"

static void *impl_handle = NULL;
static pthread_mutex_t load_lock = PTHREAD_MUTEX_INITIALIZER;
static int load_done = 0; /* load_impl ran: impl_handle, or load_error says why not */
static char load_error[8192] = "pythonfmu's library was not loaded";

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
    const int *mode;         /* the slave's FMI state, FHOBS_STATE_* (slave's) */
    size_t n_position;
    fhobs_step_fn *step;     /* the slave's doStep */
    fhobs_access_fn *access; /* the slave's check of a get/set call */
    fhobs_state_fn *check_state; /* the slave's check of a serialized state */
    const double *clock;     /* the slave's last successful time (restored with a state) */
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
    char text[8192], escaped[16384];
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

/* A function pointer from a symbol's address (dlsym's result: POSIX guarantees that it converts;
 * ISO C has no conversion between object and function pointers, so its bytes are copied). */
typedef void (*AnyFunction)(void);
static AnyFunction as_function(void *symbol)
{
    AnyFunction f;
    memcpy(&f, &symbol, sizeof f);
    return f;
}

/* A function's address as dladdr takes it (the converse of as_function). */
static void *function_address(AnyFunction f)
{
    void *address;
    memcpy(&address, &f, sizeof address);
    return address;
}

/* Marks the parameters of a function that ignores them as used. */
static void ignore_arguments(int count, ...)
{
    (void)count;
}

/* The entry point ``name`` of pythonfmu's library, looked up once (a benign race: every thread
 * that looks it up stores the same pointer); ``failed`` is returned when there is none. */
#define IMPL(name, failed) \
    static name##TYPE *name##_impl = NULL; \
    if (name##_impl == NULL) { \
        name##_impl = (name##TYPE *)as_function(impl(#name)); \
        if (name##_impl == NULL) { \
            return failed; \
        } \
    }

/* ---- Finding the interpreter and loading pythonfmu's library ---------------------------- */

/* What was tried while looking for an interpreter, for the refusal message. */
static char tried[6144];

static void note(const char *format, ...)
{
    size_t used = strlen(tried);
    if (used + 8 >= sizeof tried) {
        return;
    }
    if (used > 0) {
        strcpy(tried + used, "; ");
        used += 2;
    }
    va_list args;
    va_start(args, format);
    vsnprintf(tried + used, sizeof tried - used, format, args);
    va_end(args);
}

static int is_file(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode);
}

static void copy(char *out, size_t size, const char *text)
{
    (void)bounded_format(out, size, "%s", text != NULL ? text : "");
}

/* Drop the last component of ``path`` in place ("/a/b" -> "/a", "/a" -> "/", "a" -> "."). */
static void parent(char *path)
{
    char *slash = strrchr(path, '/');
    if (slash == NULL) {
        strcpy(path, ".");
    } else if (slash == path) {
        path[1] = '\0';
    } else {
        *slash = '\0';
    }
}

/* A candidate interpreter: its shared library, its prefix (sys.base_prefix), its executable
 * (sys.executable) and a directory holding numpy; only the library is required, the others are
 * found from it. */
typedef struct {
    char version[16];
    char library[PATH_MAX];
    char home[PATH_MAX];
    char executable[PATH_MAX];
    char site[PATH_MAX];
} Python;

/* Whether ``prefix`` holds the standard library of Python ``version`` (what Py_Initialize
 * needs, or it aborts the process: "No module named 'encodings'"). */
static int stdlib_at(const char *prefix, const char *version)
{
    char path[PATH_MAX + 64];
    (void)bounded_format(path, sizeof path, "%s/lib/python%s/encodings/__init__.py", prefix, version);
    if (is_file(path)) {
        return 1;
    }
    (void)bounded_format(path, sizeof path, "%s/lib64/python%s/encodings/__init__.py", prefix, version);
    return is_file(path);
}

/* The prefix of the interpreter whose library is ``library``: the nearest directory above it
 * that holds the standard library. */
static int prefix_of(const char *library, const char *version, char *out, size_t size)
{
    char dir[PATH_MAX];
    if (realpath(library, dir) == NULL) {
        copy(dir, sizeof dir, library);
    }
    for (int up = 0; up < 4 && strcmp(dir, "/") != 0 && strcmp(dir, ".") != 0; up++) {
        parent(dir);
        if (stdlib_at(dir, version)) {
            copy(out, size, dir);
            return 1;
        }
    }
    return 0;
}

static int has_numpy(const char *dir)
{
    char path[PATH_MAX + 32];
    (void)bounded_format(path, sizeof path, "%s/numpy/__init__.py", dir);
    return dir[0] != '\0' && is_file(path);
}

static int same_dir(const char *a, const char *b)
{
    char ra[PATH_MAX], rb[PATH_MAX];
    return realpath(a, ra) != NULL && realpath(b, rb) != NULL && strcmp(ra, rb) == 0;
}

/* Whether ``dir`` is on the interpreter's sys.path without our help: an entry of PYTHONPATH,
 * one of the site directories of prefix ``home`` or the site-packages of the virtual
 * environment of ``executable``. */
static int on_path_already(const char *dir, const char *home, const char *executable,
    const char *version)
{
    char venv[PATH_MAX + 64], config[PATH_MAX + 64];
    copy(venv, sizeof venv, executable);
    parent(venv);
    parent(venv);
    (void)bounded_format(config, sizeof config, "%s/pyvenv.cfg", venv);
    size_t used = strlen(venv);
    (void)bounded_format(venv + used, sizeof venv - used, "/lib/python%s/site-packages", version);
    int in_venv = is_file(config);
    if (in_venv && same_dir(venv, dir)) {
        return 1;
    }
    const char *pythonpath = getenv("PYTHONPATH");
    if (pythonpath != NULL) {
        char entries[8192];
        copy(entries, sizeof entries, pythonpath);
        for (char *entry = strtok(entries, ":"); entry != NULL; entry = strtok(NULL, ":")) {
            if (same_dir(entry, dir)) {
                return 1;
            }
        }
    }
    if (in_venv) {
        return 0; /* the prefix's site directories are not counted on */
    }
    static const char *sites[] = { "%s/lib/python%s/site-packages",
        "%s/lib64/python%s/site-packages", "%s/local/lib/python%s/dist-packages",
        "%s/lib/python3/dist-packages%.0s" };
    for (size_t i = 0; i < sizeof sites / sizeof *sites; i++) {
        char site[PATH_MAX + 64];
        (void)bounded_format(site, sizeof site, sites[i], home, version);
        if (same_dir(site, dir)) {
            return 1;
        }
    }
    return 0;
}

/* A directory holding numpy for the interpreter of prefix ``home``: ``site`` (recorded at build
 * time, or of a virtual environment) first, then the entries of PYTHONPATH and the site
 * directories of the prefix. */
static int find_numpy(const char *home, const char *version, const char *site, char *out,
    size_t size)
{
    if (has_numpy(site)) {
        copy(out, size, site);
        return 1;
    }
    const char *pythonpath = getenv("PYTHONPATH");
    if (pythonpath != NULL) {
        char entries[8192];
        copy(entries, sizeof entries, pythonpath);
        for (char *entry = strtok(entries, ":"); entry != NULL; entry = strtok(NULL, ":")) {
            if (has_numpy(entry)) {
                copy(out, size, entry);
                return 1;
            }
        }
    }
    static const char *sites[] = { "%s/lib/python%s/site-packages",
        "%s/lib64/python%s/site-packages", "%s/local/lib/python%s/dist-packages",
        "%s/lib/python3/dist-packages%.0s" };
    for (size_t i = 0; i < sizeof sites / sizeof *sites; i++) {
        char dir[PATH_MAX + 64];
        (void)bounded_format(dir, sizeof dir, sites[i], home, version);
        if (has_numpy(dir)) {
            copy(out, size, dir);
            return 1;
        }
    }
    return 0;
}

/* The program name the interpreter is started with (prepare_interpreter). */
static char program_name[PATH_MAX + 32];

/* Before pythonfmu starts the interpreter (Py_Initialize, which reads PYTHONHOME, PYTHONPATH and
 * the program name): make it start as ``executable`` would (its prefix, its virtual environment,
 * its site-packages; not as whatever python3 comes first on PATH, the default program name's
 * lookup), and make ``numpy_dir`` importable. PYTHONPATH is extended (after the user's own
 * entries) only when the interpreter does not add numpy's directory itself. */
static void prepare_interpreter(const char *executable, const char *home, const char *numpy_dir,
    const char *version)
{
    void (*set_program_name)(const wchar_t *)
        = (void (*)(const wchar_t *))as_function(dlsym(RTLD_DEFAULT, "Py_SetProgramName"));
    wchar_t *(*decode)(const char *, size_t *)
        = (wchar_t * (*)(const char *, size_t *))as_function(dlsym(RTLD_DEFAULT, "Py_DecodeLocale"));
    copy(program_name, sizeof program_name, executable);
    if (set_program_name != NULL && decode != NULL && executable[0] != '\0') {
        static wchar_t *program = NULL; /* kept: the interpreter may keep the pointer */
        if (program == NULL) {
            program = decode(executable, NULL);
        }
        if (program != NULL) {
            set_program_name(program);
        }
    }
    if (numpy_dir[0] != '\0' && !on_path_already(numpy_dir, home, executable, version)) {
        const char *old = getenv("PYTHONPATH");
        if (old == NULL || old[0] == '\0') {
            setenv("PYTHONPATH", numpy_dir, 1);
        } else {
            size_t size = strlen(old) + strlen(numpy_dir) + 2;
            char *joined = malloc(size);
            if (joined != NULL) {
                (void)bounded_format(joined, size, "%s:%s", old, numpy_dir);
                setenv("PYTHONPATH", joined, 1);
                free(joined);
            }
        }
    }
}

/* The executable of the candidate ``p`` of prefix ``home``: its own if it exists, else the
 * prefix's python<version> (which need not exist: the interpreter finds its prefix from the
 * path). */
static void executable_of(const Python *p, const char *home, const char *version, char *out,
    size_t size)
{
    if (p->executable[0] != '\0' && is_file(p->executable)) {
        copy(out, size, p->executable);
    } else {
        (void)bounded_format(out, size, "%s/bin/python%s", home, version);
    }
}

/* Which interpreter pythonfmu's library runs on, for the debug log. */
static char loaded_python[3 * PATH_MAX];

/* Load the candidate ``p`` (found by ``origin``) if it is usable: its library exists, its
 * prefix (or the user's PYTHONHOME, ``user_home``) holds the standard library and numpy is
 * found. Returns 1 once its library is loaded with RTLD_GLOBAL and the environment set. */
static int try_python(const char *origin, const Python *p, const char *version,
    const char *user_home)
{
    static char seen[8][PATH_MAX]; /* libraries already tried (by other candidates) */
    static int n_seen = 0;
    char home[PATH_MAX], numpy_dir[PATH_MAX], real[PATH_MAX];
    if (!is_file(p->library) || realpath(p->library, real) == NULL) {
        note("%s: no file %s", origin, p->library);
        return 0;
    }
    for (int i = 0; i < n_seen; i++) {
        if (strcmp(seen[i], real) == 0) {
            return 0;
        }
    }
    if (n_seen < 8) {
        copy(seen[n_seen++], sizeof seen[0], real);
    }
    if (user_home != NULL) {
        copy(home, sizeof home, user_home);
    } else if (p->home[0] != '\0' && stdlib_at(p->home, version)) {
        copy(home, sizeof home, p->home);
    } else if (!prefix_of(p->library, version, home, sizeof home)) {
        note("%s: %s has no standard library (lib/python%s/encodings) in the directories "
            "above it%s%s", origin, p->library, version, p->home[0] != '\0' ? " nor in " : "",
            p->home);
        return 0;
    }
    if (!find_numpy(home, version, p->site, numpy_dir, sizeof numpy_dir)) {
        note("%s: %s (prefix %s) has no numpy (looked in %s%sPYTHONPATH and the prefix's "
            "site-packages / dist-packages)", origin, p->library, home, p->site,
            p->site[0] != '\0' ? ", " : "");
        return 0;
    }
    if (dlopen(p->library, RTLD_NOW | RTLD_GLOBAL) == NULL) {
        const char *why = dlerror();
        note("%s: %s", origin, why != NULL ? why : p->library);
        return 0;
    }
    char executable[PATH_MAX + 32];
    executable_of(p, home, version, executable, sizeof executable);
    prepare_interpreter(executable, home, numpy_dir, version);
    (void)bounded_format(loaded_python, sizeof loaded_python, "%s as %s (numpy in %s; %s)", p->library,
        executable, numpy_dir, origin);
    return 1;
}

/* The shared library of Python ``version`` in directory ``dir``, into ``out``. */
static int library_in(const char *dir, const char *version, char *out, size_t size)
{
    static const char *names[] = { "%s/libpython%s.so.1.0", "%s/libpython%s.so" };
    for (size_t i = 0; i < sizeof names / sizeof *names; i++) {
        (void)bounded_format(out, size, names[i], dir, version);
        if (is_file(out)) {
            return 1;
        }
    }
    return 0;
}

/* python<version> and python3 on PATH: the interpreter they are (its prefix's library), with
 * the site-packages of the virtual environment they belong to, if any. */
static int try_path(const char *version, const char *user_home)
{
    const char *path = getenv("PATH");
    if (path == NULL || path[0] == '\0') {
        note("PATH is not set: no python3 on it");
        return 0;
    }
    char dirs[8192], names[2][32];
    copy(dirs, sizeof dirs, path);
    (void)bounded_format(names[0], sizeof names[0], "python%s", version);
    (void)bounded_format(names[1], sizeof names[1], "python3");
    int seen = 0;
    for (char *dir = strtok(dirs, ":"); dir != NULL; dir = strtok(NULL, ":")) {
        for (int n = 0; n < 2; n++) {
            char exe[PATH_MAX + 40], real[PATH_MAX], prefix[PATH_MAX], origin[PATH_MAX + 64];
            (void)bounded_format(exe, sizeof exe, "%s/%s", dir, names[n]);
            if (!is_file(exe) || access(exe, X_OK) != 0) {
                continue;
            }
            seen = 1;
            Python p = { .version = "" };
            (void)bounded_format(origin, sizeof origin, "%s on PATH", exe);
            copy(p.executable, sizeof p.executable, exe);
            char venv[PATH_MAX + 40], config[PATH_MAX + 64];
            copy(venv, sizeof venv, dir);
            parent(venv);
            (void)bounded_format(config, sizeof config, "%s/pyvenv.cfg", venv);
            if (is_file(config)) {
                (void)bounded_format(p.site, sizeof p.site, "%s/lib/python%s/site-packages", venv, version);
            }
            if (realpath(exe, real) == NULL) {
                continue;
            }
            copy(prefix, sizeof prefix, real);
            parent(prefix); /* its bin directory */
            parent(prefix);
            static const char *libdirs[] = { "lib", "lib64", "lib/x86_64-linux-gnu" };
            int found = 0;
            for (size_t i = 0; i < sizeof libdirs / sizeof *libdirs && !found; i++) {
                char libdir[PATH_MAX + 32];
                (void)bounded_format(libdir, sizeof libdir, "%s/%s", prefix, libdirs[i]);
                found = library_in(libdir, version, p.library, sizeof p.library);
            }
            if (!found) {
                note("%s (%s): no libpython%s.so.1.0 in %s/lib", origin, real, version, prefix);
                continue;
            }
            copy(p.home, sizeof p.home, prefix);
            if (try_python(origin, &p, version, user_home)) {
                return 1;
            }
        }
    }
    if (!seen) {
        note("no python%s or python3 on PATH", version);
    }
    return 0;
}

/* libpython<version>.so.1.0 in the directories of LD_LIBRARY_PATH and the standard ones. */
static int try_standard_places(const char *version, const char *user_home)
{
    static const char *standard[] = { "/usr/local/lib", "/usr/lib/x86_64-linux-gnu",
        "/usr/lib64", "/usr/lib" };
    char dirs[8192] = "";
    const char *extra = getenv("LD_LIBRARY_PATH");
    if (extra != NULL && extra[0] != '\0') {
        (void)bounded_format(dirs, sizeof dirs, "%s:", extra);
    }
    for (size_t i = 0; i < sizeof standard / sizeof *standard; i++) {
        size_t used = strlen(dirs);
        (void)bounded_format(dirs + used, sizeof dirs - used, "%s%s", standard[i],
            i + 1 < sizeof standard / sizeof *standard ? ":" : "");
    }
    int seen = 0;
    for (char *dir = strtok(dirs, ":"); dir != NULL; dir = strtok(NULL, ":")) {
        Python p = { .version = "" };
        char origin[PATH_MAX + 32];
        if (!library_in(dir, version, p.library, sizeof p.library)) {
            continue;
        }
        seen = 1;
        (void)bounded_format(origin, sizeof origin, "standard place %s", dir);
        if (try_python(origin, &p, version, user_home)) {
            return 1;
        }
    }
    if (!seen) {
        note("no libpython%s.so.1.0 in LD_LIBRARY_PATH, /usr/local/lib, "
            "/usr/lib/x86_64-linux-gnu, /usr/lib64 or /usr/lib", version);
    }
    return 0;
}

/* Python already in the process (a Python host, or LD_PRELOAD of libpython): use it. An
 * interpreter not yet started is given a prefix (the library's) and the recorded numpy. */
static int python_in_process(const Python *record, const char *version, const char *user_home)
{
    void *symbol = dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    if (symbol == NULL) {
        return 0;
    }
    int (*initialized)(void) = (int (*)(void))as_function(symbol);
    Dl_info info;
    const char *library = dladdr(symbol, &info) != 0 && info.dli_fname != NULL
        ? info.dli_fname : "the process";
    if (initialized()) {
        (void)bounded_format(loaded_python, sizeof loaded_python, "the interpreter running in %s", library);
        return 1;
    }
    char home[PATH_MAX], numpy_dir[PATH_MAX] = "", executable[PATH_MAX + 32];
    if (!prefix_of(library, version, home, sizeof home)) {
        (void)bounded_format(loaded_python, sizeof loaded_python, "%s, already in the process", library);
        return 1; /* the interpreter finds its prefix itself */
    }
    if (record->home[0] != '\0' && same_dir(record->home, home)) {
        executable_of(record, home, version, executable, sizeof executable);
        find_numpy(home, version, record->site, numpy_dir, sizeof numpy_dir);
    } else {
        executable_of(&(Python) { .version = "" }, home, version, executable, sizeof executable);
    }
    prepare_interpreter(executable, user_home != NULL ? user_home : home, numpy_dir, version);
    (void)bounded_format(loaded_python, sizeof loaded_python, "%s as %s, already in the process", library,
        executable);
    return 1;
}

/* The path of a file named ``name`` in the resource folder given as a file URI. */
static int resource_file(const char *uri, const char *name, char *out, size_t size)
{
    if (uri == NULL || strncmp(uri, "file:", 5) != 0) {
        return 0;
    }
    const char *path = uri + 5;
    if (strncmp(path, "///", 3) == 0) {
        path += 2;
    } else if (strncmp(path, "//localhost/", 12) == 0) {
        path += 11;
    } else if (strncmp(path, "//", 2) == 0) {
        return 0; /* another host */
    }
    size_t j = 0;
    for (size_t i = 0; path[i] != '\0' && j + 1 < size; i++) {
        unsigned int byte;
        if (path[i] == '%' && sscanf(path + i + 1, "%2x", &byte) == 1) {
            out[j++] = (char)byte;
            i += 2;
        } else {
            out[j++] = path[i];
        }
    }
    out[j] = '\0';
    while (j > 1 && out[j - 1] == '/') {
        out[--j] = '\0';
    }
    size_t room = size - j;
    return (size_t)snprintf(out + j, room, "/%s", name) < room;
}

/* The build record (resources/PYTHON_RECORD: lines key=value), next to this library in the
 * extracted FMU (binaries/linux64/..) or in the resource folder the importer gave. */
static int read_record(const char *resources, Python *record, char *where, size_t size)
{
    Dl_info info;
    char candidates[2][PATH_MAX + 64];
    int n = 0;
    if (dladdr(function_address((AnyFunction)&read_record), &info) != 0 && info.dli_fname != NULL) {
        char root[PATH_MAX];
        copy(root, sizeof root, info.dli_fname);
        parent(root);
        parent(root);
        parent(root);
        (void)bounded_format(candidates[n++], sizeof candidates[0], "%s/resources/%s", root, PYTHON_RECORD);
    }
    if (resource_file(resources, PYTHON_RECORD, candidates[n], sizeof candidates[0])) {
        n++;
    }
    copy(where, size, n > 0 ? candidates[0] : "resources/" PYTHON_RECORD);
    for (int i = 0; i < n; i++) {
        FILE *f = fopen(candidates[i], "r");
        if (f == NULL) {
            continue;
        }
        copy(where, size, candidates[i]);
        char line[PATH_MAX + 64];
        while (fgets(line, sizeof line, f) != NULL) {
            line[strcspn(line, "\r\n")] = '\0';
            char *eq = strchr(line, '=');
            if (line[0] == '#' || eq == NULL) {
                continue;
            }
            *eq = '\0';
            if (strcmp(line, "version") == 0) {
                copy(record->version, sizeof record->version, eq + 1);
            } else if (strcmp(line, "library") == 0) {
                copy(record->library, sizeof record->library, eq + 1);
            } else if (strcmp(line, "home") == 0) {
                copy(record->home, sizeof record->home, eq + 1);
            } else if (strcmp(line, "executable") == 0) {
                copy(record->executable, sizeof record->executable, eq + 1);
            } else if (strcmp(line, "site") == 0) {
                copy(record->site, sizeof record->site, eq + 1);
            }
        }
        fclose(f);
        return 1;
    }
    return 0;
}

/* A Python function of the loaded libpython, typed as Python.h declares it (NULL if missing). */
#define PYTHON_FUNCTION(name) ((__typeof__(&name))as_function(dlsym(RTLD_DEFAULT, #name)))

/* Start the interpreter of libpython (loaded, not running) with PyConfig, as pythonfmu's
 * Py_Initialize would start it (environment variables read, program_name as program name), and
 * release the GIL. 1 when it runs; 0 when it failed to start, load_error then naming
 * PYTHONHOME (``user_home``, or the prefix ``home`` the interpreter derives) and what failed;
 * -1 when it is left to pythonfmu (another version than this library's headers, or a
 * libpython without PyConfig). */
static int start_interpreter(const char *version, const char *user_home)
{
    __typeof__(&Py_GetVersion) get_version = PYTHON_FUNCTION(Py_GetVersion);
    __typeof__(&PyConfig_InitPythonConfig) init_config = PYTHON_FUNCTION(PyConfig_InitPythonConfig);
    __typeof__(&PyConfig_SetBytesString) set_string = PYTHON_FUNCTION(PyConfig_SetBytesString);
    __typeof__(&Py_InitializeFromConfig) initialize = PYTHON_FUNCTION(Py_InitializeFromConfig);
    __typeof__(&PyConfig_Clear) clear_config = PYTHON_FUNCTION(PyConfig_Clear);
    __typeof__(&PyStatus_Exception) failed = PYTHON_FUNCTION(PyStatus_Exception);
    __typeof__(&PyEval_SaveThread) save_thread = PYTHON_FUNCTION(PyEval_SaveThread);
    char own[16];
    (void)bounded_format(own, sizeof own, "%d.%d.", PY_MAJOR_VERSION, PY_MINOR_VERSION);
    if (get_version == NULL || init_config == NULL || set_string == NULL || initialize == NULL
        || clear_config == NULL || failed == NULL || save_thread == NULL
        || strncmp(get_version(), own, strlen(own)) != 0) {
        return -1;
    }
    PyConfig config;
    init_config(&config);
    PyStatus status = { ._type = 0 };
    if (program_name[0] != '\0') {
        status = set_string(&config, &config.program_name, program_name);
    }
    if (!failed(status)) {
        status = initialize(&config);
    }
    clear_config(&config);
    if (failed(status)) {
        char home[PATH_MAX + 64];
        (void)bounded_format(home, sizeof home, user_home != NULL ? "PYTHONHOME=%s"
            : "PYTHONHOME unset, the prefix of %s", user_home != NULL ? user_home : program_name);
        (void)bounded_format(load_error, sizeof load_error, "Python %s could not start with %s "
            "(%s: %s): PYTHONHOME must be the prefix of a complete Python %s (its standard "
            "library in lib/python%s); for a virtual environment leave PYTHONHOME unset or give "
            "its base prefix, and give its site-packages in PYTHONPATH", version, home,
            status.func != NULL ? status.func : "Py_InitializeFromConfig",
            status.err_msg != NULL ? status.err_msg : "exit requested", version, version);
        return 0;
    }
    (void)save_thread(); /* pythonfmu takes the GIL for each call (PyGILState_Ensure) */
    return 1;
}

/* At exit, before pythonfmu's static std::shared_ptr<PyState> is destroyed: release it through
 * pythonfmu's own finalizePythonInterpreter (the interpreter is finalised if no instance is
 * left). Otherwise exit() destroys that shared_ptr first and pythonfmu's destructor function
 * then resets the destroyed object (use after free, a double free of its control block). */
static void release_python_at_exit(void)
{
    void (*finalize)(void) = (void (*)(void))as_function(impl("finalizePythonInterpreter"));
    if (finalize != NULL) {
        finalize();
    }
}

/* Find an interpreter, then load pythonfmu's library (once per process; under load_lock). On
 * failure impl_handle stays NULL and load_error says why. */
static void load_impl(const char *resources)
{
    Python record = { .version = "" };
    char where[PATH_MAX + 64];
    tried[0] = '\0';
    int recorded_python = read_record(resources, &record, where, sizeof where);
    const char *version = record.version[0] != '\0' ? record.version : DEFAULT_PYTHON_VERSION;
    const char *user_home = getenv("PYTHONHOME");
    char home[PATH_MAX];
    if (user_home != NULL && user_home[0] != '\0') {
        copy(home, sizeof home, user_home);
        home[strcspn(home, ":")] = '\0'; /* prefix[:exec_prefix] */
        user_home = home;
    } else {
        user_home = NULL;
    }
    int found;
    void *is_initialized = dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    int running = is_initialized != NULL && ((int (*)(void))as_function(is_initialized))();
    if (!running && user_home != NULL && !stdlib_at(user_home, version)) {
        found = 0; /* Py_Initialize would abort the host */
        note("PYTHONHOME=%s has no lib/python%s/encodings (Python would abort the host; for a "
            "virtual environment leave PYTHONHOME unset or give its base prefix, and give its "
            "site-packages in PYTHONPATH)", getenv("PYTHONHOME"), version);
    } else {
        found = python_in_process(&record, version, user_home);
        if (!found) {
            if (recorded_python && record.library[0] != '\0') {
                found = try_python("the build's Python", &record, version, user_home);
            } else {
                note(recorded_python ? "%s names no library" : "no build record %s", where);
            }
        }
        if (!found) {
            found = try_path(version, user_home);
        }
        if (!found) {
            found = try_standard_places(version, user_home);
        }
    }
    if (!found) {
        (void)bounded_format(load_error, sizeof load_error, "no usable Python %s with numpy for "
            "pythonfmu's library (this FMU runs Python code). Tried: %s. Install Python %s "
            "with numpy, or start the host with LD_PRELOAD=<prefix>/lib/libpython%s.so and "
            "PYTHONHOME=<prefix>, or use the native FMUs (build_fmu.py --native)", version,
            tried, version, version);
        return;
    }
    void *now_initialized = dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    if (now_initialized != NULL && !((int (*)(void))as_function(now_initialized))()
        && start_interpreter(version, user_home) == 0) {
        return;
    }
    Dl_info info;
    if (dladdr(function_address((AnyFunction)&load_impl), &info) == 0 || info.dli_fname == NULL
        || strlen(info.dli_fname) < 3) {
        copy(load_error, sizeof load_error, "cannot find the path of this library");
        return;
    }
    size_t len = strlen(info.dli_fname);
    char path[PATH_MAX + sizeof IMPL_SUFFIX];
    (void)bounded_format(path, sizeof path, "%.*s%s", (int)(len - 3), info.dli_fname, IMPL_SUFFIX);
    /* Never unloaded (its interpreter cannot be started twice in a process). */
    impl_handle = dlopen(path, RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (impl_handle == NULL) {
        const char *why = dlerror();
        (void)bounded_format(load_error, sizeof load_error, "cannot load pythonfmu's library with %s: %s",
            loaded_python, why != NULL ? why : path);
        return;
    }
    /* Kept loaded too, so that the exit handler (registered after pythonfmu's static
     * destructors, hence run before them) is there at exit. */
    dlopen(info.dli_fname, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE);
    atexit(release_python_at_exit);
}

/* Load pythonfmu's library if not done yet; whether it is loaded. */
static int ensure_impl(const char *resources, int *just_loaded)
{
    pthread_mutex_lock(&load_lock);
    *just_loaded = 0;
    if (!load_done) {
        load_impl(resources);
        load_done = 1;
        *just_loaded = impl_handle != NULL;
    }
    int loaded = impl_handle != NULL;
    pthread_mutex_unlock(&load_lock);
    return loaded;
}

/* Called by the slave's constructor (through ctypes) while its instance is created: give
 * fmi2GetReal / fmi2SetReal direct access to ``values`` (``n_values`` doubles, kept alive and
 * never moved by the slave), ``position[vr]`` being the index of Real variable vr or -1 and
 * ``writable[vr]`` whether fmi2SetReal may write it now (the slave keeps it up to date), and
 * give the wrapper the slave's ``step``, ``access`` and ``check_state`` (kept alive by the
 * slave). Returns 1 if registered, 0 if no instance is being created by this thread or the
 * arguments are inconsistent (then every call goes through pythonfmu). */
int fhobs_register(double *values, size_t n_values, const long long *position,
    const unsigned char *writable, size_t n_position, const int *mode, const double *clock,
    fhobs_step_fn *step, fhobs_access_fn *access, fhobs_state_fn *check_state)
{
    Instance *w = registering;
    if (w == NULL || values == NULL || position == NULL || writable == NULL || n_position == 0
        || mode == NULL || clock == NULL || step == NULL || access == NULL
        || check_state == NULL) {
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
    w->mode = mode;
    w->clock = clock;
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
    w->mode = NULL;
    free(w->position);
    w->position = NULL;
    w->n_position = 0;
}

/* Whether ``call`` (FHOBS_CALL_*) is refused in the slave's FMI state (the table of
 * fhobs.fmu.call_rules), its message then logged. Unsupported functions are refused always;
 * without a registered slave the other calls go to pythonfmu. */
static int refused(Instance *w, int call)
{
    unsigned mask = FHOBS_CALL_MASKS[call];
    if (mask != 0 && w->mode == NULL) {
        return 0;
    }
    int mode = w->mode != NULL ? *w->mode : 0;
    if (mode >= 0 && mode < FHOBS_N_STATES && (mask >> mode & 1u)) {
        return 0;
    }
    say(w->logger, w->environment, w->name, fmi2Error, FHOBS_CALL_MESSAGES[call],
        mode >= 0 && mode < FHOBS_N_STATES ? FHOBS_STATE_NAMES[mode] : "an unknown state");
    return 1;
}

/* The start of every function of an instance: a NULL component, or a call refused in its
 * state, is answered with fmi2Error. */
#define CHECK_CALL(w, call) \
    do { \
        if ((w) == NULL || refused((Instance *)(w), (call))) { \
            return fmi2Error; \
        } \
    } while (0)

/* Whether every value reference is a registered Real variable, writable now if ``write``
 * (then the buffer is used). */
static int direct(const Instance *w, const fmi2ValueReference vr[], size_t n, int write)
{
    if (w == NULL || w->values == NULL || vr == NULL || n == 0
        || !(FHOBS_CALL_MASKS[write ? FHOBS_CALL_SETREAL : FHOBS_CALL_GETREAL] >> *w->mode & 1u)) {
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
#define FORWARD(name, call, params, args) \
    fmi2Status name params \
    { \
        IMPL(name, fmi2Error) \
        CHECK_CALL(w, call); \
        fmi2Component c = INNER(w); \
        return name##_impl args; \
    }

/* A function these FMUs do not provide: fmi2Error with the table's reason. */
#define UNSUPPORTED(name, call, params, args) \
    fmi2Status name params \
    { \
        ignore_arguments args; \
        CHECK_CALL(w, call); \
        return fmi2Error; \
    }

/* Forward a get/set call once the slave accepts it. */
#define FORWARD_ACCESS(name, code, call, params, args) \
    fmi2Status name params \
    { \
        IMPL(name, fmi2Error) \
        CHECK_CALL(w, call); \
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
    int just_loaded;
    if (!ensure_impl(resources, &just_loaded)) {
        say(logger, environment, instanceName, fmi2Error, "fhobs status wrapper: %s",
            load_error);
        return NULL;
    }
    if (just_loaded && loggingOn) {
        say(logger, environment, instanceName, fmi2OK, "fhobs status wrapper: Python: %s",
            loaded_python);
    }
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)as_function(impl("fmi2Instantiate"));
    if (instantiate == NULL) {
        say(logger, environment, instanceName, fmi2Error,
            "fhobs status wrapper: pythonfmu's library has no fmi2Instantiate");
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
    /* The slaves log errors and warnings only: handed to the host whatever loggingOn says, as
     * the native FMUs do (pythonfmu would drop them without debug logging). */
    w->impl = instantiate(instanceName, fmuType, guid, resources, functions, visible, fmi2True);
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
    if (w == NULL) {
        return;
    }
    fmi2FreeInstanceTYPE *free_instance = (fmi2FreeInstanceTYPE *)as_function(impl("fmi2FreeInstance"));
    if (free_instance != NULL) {
        free_instance(INNER(w));
    }
    unregister((Instance *)w);
    free(((Instance *)w)->name);
    free(w);
}

fmi2Status fmi2Reset(fmi2Component w)
{
    /* pythonfmu replaces the Python slave: its new constructor registers its own buffer. */
    IMPL(fmi2Reset, fmi2Error)
    CHECK_CALL(w, FHOBS_CALL_RESET);
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
    CHECK_CALL(w, FHOBS_CALL_ENTERINITIALIZATIONMODE);
    return recorded(INNER(w), fmi2EnterInitializationMode_impl(INNER(w)));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component w)
{
    IMPL(fmi2ExitInitializationMode, fmi2Error)
    CHECK_CALL(w, FHOBS_CALL_EXITINITIALIZATIONMODE);
    return recorded(INNER(w), fmi2ExitInitializationMode_impl(INNER(w)));
}

fmi2Status fmi2Terminate(fmi2Component w)
{
    IMPL(fmi2Terminate, fmi2Error)
    CHECK_CALL(w, FHOBS_CALL_TERMINATE);
    return recorded(INNER(w), fmi2Terminate_impl(INNER(w)));
}

fmi2Status fmi2DoStep(fmi2Component w, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior)
{
    Instance *self = w;
    IMPL(fmi2DoStep, fmi2Error)
    CHECK_CALL(w, FHOBS_CALL_DOSTEP);
    if (self->step != NULL) {
        switch (self->step(t, h)) {
        case FHOBS_STEP_OK:
            return fmi2OK;
        case FHOBS_STEP_OK_LOGGED:
            return recorded(self->impl, fmi2OK); /* a pythonfmu call: hands the messages over */
        case FHOBS_STEP_REJECTED:
            return recorded(self->impl, fmi2Discard);
        case FHOBS_STEP_RAISED:
            return fmi2DoStep_impl(self->impl, t, h, noSetPrior); /* re-raised there: fatal */
        default:
            return fmi2Fatal;
        }
    }
    /* The slaves' do_step returns True (fmi2OK) only on success: no status to read then. */
    fmi2Status returned = fmi2DoStep_impl(INNER(w), t, h, noSetPrior);
    return returned == fmi2OK ? returned : recorded(INNER(w), returned);
}

fmi2Status fmi2GetRealStatus(fmi2Component w, const fmi2StatusKind k, fmi2Real *v)
{
    const Instance *self = w;
    CHECK_CALL(w, FHOBS_CALL_GETREALSTATUS);
    if (self->clock != NULL && k == fmi2LastSuccessfulTime && v != NULL) {
        *v = *self->clock;
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
    CHECK_CALL(w, FHOBS_CALL_GETREAL);
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
    CHECK_CALL(w, FHOBS_CALL_SETREAL);
    fmi2Status answer;
    if (!allowed(w, FHOBS_SET_REAL, vr, n, v, &answer)) {
        return answer;
    }
    return fmi2SetReal_impl(INNER(w), vr, n, v);
}

FORWARD_ACCESS(fmi2GetInteger, FHOBS_GET_INTEGER, FHOBS_CALL_GETINTEGER, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, fmi2Integer v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2GetBoolean, FHOBS_GET_BOOLEAN, FHOBS_CALL_GETBOOLEAN, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2GetString, FHOBS_GET_STRING, FHOBS_CALL_GETSTRING, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, fmi2String v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2SetInteger, FHOBS_SET_INTEGER, FHOBS_CALL_SETINTEGER, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2SetBoolean, FHOBS_SET_BOOLEAN, FHOBS_CALL_SETBOOLEAN, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]), (c, vr, n, v))
FORWARD_ACCESS(fmi2SetString, FHOBS_SET_STRING, FHOBS_CALL_SETSTRING, (fmi2Component w,
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

/* Debug logging stays on in pythonfmu: the slaves log errors and warnings only, which reach the
 * host whatever loggingOn says (as from fmi2Instantiate). */
fmi2Status fmi2SetDebugLogging(fmi2Component w, fmi2Boolean on, size_t n, const fmi2String cat[])
{
    (void)on;
    IMPL(fmi2SetDebugLogging, fmi2Error)
    CHECK_CALL(w, FHOBS_CALL_SETDEBUGLOGGING);
    return fmi2SetDebugLogging_impl(INNER(w), fmi2True, n, cat);
}
FORWARD(fmi2SetupExperiment, FHOBS_CALL_SETUPEXPERIMENT, (fmi2Component w, fmi2Boolean tolDef,
    fmi2Real tol, fmi2Real t0, fmi2Boolean stopDef, fmi2Real t1),
    (c, tolDef, tol, t0, stopDef, t1))
FORWARD(fmi2GetBooleanStatus, FHOBS_CALL_GETBOOLEANSTATUS, (fmi2Component w,
    const fmi2StatusKind k, fmi2Boolean *v), (c, k, v))
UNSUPPORTED(fmi2GetDirectionalDerivative, FHOBS_CALL_GETDIRECTIONALDERIVATIVE, (fmi2Component w,
    const fmi2ValueReference u[], size_t nu, const fmi2ValueReference z[], size_t nz,
    const fmi2Real du[], fmi2Real dz[]), (6, u, nu, z, nz, du, dz))
UNSUPPORTED(fmi2SetRealInputDerivatives, FHOBS_CALL_SETREALINPUTDERIVATIVES, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, const fmi2Integer order[], const fmi2Real v[]),
    (4, vr, n, order, v))
UNSUPPORTED(fmi2GetRealOutputDerivatives, FHOBS_CALL_GETREALOUTPUTDERIVATIVES, (fmi2Component w,
    const fmi2ValueReference vr[], size_t n, const fmi2Integer order[], fmi2Real v[]),
    (4, vr, n, order, v))
UNSUPPORTED(fmi2CancelStep, FHOBS_CALL_CANCELSTEP, (fmi2Component w), (0))
UNSUPPORTED(fmi2GetStatus, FHOBS_CALL_GETSTATUS, (fmi2Component w, const fmi2StatusKind k,
    fmi2Status *v), (2, k, v))
UNSUPPORTED(fmi2GetIntegerStatus, FHOBS_CALL_GETINTEGERSTATUS, (fmi2Component w,
    const fmi2StatusKind k, fmi2Integer *v), (2, k, v))
UNSUPPORTED(fmi2GetStringStatus, FHOBS_CALL_GETSTRINGSTATUS, (fmi2Component w,
    const fmi2StatusKind k, fmi2String *v), (2, k, v))
