/* The loop's path follower (pmctl.motion.timescale.PathFollower with its TimeScaler) in portable
 * C99: one call per tick advances the path clock at sigma along the queued sample rows and writes
 * the NC target. The arithmetic is timescale.py's, in the same order; timescale.py stays the
 * readable reference and the test oracle (tests/motion/test_follow.py runs both on the same inputs).
 *
 * All state lives in a caller-owned float64 buffer (FL_* below), the rows in the caller's sample
 * source: a single-producer single-consumer ring (pmctl.motion.ring: two int64 counters, rows
 * written and rows consumed, and capacity x width float64 rows). Nothing is allocated per tick. */
#ifndef PMCTL_FOLLOW_H
#define PMCTL_FOLLOW_H

#include <stdint.h>

/* the state buffer */
enum {
    FL_SIGMA, FL_DSIGMA, FL_FEED_OV, FL_RAPID_OV, FL_HOLD, FL_ACCEL, FL_JERK,
    FL_FRAC, FL_LINE, FL_STATE, FL_S_TOTAL, FL_ENDED, FL_AT_END, FL_HAS_REST,
    FL_REST,                      /* 6: the pose when nothing is queued (tip, axis) */
    FL_REASON = FL_REST + 6,      /* FL_R_* */
    FL_LEN
};

/* the constant block (timescale.CompiledFollower builds it) */
enum {
    FLC_DT, FLC_K, FLC_AMAX,      /* AMAX: 5, the joint accelerations sigma may use */
    FLC_COL_CAP = FLC_AMAX + 5, FLC_COL_LINE, FLC_COL_FLAGS, FLC_COL_QT, FLC_COL_QTT,
    FLC_FLAG_RAPID, FLC_FLAG_END,
    FLC_LEN
};

/* follower states (timescale.IDLE ...) and reasons */
enum { FL_IDLE, FL_MOVING, FL_HOLDING, FL_HELD, FL_STARVED };
enum { FL_R_NONE, FL_R_DRY, FL_R_STARVED };

typedef struct {
    double dt, k, amax[5];
    int col_cap, col_line, col_flags, col_qt, col_qtt;
    int flag_rapid, flag_end;
} fl_const;

typedef struct {
    int64_t *ctr;       /* [0] rows written (the producer's), [1] rows consumed (ours) */
    const double *data; /* capacity x width */
    int64_t capacity;
    int width;
} fl_src;

/* 0, or -1 for a bad constant block (n values, columns outside width) */
int fl_setup(fl_const *c, const double *v, int n, int width);

/* One tick: the target (tip, axis, tip rate, axis rate) into tg[12]. */
void fl_next(const fl_const *c, double *st, const fl_src *src, double *tg);

/* Drop every queued sample, keeping the current pose as the rest pose. */
void fl_clear(const fl_const *c, double *st, const fl_src *src);

/* TimeScaler.step: sigma one tick towards goal; returns the new sigma. */
double fl_sigma_step(const fl_const *c, double *st, double goal, const double *qt, const double *qtt);

#endif
