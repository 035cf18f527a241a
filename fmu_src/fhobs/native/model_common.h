/*
 * What the C models of the plan families (family_<family>.c, one compiled into each native
 * FMU, chosen by its kind's family: fhobs.native.build.FAMILIES) share, behind model.h: the
 * plan cache's keys and the refusal of a step size no gain level follows, the euler plan,
 * reading the variables, the checks of counts and offsets, the estimators' initial z, their
 * internal-step count and timing check, and one observer step (split or euler) of a family's
 * plans (observer_step). Defined in model_common.c.
 */
#ifndef FHOBS_MODEL_COMMON_H
#define FHOBS_MODEL_COMMON_H

#include <stddef.h>

#include "kernel.h"
#include "model.h"
#include "planner.h"

#define FHOBS_MAX_SUBSTEPS 1000000 /* fhobs.core.runtime.MAX_SUBSTEPS */
#define FHOBS_MAX_CYCLES 1000000   /* fhobs.core.kalman_filter.MAX_CYCLES */
#define FHOBS_SAMPLE_SLACK 1e-6    /* fhobs.core.kalman_filter.SAMPLE_SLACK */
#define FHOBS_NOISE_BLOCK 1024     /* fhobs.core.plant.NOISE_BLOCK */
#define FHOBS_SCHEME_EULER 1 /* "euler" in fhobs.core.runtime.SCHEMES and plant.PLANT_SCHEMES */
/* Why an observer whose design has no euler plan refuses the scheme (timing_problem). */
#define FHOBS_NO_EULER                                                                         \
    "(this design's euler scheme needs the numpy runtime's expm path; use the pythonfmu FMU "  \
    "for it)"

#define FHOBS_PLAN_SLOTS 8 /* step sizes whose plans an instance keeps */
#define FHOBS_ZOH_ROWS (FHOBS_N_MODEL * FHOBS_ZOH_SIZE)
#define FHOBS_PLAN_WORK                                                                        \
    FHOBS_PLAN_WORK_SIZE(FHOBS_N_MODEL, FHOBS_K, FHOBS_M, FHOBS_ZOH_SIZE, FHOBS_N_TAU)

/* The plan cache's keys: the step size of each slot (NAN: empty) and when it was last used. */
typedef struct {
    double dt[FHOBS_PLAN_SLOTS];
    unsigned long long used[FHOBS_PLAN_SLOTS];
    unsigned long long clock;
} PlanKeys;

/* The euler plan of a family's design (FHOBS_HAS_EULER: the generated EULER_PLAN) with its
 * scratch; without one, nothing (timing_problem refuses the scheme). */
typedef struct {
#if FHOBS_HAS_EULER
    EulerPlan plan;
    double work[FHOBS_EULER_WORK(FHOBS_N_MODEL, FHOBS_K)];
    cplx cwork[FHOBS_EULER_CWORK(FHOBS_N_MODEL, FHOBS_K)];
#else
    char none;
#endif
} EulerScheme;

/* Every slot empty. */
FHOBS_HIDDEN void plan_keys_init(PlanKeys *keys);
/* The slot of the step size dt (exactly dt: the numpy runtime keys its plans so too) and
 * whether it was taken for dt now (*fresh; the plan is then to be computed): an empty slot or
 * the least recently used one. */
FHOBS_HIDDEN int plan_slot(PlanKeys *keys, double dt, int *fresh);
/* A split plan of the step size dt in slot `slot` that no gain level of the tau scan makes
 * contractive (`best`: the smallest spectral radius): the slot emptied, the message. */
FHOBS_HIDDEN void plan_refused(PlanKeys *keys, int slot, double dt, double best, char *msg,
                               size_t len);
/* The euler plan's scratch pointers set (nothing without an euler plan). */
FHOBS_HIDDEN void euler_scheme_init(EulerScheme *euler);

/* The outputs that are elements of the model state, where the kind's declaration places them
 * (the generated STATE_OUTPUTS: value reference, state offset, count); each family's
 * model_outputs computes the others. */
FHOBS_HIDDEN void state_outputs(double *real, const double *state);
/* Copy n reals from the variables starting at value reference vr. */
FHOBS_HIDDEN void read_vector(const double *real, int vr, int n, double *out);
/* Copy the n reals from value reference vr (the variable `name`) into out; 1 with a message
 * naming the first entry that is not finite. */
FHOBS_HIDDEN int read_finite(const double *real, int vr, int n, const char *name, double *out,
                             char *msg, size_t len);
/* Whether x is a whole number in [low, high]; else 1 with the message naming `what`. */
FHOBS_HIDDEN int whole_problem(double x, double low, double high, const char *what, char *msg,
                               size_t len);
/* Whether the Kalman filter's offset to the next sample is in [0, Ts); else 1 with the
 * message (fhobs.core.kalman_filter.KalmanObserver.set_state). */
FHOBS_HIDDEN int offset_problem(double offset, double ts, char *msg, size_t len);
/* The model state z of an estimator: z0 for the plant's states, zeros for the disturbance
 * model's. */
FHOBS_HIDDEN int initial_z(const double *real, double *state, char *msg, size_t len);
/* The internal steps of h in a communication step dt (*n_sub); 1 with the message when they
 * are more than FHOBS_MAX_SUBSTEPS. */
FHOBS_HIDDEN int substeps_of(const double *real, double dt, double *n_sub, char *msg,
                             size_t len);
/* An estimator's h and scheme; a scheme of 1 (euler) refused unless `has_euler`, the message
 * ending with `no_euler`. */
FHOBS_HIDDEN int timing_problem(const double *real, const int *integer, int has_euler,
                                const char *no_euler, char *msg, size_t len);

/* The split plan of the step size dt in a family's Work (NULL with the message when the step
 * size cannot be followed). */
typedef const void *(*SplitPlanOf)(Work *w, double dt, char *msg, size_t len);
/* One observer step dt from src into dst (its own state), y and u from the variables: the
 * euler substeps of `euler` (NULL or a design without an euler plan: none) when the scheme
 * says so, else `split_step` with the plan `plan_of` gives. */
FHOBS_HIDDEN int observer_step(Work *w, SplitPlanOf plan_of, int (*split_step)(const Call *),
                               EulerScheme *euler, const double *real, const int *integer,
                               const double *src, double *dst, double dt, char *msg,
                               size_t len);

#endif
