/*
 * What the C models of the plan families share (model_common.h): the plan cache's keys,
 * reading the variables, the checks of counts and offsets, the estimators' initial z, their
 * internal steps and timing check, one observer step of a family's plans, and the numbers of
 * the messages.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "model_common.h"

/* A number as the pythonfmu FMUs' messages show it (Python's repr, for most numbers): the
 * shortest %g that reads back as the same double. */
const char *fhobs_number(double x, char *buf, size_t len)
{
    for (int digits = 1; digits <= 17; digits++) {
        snprintf(buf, len, "%.*g", digits, x);
        if (!isfinite(x) || strtod(buf, NULL) == x)
            break;
    }
    if (isfinite(x) && !strpbrk(buf, ".e"))
        strncat(buf, ".0", len - strlen(buf) - 1);
    return buf;
}

void state_outputs(double *real, const double *state)
{
    for (int i = 0; i < FHOBS_N_STATE_OUTPUTS; i++) {
        const int *out = STATE_OUTPUTS + 3 * i;
        memcpy(real + out[0], state + out[1], (size_t)out[2] * sizeof(double));
    }
}

void plan_keys_init(PlanKeys *keys)
{
    for (int i = 0; i < FHOBS_PLAN_SLOTS; i++) {
        keys->dt[i] = NAN;
        keys->used[i] = 0;
    }
    keys->clock = 0;
}

int plan_slot(PlanKeys *keys, double dt, int *fresh)
{
    return lru_slot(keys->dt, keys->used, &keys->clock, FHOBS_PLAN_SLOTS, dt, fresh);
}

void plan_refused(PlanKeys *keys, int slot, double dt, double best, char *msg, size_t len)
{
    char a[32];
    keys->dt[slot] = NAN;
    snprintf(msg, len, "no gain level makes the split step of size %s contractive (smallest "
             "spectral radius %.6g); use a smaller communication step; state left unchanged",
             fhobs_number(dt, a, sizeof a), best);
}

void euler_scheme_init(EulerScheme *euler)
{
#if FHOBS_HAS_EULER
    euler->plan = EULER_PLAN;
    euler->plan.work = euler->work;
    euler->plan.cwork = euler->cwork;
#else
    (void)euler;
#endif
}

void read_vector(const double *real, int vr, int n, double *out)
{
    for (int i = 0; i < n; i++)
        out[i] = real[vr + i];
}

int read_finite(const double *real, int vr, int n, const char *name, double *out, char *msg,
                size_t len)
{
    for (int i = 0; i < n; i++) {
        if (!isfinite(real[vr + i])) {
            if (n > 1)
                snprintf(msg, len, "%s must be finite (%s[%d] is not)", name, name, i + 1);
            else
                snprintf(msg, len, "%s must be finite", name);
            return 1;
        }
        out[i] = real[vr + i];
    }
    return 0;
}

int whole_problem(double x, double low, double high, const char *what, char *msg, size_t len)
{
    char a[32], b[32], c[32];
    if (x == floor(x) && x >= low && x <= high)
        return 0;
    snprintf(msg, len, "its %s = %s is not a whole number in [%s, %s]", what,
             fhobs_number(x, a, sizeof a), fhobs_number(low, b, sizeof b),
             fhobs_number(high, c, sizeof c));
    return 1;
}

int offset_problem(double offset, double ts, char *msg, size_t len)
{
    char a[32], b[32];
    if (offset >= 0.0 && offset < ts)
        return 0;
    snprintf(msg, len, "its Kalman filter's offset to the next sample %s is not in [0, Ts = %s)",
             fhobs_number(offset, a, sizeof a), fhobs_number(ts, b, sizeof b));
    return 1;
}

int initial_z(const double *real, double *state, char *msg, size_t len)
{
    if (read_finite(real, VR_Z0, FHOBS_N, "z0", state, msg, len))
        return 1;
    for (int i = FHOBS_N; i < FHOBS_N_MODEL; i++)
        state[i] = 0.0;
    return 0;
}

int substeps_of(const double *real, double dt, double *n_sub, char *msg, size_t len)
{
    char a[32], b[32];
    double h = real[VR_H];
    *n_sub = ceil(dt / h * (1.0 - 1e-12));
    if (*n_sub < 1.0)
        *n_sub = 1.0;
    if (*n_sub > FHOBS_MAX_SUBSTEPS) {
        snprintf(msg, len, "the step size %s is more than %d internal steps of h = %s; state "
                 "left unchanged", fhobs_number(dt, a, sizeof a), FHOBS_MAX_SUBSTEPS,
                 fhobs_number(h, b, sizeof b));
        return 1;
    }
    return 0;
}

int timing_problem(const double *real, const int *integer, int has_euler, const char *no_euler,
                   char *msg, size_t len)
{
    char a[32];
    double h = real[VR_H];
    int scheme = integer[VR_SCHEME];
    if (!(isfinite(h) && h > 0.0)) {
        snprintf(msg, len, "internal step h = %s is not a positive finite number",
                 fhobs_number(h, a, sizeof a));
        return 1;
    }
    if (scheme < 0 || scheme > 1) {
        snprintf(msg, len, "scheme = %d is not in 0..1 (('split', 'euler'))", scheme);
        return 1;
    }
    if (scheme == FHOBS_SCHEME_EULER && !has_euler) {
        snprintf(msg, len, "scheme = 1 (euler): this native FMU runs the split scheme only %s",
                 no_euler);
        return 1;
    }
    return 0;
}

int observer_step(Work *w, SplitPlanOf plan_of, int (*split_step)(const Call *),
                  EulerScheme *scheme_euler, const double *real, const int *integer,
                  const double *src, double *dst, double dt, char *msg, size_t len)
{
#if FHOBS_HAS_EULER
    EulerPlan *euler = scheme_euler ? &scheme_euler->plan : NULL;
#else
    EulerPlan *euler = NULL;
    (void)scheme_euler;
#endif
    double n_sub, inputs[FHOBS_K + FHOBS_M];
    if (substeps_of(real, dt, &n_sub, msg, len))
        return 1;
    read_vector(real, VR_Y, FHOBS_K, inputs);
    read_vector(real, VR_U, FHOBS_M, inputs + FHOBS_K);
    int code;
    const char *scheme = "split";
    if (euler && integer[VR_SCHEME] == FHOBS_SCHEME_EULER) {
        euler->n_sub = (int)n_sub;
        euler->hs = dt / n_sub;
        Call call = {euler, src, dst, inputs};
        code = fhobs_euler_step(&call);
        scheme = "euler";
    } else {
        const void *plan = plan_of(w, dt, msg, len);
        if (!plan)
            return 1;
        Call call = {plan, src, dst, inputs};
        code = split_step(&call);
    }
    if (code != FHOBS_OK) {
        snprintf(msg, len, "the %s step diverged (non-finite state); state left unchanged",
                 scheme);
        return 1;
    }
    return 0;
}
