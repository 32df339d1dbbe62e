"""Concealed-effect recordings: realistic runs with hidden physics and a separate answer key.

``pmctl twin synth OUT_DIR [--effects backlash,pitch_error,...|random] [--count N] [--seed S]
[--clean] [--run raster|circle|calibration|warmup] [--duration S] [--rate HZ]
[--magnitude-scale F] [--noise-scale F] [--plant batch|loop]`` writes

    OUT_DIR/case-000/recording/{recording.json,data.csv}    the data (pmctl-recording/1)
    OUT_DIR/case-000/answer.json                             the answer key, outside the recording

``--effects a,b`` hides all listed effects in every case; ``random`` (default) one random effect per
case (``--max-effects K``: 1..K distinct random effects); ``--clean``: none.

How a case is made (vectorised; a 60 s run at 1 kHz takes 1-2 s to simulate, ~0.5 s to write)
----------------------------------------------------------------------------
1. A run in tool space, stop-and-go segments with trapezoidal speed profiles (and arcs), turned into
   commanded joints with :func:`pmctl.core.kinematics.ik_batch`, slowed down until every axis is
   within its speed and acceleration limits:
   - ``raster``: a pocket milled in layers, zig-zag passes along x or y (that table axis reverses
     every pass, the other between layers), a new tool tilt per layer, rapid retracts; a
     cutting-force estimate in load_* in half of them;
   - ``circle``: NAS 979-style cone circles (tool leaning toward the centre, CW and CCW, several
     heights): X and Y reverse at the quadrants, the chains with the tilt azimuth;
   - ``calibration``: point-to-point sweep over the workspace with dwells, optionally (always for
     compliance) known test loads hung/pushed on the tip during dwells (unloaded before and after);
   - ``warmup``: 10 min at 100 Hz of fast cycles that heat the screws (thermal runs).
   Screw temperatures follow friction heating (first order, time constant 5-15 min, input
   |screw speed|), the room drifts slowly; channels ``temp_screw1..3``, ``temp_screwX/Y``,
   ``temp_room`` at 10 Hz.
2. Physics at the machine level, per axis (``AXES``): motor side = cmd (or a first-order
   ``servo_lag``); load side = motor side + ``backlash`` (play operator, deadband width w) +
   ``pitch_error`` (A·sin(2π·s/lead + φ) of the screw position s) + ``thermal_growth``
   (α·(T − 20 °C)·(s − s_fixed), fixed bearing at L = 150 mm / X, Y = −75 mm) + ``lost_steps``
   (offset after t_s; the motor count does not see it) + ``resonance`` (a mode δ'' + 2ζωδ' + ω²δ =
   −γ·(commanded acceleration) of that axis; or a plate-link bending mode seen only by a strain
   gauge) + ``compliance`` (chain i shortens by a_i/k, a_i its static compression from
   :mod:`pmctl.core.statics`; the table gives way by −F/k to the tip force F).
   ``geometry`` changes the true machine (chain length offset, base joint shifted in its chain
   plane, tool length). The true tip, axis and chain forces come from the real forward
   kinematics and statics of the perturbed load-side joints.
3. Measurement: enc_* = motor side quantised to the 0.5 µm pulse (enc_* left out of 10 % of the
   recordings); laser tracker tip_* (σ 1–2 µm) and tool_* (σ 2–4e-5; no 6-DOF probe in 25 % of
   the recordings) at 50, 100 or 200 Hz (half the log rate, at most 100 Hz, for logs under
   400 Hz) with a random phase and beam drop-outs (empty cells); strain_* every row (σ 0.3–0.7
   µε); ``sensor_gain`` (measured = gain·true) / ``sensor_offset`` (measured = true + offset) on
   one channel; temperatures σ 0.02 K at 10 Hz, 0.01 K resolution; loads σ 0.3 N.

Two plants (``--plant``): ``batch`` (default) computes the axis effects over the whole run at once
(:func:`plant_batch`): the whole catalogue, fast enough for blind sets of hundreds of cases.
``loop`` machines the run's tool path through the real controller, the NC and ControlLoop (no real
time) on the sim backend carrying the effects (:func:`loop_plant`; backlash, pitch and periodic
error, friction, servo lag: :data:`LOOP_EFFECTS`); the channel effects, geometry, compliance and the
measurement (step 3) are the same code for both. The batch path stays the default because it
carries every effect (thermal warm-ups, resonance, lost steps, forced vibration of an axis are not
in the sim) and takes about a fifth of the CPU (a 20 s run at 1 kHz: 0.2 s against 1.0 s); both
share pmctl.core.plant_effects and agree on the same commands.

Further effects (issue 12): ``friction`` (motor side trails cmd by sign(v)·(coulomb_mm + Stribeck
term), 0 before the first move), ``periodic_error`` (as pitch, at a period 0.8-8 mm that is no lead
harmonic), ``sensor_latency`` (the tracker, ``channel`` ``"tip_*"``, reports the pose of t − delay_s),
``forced_vibration`` (a constant-amplitude line on an axis' load side or in a strain channel),
``sensor_drift`` (measured += rate_per_s·(t − t_mid)); a drawn periodic error gets a period (and
if need be an axis) that the run can identify (:func:`periodic_window`: the screw travels at least 3
periods, and at most a quarter period between laser-tracker samples; the cycles and the step are in
the answer's details); thermal growth draws its fixed-bearing end
(``screw_fixed_end_mm``: one end of the screw or the other) and may be given the heated screw's
rise (``details["rise_K"]``). Physics outside the catalogue (``ODDITIES``, ``synth_case(...,
oddities=[...])``, listed under ``"oddities"`` in the answer, never under ``"effects"``): a bent
table guide (``straightness``: tip_y bump over table X) and a ``chatter_burst`` (a line in tip_x for
one stretch of the run). ``synth_case(..., imperfections=True)`` applies :func:`imperfect` (dropped
rows, time-stamp jitter, coloured noise, a tracker drop-out).

Sign conventions of the answer parameters: backlash ``width_mm`` is the whole deadband (the load
side trails the motor by width/2 in the direction of motion); pitch ``amplitude_mm`` is the sine
amplitude (not peak-to-peak); ``lost_steps`` ``offset_mm`` is added to the load-side position
(load = motor + offset after t_s); geometry ``length_offset_mm`` as the config's
length_offsets_mm (true |C_i − A_i| = L_i + offset), ``base_joint_*`` move A_i by δr·e_i + δz·Z,
``tool_length_mm`` is added to l_t; ``compliance`` deflection = force / stiffness.

Answer key (answer.json) — the names of the diagnosis report (docs/diagnosis-report.md)::

    {"case": "case-003", "recording": "recording", "run": "calibration", "seed": 1234,
     "effects": [{"effect": "backlash", "axis": "X", "parameters": {"width_mm": 0.012},
                  "details": {...}}],       # [] for a clean case
     "noise": {"tip_mm": 0.0015, ...}}

Locators per effect: ``axis`` (backlash, pitch_error, thermal_growth, compliance, servo_lag,
lost_steps, resonance on an axis), ``channel`` (sensor_gain, sensor_offset, resonance in a strain
channel), ``chain`` (geometry: 1-3 or "tool"). Parameters: geometry {length_offset_mm} or
{base_joint_radial_mm, base_joint_z_mm} or {tool_length_mm}; backlash {width_mm}; pitch_error
{period_mm, amplitude_mm}; thermal_growth {alpha_per_K, channel}; compliance {stiffness_N_per_mm};
servo_lag {tau_s}; resonance {freq_hz, damping_ratio}; lost_steps {t_s, offset_mm}; sensor_gain
{gain}; sensor_offset {offset}.

Python API: ``EFFECTS``, ``RUNS``, ``make_effect(name, rng, ...) -> Effect``,
``make_run(kind, rng, machine, duration_s, rate_hz, loads) -> Run``, ``simulate(run, effects, rng,
machine, *, enc=True, tool=True, tracker_div=10) -> (columns, noise)`` (rng consumption does not
depend on the effects, so the same seed with and without effects gives the same noise),
the physics itself (``play``, ``first_order_lag``, ``mode_response``, ...) is
:mod:`pmctl.core.plant_effects`, shared with the sim backend and the diagnosis models,
``synth_case(rng, effects=..., ...) -> Case``,
``write_case(out_dir, name, case)``, ``generate(out_dir, count, ...) -> list[Path]``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import signal

from pmctl.core.config import Machine, load_machine
from pmctl.core.errors import InputError
from pmctl.core.kinematics import axis_from_roll_pitch, ik_batch, roll_pitch_from_axis
from pmctl.core.plant_effects import (SCREW_FIXED_END_MM, first_order_lag, friction_offset, mode_response,
                                      periodic_error, play, play_load, step_offset, thermal_growth)
from pmctl.core.recording import AXES, CMD, ENC, LOAD, STRAIN, TIP, TOOL, write_recording
from pmctl.core.statics import chain_forces, strain_of_axial
from pmctl.tools.twin.catalogue import EFFECTS, ODDITIES, RUNS  # names shared with the command line
from pmctl.tools.twin.nominal import pose_of_joints

# Which runs make an effect observable (thermal needs minutes; compliance needs force changes).
RUNS_FOR = {"thermal_growth": ("warmup",), "compliance": ("calibration",),
            "reversal_spike": ("raster",)}        # (an oddity: many reversals in a short run)
TEMP_CHANNELS = ("temp_screw1", "temp_screw2", "temp_screw3", "temp_screwX", "temp_screwY")
T_CAL_C = 20.0                     # geometry was calibrated at 20 °C
SCREW_FIXED = np.array(SCREW_FIXED_END_MM)                   # fixed-bearing end of each screw
SCREW_FREE = np.array([480.0, 480.0, 480.0, 75.0, 75.0])      # ... or it is mounted the other way round
PULSE_MM = 1.0 / 2000.0


# ---------------------------------------------------------------- effects

@dataclass
class Effect:
    effect: str
    locator: dict                  # {"axis": "X"} | {"channel": "strain_2"} | {"chain": 2}
    parameters: dict               # catalogue parameter names
    details: dict = field(default_factory=dict)   # generator internals (not catalogue names)

    def answer(self) -> dict:
        return {"effect": self.effect, **self.locator, "parameters": self.parameters,
                "details": self.details}


def _sgn(rng):
    return 1.0 if rng.random() < 0.5 else -1.0


def make_effect(name: str, rng, *, duration_s: float = 60.0, axis: str | None = None,
                scale: float = 1.0) -> Effect:
    """A random instance of a catalogue effect with realistic magnitude (times ``scale``)."""
    e = _draw_effect(name, rng, duration_s=duration_s, axis=axis)
    return scale_effect(e, scale) if scale != 1.0 else e


def scale_effect(e: Effect, s: float) -> Effect:
    """The same effect ``s`` times as strong (stiffness divided, gain deviation multiplied)."""
    p, d = dict(e.parameters), dict(e.details)
    for k in ("width_mm", "amplitude_mm", "alpha_per_K", "tau_s", "offset_mm", "offset",
              "length_offset_mm", "base_joint_radial_mm", "base_joint_z_mm", "tool_length_mm",
              "coulomb_mm", "delay_s", "amplitude", "rate_per_s"):
        if k in p:
            p[k] = p[k] * s
    if "stiffness_N_per_mm" in p:
        p["stiffness_N_per_mm"] = p["stiffness_N_per_mm"] / s
    if "gain" in p:
        p["gain"] = 1 + (p["gain"] - 1) * s
    for k in ("peak_mm", "peak_ue"):
        if k in d:
            d[k] = d[k] * s
    return Effect(e.effect, dict(e.locator), p, d)


def _draw_effect(name: str, rng, *, duration_s: float, axis: str | None) -> Effect:
    ax = axis or str(rng.choice(AXES))
    if name == "geometry":
        kind = str(rng.choice(["length_offset", "base_joint", "tool_length"], p=[0.4, 0.35, 0.25]))
        if kind == "tool_length":
            return Effect(name, {"chain": "tool"}, {"tool_length_mm": _sgn(rng) * rng.uniform(0.03, 0.2)})
        chain = int(rng.integers(1, 4))
        if kind == "length_offset":
            return Effect(name, {"chain": chain}, {"length_offset_mm": _sgn(rng) * rng.uniform(0.02, 0.15)})
        return Effect(name, {"chain": chain}, {"base_joint_radial_mm": _sgn(rng) * rng.uniform(0.03, 0.15),
                                              "base_joint_z_mm": _sgn(rng) * rng.uniform(0.03, 0.15)})
    if name == "backlash":
        return Effect(name, {"axis": ax}, {"width_mm": rng.uniform(0.005, 0.04)})
    if name == "pitch_error":
        return Effect(name, {"axis": ax}, {"period_mm": 5.0, "amplitude_mm": rng.uniform(0.004, 0.015)},
                      {"phase_rad": rng.uniform(0, 2 * np.pi)})
    if name == "thermal_growth":
        j = AXES.index(ax)
        fixed = float(SCREW_FIXED[j] if rng.random() < 0.5 else SCREW_FREE[j])
        return Effect(name, {"axis": ax}, {"alpha_per_K": rng.uniform(8e-6, 18e-6),
                                           "channel": "temp_screw" + ax.lstrip("L"), "screw_fixed_end_mm": fixed},
                      {"t_ref_C": T_CAL_C})
    if name == "friction":
        c = rng.uniform(0.004, 0.02)
        return Effect(name, {"axis": ax}, {"coulomb_mm": c},
                      {"stribeck_mm": c * rng.uniform(0.0, 1.0), "stribeck_speed_mm_s": rng.uniform(1.0, 5.0)})
    if name == "periodic_error":
        while True:
            per = float(np.exp(rng.uniform(np.log(0.8), np.log(8.0))))
            if all(abs(per * k / 5.0 - 1) > 0.08 for k in (1, 2, 3, 4)):
                break
        return Effect(name, {"axis": ax}, {"period_mm": per, "amplitude_mm": rng.uniform(0.004, 0.012)},
                      {"phase_rad": rng.uniform(0, 2 * np.pi)})
    if name == "sensor_latency":
        return Effect(name, {"channel": "tip_*"}, {"delay_s": rng.uniform(0.001, 0.006)})
    if name == "forced_vibration":
        if axis is None and rng.random() < 0.5:
            ch = str(rng.choice(STRAIN))
            return Effect(name, {"channel": ch}, {"freq_hz": rng.uniform(10, 90), "amplitude": rng.uniform(1.5, 5.0)},
                          {"phase_rad": rng.uniform(0, 2 * np.pi)})
        return Effect(name, {"axis": ax}, {"freq_hz": rng.uniform(4, 20), "amplitude_mm": rng.uniform(0.003, 0.01)},
                      {"phase_rad": rng.uniform(0, 2 * np.pi)})
    if name == "sensor_drift":
        ch = str(rng.choice(STRAIN + TIP))
        r = rng.uniform(0.05, 0.3) if ch.startswith("strain") else rng.uniform(1e-4, 6e-4)
        return Effect(name, {"channel": ch}, {"rate_per_s": _sgn(rng) * r})
    if name == "compliance":
        k = rng.uniform(1500, 6000) if ax.startswith("L") else rng.uniform(2000, 8000)
        return Effect(name, {"axis": ax}, {"stiffness_N_per_mm": k})
    if name == "servo_lag":
        return Effect(name, {"axis": ax}, {"tau_s": rng.uniform(0.003, 0.03)})
    if name == "resonance":
        if axis is None and rng.random() < 0.5:
            ch = str(rng.choice(STRAIN))
            return Effect(name, {"channel": ch}, {"freq_hz": rng.uniform(10, 60),
                                                  "damping_ratio": rng.uniform(0.02, 0.1)},
                          {"peak_ue": rng.uniform(8, 25)})
        return Effect(name, {"axis": ax}, {"freq_hz": rng.uniform(8, 30), "damping_ratio": rng.uniform(0.02, 0.1)},
                      {"peak_mm": rng.uniform(0.02, 0.06)})
    if name == "lost_steps":
        return Effect(name, {"axis": ax}, {"t_s": float(rng.uniform(0.25, 0.75) * duration_s),
                                           "offset_mm": _sgn(rng) * rng.uniform(0.015, 0.06)})
    if name in ("sensor_gain", "sensor_offset"):
        ch = str(rng.choice(STRAIN + TIP))
        if name == "sensor_gain":
            g = 1 + _sgn(rng) * (rng.uniform(0.03, 0.1) if ch.startswith("strain") else rng.uniform(2e-4, 1e-3))
            return Effect(name, {"channel": ch}, {"gain": g})
        o = _sgn(rng) * (rng.uniform(2, 10) if ch.startswith("strain") else rng.uniform(0.01, 0.05))
        return Effect(name, {"channel": ch}, {"offset": o})
    raise InputError("--effects", None, f"unknown effect {name!r}; the catalogue: {', '.join(EFFECTS)}")


# ---------------------------------------------------------------- runs (trajectories)

@dataclass
class Seg:
    T: float
    kind: str                     # "line" | "arc"
    a: np.ndarray                 # start (x, y, z, alpha, beta)
    b: np.ndarray                 # end
    arc: tuple | None = None      # (cx, cy, z, r, phi0, dphi, lean)
    force: np.ndarray | None = None   # tip force during the segment, N


@dataclass
class Run:
    kind: str
    t: np.ndarray                 # (n,)
    q: np.ndarray                 # (n, 5) commanded joints
    tip: np.ndarray               # (n, 3) commanded tip in W
    axis: np.ndarray              # (n, 3)
    force: np.ndarray | None      # (n, 3) tip force, N (None: no load channels)
    rate_hz: float


RAMP = 0.25          # acceleration and deceleration each take this fraction of a segment


def _profile(tau, rho=RAMP):
    """Trapezoidal velocity profile: position fraction s(tau), tau in [0, 1]; the acceleration
    steps at the ramp ends are what excites the machine's modes."""
    k = 1.0 / (2 * rho * (1 - rho))
    return np.where(tau < rho, k * tau**2,
                    np.where(tau > 1 - rho, 1 - k * (1 - tau) ** 2, (tau - rho / 2) / (1 - rho)))


_VPEAK = 1.0 / (1 - RAMP)   # peak speed / mean speed of the profile


def _arc_pose(arc, s):
    cx, cy, z, r, phi0, dphi, lean = arc
    phi = phi0 + s * dphi
    tip = np.stack([cx + r * np.cos(phi), cy + r * np.sin(phi), np.full_like(phi, z)], -1)
    axis = np.stack([-np.sin(lean) * np.cos(phi), -np.sin(lean) * np.sin(phi),
                     np.full_like(phi, np.cos(lean))], -1)
    return tip, axis


def _arc_end(arc, s):
    tip, axis = _arc_pose(arc, np.array([s]))
    al, be = roll_pitch_from_axis(axis[0])
    return np.array([*tip[0], al, be])


def _line(a, b, v, w_max=np.radians(8.0), t_min=0.15, force=None):
    d = float(np.linalg.norm(b[:3] - a[:3]))
    ang = float(np.max(np.abs(b[3:] - a[3:])))
    T = max(_VPEAK * d / v, _VPEAK * ang / w_max, t_min)
    return Seg(T, "line", np.asarray(a, float), np.asarray(b, float), None, force)


def _dwell(p, T, force=None):
    return Seg(T, "line", np.asarray(p, float), np.asarray(p, float), None, force)


def _evaluate(segs, t, stretch=1.0):
    T = np.array([s.T for s in segs]) * stretch
    t0 = np.concatenate([[0.0], np.cumsum(T)])
    k = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(segs) - 1)
    tau = np.clip((t - t0[k]) / T[k], 0.0, 1.0)
    s = _profile(tau)
    tip = np.empty((len(t), 3))
    axis = np.empty((len(t), 3))
    force = np.zeros((len(t), 3))
    bounds = np.searchsorted(k, np.arange(len(segs) + 1))      # k is sorted: one slice per segment
    for i, sg in enumerate(segs):
        m = slice(bounds[i], bounds[i + 1])
        if bounds[i] == bounds[i + 1]:
            continue
        if sg.kind == "arc":
            tip[m], axis[m] = _arc_pose(sg.arc, s[m])
        else:
            p = sg.a + s[m, None] * (sg.b - sg.a)
            tip[m] = p[:, :3]
            axis[m] = axis_from_roll_pitch(p[:, 3], p[:, 4])
        if sg.force is not None:
            force[m] = sg.force
    return tip, axis, force


def _tilt(rng, max_deg=10.0):
    return rng.uniform(-1, 1, 2) * np.radians(max_deg)


def _raster_segs(rng, duration, loads):
    """Pocket layers; each layer's passes run along x or along y (roughing, then cross finishing)."""
    segs, p = [], None
    feed, rapid = rng.uniform(15, 35), rng.uniform(60, 90)
    cx, cy = rng.uniform(-10, 10, 2)
    w, h = rng.uniform(50, 80), rng.uniform(40, 70)
    z = rng.uniform(40, 120)
    fc = rng.uniform(20, 80)
    total, layer = 0.0, 0
    while total < duration:
        al, be = _tilt(rng)
        along_y = rng.random() < 0.4
        half_u, half_v = (h / 2, w / 2) if along_y else (w / 2, h / 2)

        def at(u, v, zz):
            x, y = (cx + v, cy + u) if along_y else (cx + u, cy + v)
            return np.array([x, y, zz, al, be])

        vs = np.linspace(-half_v, half_v, int(rng.integers(4, 8)))
        if layer % 2:
            vs = vs[::-1]
        z -= rng.uniform(1, 4)
        start = at(-half_u, vs[0], z + 20)
        if p is not None:
            segs.append(_line(p, p + [0, 0, 20, 0, 0], rapid))          # retract
            segs.append(_line(segs[-1].b, start, rapid))
        else:
            segs.append(_dwell(start, 0.3))
        segs.append(_line(start, start - [0, 0, 20, 0, 0], rapid / 3))     # plunge
        p = segs[-1].b
        for i, v in enumerate(vs):
            q = at(half_u if i % 2 == 0 else -half_u, v, z)
            d = (q - p)[:3] / max(np.linalg.norm((q - p)[:3]), 1e-9)
            f = None
            if loads:     # cutting force on the tool: against the feed, a little sideways and up
                f = -fc * d + rng.normal(0, 0.1 * fc, 3) + np.array([0, 0, 0.3 * fc])
            segs.append(_line(p, q, feed, force=f))
            p = q
            if i + 1 < len(vs):
                q = at(-half_u if i % 2 == 0 else half_u, vs[i + 1], z)
                segs.append(_line(p, q, feed))
                p = q
        total = sum(s.T for s in segs)
        layer += 1
    return segs


def _circle_segs(rng, duration, loads):
    segs = []
    feed = rng.uniform(15, 40)
    p = None
    total = 0.0
    while total < duration:
        cx, cy = rng.uniform(-10, 10, 2)
        r = rng.uniform(20, 45)
        z = rng.uniform(30, 170)
        lean = np.radians(rng.uniform(0, 12))
        phi0 = rng.uniform(0, 2 * np.pi)
        dphi = _sgn(rng) * 2 * np.pi * rng.choice([1.0, 1.25])
        arc = (cx, cy, z, r, phi0, dphi, lean)
        start, end = _arc_end(arc, 0.0), _arc_end(arc, 1.0)
        if p is None:
            segs.append(_dwell(start, 0.3))
        else:
            up = p + [0, 0, 10, 0, 0]
            segs += [_line(p, up, 60), _line(up, start + [0, 0, 10, 0, 0], 60),
                     _line(start + [0, 0, 10, 0, 0], start, 30)]
        segs.append(Seg(_VPEAK * r * abs(dphi) / feed, "arc", start, end, arc))
        p = end
        segs.append(_dwell(p, rng.uniform(0.2, 0.6)))
        total = sum(s.T for s in segs)
    return segs


def _calibration_segs(rng, duration, loads, *, speed=(50, 100), dwell=(0.6, 1.5)):
    segs, p, total = [], None, 0.0
    while total < duration:
        al, be = _tilt(rng, 12.0)
        q = np.array([*rng.uniform(-40, 40, 2), rng.uniform(20, 200), al, be])
        if p is None:
            segs.append(_dwell(q, 0.3))
        else:
            segs.append(_line(p, q, rng.uniform(*speed)))
        f = None
        if loads and rng.random() < 0.85:
            f = np.array([*rng.normal(0, 100, 2), -rng.choice([0.0, 50.0, 100.0, 200.0])])
        T = rng.uniform(*dwell)
        if f is not None:      # measure unloaded, then with the test load, then unloaded again
            segs += [_dwell(q, T / 2), _dwell(q, T, f), _dwell(q, T / 2)]
        else:
            segs.append(_dwell(q, T))
        p = q
        total = sum(s.T for s in segs)
    return segs


def make_run(kind: str, rng, machine: Machine, duration_s: float, rate_hz: float, loads: bool) -> Run:
    """A reachable run of ``kind`` sampled at ``rate_hz`` within every axis limit."""
    lim = machine.limits
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    for _attempt in range(20):
        if kind == "raster":
            segs = _raster_segs(rng, duration_s, loads)
        elif kind == "circle":
            segs = _circle_segs(rng, duration_s, loads)
        elif kind == "calibration":
            segs = _calibration_segs(rng, duration_s, loads)
        elif kind == "warmup":
            segs = _calibration_segs(rng, duration_s, loads, speed=(70, 100), dwell=(0.5, 2.0))
        else:
            raise InputError("--run", None, f"unknown run {kind!r}; one of {', '.join(RUNS)}")
        stretch = 1.0
        for _ in range(6):
            # over-long segment lists are cut at the run's end
            tip, axis, force = _evaluate(segs, t, stretch)
            r = ik_batch(tip, axis, machine)
            if not r.ok.all():
                break
            dt = 1.0 / rate_hz
            v = np.abs(np.gradient(r.q, dt, axis=0)).max(0)
            a = np.abs(np.gradient(np.gradient(r.q, dt, axis=0), dt, axis=0)).max(0)
            fv = (v / (0.9 * lim.joint_speed)).max()
            fa = np.sqrt((a / (0.9 * lim.joint_accel)).max())
            f = max(fv, fa)
            if f <= 1.0:
                if loads:
                    # hand-applied / estimated loads build up over ~50 ms, not in one sample
                    b, a_ = signal.butter(2, min(0.9, 2 * 8.0 / rate_hz))
                    force = signal.filtfilt(b, a_, force, axis=0)
                return Run(kind, t, r.q, tip, axis, force if loads else None, rate_hz)
            stretch *= f * 1.05
    raise RuntimeError(f"could not build a reachable {kind} run in 20 attempts")


# ---------------------------------------------------------------- physics

def screw_temperatures(run: Run, rng, heated_axis: int | None, warm: bool, rise_K=None):
    """Friction-heated screw temperatures (n, 5) and the room (n,), °C (``rise``: the heated
    screw's rise in K, else drawn)."""
    t, dt = run.t, 1.0 / run.rate_hz
    n = len(t)
    room = rng.uniform(19.0, 22.5) + rng.uniform(-0.3, 0.6) * t / 600.0 + 0.05 * np.sin(2 * np.pi * t / 900 + rng.uniform(0, 6))
    speed = np.abs(np.gradient(run.q, dt, axis=0))
    temps = np.empty((n, 5))
    for j in range(5):
        tau = rng.uniform(300, 900)
        rise = rng.uniform(3, 12) if warm else rng.uniform(0.5, 3)
        if heated_axis == j:
            rise = max(rise, rng.uniform(6, 12))
            if rise_K is not None:       # a given rise (the draws above keep the rng sequence)
                rise = rise_K
        mean_speed = max(speed[:, j].mean(), 1e-9)
        u = rise * speed[:, j] / mean_speed
        t0 = room[0] + rng.uniform(0, 1.0)
        a = np.exp(-dt / tau)
        y, _ = signal.lfilter([1 - a], [1, -a], u, zi=[a * (t0 - room[0])])
        temps[:, j] = room + y
    return temps, room


@dataclass
class Case:
    columns: dict
    meta: dict
    answer: dict


def _true_machine(machine: Machine, effects) -> Machine:
    g = machine.geometry
    changes = {}
    for e in effects:
        if e.effect != "geometry":
            continue
        p = e.parameters
        if "tool_length_mm" in p:
            changes["tool_length"] = g.tool_length + p["tool_length_mm"]
        chain = e.locator.get("chain")
        if isinstance(chain, int):
            i = chain - 1
            if "length_offset_mm" in p:
                off = np.array(changes.get("length_offsets", g.length_offsets), float)
                off[i] += p["length_offset_mm"]
                changes["length_offsets"] = off
            if "base_joint_radial_mm" in p:
                A = np.array(changes.get("base_joints", g.base_joints), float)
                e_i = A[i] / np.linalg.norm(A[i])
                A[i] = A[i] + p["base_joint_radial_mm"] * e_i + p["base_joint_z_mm"] * np.array([0, 0, 1.0])
                changes["base_joints"] = A
    if not changes:
        return machine
    return dataclasses.replace(machine, geometry=dataclasses.replace(g, nominal=False, **changes))


def _reversals(q) -> np.ndarray:
    """Indices where a commanded axis position changes its direction of motion (after the first move)."""
    from pmctl.core.plant_effects import direction
    d = direction(q, dead=1e-9)
    return np.flatnonzero((d[1:] != d[:-1]) & (d[:-1] != 0)) + 1


def make_oddity(kind: str, rng, run: Run) -> dict:
    """A random instance of physics outside the catalogue (see ODDITIES). ``channels``: the
    measured channels it shows in (the answer key; a diagnosis should locate it there)."""
    T = float(run.t[-1])
    if kind == "straightness":
        x = run.q[:, 3]
        return {"kind": kind, "channels": ["tip_y"], "center_mm": float(rng.uniform(np.quantile(x, 0.3), np.quantile(x, 0.7))),
                "width_mm": float(max(np.ptp(x), 1.0) * rng.uniform(0.08, 0.2)),
                "amplitude_mm": float(_sgn(rng) * rng.uniform(0.008, 0.02))}
    if kind == "chatter_burst":
        ln = T * rng.uniform(0.1, 0.2)
        return {"kind": kind, "channels": ["tip_x"], "t0_s": float(rng.uniform(0.2, 0.7) * T), "length_s": ln,
                "freq_hz": float(rng.uniform(6, 15)), "amplitude_mm": float(rng.uniform(0.008, 0.02))}
    if kind == "reversal_spike":
        # stick-slip at reversals: the load side lurches ahead for a few tens of ms after each
        # reversal of the axis that reverses most, then settles; the motor side does not see it
        nrev = [len(_reversals(run.q[:, j])) for j in range(5)]
        j = int(np.argmax(nrev))
        ax = AXES[j]
        chans = ["tip_x"] if ax == "X" else ["tip_y"] if ax == "Y" else ["tip_x", "tip_y", "tip_z"]
        return {"kind": kind, "axis": ax, "channels": chans, "amplitude_mm": float(rng.uniform(0.008, 0.025)),
                "tau_s": float(rng.uniform(0.02, 0.06))}
    if kind == "crash_step":
        # a collision (or a lost reference) displaces one axis at one instant; the drive's count
        # sees it, the command does not, and nothing brings the axis back
        ax = str(rng.choice(AXES))
        return {"kind": kind, "axis": ax, "channels": [f"enc_{ax}"], "t_s": float(rng.uniform(0.3, 0.7) * T),
                "offset_mm": float(_sgn(rng) * rng.uniform(0.02, 0.08))}
    if kind == "encoder_glitch":
        # an intermittent encoder: a few short bursts in which enc_* reads off by a number of
        # pulses (the axis itself does not move); the twin's pose follows the encoder, so the
        # tracker's residual shows the bursts too
        ax = str(rng.choice(AXES))
        nb = int(rng.integers(4, 9))
        starts = np.sort(rng.uniform(0.05, 0.95, nb) * T)
        return {"kind": kind, "axis": ax, "channels": [f"enc_{ax}"],
                "bursts_s": [[float(a), float(a + rng.uniform(0.03, 0.12))] for a in starts],
                "offset_mm": float(_sgn(rng) * rng.uniform(0.01, 0.04))}
    if kind == "table_sag":
        # pose-dependent compliance the model lacks: the long table sags (tip z) at the ends of its
        # X travel, where it overhangs its saddle
        x = run.q[:, 3]
        return {"kind": kind, "channels": ["tip_z"], "center_mm": float(np.median(x)),
                "half_span_mm": float(max(np.ptp(x), 1.0) / 2), "amplitude_mm": float(rng.uniform(0.008, 0.02))}
    if kind == "pulse_train":
        # a periodic disturbance unrelated to any screw (a press next door): every period_s a
        # knock that rocks the tracker's stand at freq_hz (well below the tracker's rate) and dies away
        return {"kind": kind, "channels": ["tip_x", "tip_y"], "period_s": float(rng.uniform(0.7, 2.5)),
                "t0_s": float(rng.uniform(0, 0.5)), "freq_hz": float(rng.uniform(4, 10)),
                "damping_ratio": float(rng.uniform(0.02, 0.05)), "amplitude_mm": float(rng.uniform(0.008, 0.02)),
                "direction_rad": float(rng.uniform(0, 2 * np.pi))}
    raise InputError("--oddities", None, f"unknown {kind!r}; known: {', '.join(ODDITIES)}")


def axis_oddities(oddities, t, q_cmd, q_mot, q_load):
    """The oddities that act on the axes: (q_mot, q_load) with them (copies when changed)."""
    for o in oddities:
        if o["kind"] not in ("reversal_spike", "crash_step"):
            continue
        j = AXES.index(o["axis"])
        q_mot, q_load = q_mot.copy(), q_load.copy()
        if o["kind"] == "crash_step":
            s = step_offset(t, o["t_s"], o["offset_mm"])
            q_mot[:, j] += s
            q_load[:, j] += s
        else:
            from pmctl.core.plant_effects import direction
            d = direction(q_cmd[:, j], dead=1e-9)
            rev = _reversals(q_cmd[:, j])
            for i0, i1 in zip(rev, list(rev[1:]) + [len(t)]):
                s = (t[i0:i1] - t[i0]) / o["tau_s"]
                q_load[i0:i1, j] += d[i0] * o["amplitude_mm"] * s * np.exp(1.0 - s)
    return q_mot, q_load


def tip_oddities(oddities, t, q_load, tip):
    """The oddities the tracker sees on the tool tip: tip (n, 3) with them (a copy when changed)."""
    for o in oddities:
        k = o["kind"]
        if k == "straightness":          # a bent table guide: the part moves in y with X
            xx = q_load[:, 3]
            tip = tip.copy()
            tip[:, 1] += o["amplitude_mm"] * np.exp(-((xx - o["center_mm"]) / o["width_mm"]) ** 2)
        elif k == "chatter_burst":       # a vibration in one stretch of the run only
            tip = tip.copy()
            on = (t >= o["t0_s"]) & (t < o["t0_s"] + o["length_s"])
            tip[:, 0] += np.where(on, o["amplitude_mm"] * np.sin(2 * np.pi * o["freq_hz"] * t), 0.0)
        elif k == "table_sag":
            tip = tip.copy()
            tip[:, 2] -= o["amplitude_mm"] * ((q_load[:, 3] - o["center_mm"]) / o["half_span_mm"]) ** 2
        elif k == "pulse_train":
            s = np.mod(t - o["t0_s"], o["period_s"])
            w = 2 * np.pi * o["freq_hz"]
            ring = o["amplitude_mm"] * np.exp(-o["damping_ratio"] * w * s) * np.sin(w * s)
            tip = tip.copy()
            tip[:, 0] += np.cos(o["direction_rad"]) * ring
            tip[:, 1] += np.sin(o["direction_rad"]) * ring
    return tip


def encoder_oddities(oddities, t, enc):
    """The oddities of the encoder readings: enc (n, 5) with them (a copy when changed)."""
    for o in oddities:
        if o["kind"] == "encoder_glitch":
            j = AXES.index(o["axis"])
            enc = enc.copy()
            for a, b in o["bursts_s"]:
                enc[(t >= a) & (t < b), j] += o["offset_mm"]
    return enc


# oddities that only the drive's count (enc_*) shows: a case with one always records enc_*
ENC_ODDITIES = ("crash_step", "encoder_glitch")


def imperfect(cols: dict, rng, rate_hz: float) -> dict:
    """Recording imperfections of real loggers: 1 % of the rows dropped, timestamp jitter (±10 %
    of a step), coloured (AR(1), ρ 0.95) noise of half the white level on tip_* and strain_*, and a
    longer tracker drop-out."""
    n = len(cols["t"])
    keep = rng.random(n) > 0.01
    keep[0] = keep[-1] = True
    out = {k: np.asarray(v, float)[keep].copy() for k, v in cols.items()}
    m = int(keep.sum())
    dt = 1.0 / rate_hz
    out["t"] = out["t"] + rng.uniform(-0.1, 0.1, m) * dt
    out["t"][0] = cols["t"][0]
    for c in TIP + STRAIN:
        if c in out:
            x = out[c]
            ok = np.isfinite(x)
            lvl = 0.5 * (0.0015 if c.startswith("tip") else 0.5)
            e = signal.lfilter([np.sqrt(1 - 0.95 ** 2)], [1, -0.95], rng.normal(0, lvl, m))
            out[c] = np.where(ok, x + e, np.nan)
    s = int(rng.integers(0, max(m - 1, 1)))
    ln = int(rng.uniform(1.0, 2.0) * rate_hz)
    for c in TIP + TOOL:
        if c in out:
            out[c][s:s + ln] = np.nan
    return out


def _by_effect(effects) -> dict:
    by = {}
    for e in effects:
        by.setdefault(e.effect, []).append(e)
    return by


def plant_batch(q_cmd, t, effects, temps=None, machine: Machine | None = None):
    """The axis effects over a whole run (the fast batch path; pmctl.core.plant_effects):
    commanded joints (n, 5) at times t -> (q_mot, q_load, strain_extra). Motor side = cmd through
    servo lag and friction; load side = motor side + backlash, pitch and periodic error, thermal
    growth (``temps``: screw temperatures (n, 5), °C), forced vibration and resonance of an axis,
    lost steps; strain_extra: the axis modes' spring force at the gauges."""
    by = _by_effect(effects)
    ai = {a: j for j, a in enumerate(AXES)}
    n, dt = len(t), float(t[1] - t[0]) if len(t) > 1 else 1.0
    q_cmd = np.asarray(q_cmd, float)

    # motor side
    q_mot = q_cmd.copy()
    for e in by.get("servo_lag", []):
        j = ai[e.locator["axis"]]
        q_mot[:, j] = first_order_lag(t, q_cmd[:, j], e.parameters["tau_s"])
    for e in by.get("friction", []):       # following error of the position loop against friction
        j = ai[e.locator["axis"]]
        d_ = e.details
        q_mot[:, j] += friction_offset(q_cmd[:, j], dt, e.parameters["coulomb_mm"], d_["stribeck_mm"],
                                       d_["stribeck_speed_mm_s"])

    # load side
    q_load = q_mot.copy()
    for e in by.get("backlash", []):
        j = ai[e.locator["axis"]]
        st = e.details.get("start")    # where the load rests in the play (default: pushed by the first move)
        q_load[:, j] += (play(q_mot[:, j], e.parameters["width_mm"]) if st is None
                         else play_load(q_mot[:, j], e.parameters["width_mm"], st)) - q_mot[:, j]
    for e in by.get("pitch_error", []) + by.get("periodic_error", []):
        j = ai[e.locator["axis"]]
        p = e.parameters
        q_load[:, j] += periodic_error(q_mot[:, j], p["amplitude_mm"], p["period_mm"], e.details["phase_rad"])
    for e in by.get("thermal_growth", []):
        j = ai[e.locator["axis"]]
        fixed = e.parameters.get("screw_fixed_end_mm", SCREW_FIXED[j])
        q_load[:, j] += thermal_growth(q_mot[:, j], e.parameters["alpha_per_K"],
                                       temps[:, j] - e.details.get("t_ref_C", T_CAL_C), fixed)
    for e in by.get("forced_vibration", []):
        if "axis" in e.locator:
            j = ai[e.locator["axis"]]
            p = e.parameters
            q_load[:, j] += p["amplitude_mm"] * np.sin(2 * np.pi * p["freq_hz"] * t + e.details["phase_rad"])
    for e in by.get("lost_steps", []):
        j = ai[e.locator["axis"]]
        q_load[:, j] += step_offset(t, e.parameters["t_s"], e.parameters["offset_mm"])
    strain_extra = np.zeros((n, 3))
    for e in by.get("resonance", []):
        p = e.parameters
        if "axis" in e.locator:
            j = ai[e.locator["axis"]]
            d = mode_response(q_cmd[:, j], dt, p["freq_hz"], p["damping_ratio"])
            gamma = e.details["peak_mm"] / max(np.abs(d).max(), 1e-12)
            e.details["participation"] = gamma
            q_load[:, j] += gamma * d
            if j < 3:   # the mode's spring force reaches the gauge: k = m ω², N/mm
                m_eff = machine.mass.platform_kg / 3.0
                strain_extra[:, j] += machine.strain_gain * m_eff * (2 * np.pi * p["freq_hz"]) ** 2 * 1e-3 * gamma * d
    return q_mot, q_load, strain_extra


# Effects the sim backend carries (pmctl.hal.sim [hal.sim] options), so a case with only these
# (plus the channel effects, geometry and compliance of the shared stage) can come from the loop.
LOOP_EFFECTS = ("backlash", "pitch_error", "periodic_error", "friction", "servo_lag")
SHARED_EFFECTS = ("geometry", "compliance", "sensor_gain", "sensor_offset", "sensor_latency", "sensor_drift")
PLANTS = ("batch", "loop")


def loop_supports(effects) -> str:
    """'' when the control loop on the sim can make a case with ``effects``, else why not."""
    axes_periodic = set()
    for e in effects:
        if e.effect in ("resonance", "forced_vibration") and "channel" in e.locator:
            continue
        if e.effect in ("pitch_error", "periodic_error"):
            if e.locator["axis"] in axes_periodic:
                return f"two periodic errors on axis {e.locator['axis']} (the sim has one per axis)"
            axes_periodic.add(e.locator["axis"])
        if e.effect not in LOOP_EFFECTS + SHARED_EFFECTS:
            where = e.locator.get("axis", e.locator.get("channel", ""))
            return f"the sim plant does not carry {e.effect} {where}".rstrip()
    return ""


def sim_options(effects, q_cmd) -> dict:
    """[hal.sim] options of the axis effects (rigid chains, no sim noise: the measurement stage adds
    the noise); the play starts on the side that the first motion pushes, as in :func:`play`."""
    from pmctl.core.plant_effects import first_direction
    z = [0.0] * 5
    o = {"flex": False, "backlash_mm": list(z), "backlash_start": [-first_direction(q_cmd[:, j]) for j in range(5)],
         "pitch_error_amp_mm": list(z), "pitch_error_period_mm": [5.0] * 5, "pitch_error_phase_rad": list(z),
         "friction_coulomb_mm": list(z), "friction_stribeck_mm": list(z), "friction_stribeck_speed_mm_s": [1.0] * 5,
         "drive_tau_s": list(z)}
    for e in effects:
        if e.effect not in LOOP_EFFECTS:
            continue
        j, p = AXES.index(e.locator["axis"]), e.parameters
        if e.effect == "backlash":     # recorded in the answer: where the loop's load started in the play
            e.details.setdefault("start", o["backlash_start"][j])
            o["backlash_mm"][j] = p["width_mm"]
            o["backlash_start"][j] = e.details["start"]
        elif e.effect in ("pitch_error", "periodic_error"):
            o["pitch_error_amp_mm"][j] = p["amplitude_mm"]
            o["pitch_error_period_mm"][j] = p["period_mm"]
            o["pitch_error_phase_rad"][j] = e.details["phase_rad"]
        elif e.effect == "friction":
            o["friction_coulomb_mm"][j] = p["coulomb_mm"]
            o["friction_stribeck_mm"][j] = e.details["stribeck_mm"]
            o["friction_stribeck_speed_mm_s"][j] = e.details["stribeck_speed_mm_s"]
        elif e.effect == "servo_lag":
            o["drive_tau_s"][j] = p["tau_s"]
    return o


def loop_plant(run: Run, effects, machine: Machine, *, service=None):
    """Run ``run`` as a job through the real controller: the NC and ControlLoop of the service config
    (no real time, ticks back to back) on the sim backend carrying ``effects``, at the run's rate.
    Returns (run_as_machined, (q_cmd, q_mot, q_load)): the pulse counters x resolution, the encoders
    and the sim's load side at every tick. The loop's path follower may take longer than the run
    (it caps speeds and accelerations below the run's own); the returned Run has the loop's ticks,
    with the tool pose and the tip force at the path position the loop had reached. The
    following-error limits are widened (friction and servo lag are part of the case, not a fault
    to stop on)."""
    from pmctl import hal
    from pmctl.motion.loop import ControlLoop, build_targets
    from pmctl.motion.nc import counts_of, initial_state
    from pmctl.motion.service_config import load_service_config

    why = loop_supports(effects)
    if why:
        raise InputError("--plant loop", None, f"{why}; use --plant batch")
    dt = 1.0 / run.rate_hz
    svc = service or load_service_config()
    ncc = dataclasses.replace(svc.nc, kv_per_s=min(svc.nc.kv_per_s, 0.4 / dt), ferror_mm=max(svc.nc.ferror_mm, 5.0),
                              min_ferror_mm=max(svc.nc.min_ferror_mm, 0.5))
    params = ncc.params(machine, dt)
    n = len(run.t)
    tg = build_targets(run.tip, run.axis, np.ones(n, int), dt, machine, params)
    c0 = counts_of(tg.q[0], params)
    be = hal.create("sim", machine, dt, sim_options(effects, run.q))
    be.open(c0)
    cfg = dataclasses.replace(svc.loop, rate_hz=run.rate_hz, realtime=False, stall_timeout_s=60.0, settle_s=0.0,
                              state_file="")
    res = ControlLoop(machine, be, params, tg, cfg, initial_state(machine, c0), log=lambda m: None).run()
    if res.status != "done":
        raise RuntimeError(f"the control loop did not finish the {run.kind} run: {res.status}, {res.reason}")
    m = res.ticks
    ps = np.clip(res.path_s[:m] if res.path_s is not None else np.arange(m, dtype=float), 0, n - 1)
    k = np.arange(n)

    def at_path(x):
        return None if x is None else np.stack([np.interp(ps, k, x[:, i]) for i in range(x.shape[1])], 1)

    axis = at_path(run.axis)
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    q_cmd = res.counts[:m] / params.pulses_per_mm
    machined = Run(run.kind, np.arange(m) * dt, q_cmd, at_path(run.tip), axis, at_path(run.force), run.rate_hz)
    return machined, (q_cmd, res.enc[:m].copy(), res.truth[:m].copy())


def simulate(run: Run, effects, rng, machine: Machine, *, enc=True, tool=True, tracker_div=10,
             noise_scale=1.0, oddities=(), plant=None):
    """Inject ``effects`` as machine physics into ``run``, measure; returns (columns, noise).
    ``plant``: (q_cmd, q_mot, q_load) from the control loop (:func:`loop_plant`), which then stands
    for the axis effects of :func:`plant_batch`; channel effects, geometry, compliance and the
    measurement are the same for both paths."""
    t, n, dt = run.t, len(run.t), 1.0 / run.rate_hz
    by = _by_effect(effects)
    ai = {a: j for j, a in enumerate(AXES)}

    # temperatures
    th = by.get("thermal_growth", [])
    temps, room = screw_temperatures(run, rng, ai[th[0].locator["axis"]] if th else None,
                                     warm=run.kind == "warmup",
                                     rise_K=th[0].details.get("rise_K") if th else None)

    if plant is None:
        q_cmd = run.q
        q_mot, q_load, strain_extra = plant_batch(q_cmd, t, effects, temps, machine)
    else:
        q_cmd, q_mot, q_load = (np.array(x, float) for x in plant)
        strain_extra = np.zeros((n, 3))
    q_mot, q_load = axis_oddities(oddities, t, q_cmd, q_mot, q_load)
    for e in by.get("resonance", []):
        if "channel" in e.locator:
            p = e.parameters
            i = STRAIN.index(e.locator["channel"])
            d = mode_response(q_cmd[:, i], dt, p["freq_hz"], p["damping_ratio"])
            strain_extra[:, i] += e.details["peak_ue"] * d / max(np.abs(d).max(), 1e-12)
    for e in by.get("forced_vibration", []):
        if "channel" in e.locator:
            i = STRAIN.index(e.locator["channel"])
            p = e.parameters
            strain_extra[:, i] += p["amplitude"] * np.sin(2 * np.pi * p["freq_hz"] * t + e.details["phase_rad"])

    true_m = _true_machine(machine, by.get("geometry", []))
    force = run.force
    pose = pose_of_joints(q_load, true_m)
    cf = chain_forces(pose.P, pose.R, true_m, force)
    comp = by.get("compliance", [])
    if comp:
        for e in comp:
            j = ai[e.locator["axis"]]
            k = e.parameters["stiffness_N_per_mm"]
            if j < 3:
                q_load[:, j] -= cf.axial[:, j] / k          # compression shortens the chain
            elif force is not None:
                q_load[:, j] -= force[:, j - 3] / k         # the table gives way to -F
        pose = pose_of_joints(q_load, true_m, guess=(pose.P, pose.R))
        cf = chain_forces(pose.P, pose.R, true_m, force)
    if not pose.ok.all():
        raise RuntimeError("forward kinematics failed on the perturbed joints")
    strain_true = strain_of_axial(cf.axial, true_m) + strain_extra

    # measurement
    noise = {"tip_mm": rng.uniform(0.001, 0.002), "tool": rng.uniform(2e-5, 4e-5),
             "strain_ue": rng.uniform(0.3, 0.7), "temp_K": 0.02, "load_N": 0.3,
             "enc_quantum_mm": PULSE_MM}
    for k in ("tip_mm", "tool", "strain_ue", "temp_K", "load_N"):
        noise[k] *= noise_scale
    cols = {"t": t}
    for j, c in enumerate(CMD):
        cols[c] = q_cmd[:, j]
    if enc:
        q_enc = encoder_oddities(oddities, t, q_mot)
        for j, c in enumerate(ENC):
            cols[c] = np.round(q_enc[:, j] / PULSE_MM) * PULSE_MM
    tracked = (np.arange(n) % tracker_div) == int(rng.integers(0, tracker_div))
    tracked &= rng.random(n) > 0.01                                # lost beam, single samples
    for _ in range(int(rng.integers(0, 3))):                       # and a few longer breaks
        s = int(rng.integers(0, n))
        tracked[s:s + int(rng.uniform(0.2, 1.0) * run.rate_hz)] = False
    tip_true, axis_true = pose.tip, pose.axis
    for e in by.get("sensor_latency", []):    # the tracker reports the pose of t − delay
        ts = t - e.parameters["delay_s"]
        tip_true = np.stack([np.interp(ts, t, tip_true[:, k]) for k in range(3)], 1)
        axis_true = np.stack([np.interp(ts, t, axis_true[:, k]) for k in range(3)], 1)
    tip_true = tip_oddities(oddities, t, q_load, tip_true)
    tip = tip_true + rng.normal(0, noise["tip_mm"], (n, 3))
    ax = axis_true + rng.normal(0, noise["tool"], (n, 3))
    ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
    meas = {}
    for j, c in enumerate(TIP):
        meas[c] = tip[:, j]
    if tool:
        for j, c in enumerate(TOOL):
            meas[c] = ax[:, j]
    for j, c in enumerate(STRAIN):
        meas[c] = strain_true[:, j] + rng.normal(0, noise["strain_ue"], n)
    for e in by.get("sensor_gain", []):
        c = e.locator["channel"]
        meas[c] = meas[c] * e.parameters["gain"]
    for e in by.get("sensor_offset", []):
        c = e.locator["channel"]
        meas[c] = meas[c] + e.parameters["offset"]
    for e in by.get("sensor_drift", []):
        c = e.locator["channel"]
        meas[c] = meas[c] + e.parameters["rate_per_s"] * (t - 0.5 * (t[0] + t[-1]))
    for c in TIP + (TOOL if tool else ()):
        cols[c] = np.where(tracked, meas[c], np.nan)
    for c in STRAIN:
        cols[c] = meas[c]
    tdiv = max(1, int(round(run.rate_hz / 10.0)))
    tsamp = (np.arange(n) % tdiv) == 0
    for j, c in enumerate(TEMP_CHANNELS):
        cols[c] = np.where(tsamp, np.round(temps[:, j] + rng.normal(0, 0.02, n), 2), np.nan)
    cols["temp_room"] = np.where(tsamp, np.round(room + rng.normal(0, 0.02, n), 2), np.nan)
    if force is not None:
        for j, c in enumerate(LOAD):
            cols[c] = force[:, j] + rng.normal(0, noise["load_N"], n)
    return cols, noise


# ---------------------------------------------------------------- cases

def _pick_run(names, rng, run=None):
    if run:
        return run
    allowed = set(RUNS) - {"warmup"}
    for nm in names:
        if nm in RUNS_FOR:
            allowed &= set(RUNS_FOR[nm])
    if "thermal_growth" in names:
        return "warmup"
    return str(rng.choice(sorted(allowed))) if allowed else "calibration"


PERIODIC_MIN_CYCLES = 3.0     # the screw must travel this many periods of a periodic error ...
PERIODIC_MAX_STEP = 0.25      # ... and move at most this fraction of a period between tracker samples


def periodic_window(run: Run, j: int, tracker_div: int) -> tuple[float, float, float, float]:
    """(lo, hi, span, step): the periods (mm) of a periodic error on axis j that ``run`` can
    identify. The identifiability rule: the screw travels at least PERIODIC_MIN_CYCLES periods
    (span = its position range) and, while it moves, at most PERIODIC_MAX_STEP of a period between
    two samples of the laser tracker, which alone sees the load side (step = the median travel
    between tracker samples while moving): lo = step / 0.25, hi = span / 3."""
    s = run.q[::max(1, int(tracker_div)), j]
    ds = np.abs(np.diff(s))
    step = float(np.median(ds[ds > 1e-9])) if np.any(ds > 1e-9) else float("inf")
    span = float(np.ptp(run.q[:, j]))
    return step / PERIODIC_MAX_STEP, span / PERIODIC_MIN_CYCLES, span, step


def identifiable_periodic(e: Effect, run: Run, tracker_div: int, rng, *, taken=()) -> Effect:
    """``e`` (a drawn periodic_error) with a period, and if need be an axis, that ``run`` can
    identify (:func:`periodic_window`), drawn log-uniform in 0.8-8 mm within the window, away from
    the lead harmonics (±8 %). Kept as drawn when it already is identifiable; when no axis has a
    window, kept too (``details["identifiable"] = False``)."""
    axes = [e.locator["axis"]] + [a for a in AXES if a != e.locator["axis"]
                                  and ("periodic_error", (("axis", a),)) not in taken]
    for a in axes:
        lo, hi, span, step = periodic_window(run, AXES.index(a), tracker_div)
        lo, hi = max(lo, 0.8), min(hi, 8.0)
        if lo > hi:
            continue
        p = e.parameters["period_mm"]
        if a == e.locator["axis"] and lo <= p <= hi:
            per = p
        else:
            for _ in range(50):
                per = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
                if all(abs(per * k / 5.0 - 1) > 0.08 for k in (1, 2, 3, 4)):
                    break
            else:
                continue
        d = dict(e.details, cycles=span / per, tracker_step_mm=step, identifiable=True)
        return Effect(e.effect, {"axis": a}, dict(e.parameters, period_mm=per), d)
    return Effect(e.effect, dict(e.locator), dict(e.parameters), dict(e.details, identifiable=False))


def synth_case(rng, effects=(), *, run=None, duration_s=None, rate_hz=None, machine=None,
               seed=None, magnitude_scale=1.0, noise_scale=1.0, oddities=(), imperfections=False,
               plant="batch") -> Case:
    """One case: ``effects`` a list of catalogue names (each drawn at random) or Effect objects;
    ``oddities``: names from ODDITIES (physics outside the catalogue, listed apart in the answer);
    ``imperfections``: drop rows, jitter the time stamps, colour the noise (:func:`imperfect`);
    ``plant``: "batch" (the axis effects as arrays, :func:`plant_batch`) or "loop" (the run machined
    by the control loop on the sim backend carrying the effects, :func:`loop_plant`)."""
    machine = machine or load_machine()
    names = [e.effect if isinstance(e, Effect) else e for e in effects]
    kind = _pick_run(names + [o if isinstance(o, str) else o["kind"] for o in oddities], rng, run)
    if duration_s is None:
        duration_s = 600.0 if kind == "warmup" else 60.0
    if rate_hz is None:
        rate_hz = 100.0 if kind == "warmup" else 1000.0
    loads = "compliance" in names or (kind in ("calibration", "raster") and rng.random() < 0.5)
    # distinct axes when the same effect appears twice
    effs, used = [], set()
    for e in effects:
        if isinstance(e, Effect):
            effs.append(e)
            continue
        for _ in range(10):
            cand = make_effect(e, rng, duration_s=duration_s, scale=magnitude_scale)
            key = (cand.effect, tuple(sorted(cand.locator.items())))
            if key not in used:
                break
        used.add(key)
        effs.append(cand)
    r = make_run(kind, rng, machine, duration_s, rate_hz, loads)
    enc = any(e.effect in ("servo_lag",) for e in effs) or rng.random() < 0.9
    enc = enc or any((o if isinstance(o, str) else o["kind"]) in ENC_ODDITIES for o in oddities)
    tool = rng.random() < 0.75
    tracker_hz = float(rng.choice([50.0, 100.0, 100.0, 200.0])) if rate_hz >= 400 else min(100.0, rate_hz / 2)
    tracker_div = max(1, int(round(rate_hz / tracker_hz)))
    orng = np.random.default_rng([0 if seed is None else int(seed), 77])   # apart: same noise as without
    odd = [o if isinstance(o, dict) else make_oddity(o, orng, r) for o in oddities]
    prng = np.random.default_rng([0 if seed is None else int(seed), 53])   # apart: the other draws unchanged
    drawn = [i for i, e in enumerate(effects) if not isinstance(e, Effect)]
    for i in drawn:
        if effs[i].effect == "periodic_error":
            effs[i] = identifiable_periodic(effs[i], r, tracker_div, prng, taken=used)
    plant_cols = None
    if plant == "loop":
        r, plant_cols = loop_plant(r, effs, machine)
    elif plant != "batch":
        raise InputError("--plant", None, f"unknown plant {plant!r}; one of {', '.join(PLANTS)}")
    cols, noise = simulate(r, effs, rng, machine, enc=enc, tool=tool, tracker_div=tracker_div,
                           noise_scale=noise_scale, oddities=odd, plant=plant_cols)
    if imperfections:
        cols = imperfect(cols, orng, rate_hz)
    descr = {"raster": "pocket milling, zig-zag passes in layers",
             "circle": "cone-frustum circle test (5-axis contouring)",
             "calibration": "point-to-point calibration sweep with laser tracker",
             "warmup": "warm-up cycles with laser tracker checks"}[kind]
    notes = {c: {"source": "laser tracker", "rate_hz": rate_hz / tracker_div} for c in TIP}
    if tool:
        notes.update({c: {"source": "laser tracker 6-DOF probe", "rate_hz": rate_hz / tracker_div} for c in TOOL})
    if enc:
        notes.update({c: {"source": "drive pulse counter"} for c in ENC})
    notes.update({c: {"source": "plate-link strain gauge"} for c in STRAIN})
    if r.force is not None:
        notes.update({c: {"source": "test load / cutting-force estimate"} for c in LOAD})
    meta = {"sample_rate_hz": rate_hz, "description": f"{descr}, {duration_s:g} s",
            "channel_notes": notes}
    answer = {"run": kind, "seed": seed, "duration_s": duration_s, "sample_rate_hz": rate_hz, "plant": plant,
              "effects": [e.answer() for e in effs], "noise": noise}
    if odd:
        answer["oddities"] = odd
    if imperfections:
        answer["imperfections"] = True
    return Case(cols, meta, answer)


def write_case(out_dir, name: str, case: Case, *, overwrite=False) -> Path:
    """OUT_DIR/name/recording/ and OUT_DIR/name/answer.json; an existing case is refused unless
    ``overwrite``."""
    d = Path(out_dir) / name
    write_recording(d / "recording", case.columns, machine="prototype",
                    sample_rate_hz=case.meta["sample_rate_hz"], description=case.meta["description"],
                    channel_notes=case.meta["channel_notes"], overwrite=overwrite)
    ans = {"case": name, "recording": "recording", **case.answer}
    (d / "answer.json").write_text(json.dumps(ans, indent=2, default=_jsonable) + "\n", encoding="utf-8")
    return d


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


def parse_effects(text: str) -> list[str] | str:
    if text in ("random", ""):
        return "random"
    names = [s.strip() for s in text.split(",") if s.strip()]
    for nm in names:
        if nm not in EFFECTS:
            raise InputError("--effects", None, f"unknown effect {nm!r}; the catalogue: {', '.join(EFFECTS)}")
    return names


def generate(out_dir, count=1, *, effects="random", seed=0, clean=False, max_effects=1, run=None,
             duration_s=None, rate_hz=None, progress=None, magnitude_scale=1.0,
             noise_scale=1.0, overwrite=False, plant="batch") -> list[Path]:
    """Write ``count`` cases to OUT_DIR/case-NNN; returns their folders. Existing cases are refused
    (before anything is written) unless ``overwrite``. ``plant="loop"``: each case machined by the
    control loop on the sim (random effects then come from those the sim carries)."""
    from pmctl.core.recording import check_target
    for k in range(count):
        check_target(Path(out_dir) / f"case-{k:03d}" / "recording", overwrite=overwrite)
    machine = load_machine()
    out = []
    for k in range(count):
        case_seed = int(seed) * 1000 + k
        rng = np.random.default_rng(case_seed)
        if clean:
            names = []
        elif effects == "random":
            m = int(rng.integers(1, max_effects + 1))
            pool = EFFECTS if plant == "batch" else [e for e in EFFECTS if e in LOOP_EFFECTS + SHARED_EFFECTS]
            names = [str(x) for x in rng.choice(pool, size=min(m, len(pool)), replace=False)]
        else:
            names = list(effects)
        case = synth_case(rng, names, run=run, duration_s=duration_s, rate_hz=rate_hz,
                          magnitude_scale=magnitude_scale, noise_scale=noise_scale,
                          machine=machine, seed=case_seed, plant=plant)
        out.append(write_case(out_dir, f"case-{k:03d}", case, overwrite=overwrite))
        if progress:
            progress(k, out[-1], case)
    return out


# ---------------------------------------------------------------- CLI

def add_parser(sub):
    """Register ``synth`` (the registration lives in :mod:`pmctl.tools.twin.cli`, without numpy)."""
    from pmctl.tools.twin.cli import add_synth_parser
    return add_synth_parser(sub)


def _cmd(args) -> int:
    if args.count < 1:
        raise InputError("--count", None, "must be >= 1")
    if args.duration is not None and not 1.0 <= args.duration <= 7200:
        raise InputError("--duration", None, "must be 1..7200 s")
    if args.rate is not None and not 20 <= args.rate <= 20000:
        raise InputError("--rate", None, "must be 20..20000 Hz")
    if not 0 < args.magnitude_scale <= 100 or not 0 <= args.noise_scale <= 100:
        raise InputError("--magnitude-scale/--noise-scale", None, "must be > 0 (noise >= 0) and <= 100")
    plant = getattr(args, "plant", "batch")
    if plant == "loop" and args.rate is not None and not 200 <= args.rate <= 5000:
        raise InputError("--rate", None, "with --plant loop must be 200..5000 Hz (the control loop's tick rate)")
    if plant == "loop" and args.run == "warmup":
        raise InputError("--run", None, "warmup runs heat the screws; the sim carries no thermal model: use --plant batch")
    if args.clean and args.effects != "random":
        raise InputError("--clean", None, f"contradicts --effects {args.effects}: a clean case hides no effect")
    if getattr(args, "machine", "prototype") == "axes":
        return _cmd_axes(args)
    eff = parse_effects(args.effects)
    if plant == "loop" and eff != "random":
        bad = [nm for nm in eff if nm not in LOOP_EFFECTS + SHARED_EFFECTS + ("resonance", "forced_vibration")]
        if bad:
            raise InputError("--effects", None, f"the sim plant does not carry {', '.join(bad)}; use --plant batch "
                             f"(--plant loop: {', '.join(LOOP_EFFECTS + SHARED_EFFECTS)}, and resonance or "
                             f"forced vibration in a strain channel)")
    t0 = time.perf_counter()

    def progress(k, d, case):
        names = ", ".join(f"{e['effect']}" for e in case.answer["effects"]) or "clean"
        print(f"{d}  {case.answer['run']:<11s} {len(case.columns['t']):>7d} samples  [{names}]", flush=True)

    generate(args.out_dir, args.count, effects=eff, seed=args.seed, clean=args.clean,
             max_effects=args.max_effects, run=args.run, duration_s=args.duration, rate_hz=args.rate,
             magnitude_scale=args.magnitude_scale, noise_scale=args.noise_scale,
             progress=progress, overwrite=args.force, plant=plant)
    print(f"{args.count} case(s) in {time.perf_counter() - t0:.1f} s; answer keys are beside, not in, "
          f"each recording folder")
    return 0


def _cmd_axes(args) -> int:
    """``--machine axes``: bench runs of one ball-screw axis (pmctl.tools.twin.synth_axes)."""
    from pmctl.tools.twin.synth_axes import AXIS_EFFECTS, DRIVE, synth_axes_case, write_axes_case
    if args.effects == "random":
        names = None
    else:
        names = [e.strip() for e in args.effects.split(",") if e.strip()]
        bad = [e for e in names if e not in AXIS_EFFECTS]
        if bad:
            raise InputError("--effects", None, f"{', '.join(bad)}: not an effect of a bench axis; one of "
                                                f"{', '.join(AXIS_EFFECTS)}")
    if args.plant != "batch" or args.run is not None:
        raise InputError("--machine axes", None, "takes neither --plant loop nor --run (a bench axis has its own moves)")
    out = Path(args.out_dir)
    for k in range(args.count):
        rng = np.random.default_rng([args.seed, k])
        if args.clean:
            eff = []
        elif names is not None:
            eff = names
        else:      # the drive's force model always (every drive has one), and up to K other effects
            extra = [e for e in AXIS_EFFECTS if e not in DRIVE]
            eff = list(DRIVE) + list(rng.choice(extra, size=min(max(args.max_effects, 1), len(extra)), replace=False))
        case = synth_axes_case(rng, eff, clean=args.clean, duration_s=args.duration or 20.0, rate_hz=args.rate or 1000.0)
        write_axes_case(out, f"case-{k:03d}", case, overwrite=args.force)
        print(f"case-{k:03d}  bench axis  {len(case[0]['t']):>7d} samples  [{', '.join(eff) or 'clean'}]", flush=True)
    print(f"{args.count} case(s); answer keys are beside, not in, each recording folder")
    return 0
