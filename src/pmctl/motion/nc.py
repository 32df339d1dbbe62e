"""Closed-loop NC step (docs/machine.md §6, seed 004 ch. 2-4): a pure function of (state, target, feedback).

Each tick:
  1. model pose r^ = FK(pulse counters x resolution), Newton warm-started from the previous pose;
  2. pose error e = (p* - p^, axis error normal to the tool axis: spin about the tool is free);
  3. joint rates qdot = J+(rdot* + K_v e) with J+ a damped SVD pseudo-inverse of the 6x5 tool
     Jacobian d(tip_W, axis)/dq; minus the strain-gauge term K_theta (theta_m - theta_L) per chain;
  4. joint velocity and acceleration limits (uniform scaling: the path direction is kept);
  5. soft limits (joint ranges with the stopping distance, tilt range), following error
     (LinuxCNC FERROR scaled with speed, floor MIN_FERROR) and path error stop motion with a reason;
  6. V-F converters (pmctl.core.vf.vf_tick, the per-tick form of vf_step) -> signed pulses per axis; pulse counters += pulses.

Rest deadband (between steps 3 and 4): while the target stands still (its feed-forward, the six
velocity components, all exactly zero: a dwell, a feed hold once sigma is 0, a job's end, the idle
rest pose; the slowest feed still moves the target every tick), a joint whose desired rate is
worth at most ``rest_deadband_pulses`` (half a pulse) of position error, |qdot_i| <= kv x 0.5 /
pulses_per_mm_i (an exact half pulse is inside, by a margin of 1e-9 pulse so that both cores agree),
is commanded rate zero, and once its rate is zero its V-F residue is dropped
(nothing is owed: the counter is the pulse nearest the target, as at a stop's halt). The desired
rate there is the whole V-F input, the pose error through J+ plus the strain term, so a joint
pushed out of the band (a new target, K_theta, a compensation or chain-offset change) is driven
at once by the full, unchanged law, and only a disturbance that lasts (its integral reaches a
pulse while out of the band) moves it: a chain mode ringing about the band's edge is not rectified
into pulses. Without the deadband, a target between two pulses makes the correction integrate in
the V-F residue, pass the threshold, overshoot by the remaining fraction and come back: a one-pulse
limit cycle at rest (LinuxCNC's stepgen likewise leaves a position within half a step alone).
While the target moves and the soft-chain K_theta runs (a chain mode known, NCParams.mode_hz), a
joint whose own feed-forward rate (J+ of the target's velocity) is under ``REST_FF_PULSES`` per
tick -- a chain standing still while only the table moves, the table while only the chains move --
gets the same deadband: the same one-pulse limit cycle would run on it, and through the feedback
it rings the soft chain's mode (docs/vibration.md). Without that law such a joint is driven as
before: the deadband would let the commanded path stand up to its width off the programmed one.
Every other joint is driven as before, and pulses + residue = the integral of the rate.

With a compensation (``NCParams.compensation``, the machine config's [compensation]), the joints of
step 1 (and of the soft limits) are counts x resolution + the per-axis backlash and screw
correction (pmctl.core.compensation.comp_tick); the following error stays on the motor side.

Chain-length offset (the slow compensation of the strain DAQ, pmctl.hal.modbus_daq): an input of
three lengths (mm, one per chain) *added to the commanded chain lengths*: the model joints of
step 1 are counts x resolution (+ compensation) - offset, so the loop, closing on the model pose,
drives the counters to IK(target) + offset. The offset applied is its own state (``NCState.offset``):
it follows the input only in RUN, at most ``chain_offset_rate_mm_s`` (so a step of the input is a
ramp, never a jump of the commanded lengths), within +-``chain_offset_max_mm`` (a larger or
non-finite input is clipped / ignored here; the loop refuses it before with a reason). Sign: a
chain that is too long by d under load (tension elongation: strain / gain / stiffness) is
cancelled by the offset -d.

Units: mm, s, rad. Joint rates in mm/s; V-F input in pulses/s, threshold one pulse.

Gains, in the seed's terms (eq. 3.1): the seed's V-F input is u = K_G(theta0 - theta_m) - K_theta
(theta_m - theta_L) and the motor rate K_v K_R u. Here the rate is written directly,
qdot = K_v e - K_theta (theta_m - theta_L), so ``kv`` = (seed K_v K_R K_G) and ``k_theta`` =
(seed K_v K_R K_theta), both in 1/s.

The hot path (one pose per tick) has its own small single-pose kinematics
(:class:`pmctl.core.model_fk.ModelFK`): the batch functions of :mod:`pmctl.core.kinematics` cost
~0.3 ms per call in numpy overhead alone.

This file is the readable reference. The loop runs, by default, its C99 twin
(:mod:`pmctl.motion.ncore`, ``nc.implementation`` in the service config; ``ncore.make_nc`` picks
one), which does the same arithmetic in the same order; tests/motion/test_ncore.py runs both on the same
inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import lapack

from pmctl.core.compensation import comp_tick
from pmctl.core.config import Machine
from pmctl.core.errors import KinematicsError
from pmctl.core.kinematics import forward_platform
from pmctl.core.model_fk import ModelFK
from pmctl.core.vf import TIE, vf_tick

RUN, STOPPING, HALTED, DONE = 0, 1, 2, 3
IMPLEMENTATIONS = ("compiled", "python")
_ZERO5 = [0.0] * 5
_ZERO3 = [0.0] * 3
ACC_LP = 2.0          # soft-chain K_theta: the planned acceleration is low-passed at ACC_LP x the mode
REST_FF_PULSES = 1e-6  # a joint whose feed-forward rate is worth at most this many pulses per tick stands still
MODE_NAMES = {RUN: "run", STOPPING: "stopping", HALTED: "halted", DONE: "done"}

# ---------------------------------------------------------------- reason texts
# One place for the words, so both implementations (this file and the compiled core, which reports
# an event code and its numbers) say exactly the same thing.

_NAMES = ("L1", "L2", "L3", "X", "Y")
SVD_TEXT = "tool Jacobian SVD did not converge"


def soft_limit_text(i, x, v, L):
    return (f"soft limit: {_NAMES[i]} = {x:.4f} mm moving at {v:.3f} mm/s would pass "
            f"[{L.lower[i]:g}, {L.upper[i]:g}] mm")


def ferror_text(i, fe, lim, v):
    return f"following error: {_NAMES[i]} off by {fe:.4f} mm (limit {lim:.4f} mm at {v:.2f} mm/s)"


def encoder_fault_text(i, v):
    return f"feedback fault: encoder {_NAMES[i]} reads {v}"


def strain_fault_text(i, v):
    return f"feedback fault: strain gauge {i + 1} reads {v}"


def path_error_text(perr, params):
    return (f"path error {perr:.4f} mm over {params.max_path_error_mm:g} mm "
            f"(target not reachable within the joint limits)")


def tilt_text(r22, params):
    return (f"soft limit: tilt {math.degrees(math.acos(min(1.0, r22))):.3f} deg "
            f"over {math.degrees(params.theta2_max_rad):g} deg")


MODEL_LOST = "model pose lost: "


class _Lists:
    __slots__ = ("vmax", "adt", "lower", "upper", "ppm", "amax", "kth", "leak")

    def __init__(self, p):
        self.vmax = [float(x) for x in p.vmax]
        self.amax = [float(x) for x in p.amax]
        self.adt = [float(x) * p.dt for x in p.amax]
        self.lower = [float(x) for x in p.lower]
        self.upper = [float(x) for x in p.upper]
        self.ppm = [float(x) for x in p.pulses_per_mm]
        self.kth = [float(x) for x in p.k_theta]
        self.leak = [float(x) for x in p.k_theta_leak]


@dataclass(frozen=True)
class NCParams:
    """Gains and limits of the NC step. Build with :meth:`from_machine`."""

    dt: float
    pulses_per_mm: np.ndarray          # (5,)
    vmax: np.ndarray                   # (5,) mm/s, effective (min of the limit and the V-F maximum)
    amax: np.ndarray                   # (5,) mm/s^2
    lower: np.ndarray                  # (5,) joint soft limits, mm
    upper: np.ndarray
    theta2_max_rad: float
    kv: float = 500.0                  # 1/s, pose-error gain
    damping: float = 0.05              # max damping factor lambda of the pseudo-inverse
    sv_threshold: float = 0.05         # damping fades in below this smallest singular value
    orient_weight_mm: float = 100.0    # weight of the axis rows (mm per unit axis error)
    k_theta: np.ndarray = field(default_factory=lambda: np.zeros(3))   # 1/s per chain, 0 = off
    deflection_per_ue: np.ndarray = field(default_factory=lambda: np.zeros(3))  # mm per microstrain
    # K_theta on a soft chain (docs/vibration.md): with the chain's mode known (mode_hz > 0) the
    # planned stretch a*/w^2 is taken off the deflection, the feedback is decoupled from the pose
    # loop through a leaky offset per chain (leak 1/s), and optionally the motor leads by a*/w^2.
    mode_hz: np.ndarray = field(default_factory=lambda: np.zeros(3))   # chain mode per chain, 0 = unknown
    k_theta_leak: np.ndarray = field(default_factory=lambda: np.zeros(3))   # 1/s per chain
    # low-pass of the planned chain acceleration (the planned stretch a*/w^2), 1/s per chain; 0 = ACC_LP x w
    # (the service config's K_theta design sets it: pmctl.core.strain_loop)
    k_theta_lp: np.ndarray = field(default_factory=lambda: np.zeros(3))
    deflection_ff: bool = False        # motor leads by the planned stretch a*/w^2 (load side on the path)
    max_pulses_per_tick: int = 1
    ferror_mm: float = 1.0             # following-error limit at full speed (LinuxCNC FERROR)
    min_ferror_mm: float = 0.01        # floor at low speed (LinuxCNC MIN_FERROR)
    max_path_error_mm: float = 0.5     # model tool pose vs target (tip mm; axis weighted)
    static_strain_comp: bool = True    # subtract the model pose's gravity strain from the gauges
    implementation: str = "compiled"   # the loop's NC: "compiled" (C core, pmctl.motion.ncore) or "python" (nc_step)
    # per-axis backlash and screw compensation (pmctl.core.compensation; None = none): the model
    # joints are counts x resolution + its correction
    compensation: object = field(default=None, compare=False)
    # the chain-length offset input (slow compensation): bound of its magnitude and its slew rate
    chain_offset_max_mm: float = 0.2
    chain_offset_rate_mm_s: float = 0.05
    # rest deadband: while the target's feed-forward is zero, a joint whose desired rate is worth at
    # most this many pulses of position error (|qdot| <= kv x this / pulses_per_mm) gets rate zero
    # and its V-F residue is dropped; 0.5 to 1, or 0 = off (the loop then corrects sub-pulse errors
    # at rest: a one-pulse limit cycle)
    rest_deadband_pulses: float = 0.5

    def __post_init__(self):
        # Arrays are frozen too (use dataclasses.replace to change a limit), so the plain-float
        # copies for the per-tick scalar code (5 numbers: cheaper than numpy calls) stay in step.
        for f in ("pulses_per_mm", "vmax", "amax", "lower", "upper", "k_theta", "deflection_per_ue", "mode_hz",
                  "k_theta_leak", "k_theta_lp"):
            a = np.array(getattr(self, f), float)
            if f in ("k_theta", "mode_hz", "k_theta_leak", "k_theta_lp"):     # one value for all chains, or one per chain
                a = np.broadcast_to(a, (3,)).copy()
            a.setflags(write=False)
            object.__setattr__(self, f, a)
        if self.implementation not in IMPLEMENTATIONS:
            raise ValueError(f"NC implementation must be one of {', '.join(IMPLEMENTATIONS)}, "
                             f"got {self.implementation!r}")
        object.__setattr__(self, "_l", _Lists(self))
        object.__setattr__(self, "_kth_on", bool(np.any(self.k_theta)))
        if np.any(self.mode_hz < 0) or np.any(self.k_theta_leak < 0) or np.any(self.k_theta_lp < 0):
            raise ValueError("mode_hz, k_theta_leak and k_theta_lp must be >= 0")
        w = 2.0 * math.pi * self.mode_hz
        inv_w2 = [1.0 / (x * x) if x > 0 else 0.0 for x in w.tolist()]
        object.__setattr__(self, "_inv_w2", inv_w2)
        lp = [x if x > 0 else ACC_LP * wi for x, wi in zip(self.k_theta_lp.tolist(), w.tolist())]
        object.__setattr__(self, "_acc_lp", [1.0 - math.exp(-x * self.dt) for x in lp])
        object.__setattr__(self, "_kth_modal", self._kth_on and bool(np.any(self.mode_hz > 0)))
        for f in ("chain_offset_max_mm", "chain_offset_rate_mm_s"):
            v = float(getattr(self, f))
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{f} must be a finite number >= 0, got {v!r}")
            object.__setattr__(self, f, v)
        object.__setattr__(self, "_off_step", self.chain_offset_rate_mm_s * self.dt)    # mm per tick
        db = float(self.rest_deadband_pulses)
        if not (db == 0.0 or 0.5 <= db <= 1.0):
            # below half a pulse a target can sit where neither neighbouring pulse is in the band:
            # the joint would step back and forth between them (the limit cycle again)
            raise ValueError(f"rest_deadband_pulses must be 0 (off) or in [0.5, 1], got {self.rest_deadband_pulses!r}")
        object.__setattr__(self, "rest_deadband_pulses", db)
        # the band in rate units per axis, mm/s (kv x pulses / pulses_per_mm); a target exactly on
        # the band's edge (a half pulse from the counters) is inside it by TIE in both cores (their
        # pseudo-inverses round its rate a few units in the last place apart: pmctl.core.vf.TIE)
        object.__setattr__(self, "_rest_band",
                           [float(self.kv) * (db + TIE if db else 0.0) / x for x in self._l.ppm])

    @classmethod
    def from_machine(cls, machine: Machine, dt: float, *, max_pulses_per_tick=None, k_theta=0.0,
                     modal_stiffness_N_per_mm=None, mode_hz=None, leak_frac=0.1, **kw):
        """Limits from the machine config. ``max_pulses_per_tick=None`` -> multi-pulse mode sized by
        the joint speed limit (200 kpulse/s at 2000 pulse/mm and 100 mm/s); 1 -> the seed's mode.
        The strain->deflection scale is 1/(strain gain x chain stiffness): the chain's modal
        stiffness when given, else the machine config's chain_axial. ``mode_hz`` (one or three):
        the chain mode, which turns on the soft-chain K_theta (quasi-static stretch removed,
        decoupled from the pose loop with a leak of ``leak_frac`` x w unless k_theta_leak is given;
        the service config gives the leak and k_theta_lp its design derives from the mode,
        pmctl.core.strain_loop.design_k_theta)."""
        if mode_hz is not None:
            mh = np.broadcast_to(np.asarray(mode_hz, float), (3,)).copy()
            kw["mode_hz"] = mh
            kw.setdefault("k_theta_leak", leak_frac * 2.0 * math.pi * mh)
        lim, res = machine.limits, machine.resolution
        ppm = res.pulses_per_mm
        vlim = lim.joint_speed
        if max_pulses_per_tick is None:
            max_pulses_per_tick = int(math.ceil(float(np.max(vlim * ppm)) * dt))
        max_pulses_per_tick = max(1, int(max_pulses_per_tick))
        vmax = np.minimum(vlim, max_pulses_per_tick / (ppm * dt))
        k = machine.stiffness.chain_axial if modal_stiffness_N_per_mm is None else modal_stiffness_N_per_mm
        kth = np.broadcast_to(np.asarray(k_theta, float), (3,)).copy()
        dpu = np.broadcast_to(1.0 / (machine.strain_gain * np.asarray(k, float)), (3,)).copy()
        kw.setdefault("orient_weight_mm", machine.geometry.tool_length)
        kw.setdefault("compensation", getattr(machine, "compensation", None))
        return cls(dt=dt, pulses_per_mm=ppm, vmax=vmax, amax=lim.joint_accel, lower=lim.joint_lower,
                   upper=lim.joint_upper, theta2_max_rad=math.radians(max(abs(x) for x in lim.theta2_deg)),
                   k_theta=kth, deflection_per_ue=dpu, max_pulses_per_tick=max_pulses_per_tick, **kw)


@dataclass(frozen=True)
class NCState:
    counts: np.ndarray        # (5,) int64 pulse counters
    acc: np.ndarray           # (5,) V-F accumulators, pulses
    qdot: np.ndarray          # (5,) last commanded joint rate, mm/s
    P: np.ndarray             # model platform pose (warm start)
    R: np.ndarray
    tip: np.ndarray           # model tool tip in W and axis
    axis: np.ndarray
    mode: int = RUN
    reason: str = ""
    path_error: float = 0.0   # |e| of the last tick, mm (weighted)
    q_model: np.ndarray | None = None   # joints of the model pose (P, R)
    T: np.ndarray | None = None         # (6, 3) platform twist per unit chain-length change at (P, R)
    # compensation (pmctl.core.compensation.comp_tick; None before the first compensated tick):
    comp_dir: np.ndarray | None = None  # (5,) direction per axis (+1, -1, 0 before the first move)
    comp_bl: np.ndarray | None = None   # (5,) backlash term, mm
    comp: np.ndarray | None = None      # (5,) correction of the last tick, mm (model joint - motor)
    kth: np.ndarray | None = None       # (12,) soft-chain K_theta: offset d (3, mm), last feed-forward
                                        # chain rate (3, mm/s), last planned stretch a*/w^2 (3, mm),
                                        # low-passed planned chain acceleration (3, mm/s^2)
    offset: np.ndarray | None = None    # (3,) chain-length offset applied (mm, added to the commanded
                                        # lengths); None before the first offset input

    # Mode changes from outside the step (the loop's stop request, a backend fault, the end of the
    # job). The compiled core's state handle (pmctl.motion.ncore.CompiledState) has the same four
    # methods and changes its buffers in place; these return a new state.
    def halted(self, reason: str) -> "NCState":
        """Halt at once: no more pulses, the sub-pulse residue dropped."""
        return replace(self, mode=HALTED, reason=reason, qdot=np.zeros(5), acc=np.zeros(5))

    def stopping(self, reason: str) -> "NCState":
        """Decelerate to rest within the acceleration limits, then halt."""
        return replace(self, mode=STOPPING, reason=reason)

    def done(self) -> "NCState":
        return replace(self, mode=DONE)

    def uncounted(self, pulses) -> "NCState":
        """The counters without ``pulses`` (a backend refused them)."""
        return replace(self, counts=self.counts - np.asarray(pulses, np.int64))

    def snapshot(self) -> "NCState":
        return self

    def with_counts(self, counts) -> "NCState":
        """The counters set to what a device reports it executed (after a backend fault)."""
        return replace(self, counts=np.array(counts, np.int64))


def initial_state(machine: Machine, counts, model: ModelFK | None = None, offset=None) -> NCState:
    """State at given pulse counters: model pose by a cold-start FK (raises KinematicsError).
    ``offset``: the chain-length offset already applied (a restart keeps it: the model pose is
    that of the counters minus it, and the NC goes on from it instead of slewing it in again)."""
    counts = np.asarray(counts, dtype=np.int64).copy()
    q = counts / machine.resolution.pulses_per_mm
    off = None
    if offset is not None:
        off = np.array(offset, float).reshape(3)
        q[:3] -= off
    P, R = forward_platform(q[:3], machine.geometry)
    model = model or ModelFK(machine)
    P, R, tip, axis, _ = model.solve(q, P, R)
    return NCState(counts, np.zeros(5), np.zeros(5), P, R, tip, axis, offset=off)


def counts_of(q, params: NCParams):
    """Nearest pulse counters of joint positions q (mm)."""
    return np.rint(np.asarray(q, float) * params.pulses_per_mm).astype(np.int64)


def _limit_rates_l(des, prev, L):
    """limit_rates on plain lists (the per-tick path)."""
    m = 0.0
    for i in range(5):
        r = abs(des[i]) / L.vmax[i]
        if r > m:
            m = r
    if m > 1.0:
        des = [d / m for d in des]
    dq = [des[i] - prev[i] for i in range(5)]
    m = 0.0
    for i in range(5):
        r = abs(dq[i]) / L.adt[i]
        if r > m:
            m = r
    if m > 1.0:
        return [prev[i] + dq[i] / m for i in range(5)]
    return des


def limit_rates(qdot_des, qdot_prev, params: NCParams):
    """Joint velocity and acceleration limits by uniform scaling (path direction kept).

    First the desired rate is scaled into the velocity box, then the change from the previous
    rate is scaled into the per-tick acceleration box. The result is a convex combination of two
    points inside the velocity box, so both limits hold."""
    return np.array(_limit_rates_l(list(map(float, qdot_des)), list(map(float, qdot_prev)), params._l))


def _damped_pinv_apply(J, x, params: NCParams, x2=None):
    """J+ x (and J+ x2 with the same decomposition when x2 is given: returns both)."""
    U, s, Vt, info = lapack.dgesdd(J, full_matrices=0)
    if info != 0:
        raise KinematicsError(SVD_TEXT)
    smin = s[-1]
    eps = params.sv_threshold
    lam2 = 0.0 if smin >= eps else params.damping ** 2 * (1.0 - (smin / eps) ** 2)
    g = s / (s * s + lam2)
    if x2 is None:
        return Vt.T @ (g * (U.T @ x))
    return Vt.T @ (g * (U.T @ x)), Vt.T @ (g * (U.T @ x2))


def _kth_modal_l(qd, qf, defl, kth, params: NCParams):
    """The soft-chain K_theta term (docs/vibration.md) on lists, in the compiled core's order.
    qf: the targets' feed-forward chain rates of this tick; defl: theta_m - theta_L per chain, mm;
    kth: (12,) state (offset d, last feed-forward rate, last stretch o, low-passed a*). Adds to
    qd[:3] and returns the new state: a* = (qf - qf_prev)/dt (the targets' second difference),
    low-passed (af += c (a* - af), c = 1 - exp(-w_lp dt), w_lp = params.k_theta_lp, by default ACC_LP w:
    the stretch a*/w^2 is the deflection only for what lies below the mode, and a one-tick velocity
    step of the targets would otherwise become a one-tick motor blip of a*/w^2; the service config
    sets w_lp = K_theta, pmctl.core.strain_loop), o = af/w^2 the planned stretch, y_dyn = y + o
    (y = -defl), rate K_theta y_dyn + kv d (+ kv o + (o - o_prev)/dt with deflection feed-forward),
    d += dt (K_theta y_dyn - leak d)."""
    dt, kv, iw2, cf = params.dt, params.kv, params._inv_w2, params._acc_lp
    kt, lk = params._l.kth, params._l.leak
    out = [0.0] * 12
    for i in range(3):
        d = kth[i]
        a = (qf[i] - kth[3 + i]) / dt
        af = kth[9 + i] + cf[i] * (a - kth[9 + i])
        o = af * iw2[i]
        y = -defl[i] + o
        u = kt[i] * y + kv * d
        if params.deflection_ff:
            u = u + (kv * o + (o - kth[6 + i]) / dt)
        qd[i] = qd[i] + u
        out[i] = d + dt * (kt[i] * y - lk[i] * d)
        out[3 + i] = qf[i]
        out[6 + i] = o
        out[9 + i] = af
    return out


def _stopping_violation(q, qdot, L, dt):
    """Reason text if stopping now (uniformly scaled decel) would still cross a soft limit.
    q, qdot: lists (position after this tick, rate)."""
    T = max(abs(qdot[i]) / L.amax[i] for i in range(5))
    for i in range(5):
        v = qdot[i]
        s = abs(v) * (0.5 * T + 2.0 * dt)            # distance while braking, plus two ticks' margin
        x = q[i]
        if (v > 0 and x + s > L.upper[i]) or (v < 0 and x - s < L.lower[i]) or x > L.upper[i] or x < L.lower[i]:
            return soft_limit_text(i, x, v, L)
    return ""


def _nonfinite_feedback(enc, strain):
    """Reason text if a feedback value is NaN or infinite (a lost or broken sensor), else ''."""
    for i, v in enumerate(enc):
        if not math.isfinite(v):
            return encoder_fault_text(i, v)
    for i, v in enumerate(strain):
        if not math.isfinite(v):
            return strain_fault_text(i, v)
    return ""


def _ferror_violation(q, enc, qdot, params: NCParams):
    """LinuxCNC following error: limit = max(MIN_FERROR, FERROR |v| / v_max) per joint (lists)."""
    L = params._l
    for i in range(5):
        fe = abs(q[i] - enc[i])
        lim = params.ferror_mm * abs(qdot[i]) / L.vmax[i]
        if lim < params.min_ferror_mm:
            lim = params.min_ferror_mm
        if fe > lim:
            return ferror_text(i, fe, lim, qdot[i])
    return ""


def _slew_offset(off, want, params: NCParams):
    """The applied chain-length offset one tick on toward the input ``want`` (lists of 3): the input
    clipped to +-chain_offset_max_mm (a non-finite one holds), approached at most _off_step per tick."""
    lim, step = params.chain_offset_max_mm, params._off_step
    out = [0.0] * 3
    for i in range(3):
        w = want[i]
        if not math.isfinite(w):
            w = off[i]
        elif w > lim:
            w = lim
        elif w < -lim:
            w = -lim
        d = w - off[i]
        if d > step:
            out[i] = off[i] + step
        elif d < -step:
            out[i] = off[i] - step
        else:
            out[i] = w
    return out


def nc_step(state: NCState, target, feedback, params: NCParams, model: ModelFK, offset=None):
    """One tick. Returns (pulses int64 (5,), new NCState). Pure: ``state`` is not modified.

    target: (12,) = tip (3, mm in W), axis (3, unit), tip_vel (3, mm/s), axis_vel (3, 1/s).
    feedback: has ``enc`` (5,) motor-side positions in mm and ``strain`` (3,) microstrain.
    offset: (3,) chain-length offset input, mm (added to the commanded chain lengths, slew-limited
    and bounded: see the module docstring); None = no input this tick (the applied offset is held).
    A stop (soft limit, path error) decelerates within the acceleration limits (mode STOPPING,
    then HALTED); a fault (FK failure, following error) halts at once (no more pulses).
    ``model`` holds only constants and scratch space.
    """
    zero = np.zeros(5, np.int64)
    if state.mode in (HALTED, DONE):
        return zero, state
    L = params._l
    ql = state.counts.tolist()
    ql = [ql[i] / L.ppm[i] for i in range(5)]
    prev = state.qdot.tolist()
    enc = feedback.enc.tolist()
    bad = _nonfinite_feedback(enc, feedback.strain.tolist())
    if bad:              # a dead sensor must not blind the supervision (NaN compares false)
        return zero, replace(state, qdot=np.zeros(5), acc=np.zeros(5), mode=HALTED, reason=bad)
    fe = _ferror_violation(ql, enc, prev, params)
    if fe:
        return zero, replace(state, qdot=np.zeros(5), acc=np.zeros(5), mode=HALTED, reason=fe)
    comp = params.compensation
    if comp is not None:      # model joints = motor side + correction (pmctl.core.compensation)
        cd = _ZERO5 if state.comp_dir is None else state.comp_dir.tolist()
        cb = _ZERO5 if state.comp_bl is None else state.comp_bl.tolist()
        cc, cd, cb = comp_tick(comp, ql, prev, cd, cb, params.dt)
        qj = [ql[i] + cc[i] for i in range(5)]
    else:
        qj = ql
    off = None
    if offset is not None or state.offset is not None:      # the chain-length offset (slow compensation)
        off = _ZERO3 if state.offset is None else state.offset.tolist()
        if offset is not None and state.mode == RUN:
            off = _slew_offset(off, offset.tolist() if isinstance(offset, np.ndarray) else list(offset), params)
        qj = [qj[0] - off[0], qj[1] - off[1], qj[2] - off[2], qj[3], qj[4]]
    mode, reason = state.mode, state.reason
    P, R, tip, axis, perr = state.P, state.R, state.tip, state.axis, state.path_error
    kth_st = state.kth
    qdot_des = _ZERO5
    held = None
    if mode == RUN:
        try:
            qa = np.array(qj)
            pred = None if state.q_model is None else ((qa - state.q_model)[:3], state.T)
            P, R, tip, axis, J = model.solve_l(qa, P, R, pred)
            Tm, qm = model.last_T, qa
            t = target.tolist()
            w = params.orient_weight_mm
            kv = params.kv
            # position error; axis error = component of the target axis normal to the model axis
            c = t[3] * axis[0] + t[4] * axis[1] + t[5] * axis[2]
            e = [t[0] - tip[0], t[1] - tip[1], t[2] - tip[2],
                 (t[3] - c * axis[0]) * w, (t[4] - c * axis[1]) * w, (t[5] - c * axis[2]) * w]
            perr = math.sqrt(sum(v * v for v in e))
            x = np.array([kv * e[0] + t[6], kv * e[1] + t[7], kv * e[2] + t[8],
                          kv * e[3] + t[9] * w, kv * e[4] + t[10] * w, kv * e[5] + t[11] * w])
            for r in (3, 4, 5):
                Jr = J[r]
                J[r] = [Jr[0] * w, Jr[1] * w, Jr[2] * w, 0.0, 0.0]
            # the targets' own joint rates too (feed-forward only): the soft-chain K_theta's planned
            # stretch and the rest deadband of a joint standing still
            qd, qf = _damped_pinv_apply(np.array(J), x, params,
                                        np.array([t[6], t[7], t[8], t[9] * w, t[10] * w, t[11] * w]))
        except KinematicsError as e:
            return zero, replace(state, qdot=np.zeros(5), acc=np.zeros(5), mode=HALTED,
                                 reason=f"{MODEL_LOST}{e}")
        if params._kth_on:
            sg = feedback.strain
            if params.static_strain_comp:          # the gauges also read the weight: keep the dynamic part
                s0 = model.static_strain(R, Tm)
                sg = sg - np.array(s0)
            defl = -sg * params.deflection_per_ue                  # theta_m - theta_L, mm
            if params._kth_modal:
                qdl = qd.tolist()
                kth_st = _kth_modal_l(qdl, qf.tolist(), defl.tolist(),
                                      [0.0] * 12 if state.kth is None else state.kth.tolist(), params)
                qd = np.array(qdl)
            else:
                qd[:3] -= params.k_theta * defl
        qdot_des = qd.tolist()
        # the target at rest, or a joint whose own feed-forward is (nearly) zero: no correction for a
        # joint within the deadband (module docstring)
        moving = bool(t[6] or t[7] or t[8] or t[9] or t[10] or t[11])
        band = params._rest_band
        held = [False] * 5
        qfl = qf.tolist()
        ppm, dt = L.ppm, params.dt
        for i in range(5):
            if band[i] > 0.0 and abs(qdot_des[i]) <= band[i] and (     # (a band of 0: off)
                    not moving or (params._kth_modal and abs(qfl[i]) * ppm[i] * dt <= REST_FF_PULSES)):
                qdot_des[i] = 0.0
                held[i] = True
        if perr > params.max_path_error_mm:
            mode, reason = STOPPING, path_error_text(perr, params)
        elif R[2][2] < math.cos(params.theta2_max_rad) - 1e-12:
            mode, reason = STOPPING, tilt_text(R[2][2], params)
    if mode == STOPPING:
        qdot_des = _ZERO5
    qdot = _limit_rates_l(qdot_des, prev, L)
    if mode == RUN:
        dt = params.dt
        why = _stopping_violation([qj[i] + qdot[i] * dt for i in range(5)], qdot, L, dt)
        if why:
            mode, reason = STOPPING, why
            qdot = _limit_rates_l(_ZERO5, prev, L)
    qdot_a = np.array(qdot)
    ppm = L.ppm
    pl, al = vf_tick(state.acc.tolist(), [qdot[i] * ppm[i] for i in range(5)], params.dt, 1.0,
                     params.max_pulses_per_tick)
    if held is not None and mode == RUN:
        for i in range(5):
            if held[i] and qdot[i] == 0.0:      # held in the rest deadband: no sub-pulse residue is owed
                al[i] = 0.0
    pulses, acc = np.array(pl, np.int64), np.array(al)
    if mode == STOPPING and not any(qdot):
        # Braked to rest: drop the sub-pulse residue (no pulse is owed) and halt.
        mode = HALTED
        acc = np.zeros(5)
    if state.mode != RUN:          # no model solve this tick
        Tm, qm = state.T, state.q_model
    else:
        P, R, tip, axis = np.array(P), np.array(R), np.array(tip), np.array(axis)
    if comp is not None:
        cs = (np.array(cd), np.array(cb), np.array(cc))
    else:
        cs = (state.comp_dir, state.comp_bl, state.comp)
    if kth_st is not None and not isinstance(kth_st, np.ndarray):
        kth_st = np.array(kth_st)
    return pulses, NCState(state.counts + pulses, acc, qdot_a, P, R, tip, axis, mode, reason, perr, qm, Tm, *cs, kth_st,
                           None if off is None else np.array(off))


class PythonNC:
    """The loop's NC through the reference code (:func:`nc_step`): ``load(state)`` gives the state
    handle, ``step(state, target, feedback)`` -> (pulses, state). Same interface as
    pmctl.motion.ncore.CompiledNC."""

    implementation = "python"

    def __init__(self, machine: Machine, params: NCParams):
        self.params = params
        self.model = ModelFK(machine)

    def load(self, state: NCState) -> NCState:
        return state

    def step(self, state: NCState, target, feedback, offset=None):
        return nc_step(state, target, feedback, self.params, self.model, offset)
