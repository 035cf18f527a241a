/*
 * Compiled step kernel of the fhobs runtime (kernel.c): the plans, the one argument of a step
 * function (Call), the step functions, the scratch memory each plan needs, and the small
 * helpers the native FMUs' planner and models share with the kernel (complex arithmetic as
 * numpy does it, matrix-vector products, sigma).
 *
 * Loaded by fhobs.core.kernel through ctypes, whose Structure definitions mirror the plans
 * below field by field; compiled into the native FMUs (fhobs.native) with their planner and
 * FMI layer. No variable-length arrays: a step's scratch memory is the caller's, pointed to
 * by its plan (the FHOBS_*_WORK sizes).
 */
#ifndef FHOBS_KERNEL_H
#define FHOBS_KERNEL_H

#include <math.h>
#include <stddef.h>

/* Visibility of the functions and data shared between translation units: hidden in a native
 * FMU's shared library, which exports its fmi2 functions only; exported when FHOBS_EXPORT is
 * defined (the kernel and the noise compiled alone for ctypes). */
#ifndef FHOBS_HIDDEN
#if !defined(FHOBS_EXPORT) && (defined(__GNUC__) || defined(__clang__)) &&                     \
    !defined(_WIN32) && !defined(__CYGWIN__)
#define FHOBS_HIDDEN __attribute__((visibility("hidden")))
#else
#define FHOBS_HIDDEN
#endif
#endif

#define FHOBS_OK 0        /* fhobs.core.kernel.OK */
#define FHOBS_NONFINITE 2 /* fhobs.core.kernel.NONFINITE */
#define FHOBS_BISECTION_STEPS 40 /* fhobs.core.runtime.BISECTION_STEPS */
#define FHOBS_BISECTION_TOL 0.05 /* fhobs.core.runtime.BISECTION_TOL */

typedef struct {
    double re, im;
} cplx;

/* One call of a step function (fhobs.core.kernel.Call). */
typedef struct {
    const void *plan;
    const double *src;
    double *dst;
    const double *inputs;
} Call;

/* A model's stepper (fhobs.core.kernel.StepperHandle) as a loop in C drives it: a step calls
 * step(calls[side]), which reads the state in buffers[side] and the two inputs held in inputs
 * (one after the other) and writes buffers[1 - side], the state after the step; size is the
 * number of state entries in a buffer. */
typedef struct {
    int (*step)(const Call *call);
    const Call *calls[2];
    double *buffers[2];
    double *inputs;
    int size;
} StepperHandle;

/* ---------------------------------------------------------------------------------------- */
/* Plans (fhobs.core.kernel's Structures, field by field)                                   */

typedef struct {
    int n, m, r;           /* states, inputs u, perturbations q */
    const double *Phi;     /* n x n */
    const double *Gamma_B; /* n x m */
    const double *Gamma_E; /* n x r */
} PlantPlan;

typedef struct {
    int n, k, m;     /* states, outputs y, inputs u */
    int cycles;      /* Kalman: filter cycles per communication step; Luenberger: 1 */
    const double *M; /* n x (n + k + m): z+ = M (z, y, u) */
    double *work;    /* scratch: FHOBS_KALMAN_WORK (Kalman; NULL for the Luenberger step) */
} LinearPlan;

typedef struct {
    int n, k, m;              /* model states N, outputs, inputs */
    int real_lam;             /* R's eigenvalues all real (numpy's factors are then real) */
    double nu, gamma, p, dt;  /* degree, xi gain, nu/2 + 1, communication step */
    double floor_level, ceiling, mismatch;
    double tiny, series;      /* spectral factors: series below tau = tiny, |mu| < series */
    const double *C;          /* k x n */
    const double *M;          /* n x (n + m + k): ZOH prediction, (z, u, v) */
    const double *F;          /* n x n: carries dz into z+ */
    const cplx *V_inv;        /* 2k x 2k: R = V diag(lam) V^-1 */
    const cplx *V_k;          /* k x 2k: V[:k] */
    const cplx *WL;           /* n x 2k: V_g^-1 L V[:k] */
    const cplx *V_g;          /* n x n: G_d = V_g diag(g) V_g^-1 */
    const cplx *g;            /* n: eigenvalues of G_d */
    const cplx *lam;          /* 2k: eigenvalues of R */
    cplx *factors;            /* 4k: spectral factors of last_tau (cache, written here) */
    double *last_tau;         /* 1 (cache, written here) */
    double *work;             /* scratch: FHOBS_FILTER_WORK(n, k) */
    cplx *cwork;              /* scratch: FHOBS_FILTER_CWORK(n, k) */
} FilterPlan;

typedef struct {
    int n, k, m, n_sub;       /* model states, outputs, inputs, substeps */
    int homogeneous;          /* the filtering observer (psi, xi, gain term); else Luenberger */
    int real_g;               /* the dilation's eigen data real (numpy's products then real) */
    double hs, nu, gamma, p, guard;
    const double *A, *B, *C, *L_inj; /* n x n, n x m, k x n, n x k */
    const double *L_tilde;    /* k x k */
    const cplx *V_d;          /* n x n: G_d = V_d diag(g) V_d^-1 */
    const cplx *inverse_L;    /* n x k: V_d^-1 L */
    const cplx *g;            /* n */
    double *work;             /* scratch: FHOBS_EULER_WORK(n, k) */
    cplx *cwork;              /* scratch: FHOBS_EULER_CWORK(n, k) */
} EulerPlan;

/* Scratch entries (doubles; CWORK: complex numbers) a plan's work pointers must hold, for a
 * model of n states, k outputs (fhobs.core.kernel's *_work functions). */
#define FHOBS_KALMAN_WORK(n, k) (2 * (n))
#define FHOBS_FILTER_WORK(n, k) (2 * (n) + 2 * (k) + 1)
#define FHOBS_FILTER_CWORK(n, k) ((n) + 6 * (k))
#define FHOBS_EULER_WORK(n, k) (7 * (n) + 4 * (k) + 2)
#define FHOBS_EULER_CWORK(n, k) (n)

/* Scratch doubles of a PrescribedPlan (n model states, k outputs). */
#define FHOBS_PRESCRIBED_WORK(n, k) (4 * (k) + 3 * (n))

typedef struct {
    int n, k, m;              /* model states N, outputs, inputs */
    int real_lam;             /* Q's eigenvalues all real (numpy's factors are then real) */
    double nu, rho, dt;       /* degree, xi gain, communication step */
    double floor_level, ceiling;
    double tiny, series;      /* spectral factors: series below tau = tiny, |mu| < series */
    const double *C;          /* k x n */
    const double *M;          /* n x (n + m + k): ZOH prediction, (z, u, v) */
    const double *F;          /* n x n: carries dz into z+ */
    const cplx *Q_inv;        /* k x k: Q = C L_pt = V diag(lam) V^-1, V^-1 */
    const cplx *Q_V;          /* k x k: V */
    const cplx *lam;          /* k: eigenvalues of Q */
    const cplx *V_g;          /* n x n: G_d = V_g diag(g) V_g^-1 */
    const cplx *g;            /* n: eigenvalues of G_d */
    const cplx *inverse_L;    /* n x k: V_g^-1 L_pt */
    cplx *factors;            /* 2k: spectral factors of last_tau (cache, written here) */
    double *last_tau;         /* 1 (cache, written here) */
    double *work;             /* FHOBS_PRESCRIBED_WORK(n, k) (scratch, written here) */
} PrescribedPlan;

/* ---------------------------------------------------------------------------------------- */
/* Step functions: FHOBS_OK, or FHOBS_NONFINITE when dst is not finite                       */

FHOBS_HIDDEN int fhobs_plant_step(const Call *call);
FHOBS_HIDDEN int fhobs_luenberger_step(const Call *call);
FHOBS_HIDDEN int fhobs_kalman_step(const Call *call);
FHOBS_HIDDEN int fhobs_filter_step(const Call *call);
FHOBS_HIDDEN int fhobs_euler_step(const Call *call);
FHOBS_HIDDEN int fhobs_prescribed_step(const Call *call);

/* The prescribed-time observer's correction (dz) at the level exp(log_x) (uses p->work). */
FHOBS_HIDDEN void fhobs_prescribed_correct(const PrescribedPlan *p, const double *v,
                                           double log_x, double *dz);

/* The exact correction flow of the filtering observer over p->dt at the frozen level
 * exp(log_s): psi_new (k), xi_new (1) and the increment dz (n) of z (uses p->cwork). */
FHOBS_HIDDEN void fhobs_correct(const FilterPlan *p, const double *psi, double xi,
                                const double *v, double log_s, double *psi_new, double *xi_new,
                                double *dz);

/* ---------------------------------------------------------------------------------------- */
/* Helpers shared with the planner and the models                                           */

/* numpy's complex product */
static inline cplx cmul(cplx a, cplx b)
{
    cplx r;
    r.re = a.re * b.re - a.im * b.im;
    r.im = a.re * b.im + a.im * b.re;
    return r;
}

/* numpy's complex quotient (Smith's algorithm) */
static inline cplx cdiv(cplx a, cplx b)
{
    cplx r;
    double rat, scl;
    if (fabs(b.re) >= fabs(b.im)) {
        rat = b.im / b.re;
        scl = 1.0 / (b.re + b.im * rat);
        r.re = (a.re + a.im * rat) * scl;
        r.im = (a.im - a.re * rat) * scl;
    } else {
        rat = b.re / b.im;
        scl = 1.0 / (b.im + b.re * rat);
        r.re = (a.re * rat + a.im) * scl;
        r.im = (a.im * rat - a.re) * scl;
    }
    return r;
}

static inline cplx cexp_(cplx a)
{
    cplx r;
    double e = exp(a.re);
    if (a.im == 0.0) {
        r.re = e;
        r.im = 0.0;
    } else {
        r.re = e * cos(a.im);
        r.im = e * sin(a.im);
    }
    return r;
}

/* numpy's complex expm1 */
static inline cplx cexpm1_(cplx a)
{
    cplx r;
    if (a.im == 0.0) {
        r.re = expm1(a.re);
        r.im = 0.0;
    } else {
        double s = sin(a.im / 2.0);
        r.re = expm1(a.re) * cos(a.im) - 2.0 * s * s;
        r.im = exp(a.re) * sin(a.im);
    }
    return r;
}

static inline int all_finite(const double *x, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(x[i]))
            return 0;
    return 1;
}

/* y[i] = sum_j A[i, j] x[j], A row-major rows x cols */
static inline void matvec(const double *A, const double *x, int rows, int cols, double *y)
{
    for (int i = 0; i < rows; i++) {
        const double *a = A + (size_t)i * cols;
        double s = 0.0;
        for (int j = 0; j < cols; j++)
            s += a[j] * x[j];
        y[i] = s;
    }
}

/* y[i] = sum_j A[i, j] x[j] for a matrix A whose columns are split over the consecutive
 * vectors x0 (n0 entries), x1 (n1), x2 (n2): A (x0, x1, x2) without forming the stack. */
static inline void matvec3(const double *A, int rows, const double *x0, int n0,
                           const double *x1, int n1, const double *x2, int n2, double *y)
{
    int cols = n0 + n1 + n2;
    for (int i = 0; i < rows; i++) {
        const double *a = A + (size_t)i * cols;
        double s = 0.0;
        for (int j = 0; j < n0; j++)
            s += a[j] * x0[j];
        for (int j = 0; j < n1; j++)
            s += a[n0 + j] * x1[j];
        for (int j = 0; j < n2; j++)
            s += a[n0 + n1 + j] * x2[j];
        y[i] = s;
    }
}

/* sigma = sqrt(max(|psi|^2 / 2, xi, 0)) */
static inline double sigma_of(const double *psi, int k, double xi)
{
    double half = 0.0, s;
    for (int i = 0; i < k; i++)
        half += psi[i] * psi[i];
    half = 0.5 * half;
    s = xi;
    if (half > s)
        s = half;
    if (0.0 > s)
        s = 0.0;
    return sqrt(s);
}

#endif
