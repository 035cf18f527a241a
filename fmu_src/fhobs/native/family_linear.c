/*
 * The C model of the linear family (an observer of a constant gain, the Luenberger observer):
 * its split plans per step size (the held innovation or the closed loop's exact hold,
 * plan_luenberger), the euler plan when the design has one; state z; outputs the state's.
 */
#include <math.h>

#include "model_common.h"

struct Work {
    PlanKeys keys;
    LinearPlan split[FHOBS_PLAN_SLOTS];
    double M[FHOBS_PLAN_SLOTS][FHOBS_ZOH_ROWS]; /* the split plans' ZOH prediction */
    double scratch[FHOBS_PLAN_WORK];
    EulerScheme euler;
};

size_t model_work_size(void)
{
    return sizeof(Work);
}

void work_init(Work *w)
{
    plan_keys_init(&w->keys);
    euler_scheme_init(&w->euler);
}

/* The split plan of the step size dt: kept from an earlier step, or computed now into the
 * least recently used slot (every step size has one). */
static const void *split_plan(Work *w, double dt, char *msg, size_t len)
{
    (void)msg;
    (void)len;
    int fresh, i = plan_slot(&w->keys, dt, &fresh);
    LinearPlan *plan = &w->split[i];
    if (fresh)
        plan_luenberger(plan, &LINEAR_BASE, &HELD_INNOVATION, ZOH_TOP, dt, w->M[i], w->scratch);
    return plan;
}

int model_parameters_problem(const double *real, const int *integer, char *msg, size_t len)
{
    return timing_problem(real, integer, FHOBS_HAS_EULER, FHOBS_NO_EULER, msg, len);
}

int model_initial_state(const double *real, double *state, char *msg, size_t len)
{
    return initial_z(real, state, msg, len);
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
    return observer_step(w, split_plan, fhobs_luenberger_step, &w->euler, real, integer, src, dst,
                         dt, msg, len);
}

/* x_hat: the model state. */
void model_outputs(Work *w, double *real, const int *integer, const double *state)
{
    (void)w;
    (void)integer;
    state_outputs(real, state);
}
