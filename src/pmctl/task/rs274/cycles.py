"""Canned cycles G73, G74, G81-G86, G89 (G98/G99, R, Q, P, L), expanded into rapids, feeds, dwells
and spindle events as LinuxCNC expands them.

In the plane's coordinates (G17: X Y, drilling along Z; G18: Z X along Y; G19: Y Z along X), a cycle
block positions at its hole (X Y) and drills from the R plane to the bottom (Z):

- **Position.** If the tool is below the R plane it first rises to R. For each of the L repeats
  (incremental X Y add up per repeat in G91), a rapid in the plane at the clearance height (the first
  time at the current height if that is above R), then a rapid down to R.
- **Clearance** (the height between holes): G99 the R plane; G98 the height where the series of
  cycles started (LinuxCNC's "initial level", kept until a non-cycle motion), if above R.
- **G91**: R is measured from the initial level, Z from R.
- **The cycles**: G81 feed to Z, rapid out. G82 the same with a dwell of P seconds at the bottom.
  G73 pecks of Q with a 0.254 mm (0.010 in) back-off between them (chip break). G83 pecks of Q,
  each followed by a rapid out to R and a rapid back to 0.254 mm (0.010 in) above the last depth
  (deep hole). G85 feed in, feed out. G86 feed in, dwell P, spindle stop, rapid out, spindle on
  again. G89 feed in, dwell P, feed out. G84 (right-hand tap, spindle clockwise) and G74 (left-hand,
  counter-clockwise): feed in, spindle reversed, dwell P, feed out, spindle restored -- for a
  floating tap holder: F must match the pitch x S (this machine has no spindle encoder to
  synchronise to).
- R, Z, P, Q are remembered while the same cycle stays in force; a new cycle needs R and Z (and P or
  Q where it uses them). L is not remembered (default 1).

Refused: G87 (back boring needs spindle orientation) and G88 (a manual retract) -- this machine has
neither --, cycles with cutter compensation on or in inverse time (G93), and cycles whose drilling
axis is not the tool axis: with the tool tilted (A or B not 0) or in G18/G19, the drill would cut
sideways.
"""

from __future__ import annotations

import math

from pmctl.task.job import LINE, RAPID
from pmctl.task.rs274.arcs import PLANE_AXES
from pmctl.task.rs274.execute import Refusal, fmt, gname

PECK_CLEARANCE_IN = 0.010            # LinuxCNC's G73/G83 back-off (inch)
NEEDS_P = (820, 860, 890)
NEEDS_Q = (730, 830)


def run_cycle(ex, st, blk, motion, explicit, axis_words):
    v, col = blk.v, blk.col
    mc = blk.groups.get(1, (None, None))[1] or (col[axis_words[0]] if axis_words else None)
    name = gname(motion)
    if motion == 870:
        ex.note("machine", "G87 (back boring) needs spindle orientation (M19) to pass the tool through the hole, "
                           "which this machine lacks", mc)
    if motion == 880:
        raise Refusal("unsupported", "G88 (boring with a manual retract) is not supported: the spindle cannot be "
                                     "retracted by hand on this machine; use G86", mc)
    if st.feed_mode == 930:
        raise Refusal("syntax", f"{name} in inverse time (G93): canned cycles need G94", mc)
    if st.comp:
        raise Refusal("syntax", f"{name} with cutter compensation on: turn it off (G40) first", mc)
    if not st.feed > 0:
        raise Refusal("syntax", f"{name} with no F: set a feed rate (F, > 0) on this line or before", mc)
    for k in "ab":
        if k in v:
            raise Refusal("syntax", f"{k.upper()}{fmt(v[k])} in a canned cycle: the tool axis cannot move during a "
                                    "cycle (tilt it on a line of its own)", col[k])
    fi, si, ti = PLANE_AXES[st.plane]
    if st.plane != 170:
        ex.note("machine", f"{name} in {('G18', 'G19')[st.plane == 190]} drills along {'XYZ'[ti]}; this machine's "
                           "tool points along Z (tilted at most a few degrees): drill in G17", mc)
    else:
        ax = ex.axis(st.pos[3], st.pos[4])
        if abs(ax[2] - 1.0) > 1e-12:
            ex.note("machine", f"{name} with the tool tilted (A{fmt(st.pos[3])} B{fmt(st.pos[4])}): the cycle drills "
                               "along Z, not along the tool; level the tool (A0 B0) first", mc)
    prev = ex.prev_motion
    mem = dict(st.cycle or {})
    third = "xyz"[ti]
    u = st.units
    if "r" not in v:
        if prev != motion or "r" not in mem:
            raise Refusal("syntax", f"{name} needs R (the retract plane) when the cycle starts", mc)
        r_word = mem["r"]
    else:
        r_word = v["r"] * u
    if third not in v:
        if prev != motion or "z" not in mem:
            raise Refusal("syntax", f"{name} needs {third.upper()} (the bottom of the hole) when the cycle starts",
                          mc)
        z_word = mem["z"]
    else:
        z_word = v[third] * u
    repeats = 1
    if "l" in v:
        L = v["l"]
        if L != int(L) or L < 0:
            raise Refusal("syntax", f"{name} L{fmt(L)}: L (repeats) must be a positive integer", col["l"])
        if L == 0:
            raise Refusal("syntax", f"{name} L0: a cycle cannot be repeated zero times", col["l"])
        repeats = int(L)
    dwell = 0.0
    if motion in NEEDS_P or motion in (740, 840):
        if "p" in v:
            dwell = v["p"]
            if dwell < 0:
                raise Refusal("syntax", f"{name} P{fmt(dwell)}: the dwell must be >= 0", col["p"])
        elif prev != motion and motion in NEEDS_P:
            raise Refusal("syntax", f"{name} needs P (the dwell at the bottom, seconds) when the cycle starts", mc)
        else:
            dwell = mem.get("p", 0.0)
    delta = 0.0
    if motion in NEEDS_Q:
        if "q" in v:
            delta = v["q"] * u
        elif prev != motion or "q" not in mem:
            raise Refusal("syntax", f"{name} needs Q (the peck depth) when the cycle starts", mc)
        else:
            delta = mem["q"]
        if not delta > 0:
            raise Refusal("syntax", f"{name} Q{fmt(delta / u)}: the peck depth must be > 0", col.get("q", mc))
    if motion in (740, 840):
        want = -1 if motion == 740 else 1
        if st.spindle != want or not st.speed > 0:
            raise Refusal("syntax", f"{name} needs the spindle turning {'counter-clockwise (M4)' if want < 0 else 'clockwise (M3)'} "
                                    "at a speed (S)", mc)
    if motion in (860, 870) and (not st.spindle or not st.speed > 0):
        raise Refusal("syntax", f"{name} needs the spindle turning (M3/M4 S)", mc)

    if motion == 870:
        if prev != motion:
            for k in "ijk":
                if k not in v:
                    raise Refusal("syntax", f"G87 needs I J K (the offset and the top of the back bore) when the "
                                            "cycle starts", mc)
        bi = v["i"] * u if "i" in v else mem.get("i", 0.0)
        bj = v["j"] * u if "j" in v else mem.get("j", 0.0)
        bk = v["k"] * u if "k" in v else mem.get("k", 0.0)
        mem.update(i=bi, j=bj, k=bk)
    p = ex.to_prog(st, st.pos)
    cur_cc = p[ti]
    old_cc = st.cycle_il if st.cycle_il is not None else cur_cc
    st.cycle_il = old_cc
    polar = ("@" in v or "^" in v)
    if polar and ("x" in v or "y" in v or st.plane != 170):
        raise Refusal("syntax", "polar coordinates (@ ^) in a canned cycle go in G17 without X and Y", mc)
    r_inc = th_inc = 0.0
    if st.absolute:
        aa_inc = bb_inc = 0.0
        r = r_word
        cc = z_word
        aa = v["xyz"[fi]] * u if "xyz"[fi] in v else p[fi]
        bb = v["xyz"[si]] * u if "xyz"[si] in v else p[si]
        if polar:
            rad = v["@"] * u if "@" in v else math.hypot(p[0], p[1])
            th = math.radians(v["^"]) if "^" in v else math.atan2(p[1], p[0])
            aa, bb = rad * math.cos(th), rad * math.sin(th)
    else:
        aa_inc = v["xyz"[fi]] * u if "xyz"[fi] in v else 0.0
        bb_inc = v["xyz"[si]] * u if "xyz"[si] in v else 0.0
        r_inc = v["@"] * u if "@" in v else 0.0
        th_inc = math.radians(v["^"]) if "^" in v else 0.0
        r = r_word + old_cc
        cc = r + z_word
        aa, bb = p[fi], p[si]
    if motion == 870 and not st.absolute:
        bk = cc + bk
    if r < cc:
        raise Refusal("syntax", f"{name}: the R plane ({fmt(r / u)}) is below the bottom {third.upper()} "
                                f"({fmt(cc / u)})", col.get("r", mc))
    feed = st.feed / 60.0
    peck = PECK_CLEARANCE_IN * 25.4

    def point(a, b, c):
        q = list(p)
        q[fi], q[si], q[ti] = a, b, c
        return ex.to_w(st, q)

    def rapid(a, b, c):
        ex.move(st, RAPID, point(a, b, c))

    def cut(a, b, c):
        ex.move(st, LINE, point(a, b, c), feed=feed)

    def down(a, b):                              # feed to the bottom and wait there
        cut(a, b, cc)
        if dwell > 0:
            ex.dwell(st, dwell)

    if old_cc < r:
        rapid(p[fi], p[si], r)
        old_cc = r
        cur_cc = r
    clear = r if st.retract == 990 else old_cc
    rpm = st.speed * st.spindle
    for k in range(repeats):
        aa += aa_inc
        bb += bb_inc
        if r_inc or th_inc:
            if aa == 0.0 and bb == 0.0:
                raise Refusal("syntax", "incremental polar coordinates (@ ^) from the origin: the angle is "
                                        "undefined there", mc)
            rad, th = math.hypot(aa, bb) + r_inc, math.atan2(bb, aa) + th_inc
            aa, bb = rad * math.cos(th), rad * math.sin(th)
        if k == 0 and cur_cc > r:
            rapid(aa, bb, cur_cc)
            rapid(aa, bb, r)
        else:
            rapid(aa, bb, clear)
            if clear > r:
                rapid(aa, bb, r)
        if motion == 810:
            cut(aa, bb, cc)
            rapid(aa, bb, clear)
        elif motion == 820:
            down(aa, bb)
            rapid(aa, bb, clear)
        elif motion in (730, 830):
            depth = r - delta
            while depth > cc:
                cut(aa, bb, depth)
                if motion == 830:
                    rapid(aa, bb, r)
                rapid(aa, bb, depth + peck)
                depth -= delta
            cut(aa, bb, cc)
            rapid(aa, bb, clear)
        elif motion in (740, 840):
            cut(aa, bb, cc)
            ex.spindle_now(st, -rpm)
            if dwell > 0:
                ex.dwell(st, dwell)
            cut(aa, bb, clear)
            ex.spindle_now(st, rpm)
        elif motion == 850:
            cut(aa, bb, cc)
            cut(aa, bb, r)
            rapid(aa, bb, clear)
        elif motion == 860:
            down(aa, bb)
            saved = st.spindle
            ex.spindle_now(st, 0.0)
            st.spindle = 0
            rapid(aa, bb, clear)
            st.spindle = saved
            ex.spindle_now(st, rpm)
        elif motion == 890:
            down(aa, bb)
            cut(aa, bb, clear)
        elif motion == 870:
            ox, oy = aa + bi, bb + bj
            rapid(ox, oy, r)
            ex.spindle_now(st, 0.0)
            rapid(ox, oy, cc)
            rapid(aa, bb, cc)
            ex.spindle_now(st, rpm)
            cut(aa, bb, bk)
            cut(aa, bb, cc)
            ex.spindle_now(st, 0.0)
            rapid(ox, oy, cc)
            rapid(ox, oy, clear)
            rapid(aa, bb, clear)
            ex.spindle_now(st, rpm)
    mem.update(r=r_word, z=z_word)
    if motion in NEEDS_P or motion in (740, 840):
        mem["p"] = dwell
    if motion in NEEDS_Q:
        mem["q"] = delta
    st.cycle = mem
