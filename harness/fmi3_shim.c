/*
 * An FMI 3.0 co-simulation instance seen through the three FMI 2.0 calls of harness.master's
 * step loop (fmi2SetReal, fmi2DoStep, fmi2GetReal, with a Shim as the component): the scalar
 * "value references" are element numbers (harness.fmi3.ElementSpace: each Float64 variable's
 * elements numbered in turn, row-major), which the shim maps onto the variables' value
 * references and offsets; a set writes the elements into its copy of their arrays and sets
 * each array touched whole (fmi3SetFloat64 with nValues its size), a get reads each array
 * asked whole and picks the elements. Compiled and loaded by harness.fmi3.
 */
#include <stdbool.h>
#include <stddef.h>

typedef int set_float64_fn(void *instance, const unsigned int vr[], size_t nvr,
                           const double values[], size_t n_values);
typedef int get_float64_fn(void *instance, const unsigned int vr[], size_t nvr, double values[],
                           size_t n_values);
typedef int do_step_fn(void *instance, double t, double h, bool no_set_prior,
                       bool *event_handling_needed, bool *terminate, bool *early_return,
                       double *last_successful_time);

/* harness.fmi3.Shim */
typedef struct {
    void *instance;
    set_float64_fn *set_float64;
    get_float64_fn *get_float64;
    do_step_fn *do_step;
    const unsigned int *array_vr; /* per element: its variable's value reference */
    const long *array_start;      /* per element: where its variable's values start in values */
    const long *array_size;       /* per element: its variable's number of values */
    double *values;               /* every variable's values, in element order */
    long *stamp;                  /* per element: the call that last set or read its variable */
    long calls;
} Shim;

#define FMI_WARNING 1
#define FMI_ERROR 3

int fmi2SetReal(Shim *s, const unsigned int vr[], size_t n, const double v[])
{
    long call = ++s->calls;
    for (size_t i = 0; i < n; i++)
        s->values[vr[i]] = v[i];
    for (size_t i = 0; i < n; i++) {
        long start = s->array_start[vr[i]];
        if (s->stamp[start] == call)
            continue;
        s->stamp[start] = call;
        int status = s->set_float64(s->instance, &s->array_vr[vr[i]], 1, s->values + start,
                                    (size_t)s->array_size[vr[i]]);
        if (status > FMI_WARNING)
            return status;
    }
    return 0;
}

int fmi2GetReal(Shim *s, const unsigned int vr[], size_t n, double v[])
{
    long call = ++s->calls;
    for (size_t i = 0; i < n; i++) {
        long start = s->array_start[vr[i]];
        if (s->stamp[start] != call) {
            s->stamp[start] = call;
            int status = s->get_float64(s->instance, &s->array_vr[vr[i]], 1, s->values + start,
                                        (size_t)s->array_size[vr[i]]);
            if (status > FMI_WARNING)
                return status;
        }
        v[i] = s->values[vr[i]];
    }
    return 0;
}

/* A step that asks for event handling, to terminate or returned early is an error: the
 * master's fixed steps have no event mode. */
int fmi2DoStep(Shim *s, double t, double h, int no_set_prior)
{
    bool event = false, terminate = false, early = false;
    double last = t;
    int status = s->do_step(s->instance, t, h, no_set_prior != 0, &event, &terminate, &early,
                            &last);
    if (status <= FMI_WARNING && (event || terminate || early))
        return FMI_ERROR;
    return status;
}
