/* pmctl compiled NC core (see ncore.h). Mirrors pmctl/motion/nc.py operation by operation, so
 * the two agree to rounding: the Python code is the readable reference and the test oracle. */
#include "ncore.h"

#include <math.h>
#include <string.h>

int nc_setup(nc_const *c, const double *f, int n)
{
    int k = 0, i, j;
    if (n != NC_C_LEN)
        return -1;
#define TAKE(x) ((x) = f[k++])
    for (i = 0; i < 3; i++) for (j = 0; j < 3; j++) TAKE(c->A[i][j]);
    for (i = 0; i < 3; i++) for (j = 0; j < 3; j++) TAKE(c->Cp[i][j]);
    for (i = 0; i < 3; i++) for (j = 0; j < 3; j++) TAKE(c->N[i][j]);
    for (i = 0; i < 3; i++) TAKE(c->off[i]);
    for (i = 0; i < 3; i++) TAKE(c->tip_p[i]);
    for (i = 0; i < 3; i++) TAKE(c->axis_p[i]);
    TAKE(c->z_table); TAKE(c->tol); TAKE(c->max_iter); TAKE(c->cos_max_tilt); TAKE(c->fz);
    for (i = 0; i < 3; i++) TAKE(c->com[i]);
    TAKE(c->keps);
    TAKE(c->dt);
    for (i = 0; i < 5; i++) TAKE(c->ppm[i]);
    for (i = 0; i < 5; i++) TAKE(c->vmax[i]);
    for (i = 0; i < 5; i++) TAKE(c->amax[i]);
    for (i = 0; i < 5; i++) TAKE(c->adt[i]);
    for (i = 0; i < 5; i++) TAKE(c->lower[i]);
    for (i = 0; i < 5; i++) TAKE(c->upper[i]);
    TAKE(c->cos_theta2_max); TAKE(c->kv); TAKE(c->damping); TAKE(c->sv_threshold); TAKE(c->w);
    for (i = 0; i < 3; i++) TAKE(c->k_theta[i]);
    for (i = 0; i < 3; i++) TAKE(c->dpu[i]);
    TAKE(c->max_pulses); TAKE(c->ferror); TAKE(c->min_ferror); TAKE(c->max_path_error);
    TAKE(c->static_comp); TAKE(c->kth_on);
    for (i = 0; i < 3; i++) TAKE(c->leak[i]);
    for (i = 0; i < 3; i++) TAKE(c->inv_w2[i]);
    for (i = 0; i < 3; i++) TAKE(c->acc_lp[i]);
    TAKE(c->defl_ff); TAKE(c->kth_modal);
    TAKE(c->off_max); TAKE(c->off_step);
    for (i = 0; i < 5; i++) TAKE(c->rest_band[i]);
#undef TAKE
    c->comp = NULL;
    return k == NC_C_LEN ? 0 : -1;
}

int nc_setup_comp(nc_const *c, const double *t, int n)
{
    int a, i;
    c->comp = NULL;
    if (t == NULL)
        return 0;
    if (n < 20)
        return -1;
    for (a = 0; a < 5; a++) {
        double bl = t[4 * a], rate = t[4 * a + 1], np_ = t[4 * a + 2], off = t[4 * a + 3];
        int m, o;
        if (!(bl >= 0.0 && isfinite(bl) && rate > 0.0 && isfinite(rate)))
            return -1;
        if (!(np_ >= 0.0 && np_ <= 1e6 && np_ == floor(np_) && np_ != 1.0 && off >= 20.0 && off <= n &&
              off == floor(off)))
            return -1;
        m = (int)np_;
        o = (int)off;
        if (o + 3 * m > n)
            return -1;
        for (i = 0; i < 3 * m; i++)
            if (!isfinite(t[o + i]))
                return -1;
        for (i = 1; i < m; i++)
            if (!(t[o + i] > t[o + i - 1]))
                return -1;
    }
    c->comp = t;
    return 0;
}

/* ------------------------------------------------------------------ compensation */

/* Linear interpolation in the strictly increasing P (n >= 2), end values beyond the ends
 * (compensation._interp: bisect_right, then the same formula). */
static double comp_interp(const double *P, const double *Y, int n, double x)
{
    int lo = 0, hi = n, k;
    if (!(x > P[0]))
        return Y[0];
    if (!(x < P[n - 1]))
        return Y[n - 1];
    while (lo < hi) {
        int mid = (lo + hi) / 2;
        if (x < P[mid])
            hi = mid;
        else
            lo = mid + 1;
    }
    k = lo - 1;
    return Y[k] + (x - P[k]) * ((Y[k + 1] - Y[k]) / (P[k + 1] - P[k]));
}

/* compensation.comp_tick: x motor positions, prev last commanded rates, d0/b0 the last direction
 * and backlash term; writes this tick's correction cc, direction d and backlash term b. */
static void comp_tick(const nc_const *c, const double x[5], const double prev[5], const double d0[5],
                      const double b0[5], double cc[5], double d[5], double b[5])
{
    const double *t = c->comp;
    int i;
    for (i = 0; i < 5; i++) {
        double di = d0[i], v = prev[i], bl = t[4 * i], step = t[4 * i + 1] * c->dt, tgt, bi, sc = 0.0;
        int m = (int)t[4 * i + 2];
        const double *P = t + (int)t[4 * i + 3];
        if (v > NC_COMP_STILL)
            di = 1.0;
        else if (v < -NC_COMP_STILL)
            di = -1.0;
        tgt = -0.5 * bl * di;
        bi = b0[i];
        if (tgt - bi > step)
            bi = bi + step;
        else if (bi - tgt > step)
            bi = bi - step;
        else
            bi = tgt;
        if (m > 0) {
            if (di > 0)
                sc = comp_interp(P, P + m, m, x[i]);
            else if (di < 0)
                sc = comp_interp(P, P + 2 * m, m, x[i]);
            else
                sc = 0.5 * (comp_interp(P, P + m, m, x[i]) + comp_interp(P, P + 2 * m, m, x[i]));
        }
        cc[i] = bi + sc;
        d[i] = di;
        b[i] = bi;
    }
}

/* ------------------------------------------------------------------ small linear algebra */

/* Rotation matrix of the rotation vector w (kinematics.expm_so3, model_fk._rodrigues_l). */
static void rodrigues(double wx, double wy, double wz, double E[9])
{
    double th2 = wx * wx + wy * wy + wz * wz, a, b;
    if (th2 < 1e-16) {
        a = 1.0 - th2 / 6.0;
        b = 0.5 - th2 / 24.0;
    } else {
        double th = sqrt(th2);
        a = sin(th) / th;
        b = (1.0 - cos(th)) / th2;
    }
    E[0] = 1.0 - b * (wy * wy + wz * wz); E[1] = -a * wz + b * wx * wy;      E[2] = a * wy + b * wx * wz;
    E[3] = a * wz + b * wx * wy;          E[4] = 1.0 - b * (wx * wx + wz * wz); E[5] = -a * wx + b * wy * wz;
    E[6] = -a * wy + b * wx * wz;         E[7] = a * wx + b * wy * wz;      E[8] = 1.0 - b * (wx * wx + wy * wy);
}

/* R <- E R (3x3, row-major) */
static void rotate(const double E[9], double R[9])
{
    double o[9];
    int r, c;
    for (r = 0; r < 3; r++)
        for (c = 0; c < 3; c++)
            o[3 * r + c] = E[3 * r] * R[c] + E[3 * r + 1] * R[3 + c] + E[3 * r + 2] * R[6 + c];
    memcpy(R, o, sizeof o);
}

/* Solve M X = B in place (M 6x6, B 6xnr, row-major, nr <= 4) by LU with partial pivoting
 * (LAPACK dgesv's scheme). Returns -1 on an exactly zero pivot (dgesv's info > 0). */
static int solve6(double M[36], double *B, int nr)
{
    int k, i, j, p;
    for (k = 0; k < 6; k++) {
        double mx = fabs(M[6 * k + k]);
        p = k;
        for (i = k + 1; i < 6; i++)
            if (fabs(M[6 * i + k]) > mx) {
                mx = fabs(M[6 * i + k]);
                p = i;
            }
        if (M[6 * p + k] == 0.0)
            return -1;
        if (p != k) {
            for (j = 0; j < 6; j++) {
                double t = M[6 * k + j]; M[6 * k + j] = M[6 * p + j]; M[6 * p + j] = t;
            }
            for (j = 0; j < nr; j++) {
                double t = B[nr * k + j]; B[nr * k + j] = B[nr * p + j]; B[nr * p + j] = t;
            }
        }
        for (i = k + 1; i < 6; i++) {
            double l = M[6 * i + k] / M[6 * k + k];
            if (l == 0.0)
                continue;
            for (j = k + 1; j < 6; j++)
                M[6 * i + j] -= l * M[6 * k + j];
            for (j = 0; j < nr; j++)
                B[nr * i + j] -= l * B[nr * k + j];
        }
    }
    for (k = 5; k >= 0; k--)
        for (j = 0; j < nr; j++) {
            double s = B[nr * k + j];
            for (i = k + 1; i < 6; i++)
                s -= M[6 * k + i] * B[nr * i + j];
            B[nr * k + j] = s / M[6 * k + k];
        }
    return 0;
}

/* out = V diag(s / (s^2 + lam^2)) U^T x for the 6x5 matrix J (damped SVD pseudo-inverse, nc.
 * _damped_pinv_apply), by a one-sided Jacobi SVD: rotate column pairs of J until orthogonal (the
 * columns are then s_j u_j), accumulating V. lam^2 fades in below the smallest singular value
 * sv_threshold. Returns -1 if the sweeps do not converge. */
/* out = V diag(1 / (s2 + lam2)) (A^T x), A's columns s_j u_j after the Jacobi sweeps */
static void apply_decomposition(const double A[30], const double V[25], const double s2[5], double lam2,
                                const double x[6], double out[5])
{
    int p, i;
    for (i = 0; i < 5; i++)
        out[i] = 0.0;
    for (p = 0; p < 5; p++) {
        double ux = 0.0, g;
        for (i = 0; i < 6; i++)
            ux += A[5 * i + p] * x[i];
        g = ux / (s2[p] + lam2);
        for (i = 0; i < 5; i++)
            out[i] += V[5 * i + p] * g;
    }
}

static int damped_pinv_apply(double A[30], const double x[6], double damping, double eps, double out[5],
                             const double *x2, double *out2)
{
    double V[25] = {0}, s2[5], smin2, lam2, worst = INFINITY;
    int sweep, p, q, i, rotated = 1;
    for (i = 0; i < 5; i++)
        V[6 * i] = 1.0;     /* V[i][i], 5x5 row-major: index 5 i + i = 6 i */
    for (sweep = 0; sweep < 60 && rotated; sweep++) {
        rotated = 0;
        worst = 0.0;
        for (p = 0; p < 4; p++)
            for (q = p + 1; q < 5; q++) {
                double al = 0.0, be = 0.0, ga = 0.0, ze, t, cs, sn;
                for (i = 0; i < 6; i++) {
                    double ap = A[5 * i + p], aq = A[5 * i + q];
                    al += ap * ap;
                    be += aq * aq;
                    ga += ap * aq;
                }
                if (ga == 0.0 || fabs(ga) <= 1e-15 * sqrt(al * be))
                    continue;
                if (fabs(ga) > worst * sqrt(al * be))
                    worst = fabs(ga) / sqrt(al * be);
                rotated = 1;
                ze = (be - al) / (2.0 * ga);
                t = (ze >= 0.0 ? 1.0 : -1.0) / (fabs(ze) + sqrt(1.0 + ze * ze));
                cs = 1.0 / sqrt(1.0 + t * t);
                sn = cs * t;
                for (i = 0; i < 6; i++) {
                    double ap = A[5 * i + p], aq = A[5 * i + q];
                    A[5 * i + p] = cs * ap - sn * aq;
                    A[5 * i + q] = sn * ap + cs * aq;
                }
                for (i = 0; i < 5; i++) {
                    double vp = V[5 * i + p], vq = V[5 * i + q];
                    V[5 * i + p] = cs * vp - sn * vq;
                    V[5 * i + q] = sn * vp + cs * vq;
                }
            }
    }
    if (rotated && !(worst <= 1e-12))    /* rounding may keep a pair just above 1e-15: accept 1e-12 */
        return -1;
    smin2 = INFINITY;
    for (p = 0; p < 5; p++) {
        double a = 0.0;
        for (i = 0; i < 6; i++)
            a += A[5 * i + p] * A[5 * i + p];
        s2[p] = a;
        if (a < smin2)
            smin2 = a;
    }
    {
        double smin = sqrt(smin2), r = smin / eps;
        lam2 = smin >= eps ? 0.0 : damping * damping * (1.0 - r * r);
    }
    apply_decomposition(A, V, s2, lam2, x, out);
    if (x2)             /* a second right-hand side through the same decomposition */
        apply_decomposition(A, V, s2, lam2, x2, out2);
    return 0;
}

/* ------------------------------------------------------------------ model FK */

/* Loop equations at (P, R): f (6), rotated platform joints rc, chain vectors d, lengths ln. */
static double residual(const nc_const *c, const double *P, const double *R, const double *L,
                       double f[6], double rc[9], double d[9], double ln[3])
{
    int i;
    double res;
    for (i = 0; i < 3; i++) {
        double cx = c->Cp[i][0], cy = c->Cp[i][1], cz = c->Cp[i][2];
        double rx = R[0] * cx + R[1] * cy + R[2] * cz;
        double ry = R[3] * cx + R[4] * cy + R[5] * cz;
        double rz = R[6] * cx + R[7] * cy + R[8] * cz;
        double dx = rx + P[0] - c->A[i][0], dy = ry + P[1] - c->A[i][1], dz = rz + P[2] - c->A[i][2];
        double l = sqrt(dx * dx + dy * dy + dz * dz);
        f[i] = l - L[i] - c->off[i];
        f[3 + i] = dx * c->N[i][0] + dy * c->N[i][1] + dz * c->N[i][2];
        rc[3 * i] = rx; rc[3 * i + 1] = ry; rc[3 * i + 2] = rz;
        d[3 * i] = dx; d[3 * i + 1] = dy; d[3 * i + 2] = dz;
        ln[i] = l;
    }
    /* max(abs(x) for x in f), with Python's rule: a later item replaces the maximum only if greater */
    res = fabs(f[0]);
    for (i = 1; i < 6; i++)
        if (fabs(f[i]) > res)
            res = fabs(f[i]);
    return res;
}

/* Constraint Jacobian d(loop equations)/d(P, w), 6x6 row-major. */
static void linearise(const nc_const *c, const double rc[9], const double d[9], const double ln[3], double M[36])
{
    int i;
    for (i = 0; i < 3; i++) {
        double rx = rc[3 * i], ry = rc[3 * i + 1], rz = rc[3 * i + 2];
        double ux = d[3 * i] / ln[i], uy = d[3 * i + 1] / ln[i], uz = d[3 * i + 2] / ln[i];
        double nx = c->N[i][0], ny = c->N[i][1], nz = c->N[i][2];
        double *a = M + 6 * i, *b = M + 6 * (3 + i);
        a[0] = ux; a[1] = uy; a[2] = uz;
        a[3] = ry * uz - rz * uy; a[4] = rz * ux - rx * uz; a[5] = rx * uy - ry * ux;
        b[0] = nx; b[1] = ny; b[2] = nz;
        b[3] = ry * nz - rz * ny; b[4] = rz * nx - rx * nz; b[5] = rx * ny - ry * nx;
    }
}

int nc_fk(const nc_const *c, const double *q, double *Pio, double *Rio, const double *dL, const double *T0,
          double *tip, double *axis, double *J, double *T, int64_t *iters, double *ev)
{
    double P[3], R[9], f[6], rc[9], d[9], ln[3], M[36], B[24], res, rt[3], ax[3];
    const double *L = q;
    int it = 0, haveT = 0, i, j, r;
    memcpy(P, Pio, sizeof P);
    memcpy(R, Rio, sizeof R);
    if (dL != NULL && (dL[0] != 0.0 || dL[1] != 0.0 || dL[2] != 0.0)) {
        double st[6], E[9];
        for (r = 0; r < 6; r++)
            st[r] = T0[3 * r] * dL[0] + T0[3 * r + 1] * dL[1] + T0[3 * r + 2] * dL[2];
        P[0] += st[0]; P[1] += st[1]; P[2] += st[2];
        rodrigues(st[3], st[4], st[5], E);
        rotate(E, R);
    }
    res = residual(c, P, R, L, f, rc, d, ln);
    while (!(res < c->tol)) {
        double step[6], sp, sr, sc, E[9];
        if (it >= c->max_iter || !isfinite(res)) {
            ev[0] = L[0]; ev[1] = L[1]; ev[2] = L[2]; ev[3] = res; ev[4] = it;
            return NC_EV_FK_NOCONV;
        }
        linearise(c, rc, d, ln, M);
        memset(B, 0, sizeof B);
        for (i = 0; i < 6; i++)
            B[4 * i] = f[i];
        B[1] = B[4 + 2] = B[8 + 3] = 1.0;
        if (solve6(M, B, 4))
            return NC_EV_FK_SINGULAR;
        if (!haveT) {
            for (i = 0; i < 6; i++)
                for (j = 0; j < 3; j++)
                    T[3 * i + j] = B[4 * i + 1 + j];
            haveT = 1;
        }
        for (i = 0; i < 6; i++)
            step[i] = -B[4 * i];
        sp = sqrt(step[0] * step[0] + step[1] * step[1] + step[2] * step[2]);
        sr = sqrt(step[3] * step[3] + step[4] * step[4] + step[5] * step[5]);
        sc = 1.0;
        {
            double a = 50.0 / (sp > 1e-300 ? sp : 1e-300), b = 0.2 / (sr > 1e-300 ? sr : 1e-300);
            if (a < sc) sc = a;
            if (b < sc) sc = b;
        }
        P[0] = P[0] + sc * step[0]; P[1] = P[1] + sc * step[1]; P[2] = P[2] + sc * step[2];
        rodrigues(sc * step[3], sc * step[4], sc * step[5], E);
        rotate(E, R);
        res = residual(c, P, R, L, f, rc, d, ln);
        it++;
    }
    if (!(P[2] > 0.0 && R[8] > c->cos_max_tilt)) {
        ev[0] = L[0]; ev[1] = L[1]; ev[2] = L[2];
        return NC_EV_FK_BRANCH;
    }
    if (!haveT) {           /* already converged: linearise at the pose */
        linearise(c, rc, d, ln, M);
        memset(B, 0, 18 * sizeof(double));
        B[0] = B[3 + 1] = B[6 + 2] = 1.0;
        if (solve6(M, B, 3))
            return NC_EV_FK_SINGULAR;
        memcpy(T, B, 18 * sizeof(double));
    }
    *iters = it;
    memcpy(Pio, P, sizeof P);
    memcpy(Rio, R, sizeof R);
    /* tool pose and the 6x5 tool Jacobian d(tip_W, axis)/dq */
    for (r = 0; r < 3; r++) {
        rt[r] = R[3 * r] * c->tip_p[0] + R[3 * r + 1] * c->tip_p[1] + R[3 * r + 2] * c->tip_p[2];
        ax[r] = R[3 * r] * c->axis_p[0] + R[3 * r + 1] * c->axis_p[1] + R[3 * r + 2] * c->axis_p[2];
    }
    tip[0] = P[0] + rt[0] - q[3];
    tip[1] = P[1] + rt[1] - q[4];
    tip[2] = P[2] + rt[2] - c->z_table;
    axis[0] = ax[0]; axis[1] = ax[1]; axis[2] = ax[2];
    for (i = 0; i < 30; i++)
        J[i] = 0.0;
    for (j = 0; j < 3; j++) {
        double wx = T[9 + j], wy = T[12 + j], wz = T[15 + j];
        J[j] = T[j] + wy * rt[2] - wz * rt[1];
        J[5 + j] = T[3 + j] + wz * rt[0] - wx * rt[2];
        J[10 + j] = T[6 + j] + wx * rt[1] - wy * rt[0];
        J[15 + j] = wy * ax[2] - wz * ax[1];
        J[20 + j] = wz * ax[0] - wx * ax[2];
        J[25 + j] = wx * ax[1] - wy * ax[0];
    }
    J[3] = -1.0;
    J[5 + 4] = -1.0;
    return 0;
}

void nc_static_strain(const nc_const *c, const double *R, const double *T, double *out)
{
    double rc[3], w[6], k = c->keps, fz = c->fz;
    int r, i;
    for (r = 0; r < 3; r++)
        rc[r] = R[3 * r] * c->com[0] + R[3 * r + 1] * c->com[1] + R[3 * r + 2] * c->com[2];
    w[0] = 0.0; w[1] = 0.0; w[2] = fz; w[3] = rc[1] * fz; w[4] = -rc[0] * fz; w[5] = 0.0;
    for (i = 0; i < 3; i++) {
        double s = 0.0;
        for (r = 0; r < 6; r++)
            s += T[3 * r + i] * w[r];
        out[i] = k * s;
    }
}

/* ------------------------------------------------------------------ the tick */

/* nc._limit_rates_l: velocity box by uniform scaling, then the per-tick acceleration box. */
static void limit_rates(const nc_const *c, const double des_in[5], const double prev[5], double out[5])
{
    double des[5], dq[5], m = 0.0;
    int i;
    for (i = 0; i < 5; i++) {
        double r = fabs(des_in[i]) / c->vmax[i];
        if (r > m)
            m = r;
    }
    for (i = 0; i < 5; i++)
        des[i] = m > 1.0 ? des_in[i] / m : des_in[i];
    for (i = 0; i < 5; i++)
        dq[i] = des[i] - prev[i];
    m = 0.0;
    for (i = 0; i < 5; i++) {
        double r = fabs(dq[i]) / c->adt[i];
        if (r > m)
            m = r;
    }
    for (i = 0; i < 5; i++)
        out[i] = m > 1.0 ? prev[i] + dq[i] / m : des[i];
}

/* nc._slew_offset: the applied chain-length offset one tick on toward the input (clipped to
 * +-off_max; a non-finite input holds), at most off_step per tick. */
static void slew_offset(const nc_const *c, double *off, const double *want_in)
{
    int i;
    for (i = 0; i < 3; i++) {
        double w = want_in[i], d;
        if (!isfinite(w))
            w = off[i];
        else if (w > c->off_max)
            w = c->off_max;
        else if (w < -c->off_max)
            w = -c->off_max;
        d = w - off[i];
        if (d > c->off_step)
            off[i] = off[i] + c->off_step;
        else if (d < -c->off_step)
            off[i] = off[i] - c->off_step;
        else
            off[i] = w;
    }
}

static int halt_now(double *s, int64_t *n, int ev)
{
    int i;
    for (i = 0; i < 5; i++) {
        s[NC_S_QDOT + i] = 0.0;
        s[NC_S_ACC + i] = 0.0;
        n[NC_N_PULSES + i] = 0;
    }
    n[NC_N_MODE] = NC_HALTED;
    n[NC_N_EVENT] = ev;
    return ev;
}

int nc_step(const nc_const *c, double *s, int64_t *n, const double *t, const double *enc, const double *strain,
            const double *offset)
{
    double ql[5], prev[5], qd_des[5] = {0, 0, 0, 0, 0}, qdot[5], *ev = s + NC_S_EV;
    double qj[5], cc[5], cd[5], cb[5];
    int64_t mode0 = n[NC_N_MODE], mode = mode0;
    int i, event = NC_EV_NONE, held[5] = {0, 0, 0, 0, 0};

    n[NC_N_EVENT] = NC_EV_NONE;
    if (mode0 == NC_HALTED || mode0 == NC_DONE) {
        for (i = 0; i < 5; i++)
            n[NC_N_PULSES + i] = 0;
        return NC_EV_NONE;
    }
    for (i = 0; i < 5; i++) {
        ql[i] = (double)n[NC_N_COUNTS + i] / c->ppm[i];
        prev[i] = s[NC_S_QDOT + i];
    }
    /* a dead sensor must not blind the supervision */
    for (i = 0; i < 5; i++)
        if (!isfinite(enc[i])) {
            ev[0] = i; ev[1] = enc[i];
            return halt_now(s, n, NC_EV_ENC_NONFINITE);
        }
    for (i = 0; i < 3; i++)
        if (!isfinite(strain[i])) {
            ev[0] = i; ev[1] = strain[i];
            return halt_now(s, n, NC_EV_STRAIN_NONFINITE);
        }
    /* following error (LinuxCNC FERROR scaled with speed, floor MIN_FERROR) */
    for (i = 0; i < 5; i++) {
        double fe = fabs(ql[i] - enc[i]), lim = c->ferror * fabs(prev[i]) / c->vmax[i];
        if (lim < c->min_ferror)
            lim = c->min_ferror;
        if (fe > lim) {
            ev[0] = i; ev[1] = fe; ev[2] = lim; ev[3] = prev[i];
            return halt_now(s, n, NC_EV_FERROR);
        }
    }
    if (c->comp != NULL) {      /* model joints = motor side + correction (pmctl/core/compensation.py) */
        comp_tick(c, ql, prev, s + NC_S_CDIR, s + NC_S_CBL, cc, cd, cb);
        for (i = 0; i < 5; i++)
            qj[i] = ql[i] + cc[i];
    } else {
        memcpy(qj, ql, sizeof ql);
    }
    /* the chain-length offset (slow compensation): slewed in RUN only, subtracted from the model
     * joints, so that the counters follow IK(target) + offset */
    if (offset != NULL && mode0 == NC_RUN)
        slew_offset(c, s + NC_S_OFF, offset);
    for (i = 0; i < 3; i++)
        qj[i] = qj[i] - s[NC_S_OFF + i];
    if (mode == NC_RUN) {
        double P[3], R[9], tip[3], axis[3], J[30], T[18], x[6], e[6], qd[5], w = c->w, kv = c->kv;
        double qf[5], kth_new[12];
        double dLb[3], *dL = NULL, cc, perr;
        int64_t iters = 0;
        int k;
        memcpy(P, s + NC_S_P, sizeof P);
        memcpy(R, s + NC_S_R, sizeof R);
        if (n[NC_N_HAS_QM]) {
            for (i = 0; i < 3; i++)
                dLb[i] = qj[i] - s[NC_S_QM + i];
            dL = dLb;
        }
        k = nc_fk(c, qj, P, R, dL, s + NC_S_T, tip, axis, J, T, &iters, ev);
        if (k)
            return halt_now(s, n, k);
        /* position error; axis error = component of the target axis normal to the model axis */
        cc = t[3] * axis[0] + t[4] * axis[1] + t[5] * axis[2];
        e[0] = t[0] - tip[0]; e[1] = t[1] - tip[1]; e[2] = t[2] - tip[2];
        e[3] = (t[3] - cc * axis[0]) * w; e[4] = (t[4] - cc * axis[1]) * w; e[5] = (t[5] - cc * axis[2]) * w;
        perr = 0.0;
        for (i = 0; i < 6; i++)
            perr += e[i] * e[i];
        perr = sqrt(perr);
        x[0] = kv * e[0] + t[6]; x[1] = kv * e[1] + t[7]; x[2] = kv * e[2] + t[8];
        x[3] = kv * e[3] + t[9] * w; x[4] = kv * e[4] + t[10] * w; x[5] = kv * e[5] + t[11] * w;
        for (i = 15; i < 30; i += 5) {
            J[i] *= w; J[i + 1] *= w; J[i + 2] *= w; J[i + 3] = 0.0; J[i + 4] = 0.0;
        }
        {
            /* the targets' own joint rates too (feed-forward only): the soft-chain K_theta's planned
             * stretch and the rest deadband of a joint standing still */
            double xf[6] = {t[6], t[7], t[8], t[9] * w, t[10] * w, t[11] * w};
            if (damped_pinv_apply(J, x, c->damping, c->sv_threshold, qd, xf, qf))
                return halt_now(s, n, NC_EV_SVD);
        }
        if (c->kth_on != 0.0) {
            double s0[3] = {0.0, 0.0, 0.0};
            if (c->static_comp != 0.0)      /* the gauges also read the weight: keep the dynamic part */
                nc_static_strain(c, R, T, s0);
            for (i = 0; i < 3; i++) {
                double defl = -(strain[i] - s0[i]) * c->dpu[i];      /* theta_m - theta_L, mm */
                if (c->kth_modal != 0.0) {
                    /* soft chain (nc._kth_modal_l): planned stretch off, decoupled offset d */
                    double *ks = s + NC_S_KTH, d = ks[i], a = (qf[i] - ks[3 + i]) / c->dt;
                    double af = ks[9 + i] + c->acc_lp[i] * (a - ks[9 + i]);
                    double o = af * c->inv_w2[i], y = -defl + o, u = c->k_theta[i] * y + kv * d;
                    if (c->defl_ff != 0.0)
                        u = u + (kv * o + (o - ks[6 + i]) / c->dt);
                    qd[i] = qd[i] + u;
                    kth_new[i] = d + c->dt * (c->k_theta[i] * y - c->leak[i] * d);
                    kth_new[3 + i] = qf[i];
                    kth_new[6 + i] = o;
                    kth_new[9 + i] = af;
                } else {
                    qd[i] -= c->k_theta[i] * defl;
                }
            }
            if (c->kth_modal != 0.0)
                memcpy(s + NC_S_KTH, kth_new, sizeof kth_new);
        }
        /* commit the model pose */
        memcpy(s + NC_S_P, P, sizeof P);
        memcpy(s + NC_S_R, R, sizeof R);
        memcpy(s + NC_S_TIP, tip, sizeof tip);
        memcpy(s + NC_S_AXIS, axis, sizeof axis);
        memcpy(s + NC_S_T, T, sizeof T);
        memcpy(s + NC_S_QM, qj, sizeof qj);
        s[NC_S_PERR] = perr;
        n[NC_N_HAS_QM] = 1;
        n[NC_N_ITER] = iters;
        memcpy(qd_des, qd, sizeof qd);
        {
            /* the target at rest (feed-forward exactly zero), or a joint whose own feed-forward is
             * (nearly) zero under the soft-chain K_theta: no correction for a joint whose desired rate is worth at most the
             * deadband's position error (nc.py, rest deadband) */
            int moving = !(t[6] == 0.0 && t[7] == 0.0 && t[8] == 0.0 && t[9] == 0.0 && t[10] == 0.0 && t[11] == 0.0);
            for (i = 0; i < 5; i++)
                if (c->rest_band[i] > 0.0 && fabs(qd_des[i]) <= c->rest_band[i] &&     /* (a band of 0: off) */
                    (!moving || (c->kth_modal != 0.0 && fabs(qf[i]) * c->ppm[i] * c->dt <= NC_REST_FF))) {
                    qd_des[i] = 0.0;
                    held[i] = 1;
                }
        }
        if (perr > c->max_path_error) {
            mode = NC_STOPPING;
            event = NC_EV_PATH_ERROR;
            ev[0] = perr;
        } else if (R[8] < c->cos_theta2_max - 1e-12) {
            mode = NC_STOPPING;
            event = NC_EV_TILT;
            ev[0] = R[8];
        }
    }
    if (mode == NC_STOPPING)
        for (i = 0; i < 5; i++)
            qd_des[i] = 0.0;
    limit_rates(c, qd_des, prev, qdot);
    if (mode == NC_RUN) {
        /* stopping now (uniformly scaled deceleration) must not cross a soft limit */
        double Tb = fabs(qdot[0]) / c->amax[0], dt = c->dt;
        for (i = 1; i < 5; i++)
            if (fabs(qdot[i]) / c->amax[i] > Tb)
                Tb = fabs(qdot[i]) / c->amax[i];
        for (i = 0; i < 5; i++) {
            double v = qdot[i], sd = fabs(v) * (0.5 * Tb + 2.0 * dt), xq = qj[i] + qdot[i] * dt;
            if ((v > 0 && xq + sd > c->upper[i]) || (v < 0 && xq - sd < c->lower[i]) || xq > c->upper[i] ||
                xq < c->lower[i]) {
                double zero[5] = {0, 0, 0, 0, 0};
                mode = NC_STOPPING;
                event = NC_EV_SOFT_LIMIT;
                ev[0] = i; ev[1] = xq; ev[2] = v;
                limit_rates(c, zero, prev, qdot);
                break;
            }
        }
    }
    /* V-F converters (core.vf.vf_tick), threshold one pulse, reached within NC_VF_TIE */
    {
        int any = 0;
        for (i = 0; i < 5; i++) {
            double a = s[NC_S_ACC + i] + qdot[i] * c->ppm[i] * c->dt, m;
            m = trunc(a >= 0.0 ? a / 1.0 + NC_VF_TIE : a / 1.0 - NC_VF_TIE);
            if (m > c->max_pulses)
                m = c->max_pulses;
            else if (m < -c->max_pulses)
                m = -c->max_pulses;
            a = a - m * 1.0;
            if (a > 1.0)
                a = 1.0;
            else if (a < -1.0)
                a = -1.0;
            if (held[i] && mode == NC_RUN && qdot[i] == 0.0)
                a = 0.0;        /* held in the rest deadband: no sub-pulse residue is owed */
            n[NC_N_PULSES + i] = (int64_t)m;
            s[NC_S_ACC + i] = a;
            s[NC_S_QDOT + i] = qdot[i];
            if (qdot[i] != 0.0)
                any = 1;
        }
        if (mode == NC_STOPPING && !any) {
            /* braked to rest: drop the sub-pulse residue (no pulse is owed) and halt */
            mode = NC_HALTED;
            for (i = 0; i < 5; i++)
                s[NC_S_ACC + i] = 0.0;
        }
    }
    for (i = 0; i < 5; i++)
        n[NC_N_COUNTS + i] += n[NC_N_PULSES + i];
    if (c->comp != NULL) {
        memcpy(s + NC_S_CDIR, cd, sizeof cd);
        memcpy(s + NC_S_CBL, cb, sizeof cb);
        memcpy(s + NC_S_COMP, cc, sizeof cc);
    }
    n[NC_N_MODE] = mode;
    n[NC_N_EVENT] = event;
    return event;
}
