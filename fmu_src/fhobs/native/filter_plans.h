/*
 * The filtering observer's split plans per step size (FILTER_BASE, LEVEL_SCAN of the generated
 * data), for the families that run it: family_filtering.c and family_supervised.c. Defined in
 * filter_plans.c.
 */
#ifndef FHOBS_FILTER_PLANS_H
#define FHOBS_FILTER_PLANS_H

#include "model_common.h"

/* The plans of the FHOBS_PLAN_SLOTS step sizes used last and their scratch. */
typedef struct {
    PlanKeys keys;
    FilterPlan split[FHOBS_PLAN_SLOTS];
    double M[FHOBS_PLAN_SLOTS][FHOBS_ZOH_ROWS]; /* the split plans' ZOH prediction */
    double F[FHOBS_PLAN_SLOTS][FHOBS_N_MODEL * FHOBS_N_MODEL];
    cplx factors[FHOBS_PLAN_SLOTS][4 * FHOBS_K]; /* spectral-factor caches of the split plans */
    double last_tau[FHOBS_PLAN_SLOTS];
    double split_work[FHOBS_FILTER_WORK(FHOBS_N_MODEL, FHOBS_K)]; /* the split plans' scratch */
    cplx split_cwork[FHOBS_FILTER_CWORK(FHOBS_N_MODEL, FHOBS_K)];
    BinCache bins; /* the tau scans per bin of step sizes */
    double scratch[FHOBS_PLAN_WORK];
} FilterPlans;

/* An empty plan cache. */
FHOBS_HIDDEN void filter_plans_init(FilterPlans *plans);
/* The split plan of the step size dt: kept from an earlier step, or computed now into the
 * least recently used slot; NULL with the message when the filtering observer cannot follow
 * dt (no gain level of the tau scan contracts). */
FHOBS_HIDDEN const FilterPlan *filter_plan(FilterPlans *plans, double dt, char *msg,
                                           size_t len);

#endif
