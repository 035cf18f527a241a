/*
 * The C model of the prescribed_time family (the prescribed-time observer, Theorem 1): split
 * plans per step size, the split scheme only; xi0 from T0. State: z, xi, the gain-level state;
 * outputs the state's.
 */
#include <float.h>
#include <math.h>
#include <stdio.h>

#include "model_common.h"

struct Work {
    PlanKeys keys;
    PrescribedPlan split[FHOBS_PLAN_SLOTS];
    double M[FHOBS_PLAN_SLOTS][FHOBS_ZOH_ROWS]; /* the split plans' ZOH prediction */
    double F[FHOBS_PLAN_SLOTS][FHOBS_N_MODEL * FHOBS_N_MODEL];
    cplx factors[FHOBS_PLAN_SLOTS][2 * FHOBS_K]; /* spectral-factor caches of the split plans */
    double last_tau[FHOBS_PLAN_SLOTS];
    double step_work[FHOBS_PRESCRIBED_WORK(FHOBS_N_MODEL, FHOBS_K)]; /* a step's scratch */
    double scratch[FHOBS_PLAN_WORK];
    BinCache bins; /* the tau scans per bin of step sizes */
};

size_t model_work_size(void)
{
    return sizeof(Work);
}

void work_init(Work *w)
{
    plan_keys_init(&w->keys);
    bin_cache_init(&w->bins);
}

/* The split plan of the step size dt: kept from an earlier step, or computed now into the
 * least recently used slot; NULL with the message when no gain level of the tau scan makes
 * the split step contractive. */
static const void *split_plan(Work *w, double dt, char *msg, size_t len)
{
    double best;
    int fresh, i = plan_slot(&w->keys, dt, &fresh);
    PrescribedPlan *plan = &w->split[i];
    if (!fresh)
        return plan;
    plan->factors = w->factors[i];
    plan->last_tau = &w->last_tau[i];
    plan->work = w->step_work;
    if (plan_prescribed(plan, &PRESCRIBED_BASE, &LEVEL_SCAN, &w->bins, ZOH_TOP, dt, w->M[i],
                        w->F[i], &best, w->scratch)) {
        plan_refused(&w->keys, i, dt, best, msg, len);
        return NULL;
    }
    return plan;
}

int model_parameters_problem(const double *real, const int *integer, char *msg, size_t len)
{
    return timing_problem(real, integer, 0, "(use the pythonfmu FMU for the euler scheme)", msg,
                          len);
}

/* z0 (zeros for a disturbance model's states) and xi0 = (-nu rho T0)^(-1/nu) of the parameter
 * T0 (fhobs.core.runtime.prescribed_xi0), with its checks and messages. */
int model_initial_state(const double *real, double *state, char *msg, size_t len)
{
    char a[32], b[32];
    const double T0 = real[VR_T0], nu = PRESCRIBED_BASE.nu, rho = PRESCRIBED_BASE.rho;
    if (initial_z(real, state, msg, len))
        return 1;
    if (!(isfinite(T0) && T0 > 0.0)) {
        snprintf(msg, len, "prescribed time T0 = %s is not a positive finite number",
                 fhobs_number(T0, a, sizeof a));
        return 1;
    }
    double xi0 = pow(-nu * rho * T0, -1.0 / nu);
    if (!(isfinite(xi0) && xi0 >= DBL_MIN)) {
        snprintf(msg, len, "T0 = %s s gives xi0 = (-nu rho T0)^(-1/nu) = %s, outside the "
                 "normal floating-point numbers", fhobs_number(T0, a, sizeof a),
                 fhobs_number(xi0, b, sizeof b));
        return 1;
    }
    state[FHOBS_N_MODEL] = xi0;
    state[FHOBS_N_MODEL + 1] = xi0; /* the gain-level state starts at xi0 (positive) */
    return 0;
}

/* The split step (the euler scheme is refused with the parameters). */
int model_step(Work *w, const double *real, const int *integer, const double *src, double *dst,
               double dt, char *msg, size_t len)
{
    return observer_step(w, split_plan, fhobs_prescribed_step, NULL, real, integer, src, dst,
                         dt, msg, len);
}

int model_state_problem(const double *state, char *msg, size_t len)
{
    (void)state; /* no counts or indices: any finite state */
    (void)msg;
    (void)len;
    return 0;
}

/* x_hat, q_hat (with a disturbance model) and xi: the model state. */
void model_outputs(Work *w, double *real, const int *integer, const double *state)
{
    (void)w;
    (void)integer;
    state_outputs(real, state);
}
