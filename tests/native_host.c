/*
 * A minimal native FMI 2.0 co-simulation host for the tests: no Python anywhere in its
 * process. It loads an extracted FMU's binaries/linux64/<modelIdentifier>.so, checks that no
 * libpython is mapped, runs the FMI call sequence with the inputs of a CSV file and writes the
 * outputs to another CSV file.
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
 * Exit codes: 0 success, 1 usage or file error, 2 an FMI call did not return fmi2OK,
 * 3 libpython is mapped into the process.
 */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

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

static int fail(int code, const char *format, ...)
{
    va_list args;
    va_start(args, format);
    fprintf(stderr, "native_host: ");
    vfprintf(stderr, format, args);
    fprintf(stderr, "\n");
    va_end(args);
    return code;
}

static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env;
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s] status %d %s: ", instance ? instance : "?", (int)status,
            category ? category : "");
    vfprintf(stderr, message, args);
    fprintf(stderr, "\n");
    va_end(args);
}

static char *read_file(const char *path)
{
    /* read in chunks: files of /proc report a size of 0 */
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    size_t size = 0, capacity = 1 << 16;
    char *text = malloc(capacity);
    while (text) {
        size += fread(text + size, 1, capacity - size - 1, f);
        if (size < capacity - 1)
            break;
        char *grown = realloc(text, capacity *= 2);
        if (!grown)
            free(text);
        text = grown;
    }
    if (text)
        text[size] = '\0';
    fclose(f);
    return text;
}

/* The value of attribute `name` inside the tag [tag, end): copied to out, 0 if absent. */
static int attribute(const char *tag, const char *end, const char *name, char *out, size_t size)
{
    char key[64];
    snprintf(key, sizeof key, " %s=\"", name);
    const char *start = strstr(tag, key);
    if (!start || start >= end)
        return 0;
    start += strlen(key);
    const char *stop = strchr(start, '"');
    if (!stop || (size_t)(stop - start) >= size)
        return 0;
    memcpy(out, start, (size_t)(stop - start));
    out[stop - start] = '\0';
    return 1;
}

/* Scalar variables (name, value reference, causality, Real or not) of modelDescription.xml. */
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

static int libpython_mapped(void)
{
    char *maps = read_file("/proc/self/maps");
    int found = maps && strstr(maps, "libpython") != NULL;
    free(maps);
    return found;
}

/* Split a CSV line in place into at most max fields; returns the count. */
static int split(char *line, char **fields, int max)
{
    int count = 0;
    line[strcspn(line, "\r\n")] = '\0';
    for (char *tok = strtok(line, ","); tok && count < max; tok = strtok(NULL, ","))
        fields[count++] = tok;
    return count;
}

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

int main(int argc, char **argv)
{
    if (argc < 5)
        return fail(1, "usage: native_host FMU_DIR INPUTS.csv OUTPUTS.csv STEP [NAME=VALUE ...]");
    int step_column = strcmp(argv[4], "-") == 0;
    double step = step_column ? 0.0 : strtod(argv[4], NULL);
    if (!step_column && !(step > 0.0))
        return fail(1, "STEP must be positive or '-', got '%s'", argv[4]);
    char path[4096], identifier[256], guid[256];
    snprintf(path, sizeof path, "%s/modelDescription.xml", argv[1]);
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

    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", argv[1], identifier);
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib)
        return fail(1, "dlopen %s: %s", path, dlerror());
    if (libpython_mapped())
        return fail(3, "libpython is mapped into the host process");
    LOAD(fmi2Instantiate)
    LOAD(fmi2SetupExperiment)
    LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode)
    LOAD(fmi2SetReal)
    LOAD(fmi2GetReal)
    LOAD(fmi2DoStep)
    LOAD(fmi2Terminate)
    LOAD(fmi2FreeInstance)

    FILE *in = fopen(argv[2], "r");
    FILE *out = fopen(argv[3], "w");
    if (!in || !out)
        return fail(1, "cannot open %s or %s", argv[2], argv[3]);
    static char line[MAX_LINE];
    char *fields[MAX_VARS];
    if (!fgets(line, sizeof line, in))
        return fail(1, "%s is empty", argv[2]);
    int n_columns = split(line, fields, MAX_VARS);
    int first_input = step_column ? 2 : 1; /* the column of the first input */
    int n_inputs = n_columns - first_input;
    if (step_column && (n_columns < 2 || strcmp(fields[1], "step") != 0))
        return fail(1, "with STEP '-' the second column of %s must be 'step'", argv[2]);
    fmi2ValueReference input_vrs[MAX_VARS], output_vrs[MAX_VARS];
    for (int i = 0; i < n_inputs; i++) {
        const Variable *v = find(fields[i + first_input]);
        if (!v || !v->is_real || strcmp(v->causality, "input") != 0)
            return fail(1, "'%s' is not a Real input of the FMU", fields[i + first_input]);
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

    char resources[4200];
    snprintf(resources, sizeof resources, "file://%s/resources", argv[1]);
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("host", fmi2CoSimulation, guid, resources, &callbacks,
                                      fmi2False, fmi2False);
    if (!c)
        return fail(2, "fmi2Instantiate returned NULL");
    for (int i = 5; i < argc; i++) {
        char name[256];
        const char *eq = strchr(argv[i], '=');
        if (!eq || (size_t)(eq - argv[i]) >= sizeof name)
            return fail(1, "'%s' is not NAME=VALUE", argv[i]);
        memcpy(name, argv[i], (size_t)(eq - argv[i]));
        name[eq - argv[i]] = '\0';
        const Variable *v = find(name);
        if (!v || !v->is_real)
            return fail(1, "'%s' is not a Real variable of the FMU", name);
        fmi2Real value = strtod(eq + 1, NULL);
        CHECK(fmi2SetReal(c, &v->vr, 1, &value));
    }

    double values[MAX_VARS], inputs[MAX_VARS], t0, t;
    int row = 0, have_row = fgets(line, sizeof line, in) != NULL;
    if (!have_row)
        return fail(1, "%s has no data row", argv[2]);
    if (split(line, fields, MAX_VARS) != n_columns)
        return fail(1, "row 1 of %s has the wrong number of fields", argv[2]);
    t = t0 = strtod(fields[0], NULL);
    if (step_column)
        step = strtod(fields[1], NULL);
    for (int i = 0; i < n_inputs; i++)
        inputs[i] = strtod(fields[i + first_input], NULL);
    CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, t, fmi2False, 0.0));
    CHECK(fmi2EnterInitializationMode(c));
    CHECK(fmi2ExitInitializationMode(c));
    for (;;) {
        CHECK(fmi2GetReal(c, output_vrs, (size_t)n_outputs, values));
        fprintf(out, "%.17g", t);
        for (int i = 0; i < n_outputs; i++)
            fprintf(out, ",%.17g", values[i]);
        fprintf(out, "\n");
        if (!fgets(line, sizeof line, in))
            break;
        row++;
        if (split(line, fields, MAX_VARS) != n_columns)
            return fail(1, "row %d of %s has the wrong number of fields", row + 1, argv[2]);
        CHECK(fmi2SetReal(c, input_vrs, (size_t)n_inputs, inputs));
        CHECK(fmi2DoStep(c, t, step, fmi2True));
        if (step_column) {
            t += step;
            step = strtod(fields[1], NULL);
        } else {
            t = t0 + row * step;
        }
        for (int i = 0; i < n_inputs; i++)
            inputs[i] = strtod(fields[i + first_input], NULL);
    }
    CHECK(fmi2Terminate(c));
    fmi2FreeInstance(c);
    fclose(in);
    fclose(out);
    free(xml);
    return 0;
}
