/*
 * The C model of the plant family (fhobs.core.plant.LTIPlant): ZOH plans per step size,
 * explicit Euler from A, B, E; the measurement noise from (seed, step index) (noise.c). State:
 * x, then the step index k; outputs y = C x + noise and the state's x.
 */
#include <math.h>
#include <stdio.h>

#include "model_common.h"
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

size_t model_work_size(void)
{
    return sizeof(Work);
}

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
