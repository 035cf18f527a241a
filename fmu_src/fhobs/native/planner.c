/*
 * Step plans of a native fhobs FMU computed in C at the first step of each size: what the
 * numpy runtime prepares per communication step size for its kernel, by the same algorithms.
 *
 *   - zoh_rows: the exact zero-order hold of fhobs.core.linalg.zoh_blocks, the first n rows
 *     of expm(h [[A, B_1, ...], [0, 0, ...]]) = [Phi, Gamma_1, ...];
 *   - expm: fhobs.core.linalg.expm (Pade 13, the same squaring count, the same polynomial
 *     evaluation, the solve by LU with partial pivoting, the squarings);
 *   - the Luenberger observer's choice of hold (plan_luenberger);
 *   - the filtering observer's gain-level floor and ceiling: gain_levels.c.
 *
 * Every function takes its scratch memory from the caller (no variable-length arrays): see
 * FHOBS_PLAN_WORK_SIZE (planner.h). Compiled into every native FMU; also built with
 * planner_api.c into a library for the tests.
 */
#include <math.h>

#include "planner.h"

/* C = A B, all n x n row-major, each entry a sequence of fused multiply-adds as numpy's
 * matrix product forms it (OpenBLAS's dgemm on x86-64 with FMA): the squarings of expm
 * amplify any difference in the rounding of the products by up to 2^squarings. */
static void square_product(const double *A, const double *B, int n, double *C)
{
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            double s = 0.0;
            for (int l = 0; l < n; l++)
                s = fma(A[(size_t)i * n + l], B[(size_t)l * n + j], s);
            C[(size_t)i * n + j] = s;
        }
}

/* Solve A X = B (A n x n, B n x cols, row-major) by LU with partial pivoting in the order of
 * numpy's solve (LAPACK's gesv as OpenBLAS computes it for small matrices): the columns of L
 * and U formed left to right (each entry minus the dot product of the finished ones), the
 * pivot the first entry of largest modulus, L's column scaled by the pivot's reciprocal; then
 * L y = B and U X = y solved row by row, each solved entry (U's: times its diagonal's
 * reciprocal) subtracted from the rows not yet solved. A becomes L and U, B becomes X; 1 when
 * a pivot is exactly zero (LAPACK's singular case), else 0. */
int lu_solve(double *A, double *B, int n, int cols)
{
#define LU_A(i, j) A[(size_t)(i) * n + (j)]
#define LU_B(i, j) B[(size_t)(i) * cols + (j)]
    for (int j = 0; j < n; j++) {
        for (int i = 1; i < n; i++) {
            int terms = i < j ? i : j;
            double d = 0.0;
            for (int l = 0; l < terms; l++)
                d += LU_A(i, l) * LU_A(l, j);
            LU_A(i, j) -= d;
        }
        int pivot = j;
        for (int i = j + 1; i < n; i++)
            if (fabs(LU_A(i, j)) > fabs(LU_A(pivot, j)))
                pivot = i;
        if (LU_A(pivot, j) == 0.0)
            return 1;
        if (pivot != j) {
            for (int l = 0; l < n; l++) {
                double t = LU_A(j, l);
                LU_A(j, l) = LU_A(pivot, l);
                LU_A(pivot, l) = t;
            }
            for (int l = 0; l < cols; l++) {
                double t = LU_B(j, l);
                LU_B(j, l) = LU_B(pivot, l);
                LU_B(pivot, l) = t;
            }
        }
        double reciprocal = 1.0 / LU_A(j, j);
        for (int i = j + 1; i < n; i++)
            LU_A(i, j) *= reciprocal;
    }
    for (int i = 0; i < n; i++)
        for (int c = 0; c < cols; c++)
            for (int r = i + 1; r < n; r++)
                LU_B(r, c) -= LU_B(i, c) * LU_A(r, i);
    for (int i = n - 1; i >= 0; i--) {
        double reciprocal = 1.0 / LU_A(i, i);
        for (int c = 0; c < cols; c++) {
            double x = LU_B(i, c) * reciprocal;
            LU_B(i, c) = x;
            for (int r = 0; r < i; r++)
                LU_B(r, c) -= x * LU_A(r, i);
        }
    }
    return 0;
#undef LU_A
#undef LU_B
}

/* Pade(13) coefficients and theta_13 (fhobs.core.linalg._PADE13, _THETA13) */
static const double PADE13[14] = {
    64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
    129060195264000.0,   10559470521600.0,    670442572800.0,     33522128640.0,
    1323241920.0,        40840800.0,          960960.0,           16380.0,
    182.0,               1.0};
#define FHOBS_THETA13 5.371920351148152

/* out = b0 P0 + b1 P1 + b2 P2 (left to right, as numpy evaluates the sum), n x n */
static void combine3(double b0, const double *P0, double b1, const double *P1, double b2,
                     const double *P2, int n, double *out)
{
    for (size_t i = 0; i < (size_t)n * n; i++)
        out[i] = b0 * P0[i] + b1 * P1[i] + b2 * P2[i];
}

/* out += b0 P0 + b1 P1 + b2 P2 + b3 I, each added in turn as numpy does */
static void add_terms(double b0, const double *P0, double b1, const double *P1, double b2,
                      const double *P2, double b3, int n, double *out)
{
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            size_t e = (size_t)i * n + j;
            out[e] = out[e] + b0 * P0[e] + b1 * P1[e] + b2 * P2[e] + b3 * (i == j ? 1.0 : 0.0);
        }
}

/* E = expm(M) (n x n) as fhobs.core.linalg.expm; work: 7 n^2 doubles. A matrix whose 1-norm
 * is not finite gives NaN (the numpy runtime refuses it with an error). */
static void expm(const double *M, int n, double *E, double *work)
{
    const size_t nn = (size_t)n * n;
    double *X = work, *X2 = X + nn, *X4 = X2 + nn, *X6 = X4 + nn, *U = X6 + nn, *V = U + nn;
    double *T = V + nn;
    double norm = 0.0;
    for (int j = 0; j < n; j++) {
        double s = 0.0;
        for (int i = 0; i < n; i++)
            s += fabs(M[(size_t)i * n + j]);
        if (s > norm || isnan(s))
            norm = s;
    }
    if (!isfinite(norm)) {
        for (size_t i = 0; i < nn; i++)
            E[i] = NAN;
        return;
    }
    int squarings = 0;
    if (norm > FHOBS_THETA13) {
        double c = ceil(log2(norm / FHOBS_THETA13));
        squarings = c > 0.0 ? (int)c : 0;
    }
    double scale = pow(2.0, squarings);
    for (size_t i = 0; i < nn; i++)
        X[i] = M[i] / scale;
    const double *b = PADE13;
    square_product(X, X, n, X2);
    square_product(X2, X2, n, X4);
    square_product(X4, X2, n, X6);
    combine3(b[13], X6, b[11], X4, b[9], X2, n, T);
    square_product(X6, T, n, E);
    add_terms(b[7], X6, b[5], X4, b[3], X2, b[1], n, E);
    square_product(X, E, n, U);
    combine3(b[12], X6, b[10], X4, b[8], X2, n, T);
    square_product(X6, T, n, V);
    add_terms(b[6], X6, b[4], X4, b[2], X2, b[0], n, V);
    for (size_t i = 0; i < nn; i++) { /* solve (V - U) E = V + U */
        double u = U[i], v = V[i];
        T[i] = v - u;
        E[i] = v + u;
    }
    lu_solve(T, E, n, n);
    for (int s = 0; s < squarings; s++) {
        square_product(E, E, n, T);
        for (size_t i = 0; i < nn; i++)
            E[i] = T[i];
    }
}

/* The first n rows of expm(h aug), aug = [[top], [0]] (size x size, top = [A, B_1, ...]
 * n x size): [Phi, Gamma_1, ...] (fhobs.core.linalg.zoh_blocks), into out (n x size);
 * work: 9 size^2 doubles. */
void zoh_rows(const double *top, int n, int size, double h, double *out, double *work)
{
    const size_t ss = (size_t)size * size;
    double *aug = work, *E = aug + ss;
    for (size_t i = 0; i < ss; i++)
        aug[i] = i < (size_t)n * size ? h * top[i] : h * 0.0;
    expm(aug, size, E, E + ss);
    for (size_t i = 0; i < (size_t)n * size; i++)
        out[i] = E[i];
}

/* The Luenberger observer's plan of dt (planner.h): the held innovation's rows [Phi, Gamma_B,
 * Gamma_L] into M, F and its radius; then M rearranged row by row into [F, -Gamma_L,
 * Gamma_B], or overwritten by the closed loop's hold. work: n^2 + 9 size^2 doubles. */
double plan_luenberger(LinearPlan *plan, const LinearPlan *base, const HeldInnovation *held,
                       const double *top, double dt, double *M, double *work)
{
    const int n = base->n, k = base->k, m = base->m, size = n + k + m;
    double *F = work, *scratch = F + (size_t)n * n;
    zoh_rows(held->held_top, n, size, dt, M, scratch);
    carry_matrix(M, held->C, n, size, k, F);
    for (size_t i = 0; i < (size_t)n * n; i++)
        scratch[i] = F[i];
    double radius = spectral_radius(scratch, n, scratch + (size_t)n * n);
    if (radius < held->limit) {
        double *row = scratch;
        for (int i = 0; i < n; i++) {
            double *Mi = M + (size_t)i * size;
            for (int j = 0; j < size; j++)
                row[j] = Mi[j];
            for (int j = 0; j < n; j++)
                Mi[j] = F[(size_t)i * n + j];
            for (int j = 0; j < k; j++)
                Mi[n + j] = -row[n + m + j];
            for (int j = 0; j < m; j++)
                Mi[n + k + j] = row[n + j];
        }
    } else
        zoh_rows(top, n, size, dt, M, scratch);
    *plan = *base;
    plan->M = M;
    return radius;
}
