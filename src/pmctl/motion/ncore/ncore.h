/* pmctl compiled NC core: one tick of the closed-loop NC (model FK by Newton with the predictor
 * warm start, tool Jacobian, damped pseudo-inverse, the rest deadband, rate/acceleration limits,
 * soft-limit and following-error supervision, the K_theta strain term, V-F converters), portable C99.
 *
 * The readable reference is pmctl/motion/nc.py (nc_step) with pmctl/core/model_fk.py (ModelFK); this file does the same
 * arithmetic in the same order. No allocation: the caller owns every buffer (constants, state,
 * scratch), so the state can live anywhere, e.g. in shared memory.
 *
 * Units: mm, s, rad; joint rates in mm/s; V-F input in pulses/s, threshold one pulse. */
#ifndef PMCTL_NCORE_H
#define PMCTL_NCORE_H

#include <stdint.h>

/* modes (nc.RUN ... nc.DONE) */
#define NC_RUN 0
#define NC_STOPPING 1
#define NC_HALTED 2
#define NC_DONE 3

/* events: why the mode changed this tick (the caller turns them into reason texts) */
#define NC_EV_NONE 0
#define NC_EV_ENC_NONFINITE 1      /* args: axis, value */
#define NC_EV_STRAIN_NONFINITE 2   /* args: gauge, value */
#define NC_EV_FERROR 3             /* args: axis, |error|, limit, rate */
#define NC_EV_FK_NOCONV 4          /* args: L1, L2, L3, residual, iterations */
#define NC_EV_FK_BRANCH 5          /* args: L1, L2, L3 */
#define NC_EV_FK_SINGULAR 6
#define NC_EV_SVD 7
#define NC_EV_PATH_ERROR 8         /* args: path error */
#define NC_EV_TILT 9               /* args: R[2][2] */
#define NC_EV_SOFT_LIMIT 10        /* args: axis, position, rate */

/* double state buffer layout */
#define NC_S_ACC 0      /* 5: V-F accumulators, pulses */
#define NC_S_QDOT 5     /* 5: last commanded joint rate, mm/s */
#define NC_S_P 10       /* 3: model platform position */
#define NC_S_R 13       /* 9: model platform rotation, row-major */
#define NC_S_TIP 22     /* 3: model tool tip in W */
#define NC_S_AXIS 25    /* 3: model tool axis */
#define NC_S_PERR 28    /* 1: path error of the last solve, mm (weighted) */
#define NC_S_QM 29      /* 5: joints of the model pose */
#define NC_S_T 34       /* 18: (6, 3) twist map d(P, w)/dL at the model pose, row-major */
#define NC_S_EV 52      /* 6: event arguments */
#define NC_S_CDIR 58    /* 5: compensation: direction per axis (+1, -1, 0 before the first move) */
#define NC_S_CBL 63     /* 5: compensation: backlash term, mm */
#define NC_S_COMP 68    /* 5: compensation of the last tick, mm (model joint - motor position) */
#define NC_S_KTH 73     /* 12: soft-chain K_theta: offset d (3, mm), last feed-forward chain rate (3, mm/s),
                         *    last planned stretch a*|w^2 (3, mm), low-passed a* (3) (nc.NCState.kth) */
#define NC_S_OFF 85     /* 3: chain-length offset applied, mm (added to the commanded chain lengths; nc.NCState.offset) */
#define NC_S_LEN 88

/* int64 state buffer layout */
#define NC_N_COUNTS 0   /* 5: pulse counters */
#define NC_N_PULSES 5   /* 5: pulses of the last tick */
#define NC_N_MODE 10
#define NC_N_EVENT 11   /* event of the last tick (NC_EV_*) */
#define NC_N_HAS_QM 12  /* 1 when NC_S_QM / NC_S_T hold a model pose (after the first solve) */
#define NC_N_ITER 13    /* Newton iterations of the last solve */
#define NC_N_LEN 14

/* rest deadband: a joint whose feed-forward rate is worth at most this many pulses per tick stands
 * still (pmctl.motion.nc.REST_FF_PULSES) */
#define NC_REST_FF 1e-6

/* compensation: a commanded rate below this (mm/s) leaves an axis's direction as it was
 * (pmctl.core.compensation.STILL_MM_S) */
#define NC_COMP_STILL 1e-9

/* V-F converters: an accumulator this close (pulses) below a whole pulse has reached it, so that a
 * rate sum landing exactly on a pulse sends it in both cores (pmctl.core.vf.TIE) */
#define NC_VF_TIE 1e-9

/* Constants: filled once by nc_setup from a flat array of NC_C_LEN doubles, in this order. */
typedef struct {
    /* model (ModelFK) */
    double A[3][3], Cp[3][3], N[3][3], off[3], tip_p[3], axis_p[3];
    double z_table, tol, max_iter, cos_max_tilt, fz, com[3], keps;
    /* params (NCParams and its plain-float lists) */
    double dt, ppm[5], vmax[5], amax[5], adt[5], lower[5], upper[5];
    double cos_theta2_max, kv, damping, sv_threshold, w, k_theta[3], dpu[3];
    double max_pulses, ferror, min_ferror, max_path_error, static_comp, kth_on;
    /* per-axis backlash and screw compensation (pmctl/core/compensation.py): the caller's flat
     * table (nc_setup_comp), NULL = none */
    const double *comp;
    double leak[3], inv_w2[3], acc_lp[3], defl_ff, kth_modal;    /* soft-chain K_theta (nc._kth_modal_l) */
    double off_max, off_step;    /* chain-length offset: bound (mm) and slew per tick (mm) (nc._slew_offset) */
    double rest_band[5];         /* rest deadband per axis, mm/s (NCParams._rest_band: kv x pulses / ppm) */
} nc_const;

#define NC_C_LEN 111     /* model 45 (27 + 9 + 5 + 3 + 1), params 66 (1 + 30 + 5 + 3 + 3 + 6 + 11 + 2 + 5) */

/* Returns 0, or -1 if n != NC_C_LEN. */
int nc_setup(nc_const *c, const double *flat, int n);

/* Compensation table (pmctl.core.compensation.Compensation.flat): 5 x (backlash mm, take-up rate
 * mm/s, points, offset), then per axis positions, forward and reverse errors (points each) from
 * offset. The caller keeps the buffer alive. Returns 0, or -1 on a bad layout (then none is used).
 * comp = NULL: no compensation. */
int nc_setup_comp(nc_const *c, const double *comp, int n);

/* Single-pose FK (ModelFK.solve_l): Newton on the 6 loop equations for the joints q (5) from the
 * warm start (P, R); dL (3) / T0 (6x3) the predictor (dL = NULL: none). On success writes P, R,
 * tip (3), axis (3), J (6x5, row-major), T (6x3) and the iteration count, and returns 0; on failure
 * returns an NC_EV_FK_* event with its arguments in ev (P, R unchanged). */
int nc_fk(const nc_const *c, const double *q, double *P, double *R, const double *dL, const double *T0,
          double *tip, double *axis, double *J, double *T, int64_t *iters, double *ev);

/* Gravity strain of the platform at rotation R with twist map T (ModelFK.static_strain). */
void nc_static_strain(const nc_const *c, const double *R, const double *T, double *out3);

/* One tick (nc.nc_step) on the state buffers s (NC_S_LEN) and n (NC_N_LEN). target (12): tip,
 * axis, tip velocity, axis velocity; enc (5) motor-side positions, mm; strain (3) microstrain;
 * offset (3) the chain-length offset input, mm (NULL: none this tick, the applied offset is held).
 * Returns the event of this tick (also in n[NC_N_EVENT]). */
int nc_step(const nc_const *c, double *s, int64_t *n, const double *target, const double *enc,
            const double *strain, const double *offset);

#endif
