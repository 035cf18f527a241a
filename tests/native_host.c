/*
 * A minimal native co-simulation host for the tests, FMI 2.0 or FMI 3.0 (the modelDescription's
 * fmiVersion): no Python anywhere in its process. It loads an extracted FMU's binary, checks
 * that no libpython is mapped, runs the FMI call sequence with the inputs of a CSV file and
 * writes the outputs to another CSV file.
 *
 *   native_host FMU_DIR INPUTS.csv OUTPUTS.csv STEP [NAME=VALUE ...]
 *
 * FMU_DIR    the extracted FMU (modelDescription.xml, binaries/, resources/)
 * INPUTS.csv header "time,<input name>,...", then one row per communication point
 *            t_k = t_0 + k STEP (the time column of the rows after the first is not read)
 *            with the inputs held over [t_k, t_k+1); the last row ends the run. With STEP
 *            "-", the header is "time,step,<input name>,..." and each row also gives the
 *            size of the step taken from it; the host then accumulates the communication
 *            point in floating point, t_k+1 = t_k + step_k, as hosts such as OMSimulator do
 * STEP       the communication step, or "-" (the steps of the input rows)
 * OUTPUTS.csv written: header "time,<output name>,..." (every Real output, in the order of
 *            modelDescription.xml), a row after initialisation and one after each doStep
 * NAME=VALUE Real parameters set before initialisation
 *
 * Names are the scalar signals: an FMI 3.0 array's elements are named as the FMI 2.0 build
 * names them (x_hat[2], P_bar[1,3], row-major). An FMI 3.0 FMU is driven through whole arrays
 * (fmi3SetFloat64 / fmi3GetFloat64 with nValues the array's size); its run also checks, each
 * check printed as a line "check: ..." on stdout:
 *   - every function given a NULL instance returns fmi3Error (fmi3FreeInstance: returns);
 *   - fmi3DoStep, fmi3ExitInitializationMode and fmi3EnterStepMode before the initialisation,
 *     and fmi3DoStep after fmi3Terminate, return fmi3Error;
 *   - fmi3GetFloat64 of an output array with nValues one more or one less than its size
 *     returns fmi3Error;
 *   - the FMU state after the middle row, taken in memory (fmi3GetFMUState) and through its
 *     bytes (fmi3SerializeFMUState, fmi3DeserializeFMUState), set back (fmi3SetFMUState):
 *     the rows after it replay bit for bit; the bytes with one bit flipped are refused;
 * then frees the states and the instance.
 *
 * Exit codes: 0 success, 1 usage or file error, 2 an FMI call did not return OK (or a check
 * did not hold), 3 libpython is mapped into the process.
 */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi3Functions.h"

#define HOST_NAME "native_host"
#include "host_common.h"

#define MAX_VARS 4096
#define MAX_LINE 65536
#define MAX_DIMS 4
#define STATUS_OK 0    /* fmi2OK, fmi3OK */
#define STATUS_ERROR 3 /* fmi2Error, fmi3Error */

/* A scalar signal: a ScalarVariable (FMI 2.0) or an element of an FMI 3.0 variable. */
typedef struct {
    char name[256];
    unsigned vr;   /* the value reference (FMI 3.0: of the variable the element is of) */
    int offset;    /* FMI 3.0: the element's index in its variable, row-major */
    int size;      /* FMI 3.0: the number of elements of its variable */
    int first;     /* FMI 3.0: the index in vars of its variable's first element */
    int is_real;
    char causality[32];
    double start; /* FMI 3.0: its start value (0 without one) */
} Variable;

static Variable vars[MAX_VARS];
static int n_vars;

static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                    fmi3String message)
{
    (void)env;
    fprintf(stderr, "[host] status %d %s: %s\n", (int)status, category ? category : "",
            message ? message : "");
}

/* Name, value reference and causality of the variable whose tag starts at p (up to end). */
static int variable_head(const char *p, const char *end, Variable *v)
{
    char vr[32];
    if (!attribute(p, end, "name", v->name, sizeof v->name) ||
        !attribute(p, end, "valueReference", vr, sizeof vr))
        return 0;
    if (!attribute(p, end, "causality", v->causality, sizeof v->causality))
        strcpy(v->causality, "local");
    v->vr = (unsigned)strtoul(vr, NULL, 10);
    v->offset = 0;
    v->size = 1;
    v->first = n_vars;
    return 1;
}

/* Scalar variables (name, value reference, causality, Real or not) of an FMI 2.0
 * modelDescription.xml. */
static int parse_variables2(const char *xml)
{
    const char *p = xml;
    while ((p = strstr(p, "<ScalarVariable")) != NULL) {
        const char *end = strchr(p, '>');
        const char *close = strstr(p, "</ScalarVariable>");
        if (!end || n_vars == MAX_VARS || !variable_head(p, end, &vars[n_vars]))
            return 0;
        const char *real = strstr(end, "<Real");
        vars[n_vars].is_real = real && (!close || real < close);
        n_vars++;
        p = end;
    }
    return n_vars > 0;
}

/* The elements of the FMI 3.0 variable whose tag starts at p, named as the FMI 2.0 build
 * names them, appended to vars. */
static int add_elements(const char *p, int is_real)
{
    const char *end = strchr(p, '>');
    Variable head;
    if (!end || !variable_head(p, end, &head))
        return 0;
    head.is_real = is_real;
    head.start = 0.0;
    int dims[MAX_DIMS], n_dims = 0, size = 1;
    if (end[-1] != '/') { /* <Dimension start="n"/> children up to the closing tag */
        const char *close = strstr(end, is_real ? "</Float64>" : "</Int32>");
        for (const char *d = strstr(end, "<Dimension"); d && close && d < close;
             d = strstr(d + 1, "<Dimension")) {
            char start[32];
            if (n_dims == MAX_DIMS || !attribute(d, strchr(d, '>'), "start", start, sizeof start))
                return 0;
            dims[n_dims] = atoi(start);
            size *= dims[n_dims++];
        }
    }
    if (n_vars + size > MAX_VARS)
        return 0;
    const char *start = strstr(p, " start=\"");
    start = start && start < end ? start + 8 : NULL; /* the elements' start values, row-major */
    for (int k = 0; k < size; k++) {
        Variable *v = &vars[n_vars + k];
        *v = head;
        v->offset = k;
        v->size = size;
        v->first = n_vars;
        if (start) {
            char *next;
            v->start = strtod(start, &next);
            start = next;
        }
        if (!n_dims)
            continue;
        char index[64] = "";
        for (int d = 0, rest = k, stride = size; d < n_dims; d++) {
            stride /= dims[d];
            snprintf(index + strlen(index), sizeof index - strlen(index), "%s%d", d ? "," : "",
                     rest / stride + 1);
            rest %= stride;
        }
        snprintf(v->name, sizeof v->name, "%.190s[%.60s]", head.name, index);
    }
    n_vars += size;
    return 1;
}

/* The scalar signals of an FMI 3.0 modelDescription.xml's Float64 and Int32 variables. */
static int parse_variables3(const char *xml)
{
    const char *p = strstr(xml, "<ModelVariables");
    const char *stop = p ? strstr(p, "</ModelVariables>") : NULL;
    while (p && stop && (p = strchr(p + 1, '<')) != NULL && p < stop) {
        int real = strncmp(p, "<Float64 ", 9) == 0;
        if ((real || strncmp(p, "<Int32 ", 7) == 0) && !add_elements(p, real))
            return 0;
    }
    return n_vars > 0;
}

static const Variable *find(const char *name)
{
    for (int i = 0; i < n_vars; i++)
        if (strcmp(vars[i].name, name) == 0)
            return &vars[i];
    return NULL;
}

static int libpython_mapped(void)
{
    char *maps = read_file("/proc/self/maps");
    int found = maps && strstr(maps, "libpython") != NULL;
    free(maps);
    return found;
}

/* Split a CSV line in place into at most max fields; returns the count. */

/* -- the FMU, either version ------------------------------------------------------------- */

typedef struct {
    int version; /* 2 or 3 */
    void *lib;
    void *instance;
    double *values; /* FMI 3.0: every element's value, in vars' order (a copy of the FMU's) */
} Fmu;

#define SYMBOL(fmu, name) ((name##TYPE *)dlsym((fmu)->lib, #name))

/* Set the elements vars[index[i]] to value[i]: FMI 2.0 each scalar, FMI 3.0 each variable
 * touched whole. */
static int set_reals(Fmu *fmu, const int index[], int n, const double value[])
{
    if (fmu->version == 2) {
        fmi2ValueReference vr[MAX_VARS];
        for (int i = 0; i < n; i++)
            vr[i] = vars[index[i]].vr;
        return SYMBOL(fmu, fmi2SetReal)(fmu->instance, vr, (size_t)n, value);
    }
    for (int i = 0; i < n; i++)
        fmu->values[index[i]] = value[i];
    for (int i = 0; i < n; i++) {
        const Variable *v = &vars[index[i]];
        int first = 1;
        for (int j = 0; j < i; j++)
            first = first && vars[index[j]].first != v->first;
        if (!first)
            continue;
        int status = SYMBOL(fmu, fmi3SetFloat64)(fmu->instance, &v->vr, 1,
                                                  fmu->values + v->first, (size_t)v->size);
        if (status != STATUS_OK)
            return status;
    }
    return STATUS_OK;
}

/* The values of the elements vars[index[i]] into value[i]. */
static int get_reals(Fmu *fmu, const int index[], int n, double value[])
{
    if (fmu->version == 2) {
        fmi2ValueReference vr[MAX_VARS];
        for (int i = 0; i < n; i++)
            vr[i] = vars[index[i]].vr;
        return SYMBOL(fmu, fmi2GetReal)(fmu->instance, vr, (size_t)n, value);
    }
    for (int i = 0; i < n; i++) {
        const Variable *v = &vars[index[i]];
        if (i == 0 || vars[index[i - 1]].first != v->first) { /* a variable read whole */
            int status = SYMBOL(fmu, fmi3GetFloat64)(fmu->instance, &v->vr, 1,
                                                     fmu->values + v->first, (size_t)v->size);
            if (status != STATUS_OK)
                return status;
        }
        value[i] = fmu->values[index[i]];
    }
    return STATUS_OK;
}

static int do_step(Fmu *fmu, double t, double step)
{
    if (fmu->version == 2)
        return SYMBOL(fmu, fmi2DoStep)(fmu->instance, t, step, fmi2True);
    bool event = false, terminate = false, early = false;
    double last = t;
    int status = SYMBOL(fmu, fmi3DoStep)(fmu->instance, t, step, true, &event, &terminate,
                                         &early, &last);
    return status == STATUS_OK && (event || terminate || early || last != t + step)
               ? STATUS_ERROR
               : status;
}

/* -- the run --------------------------------------------------------------------------------- */

/* The input rows of the CSV file: times, steps and inputs, row-major. */
typedef struct {
    int n_inputs, n_rows;
    int index[MAX_VARS]; /* each input column's index in vars */
    double *step, *inputs;
    double t0;
} Rows;

/* The run from row `from` (its time t) to the end: one output row per row. */
static int run_rows(Fmu *fmu, const Rows *rows, int from, double t, const double fixed_step,
                    const int outputs[], int n_outputs, double *record)
{
    for (int row = from;; row++) {
        if (get_reals(fmu, outputs, n_outputs, record + (size_t)row * n_outputs) != STATUS_OK)
            return fail(2, "getting the outputs after row %d failed", row);
        if (row + 1 == rows->n_rows)
            return 0;
        const double *inputs = rows->inputs + (size_t)row * rows->n_inputs;
        if (set_reals(fmu, rows->index, rows->n_inputs, inputs) != STATUS_OK)
            return fail(2, "setting the inputs of row %d failed", row + 1);
        double step = fixed_step > 0.0 ? fixed_step : rows->step[row];
        int status = do_step(fmu, t, step);
        if (status != STATUS_OK)
            return fail(2, "doStep at row %d returned status %d", row + 1, status);
        t = fixed_step > 0.0 ? rows->t0 + (row + 1) * fixed_step : t + step;
    }
}

static int read_rows(const char *path, int step_column, Rows *rows)
{
    static char line[MAX_LINE];
    char *fields[MAX_VARS];
    FILE *in = fopen(path, "r");
    if (!in)
        return fail(1, "cannot open %s", path);
    if (!fgets(line, sizeof line, in)) {
        fclose(in);
        return fail(1, "%s is empty", path);
    }
    int n_columns = split(line, fields, MAX_VARS);
    int first_input = step_column ? 2 : 1; /* the column of the first input */
    if (step_column && (n_columns < 2 || strcmp(fields[1], "step") != 0)) {
        fclose(in);
        return fail(1, "with STEP '-' the second column of %s must be 'step'", path);
    }
    rows->n_inputs = n_columns - first_input;
    for (int i = 0; i < rows->n_inputs; i++) {
        const Variable *v = find(fields[i + first_input]);
        if (!v || !v->is_real || strcmp(v->causality, "input") != 0) {
            fclose(in);
            return fail(1, "'%s' is not a Real input of the FMU", fields[i + first_input]);
        }
        rows->index[i] = (int)(v - vars);
    }
    size_t capacity = 0;
    rows->n_rows = 0;
    while (fgets(line, sizeof line, in)) {
        if (split(line, fields, MAX_VARS) != n_columns) {
            fclose(in);
            return fail(1, "row %d of %s has the wrong number of fields", rows->n_rows + 1,
                        path);
        }
        if ((size_t)rows->n_rows == capacity) { /* room for twice as many rows */
            capacity = capacity ? 2 * capacity : 1024;
            double *step = realloc(rows->step, capacity * sizeof(double));
            rows->step = step ? step : rows->step;
            double *inputs = realloc(rows->inputs,
                                     capacity * (size_t)(rows->n_inputs + 1) * sizeof(double));
            rows->inputs = inputs ? inputs : rows->inputs;
            if (!step || !inputs) {
                fclose(in);
                return fail(1, "out of memory");
            }
        }
        if (rows->n_rows == 0)
            rows->t0 = strtod(fields[0], NULL);
        rows->step[rows->n_rows] = step_column ? strtod(fields[1], NULL) : 0.0;
        for (int i = 0; i < rows->n_inputs; i++)
            rows->inputs[(size_t)rows->n_rows * rows->n_inputs + i] =
                strtod(fields[i + first_input], NULL);
        rows->n_rows++;
    }
    fclose(in);
    return rows->n_rows ? 0 : fail(1, "%s has no data row", path);
}

/* -- the FMI 3.0 checks ---------------------------------------------------------------------- */

#define EXPECT(call, expected, what)                                                           \
    do {                                                                                       \
        int status_ = (call);                                                                  \
        if (status_ != (expected))                                                             \
            return fail(2, "check failed: %s returned %d, not %d", what, status_, expected);  \
        printf("check: %s -> %d\n", what, status_);                                            \
    } while (0)

/* Every function of an instance given NULL: fmi3Error, no crash. */
static int check_null_instance(Fmu *fmu)
{
    fmi3ValueReference vr = 0;
    double value = 0.0;
    bool flag = false;
    fmi3FMUState state = NULL;
    EXPECT(SYMBOL(fmu, fmi3EnterInitializationMode)(NULL, false, 0.0, 0.0, false, 0.0),
           STATUS_ERROR, "fmi3EnterInitializationMode(NULL)");
    EXPECT(SYMBOL(fmu, fmi3ExitInitializationMode)(NULL), STATUS_ERROR,
           "fmi3ExitInitializationMode(NULL)");
    EXPECT(SYMBOL(fmu, fmi3GetFloat64)(NULL, &vr, 1, &value, 1), STATUS_ERROR,
           "fmi3GetFloat64(NULL)");
    EXPECT(SYMBOL(fmu, fmi3SetFloat64)(NULL, &vr, 1, &value, 1), STATUS_ERROR,
           "fmi3SetFloat64(NULL)");
    EXPECT(SYMBOL(fmu, fmi3DoStep)(NULL, 0.0, 1e-3, true, &flag, &flag, &flag, &value),
           STATUS_ERROR, "fmi3DoStep(NULL)");
    EXPECT(SYMBOL(fmu, fmi3GetFMUState)(NULL, &state), STATUS_ERROR, "fmi3GetFMUState(NULL)");
    EXPECT(SYMBOL(fmu, fmi3Terminate)(NULL), STATUS_ERROR, "fmi3Terminate(NULL)");
    EXPECT(SYMBOL(fmu, fmi3Reset)(NULL), STATUS_ERROR, "fmi3Reset(NULL)");
    SYMBOL(fmu, fmi3FreeInstance)(NULL);
    printf("check: fmi3FreeInstance(NULL) returned\n");
    return 0;
}

/* Calls before the initialisation that belong after it: fmi3Error. */
static int check_sequence(Fmu *fmu)
{
    bool flag = false;
    double last = 0.0;
    EXPECT(SYMBOL(fmu, fmi3DoStep)(fmu->instance, 0.0, 1e-3, true, &flag, &flag, &flag, &last),
           STATUS_ERROR, "fmi3DoStep before the initialisation");
    EXPECT(SYMBOL(fmu, fmi3ExitInitializationMode)(fmu->instance), STATUS_ERROR,
           "fmi3ExitInitializationMode before fmi3EnterInitializationMode");
    EXPECT(SYMBOL(fmu, fmi3EnterStepMode)(fmu->instance), STATUS_ERROR,
           "fmi3EnterStepMode before the initialisation");
    return 0;
}

/* fmi3GetFloat64 of the variable of vars[index] with nValues one off its size: fmi3Error. */
static int check_nvalues(Fmu *fmu, int index)
{
    const Variable *v = &vars[index];
    EXPECT(SYMBOL(fmu, fmi3GetFloat64)(fmu->instance, &v->vr, 1, fmu->values + v->first,
                                       (size_t)v->size - 1),
           STATUS_ERROR, "fmi3GetFloat64 with nValues one less than the variable's size");
    double *more = malloc(sizeof(double) * (size_t)(v->size + 1));
    int status = more ? SYMBOL(fmu, fmi3GetFloat64)(fmu->instance, &v->vr, 1, more,
                                                    (size_t)v->size + 1)
                      : STATUS_OK;
    free(more);
    EXPECT(status, STATUS_ERROR, "fmi3GetFloat64 with nValues one more than the variable's size");
    return 0;
}

/* The rows from `from` replayed from `state` (set into the instance): the recorded outputs
 * bit for bit. */
static int check_replay(Fmu *fmu, fmi3FMUState state, const Rows *rows, int from, double t,
                        double fixed_step, const int outputs[], int n_outputs,
                        const double *record, const char *what)
{
    size_t n = (size_t)rows->n_rows * n_outputs;
    double *again = calloc(n ? n : 1, sizeof(double));
    if (!again)
        return fail(1, "out of memory");
    int code = SYMBOL(fmu, fmi3SetFMUState)(fmu->instance, state) != STATUS_OK
                   ? fail(2, "fmi3SetFMUState (%s) failed", what)
                   : run_rows(fmu, rows, from, t, fixed_step, outputs, n_outputs, again);
    size_t start = (size_t)from * n_outputs;
    if (!code && memcmp(again + start, record + start, sizeof(double) * (n - start)) != 0)
        code = fail(2, "check failed: the rows replayed from %s differ", what);
    free(again);
    if (!code)
        printf("check: the rows replayed from %s are the same, bit for bit\n", what);
    return code;
}

/* The state's bytes: with one bit flipped refused, as serialized a state replaying the rows. */
static int check_states(Fmu *fmu, fmi3FMUState state, const Rows *rows, int from, double t,
                        double fixed_step, const int outputs[], int n_outputs,
                        const double *record)
{
    size_t size = 0;
    EXPECT(SYMBOL(fmu, fmi3SerializedFMUStateSize)(fmu->instance, state, &size), STATUS_OK,
           "fmi3SerializedFMUStateSize");
    unsigned char *bytes = malloc(size);
    if (!bytes)
        return fail(1, "out of memory");
    fmi3FMUState restored = NULL;
    int code = 0;
    if (SYMBOL(fmu, fmi3SerializeFMUState)(fmu->instance, state, bytes, size) != STATUS_OK)
        code = fail(2, "fmi3SerializeFMUState failed");
    if (!code) {
        bytes[size / 2] ^= 4;
        int status = SYMBOL(fmu, fmi3DeserializeFMUState)(fmu->instance, bytes, size, &restored);
        bytes[size / 2] ^= 4;
        if (status != STATUS_ERROR || restored)
            code = fail(2, "check failed: bytes with a flipped bit were taken (status %d)", status);
        else
            printf("check: fmi3DeserializeFMUState of bytes with a flipped bit -> 3\n");
    }
    if (!code && SYMBOL(fmu, fmi3DeserializeFMUState)(fmu->instance, bytes, size, &restored) !=
                     STATUS_OK)
        code = fail(2, "fmi3DeserializeFMUState of the serialized bytes failed");
    if (!code)
        code = check_replay(fmu, state, rows, from, t, fixed_step, outputs, n_outputs, record,
                            "the FMU state in memory");
    if (!code)
        code = check_replay(fmu, restored, rows, from, t, fixed_step, outputs, n_outputs, record,
                            "the deserialized FMU state");
    if (restored && SYMBOL(fmu, fmi3FreeFMUState)(fmu->instance, &restored) != STATUS_OK)
        code = code ? code : fail(2, "fmi3FreeFMUState failed");
    free(bytes);
    return code;
}

/* -- main ------------------------------------------------------------------------------------ */

/* The instance: FMI 2.0 fmi2Instantiate, FMI 3.0 fmi3InstantiateCoSimulation (the host's copy
 * of the values: the start values of modelDescription.xml). */
static int instantiate(Fmu *fmu, const char *dir, const char *guid)
{
    char resources[4200];
    if (fmu->version == 2) {
        static fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
        snprintf(resources, sizeof resources, "file://%s/resources", dir);
        fmu->instance = SYMBOL(fmu, fmi2Instantiate)("host", fmi2CoSimulation, guid, resources,
                                                     &callbacks, fmi2False, fmi2False);
        return fmu->instance ? 0 : fail(2, "fmi2Instantiate returned NULL");
    }
    snprintf(resources, sizeof resources, "%s/resources/", dir);
    fmu->instance = SYMBOL(fmu, fmi3InstantiateCoSimulation)(
        "host", guid, resources, false, false, false, false, NULL, 0, NULL, logger3, NULL);
    if (!fmu->instance)
        return fail(2, "fmi3InstantiateCoSimulation returned NULL");
    fmu->values = calloc((size_t)n_vars, sizeof(double));
    if (!fmu->values)
        return fail(1, "out of memory");
    for (int i = 0; i < n_vars; i++)
        fmu->values[i] = vars[i].start;
    return 0;
}

static int initialise(Fmu *fmu, double t0)
{
    int status;
    if (fmu->version == 2) {
        status = (int)SYMBOL(fmu, fmi2SetupExperiment)(fmu->instance, fmi2False, 0.0, t0,
                                                       fmi2False, 0.0);
        if (status == STATUS_OK)
            status = (int)SYMBOL(fmu, fmi2EnterInitializationMode)(fmu->instance);
        if (status == STATUS_OK)
            status = (int)SYMBOL(fmu, fmi2ExitInitializationMode)(fmu->instance);
    } else {
        status = (int)SYMBOL(fmu, fmi3EnterInitializationMode)(fmu->instance, false, 0.0, t0,
                                                               false, 0.0);
        if (status == STATUS_OK)
            status = (int)SYMBOL(fmu, fmi3ExitInitializationMode)(fmu->instance);
    }
    return status == STATUS_OK ? 0 : fail(2, "the initialisation returned status %d", status);
}

static const char *const FMI2_FUNCTIONS[] = {
    "fmi2Instantiate", "fmi2SetupExperiment", "fmi2EnterInitializationMode",
    "fmi2ExitInitializationMode", "fmi2SetReal", "fmi2GetReal", "fmi2DoStep", "fmi2Terminate",
    "fmi2FreeInstance"};
static const char *const FMI3_FUNCTIONS[] = {
    "fmi3InstantiateCoSimulation", "fmi3EnterInitializationMode", "fmi3ExitInitializationMode",
    "fmi3EnterStepMode", "fmi3SetFloat64", "fmi3GetFloat64", "fmi3DoStep", "fmi3Terminate",
    "fmi3Reset", "fmi3FreeInstance", "fmi3GetFMUState", "fmi3SetFMUState", "fmi3FreeFMUState",
    "fmi3SerializedFMUStateSize", "fmi3SerializeFMUState", "fmi3DeserializeFMUState"};

/* The binary of the FMU in dir, its functions checked; 0 or the exit code. */
static int load(Fmu *fmu, const char *dir, const char *identifier)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/binaries/%s/%s.so", dir,
             fmu->version == 2 ? "linux64" : "x86_64-linux", identifier);
    fmu->lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!fmu->lib)
        return fail(1, "dlopen %s: %s", path, dlerror());
    if (libpython_mapped())
        return fail(3, "libpython is mapped into the host process");
    const char *const *names = fmu->version == 2 ? FMI2_FUNCTIONS : FMI3_FUNCTIONS;
    size_t n = fmu->version == 2 ? sizeof FMI2_FUNCTIONS / sizeof *names
                                 : sizeof FMI3_FUNCTIONS / sizeof *names;
    for (size_t i = 0; i < n; i++)
        if (!dlsym(fmu->lib, names[i]))
            return fail(1, "%s not exported", names[i]);
    return 0;
}

/* The run of an instantiated FMU: parameters, initialisation, the rows (FMI 3.0: the checks),
 * termination. */
static int run(Fmu *fmu, const Rows *rows, double fixed_step, char **parameters, int n_parameters,
               FILE *out)
{
    int outputs[MAX_VARS], n_outputs = 0, code = 0;
    fprintf(out, "time");
    for (int i = 0; i < n_vars; i++)
        if (vars[i].is_real && strcmp(vars[i].causality, "output") == 0) {
            outputs[n_outputs++] = i;
            fprintf(out, ",%s", vars[i].name);
        }
    fprintf(out, "\n");
    if (fmu->version == 3 && (code = check_sequence(fmu)) != 0)
        return code;
    for (int i = 0; i < n_parameters; i++) {
        char name[256];
        const char *eq = strchr(parameters[i], '=');
        if (!eq || (size_t)(eq - parameters[i]) >= sizeof name)
            return fail(1, "'%s' is not NAME=VALUE", parameters[i]);
        memcpy(name, parameters[i], (size_t)(eq - parameters[i]));
        name[eq - parameters[i]] = '\0';
        const Variable *v = find(name);
        if (!v || !v->is_real)
            return fail(1, "'%s' is not a Real variable of the FMU", name);
        int index = (int)(v - vars);
        double value = strtod(eq + 1, NULL);
        int status = set_reals(fmu, &index, 1, &value);
        if (status != STATUS_OK)
            return fail(2, "setting %s returned status %d", name, status);
    }
    if ((code = initialise(fmu, rows->t0)) != 0)
        return code;
    double *record = calloc((size_t)rows->n_rows * n_outputs + 1, sizeof(double));
    if (!record)
        return fail(1, "out of memory");
    int middle = rows->n_rows / 2;
    double t_middle = fixed_step > 0.0 ? rows->t0 + middle * fixed_step : rows->t0;
    for (int row = 0; row < middle && fixed_step <= 0.0; row++)
        t_middle += rows->step[row];
    fmi3FMUState state = NULL;
    if (fmu->version == 3 && middle > 0) {
        Rows head = *rows;
        head.n_rows = middle + 1;
        code = run_rows(fmu, &head, 0, rows->t0, fixed_step, outputs, n_outputs, record);
        if (!code && SYMBOL(fmu, fmi3GetFMUState)(fmu->instance, &state) != STATUS_OK)
            code = fail(2, "fmi3GetFMUState failed");
        code = code ? code : run_rows(fmu, rows, middle, t_middle, fixed_step, outputs,
                                      n_outputs, record);
    } else {
        code = run_rows(fmu, rows, 0, rows->t0, fixed_step, outputs, n_outputs, record);
    }
    double t = rows->t0;
    for (int row = 0; !code && row < rows->n_rows; row++) {
        if (row > 0) /* the times of run_rows */
            t = fixed_step > 0.0 ? rows->t0 + row * fixed_step : t + rows->step[row - 1];
        fprintf(out, "%.17g", t);
        for (int i = 0; i < n_outputs; i++)
            fprintf(out, ",%.17g", record[(size_t)row * n_outputs + i]);
        fprintf(out, "\n");
    }
    if (!code && fmu->version == 3 && n_outputs)
        code = check_nvalues(fmu, outputs[0]);
    if (!code && state)
        code = check_states(fmu, state, rows, middle, t_middle, fixed_step, outputs, n_outputs,
                            record);
    if (state && SYMBOL(fmu, fmi3FreeFMUState)(fmu->instance, &state) != STATUS_OK)
        code = code ? code : fail(2, "fmi3FreeFMUState failed");
    free(record);
    if (code)
        return code;
    int status = fmu->version == 2 ? SYMBOL(fmu, fmi2Terminate)(fmu->instance)
                                   : SYMBOL(fmu, fmi3Terminate)(fmu->instance);
    if (status != STATUS_OK)
        return fail(2, "terminate returned status %d", status);
    if (fmu->version == 3) {
        bool flag = false;
        double last = 0.0;
        EXPECT(SYMBOL(fmu, fmi3DoStep)(fmu->instance, 0.0, 1e-3, true, &flag, &flag, &flag,
                                       &last),
               STATUS_ERROR, "fmi3DoStep after fmi3Terminate");
    }
    return 0;
}

int main(int argc, char **argv)
{
    if (argc < 5)
        return fail(1, "usage: native_host FMU_DIR INPUTS.csv OUTPUTS.csv STEP [NAME=VALUE ...]");
    int step_column = strcmp(argv[4], "-") == 0;
    double step = step_column ? 0.0 : strtod(argv[4], NULL);
    if (!step_column && !(step > 0.0))
        return fail(1, "STEP must be positive or '-', got '%s'", argv[4]);
    char path[4096], identifier[256], guid[256], version[16];
    snprintf(path, sizeof path, "%s/modelDescription.xml", argv[1]);
    char *xml = read_file(path);
    if (!xml)
        return fail(1, "cannot read %s", path);
    Fmu fmu = {0};
    const char *root = strstr(xml, "<fmiModelDescription");
    const char *root_end = root ? strchr(root, '>') : NULL;
    if (!root || !attribute(root, root_end, "fmiVersion", version, sizeof version))
        return fail(1, "no fmiVersion in %s", path);
    fmu.version = strcmp(version, "3.0") == 0 ? 3 : 2;
    const char *cs = strstr(xml, "<CoSimulation");
    if (!cs || !attribute(cs, strchr(cs, '>'), "modelIdentifier", identifier, sizeof identifier))
        return fail(1, "no CoSimulation modelIdentifier in %s", path);
    if (!attribute(root, root_end, fmu.version == 2 ? "guid" : "instantiationToken", guid,
                   sizeof guid))
        return fail(1, "no guid or instantiationToken in %s", path);
    if (!(fmu.version == 2 ? parse_variables2(xml) : parse_variables3(xml)))
        return fail(1, "no variables in %s", path);
    free(xml);

    int code = load(&fmu, argv[1], identifier);
    if (code)
        return code;
    static Rows rows;
    if ((code = read_rows(argv[2], step_column, &rows)) != 0)
        return code;
    FILE *out = fopen(argv[3], "w");
    if (!out)
        return fail(1, "cannot open %s", argv[3]);
    if (fmu.version == 3 && (code = check_null_instance(&fmu)) != 0)
        return code;
    code = instantiate(&fmu, argv[1], guid);
    if (!code)
        code = run(&fmu, &rows, step, argv + 5, argc - 5, out);
    if (fmu.instance && fmu.version == 2)
        SYMBOL(&fmu, fmi2FreeInstance)(fmu.instance);
    else if (fmu.instance)
        SYMBOL(&fmu, fmi3FreeInstance)(fmu.instance);
    fclose(out);
    free(fmu.values);
    free(rows.step);
    free(rows.inputs);
    dlclose(fmu.lib);
    return code;
}
