/*
 * The step planner of the native FMUs: the plan of a communication step size computed in C at
 * its first use (planner.c: the zero-order hold by expm; gain_levels.c: the filtering
 * observer's gain-level floor and ceiling). Every function takes its scratch memory from the
 * caller (FHOBS_PLAN_WORK_SIZE).
 */
#ifndef FHOBS_PLANNER_H
#define FHOBS_PLANNER_H

#include "kernel.h"

/* Scratch doubles needed by plan_filter (model states n, outputs k, inputs m, the ZOH's
 * augmented size z, taus scanned) and, a fortiori, by zoh_rows of size z. */
#define FHOBS_PLAN_WORK_SIZE(n, k, m, z, taus)                                                 \
    ((n) * (z) + (n) * (n) + 9 * (z) * (z) + 2 * ((n) + (k)) * ((n) + (k)) + 4 * ((n) + (k)) + \
     (m) + 2 * (taus) + 8)

#define FHOBS_SIZE_BINS_PER_OCTAVE 8 /* fhobs.core.runtime.SIZE_BINS_PER_OCTAVE */
#define FHOBS_BIN_SLOTS 64           /* fhobs.core.runtime.BIN_CACHE_SIZE */

/* The tau scans of the bins of step sizes used last (fhobs.core.runtime._Observer._bin_scan):
 * a scan is made once per bin, at the bin's representative size (size_bin), and each step
 * size of the bin checks the taus it gives at its own size (plan_filter). */
typedef struct {
    double size[FHOBS_BIN_SLOTS];             /* the bins' representative sizes (NAN: empty) */
    unsigned long long used[FHOBS_BIN_SLOTS]; /* when each was last used */
    unsigned long long clock;
    int best[FHOBS_BIN_SLOTS];  /* the grid index of tau_max; -1: no tau contracts */
    int first[FHOBS_BIN_SLOTS]; /* the grid index of tau_min; -1: no ceiling */
    long long scans;            /* tau scans made (fhobs.core.runtime.PlanCacheInfo.scans) */
} BinCache;

/* An empty BinCache. */
FHOBS_HIDDEN void bin_cache_init(BinCache *bins);
/* The slot of `value` among the n slots of a cache kept by least recent use (key[i]: a slot's
 * key, NAN when empty; used[i]: when it was last used, by the cache's *clock) and whether it
 * was taken for `value` now (*fresh: its content is to be computed): an empty slot or the
 * least recently used one (gain_levels.c). */
FHOBS_HIDDEN int lru_slot(double key[], unsigned long long used[], unsigned long long *clock,
                          int n, double value, int *fresh);

/* The representative step size of dt's bin (fhobs.core.runtime.size_bin): with dt = f 2^e,
 * f in [1/2, 1), the upper end of f's part of FHOBS_SIZE_BINS_PER_OCTAVE equal parts. */
FHOBS_HIDDEN double size_bin(double dt);

/* The tau scan of the filtering observer (fhobs.core.runtime._Observer._auto_taus). */
typedef struct {
    const double *tau_grid; /* fhobs.core.runtime.TAU_GRID, increasing */
    int n_tau;
    const cplx *Vg_inv;  /* n x n: inverse of the eigenvectors V_g of G_d (FilterPlan.V_g) */
    double roundoff;     /* the round-off floor of the gain level (independent of dt) */
    double contraction;  /* fhobs.core.runtime.CONTRACTION_LIMIT */
    double tie;          /* fhobs.core.runtime.RADIUS_TIE */
    double trusted_low;  /* the levels whose dilated radius the scan reads: */
    double trusted_high; /* _Observer._scaling_band (independent of dt) */
} LevelScan;

/* The Luenberger observer's held-innovation hold (fhobs.core.runtime.LuenbergerObserver,
 * held_innovation_map), chosen for a step size whose error map has a spectral radius below
 * `limit`. */
typedef struct {
    const double *held_top; /* n x (n + m + k): [A, B, L_lin], the ZOH's augmented top rows */
    const double *C;        /* k x n */
    double limit;           /* fhobs.core.runtime.HELD_INNOVATION_LIMIT */
} HeldInnovation;

/* Solve A X = B (A n x n, B n x cols, row-major) by LU with partial pivoting in numpy's order
 * of operations; A becomes L and U, B becomes X; 1 when a pivot is exactly zero, else 0. */
FHOBS_HIDDEN int lu_solve(double *A, double *B, int n, int cols);

/* The first n rows of expm(h [[top], [0]]) (top n x size) into out (n x size): [Phi,
 * Gamma_1, ...] (fhobs.core.linalg.zoh_blocks); work: 9 size^2 doubles. */
FHOBS_HIDDEN void zoh_rows(const double *top, int n, int size, double h, double *out,
                           double *work);

/* F = Phi + Gamma_inj C of a ZOH's rows M = [Phi, ..., Gamma_inj] (n x size, Gamma_inj its
 * last k columns; C k x n) into F (n x n), in numpy's order (gain_levels.c). */
FHOBS_HIDDEN void carry_matrix(const double *M, const double *C, int n, int size, int k,
                               double *F);

/* Spectral radius of A (n x n, destroyed), inf if an entry or the result is not finite;
 * work: n doubles (gain_levels.c). */
FHOBS_HIDDEN double spectral_radius(double *A, int n, double *work);

/* The Luenberger observer's plan of the step size dt (fhobs.core.runtime.LuenbergerObserver.
 * step_map): base's fields and M (the caller's n x (n + k + m) array) of z+ = M (z, y, u),
 * the held innovation [F, -Gamma_L, Gamma_B] (F = expm(dt A) + Gamma_L C) when F's spectral
 * radius is below held->limit, else the closed loop's hold, the first rows of expm(dt [[top],
 * [0]]) with top = [A + L_lin C, -L_lin, B]. Returns F's spectral radius (inf when not
 * finite). work: FHOBS_PLAN_WORK_SIZE. */
FHOBS_HIDDEN double plan_luenberger(LinearPlan *plan, const LinearPlan *base,
                                    const HeldInnovation *held, const double *top, double dt,
                                    double *M, double *work);

/* The filtering observer's plan of the step size dt (gain_levels.c): base's fields, M and F
 * (the caller's arrays), the gain-level floor and ceiling from the tau scan of dt's bin
 * (kept in bins) checked at dt, or from dt's own scan; plan's factors, last_tau, work and
 * cwork are the caller's. 0, or 1 when the observer cannot follow dt (*best: the smallest
 * spectral radius). work: FHOBS_PLAN_WORK_SIZE. */
FHOBS_HIDDEN int plan_filter(FilterPlan *plan, const FilterPlan *base, const LevelScan *scan,
                             BinCache *bins, const double *top, double dt, double *M,
                             double *F, double *best, double *work);

/* The prescribed-time observer's plan of the step size dt (gain_levels.c), as plan_filter's
 * (plan's factors, last_tau and work: the caller's). */
FHOBS_HIDDEN int plan_prescribed(PrescribedPlan *plan, const PrescribedPlan *base,
                                 const LevelScan *scan, BinCache *bins, const double *top,
                                 double dt, double *M, double *F, double *best, double *work);

#endif
