"""Concealed-effect recordings of a machine of independent axes (``"machine": "axes"``): a ball-screw
axis on a test bench, with the physics of real drives and a separate answer key.

One plant, the one the prototype's synth and the sim backend use (pmctl.core.plant_effects): the
drive's force (:func:`drive_force`), the servo's lag (:func:`first_order_lag`), backlash (the play
operator), a flexible mode (:func:`mode_response`), periodic errors. Per axis:

- ``cmd_<A>``: back-and-forth moves between random targets with trapezoidal speed profiles at a
  few speeds, with dwells (the bang-bang excitation of drive identification);
- motor side ``enc_<A>``: the command through the servo (a first-order lag ``servo_tracking``,
  τ = ``lag_s``; else ideal), quantised to the encoder's count;
- the force ``effort_<A>``: the drive's force model (``inertia`` ``mass_kg``, ``friction``
  ``coulomb_N`` ``viscous_N_s_per_m`` (and ``viscous_neg_N_s_per_m`` when asymmetric),
  ``force_offset`` ``offset_N``) at the motor side's motion, plus ``cogging`` (``period_mm``,
  ``amplitude_N``) and noise;
- load side ``load_<A>`` (a linear scale): the motor side plus ``backlash`` (``width_mm``) and the
  give of ``compliance`` (−F/``stiffness_N_per_mm``), quantised;
- ``acc_<A>``: the load side's acceleration plus a ``resonance`` of the carriage (``freq_hz``,
  ``damping_ratio``; an accelerometer reads y'') and noise.

Out of the catalogue (``oddities``): ``external_force`` (a push on the carriage for a moment:
the drive's force answers it, no effect of the catalogue does). A ``clean`` case has an ideal servo,
no force channel and no effects.

``synth_axes_case(rng, effects=..., ...) -> (columns, notes, answer)``; ``write_axes_case(out, name,
case)``; the answer key uses the diagnosis report's names.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pmctl.core.plant_effects import drive_force, first_order_lag, mode_response, periodic_error, play_load
from pmctl.core.recording import write_recording

AXIS_EFFECTS = ("inertia", "friction", "force_offset", "servo_tracking", "backlash", "compliance",
                "resonance", "cogging")
AXIS_ODDITIES = ("external_force",)
DRIVE = ("inertia", "friction", "force_offset")


def _profile(n_moves, rng, stroke_mm, speeds, accel, dwell, dt, x0=0.0):
    """Commanded positions: trapezoidal moves between random targets within ±stroke/2 of x0."""
    xs = [np.array([x0])]
    x = x0
    for k in range(n_moves):
        target = x0 + rng.uniform(-0.5, 0.5) * stroke_mm
        if abs(target - x) < 0.1 * stroke_mm:
            target = x0 + (0.45 * stroke_mm if x < x0 else -0.45 * stroke_mm)
        d = target - x
        v = speeds[k % len(speeds)]
        ta = v / accel
        if abs(d) < v * ta:                      # triangular
            ta = np.sqrt(abs(d) / accel)
            v = accel * ta
        tc = abs(d) / v - ta
        T = 2 * ta + tc
        t = np.arange(1, int(np.ceil(T / dt)) + 1) * dt
        t = np.minimum(t, T)
        s = np.where(t < ta, 0.5 * accel * t ** 2,
                     np.where(t < ta + tc, 0.5 * accel * ta ** 2 + v * (t - ta),
                              abs(d) - 0.5 * accel * np.maximum(T - t, 0) ** 2))
        xs.append(x + np.sign(d) * s)
        x = target
        nd = int(rng.uniform(*dwell) / dt)
        xs.append(np.full(nd, x))
    return np.concatenate(xs)


def default_effects(rng, effects, rotary=False):
    """Parameters of the listed effects, drawn at a bench's magnitudes."""
    out = {}
    for e in effects:
        if e == "inertia":
            out[e] = {"mass_kg": float(rng.uniform(20, 150))}
        elif e == "friction":
            out[e] = {"coulomb_N": float(rng.uniform(8, 40)), "viscous_N_s_per_m": float(rng.uniform(80, 400))}
        elif e == "force_offset":
            out[e] = {"offset_N": float(rng.choice([-1, 1]) * rng.uniform(3, 30))}
        elif e == "servo_tracking":
            out[e] = {"lag_s": float(rng.uniform(0.002, 0.012))}
        elif e == "backlash":
            out[e] = {"width_mm": float(rng.uniform(0.005, 0.03))}
        elif e == "compliance":
            out[e] = {"stiffness_N_per_mm": float(rng.uniform(2e3, 2e4))}
        elif e == "resonance":
            out[e] = {"freq_hz": float(rng.uniform(25, 120)), "damping_ratio": float(rng.uniform(0.02, 0.1))}
        elif e == "cogging":
            out[e] = {"period_mm": float(rng.uniform(2.0, 8.0)), "amplitude_N": float(rng.uniform(2, 6))}
        else:
            raise ValueError(f"unknown effect {e!r}: one of {', '.join(AXIS_EFFECTS)}")
    return out


def synth_axes_case(rng, effects=(), *, params=None, oddities=(), duration_s=20.0, rate_hz=1000.0,
                    axis="X", stroke_mm=200.0, clean=False, count_mm=5e-5, noise_N=0.5, noise_acc=50.0):
    """(columns, channel notes, answer) of one bench run of axis ``axis`` with the hidden effects.
    ``params``: {effect: {parameter: value}} overriding the drawn ones. Positions are written in m
    (units in the notes, converted on read)."""
    params = {**default_effects(rng, [e for e in effects if e not in (params or {})]), **(params or {})}
    dt = 1.0 / rate_hz
    n_moves = max(4, int(duration_s / 1.2))
    cmd = _profile(n_moves, rng, stroke_mm, speeds=(50.0, 150.0, 300.0, 100.0), accel=3000.0,
                   dwell=(0.05, 0.3), dt=dt, x0=stroke_mm)
    # jerk-limited: the trapezoids through a 25 ms moving average (a drive's force cannot step)
    k = max(int(round(0.025 / dt)), 1)
    for _ in range(2):       # twice: the acceleration ramps, and so does the jerk
        cmd = np.convolve(np.concatenate([np.full(k, cmd[0]), cmd, np.full(k, cmd[-1])]), np.ones(k) / k, "same")[k:-k]
    n = min(len(cmd), int(duration_s * rate_hz))
    cmd = cmd[:n]
    t = np.arange(n) * dt
    # the motor side: through the servo
    lag = params.get("servo_tracking", {}).get("lag_s")
    motor = first_order_lag(t, cmd, lag) if lag else cmd.copy()
    v = np.gradient(motor, dt)
    a = np.gradient(v, dt)
    ip, fp, op = params.get("inertia", {}), params.get("friction", {}), params.get("force_offset", {})
    F = drive_force(v, a, mass=ip.get("mass_kg", 0.0) / 1000.0, viscous=fp.get("viscous_N_s_per_m", 0.0) / 1000.0,
                    coulomb=fp.get("coulomb_N", 0.0), offset=op.get("offset_N", 0.0),
                    viscous_neg=(fp["viscous_neg_N_s_per_m"] / 1000.0 if "viscous_neg_N_s_per_m" in fp else None),
                    v_dead=1e-3 * float(np.quantile(np.abs(v), 0.99)))
    if "cogging" in params:
        c = params["cogging"]
        F = F + periodic_error(motor, c["amplitude_N"], c["period_mm"], float(rng.uniform(0, 2 * np.pi)))
    ext = None
    if "external_force" in oddities:
        t0 = float(rng.uniform(0.3, 0.6) * t[-1])
        push = float(rng.choice([-1, 1]) * rng.uniform(20, 40))
        bump = push * np.exp(-0.5 * ((t - t0) / 0.05) ** 2)        # a push of about 0.2 s
        F = F + bump                          # the drive holds the axis against the push
        ext = {"kind": "external_force", "channels": [f"effort_{axis}"], "t_s": t0, "peak_N": push}
    load = motor.copy()
    if "backlash" in params:
        load = play_load(motor, params["backlash"]["width_mm"])
    if "compliance" in params:
        load = load - F / params["compliance"]["stiffness_N_per_mm"]
    acc = np.gradient(np.gradient(load, dt), dt)
    if "resonance" in params:
        r = params["resonance"]
        y = mode_response(load, dt, r["freq_hz"], r["damping_ratio"])
        acc = acc + np.gradient(np.gradient(y, dt), dt)
    q = count_mm

    def quant(x):
        return np.round(x / q) * q
    cols = {"t": t, f"cmd_{axis}": cmd / 1000.0, f"enc_{axis}": quant(motor) / 1000.0}
    notes = {f"cmd_{axis}": {"unit": "m"}, f"enc_{axis}": {"unit": "m", "source": "motor encoder"}}
    if not clean:
        cols[f"effort_{axis}"] = F + rng.normal(0, noise_N, n)
        notes[f"effort_{axis}"] = {"unit": "N", "source": "drive force (current x force constant)"}
    if clean or any(e in params for e in ("backlash", "compliance")):
        cols[f"load_{axis}"] = quant(load + rng.normal(0, 0.2 * q, n)) / 1000.0
        notes[f"load_{axis}"] = {"unit": "m", "source": "linear scale"}
    if clean or "resonance" in params:
        cols[f"acc_{axis}"] = (acc + rng.normal(0, noise_acc, n)) / 1000.0
        notes[f"acc_{axis}"] = {"unit": "m/s^2", "source": "accelerometer on the carriage"}
    answer = {"machine": "axes", "effects": [], "oddities": [ext] if ext else []}
    for e, p in params.items():
        loc = {"channel": f"acc_{axis}"} if e == "resonance" else {"axis": axis}
        answer["effects"].append({"effect": e, **loc, "parameters": dict(p)})
    return cols, notes, answer


def write_axes_case(out_dir, name, case, *, overwrite=False) -> Path:
    """OUT_DIR/NAME/recording/ and OUT_DIR/NAME/answer.json (the answer outside the recording)."""
    cols, notes, answer = case
    d = Path(out_dir) / name
    rec = write_recording(d / "recording", cols, machine="axes", sample_rate_hz=1.0 / float(cols["t"][1] - cols["t"][0]),
                          description="synth bench run of an axis (pmctl twin synth --machine axes)",
                          channel_notes=notes, overwrite=overwrite)
    (d / "answer.json").write_text(json.dumps({"case": name, "recording": "recording", **answer}, indent=2) + "\n",
                                   encoding="utf-8")
    return rec
