/*
 * The C model of the supervised family (fhobs.core.supervisor.SupervisedObserver): the
 * filtering observer's step (filter_plans.c) and the Kalman filter's cycles on the same y and
 * u, the innovation statistics, the mode, the handover and the time-varying recursion after
 * it. State: the statistic, the mode, the homogeneous statistic, the time in the return band
 * (SUPERVISOR_HEAD entries), the filtering observer's z, psi, xi, the Kalman filter's z and
 * its offset to the next sample (0: a step holds whole samples), its covariance P (row by
 * row) and the cycles left of the recursion (0: the steady-state gain).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "filter_plans.h"

#define SUPERVISOR_HEAD 4 /* fhobs.core.supervisor.HEAD_SIZE */
#define HOMOGENEOUS_STATE SUPERVISOR_HEAD
#define KALMAN_STATE (SUPERVISOR_HEAD + FHOBS_N_MODEL + FHOBS_K + 1)
#define COVARIANCE_STATE (KALMAN_STATE + FHOBS_N_MODEL + 1)
#define CYCLES_STATE (COVARIANCE_STATE + FHOBS_N_MODEL * FHOBS_N_MODEL)
#define MODE_KALMAN 0.0      /* fhobs.core.supervisor.MODE_KALMAN */
#define MODE_HOMOGENEOUS 1.0 /* fhobs.core.supervisor.MODE_HOMOGENEOUS */
#define FHOBS_DWELL_SLACK 1e-9 /* fhobs.core.supervisor.DWELL_SLACK */
#define FHOBS_RECURSION_TOLERANCE 1e-9   /* fhobs.core.supervisor.RECURSION_TOLERANCE */
#define FHOBS_RECURSION_CYCLES 1000000.0 /* fhobs.core.supervisor.RECURSION_CYCLES */
#define NN (FHOBS_N_MODEL * FHOBS_N_MODEL)

struct Work {
    FilterPlans plans;
    EulerScheme euler;
    LinearPlan kalman; /* one cycle of the Kalman filter */
    double kalman_work[FHOBS_KALMAN_WORK(FHOBS_N_MODEL, FHOBS_K)];
};

size_t model_work_size(void)
{
    return sizeof(Work);
}

void work_init(Work *w)
{
    filter_plans_init(&w->plans);
    euler_scheme_init(&w->euler);
    w->kalman = KALMAN_PLAN;
    w->kalman.work = w->kalman_work;
}

static const void *split_plan(Work *w, double dt, char *msg, size_t len)
{
    return filter_plan(&w->plans, dt, msg, len);
}

int model_parameters_problem(const double *real, const int *integer, char *msg, size_t len)
{
    return timing_problem(real, integer, FHOBS_HAS_EULER, FHOBS_NO_EULER, msg, len);
}

/* The homogeneous observer's z (psi and xi zeros: it has no psi0, xi0), the statistics at
 * their mean k, the homogeneous mode, the Kalman filter's z the same, its covariance the
 * steady-state one. */
int model_initial_state(const double *real, double *state, char *msg, size_t len)
{
    if (initial_z(real, state + HOMOGENEOUS_STATE, msg, len))
        return 1;
    for (int i = 0; i <= FHOBS_K; i++)
        state[HOMOGENEOUS_STATE + FHOBS_N_MODEL + i] = 0.0;
    state[0] = state[2] = (double)FHOBS_K; /* the statistics start at their mean, k */
    state[1] = MODE_HOMOGENEOUS;
    state[3] = 0.0;
    memcpy(state + KALMAN_STATE, state + HOMOGENEOUS_STATE, sizeof(double) * FHOBS_N_MODEL);
    state[KALMAN_STATE + FHOBS_N_MODEL] = 0.0;
    memcpy(state + COVARIANCE_STATE, SUPERVISOR_P_STEADY, sizeof(double) * NN);
    state[CYCLES_STATE] = 0.0;
    return 0;
}

/* e = y - C z: the innovation of the Kalman filter's z, the output residual of the
 * homogeneous observer's. */
static void residual_of(const double *y, const double *z, double *e)
{
    for (int i = 0; i < FHOBS_K; i++) {
        double c = 0.0;
        for (int j = 0; j < FHOBS_N_MODEL; j++)
            c += SUPERVISOR_C[i * FHOBS_N_MODEL + j] * z[j];
        e[i] = y[i] - c;
    }
}

/* The normalised residual squared e^T S^-1 e of e = y - C z, S^-1 given (k x k), in numpy's
 * order. */
static double normalised_squared(const double *y, const double *z, const double *S_inv)
{
    double e[FHOBS_K], s = 0.0;
    residual_of(y, z, e);
    for (int j = 0; j < FHOBS_K; j++) {
        double t = 0.0;
        for (int i = 0; i < FHOBS_K; i++)
            t += e[i] * S_inv[i * FHOBS_K + j];
        s += t * e[j];
    }
    return s;
}

/* X = S^-1 B for the k x k matrix S (row by row, overwritten) and the k x cols B (row by row,
 * overwritten by X): Gaussian elimination with partial pivoting (numpy.linalg.solve's LU). */
static void solve_in_place(double *S, double *B, int cols)
{
    for (int c = 0; c < FHOBS_K; c++) {
        int pivot = c;
        for (int r = c + 1; r < FHOBS_K; r++)
            if (fabs(S[r * FHOBS_K + c]) > fabs(S[pivot * FHOBS_K + c]))
                pivot = r;
        if (pivot != c) {
            for (int j = 0; j < FHOBS_K; j++) {
                double t = S[c * FHOBS_K + j];
                S[c * FHOBS_K + j] = S[pivot * FHOBS_K + j];
                S[pivot * FHOBS_K + j] = t;
            }
            for (int j = 0; j < cols; j++) {
                double t = B[c * cols + j];
                B[c * cols + j] = B[pivot * cols + j];
                B[pivot * cols + j] = t;
            }
        }
        for (int r = c + 1; r < FHOBS_K; r++) {
            double f = S[r * FHOBS_K + c] / S[c * FHOBS_K + c];
            for (int j = c; j < FHOBS_K; j++)
                S[r * FHOBS_K + j] -= f * S[c * FHOBS_K + j];
            for (int j = 0; j < cols; j++)
                B[r * cols + j] -= f * B[c * cols + j];
        }
    }
    for (int c = FHOBS_K - 1; c >= 0; c--)
        for (int j = 0; j < cols; j++) {
            double t = B[c * cols + j];
            for (int i = c + 1; i < FHOBS_K; i++)
                t -= S[c * FHOBS_K + i] * B[i * cols + j];
            B[c * cols + j] = t / S[c * FHOBS_K + c];
        }
}

/* One cycle of the time-varying Kalman filter (SupervisedObserver._recursion_cycle) from z
 * and the a-priori covariance P (updated in place) into out; its normalised innovation
 * squared under S = C P C^T + R, and *left the cycles left (0 once P is within the tolerance
 * of the steady state). */
static double recursion_cycle(const double *inputs, const double *z, double *out, double *P,
                              double *left)
{
    double e[FHOBS_K], S[FHOBS_K * FHOBS_K], CP[FHOBS_K * FHOBS_N_MODEL];
    double rhs[FHOBS_K * (FHOBS_N_MODEL + 1)], post[FHOBS_N_MODEL], Pp[NN], T[NN];
    residual_of(inputs, z, e);
    for (int i = 0; i < FHOBS_K; i++)
        for (int j = 0; j < FHOBS_N_MODEL; j++) {
            double t = 0.0;
            for (int l = 0; l < FHOBS_N_MODEL; l++)
                t += SUPERVISOR_C[i * FHOBS_N_MODEL + l] * P[l * FHOBS_N_MODEL + j];
            CP[i * FHOBS_N_MODEL + j] = t;
        }
    for (int i = 0; i < FHOBS_K; i++)
        for (int j = 0; j < FHOBS_K; j++) {
            double t = 0.0;
            for (int l = 0; l < FHOBS_N_MODEL; l++)
                t += CP[i * FHOBS_N_MODEL + l] * SUPERVISOR_C[j * FHOBS_N_MODEL + l];
            S[i * FHOBS_K + j] = t + SUPERVISOR_R[i * FHOBS_K + j];
        }
    /* [S^-1 C P, S^-1 e] in one solve: the gain's transpose and the normalised innovation */
    for (int i = 0; i < FHOBS_K; i++) {
        memcpy(rhs + i * (FHOBS_N_MODEL + 1), CP + i * FHOBS_N_MODEL,
               sizeof(double) * FHOBS_N_MODEL);
        rhs[i * (FHOBS_N_MODEL + 1) + FHOBS_N_MODEL] = e[i];
    }
    solve_in_place(S, rhs, FHOBS_N_MODEL + 1);
    double nis = 0.0;
    for (int i = 0; i < FHOBS_K; i++)
        nis += e[i] * rhs[i * (FHOBS_N_MODEL + 1) + FHOBS_N_MODEL];
    for (int j = 0; j < FHOBS_N_MODEL; j++) {
        double t = 0.0;
        for (int i = 0; i < FHOBS_K; i++)
            t += rhs[i * (FHOBS_N_MODEL + 1) + j] * e[i];
        post[j] = z[j] + t;
    }
    for (int i = 0; i < FHOBS_N_MODEL; i++) {
        double t = 0.0;
        for (int j = 0; j < FHOBS_N_MODEL; j++)
            t += SUPERVISOR_PHI[i * FHOBS_N_MODEL + j] * post[j];
        for (int j = 0; j < FHOBS_M; j++)
            t += SUPERVISOR_GAMMA[i * FHOBS_M + j] * inputs[FHOBS_K + j];
        out[i] = t;
    }
    for (int i = 0; i < FHOBS_N_MODEL; i++) /* P - K C P, K = (S^-1 C P)^T */
        for (int j = 0; j < FHOBS_N_MODEL; j++) {
            double t = 0.0;
            for (int l = 0; l < FHOBS_K; l++)
                t += rhs[l * (FHOBS_N_MODEL + 1) + i] * CP[l * FHOBS_N_MODEL + j];
            Pp[i * FHOBS_N_MODEL + j] = P[i * FHOBS_N_MODEL + j] - t;
        }
    for (int i = 0; i < FHOBS_N_MODEL; i++) /* T = Phi Pp */
        for (int j = 0; j < FHOBS_N_MODEL; j++) {
            double t = 0.0;
            for (int l = 0; l < FHOBS_N_MODEL; l++)
                t += SUPERVISOR_PHI[i * FHOBS_N_MODEL + l] * Pp[l * FHOBS_N_MODEL + j];
            T[i * FHOBS_N_MODEL + j] = t;
        }
    for (int i = 0; i < FHOBS_N_MODEL; i++) /* T Phi^T + Q_d */
        for (int j = 0; j < FHOBS_N_MODEL; j++) {
            double t = 0.0;
            for (int l = 0; l < FHOBS_N_MODEL; l++)
                t += T[i * FHOBS_N_MODEL + l] * SUPERVISOR_PHI[j * FHOBS_N_MODEL + l];
            Pp[i * FHOBS_N_MODEL + j] = t + SUPERVISOR_Q_D[i * FHOBS_N_MODEL + j];
        }
    double gap = 0.0, scale = 0.0;
    for (int i = 0; i < FHOBS_N_MODEL; i++)
        for (int j = 0; j < FHOBS_N_MODEL; j++) {
            double v = 0.5 * (Pp[i * FHOBS_N_MODEL + j] + Pp[j * FHOBS_N_MODEL + i]);
            P[i * FHOBS_N_MODEL + j] = v;
            gap = fmax(gap, fabs(v - SUPERVISOR_P_STEADY[i * FHOBS_N_MODEL + j]));
            scale = fmax(scale, fabs(SUPERVISOR_P_STEADY[i * FHOBS_N_MODEL + j]));
        }
    *left = gap <= FHOBS_RECURSION_TOLERANCE * scale ? 0.0 : *left - 1.0;
    return nis;
}

/* A statistic after one more value: its exponential mean, held at most at the ceiling. */
static double averaged(double statistic, double value)
{
    double next = statistic + SUPERVISOR_WEIGHT * (value - statistic);
    return next > SUPERVISOR_CEILING ? SUPERVISOR_CEILING : next;
}

/* fhobs.core.supervisor.sample_count: the Kalman samples n of a step dt = n Ts; 1 with the
 * message when dt is not a whole multiple of Ts or holds too many. */
static int sample_count(double dt, double *n, char *msg, size_t len)
{
    char a[32], b[32];
    *n = nearbyint(dt / KALMAN_TS);
    if (*n < 1.0 || fabs(dt - *n * KALMAN_TS) > FHOBS_SAMPLE_SLACK * KALMAN_TS) {
        snprintf(msg, len, "the step size %s is not a whole multiple of the Kalman sample time "
                 "Ts = %s; state left unchanged", fhobs_number(dt, a, sizeof a),
                 fhobs_number(KALMAN_TS, b, sizeof b));
        return 1;
    }
    if (*n > FHOBS_MAX_CYCLES) {
        snprintf(msg, len, "the step size %s holds %.0f samples of Ts = %s, more than %d; "
                 "state left unchanged", fhobs_number(dt, a, sizeof a), *n,
                 fhobs_number(KALMAN_TS, b, sizeof b), FHOBS_MAX_CYCLES);
        return 1;
    }
    return 0;
}

/* The mode after a step of dt (SupervisedObserver._decide); at a switch to K with the Kalman
 * filter's statistic outside the return band, the handover into dst: the homogeneous
 * estimate, the handover covariance, the homogeneous statistic, the recursion on. */
static void decide(const double *src, double *dst, double dt)
{
    double mode = src[1], time = src[3];
    const double kalman = dst[0], homogeneous = dst[2];
    const int kalman_consistent =
        SUPERVISOR_LOWER_RETURN < kalman && kalman < SUPERVISOR_UPPER_RETURN;
    if (mode == MODE_KALMAN) {
        if (kalman > SUPERVISOR_UPPER || (kalman < SUPERVISOR_LOWER && homogeneous < kalman)) {
            mode = MODE_HOMOGENEOUS;
            time = 0.0;
        }
    } else if (!kalman_consistent
               && !(SUPERVISOR_LOWER <= homogeneous && homogeneous <= SUPERVISOR_UPPER)) {
        time = 0.0;
    } else {
        time += dt;
        if (time >= SUPERVISOR_DWELL_TIME * (1.0 - FHOBS_DWELL_SLACK)) {
            if (!kalman_consistent) {
                memcpy(dst + KALMAN_STATE, dst + HOMOGENEOUS_STATE,
                       sizeof(double) * FHOBS_N_MODEL);
                dst[KALMAN_STATE + FHOBS_N_MODEL] = 0.0;
                memcpy(dst + COVARIANCE_STATE, SUPERVISOR_P_HANDOVER, sizeof(double) * NN);
                dst[CYCLES_STATE] = FHOBS_RECURSION_CYCLES;
                dst[0] = homogeneous;
            }
            mode = MODE_KALMAN;
        }
    }
    dst[1] = mode;
    dst[3] = time;
}

/* The homogeneous observer's step, one Kalman cycle per sample with the statistics updated
 * before each (the homogeneous one with its residual at the step's start), then the mode. */
int model_step(Work *w, const double *real, const int *integer, const double *src,
               double *dst, double dt, char *msg, size_t len)
{
    double n, inputs[FHOBS_K + FHOBS_M], buffers[2][FHOBS_N_MODEL];
    if (sample_count(dt, &n, msg, len))
        return 1;
    read_vector(real, VR_Y, FHOBS_K, inputs);
    read_vector(real, VR_U, FHOBS_M, inputs + FHOBS_K);
    const double residual =
        normalised_squared(inputs, src + HOMOGENEOUS_STATE, SUPERVISOR_S_HOMOGENEOUS_INV);
    if (observer_step(w, split_plan, fhobs_filter_step, &w->euler, real, integer,
                      src + HOMOGENEOUS_STATE, dst + HOMOGENEOUS_STATE, dt, msg, len))
        return 1;
    double kalman = src[0], homogeneous = src[2], left = src[CYCLES_STATE];
    double *P = dst + COVARIANCE_STATE;
    memcpy(P, src + COVARIANCE_STATE, sizeof(double) * NN);
    const double *z = src + KALMAN_STATE;
    for (int c = 0; c < (int)n; c++) {
        double *out = c == (int)n - 1 ? dst + KALMAN_STATE : buffers[c % 2];
        double nis;
        int diverged;
        if (left > 0.0) {
            nis = recursion_cycle(inputs, z, out, P, &left);
            diverged = !all_finite(out, FHOBS_N_MODEL);
        } else {
            nis = normalised_squared(inputs, z, SUPERVISOR_S_INV);
            Call call = {&w->kalman, z, out, inputs};
            diverged = fhobs_kalman_step(&call) != FHOBS_OK;
        }
        if (diverged) {
            snprintf(msg, len, "the Kalman step diverged (non-finite state); state left "
                     "unchanged");
            return 1;
        }
        kalman = averaged(kalman, nis);
        homogeneous = averaged(homogeneous, residual);
        z = out;
    }
    if (!(isfinite(kalman) && isfinite(homogeneous) && all_finite(P, NN))) {
        snprintf(msg, len, "the innovation statistics or the Kalman filter's covariance are "
                 "not finite");
        return 1;
    }
    dst[0] = kalman;
    dst[2] = homogeneous;
    dst[KALMAN_STATE + FHOBS_N_MODEL] = src[KALMAN_STATE + FHOBS_N_MODEL];
    dst[CYCLES_STATE] = left;
    decide(src, dst, dt);
    return 0;
}

/* The statistics and the time in band >= 0, the mode 0 or 1, the Kalman filter's offset in
 * [0, Ts), the cycles left a whole number in [0, RECURSION_CYCLES]
 * (SupervisedObserver.set_state). */
int model_state_problem(const double *state, char *msg, size_t len)
{
    char a[32];
    for (int i = 0; i < SUPERVISOR_HEAD; i++) {
        if (i != 1 && !(state[i] >= 0.0)) {
            snprintf(msg, len, "its %s = %s is negative",
                     i == 3 ? "time in the return band" : "innovation statistic",
                     fhobs_number(state[i], a, sizeof a));
            return 1;
        }
    }
    return whole_problem(state[1], MODE_KALMAN, MODE_HOMOGENEOUS, "mode", msg, len) ||
           offset_problem(state[KALMAN_STATE + FHOBS_N_MODEL], KALMAN_TS, msg, len) ||
           whole_problem(state[CYCLES_STATE], 0.0, FHOBS_RECURSION_CYCLES,
                         "cycles left of the Kalman recursion", msg, len);
}

/* The statistic and the mode (state outputs); x_hat and q_hat of the mode's estimator. */
void model_outputs(Work *w, double *real, const int *integer, const double *state)
{
    (void)w;
    (void)integer;
    state_outputs(real, state);
    const double *z = state + (state[1] == MODE_KALMAN ? KALMAN_STATE : HOMOGENEOUS_STATE);
    memcpy(real + VR_X_HAT, z, sizeof(double) * FHOBS_N);
#if FHOBS_N_MODEL > FHOBS_N
    memcpy(real + VR_Q_HAT, z + FHOBS_N, sizeof(double) * (FHOBS_N_MODEL - FHOBS_N));
#endif
}
