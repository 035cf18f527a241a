/*
 * The model of a native fhobs FMU for the kind its generated data names (FHOBS_KIND): the
 * state it keeps, the initial state from the per-instance parameters, the checks of those
 * parameters, the step and the outputs. The steps are the compiled kernel's (kernel.c); the
 * plan of a communication step size (ZOH matrices, the filtering observer's gain-level floor
 * and ceiling) is computed by planner.c at the first step of that size from the design data
 * compiled in (model_data.c) and kept per instance for the FHOBS_PLAN_SLOTS step sizes used
 * last, so nothing here depends on numpy. The FMI layer calls it through model.h; its Work is
 * fixed in size by the generated model_data.h (no variable-length arrays).
 */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "kernel.h"
#include "model.h"
#include "planner.h"

#define FHOBS_MAX_SUBSTEPS 1000000 /* fhobs.core.runtime.MAX_SUBSTEPS */
#define FHOBS_MAX_CYCLES 1000000   /* fhobs.core.kalman_filter.MAX_CYCLES */
#define FHOBS_SAMPLE_SLACK 1e-6    /* fhobs.core.kalman_filter.SAMPLE_SLACK */
#define FHOBS_NOISE_BLOCK 1024     /* fhobs.core.plant.NOISE_BLOCK */
#define FHOBS_SCHEME_EULER 1 /* "euler" in fhobs.core.runtime.SCHEMES and plant.PLANT_SCHEMES */

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

/* The outputs that are elements of the model state, where the kind's declaration places them
 * (the generated STATE_OUTPUTS: value reference, state offset, count); each kind's
 * model_outputs computes the others. */
static void state_outputs(double *real, const double *state)
{
    for (int i = 0; i < FHOBS_N_STATE_OUTPUTS; i++) {
        const int *out = STATE_OUTPUTS + 3 * i;
        memcpy(real + out[0], state + out[1], (size_t)out[2] * sizeof(double));
    }
}

/* The filtering observer's split step runs in this FMU (alone, or in the supervised one). */
#define FHOBS_FILTERING                                                                        \
    (FHOBS_KIND == FHOBS_KIND_OBSERVER || FHOBS_KIND == FHOBS_KIND_SUPERVISED)

#if FHOBS_FILTERING || FHOBS_KIND == FHOBS_KIND_LUENBERGER || FHOBS_KIND == FHOBS_KIND_PLANT ||  \
    FHOBS_KIND == FHOBS_KIND_PRESCRIBED_TIME
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

static void plan_keys_init(PlanKeys *keys)
{
    for (int i = 0; i < FHOBS_PLAN_SLOTS; i++) {
        keys->dt[i] = NAN;
        keys->used[i] = 0;
    }
    keys->clock = 0;
}

/* The slot of the step size dt (exactly dt: the numpy runtime keys its plans so too) and
 * whether it was taken for dt now (*fresh; the plan is then to be computed): an empty slot or
 * the least recently used one. */
static int plan_slot(PlanKeys *keys, double dt, int *fresh)
{
    int slot = 0;
    for (int i = 0; i < FHOBS_PLAN_SLOTS; i++) {
        if (keys->dt[i] == dt) {
            keys->used[i] = ++keys->clock;
            *fresh = 0;
            return i;
        }
        if (keys->used[i] < keys->used[slot])
            slot = i;
    }
    keys->dt[slot] = dt;
    keys->used[slot] = ++keys->clock;
    *fresh = 1;
    return slot;
}
#endif

/* Copy n reals from the variables starting at value reference vr. */
static void read_vector(const double *real, int vr, int n, double *out)
{
    for (int i = 0; i < n; i++)
        out[i] = real[vr + i];
}

/* Copy the n reals from value reference vr (the variable `name`) into out; 1 with a message
 * naming the first entry that is not finite. */
static int read_finite(const double *real, int vr, int n, const char *name, double *out,
                       char *msg, size_t len)
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

#if FHOBS_KIND == FHOBS_KIND_PLANT || FHOBS_KIND == FHOBS_KIND_SUPERVISED
/* Whether x is a whole number in [low, high]; else 1 with the message naming `what`. */
static int whole_problem(double x, double low, double high, const char *what, char *msg,
                         size_t len)
{
    char a[32], b[32], c[32];
    if (x == floor(x) && x >= low && x <= high)
        return 0;
    snprintf(msg, len, "its %s = %s is not a whole number in [%s, %s]", what,
             fhobs_number(x, a, sizeof a), fhobs_number(low, b, sizeof b),
             fhobs_number(high, c, sizeof c));
    return 1;
}
#endif

#if FHOBS_KIND == FHOBS_KIND_KALMAN || FHOBS_KIND == FHOBS_KIND_SUPERVISED
/* Whether the Kalman filter's offset to the next sample is in [0, Ts); else 1 with the
 * message (fhobs.core.kalman_filter.KalmanObserver.set_state). */
static int offset_problem(double offset, char *msg, size_t len)
{
    char a[32], b[32];
    if (offset >= 0.0 && offset < KALMAN_TS)
        return 0;
    snprintf(msg, len, "its Kalman filter's offset to the next sample %s is not in [0, Ts = %s)",
             fhobs_number(offset, a, sizeof a), fhobs_number(KALMAN_TS, b, sizeof b));
    return 1;
}
#endif

#if FHOBS_KIND != FHOBS_KIND_PLANT
/* The model state z of an estimator: z0 for the plant's states, zeros for the disturbance
 * model's. */
static int initial_z(const double *real, double *state, char *msg, size_t len)
{
    if (read_finite(real, VR_Z0, FHOBS_N, "z0", state, msg, len))
        return 1;
    for (int i = FHOBS_N; i < FHOBS_N_MODEL; i++)
        state[i] = 0.0;
    return 0;
}
#endif

#if FHOBS_FILTERING || FHOBS_KIND == FHOBS_KIND_LUENBERGER
/* ---------------------------------------------------------------------------------------- */
/* Observers (filtering homogeneous, Luenberger; the supervised one's homogeneous part):    */
/* split plans per step size, euler plan                                                    */

#if FHOBS_FILTERING
typedef FilterPlan SplitPlan;
#define SPLIT_STEP fhobs_filter_step
#else
typedef LinearPlan SplitPlan;
#define SPLIT_STEP fhobs_luenberger_step
#endif

struct Work {
    PlanKeys keys;
    SplitPlan split[FHOBS_PLAN_SLOTS];
    double M[FHOBS_PLAN_SLOTS][FHOBS_ZOH_ROWS]; /* the split plans' ZOH prediction */
#if FHOBS_FILTERING
    double F[FHOBS_PLAN_SLOTS][FHOBS_N_MODEL * FHOBS_N_MODEL];
    cplx factors[FHOBS_PLAN_SLOTS][4 * FHOBS_K]; /* spectral-factor caches of the split plans */
    double last_tau[FHOBS_PLAN_SLOTS];
    double split_work[FHOBS_FILTER_WORK(FHOBS_N_MODEL, FHOBS_K)]; /* the split plans' scratch */
    cplx split_cwork[FHOBS_FILTER_CWORK(FHOBS_N_MODEL, FHOBS_K)];
    BinCache bins; /* the tau scans per bin of step sizes */
#endif
    double scratch[FHOBS_PLAN_WORK];
#if FHOBS_HAS_EULER
    EulerPlan euler;
    double euler_work[FHOBS_EULER_WORK(FHOBS_N_MODEL, FHOBS_K)];
    cplx euler_cwork[FHOBS_EULER_CWORK(FHOBS_N_MODEL, FHOBS_K)];
#endif
#if FHOBS_KIND == FHOBS_KIND_SUPERVISED
    LinearPlan kalman; /* one cycle of the Kalman filter */
    double kalman_work[FHOBS_KALMAN_WORK(FHOBS_N_MODEL, FHOBS_K)];
#endif
};

void work_init(Work *w)
{
    plan_keys_init(&w->keys);
#if FHOBS_FILTERING
    bin_cache_init(&w->bins);
#endif
#if FHOBS_HAS_EULER
    w->euler = EULER_PLAN;
    w->euler.work = w->euler_work;
    w->euler.cwork = w->euler_cwork;
#endif
#if FHOBS_KIND == FHOBS_KIND_SUPERVISED
    w->kalman = KALMAN_PLAN;
    w->kalman.work = w->kalman_work;
#endif
}

/* The split plan of the step size dt: kept from an earlier step, or computed now into the
 * least recently used slot; NULL with the message when the filtering observer cannot follow
 * dt (no gain level of the tau scan contracts). */
static const SplitPlan *split_plan(Work *w, double dt, char *msg, size_t len)
{
    int fresh, i = plan_slot(&w->keys, dt, &fresh);
    SplitPlan *plan = &w->split[i];
    if (!fresh)
        return plan;
#if FHOBS_FILTERING
    char a[32];
    double best;
    plan->factors = w->factors[i];
    plan->last_tau = &w->last_tau[i];
    plan->work = w->split_work;
    plan->cwork = w->split_cwork;
    if (plan_filter(plan, &FILTER_BASE, &LEVEL_SCAN, &w->bins, ZOH_TOP, dt, w->M[i], w->F[i],
                    &best, w->scratch)) {
        w->keys.dt[i] = NAN;
        snprintf(msg, len, "no gain level makes the split step of size %s contractive (smallest "
                 "spectral radius %.6g); use a smaller communication step; state left unchanged",
                 fhobs_number(dt, a, sizeof a), best);
        return NULL;
    }
#else
    (void)msg;
    (void)len;
    plan_luenberger(plan, &LINEAR_BASE, &HELD_INNOVATION, ZOH_TOP, dt, w->M[i], w->scratch);
#endif
    return plan;
}

int model_parameters_problem(const double *real, const int *integer, char *msg,
                             size_t len)
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
    if (scheme == FHOBS_SCHEME_EULER && !FHOBS_HAS_EULER) {
        snprintf(msg, len, "scheme = 1 (euler): this native FMU runs the split scheme only "
                           "(this design's euler scheme needs the numpy runtime's expm path; "
                           "use the pythonfmu FMU for it)");
        return 1;
    }
    return 0;
}

/* The observer's initial state: z; the filtering observer's psi and xi (psi0 and xi0, or
 * zeros in the supervised observer, which has no such parameters). */
static int observer_initial_state(const double *real, double *state, char *msg, size_t len)
{
    if (initial_z(real, state, msg, len))
        return 1;
#if FHOBS_KIND == FHOBS_KIND_OBSERVER
    if (read_finite(real, VR_PSI0, FHOBS_K, "psi0", state + FHOBS_N_MODEL, msg, len) ||
        read_finite(real, VR_XI0, 1, "xi0", state + FHOBS_N_MODEL + FHOBS_K, msg, len))
        return 1;
#elif FHOBS_FILTERING
    for (int i = 0; i <= FHOBS_K; i++)
        state[FHOBS_N_MODEL + i] = 0.0;
#endif
    return 0;
}

/* The observer's step dt from src into dst (its own state), y and u from the variables. */
static int observer_step(Work *w, const double *real, const int *integer, const double *src,
                         double *dst, double dt, char *msg, size_t len)
{
    char a[32], b[32];
    double inputs[FHOBS_K + FHOBS_M];
    double h = real[VR_H];
    double n_sub = ceil(dt / h * (1.0 - 1e-12));
    if (n_sub < 1.0)
        n_sub = 1.0;
    if (n_sub > FHOBS_MAX_SUBSTEPS) {
        snprintf(msg, len, "the step size %s is more than %d internal steps of h = %s; state "
                 "left unchanged", fhobs_number(dt, a, sizeof a), FHOBS_MAX_SUBSTEPS,
                 fhobs_number(h, b, sizeof b));
        return 1;
    }
    read_vector(real, VR_Y, FHOBS_K, inputs);
    read_vector(real, VR_U, FHOBS_M, inputs + FHOBS_K);
    int code;
    const char *scheme = "split";
#if FHOBS_HAS_EULER
    if (integer[VR_SCHEME] == FHOBS_SCHEME_EULER) {
        w->euler.n_sub = (int)n_sub;
        w->euler.hs = dt / n_sub;
        Call call = {&w->euler, src, dst, inputs};
        code = fhobs_euler_step(&call);
        scheme = "euler";
    } else
#else
    (void)integer;
#endif
    {
        const SplitPlan *plan = split_plan(w, dt, msg, len);
        if (!plan)
            return 1;
        Call call = {plan, src, dst, inputs};
        code = SPLIT_STEP(&call);
    }
    if (code != FHOBS_OK) {
        snprintf(msg, len, "the %s step diverged (non-finite state); state left unchanged",
                 scheme);
        return 1;
    }
    return 0;
}

#if FHOBS_KIND != FHOBS_KIND_SUPERVISED
int model_initial_state(const double *real, double *state, char *msg, size_t len)
{
    return observer_initial_state(real, state, msg, len);
}

int model_state_problem(const double *state, char *msg, size_t len)
{
    (void)state; /* no counts or indices: any finite state */
    (void)msg;
    (void)len;
    return 0;
}

int model_step(Work *w, const double *real, const int *integer, const double *src,
               double *dst, double dt, char *msg, size_t len)
{
    return observer_step(w, real, integer, src, dst, dt, msg, len);
}

/* The state outputs; the observer's sigma. */
void model_outputs(Work *w, double *real, const int *integer, const double *state)
{
    (void)w;
    (void)integer;
    state_outputs(real, state);
#if FHOBS_KIND == FHOBS_KIND_OBSERVER
    real[VR_SIGMA] = sigma_of(state + FHOBS_N_MODEL, FHOBS_K, state[FHOBS_N_MODEL + FHOBS_K]);
#endif
}
#else
/* ---------------------------------------------------------------------------------------- */
/* Supervised observer (fhobs.core.supervisor.SupervisedObserver): the filtering observer's */
/* step and the Kalman filter's cycles on the same y and u, the innovation statistics, the  */
/* mode, the handover and the time-varying recursion after it. State: the statistic, the    */
/* mode, the homogeneous statistic, the time in the return band (SUPERVISOR_HEAD entries),  */
/* the filtering observer's z, psi, xi, the Kalman filter's z and its offset to the next    */
/* sample (0: a step holds whole samples), its covariance P (row by row) and the cycles     */
/* left of the recursion (0: the steady-state gain).                                        */
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

int model_initial_state(const double *real, double *state, char *msg, size_t len)
{
    if (observer_initial_state(real, state + HOMOGENEOUS_STATE, msg, len))
        return 1;
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
    if (observer_step(w, real, integer, src + HOMOGENEOUS_STATE, dst + HOMOGENEOUS_STATE, dt,
                      msg, len))
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
           offset_problem(state[KALMAN_STATE + FHOBS_N_MODEL], msg, len) ||
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
#endif

#elif FHOBS_KIND == FHOBS_KIND_PLANT
/* ---------------------------------------------------------------------------------------- */
/* Plant: ZOH plans per step size, explicit Euler from A, B, E; noise from (seed, step)     */
#include "noise.h"

struct Work {
    double noise[FHOBS_NOISE_BLOCK * FHOBS_K]; /* draws of the block `block` of `seed` */
    long long block;                           /* -1: none drawn */
    int seed;
    PlanKeys keys;
    PlantPlan zoh[FHOBS_PLAN_SLOTS];
    double Phi[FHOBS_PLAN_SLOTS][FHOBS_N * FHOBS_N];
    double Gamma_B[FHOBS_PLAN_SLOTS][FHOBS_N * FHOBS_M + 1];
    double Gamma_E[FHOBS_PLAN_SLOTS][FHOBS_N * FHOBS_R + 1];
    double rows[FHOBS_ZOH_ROWS]; /* [Phi, Gamma_B, Gamma_E] of the plan being made */
    double scratch[FHOBS_PLAN_WORK];
};

void work_init(Work *w)
{
    w->block = -1;
    w->seed = -1;
    plan_keys_init(&w->keys);
}

/* The ZOH plan of the step size dt: kept from an earlier step, or computed now into the least
 * recently used slot (fhobs.core.plant.LTIPlant._blocks). */
static const PlantPlan *zoh_plan(Work *w, double dt)
{
    int fresh, i = plan_slot(&w->keys, dt, &fresh);
    PlantPlan *plan = &w->zoh[i];
    if (!fresh)
        return plan;
    zoh_rows(ZOH_TOP, FHOBS_N, FHOBS_ZOH_SIZE, dt, w->rows, w->scratch);
    for (int r = 0; r < FHOBS_N; r++) {
        const double *row = w->rows + (size_t)r * FHOBS_ZOH_SIZE;
        for (int j = 0; j < FHOBS_N; j++)
            w->Phi[i][r * FHOBS_N + j] = row[j];
        for (int j = 0; j < FHOBS_M; j++)
            w->Gamma_B[i][r * FHOBS_M + j] = row[FHOBS_N + j];
        for (int j = 0; j < FHOBS_R; j++)
            w->Gamma_E[i][r * FHOBS_R + j] = row[FHOBS_N + FHOBS_M + j];
    }
    plan->n = FHOBS_N;
    plan->m = FHOBS_M;
    plan->r = FHOBS_R;
    plan->Phi = w->Phi[i];
    plan->Gamma_B = w->Gamma_B[i];
    plan->Gamma_E = w->Gamma_E[i];
    return plan;
}

int model_parameters_problem(const double *real, const int *integer, char *msg,
                             size_t len)
{
    char a[32];
    double amplitude = real[VR_NOISE_AMPLITUDE];
    int scheme = integer[VR_SCHEME];
    if (scheme < 0 || scheme > 1) {
        snprintf(msg, len, "scheme = %d is not in 0..1", scheme);
        return 1;
    }
    if (!(amplitude >= 0.0 && isfinite(amplitude))) {
        snprintf(msg, len, "noise_amplitude must be finite and >= 0, got %s",
                 fhobs_number(amplitude, a, sizeof a));
        return 1;
    }
    if (integer[VR_NOISE_SEED] < 0) {
        snprintf(msg, len, "seed must be >= 0, got %d", integer[VR_NOISE_SEED]);
        return 1;
    }
    return 0;
}

int model_initial_state(const double *real, double *state, char *msg, size_t len)
{
    if (read_finite(real, VR_X0, FHOBS_N, "x0", state, msg, len))
        return 1;
    state[FHOBS_N] = 0.0; /* the step index k */
    return 0;
}

/* The step index k: a whole number in [0, FHOBS_MAX_STEP_INDEX) (its noise block a 32-bit
 * word). */
int model_state_problem(const double *state, char *msg, size_t len)
{
    return whole_problem(state[FHOBS_N], 0.0, FHOBS_MAX_STEP_INDEX - 1.0,
                         "step index k (the plant's noise sample)", msg, len);
}

int model_step(Work *w, const double *real, const int *integer, const double *src,
               double *dst, double dt, char *msg, size_t len)
{
    double u[FHOBS_M + FHOBS_R + 1];
    read_vector(real, VR_U, FHOBS_M, u);
    read_vector(real, VR_Q, FHOBS_R, u + FHOBS_M);
    if (integer[VR_SCHEME] == FHOBS_SCHEME_EULER) { /* x + dt ((A x + B u) + E q) */
        for (int i = 0; i < FHOBS_N; i++) {
            double s = 0.0, t = 0.0, e = 0.0;
            for (int j = 0; j < FHOBS_N; j++)
                s += PLANT_A[i * FHOBS_N + j] * src[j];
            for (int j = 0; j < FHOBS_M; j++)
                t += PLANT_B[i * FHOBS_M + j] * u[j];
            for (int j = 0; j < FHOBS_R; j++)
                e += PLANT_E[i * FHOBS_R + j] * u[FHOBS_M + j];
            dst[i] = src[i] + dt * ((s + t) + e);
        }
    } else {
        Call call = {zoh_plan(w, dt), src, dst, u};
        fhobs_plant_step(&call);
    }
    if (!all_finite(dst, FHOBS_N)) {
        snprintf(msg, len, "the plant state overflowed; state left unchanged");
        return 1;
    }
    dst[FHOBS_N] = src[FHOBS_N] + 1.0;
    return 0;
}

/* y = C x + eta_k, eta_k = noise_amplitude * draws[k mod NOISE_BLOCK] of block k / NOISE_BLOCK
 * (fhobs.core.plant.uniform_noise); the state output x */
void model_outputs(Work *w, double *real, const int *integer, const double *state)
{
    double amplitude = real[VR_NOISE_AMPLITUDE];
    long long k = (long long)state[FHOBS_N];
    const double *eta = NULL;
    if (amplitude != 0.0) {
        int seed = integer[VR_NOISE_SEED];
        long long block = k / FHOBS_NOISE_BLOCK;
        if (block != w->block || seed != w->seed) {
            fhobs_noise_block((uint32_t)seed, (uint32_t)block,
                              (size_t)FHOBS_NOISE_BLOCK * FHOBS_K, w->noise);
            w->block = block;
            w->seed = seed;
        }
        eta = w->noise + (size_t)(k % FHOBS_NOISE_BLOCK) * FHOBS_K;
    }
    for (int i = 0; i < FHOBS_K; i++) {
        double s = 0.0;
        for (int j = 0; j < FHOBS_N; j++)
            s += PLANT_C[i * FHOBS_N + j] * state[j];
        real[VR_Y + i] = eta ? s + amplitude * eta[i] : s;
    }
    state_outputs(real, state);
}

#elif FHOBS_KIND == FHOBS_KIND_KALMAN
/* ---------------------------------------------------------------------------------------- */
/* Kalman filter: the cycle matrix; one cycle per sample instant inside a step              */

struct Work {
    LinearPlan plan;
    double work[FHOBS_KALMAN_WORK(FHOBS_N_MODEL, FHOBS_K)];
};

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
    return offset_problem(state[FHOBS_N_MODEL], msg, len);
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
#elif FHOBS_KIND == FHOBS_KIND_PRESCRIBED_TIME
/* ---------------------------------------------------------------------------------------- */
/* Prescribed-time observer (Theorem 1): split plans per step size; xi0 from T0              */

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

void work_init(Work *w)
{
    plan_keys_init(&w->keys);
    bin_cache_init(&w->bins);
}

/* The split plan of the step size dt: kept from an earlier step, or computed now into the
 * least recently used slot; NULL with the message when no gain level of the tau scan makes
 * the split step contractive. */
static const PrescribedPlan *prescribed_plan(Work *w, double dt, char *msg, size_t len)
{
    char a[32];
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
        w->keys.dt[i] = NAN;
        snprintf(msg, len, "no gain level makes the split step of size %s contractive (smallest "
                 "spectral radius %.6g); use a smaller communication step; state left unchanged",
                 fhobs_number(dt, a, sizeof a), best);
        return NULL;
    }
    return plan;
}

int model_parameters_problem(const double *real, const int *integer, char *msg,
                             size_t len)
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
    if (scheme == FHOBS_SCHEME_EULER) {
        snprintf(msg, len, "scheme = 1 (euler): this native FMU runs the split scheme only "
                           "(use the pythonfmu FMU for the euler scheme)");
        return 1;
    }
    return 0;
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

int model_step(Work *w, const double *real, const int *integer, const double *src,
               double *dst, double dt, char *msg, size_t len)
{
    (void)integer;
    char a[32], b[32];
    double inputs[FHOBS_K + FHOBS_M];
    double h = real[VR_H];
    double n_sub = ceil(dt / h * (1.0 - 1e-12));
    if (n_sub < 1.0)
        n_sub = 1.0;
    if (n_sub > FHOBS_MAX_SUBSTEPS) {
        snprintf(msg, len, "the step size %s is more than %d internal steps of h = %s; state "
                 "left unchanged", fhobs_number(dt, a, sizeof a), FHOBS_MAX_SUBSTEPS,
                 fhobs_number(h, b, sizeof b));
        return 1;
    }
    const PrescribedPlan *plan = prescribed_plan(w, dt, msg, len);
    if (!plan)
        return 1;
    read_vector(real, VR_Y, FHOBS_K, inputs);
    read_vector(real, VR_U, FHOBS_M, inputs + FHOBS_K);
    Call call = {plan, src, dst, inputs};
    if (fhobs_prescribed_step(&call) != FHOBS_OK) {
        snprintf(msg, len, "the split step diverged (non-finite state); state left unchanged");
        return 1;
    }
    return 0;
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
#else
#error "model_data.c names no known FHOBS_KIND"
#endif

size_t model_work_size(void)
{
    return sizeof(Work);
}
