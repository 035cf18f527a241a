/*
 * One communication step of harness.master's Jacobi loop: fmi2SetReal of every FMU with
 * inputs, fmi2DoStep of every FMU, fmi2GetReal of every FMU with outputs, in that order,
 * exactly the calls the master's Python loop makes. Compiled and loaded by harness.native;
 * calling it once per step spares eight of the nine ctypes calls per step.
 */
#include <stddef.h>

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

/* Step the n FMUs from t by h. Returns 0, or the first status worse than fmi2Warning, the
 * call stopping there: failed[0] = index of the FMU, failed[1] = 0 set, 1 doStep, 2 get. */
int harness_step(const StepFmu *fmus, int n, double t, double h, int failed[2])
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
