/*
 * The filtering observer's split plans per step size (filter_plans.h).
 */
#include <math.h>
#include <stdio.h>

#include "filter_plans.h"

void filter_plans_init(FilterPlans *plans)
{
    plan_keys_init(&plans->keys);
    bin_cache_init(&plans->bins);
}

const FilterPlan *filter_plan(FilterPlans *plans, double dt, char *msg, size_t len)
{
    char a[32];
    double best;
    int fresh, i = plan_slot(&plans->keys, dt, &fresh);
    FilterPlan *plan = &plans->split[i];
    if (!fresh)
        return plan;
    plan->factors = plans->factors[i];
    plan->last_tau = &plans->last_tau[i];
    plan->work = plans->split_work;
    plan->cwork = plans->split_cwork;
    if (plan_filter(plan, &FILTER_BASE, &LEVEL_SCAN, &plans->bins, ZOH_TOP, dt, plans->M[i],
                    plans->F[i], &best, plans->scratch)) {
        plans->keys.dt[i] = NAN;
        snprintf(msg, len, "no gain level makes the split step of size %s contractive (smallest "
                 "spectral radius %.6g); use a smaller communication step; state left unchanged",
                 fhobs_number(dt, a, sizeof a), best);
        return NULL;
    }
    return plan;
}
