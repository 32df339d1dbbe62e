"""The closed loop ringing down (tests of K_theta): the real NC and the sim with its flexible chain
mode and gauges holding a pose while the chains start from a deflection."""

import math

from pmctl.core.config import load_machine
from pmctl.motion import nc as NC
from pmctl.tools.analysis.vibration import ringdown_on_sim

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
    ys, res = ringdown_on_sim(M, p, k, MASS, ZETA, y0, duration or max(0.3, 10.0 / f_plant),
                              sim=dict(strain_noise_ue=0.0))
    assert res.status == "done", res.reason
    return ys
