/*
 * The C model of the kalman family (fhobs.core.kalman_filter.KalmanObserver): the cycle
 * matrix; one cycle per sample instant inside a step. State: z, then the offset to the next
 * sample instant; outputs the state's.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "model_common.h"

struct Work {
    LinearPlan plan;
    double work[FHOBS_KALMAN_WORK(FHOBS_N_MODEL, FHOBS_K)];
};

size_t model_work_size(void)
{
    return sizeof(Work);
}

void work_init(Work *w)
{
    w->plan = KALMAN_PLAN;
    w->plan.work = w->work;
}

int model_parameters_problem(const double *real, const int *integer, char *msg,
                             size_t len)
{
    (void)real;
    (void)integer;
    (void)msg;
    (void)len;
    return 0;
}

int model_initial_state(const double *real, double *state, char *msg, size_t len)
{
    state[FHOBS_N_MODEL] = 0.0; /* the offset to the next sample instant */
    return initial_z(real, state, msg, len);
}

int model_state_problem(const double *state, char *msg, size_t len)
{
    return offset_problem(state[FHOBS_N_MODEL], KALMAN_TS, msg, len);
}

/* fhobs.core.kalman_filter.samples_in_step: the cycles of the sample instants offset + i Ts inside
 * the step (before dt - SAMPLE_SLACK Ts; a sample at the step's start, offset 0, always) and
 * the offset of the next one after it. */
static double samples_in_step(double offset, double dt, double *next)
{
    double n = ceil((dt - offset) / KALMAN_TS - FHOBS_SAMPLE_SLACK);
    if (n < (offset > 0.0 ? 0.0 : 1.0))
        n = offset > 0.0 ? 0.0 : 1.0;
    *next = (offset + n * KALMAN_TS) - dt;
    if (*next < 0.0)
        *next = 0.0;
    return n;
}

/* One cycle per sample instant inside the step, y and u held; the estimate held between
 * samples. State: z, then the offset to the next sample instant. */
int model_step(Work *w, const double *real, const int *integer, const double *src,
               double *dst, double dt, char *msg, size_t len)
{
    (void)integer;
    char a[32], b[32];
    double inputs[FHOBS_K + FHOBS_M], offset;
    double n = samples_in_step(src[FHOBS_N_MODEL], dt, &offset);
    if (n > FHOBS_MAX_CYCLES) {
        snprintf(msg, len, "the step size %s holds %.0f samples of Ts = %s, more than %d; "
                 "state left unchanged", fhobs_number(dt, a, sizeof a), n,
                 fhobs_number(KALMAN_TS, b, sizeof b), FHOBS_MAX_CYCLES);
        return 1;
    }
    if (n == 0.0) {
        memcpy(dst, src, sizeof(double) * FHOBS_N_MODEL);
    } else {
        read_vector(real, VR_Y, FHOBS_K, inputs);
        read_vector(real, VR_U, FHOBS_M, inputs + FHOBS_K);
        w->plan.cycles = (int)n;
        Call call = {&w->plan, src, dst, inputs};
        if (fhobs_kalman_step(&call) != FHOBS_OK) {
            snprintf(msg, len, "the Kalman step diverged (non-finite state); state left "
                     "unchanged");
            return 1;
        }
    }
    dst[FHOBS_N_MODEL] = offset;
    return 0;
}

void model_outputs(Work *w, double *real, const int *integer, const double *state)
{
    (void)w;
    (void)integer;
    state_outputs(real, state);
}
