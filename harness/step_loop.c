/*
 * The steps of harness.master's Jacobi loop: per step, the inputs gathered from the outputs
 * (the connections' gains, row by row, summed left to right), fmi2SetReal of every FMU with
 * inputs, fmi2DoStep of every FMU, fmi2GetReal of every FMU with outputs, in that order, and
 * the outputs recorded: exactly what the master's Python loop does. Compiled and loaded by
 * harness.native; one call runs a chunk of steps.
 */
#include <stddef.h>
#include <string.h>

typedef int set_real_fn(void *c, const unsigned int vr[], size_t n, const double v[]);
typedef int get_real_fn(void *c, const unsigned int vr[], size_t n, double v[]);
typedef int do_step_fn(void *c, double t, double h, int no_set_prior);

/* One FMU: its component, entry points and buffers (harness.native.StepFmu). */
typedef struct {
    void *component;
    set_real_fn *set_real;
    do_step_fn *do_step;
    get_real_fn *get_real;
    const unsigned int *in_vr;
    size_t in_n;
    const double *in_buf;
    const unsigned int *out_vr;
    size_t out_n;
    double *out_buf;
} StepFmu;

#define FMI2_WARNING 1

/* The connections: input i = sum over e in [row_start[i], row_start[i+1]) of
 * gains[e] * (outputs[cols[e]] - offsets[e] + draw), summed left to right, plus bias[i]
 * (harness.master.Connections); draw = noise[(k - noise_from) * n_noise + noise_index[e]] of
 * step k when noise_index[e] >= 0, none else. */
typedef struct {
    int n_inputs;
    const int *row_start;
    const int *cols;
    const double *gains;
    const double *offsets;
    const double *bias;
    const int *noise_index;
    const double *noise;
    int n_noise;
    long noise_from;
} Gather;

static void gather(const Gather *g, const double *outputs, double *inputs, long k)
{
    const double *draws = g->noise + (size_t)(k - g->noise_from) * (size_t)g->n_noise;
    for (int i = 0; i < g->n_inputs; i++) {
        double s = 0.0;
        for (int e = g->row_start[i]; e < g->row_start[i + 1]; e++) {
            double v = outputs[g->cols[e]] - g->offsets[e];
            if (g->noise_index[e] >= 0)
                v += draws[g->noise_index[e]];
            s += g->gains[e] * v;
        }
        inputs[i] = s + g->bias[i];
    }
}

/* Step the n FMUs from t by h. Returns 0, or the first status worse than fmi2Warning, the
 * call stopping there: failed[0] = index of the FMU, failed[1] = 0 set, 1 doStep, 2 get. */
static int harness_step(const StepFmu *fmus, int n, double t, double h, int failed[2])
{
    int status;
    for (int i = 0; i < n; i++) {
        const StepFmu *f = &fmus[i];
        if (f->in_n && (status = f->set_real(f->component, f->in_vr, f->in_n, f->in_buf)) > FMI2_WARNING) {
            failed[0] = i;
            failed[1] = 0;
            return status;
        }
    }
    for (int i = 0; i < n; i++) {
        const StepFmu *f = &fmus[i];
        if ((status = f->do_step(f->component, t, h, 1)) > FMI2_WARNING) {
            failed[0] = i;
            failed[1] = 1;
            return status;
        }
    }
    for (int i = 0; i < n; i++) {
        const StepFmu *f = &fmus[i];
        if (f->out_n && (status = f->get_real(f->component, f->out_vr, f->out_n, f->out_buf)) > FMI2_WARNING) {
            failed[0] = i;
            failed[1] = 2;
            return status;
        }
    }
    return 0;
}

/* Steps k_from .. k_to - 1 from t_k = t0 + k h: gather, step, record the outputs (n_outputs
 * of them) as row k + 1 of values. Returns 0, or the failed step's status with failed[0] the
 * FMU, failed[1] the call (0 set, 1 doStep, 2 get) and *failed_step = k. */
int harness_run(const StepFmu *fmus, int n, const Gather *g, const double *outputs,
                double *inputs, int n_outputs, double *values, long k_from, long k_to,
                double t0, double h, int failed[2], long *failed_step)
{
    for (long k = k_from; k < k_to; k++) {
        gather(g, outputs, inputs, k);
        int status = harness_step(fmus, n, t0 + (double)k * h, h, failed);
        if (status) {
            *failed_step = k;
            return status;
        }
        memcpy(values + (size_t)(k + 1) * (size_t)n_outputs, outputs,
               sizeof(double) * (size_t)n_outputs);
    }
    return 0;
}
