/*
 * The filtering observer's split plans per step size (filter_plans.h).
 */
#include "filter_plans.h"

void filter_plans_init(FilterPlans *plans)
{
    plan_keys_init(&plans->keys);
    bin_cache_init(&plans->bins);
}

const FilterPlan *filter_plan(FilterPlans *plans, double dt, char *msg, size_t len)
{
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
        plan_refused(&plans->keys, i, dt, best, msg, len);
        return NULL;
    }
    return plan;
}
