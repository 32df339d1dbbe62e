"""Jogging (grbl's ``$J=``): a short straight move from where the machine is, planned and run like
any other motion (so a jog cancel decelerates on the path), refused before it moves if any point of
it leaves the workspace.

``$J=`` takes ``G20``/``G21``, ``G90``/``G91``, ``G53``, axis words ``X Y Z A B`` and ``F`` (required);
nothing else (grbl's error 16). The modes apply to the jog only, never to the parser.
"""

from __future__ import annotations

import math

import numpy as np

from pmctl.core import kinematics as K
from pmctl.task.interp import AXES, LineError
from pmctl.task.job import LINE, Job, Move
from pmctl.task.rs274.modal import MM_PER_INCH
from pmctl.task.rs274.words import LexError, lex_line

CHECK_POINTS = 64


def parse_jog(text: str, interp, start_tip, start_axis):
    """(end tip, end axis, feed mm/s) of a jog line in the console's frame; raises LineError."""
    try:
        ln = lex_line(text)
    except LexError as e:
        raise LineError(1 if "word letter" in e.message else 16, f"bad jog line: {e.message}") from None
    if ln.oword is not None or ln.assigns or ln.delete or ln.percent:
        raise LineError(16, "bad jog line: only G20 G21 G90 G91 G53, axis words and F")
    words = []
    for letter, v, _ in ln.words:
        if v.__class__ is not float:
            raise LineError(16, "a jog takes plain numbers (no expressions or parameters)")
        words.append((letter.upper(), v))
    st = interp.st
    units, absolute, machine = st.units, st.absolute, False
    vals = {}
    for k, v in words:
        if k == "G":
            c = round(v * 10)
            if c == 200:
                units = MM_PER_INCH
            elif c == 210:
                units = 1.0
            elif c == 900:
                absolute = True
            elif c == 910:
                absolute = False
            elif c == 530:
                machine = True
            else:
                raise LineError(16, f"G{v:g} not allowed in a jog")
        elif k in AXES or k == "F":
            if k in vals:
                raise LineError(25, f"{k} repeated")
            vals[k] = v
        elif k == "N":
            continue
        else:
            raise LineError(16, f"{k} not allowed in a jog")
    if vals.get("F", 0.0) < 0:
        raise LineError(4, "jog feed F must not be negative")      # grbl: negative value
    if "F" not in vals or not vals["F"] > 0:
        raise LineError(22, "jog needs a feed F > 0")
    if not any(k in vals for k in AXES):
        raise LineError(26, "jog needs an axis word")
    a0, b0 = (math.degrees(float(x)) for x in K.roll_pitch_from_axis(np.asarray(start_axis, float)))
    cur = [*map(float, start_tip), a0, b0]
    wco = [0.0] * 5 if machine else interp.wco()
    end = list(cur)
    for i, k in enumerate(AXES):
        if k in vals:
            v = vals[k] * (units if i < 3 else 1.0)
            end[i] = (v + wco[i]) if absolute else cur[i] + v
    tip = np.array(end[:3])
    axis = K.axis_from_roll_pitch(math.radians(end[3]), math.radians(end[4]))
    return tip, np.asarray(axis, float), vals["F"] * units / 60.0


def check_jog(machine, params, start_tip, start_axis, tip, axis):
    """Every point of the straight jog (tip on the line, axis slerped as the planner does) reachable
    and inside the joint soft limits; LineError 15 otherwise."""
    u = np.linspace(0.0, 1.0, CHECK_POINTS)[:, None]
    tips = start_tip + u * (tip - start_tip)
    a0, a1 = np.asarray(start_axis, float), np.asarray(axis, float)
    phi = math.acos(max(-1.0, min(1.0, float(a0 @ a1))))
    if phi < 1e-9:
        axes = np.repeat(a1[None], CHECK_POINTS, 0)
    else:
        axes = (np.sin((1 - u) * phi) * a0 + np.sin(u * phi) * a1) / math.sin(phi)
    lo, hi = machine.limits.theta2_deg
    if np.any(np.degrees(np.arccos(np.clip(axes[:, 2], -1, 1))) > min(abs(lo), abs(hi))):
        raise LineError(15, "jog target exceeds the tilt range")
    r = K.ik_batch(tips, axes, machine)
    if not np.all(r.ok):
        raise LineError(15, f"jog leaves the workspace: {r.reason[int(np.argmax(~r.ok))]}")
    q = r.q
    if np.any(q < params.lower) or np.any(q > params.upper):
        raise LineError(15, "jog target exceeds machine travel (joint soft limits)")


def jog_job(tip, axis, feed) -> Job:
    return Job((Move(LINE, np.asarray(tip, float), np.asarray(axis, float), line=0, feed=float(feed)),),
               "jog", np.asarray(tip, float)[None], np.zeros(1, int))


def make_jogger(sup):
    """The console's ``$J=`` handler: check, then queue; the parser position follows the jog."""
    def jog(text, interp):
        start_tip, start_axis = sup.end_pose()
        tip, axis, feed = parse_jog(text, interp, start_tip, start_axis)
        check_jog(sup.machine, sup.params, np.asarray(start_tip), np.asarray(start_axis), tip, axis)
        if sup.check_mode:
            return
        if np.linalg.norm(tip - start_tip) < 1e-9 and float(np.asarray(axis) @ np.asarray(start_axis)) > 1 - 1e-15:
            return
        sup.submit(jog_job(tip, axis, min(feed, 50.0)), kind="jog", name="jog")
        interp.sync(tip, axis)
    return jog
