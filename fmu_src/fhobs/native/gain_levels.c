/*
 * The plan of a communication step size of the homogeneous observers, the filtering and the
 * prescribed-time one (fhobs.core.runtime: _prediction, the tau scan of _Observer._tau_scan
 * with error_map and _dilated_radius, made once per bin of step sizes and checked at each
 * size, _binned_taus, _step_size_plan): M, F, the gain-level floor and ceiling; the scan is
 * shared, each observer brings its dilated error map. The spectral
 * radius of that map is computed by balancing, a Hessenberg reduction and Francis double-shift
 * QR sweeps; it only decides (the argmin over the tau grid, the contraction limit), so it needs the accuracy of
 * numpy's eigenvalues, not their bits.
 *
 * Compiled into every native FMU (planner.h); also built with planner_api.c into a library
 * for the tests.
 */
#include <float.h>
#include <math.h>

#include "planner.h"

#define FHOBS_QR_SWEEPS 30       /* times max(10, n): QR sweeps before the radius is unknown */
#define FHOBS_BALANCE_SWEEPS 100 /* fhobs.core.linalg.BALANCE_SWEEPS */

/* F = Phi + Gamma_inj C: Phi the first n columns of M (n x size), Gamma_inj its last k; the
 * product's entries fused multiply-adds in sequence, as numpy's matrix product. */
void carry_matrix(const double *M, const double *C, int n, int size, int k, double *F)
{
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            double s = 0.0;
            for (int l = 0; l < k; l++)
                s = fma(M[(size_t)i * size + size - k + l], C[(size_t)l * n + j], s);
            F[(size_t)i * n + j] = M[(size_t)i * size + j] + s;
        }
}

/* ---------------------------------------------------------------------------------------- */
/* Spectral radius of a real nonsymmetric matrix: balancing, Hessenberg reduction by         */
/* Householder reflections, Francis double-shift QR with deflation                           */

/* Scale A (n x n) by a diagonal similarity of powers of two (exact) until its off-diagonal row
 * and column norms are balanced (fhobs.core.linalg.balancing_scale): the eigenvalues are kept,
 * their computation is as accurate as for a balanced matrix. */
static void balance(double *A, int n)
{
    for (int sweep = 0; sweep < FHOBS_BALANCE_SWEEPS; sweep++) {
        int converged = 1;
        for (int i = 0; i < n; i++) {
            double col = 0.0, row = 0.0;
            for (int j = 0; j < n; j++)
                if (j != i) {
                    col += fabs(A[(size_t)j * n + i]);
                    row += fabs(A[(size_t)i * n + j]);
                }
            if (col == 0.0 || row == 0.0)
                continue;
            double f = 1.0, c = col, r = row;
            while (c < r / 2.0) {
                f *= 2.0;
                c *= 2.0;
                r /= 2.0;
            }
            while (c >= 2.0 * r) {
                f /= 2.0;
                c /= 2.0;
                r *= 2.0;
            }
            if (c + r < 0.95 * (col + row)) {
                converged = 0;
                for (int j = 0; j < n; j++) {
                    A[(size_t)j * n + i] *= f;
                    A[(size_t)i * n + j] /= f;
                }
            }
        }
        if (converged)
            return;
    }
}

/* Apply the reflection I - 2 v v^T / (v^T v) (v of `len` entries, rows r0.. of A) from the
 * left to columns c0..c1 and from the right (columns r0..) to rows q0..q1. */
static void reflect(double *A, int n, const double *v, int len, int r0, int c0, int c1, int q0,
                    int q1)
{
    double vv = 0.0;
    for (int i = 0; i < len; i++)
        vv += v[i] * v[i];
    if (vv == 0.0)
        return;
    for (int j = c0; j <= c1; j++) {
        double w = 0.0;
        for (int i = 0; i < len; i++)
            w += v[i] * A[(size_t)(r0 + i) * n + j];
        w = 2.0 * w / vv;
        for (int i = 0; i < len; i++)
            A[(size_t)(r0 + i) * n + j] -= w * v[i];
    }
    for (int i = q0; i <= q1; i++) {
        double w = 0.0;
        for (int j = 0; j < len; j++)
            w += A[(size_t)i * n + r0 + j] * v[j];
        w = 2.0 * w / vv;
        for (int j = 0; j < len; j++)
            A[(size_t)i * n + r0 + j] -= w * v[j];
    }
}

/* The Householder vector that maps x (len entries) onto a multiple of e_1, into v. */
static void householder(const double *x, int len, double *v)
{
    double norm = 0.0;
    for (int i = 0; i < len; i++)
        norm = hypot(norm, x[i]);
    for (int i = 0; i < len; i++)
        v[i] = x[i];
    v[0] += x[0] < 0.0 ? -norm : norm;
}

/* Reduce A (n x n) to upper Hessenberg form by similarity; work: n doubles. */
static void hessenberg(double *A, int n, double *work)
{
    for (int c = 0; c < n - 2; c++) {
        int len = n - c - 1;
        for (int i = 0; i < len; i++)
            work[i] = A[(size_t)(c + 1 + i) * n + c];
        householder(work, len, work);
        reflect(A, n, work, len, c + 1, c, n - 1, 0, n - 1);
    }
}

/* The larger modulus of the eigenvalues of [[a, b], [c, d]]. */
static double block_radius(double a, double b, double c, double d)
{
    double mid = 0.5 * (a + d), half = 0.5 * (a - d);
    double disc = half * half + b * c;
    if (disc >= 0.0)
        return fabs(mid) + sqrt(disc);
    return sqrt(fabs(a * d - b * c));
}

/* Spectral radius of the upper Hessenberg H (n x n, destroyed) by Francis double-shift QR
 * sweeps on its unreduced trailing block, deflating 1 x 1 and 2 x 2 blocks; the shifts are the
 * eigenvalues of the trailing 2 x 2 block, or twice the one of them nearer its last diagonal
 * entry when both are real, with exceptional shifts every 11th sweep; inf when the sweeps do
 * not converge within FHOBS_QR_SWEEPS max(10, n) in all (the budget of LAPACK's dlahqr). */
static double hessenberg_radius(double *H, int n)
{
    double radius = 0.0, scale = 0.0;
    for (size_t i = 0; i < (size_t)n * n; i++)
        scale = fabs(H[i]) > scale ? fabs(H[i]) : scale;
    int hi = n - 1, iterations = 0, budget = FHOBS_QR_SWEEPS * (n > 10 ? n : 10);
    while (hi >= 0) {
        int lo = hi;
        while (lo > 0) { /* the first negligible subdiagonal entry above hi */
            double s = fabs(H[(size_t)(lo - 1) * n + lo - 1]) + fabs(H[(size_t)lo * n + lo]);
            if (s == 0.0)
                s = scale;
            if (fabs(H[(size_t)lo * n + lo - 1]) <= DBL_EPSILON * s)
                break;
            lo--;
        }
        double r;
        if (lo == hi) {
            r = fabs(H[(size_t)hi * n + hi]);
            hi -= 1;
        } else if (lo == hi - 1) {
            r = block_radius(H[(size_t)lo * n + lo], H[(size_t)lo * n + hi],
                             H[(size_t)hi * n + lo], H[(size_t)hi * n + hi]);
            hi -= 2;
        } else {
            if (--budget < 0)
                return INFINITY;
            iterations++;
            /* the shifts: the eigenvalues of [[y, .], [., x]] with product w of the
             * off-diagonal entries */
            double y = H[(size_t)(hi - 1) * n + hi - 1], x = H[(size_t)hi * n + hi];
            double w = H[(size_t)hi * n + hi - 1] * H[(size_t)(hi - 1) * n + hi];
            double half = 0.5 * (y - x), disc = half * half + w;
            if (iterations % 11 == 10) { /* exceptional shifts against cycling */
                double e = fabs(H[(size_t)hi * n + hi - 1]) +
                           fabs(H[(size_t)(hi - 1) * n + hi - 2]);
                x = y = x + 0.75 * e;
                w = -0.4375 * e * e;
            } else if (disc >= 0.0) { /* real shifts: the one nearer x, twice */
                x = y = x + half + (half > 0.0 ? -sqrt(disc) : sqrt(disc));
                w = 0.0;
            }
            /* the first column of (H - s1)(H - s2) at lo, divided by H[lo + 1][lo], in
             * differences from the diagonal (no cancellation of the shifts) */
            const double *h0 = H + (size_t)lo * n, *h1 = h0 + n, *h2 = h1 + n;
            double dx = x - h0[lo], dy = y - h0[lo], v[3];
            double xv[3] = {(dx * dy - w) / h1[lo] + h0[lo + 1], h1[lo + 1] - h0[lo] - dx - dy,
                            h2[lo + 1]};
            for (int k = lo; k < hi - 1; k++) {
                householder(xv, 3, v);
                int c0 = k > lo ? k - 1 : lo, q1 = k + 3 < hi ? k + 3 : hi;
                reflect(H, n, v, 3, k, c0, hi, lo, q1);
                xv[0] = H[(size_t)(k + 1) * n + k];
                xv[1] = H[(size_t)(k + 2) * n + k];
                if (k < hi - 2)
                    xv[2] = H[(size_t)(k + 3) * n + k];
            }
            householder(xv, 2, v);
            reflect(H, n, v, 2, hi - 1, hi - 2, hi, lo, hi);
            continue;
        }
        iterations = 0;
        if (!(r <= radius))
            radius = r;
    }
    return radius;
}

/* Spectral radius of A (n x n, destroyed), inf if an entry or the result is not finite
 * (the runtime observers' _dilated_radius, fhobs.core.runtime); work: n doubles. */
double spectral_radius(double *A, int n, double *work)
{
    for (size_t i = 0; i < (size_t)n * n; i++)
        if (!isfinite(A[i]))
            return INFINITY;
    balance(A, n);
    hessenberg(A, n, work);
    double r = hessenberg_radius(A, n);
    return isfinite(r) ? r : INFINITY;
}

/* ---------------------------------------------------------------------------------------- */
/* The tau scan of the gain-level floor and ceiling (any observer with a dilated error map)  */

/* The radius of an observer's dilated error map at a frozen gain level (its plan, the scan's
 * dilation data, the level, scratch): inf where the map cannot be formed. */
typedef double (*LevelRadius)(const void *plan, const LevelScan *scan, double level,
                              double *work);

/* factor d(log_s) into the n x n block of S (N x N, row-major) that starts at row and column
 * `offset`: d(s) = V_g diag(exp(s g)) V_g^-1 (fhobs.core.dilation.Dilation.matrix), each entry
 * then multiplied by factor; work: 2 n doubles. */
static void dilation_block(const cplx *V_g, const cplx *g, const cplx *Vg_inv, int n,
                           double log_s, double factor, double *S, int N, int offset,
                           double *work)
{
    cplx *scale = (cplx *)work;
    for (int l = 0; l < n; l++)
        scale[l] = cexp_((cplx){log_s * g[l].re, log_s * g[l].im});
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            double re = 0.0;
            for (int l = 0; l < n; l++) {
                cplx t = cmul(scale[l], Vg_inv[(size_t)l * n + j]);
                re += V_g[(size_t)i * n + l].re * t.re - V_g[(size_t)i * n + l].im * t.im;
            }
            S[(size_t)(offset + i) * N + offset + j] = factor * re;
        }
}

/* Spectral radius of S^-1 map (both N x N, destroyed), inf where S is singular or the result
 * not finite; work: N doubles. */
static double dilated_map_radius(double *S, double *map, int N, double *work)
{
    if (lu_solve(S, map, N, N))
        return INFINITY;
    return spectral_radius(map, N, work);
}

/* The tau scan of _Observer._tau_scan for the step size dt: the radius of each tau of the
 * grid at the level (tau / dt)^(1/nu); 0 with *best_index (tau_max) and *first_index
 * (tau_min, -1 for none) set, or 1 when no tau contracts (*best: the smallest radius).
 * tau_max is the largest tau whose radius is within scan->tie of the smallest; its level or
 * the round-off floor, the higher, is the floor; the run of contractive taus from tau_max
 * towards higher levels reads only the levels at or above the floor, within the scan's
 * trusted band, whose radius is finite, and passes the others; tau_min is its last tau, none
 * when no tau ends it. work: 2 n_tau doubles, then the radius function's. */
static int scan_taus(const LevelScan *scan, double dt, double nu, LevelRadius radius,
                     const void *plan, int *best_index, int *first_index, double *best,
                     double *work)
{
    double *radii = work, *levels = work + scan->n_tau, *rest = levels + scan->n_tau;
    const double inverse_nu = 1.0 / nu;
    int arg = 0;
    for (int i = 0; i < scan->n_tau; i++) {
        levels[i] = pow(scan->tau_grid[i] / dt, inverse_nu);
        radii[i] = radius(plan, scan, levels[i], rest);
        if (radii[i] < radii[arg])
            arg = i;
    }
    *best = radii[arg];
    if (!(radii[arg] < scan->contraction))
        return 1;
    for (int i = scan->n_tau - 1; i > arg; i--)
        if (radii[i] <= *best + scan->tie) { /* the largest tau as small as the smallest */
            arg = i;
            break;
        }
    const double floor = scan->roundoff > levels[arg] ? scan->roundoff : levels[arg];
    int first = arg;
    *best_index = arg;
    *first_index = -1;
    for (int i = arg - 1; i >= 0; i--) {
        if (!(levels[i] >= floor && levels[i] >= scan->trusted_low &&
              levels[i] <= scan->trusted_high && isfinite(radii[i])))
            continue;
        if (!(radii[i] < scan->contraction)) {
            *first_index = first;
            break;
        }
        first = i;
    }
    return 0;
}

/* The floor and ceiling of _step_size_plan for dt from dt's own tau scan: the floor the level
 * of tau_max or the round-off floor, the higher; the ceiling the level of tau_min, at least
 * the floor, inf without tau_min. 0, or 1 when no tau contracts (*best: the smallest
 * radius). work: as scan_taus. */
static int scan_levels(const LevelScan *scan, double dt, double nu, LevelRadius radius,
                       const void *plan, double *floor_level, double *ceiling, double *best,
                       double *work)
{
    int best_index, first_index;
    if (scan_taus(scan, dt, nu, radius, plan, &best_index, &first_index, best, work))
        return 1;
    const double inverse_nu = 1.0 / nu, level = pow(scan->tau_grid[best_index] / dt, inverse_nu);
    *floor_level = scan->roundoff > level ? scan->roundoff : level;
    *ceiling = INFINITY;
    if (first_index >= 0) {
        const double top_level = pow(scan->tau_grid[first_index] / dt, inverse_nu);
        *ceiling = top_level > *floor_level ? top_level : *floor_level;
    }
    return 0;
}

/* The floor and ceiling of dt from its bin's taus (tau_max = grid[best_index], tau_min =
 * grid[first_index] or none), checked at dt (_Observer._binned_taus): the floor, the level
 * of tau_max or the round-off floor, must contract at dt (else 1: dt needs its own scan);
 * the ceiling is the level of the first tau from tau_min towards tau_max whose level is
 * trusted (at or above the floor, within the band) and contracts at dt, the floor when none
 * does, inf without tau_min. work: the radius function's. */
static int binned_levels(const LevelScan *scan, int best_index, int first_index, double dt,
                         double nu, LevelRadius radius, const void *plan, double *floor_level,
                         double *ceiling, double *work)
{
    const double inverse_nu = 1.0 / nu;
    const double level = pow(scan->tau_grid[best_index] / dt, inverse_nu);
    const double floor = scan->roundoff > level ? scan->roundoff : level;
    if (!(radius(plan, scan, floor, work) < scan->contraction))
        return 1;
    *floor_level = floor;
    *ceiling = first_index < 0 ? INFINITY : floor;
    for (int i = first_index; i >= 0 && i < best_index; i++) {
        const double candidate = pow(scan->tau_grid[i] / dt, inverse_nu);
        if (candidate >= floor && candidate >= scan->trusted_low &&
            candidate <= scan->trusted_high &&
            radius(plan, scan, candidate, work) < scan->contraction) {
            *ceiling = candidate;
            break;
        }
    }
    return 0;
}

void bin_cache_init(BinCache *bins)
{
    for (int i = 0; i < FHOBS_BIN_SLOTS; i++) {
        bins->size[i] = NAN;
        bins->used[i] = 0;
        bins->best[i] = bins->first[i] = -1;
    }
    bins->clock = 0;
    bins->scans = 0;
}

double size_bin(double dt)
{
    int exponent;
    const double fraction = frexp(dt, &exponent);
    const int part = (int)((fraction - 0.5) * (2 * FHOBS_SIZE_BINS_PER_OCTAVE));
    return ldexp(0.5 + (double)(part + 1) / (2 * FHOBS_SIZE_BINS_PER_OCTAVE), exponent);
}

int lru_slot(double key[], unsigned long long used[], unsigned long long *clock, int n,
             double value, int *fresh)
{
    int slot = 0;
    for (int i = 0; i < n; i++) {
        if (key[i] == value) {
            used[i] = ++*clock;
            *fresh = 0;
            return i;
        }
        if (used[i] < used[slot])
            slot = i;
    }
    key[slot] = value;
    used[slot] = ++*clock;
    *fresh = 1;
    return slot;
}

/* A plan's fields that depend on the step size, and what the ZOH of another size needs. */
typedef struct {
    double *dt;
    const double **M, **F; /* n x size, n x n */
    const double *top, *C; /* the ZOH's augmented top rows (n x size), C (k x n) */
    int n, size, k;
} SizeFields;

/* The floor and ceiling of the plan's step size (its fields `at`): from its bin's tau scan
 * (made now at the bin's size if not kept, the plan's fields pointed there meanwhile)
 * checked at the plan's size, or from a scan of its own where the bin has no contractive tau
 * or the check fails. 0, or 1 when no tau contracts at the plan's size (*best: the smallest
 * radius). work: the bin's M and F, then zoh_rows' or scan_taus'. */
static int plan_levels(const LevelScan *scan, BinCache *bins, LevelRadius radius, void *plan,
                       const SizeFields *at, double nu, double *floor_level, double *ceiling,
                       double *best, double *work)
{
    const double dt = *at->dt;
    int fresh, slot = lru_slot(bins->size, bins->used, &bins->clock, FHOBS_BIN_SLOTS,
                              size_bin(dt), &fresh); /* fresh: the bin's scan is to be made */
    if (fresh) {
        const double *own_M = *at->M, *own_F = *at->F;
        double *M = work, *F = M + (size_t)at->n * at->size, *rest = F + (size_t)at->n * at->n;
        double smallest;
        *at->dt = bins->size[slot];
        zoh_rows(at->top, at->n, at->size, *at->dt, M, rest);
        carry_matrix(M, at->C, at->n, at->size, at->k, F);
        *at->M = M;
        *at->F = F;
        bins->scans++;
        if (scan_taus(scan, *at->dt, nu, radius, plan, &bins->best[slot], &bins->first[slot],
                      &smallest, rest))
            bins->best[slot] = -1;
        *at->dt = dt;
        *at->M = own_M;
        *at->F = own_F;
    }
    if (bins->best[slot] >= 0 && !binned_levels(scan, bins->best[slot], bins->first[slot], dt,
                                                nu, radius, plan, floor_level, ceiling, work))
        return 0;
    bins->scans++;
    return scan_levels(scan, dt, nu, radius, plan, floor_level, ceiling, best, work);
}

/* ---------------------------------------------------------------------------------------- */
/* The filtering observer's plan                                                              */

/* Spectral radius of the split step's map of the dilated error S^-1 (psi, z - x) at the
 * frozen gain level, S = diag(level I_k, d(ln level)) (fhobs.core.runtime._Observer.error_map
 * with x = y = u = 0, FilteringObserver._error_scaling), inf where it cannot be formed; work:
 * 2 N^2 + 4 N + m + 4 doubles (N = n + k). */
static double dilated_radius(const void *plan, const LevelScan *scan, double level,
                             double *work)
{
    const FilterPlan *p = plan;
    const int n = p->n, k = p->k, N = n + k;
    const size_t NN = (size_t)N * N;
    double *S = work, *map = S + NN, *v = map + NN, *psi_new = v + k, *dz = psi_new + k + 1;
    double *z_new = dz + n, *u = z_new + n, *scratch = u + p->m + 1;
    const double log_s = log(level);
    for (size_t i = 0; i < NN; i++)
        S[i] = 0.0;
    for (int i = 0; i < k; i++)
        S[(size_t)i * N + i] = level;
    dilation_block(p->V_g, p->g, scan->Vg_inv, n, log_s, 1.0, S, N, k, scratch);
    for (int i = 0; i < p->m; i++)
        u[i] = 0.0;
    for (int j = 0; j < N; j++) { /* the column e = S[:, j]: psi = e[:k], z = e[k:] */
        double *psi = scratch, *z = scratch + k;
        for (int i = 0; i < N; i++)
            psi[i] = S[(size_t)i * N + j];
        matvec(p->C, z, k, n, v);
        fhobs_correct(p, psi, 0.0, v, log_s, psi_new, psi_new + k, dz);
        matvec3(p->M, n, z, n, u, p->m, v, k, z_new);
        for (int i = 0; i < n; i++) {
            const double *a = p->F + (size_t)i * n;
            double s = 0.0;
            for (int l = 0; l < n; l++)
                s += a[l] * dz[l];
            z_new[i] += s;
        }
        for (int i = 0; i < k; i++)
            map[(size_t)i * N + j] = psi_new[i];
        for (int i = 0; i < n; i++)
            map[(size_t)(k + i) * N + j] = z_new[i];
    }
    return dilated_map_radius(S, map, N, scratch);
}

/* The filtering observer's plan of the step size dt: base's fields, then M and F (into the
 * caller's arrays, n x (n + m + k) and n x n) from the ZOH of top = [A, B, L0], then the
 * floor and ceiling (plan's factors and last_tau: the caller's cache, reset here). 0, or 1
 * when the observer cannot follow dt (*best: the smallest spectral radius). work:
 * FHOBS_PLAN_WORK_SIZE. */
int plan_filter(FilterPlan *plan, const FilterPlan *base, const LevelScan *scan, BinCache *bins,
                const double *top, double dt, double *M, double *F, double *best, double *work)
{
    cplx *factors = plan->factors, *cscratch = plan->cwork;
    double *last_tau = plan->last_tau, *scratch = plan->work;
    const int n = base->n, size = base->n + base->m + base->k;
    *plan = *base;
    plan->factors = factors;
    plan->last_tau = last_tau;
    plan->work = scratch;
    plan->cwork = cscratch;
    *last_tau = NAN;
    plan->dt = dt;
    zoh_rows(top, n, size, dt, M, work);
    carry_matrix(M, base->C, n, size, base->k, F);
    plan->M = M;
    plan->F = F;
    const SizeFields at = {&plan->dt, &plan->M, &plan->F, top, base->C, n, size, base->k};
    return plan_levels(scan, bins, dilated_radius, plan, &at, plan->nu, &plan->floor_level,
                       &plan->ceiling, best, work);
}

/* ---------------------------------------------------------------------------------------- */
/* The prescribed-time observer's plan                                                        */

/* Spectral radius of the split step's map of the dilated error S^-1 (z - x) at the frozen
 * gain level, S = level^-nu d(ln level) (PrescribedTimeObserver._error_scaling; xi plays no
 * part), inf where it cannot be formed; work: 2 n^2 + 5 n + k + m + 1 doubles. */
static double prescribed_radius(const void *plan, const LevelScan *scan, double level,
                                double *work)
{
    const PrescribedPlan *p = plan;
    const int n = p->n, k = p->k;
    const size_t NN = (size_t)n * n;
    double *S = work, *map = S + NN, *v = map + NN, *dz = v + k, *z_new = dz + n;
    double *u = z_new + n, *z = u + p->m + 1, *scratch = z + n;
    const double log_x = log(level);
    dilation_block(p->V_g, p->g, scan->Vg_inv, n, log_x, pow(level, -p->nu), S, n, 0,
                   scratch);
    for (int i = 0; i < p->m; i++)
        u[i] = 0.0;
    for (int j = 0; j < n; j++) { /* the column z = S[:, j] */
        for (int i = 0; i < n; i++)
            z[i] = S[(size_t)i * n + j];
        matvec(p->C, z, k, n, v);
        fhobs_prescribed_correct(p, v, log_x, dz);
        matvec3(p->M, n, z, n, u, p->m, v, k, z_new);
        for (int i = 0; i < n; i++) {
            const double *a = p->F + (size_t)i * n;
            double s = 0.0;
            for (int l = 0; l < n; l++)
                s += a[l] * dz[l];
            map[(size_t)i * n + j] = z_new[i] + s;
        }
    }
    return dilated_map_radius(S, map, n, scratch);
}

/* The prescribed-time observer's plan of the step size dt, as plan_filter's (plan's factors,
 * last_tau and work: the caller's, the cache reset here). 0, or 1 when the observer cannot
 * follow dt (*best: the smallest spectral radius). work: FHOBS_PLAN_WORK_SIZE. */
int plan_prescribed(PrescribedPlan *plan, const PrescribedPlan *base, const LevelScan *scan,
                    BinCache *bins, const double *top, double dt, double *M, double *F,
                    double *best, double *work)
{
    cplx *factors = plan->factors;
    double *last_tau = plan->last_tau, *scratch = plan->work;
    const int n = base->n, size = base->n + base->m + base->k;
    *plan = *base;
    plan->factors = factors;
    plan->last_tau = last_tau;
    plan->work = scratch;
    *last_tau = NAN;
    plan->dt = dt;
    zoh_rows(top, n, size, dt, M, work);
    carry_matrix(M, base->C, n, size, base->k, F);
    plan->M = M;
    plan->F = F;
    const SizeFields at = {&plan->dt, &plan->M, &plan->F, top, base->C, n, size, base->k};
    return plan_levels(scan, bins, prescribed_radius, plan, &at, plan->nu, &plan->floor_level,
                       &plan->ceiling, best, work);
}
