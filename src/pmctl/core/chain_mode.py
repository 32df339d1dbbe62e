"""A chain mode under the NC's feedback (seed eq. 3.1 in pmctl's gains): where the closed loop puts
the mode (continuous and sampled at the tick, as the NC runs it) and the K_theta that damps it.

The resonance analysis (pmctl analyze resonance) advises with it; the service config's
``k_theta = auto`` and the shaper's design point (pmctl.motion.service_config) are computed with
it when a run starts (docs/vibration.md).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm


def predict_continuous(f, kth, kv, zeta=0.0, leak=None):
    """Mode (Hz, damping ratio) of seed eq. 3.1 in pmctl's gains (kv = K_G K_v K_R, K_theta =
    K_theta K_v K_R, 1/s) with the plant damping zeta added. ``leak`` None: nc.py's loop (the pose loop
    pulls the feedback's motion back): s^3 + (kv + K_theta + 2 zeta w) s^2 + (w^2 + 2 zeta w kv) s
    + kv w^2; a number: the decoupled feedback (offset d' = K_theta y - leak d, rate + kv d):
    (s + leak)(s + kv)(s^2 + 2 zeta w s + w^2) + K_theta s^2 (s + leak + kv)."""
    w = 2 * math.pi * f
    plant = np.array([1.0, 2 * zeta * w, w * w])
    if leak is None:
        poly = np.polyadd(np.polymul([1.0, kv], plant), [kth, 0.0, 0.0])
    else:
        poly = np.polyadd(np.polymul(np.polymul([1.0, leak], [1.0, kv]), plant),
                          kth * np.array([1.0, leak + kv, 0.0, 0.0]))
    r = np.roots(poly)
    osc = r[r.imag > 1e-9]
    if len(osc) == 0:
        return float("nan"), 1.0
    c = osc[np.argmin(-osc.real / np.abs(osc))]
    return abs(c) / (2 * math.pi), -c.real / abs(c)


def predict_sampled(f, kth, kv, dt, zeta=0.0, leak=None):
    """The same loop sampled at dt as the NC runs it: state (x_m, y, y', v_prev, d); each tick
    v = -kv x_m + kv d + K_theta y (deflection read at the tick start; d = 0 without ``leak``), the
    motor ramps by v dt (y' jumps by -(v - v_prev), then (y, y') propagate exactly), and
    d += dt (K_theta y - leak d). Returns the least damped oscillating pole as (Hz, damping ratio)."""
    w = 2 * math.pi * f
    Phi = expm(np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]]) * dt)
    on = leak is not None
    V = np.array([-kv, kth, 0.0, 0.0, kv if on else 0.0])
    A = np.zeros((5, 5))
    A[0] = np.eye(5)[0] + dt * V
    J = np.eye(5)
    J[2] -= V
    J[2, 3] += 1.0
    A[1:3] = Phi @ J[1:3]
    A[3] = V
    A[4] = np.eye(5)[4] + (dt * np.array([0.0, kth, 0.0, 0.0, -(leak or 0.0)]) if on else 0.0)
    z = np.linalg.eigvals(A)
    osc = z[z.imag > 1e-12]
    if len(osc) == 0:
        return float("nan"), 1.0
    lz = np.log(osc)
    zs = -lz.real / np.abs(lz)
    i = int(np.argmin(zs))
    return abs(lz[i].imag) / (2 * math.pi * dt), float(zs[i])


def k_theta_for_mode(f, kv, dt, zeta=0.02, leak=None, target=0.3, max_kdt=0.4):
    """Smallest K_theta (1/s, K_theta dt <= max_kdt) giving the mode ``target`` damping in the
    sampled model, else the one giving the most. Returns (K_theta, damping ratio reached)."""
    g = np.linspace(0.0, max_kdt / dt, 161)
    zs = np.array([predict_sampled(f, k, kv, dt, zeta, leak)[1] for k in g])
    hit = np.nonzero(zs >= target)[0]
    i = int(hit[0]) if len(hit) else int(np.nanargmax(zs))
    return float(g[i]), float(zs[i])
