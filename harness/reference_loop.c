/*
 * The steps of harness.reference.simulate's closed loop in C, for models that step in the
 * compiled kernel: at t_k, y_k = C x_k + eta_k, u_k = K v_k (v the filtering observer's estimate
 * or the plant's state), then the plant (inputs u_k, q_k), the filtering observer and the other
 * observers (inputs y_k, u_k) each make one kernel step; the states are recorded before each
 * step and after the last. The same order and the same kernel steps as the loop in Python; the
 * products C x and K v are kernel.h's matvec, summed left to right (numpy's BLAS may add them
 * in another order).
 * Compiled and loaded by harness.native.
 */
#include <string.h>

#include "kernel.h"

/* The loop's data (harness.native.ReferenceLoop): sizes, matrices, the precomputed eta and q,
 * the models' steppers. */
typedef struct {
    long n_steps;
    int n, k, m, r;            /* plant states, outputs, inputs, perturbations */
    int feedback_state;        /* 1: v = x; 0: v = the first n entries of the observer's z */
    const double *C;           /* k x n */
    const double *K;           /* m x n */
    const double *eta;         /* n_steps x k */
    const double *q;           /* n_steps x r */
    StepperHandle *plant;
    StepperHandle *observer;   /* the filtering observer, in the loop */
    StepperHandle *others;     /* n_others observers, open loop on (y, u) */
    int n_others;
} ReferenceLoop;

/* The recorded trajectories (rows: steps 0 .. n_steps for the states, 0 .. n_steps - 1 for
 * y and u). */
typedef struct {
    double *x;                 /* (n_steps + 1) x n */
    double *observer;          /* (n_steps + 1) x observer->size */
    double *others;            /* n_others x (n_steps + 1) x n */
    double *y;                 /* n_steps x k */
    double *u;                 /* n_steps x m */
} ReferenceRecord;

/* One kernel step of a model from buffer *side; the status of the step function. */
static int advance(const StepperHandle *h, int *side)
{
    int status = h->step(h->calls[*side]);
    if (status == FHOBS_OK)
        *side = 1 - *side;
    return status;
}

/* The status of a failed step, with failed[0] = the model, failed[1] = the step. */
static int failure(int status, long model, long step, long failed[2])
{
    failed[0] = model;
    failed[1] = step;
    return status;
}

/* Runs the loop's steps k_from .. k_to - 1, recording the states at t_k_from .. t_k_to (and
 * y, u of the steps) into rec; sides (n_others + 2 entries, zeros before the first call) holds
 * the buffer each model's state is in, from one call to the next. Returns 0, or the step
 * function's status of the first failing step: failed[0] = the model (0 plant, 1 filtering
 * observer, 2 + i the other observer i), failed[1] = the step index k. */
int reference_run(const ReferenceLoop *loop, const ReferenceRecord *rec, int *sides,
                  long k_from, long k_to, long failed[2])
{
    const int n = loop->n, k = loop->k, m = loop->m, r = loop->r;
    const long n_rows = loop->n_steps + 1;
    for (long step = k_from;; step++) {
        const double *x = loop->plant->buffers[sides[0]];
        const double *z = loop->observer->buffers[sides[1]];
        memcpy(rec->x + step * n, x, sizeof(double) * (size_t)n);
        memcpy(rec->observer + step * loop->observer->size, z,
               sizeof(double) * (size_t)loop->observer->size);
        for (int i = 0; i < loop->n_others; i++)
            memcpy(rec->others + ((long)i * n_rows + step) * n,
                   loop->others[i].buffers[sides[2 + i]], sizeof(double) * (size_t)n);
        if (step == k_to)
            return 0;
        double *y = rec->y + step * k, *u = rec->u + step * m;
        matvec(loop->C, x, k, n, y);
        for (int i = 0; i < k; i++)
            y[i] += loop->eta[step * k + i];
        matvec(loop->K, loop->feedback_state ? x : z, m, n, u);
        memcpy(loop->plant->inputs, u, sizeof(double) * (size_t)m);
        memcpy(loop->plant->inputs + m, loop->q + step * r, sizeof(double) * (size_t)r);
        int status = advance(loop->plant, &sides[0]);
        if (status != FHOBS_OK)
            return failure(status, 0, step, failed);
        for (int i = -1; i < loop->n_others; i++) {
            StepperHandle *h = i < 0 ? loop->observer : &loop->others[i];
            memcpy(h->inputs, y, sizeof(double) * (size_t)k);
            memcpy(h->inputs + k, u, sizeof(double) * (size_t)m);
            if ((status = advance(h, &sides[2 + i])) != FHOBS_OK)
                return failure(status, 2 + i, step, failed);
        }
    }
}
