"""The closed loop ringing down (tests of K_theta): the real NC and the sim with its flexible chain
mode and gauges holding a pose while the chains start from a deflection."""

import math

import numpy as np

from pmctl import hal
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.motion import loop as L
from pmctl.motion import nc as NC
from pmctl.motion.service_config import LoopConfig
from pmctl.task.planner import home_pose

M = load_machine()
MASS, ZETA, KV, DT = 31.66, 0.02, 400.0, 1e-3


def ringdown(f_plant, kth, y0=0.05, duration=None, **nc):
    """The load-side deflection y (mm), one sample a tick, of the three chains' mode at ``f_plant``
    Hz (modal mass MASS, 2 % damping, no gauge noise) starting from ``y0`` while the NC (kv KV, K_theta
    ``kth``, the plant's modal stiffness; ``nc``: more NCParams, e.g. mode_hz and k_theta_leak for
    the decoupled law) holds the pose; the acceleration limit is raised so the loop stays linear."""
    from dataclasses import replace
    k = MASS * (2 * math.pi * f_plant) ** 2 / 1e3
    p = NC.NCParams.from_machine(M, DT, k_theta=kth, kv=KV, modal_stiffness_N_per_mm=k, **nc)
    p = replace(p, amax=p.amax * 100)       # the linear model: no acceleration clipping
    tip, axis = home_pose(M)
    tip = np.asarray(tip, float) + [0, 0, -100.0]
    c0 = NC.counts_of(K.ik(tip, axis, M).q, p)
    st = NC.initial_state(M, c0)
    n = int((duration or max(0.3, 10.0 / f_plant)) / DT)
    tg = L.build_targets(np.repeat(st.tip[None], n, 0), np.repeat(st.axis[None], n, 0), np.zeros(n, int), DT, M, p)
    be = hal.create("sim", M, DT, dict(flex=True, mode_stiffness_N_per_mm=k, mode_mass_kg=MASS,
                                       mode_damping_ratio=ZETA, strain_noise_ue=0.0))
    be.open(c0)
    Ly = be._lib.D_Y                                   # the plant's deflection state (simplant.c)
    be._d[Ly:Ly + 3] = y0
    be._check(be._plant.sample(be._draw(), 0))
    ys = []
    wp = be.write_pulses

    def write(pl):
        wp(pl)
        ys.append(be._d[Ly])
    be.write_pulses = write
    res = L.ControlLoop(M, be, p, tg, LoopConfig(realtime=False, state_file="", settle_s=0.0, stall_timeout_s=60.0),
                        st, log=lambda s: None).run()
    assert res.status == "done", res.reason
    return np.array(ys)
