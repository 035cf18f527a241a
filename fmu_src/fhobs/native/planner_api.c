/*
 * The step planner of the native FMUs (planner.c, gain_levels.c, with the kernel they drive) as a shared
 * library with exported entry points, for the tests that compare it with the numpy runtime's
 * plans (fhobs.native.planner), linked with kernel.c, planner.c and gain_levels.c. Not part
 * of any FMU.
 */
#include "planner.h"

int fhobs_plan_work_size(int n, int k, int m, int z, int taus);
void fhobs_plan_zoh(const double *top, int n, int size, double h, double *out, double *work);
double fhobs_plan_luenberger(LinearPlan *plan, const LinearPlan *base,
                             const HeldInnovation *held, const double *top, double dt,
                             double *M, double *work);
int fhobs_plan_filter(FilterPlan *plan, const FilterPlan *base, const LevelScan *scan,
                      BinCache *bins, const double *top, double dt, double *M, double *F,
                      double *best, double *work);
int fhobs_plan_prescribed(PrescribedPlan *plan, const PrescribedPlan *base,
                          const LevelScan *scan, BinCache *bins, const double *top, double dt,
                          double *M, double *F, double *best, double *work);
int fhobs_bin_cache_bytes(void);
void fhobs_bin_cache_init(BinCache *bins);
int fhobs_bin_cache_info(const BinCache *bins, long long *scans);

/* Scratch doubles the entry points below need (FHOBS_PLAN_WORK_SIZE). */
int fhobs_plan_work_size(int n, int k, int m, int z, int taus)
{
    return FHOBS_PLAN_WORK_SIZE(n, k, m, z, taus);
}

/* The first n rows of expm(h [[top], [0]]) (top n x size) into out: zoh_rows. */
void fhobs_plan_zoh(const double *top, int n, int size, double h, double *out, double *work)
{
    zoh_rows(top, n, size, h, out, work);
}

/* The Luenberger observer's plan of dt, F's spectral radius returned: plan_luenberger. */
double fhobs_plan_luenberger(LinearPlan *plan, const LinearPlan *base,
                             const HeldInnovation *held, const double *top, double dt,
                             double *M, double *work)
{
    return plan_luenberger(plan, base, held, top, dt, M, work);
}

/* The filtering observer's plan of dt (plan's factors, last_tau, work and cwork set by the
 * caller): plan_filter. */
int fhobs_plan_filter(FilterPlan *plan, const FilterPlan *base, const LevelScan *scan,
                      BinCache *bins, const double *top, double dt, double *M, double *F,
                      double *best, double *work)
{
    return plan_filter(plan, base, scan, bins, top, dt, M, F, best, work);
}

/* The prescribed-time observer's plan of dt (plan's factors, last_tau and work set by the
 * caller): plan_prescribed. */
int fhobs_plan_prescribed(PrescribedPlan *plan, const PrescribedPlan *base,
                          const LevelScan *scan, BinCache *bins, const double *top, double dt,
                          double *M, double *F, double *best, double *work)
{
    return plan_prescribed(plan, base, scan, bins, top, dt, M, F, best, work);
}

/* The size of a BinCache in bytes (the tests allocate it). */
int fhobs_bin_cache_bytes(void)
{
    return (int)sizeof(BinCache);
}

/* An empty BinCache: bin_cache_init. */
void fhobs_bin_cache_init(BinCache *bins)
{
    bin_cache_init(bins);
}

/* The bins whose tau scan the cache keeps, and the scans made (*scans). */
int fhobs_bin_cache_info(const BinCache *bins, long long *scans)
{
    int kept = 0;
    for (int i = 0; i < FHOBS_BIN_SLOTS; i++)
        kept += bins->size[i] == bins->size[i];
    *scans = bins->scans;
    return kept;
}
