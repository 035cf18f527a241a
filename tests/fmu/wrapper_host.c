/*
 * A native FMI 2.0 co-simulation host for the status wrapper tests (tests/fmu/test_wrapper_*.py).
 * Unlike tests/native_host.c it accepts libpython in its process: it drives the pythonfmu FMUs,
 * whose wrapper loads the interpreter itself. The host never links or loads Python.
 *
 *   wrapper_host run FMU_DIR INPUTS.csv OUTPUTS.csv STEP
 *   wrapper_host null FMU_DIR FUNCTION...
 *
 * run   as tests/native_host.c: INPUTS.csv is "time,<input name>,..." then one row per
 *       communication point (inputs held over the step); OUTPUTS.csv gets "time,<output>,..."
 *       (every Real output), a row after initialisation and one after each doStep; then
 *       fmi2Terminate, fmi2FreeInstance and a normal exit.
 * null  instantiate, then call each FUNCTION (fmi2DoStep, fmi2GetReal, ...) in turn with a NULL
 *       component and otherwise valid arguments; prints a line "STATUS <n>" (or "CALLED" for
 *       fmi2FreeInstance) per call, flushed, then frees the instance and exits normally.
 *
 * The instance is made with loggingOn; the FMU's log messages go to stderr as
 * "[instance] status <n> <category>: <message>".
 * Exit codes: 0 success, 1 usage or file error, 2 an FMI call did not return fmi2OK (or
 * fmi2Instantiate returned NULL).
 */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define HOST_NAME "wrapper_host"
#include "../host_common.h"

#define MAX_VARS 4096
#define MAX_LINE 65536

typedef struct {
    char name[256];
    fmi2ValueReference vr;
    int is_real;
    char causality[32];
} Variable;

static Variable vars[MAX_VARS];
static int n_vars;

static int parse_variables(const char *xml)
{
    const char *p = xml;
    while ((p = strstr(p, "<ScalarVariable")) != NULL) {
        const char *end = strchr(p, '>');
        const char *close = strstr(p, "</ScalarVariable>");
        if (!end || n_vars == MAX_VARS)
            return 0;
        Variable *v = &vars[n_vars];
        char vr[32];
        if (!attribute(p, end, "name", v->name, sizeof v->name) ||
            !attribute(p, end, "valueReference", vr, sizeof vr))
            return 0;
        if (!attribute(p, end, "causality", v->causality, sizeof v->causality))
            strcpy(v->causality, "local");
        v->vr = (fmi2ValueReference)strtoul(vr, NULL, 10);
        const char *real = strstr(end, "<Real");
        v->is_real = real && (!close || real < close);
        n_vars++;
        p = end;
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

static void *lib;

#define LOAD(name)                                                                          \
    name##TYPE *name = (name##TYPE *)dlsym(lib, #name);                                     \
    if (!name)                                                                              \
        return fail(1, "%s not exported", #name);

#define CHECK(call)                                                                         \
    do {                                                                                    \
        fmi2Status status_ = (call);                                                        \
        if (status_ != fmi2OK)                                                              \
            return fail(2, "%s returned status %d", #call, (int)status_);                   \
    } while (0)

static int run(fmi2Component c, const char *inputs_path, const char *outputs_path, double step)
{
    LOAD(fmi2SetupExperiment)
    LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode)
    LOAD(fmi2SetReal)
    LOAD(fmi2GetReal)
    LOAD(fmi2DoStep)
    LOAD(fmi2Terminate)
    FILE *in = fopen(inputs_path, "r");
    FILE *out = fopen(outputs_path, "w");
    if (!in || !out)
        return fail(1, "cannot open %s or %s", inputs_path, outputs_path);
    static char line[MAX_LINE];
    static char *fields[MAX_VARS];
    static fmi2ValueReference input_vrs[MAX_VARS], output_vrs[MAX_VARS];
    static double values[MAX_VARS], inputs[MAX_VARS];
    if (!fgets(line, sizeof line, in))
        return fail(1, "%s is empty", inputs_path);
    int n_columns = split(line, fields, MAX_VARS);
    int n_inputs = n_columns - 1;
    for (int i = 0; i < n_inputs; i++) {
        const Variable *v = find(fields[i + 1]);
        if (!v || !v->is_real || strcmp(v->causality, "input") != 0)
            return fail(1, "'%s' is not a Real input of the FMU", fields[i + 1]);
        input_vrs[i] = v->vr;
    }
    int n_outputs = 0;
    fprintf(out, "time");
    for (int i = 0; i < n_vars; i++)
        if (vars[i].is_real && strcmp(vars[i].causality, "output") == 0) {
            output_vrs[n_outputs++] = vars[i].vr;
            fprintf(out, ",%s", vars[i].name);
        }
    fprintf(out, "\n");
    if (!fgets(line, sizeof line, in) || split(line, fields, MAX_VARS) != n_columns)
        return fail(1, "%s has no complete data row", inputs_path);
    double t0 = strtod(fields[0], NULL), t = t0;
    for (int i = 0; i < n_inputs; i++)
        inputs[i] = strtod(fields[i + 1], NULL);
    CHECK(fmi2SetReal(c, input_vrs, (size_t)n_inputs, inputs));
    CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, t, fmi2False, 0.0));
    CHECK(fmi2EnterInitializationMode(c));
    CHECK(fmi2ExitInitializationMode(c));
    for (int row = 0;;) {
        CHECK(fmi2GetReal(c, output_vrs, (size_t)n_outputs, values));
        fprintf(out, "%.17g", t);
        for (int i = 0; i < n_outputs; i++)
            fprintf(out, ",%.17g", values[i]);
        fprintf(out, "\n");
        if (!fgets(line, sizeof line, in))
            break;
        row++;
        if (split(line, fields, MAX_VARS) != n_columns)
            return fail(1, "row %d of %s has the wrong number of fields", row + 1, inputs_path);
        CHECK(fmi2SetReal(c, input_vrs, (size_t)n_inputs, inputs));
        CHECK(fmi2DoStep(c, t, step, fmi2True));
        t = t0 + row * step;
        for (int i = 0; i < n_inputs; i++)
            inputs[i] = strtod(fields[i + 1], NULL);
    }
    CHECK(fmi2Terminate(c));
    fclose(in);
    fclose(out);
    return 0;
}

/* Call ``function`` with a NULL component (other arguments valid) and print its status. */
static int call_with_null(const char *function)
{
    void *f = dlsym(lib, function);
    if (!f)
        return fail(1, "%s not exported", function);
    fmi2ValueReference vr = 0;
    fmi2Real real = 0.0;
    fmi2Integer integer = 0;
    fmi2Boolean boolean = fmi2False;
    fmi2String string = "";
    fmi2FMUstate state = NULL;
    fmi2Status kind_status;
    size_t size = 0;
    fmi2Byte bytes[16] = { 0 };
    const fmi2String categories[] = { "logAll" };
    fmi2Status status;
    if (strcmp(function, "fmi2FreeInstance") == 0) {
        ((fmi2FreeInstanceTYPE *)f)(NULL);
        printf("CALLED\n");
        fflush(stdout);
        return 0;
    }
#define IS(name) (strcmp(function, #name) == 0)
    if (IS(fmi2DoStep))
        status = ((fmi2DoStepTYPE *)f)(NULL, 0.0, 1e-3, fmi2True);
    else if (IS(fmi2Terminate) || IS(fmi2Reset) || IS(fmi2EnterInitializationMode)
             || IS(fmi2ExitInitializationMode) || IS(fmi2CancelStep))
        status = ((fmi2TerminateTYPE *)f)(NULL);
    else if (IS(fmi2SetupExperiment))
        status = ((fmi2SetupExperimentTYPE *)f)(NULL, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    else if (IS(fmi2SetDebugLogging))
        status = ((fmi2SetDebugLoggingTYPE *)f)(NULL, fmi2True, 1, categories);
    else if (IS(fmi2GetReal))
        status = ((fmi2GetRealTYPE *)f)(NULL, &vr, 1, &real);
    else if (IS(fmi2SetReal))
        status = ((fmi2SetRealTYPE *)f)(NULL, &vr, 1, &real);
    else if (IS(fmi2GetInteger))
        status = ((fmi2GetIntegerTYPE *)f)(NULL, &vr, 1, &integer);
    else if (IS(fmi2SetInteger))
        status = ((fmi2SetIntegerTYPE *)f)(NULL, &vr, 1, &integer);
    else if (IS(fmi2GetBoolean))
        status = ((fmi2GetBooleanTYPE *)f)(NULL, &vr, 1, &boolean);
    else if (IS(fmi2SetBoolean))
        status = ((fmi2SetBooleanTYPE *)f)(NULL, &vr, 1, &boolean);
    else if (IS(fmi2GetString))
        status = ((fmi2GetStringTYPE *)f)(NULL, &vr, 1, &string);
    else if (IS(fmi2SetString))
        status = ((fmi2SetStringTYPE *)f)(NULL, &vr, 1, &string);
    else if (IS(fmi2GetFMUstate))
        status = ((fmi2GetFMUstateTYPE *)f)(NULL, &state);
    else if (IS(fmi2SetFMUstate))
        status = ((fmi2SetFMUstateTYPE *)f)(NULL, state);
    else if (IS(fmi2FreeFMUstate))
        status = ((fmi2FreeFMUstateTYPE *)f)(NULL, &state);
    else if (IS(fmi2SerializedFMUstateSize))
        status = ((fmi2SerializedFMUstateSizeTYPE *)f)(NULL, state, &size);
    else if (IS(fmi2SerializeFMUstate))
        status = ((fmi2SerializeFMUstateTYPE *)f)(NULL, state, bytes, sizeof bytes);
    else if (IS(fmi2DeSerializeFMUstate))
        status = ((fmi2DeSerializeFMUstateTYPE *)f)(NULL, bytes, sizeof bytes, &state);
    else if (IS(fmi2GetStatus))
        status = ((fmi2GetStatusTYPE *)f)(NULL, fmi2DoStepStatus, &kind_status);
    else if (IS(fmi2GetRealStatus))
        status = ((fmi2GetRealStatusTYPE *)f)(NULL, fmi2LastSuccessfulTime, &real);
    else if (IS(fmi2GetIntegerStatus))
        status = ((fmi2GetIntegerStatusTYPE *)f)(NULL, fmi2DoStepStatus, &integer);
    else if (IS(fmi2GetBooleanStatus))
        status = ((fmi2GetBooleanStatusTYPE *)f)(NULL, fmi2Terminated, &boolean);
    else if (IS(fmi2GetStringStatus))
        status = ((fmi2GetStringStatusTYPE *)f)(NULL, fmi2PendingStatus, &string);
    else if (IS(fmi2GetDirectionalDerivative))
        status = ((fmi2GetDirectionalDerivativeTYPE *)f)(NULL, &vr, 1, &vr, 1, &real, &real);
    else if (IS(fmi2SetRealInputDerivatives))
        status = ((fmi2SetRealInputDerivativesTYPE *)f)(NULL, &vr, 1, &integer, &real);
    else if (IS(fmi2GetRealOutputDerivatives))
        status = ((fmi2GetRealOutputDerivativesTYPE *)f)(NULL, &vr, 1, &integer, &real);
    else
        return fail(1, "no NULL call written for %s", function);
#undef IS
    printf("STATUS %d\n", (int)status);
    fflush(stdout); /* the calls before a crash stay reported */
    return 0;
}

int main(int argc, char **argv)
{
    int is_run = argc == 6 && strcmp(argv[1], "run") == 0;
    int is_null = argc >= 4 && strcmp(argv[1], "null") == 0;
    if (!is_run && !is_null)
        return fail(1, "usage: wrapper_host run FMU_DIR INPUTS.csv OUTPUTS.csv STEP | "
                       "wrapper_host null FMU_DIR FUNCTION...");
    char path[4096], identifier[256], guid[256], resources[4200];
    snprintf(path, sizeof path, "%s/modelDescription.xml", argv[2]);
    char *xml = read_file(path);
    if (!xml)
        return fail(1, "cannot read %s", path);
    const char *cs = strstr(xml, "<CoSimulation");
    if (!cs || !attribute(cs, strchr(cs, '>'), "modelIdentifier", identifier, sizeof identifier))
        return fail(1, "no CoSimulation modelIdentifier in %s", path);
    const char *root = strstr(xml, "<fmiModelDescription");
    if (!root || !attribute(root, strchr(root, '>'), "guid", guid, sizeof guid))
        return fail(1, "no guid in %s", path);
    if (!parse_variables(xml))
        return fail(1, "no scalar variables in %s", path);
    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", argv[2], identifier);
    lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib)
        return fail(1, "dlopen %s: %s", path, dlerror());
    LOAD(fmi2Instantiate)
    LOAD(fmi2FreeInstance)
    snprintf(resources, sizeof resources, "file://%s/resources", argv[2]);
    fmi2CallbackFunctions callbacks = { logger, calloc, free, NULL, NULL };
    fmi2Component c = fmi2Instantiate("host", fmi2CoSimulation, guid, resources, &callbacks,
                                      fmi2False, fmi2True);
    if (!c)
        return fail(2, "fmi2Instantiate returned NULL");
    int code = 0;
    if (is_run)
        code = run(c, argv[3], argv[4], strtod(argv[5], NULL));
    else
        for (int i = 3; i < argc && code == 0; i++)
            code = call_with_null(argv[i]);
    fmi2FreeInstance(c);
    free(xml);
    fflush(stdout);
    return code;
}
