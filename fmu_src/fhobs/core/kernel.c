/*
 * Compiled step kernel of the fhobs runtime (loaded by fhobs.core.kernel through ctypes).
 *
 * Each function advances one model by one communication step: its one argument, a Call,
 * names the plan, the state to read (`src`, never written), where to write the new state
 * (`dst`) and the inputs held over the step (arrays the caller owns). One argument keeps the
 * ctypes call cheap. Everything that depends on the design or on the step size (ZOH matrices,
 * eigen-decompositions, gain-level floor and ceiling) is prepared by the numpy runtime and
 * handed over in a plan. The arithmetic follows the numpy reference step operation by
 * operation (same formulas, complex products and quotients as numpy forms them); only the
 * summation order of the matrix-vector products may differ from numpy's BLAS.
 *
 * Return codes: FHOBS_OK, FHOBS_NONFINITE (dst is not finite). The plans, the scratch sizes
 * and the helpers shared with the native FMUs are in kernel.h; the scratch memory of a step
 * (FHOBS_*_WORK) is the caller's, pointed to by its plan.
 */
#include "kernel.h"

/* ---------------------------------------------------------------------------------------- */
/* Linear models: the plant's ZOH, the Luenberger observer, the Kalman filter               */

/* x+ = (Phi x + Gamma_B u) + Gamma_E q; inputs = (u, q). */
int fhobs_plant_step(const Call *call)
{
    const PlantPlan *p = call->plan;
    const double *src = call->src, *inputs = call->inputs;
    double *dst = call->dst;
    const double *u = inputs, *q = inputs + p->m;
    for (int i = 0; i < p->n; i++) {
        const double *a = p->Phi + (size_t)i * p->n, *b = p->Gamma_B + (size_t)i * p->m;
        const double *e = p->Gamma_E + (size_t)i * p->r;
        double s = 0.0, t = 0.0, w = 0.0;
        for (int j = 0; j < p->n; j++)
            s += a[j] * src[j];
        for (int j = 0; j < p->m; j++)
            t += b[j] * u[j];
        for (int j = 0; j < p->r; j++)
            w += e[j] * q[j];
        dst[i] = (s + t) + w;
    }
    return all_finite(dst, p->n) ? FHOBS_OK : FHOBS_NONFINITE;
}

/* Luenberger split step, the exact hold its plan chose (innovation or y held): z+ = M (z, y, u);
 * inputs = (y, u). */
int fhobs_luenberger_step(const Call *call)
{
    const LinearPlan *p = call->plan;
    const double *inputs = call->inputs;
    matvec3(p->M, p->n, call->src, p->n, inputs, p->k, inputs + p->k, p->m, call->dst);
    return all_finite(call->dst, p->n) ? FHOBS_OK : FHOBS_NONFINITE;
}

/* Kalman filter: `cycles` times z <- M (z, y, u); inputs = (y, u). */
int fhobs_kalman_step(const Call *call)
{
    const LinearPlan *p = call->plan;
    const double *src = call->src, *inputs = call->inputs;
    double *dst = call->dst;
    const double *y = inputs, *u = inputs + p->k, *z = src;
    for (int c = 0; c < p->cycles; c++) {
        double *out = (c == p->cycles - 1) ? dst : p->work + (size_t)(c % 2) * p->n;
        matvec3(p->M, p->n, z, p->n, y, p->k, u, p->m, out);
        z = out;
    }
    return all_finite(dst, p->n) ? FHOBS_OK : FHOBS_NONFINITE;
}

/* ---------------------------------------------------------------------------------------- */
/* Filtering homogeneous observer, split scheme                                             */

/* ExpmFamily.spectral_factors: [exp(tau lam); tau phi1(tau lam)] */
static void spectral_factors(const FilterPlan *p, double tau, cplx *f)
{
    int k2 = 2 * p->k;
    if (tau > p->tiny) {
        for (int i = 0; i < k2; i++) {
            cplx mu = {tau * p->lam[i].re, tau * p->lam[i].im};
            cplx e = cexpm1_(mu);
            f[i].re = e.re + 1.0;
            f[i].im = e.im;
            if (p->real_lam) {
                f[k2 + i].re = e.re / p->lam[i].re;
                f[k2 + i].im = 0.0;
            } else {
                f[k2 + i] = cdiv(e, p->lam[i]);
            }
        }
        return;
    }
    for (int i = 0; i < k2; i++) {
        cplx mu = {tau * p->lam[i].re, tau * p->lam[i].im};
        cplx phi;
        f[i] = cexp_(mu);
        if (hypot(mu.re, mu.im) < p->series) {
            phi.re = 1.0 + 0.5 * mu.re;
            phi.im = 0.5 * mu.im;
        } else {
            phi = p->real_lam ? (cplx){expm1(mu.re) / mu.re, 0.0} : cdiv(cexpm1_(mu), mu);
        }
        f[k2 + i].re = tau * phi.re;
        f[k2 + i].im = tau * phi.im;
    }
}

/* Exact w-decay of the xi equation (runtime.signed_power_decay). */
static double signed_power_decay(double w, double gamma, double p, double h)
{
    if (w == 0.0)
        return 0.0;
    double q = 1.0 - p;
    double base = pow(fabs(w), q) - q * gamma * h;
    if (0.0 > base) /* Python's max(base, 0.0) */
        base = 0.0;
    return copysign(pow(base, 1.0 / q), w);
}

/* Exact correction flow over dt at the frozen level exp(log_s) (FilteringObserver._correct):
 * psi_new (k), xi_new (1) and the increment dz (n) of z. */
static void correct(const FilterPlan *p, const double *psi, double xi, const double *v,
                    double log_s, double *psi_new, double *xi_new, double *dz)
{
    const int n = p->n, k = p->k, k2 = 2 * p->k;
    const double tau = p->dt * exp(p->nu * log_s);
    cplx *c = p->cwork, *prod = c + k2, *out_n = prod + 2 * k2; /* 2k, 4k, n */

    /* InjectionFlow.apply: r = (psi, v) scaled by (s^-1, s^-(1+nu)), its coefficients c */
    cplx scale_psi = cexp_((cplx){log_s * -1.0, 0.0});
    cplx scale_v = cexp_((cplx){log_s * -(1.0 + p->nu), 0.0});
    for (int i = 0; i < k2; i++) {
        double re = 0.0, im = 0.0;
        const cplx *a = p->V_inv + (size_t)i * k2;
        for (int j = 0; j < k2; j++) {
            double r = j < k ? psi[j] * scale_psi.re : v[j - k] * scale_v.re;
            re += a[j].re * r;
            im += a[j].im * r;
        }
        c[i].re = re;
        c[i].im = im;
    }
    if (tau != *p->last_tau) {
        spectral_factors(p, tau, p->factors);
        *p->last_tau = tau;
    }
    for (int i = 0; i < 2 * k2; i++)
        prod[i] = cmul(p->factors[i], c[i % k2]);
    cplx s_level = cexp_((cplx){log_s * 1.0, 0.0});
    for (int i = 0; i < k; i++) {
        double re = 0.0, im = 0.0;
        const cplx *a = p->V_k + (size_t)i * k2;
        for (int j = 0; j < k2; j++) {
            cplx t = cmul(a[j], prod[j]);
            re += t.re;
            im += t.im;
        }
        psi_new[i] = cmul((cplx){re, im}, s_level).re;
    }
    for (int i = 0; i < n; i++) {
        double re = 0.0, im = 0.0;
        const cplx *a = p->WL + (size_t)i * k2;
        for (int j = 0; j < k2; j++) {
            cplx t = cmul(a[j], prod[k2 + j]);
            re += t.re;
            im += t.im;
        }
        cplx scale = cexp_((cplx){log_s * p->g[i].re, log_s * p->g[i].im});
        out_n[i] = cmul((cplx){re, im}, scale);
    }
    for (int i = 0; i < n; i++) {
        double re = 0.0;
        const cplx *a = p->V_g + (size_t)i * n;
        for (int j = 0; j < n; j++)
            re += a[j].re * out_n[j].re - a[j].im * out_n[j].im;
        dz[i] = re;
    }

    /* xi: |Delta |psi|^2/2| integrated, then the exact decay of w = xi - |psi|^2/2. The
     * squared norms are fused multiply-adds in sequence, as numpy's dot of a short vector
     * (OpenBLAS on x86-64 with FMA): the invariant xi >= |psi|^2/2, reached exactly by the
     * decay, then holds for numpy's |psi|^2 too. */
    double half_old = 0.0, half_new = 0.0;
    for (int i = 0; i < k; i++) {
        half_old = fma(psi[i], psi[i], half_old);
        half_new = fma(psi_new[i], psi_new[i], half_new);
    }
    half_old *= 0.5;
    half_new *= 0.5;
    double w = xi + fabs(half_new - half_old) - half_new;
    *xi_new = signed_power_decay(w, p->gamma, p->p, p->dt) + half_new;
}

void fhobs_correct(const FilterPlan *p, const double *psi, double xi, const double *v,
                   double log_s, double *psi_new, double *xi_new, double *dz)
{
    correct(p, psi, xi, v, log_s, psi_new, xi_new, dz);
}

/* Python's min(a, b): a unless b < a (so a NaN first argument is kept, as numpy's step does) */
static double py_min(double a, double b)
{
    return b < a ? b : a;
}

/* The correction at the level exp(log_level) (FilteringObserver._correct takes the level and
 * forms its logarithm again) into psi_new, xi_new, dz; whether its sigma is at most that
 * level. */
static int correct_at(const FilterPlan *p, const double *psi, double xi, const double *v,
                      double log_level, double *psi_new, double *xi_new, double *dz)
{
    double level = exp(log_level);
    correct(p, psi, xi, v, log(level), psi_new, xi_new, dz);
    return sigma_of(psi_new, p->k, *xi_new) <= level;
}

/* The correction at the filtering observer's own level (FilteringObserver.
 * _consistent_correction): sigma between the floor and the ceiling; when sigma after the
 * correction exceeds `mismatch` times that level, the self-consistent level s,
 * sigma_after(s) = s, is searched in ln s (bracket expansion by 2 up to the ceiling, then bisection to BISECTION_TOL), the decisions
 * and the levels tried as in the numpy runtime. Writes psi_new, xi_new (consecutive) and dz. */
static void correct_own_level(const FilterPlan *p, const double *psi, double xi,
                              const double *v, double *psi_new, double *xi_new, double *dz)
{
    const int n = p->n, k = p->k;
    double level = sigma_of(psi, k, xi);
    if (p->floor_level > level)
        level = p->floor_level;
    if (p->ceiling < level)
        level = p->ceiling;
    correct(p, psi, xi, v, log(level), psi_new, xi_new, dz);
    double after = sigma_of(psi_new, k, *xi_new);
    if (after <= p->mismatch * level)
        return;
    const double log_ceiling = log(p->ceiling);
    double lo = log(level), hi = py_min(log(after), log_ceiling);
    for (int i = 0; i < FHOBS_BISECTION_STEPS; i++) {
        if (correct_at(p, psi, xi, v, hi, psi_new, xi_new, dz))
            break;
        if (hi >= log_ceiling)
            return;
        lo = hi;
        hi = py_min(hi + 2.0, log_ceiling);
    }
    double *trial = p->work + k + n, *trial_dz = trial + k + 1; /* k + 1, n */
    while (hi - lo > FHOBS_BISECTION_TOL) {
        double mid = 0.5 * (lo + hi);
        if (correct_at(p, psi, xi, v, mid, trial, trial + k, trial_dz)) {
            hi = mid;
            for (int i = 0; i <= k; i++)
                psi_new[i] = trial[i];
            for (int i = 0; i < n; i++)
                dz[i] = trial_dz[i];
        } else {
            lo = mid;
        }
    }
}

/* One split step over dt: state (z, psi, xi), inputs (y, u): the correction at the
 * observer's own level, xi raised to at least the floor squared (FilteringObserver.
 * _correct_own_level), then the prediction. */
int fhobs_filter_step(const Call *call)
{
    const FilterPlan *p = call->plan;
    const double *src = call->src, *inputs = call->inputs;
    double *dst = call->dst;
    const int n = p->n, k = p->k;
    const double *z = src, *psi = src + n, *y = inputs, *u = inputs + k;
    double *v = p->work, *dz = v + k; /* k, n: trial, trial_dz follow (correct_own_level) */

    matvec(p->C, z, k, n, v);
    for (int i = 0; i < k; i++)
        v[i] -= y[i];
    correct_own_level(p, psi, src[n + k], v, dst + n, dst + n + k, dz);
    /* xi at least the floor squared: the floor carried into the next step (Python's max) */
    const double floor_squared = p->floor_level * p->floor_level;
    if (floor_squared > dst[n + k])
        dst[n + k] = floor_squared;

    /* prediction: z+ = M (z, u, v) + F dz */
    matvec3(p->M, n, z, n, u, p->m, v, k, dst);
    for (int i = 0; i < n; i++) {
        const double *a = p->F + (size_t)i * n;
        double s = 0.0;
        for (int j = 0; j < n; j++)
            s += a[j] * dz[j];
        dst[i] += s;
    }
    return all_finite(dst, n + k + 1) ? FHOBS_OK : FHOBS_NONFINITE;
}

/* ---------------------------------------------------------------------------------------- */
/* Explicit Euler scheme of the filtering and Luenberger observers                          */

/* sum_i a[i] b[i] as numpy's dot of a short vector (fused multiply-adds in sequence) */
static double dot_fma(const double *a, const double *b, int k)
{
    double s = 0.0;
    for (int i = 0; i < k; i++)
        s = fma(a[i], b[i], s);
    return s;
}

/* The paper's right-hand side beyond A z + B u + L_inj v (FilteringObserver._euler_rates):
 * dpsi, dxi and the gain term of dz at the state (psi, xi). */
static void euler_rates(const EulerPlan *p, const double *psi, double xi, const double *v,
                        double *dpsi, double *dxi, double *dz_gain)
{
    const int n = p->n, k = p->k;
    double sigma = sigma_of(psi, k, xi);
    if (sigma > 0.0) {
        double log_s = log(sigma > p->guard ? sigma : p->guard);
        double gain = exp((p->nu - 1.0) * log_s), level = exp(p->nu * log_s);
        cplx *c = p->cwork; /* n */
        for (int i = 0; i < n; i++) { /* Dilation.apply: V (exp(s g) * (V^-1 L psi)) */
            double re = 0.0, im = 0.0;
            const cplx *a = p->inverse_L + (size_t)i * k;
            for (int j = 0; j < k; j++) {
                re += a[j].re * psi[j];
                im += a[j].im * psi[j];
            }
            cplx scale = cexp_((cplx){log_s * p->g[i].re, log_s * p->g[i].im});
            c[i] = p->real_g ? (cplx){scale.re * re, 0.0} : cmul(scale, (cplx){re, im});
        }
        for (int i = 0; i < n; i++) {
            double re = 0.0;
            const cplx *a = p->V_d + (size_t)i * n;
            for (int j = 0; j < n; j++)
                re += a[j].re * c[j].re - a[j].im * c[j].im;
            dz_gain[i] = gain * re;
        }
        for (int i = 0; i < k; i++) {
            const double *a = p->L_tilde + (size_t)i * k;
            double s = 0.0;
            for (int j = 0; j < k; j++)
                s += a[j] * psi[j];
            dpsi[i] = v[i] + level * s;
        }
    } else { /* sigma = 0 forces psi = 0: the homogeneous terms vanish */
        for (int i = 0; i < n; i++)
            dz_gain[i] = 0.0;
        for (int i = 0; i < k; i++)
            dpsi[i] = v[i];
    }
    double w = xi - 0.5 * dot_fma(psi, psi, k), power = 0.0;
    if (w != 0.0)
        power = copysign(pow(fabs(w), p->p), w);
    *dxi = fabs(dot_fma(psi, dpsi, k)) - p->gamma * power;
}

/* n_sub explicit Euler substeps of size hs (_Observer._run_euler): state (z[, psi, xi]),
 * inputs (y, u). */
int fhobs_euler_step(const Call *call)
{
    const EulerPlan *p = call->plan;
    const int n = p->n, k = p->k, size = n + (p->homogeneous ? k + 1 : 0);
    const double *y = call->inputs, *u = call->inputs + k, *src = call->src;
    double *dst = call->dst;
    /* work: two substep states of n + k + 1, then v, dpsi (k), dz_gain, rate, az, bu, lv (n) */
    double *v = p->work + 2 * (n + k + 1), *dpsi = v + k, *dz_gain = dpsi + k;
    double *rate = dz_gain + n, *az = rate + n, *bu = az + n, *lv = bu + n, dxi = 0.0;

    for (int s = 0; s < p->n_sub; s++) {
        /* read from src, then from the last written scratch; the last substep writes dst */
        const double *x = s == 0 ? src : p->work + (size_t)((s - 1) % 2) * (n + k + 1);
        double *out = s == p->n_sub - 1 ? dst : p->work + (size_t)(s % 2) * (n + k + 1);
        matvec(p->C, x, k, n, v);
        for (int i = 0; i < k; i++)
            v[i] -= y[i];
        if (p->homogeneous) {
            euler_rates(p, x + n, x[n + k], v, dpsi, &dxi, dz_gain);
        } else {
            for (int i = 0; i < n; i++)
                dz_gain[i] = 0.0;
        }
        matvec(p->A, x, n, n, az);
        matvec(p->B, u, n, p->m, bu);
        matvec(p->L_inj, v, n, k, lv);
        for (int i = 0; i < n; i++) {
            rate[i] = ((az[i] + bu[i]) + lv[i]) + dz_gain[i];
            out[i] = x[i] + p->hs * rate[i];
        }
        if (p->homogeneous) {
            for (int i = 0; i < k; i++)
                out[n + i] = x[n + i] + p->hs * dpsi[i];
            out[n + k] = x[n + k] + p->hs * dxi;
        }
    }
    return all_finite(dst, size) ? FHOBS_OK : FHOBS_NONFINITE;
}

/* ---------------------------------------------------------------------------------------- */
/* Prescribed-time observer (Theorem 1), split scheme                                       */

/* ExpmFamily.spectral_factors of the `size` eigenvalues lam: [exp(tau lam); tau phi1(tau lam)]
 * into f (2 size). */
static void family_factors(const cplx *lam, int size, int real_lam, double tiny, double series,
                           double tau, cplx *f)
{
    if (tau > tiny) {
        for (int i = 0; i < size; i++) {
            cplx mu = {tau * lam[i].re, tau * lam[i].im};
            cplx e = cexpm1_(mu);
            f[i].re = e.re + 1.0;
            f[i].im = e.im;
            if (real_lam) {
                f[size + i].re = e.re / lam[i].re;
                f[size + i].im = 0.0;
            } else {
                f[size + i] = cdiv(e, lam[i]);
            }
        }
        return;
    }
    for (int i = 0; i < size; i++) {
        cplx mu = {tau * lam[i].re, tau * lam[i].im};
        cplx phi;
        f[i] = cexp_(mu);
        if (hypot(mu.re, mu.im) < series) {
            phi.re = 1.0 + 0.5 * mu.re;
            phi.im = 0.5 * mu.im;
        } else if (real_lam) {
            phi.re = expm1(mu.re) / mu.re;
            phi.im = 0.0;
        } else {
            phi = cdiv(cexpm1_(mu), mu);
        }
        f[size + i].re = tau * phi.re;
        f[size + i].im = tau * phi.im;
    }
}

/* Exact flow of dxi/dt = -rho |xi|^(1+nu) sign(xi) over dt (PrescribedTimeObserver._xi_exact):
 * |xi|^-nu decreases linearly, reaches 0 and stays 0. */
static double prescribed_xi(const PrescribedPlan *p, double xi)
{
    if (xi == 0.0)
        return 0.0;
    double base = pow(fabs(xi), -p->nu) + p->nu * p->rho * p->dt;
    if (0.0 > base) /* Python's max(base, 0.0) */
        base = 0.0;
    return copysign(pow(base, -1.0 / p->nu), xi);
}

/* The gain level of the level state: its modulus between the floor and the ceiling
 * (PrescribedTimeObserver._level, Python's min(max(.)) order). */
static double prescribed_level(const PrescribedPlan *p, double xi)
{
    double level = fabs(xi);
    if (p->floor_level > level)
        level = p->floor_level;
    if (p->ceiling < level)
        level = p->ceiling;
    return level;
}

/* Exact flow over dt of dz = gain (C z - y) with x frozen at the level exp(log_x)
 * (PrescribedTimeObserver._correct): dz = d(log_x) L_pt tau phi1(tau Q) v / level^(1+nu),
 * tau = dt level^nu. Uses work[k .. 4k + 2n). */
static void prescribed_correct(const PrescribedPlan *p, const double *v, double log_x,
                               double *dz)
{
    const int n = p->n, k = p->k;
    const double tau = p->dt * exp(p->nu * log_x);
    const double scale_v = exp(-(1.0 + p->nu) * log_x);
    cplx *c = (cplx *)(p->work + k);
    double *phi = p->work + 3 * k;
    cplx *w = (cplx *)(p->work + 4 * k);
    for (int i = 0; i < k; i++) { /* c = V^-1 (v / level^(1+nu)) */
        double re = 0.0, im = 0.0;
        const cplx *a = p->Q_inv + (size_t)i * k;
        for (int j = 0; j < k; j++) {
            double r = v[j] * scale_v;
            re += a[j].re * r;
            im += a[j].im * r;
        }
        c[i].re = re;
        c[i].im = im;
    }
    if (tau != *p->last_tau) {
        family_factors(p->lam, k, p->real_lam, p->tiny, p->series, tau, p->factors);
        *p->last_tau = tau;
    }
    for (int i = 0; i < k; i++) /* tau phi1(tau Q) r = V (factors[k:] c), real part */
        c[i] = cmul(p->factors[k + i], c[i]);
    for (int i = 0; i < k; i++) {
        double re = 0.0;
        const cplx *a = p->Q_V + (size_t)i * k;
        for (int j = 0; j < k; j++)
            re += a[j].re * c[j].re - a[j].im * c[j].im;
        phi[i] = re;
    }
    for (int i = 0; i < n; i++) { /* Dilation.apply: V_g (exp(log_x g) * (V_g^-1 L_pt phi)) */
        double re = 0.0, im = 0.0;
        const cplx *a = p->inverse_L + (size_t)i * k;
        for (int j = 0; j < k; j++) {
            re += a[j].re * phi[j];
            im += a[j].im * phi[j];
        }
        cplx scale = cexp_((cplx){log_x * p->g[i].re, log_x * p->g[i].im});
        w[i] = cmul(scale, (cplx){re, im});
    }
    for (int i = 0; i < n; i++) {
        double re = 0.0;
        const cplx *a = p->V_g + (size_t)i * n;
        for (int j = 0; j < n; j++)
            re += a[j].re * w[j].re - a[j].im * w[j].im;
        dz[i] = re;
    }
}

/* One split step over dt of the prescribed-time observer: state (z, xi, the gain-level state),
 * inputs (y, u): the correction at the level of the level state, the exact flow of xi and of
 * the level state (then raised to at least the floor: PrescribedTimeObserver.
 * _correct_own_level), then the prediction z+ = M (z, u, v) + F dz. */
void fhobs_prescribed_correct(const PrescribedPlan *p, const double *v, double log_x,
                              double *dz)
{
    prescribed_correct(p, v, log_x, dz);
}

int fhobs_prescribed_step(const Call *call)
{
    const PrescribedPlan *p = call->plan;
    const double *src = call->src, *inputs = call->inputs;
    double *dst = call->dst;
    const int n = p->n, k = p->k;
    const double *z = src, *y = inputs, *u = inputs + k;
    double *v = p->work, *dz = p->work + 4 * k + 2 * n;

    matvec(p->C, z, k, n, v);
    for (int i = 0; i < k; i++)
        v[i] -= y[i];
    prescribed_correct(p, v, log(prescribed_level(p, src[n + 1])), dz);
    dst[n] = prescribed_xi(p, src[n]);
    dst[n + 1] = prescribed_xi(p, src[n + 1]); /* the gain-level state, at least the floor */
    if (p->floor_level > dst[n + 1])
        dst[n + 1] = p->floor_level;
    matvec3(p->M, n, z, n, u, p->m, v, k, dst);
    for (int i = 0; i < n; i++) {
        const double *a = p->F + (size_t)i * n;
        double s = 0.0;
        for (int j = 0; j < n; j++)
            s += a[j] * dz[j];
        dst[i] += s;
    }
    return all_finite(dst, n + 2) ? FHOBS_OK : FHOBS_NONFINITE;
}
