/*
 * The C model of the filtering family (the filtering homogeneous observer, Theorem 2): its
 * split plans per step size (filter_plans.c), the euler plan when the design has one; state
 * z, psi, xi; outputs the state's and sigma.
 */
#include <stdio.h>

#include "filter_plans.h"

struct Work {
    FilterPlans plans;
    EulerScheme euler;
};

size_t model_work_size(void)
{
    return sizeof(Work);
}

void work_init(Work *w)
{
    filter_plans_init(&w->plans);
    euler_scheme_init(&w->euler);
}

static const void *split_plan(Work *w, double dt, char *msg, size_t len)
{
    return filter_plan(&w->plans, dt, msg, len);
}

int model_parameters_problem(const double *real, const int *integer, char *msg, size_t len)
{
    return timing_problem(real, integer, FHOBS_HAS_EULER, FHOBS_NO_EULER, msg, len);
}

/* z, then psi0 and xi0. */
int model_initial_state(const double *real, double *state, char *msg, size_t len)
{
    return initial_z(real, state, msg, len) ||
           read_finite(real, VR_PSI0, FHOBS_K, "psi0", state + FHOBS_N_MODEL, msg, len) ||
           read_finite(real, VR_XI0, 1, "xi0", state + FHOBS_N_MODEL + FHOBS_K, msg, len);
}

int model_state_problem(const double *state, char *msg, size_t len)
{
    (void)state; /* no counts or indices: any finite state */
    (void)msg;
    (void)len;
    return 0;
}

int model_step(Work *w, const double *real, const int *integer, const double *src, double *dst,
               double dt, char *msg, size_t len)
{
    return observer_step(w, split_plan, fhobs_filter_step, &w->euler, real, integer, src, dst, dt,
                         msg, len);
}

/* The state outputs and sigma. */
void model_outputs(Work *w, double *real, const int *integer, const double *state)
{
    (void)w;
    (void)integer;
    state_outputs(real, state);
    real[VR_SIGMA] = sigma_of(state + FHOBS_N_MODEL, FHOBS_K, state[FHOBS_N_MODEL + FHOBS_K]);
}
