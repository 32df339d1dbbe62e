/* The path follower's tick (see follow.h); every line mirrors timescale.py. Compile with
 * -ffp-contract=off (no fused multiply-add): the results must equal Python's bit for bit. */
#include <math.h>
#include <stddef.h>

#include "follow.h"

#if defined(__GNUC__) || defined(__clang__)
#define LOAD_ACQ(p) __atomic_load_n((p), __ATOMIC_ACQUIRE)
#define STORE_REL(p, v) __atomic_store_n((p), (v), __ATOMIC_RELEASE)
#else
#define LOAD_ACQ(p) (*(volatile int64_t *)(p))
#define STORE_REL(p, v) (*(volatile int64_t *)(p) = (v))
#endif

int fl_setup(fl_const *c, const double *v, int n, int width)
{
    int j, cols[5];
    if (n != FLC_LEN || width < 6)
        return -1;
    c->dt = v[FLC_DT];
    c->k = v[FLC_K];
    for (j = 0; j < 5; j++)
        c->amax[j] = v[FLC_AMAX + j];
    c->col_cap = cols[0] = (int)v[FLC_COL_CAP];
    c->col_line = cols[1] = (int)v[FLC_COL_LINE];
    c->col_flags = cols[2] = (int)v[FLC_COL_FLAGS];
    c->col_qt = cols[3] = (int)v[FLC_COL_QT];
    c->col_qtt = cols[4] = (int)v[FLC_COL_QTT];
    c->flag_rapid = (int)v[FLC_FLAG_RAPID];
    c->flag_end = (int)v[FLC_FLAG_END];
    for (j = 0; j < 5; j++)
        if (cols[j] < 0 || cols[j] + (j >= 3 ? 5 : 1) > width)
            return -1;
    if (!(c->dt > 0.0) || !(c->k > 0.0))
        return -1;
    return 0;
}

/* ---- the sample source (pmctl.motion.ring.Ring's consumer side) */

static int64_t src_count(const fl_src *s)
{
    return LOAD_ACQ(&s->ctr[0]) - s->ctr[1];
}

static const double *src_row(const fl_src *s, int64_t i)
{
    return s->data + ((s->ctr[1] + i) % s->capacity) * (int64_t)s->width;
}

static void src_advance(const fl_src *s, int64_t n)
{
    int64_t cnt = src_count(s);
    if (n > cnt)
        n = cnt;
    if (n > 0)
        STORE_REL(&s->ctr[1], s->ctr[1] + n);
}

static void src_clear(const fl_src *s)
{
    STORE_REL(&s->ctr[1], LOAD_ACQ(&s->ctr[0]));
}

/* ---- the follower */

static void copy6(double *dst, const double *a)
{
    int m;
    for (m = 0; m < 6; m++)
        dst[m] = a[m];
}

/* PathFollower._pose: the pose at row i + f (axis renormalised) */
static void pose_at(const fl_src *s, int64_t i, double f, double *p)
{
    const double *a = src_row(s, i), *b;
    double nrm;
    int m;
    if (f <= 0.0) {
        copy6(p, a);
        return;
    }
    b = src_row(s, i + 1);
    for (m = 0; m < 6; m++)
        p[m] = a[m] + f * (b[m] - a[m]);
    nrm = sqrt(p[3] * p[3] + p[4] * p[4] + p[5] * p[5]);
    p[3] /= nrm;
    p[4] /= nrm;
    p[5] /= nrm;
}

static int flags_of(const fl_const *c, const double *r)
{
    return (int)r[c->col_flags];
}

double fl_sigma_step(const fl_const *c, double *st, double goal, const double *qt, const double *qtt)
{
    const double dt = c->dt, A = st[FL_ACCEL], J = st[FL_JERK];
    double s = st[FL_SIGMA], ds = st[FL_DSIGMA];
    double e = goal - s, v, x, dds, lo = -INFINITY, hi = INFINITY, s2;
    int j;
    if (fabs(e) < 1e-9 && fabs(ds) < J * dt) {
        st[FL_SIGMA] = (0.0 > goal) ? 0.0 : goal;
        st[FL_DSIGMA] = 0.0;
        return st[FL_SIGMA];
    }
    /* the rate that still lets sigma' come back to 0 at the goal under the jerk limit */
    v = sqrt(2.0 * J * 0.8 * fabs(e));
    if (A < v)
        v = A;
    x = 0.5 * fabs(e) / dt;
    if (x < v)
        v = x;
    v = e > 0 ? v : -v;
    dds = (v - ds) / dt;
    if (dds > J)
        dds = J;
    else if (dds < -J)
        dds = -J;
    ds = ds + dds * dt;
    if (ds > A)
        ds = A;
    else if (ds < -A)
        ds = -A;
    /* joint accelerations: |ds qt_j + s^2 qtt_j| <= amax_j  ->  an interval for ds */
    s2 = s * s;
    for (j = 0; j < 5; j++) {
        double t = qt[j];
        if (fabs(t) > 1e-9) {
            double b1 = (c->amax[j] - s2 * qtt[j]) / t;
            double b2 = (-c->amax[j] - s2 * qtt[j]) / t;
            if (b1 > b2) {
                double w = b1;
                b1 = b2;
                b2 = w;
            }
            if (b1 > lo)
                lo = b1;
            if (b2 < hi)
                hi = b2;
        }
    }
    /* never forced up, never kept from slowing towards the goal at a quarter of the rate limit */
    if (lo <= hi) {
        if (ds > hi) {
            ds = hi;
        } else if (ds < lo) {
            double m = (-0.25 * A > ds) ? -0.25 * A : ds;
            ds = (m < lo) ? m : lo;
        }
    }
    if (ds > A)
        ds = A;
    else if (ds < -A)
        ds = -A;
    if (e >= 0.0 && s + ds * dt > goal) {    /* arrived: land on the goal, never past it */
        st[FL_SIGMA] = goal;
        st[FL_DSIGMA] = 0.0;
        return goal;
    }
    s = s + ds * dt;
    if (s <= 0.0) {
        s = 0.0;
        ds = 0.0;
    }
    st[FL_SIGMA] = s;
    st[FL_DSIGMA] = ds;
    return s;
}

void fl_clear(const fl_const *c, double *st, const fl_src *src)
{
    int64_t n = src_count(src);
    (void)c;
    if (n) {
        if (n > 1 || st[FL_FRAC] == 0.0)
            pose_at(src, 0, st[FL_FRAC], st + FL_REST);
        else
            copy6(st + FL_REST, src_row(src, 0));
        st[FL_HAS_REST] = 1.0;
    }
    src_clear(src);
    st[FL_FRAC] = 0.0;
    st[FL_SIGMA] = st[FL_DSIGMA] = 0.0;
    st[FL_STATE] = FL_IDLE;
    st[FL_AT_END] = 0.0;    /* the end it rested on is gone: the next job's end is a new one */
}

static void target(double *tg, const double *pose, const double *ff)
{
    int m;
    for (m = 0; m < 6; m++) {
        tg[m] = pose[m];
        tg[6 + m] = ff ? ff[m] : 0.0;
    }
}

void fl_next(const fl_const *c, double *st, const fl_src *src, double *tg)
{
    static const double dflt[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 1.0};
    const int END = c->flag_end;
    const double hold = st[FL_HOLD];
    int64_t n = src_count(src), adv, i, stop;
    const double *r0, *r1, *last;
    double pose[6], nxt[6], ff[6], qt[5], qtt[5];
    double f, f2, goal, cap, sigma, inv;
    int flags, starving = 0, moving, j, m;

    if (n == 0) {
        st[FL_STATE] = hold ? FL_HELD : FL_IDLE;
        st[FL_SIGMA] = st[FL_DSIGMA] = 0.0;
        target(tg, st[FL_HAS_REST] != 0.0 ? st + FL_REST : dflt, NULL);
        return;
    }
    r0 = src_row(src, 0);
    flags = flags_of(c, r0);
    st[FL_LINE] = (double)(int64_t)r0[c->col_line];
    f = st[FL_FRAC];
    if ((flags & END) && f == 0.0) {
        /* resting on a job's last sample: pass it on to the next job, if one is queued */
        if (n == 1) {
            if (st[FL_AT_END] == 0.0) {
                st[FL_AT_END] = 1.0;
                st[FL_ENDED] += 1.0;
            }
            copy6(st + FL_REST, r0);
            st[FL_HAS_REST] = 1.0;
            st[FL_STATE] = hold ? FL_HELD : FL_IDLE;
            target(tg, r0, NULL);
            return;
        }
        if (st[FL_AT_END] == 0.0)
            st[FL_ENDED] += 1.0;
        st[FL_AT_END] = 0.0;
        src_advance(src, 1);
        n -= 1;
        r0 = src_row(src, 0);
        flags = flags_of(c, r0);
    }
    st[FL_AT_END] = 0.0;
    if (n > 1)
        pose_at(src, 0, f, pose);
    else
        copy6(pose, r0);
    /* ---- sigma's goal */
    goal = hold ? 0.0 : ((flags & c->flag_rapid) ? st[FL_RAPID_OV] : st[FL_FEED_OV]);
    r1 = n > 1 ? src_row(src, 1) : r0;
    cap = (r1[c->col_cap] < r0[c->col_cap]) ? r1[c->col_cap] : r0[c->col_cap];
    if (goal > cap)
        goal = cap;
    last = src_row(src, n - 1);
    if (!(flags_of(c, last) & END)) {
        double remain = (double)(n - 1) - f, g;
        remain = (remain > 0.0 ? remain : 0.0) * c->dt / c->k;      /* tau left in the queue, s */
        g = sqrt(2.0 * 0.5 * st[FL_ACCEL] * remain) * 0.9;
        if (g < goal) {
            goal = g;
            starving = 1;
        }
    }
    for (j = 0; j < 5; j++) {
        qt[j] = r0[c->col_qt + j];
        qtt[j] = r0[c->col_qtt + j];
    }
    if (st[FL_SIGMA] == 0.0 && st[FL_STATE] == FL_IDLE && goal > 0.0) {
        int ok = 1;
        for (j = 0; j < 5 && ok; j++)
            ok = fabs(qt[j]) * goal <= 0.5 * c->amax[j] * c->dt;
        if (ok)
            st[FL_SIGMA] = goal;    /* leaving a rest point: a velocity step within one tick's accel */
    }
    sigma = fl_sigma_step(c, st, goal, qt, qtt);
    /* ---- advance the path clock to the next tick's target */
    f2 = f + sigma * c->k;
    adv = (int64_t)f2;
    /* never step over a job's end (at rest) short of the queue's last sample: stop on it, so it is
       counted. Row 0 is one only for a job of one sample right after the end passed above. */
    stop = (flags & END) ? 0 : -1;
    for (i = 1; stop < 0 && i <= adv && i < n - 1; i++) {
        if (flags_of(c, src_row(src, i)) & END)
            stop = i;
    }
    if (stop >= 0 && stop < n - 1) {
        adv = stop;
        f2 = 0.0;
    } else if (adv >= n - 1) {      /* the queue ends here (a job end or starvation) */
        adv = n - 1;
        f2 = 0.0;
        if (!(flags_of(c, last) & END) && sigma > 0)
            st[FL_REASON] = FL_R_DRY;
        st[FL_SIGMA] = st[FL_DSIGMA] = 0.0;
    } else {
        f2 -= (double)adv;
    }
    st[FL_S_TOTAL] += ((double)adv + f2) - f;
    if (adv)
        src_advance(src, adv);
    st[FL_FRAC] = f2;
    if (src_count(src) > 1)
        pose_at(src, 0, f2, nxt);
    else
        copy6(nxt, src_row(src, 0));
    inv = 1.0 / c->dt;
    moving = st[FL_SIGMA] > 0.0;
    for (m = 0; m < 6; m++) {
        ff[m] = (nxt[m] - pose[m]) * inv;
        if (ff[m] != 0.0)
            moving = 1;
    }
    if (moving) {
        st[FL_STATE] = hold ? FL_HOLDING : (starving ? FL_STARVED : FL_MOVING);
        if (starving)
            st[FL_REASON] = FL_R_STARVED;
    } else {
        st[FL_STATE] = hold ? FL_HELD : (starving ? FL_STARVED : FL_IDLE);
    }
    copy6(st + FL_REST, nxt);
    st[FL_HAS_REST] = 1.0;
    target(tg, pose, ff);
}
