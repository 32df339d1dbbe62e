"""pmctl's RS-274 interpreter against LinuxCNC's (``rs274`` of linuxcnc-uspace, tests/peers/linuxcnc.apt):
the same program gives the same motion -- end points, arc centres, normals and sweeps, feeds, dwells,
tool length offsets -- within what rs274 prints (4 decimals of the program's unit).

Three sources of programs: LinuxCNC's own sample programs (installed with it in
/usr/share/linuxcnc/ncfiles), programs written here per feature, and programs generated under
hypothesis (lines, arcs in the three planes with I J K and R, G91, G20, work offsets and G92, G28/G30,
canned cycles, cutter compensation, parameters and expressions, O-word subroutines and loops).

Known differences, by design (docs/gcode.md), kept out of the generated programs: a tool length offset
that changes while the tool is tilted moves the tip along the tool axis here, along Z in LinuxCNC;
rs274 (standalone) does not convert a tool offset set in mm when the program then switches to G20.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import rs274_oracle as O
from pmctl.task.rs274 import interpret, make_config
from pmctl.task.rs274.tools import Tool, ToolTable

NCFILES = Path("/usr/share/linuxcnc/ncfiles")
TOOLS = [(1, 10.0, 6.0), (2, -5.5, 3.0), (3, 0.0, 10.0), (4, 25.0, 2.0), (5, 0.0, -2.0)]
CFG = make_config(tools=ToolTable([Tool(n, k + 1, length, d) for k, (n, length, d) in enumerate(TOOLS)], "t.tbl"))


def both(text, tools=TOOLS, cfg=CFG):
    """(rs274 result, pmctl job, pmctl problems)."""
    return O.run(text, tools), *interpret(text, "t.ngc", cfg=cfg)


def agree(text, *, want_motions=1):
    res, job, problems = both(text)
    assert res.ok, f"rs274 refused the program: {res.error}\n{text}"
    assert not problems, [str(p) for p in problems]
    diffs, n, worst = O.compare(O.pmctl_motions(job), res.motions)
    assert not diffs, "\n".join(diffs) + "\n" + text
    assert n >= want_motions
    return n, worst


def test_rs274_is_installed_and_answers():
    assert O.available(), "rs274 missing: tests/peers/install installs linuxcnc-uspace"
    res = O.run("G21 G0 X1 Y2 Z3\nM2\n")
    assert res.ok and [m.end[:3] for m in res.motions] == [(1.0, 2.0, 3.0)]


# ---------------------------------------------------------------- LinuxCNC's sample programs

# Files pmctl and rs274 both run, with the same motion (the rest: see REFUSED below)
SAMPLES_AGREE = ["3D_Chips.ngc", "3dtest.ngc", "arcspiral.ngc", "b-index.ngc", "cds.ngc", "comp-g1.ngc",
                 "comp311.ngc", "comp311_2.ngc", "daisy.ngc", "flowsnake.ngc", "gmoccapy_2_tools_with_cutter_radius_compensation.ngc",
                 "hole-circle.ngc", "lathe_pawn.ngc", "offsets.ngc", "plasmatest.ngc", "polar.ngc", "retval.ngc",
                 "spiral.ngc", "tort.ngc", "factorial.ngc", "g20sub.ngc", "roparams.ngc", "touchoff.ngc", "m6demo.ngc",
                 "m61demo.ngc", "testm6fail.ngc", "m250.ngc", "m75.ngc", "m76.ngc", "g881.ngc", "g881min.ngc",
                 "g882.ngc", "m6remap.ngc"]
# Files refused here on purpose, with the kind and the words of the reason
SAMPLES_REFUSED = {
    "threading.ngc": ("machine", "G33 (spindle-synchronised motion) needs a spindle encoder"),
    "g76.ngc": ("unsupported", "cutter compensation runs in the XY plane (G17) only"),
    "lathecomp.ngc": ("unsupported", "cutter compensation runs in the XY plane (G17) only"),
    "comp.ngc": ("unsupported", "cutter compensation runs in the XY plane (G17) only"),
    "lathe_g7x_quadrants.ngc": ("machine", "G70 (a lathe finishing cycle): this machine is a mill"),
    "smartprobe.ngc": ("unsupported", "(logopen,...): writing files from a program is not supported"),
    "gridprobe.ngc": ("unsupported", "(probeclose,...): writing files from a program is not supported"),
    "skeleton.ngc": ("machine", "G53 Z0: machine Z 0 mm is at or below the table top"),
    "mmount.ngc": ("machine", "G53 Z0: machine Z 0 mm is at or below the table top"),
    "cone.ngc": ("machine", "C0: axis C is not on this machine"),
}


@pytest.mark.parametrize("name", SAMPLES_AGREE)
def test_linuxcnc_sample_programs_give_the_same_motion(name):
    path = NCFILES / name
    text = path.read_text(errors="replace")
    res, job, problems = both(text)
    assert res.ok and not problems, (res.error, [str(p) for p in problems])
    diffs, n, worst = O.compare(O.pmctl_motions(job), res.motions)
    assert not diffs, diffs


def test_the_spline_sample_runs_and_ends_where_rs274_ends():
    # systems.ngc draws with G5.1: rs274 prints NURBS_FEED without its points, so what can be compared is
    # every other motion, in order, and that pmctl's flattened curves end where rs274's next motion starts
    text = (NCFILES / "systems.ngc").read_text()
    res, job, problems = both(text)
    assert res.ok and not problems
    mine = [m for m in O.pmctl_motions(job)]
    spline_lines = {i + 1 for i, ln in enumerate(text.splitlines()) if "g5.1" in ln.lower().replace(" ", "")}
    straight = [m for m, mv in zip(mine, [m for m in job.moves if m.kind != "event"]) if mv.line not in spline_lines]
    assert len(spline_lines) > 50 and len(straight) < len(mine)
    diffs, n, _ = O.compare(straight, res.motions)
    assert not diffs and n > 200, diffs


@pytest.mark.parametrize("name", ["m70m72-demo.ngc", "m73-demo.ngc", "toplevel.ngc", "retval.ngc"])
def test_modal_state_and_return_values_print_what_rs274_prints(name):
    # these samples say what they do in (DEBUG,) messages with parameter values: M70-M73 save and restore
    # the modes around subroutine calls, o-word returns set #<_value>
    text = (NCFILES / name).read_text()
    res, job, problems = both(text)
    assert res.ok and not problems and res.messages
    assert [t for _, t in job.messages] == [m.strip() for m in res.messages]


@pytest.mark.parametrize("name", sorted(SAMPLES_REFUSED))
def test_linuxcnc_sample_programs_refused_here_say_why(name):
    kind, words = SAMPLES_REFUSED[name]
    _, problems = interpret((NCFILES / name).read_text(errors="replace"), name, cfg=CFG)
    assert problems and any(p.kind == kind and words in p.message for p in problems), [str(p) for p in problems]
    assert all(p.file == name and p.line >= 1 for p in problems)


# ---------------------------------------------------------------- one program per feature

FEATURES = {
    "offsets and rotation": """G21 G90 G17 F200
G10 L2 P1 X10 Y20 Z5
G10 L2 P2 X-5 Y3 R30
G10 L2 P9 X1 Y1 Z1 A2 B-3
G0 X1 Y2 Z3
G55 G0 X4 Y4
G1 X10 Y0
G2 X10 Y10 I0 J5
G59.3 G0 X1 A1
G54 G92 X0 Y0
G0 X5 Y5
G92.2
G0 X5 Y5
G92.3
G0 X6 Y6
G92.1
G52 X2 Y3
G0 X1 Y1
G10 L20 P0 X0 Y0
G0 X2 Y2
G10 L20 P3 Z7
G56 G0 Z0
M2""",
    "tool length": """G21 G90 G17 F300
G0 X0 Y0 Z50
G43 H1
G0 X5
G43 H2
G1 Z20
G43.1 Z7.5
G0 Y5
G53 G0 Z30
G49
G0 Z40
G43 H4
G28.1
G0 X20 Y20 Z10
G28
G30 Z15
M2""",
    "arcs in every plane": """G21 G90 F120
G0 X10 Y0 Z0
G17 G3 X0 Y10 I-10 J0
G2 X10 Y0 Z-3 R10
G3 X10 Y0 Z-6 I-10 J0 P3
G18 G2 X0 Z4 I-5 K5
G3 X10 Z-6 R10
G19 G2 Y10 Z-6 J5 K3
G3 Y-5 Z0 R-9
G90.1 G17 G2 X20 Y-5 I15 J0
G91.1 G91 G3 X-5 Y5 I-5
M2""",
    "canned cycles": """G21 G90 G17 F100 S1000 M3
G0 X0 Y0 Z10
G98 G81 X5 Y5 Z-3 R2
X10
G99 G82 X15 Y5 Z-3 R2 P0.5
G83 X20 Y5 Z-8 R2 Q2.5
G73 X25 Y5 Z-6 R1 Q1
G85 X30 Y5 Z-4 R2
G86 X35 Y5 Z-4 R2 P0.3
G89 X40 Y5 Z-4 R2 P0.2
G84 X45 Y5 Z-4 R2
G91 G81 X5 Y0 Z-3 R2 L4
G90 G80
M4
G74 X0 Y30 Z-4 R2
G80
M2""",
    "cutter compensation": """G21 G90 G17 F300
G0 X-20 Y-20 Z5
G1 Z-1
G41 D1
G1 X0 Y0
G1 X30
G3 X40 Y10 R10
G1 Y30
G2 X30 Y40 I-10 J0
G1 X10
G1 X15 Y20
G1 X0 Y20
G1 Y0
G40
G0 X-20 Y-20
G42 D3
G1 X0 Y0
G1 X20 Y0
G1 X20 Y20 Z-2
G1 X0 Y20
G1 X0 Y0
G40 G1 X-10 Y-10
G41 D1 G1 X0 Y-10
G1 X20
G0 Z5
G40
T2 M6 G0 Z10
G41 D1 G1 X0 Y-10
G1 X20
G0 Z15
G40
T1 M6
G0 Z20
M2""",
    "parameters and expressions": """G21 G90 F100
#1 = 3
#2 = [#1 * 2 + SQRT[16] - ABS[-1]]
#<len> = [ATAN[1]/[1]]
#<_g> = [2 ** 3 MOD 5]
#[#1 + 10] = 7
G0 X#2 Y#<len> Z#13
G1 X[SIN[30] * 10] Y[COS[60] * 10] Z[TAN[45]]
G1 X[FIX[2.7]] Y[FUP[2.1]] Z[ROUND[-2.5]]
G1 X[EXP[1]] Y[LN[10]] Z[ASIN[0.5] / 10]
G1 X[#1 GT 2] Y[#1 EQ 3 AND #2 LT 0] Z[-#<_g>]
G1 X[ACOS[0.5] / 10] Y[7 MOD -3] Z[-7 MOD 3]
G1 X[EXISTS[#<len>]] Y[EXISTS[#<nope>]]
M2""",
    "O-word subroutines and loops": """G21 G90 F500
o<square> sub
  G1 X[#1] Y0
  G1 X[#1] Y[#1]
  G1 X0 Y[#1]
  G1 X0 Y0
  o<square> return [#1 * 2]
o<square> endsub
o100 sub
  o101 if [#1 GT 5]
    G0 Z[#1]
  o101 elseif [#1 GT 2]
    G0 Z[-#1]
  o101 else
    G0 Z0
  o101 endif
o100 endsub
G0 X0 Y0 Z1
o<square> call [5]
G0 X#<_value>
#1 = 0
o200 while [#1 LT 4]
  o<square> call [#1 + 1]
  #1 = [#1 + 1]
  o210 if [#1 EQ 2]
    o200 continue
  o210 endif
  G0 Z[#1]
o200 endwhile
o300 do
  #1 = [#1 - 1]
  o310 if [#1 EQ 1]
    o300 break
  o310 endif
  G0 X[#1 * 3]
o300 while [#1 GT 0]
o400 repeat [3]
  G91 G1 X1 Y1
o400 endrepeat
G90
o100 call [7]
o100 call [3]
o100 call [1]
M2""",
    "Fanuc subprograms": """O1003 (MAIN)
G21 G90 F300
G0 X0 Y0 Z5
M98 P2000 L3
G0 X50
M30
O2000 (SUB)
G91 G1 X5 Y2
G90
M99""",
    "inverse time and feed per rev": """G21 G90 F400
G0 X0 Y0 Z0
G93 G1 X10 Y5 F2
G3 X20 Y5 R5 F4
G1 X30 A5 F1.5
G94 F300
G1 X40
S2000 M3
G95 F0.05
G1 X50
G2 X60 Y5 R5
G94 F250
G1 X0 A0
M2""",
    "inverse time under cutter compensation": """G20 G90 F10
G0 X-1 Y-1 Z0.1
G42.1 D0.4
G93 G1 X1 F30
Y1 F20
X-1 F20
Y2 F40
G94 X1 F33
Y3
G93 G3 Y5 J1 F6.3662
G40 G94 G1 Y6 F25
M2""",
    "a Fanuc-style post": """%
O1001 (PART)
(T1 D=6. CR=0. - ZMIN=-1. - FLAT END MILL)
N10 G90 G94 G17 G40 G49 G80
N15 G21
N20 G28 G91 Z0.
N25 G90
N30 T1 M06
N35 S5000 M03
N40 G54
N45 M08
N50 G00 X10. Y10.
N55 G43 Z15. H01
N60 G00 Z5.
N65 G01 Z-1. F300.
N70 G02 X20. Y10. I5. J0.
N75 G03 X10. Y10. R5.
N80 G98 G81 X30. Y10. Z-3. R2. F100.
N85 X40.
N90 G80 G00 Z15.
N95 M09
N100 G28 G91 Z0.
N105 G90
N110 M30
%""",
    "units and feeds": """G21 G90 F600
G0 X1 Y1 Z1
G20
G1 X1 Y1
F10
G1 X2
G21 G1 X10 F300
G91 G20 G1 X0.5 Y-0.5
G90 G21
M2""",
    "polar coordinates": """G21 G90 F200
G0 X10 Y0
G1 @10 ^45
G1 ^90
G91 G1 @2 ^-30
G90 G2 @12 ^0 R12
M2""",
}


@pytest.mark.parametrize("name", sorted(FEATURES))
def test_programs_per_feature_give_rs274s_motion(name):
    agree(FEATURES[name])


def test_events_follow_rs274s_spindle_coolant_tool_and_stop_calls():
    text = ("G21 G90 F100\nT2 M6\nS1000 M3\nM8\nM7\nG1 X5\nS2000\nM9\nM4\nG4 P1\nM5\nM0\nM1\nT3 M6\n"
            "M62 P1\nM65 P2\nM67 E0 Q3.5\nM68 E1 Q2\nM30\n")
    res, job, problems = both(text)
    assert res.ok and not problems
    mine = [e for m in job.moves if m.kind == "event" for e in m.events]
    spindle = [v for name, v in mine if name == "spindle"]
    assert spindle == [e[1] for e in res.events if e[0] == "spindle"] == [1000.0, 2000.0, -2000.0, 0.0]
    assert [v for name, v in mine if name == "coolant"] == ["flood", "mist", "off"]
    assert [e[1] for e in res.events if e[0] == "coolant"] == ["FLOOD_ON", "MIST_ON", "MIST_OFF", "FLOOD_OFF"]
    assert [v for name, v in mine if name == "tool_change"] == [2, 3]
    assert len([1 for e in res.events if e[0] == "tool_change"]) == 2
    assert [v for name, v in mine if name == "pause"] == ["M0", "M1"]
    assert [e[1] for e in res.events if e[0] == "pause"] == ["PROGRAM_STOP", "OPTIONAL_PROGRAM_STOP", "PALLET_SHUTTLE"]
    assert [v for name, v in mine if name == "output"] == [("digital", 1, 1.0), ("digital", 2, 0.0),
                                                           ("analog", 0, 3.5), ("analog", 1, 2.0)]
    assert len([1 for e in res.events if e[0] == "output"]) == 4


# ---------------------------------------------------------------- generated programs

MM = st.integers(-40000, 40000).map(lambda k: k / 1000.0)
SMALL = st.integers(-5000, 5000).map(lambda k: k / 1000.0)


def _n(v):
    return f"{v:.4f}"


@st.composite
def motion_line(draw):
    code = draw(st.sampled_from(["G0", "G1"]))
    axes = draw(st.lists(st.sampled_from("XYZ"), min_size=1, max_size=3, unique=True))
    return f"{code} " + " ".join(f"{a}{_n(draw(MM))}" for a in axes)


@st.composite
def arc_line(draw):
    """An arc from wherever the tool is, valid by construction: I J K centre offsets (or R) and an end
    that lies on the circle (G91: increments; G90: the current position #<_x>... plus increments)."""
    plane = draw(st.sampled_from([17, 18, 19]))
    first, second, third = {17: ("X", "Y", "Z"), 18: ("Z", "X", "Y"), 19: ("Y", "Z", "X")}[plane]
    ci, cj = {17: ("I", "J"), 18: ("K", "I"), 19: ("J", "K")}[plane]
    oi, oj = draw(SMALL), draw(SMALL)
    if math.hypot(oi, oj) < 0.5:
        oi = 2.0
    th = math.radians(draw(st.integers(5, 355)))
    # end - start = (centre - start) + R(th) (start - centre), with centre - start = (oi, oj)
    di = oi - (oi * math.cos(th) - oj * math.sin(th))
    dj = oj - (oi * math.sin(th) + oj * math.cos(th))
    dz = draw(SMALL)
    g = draw(st.sampled_from(["G2", "G3"]))
    inc = draw(st.booleans())
    if inc:
        end = f"{first}{_n(di)} {second}{_n(dj)} {third}{_n(dz)}"
        pre, post = "G91 ", "\nG90"
    else:
        end = (f"{first}[#<_{first.lower()}> + {_n(di)}] {second}[#<_{second.lower()}> + {_n(dj)}] "
               f"{third}[#<_{third.lower()}> + {_n(dz)}]")
        pre = post = ""
    if draw(st.booleans()):
        centre = f"{ci}{_n(oi)} {cj}{_n(oj)}"
        turns = draw(st.sampled_from(["", "", " P2"]))
    else:
        r = math.hypot(oi, oj)
        # R > 0: the short way; the generated sweep th decides which (G3: th; G2: 2 pi - th ...)
        short = (th <= math.pi) if g == "G3" else (th >= math.pi)
        centre = f"R{_n(r if short else -r)}"
        turns = ""
        if abs(th - math.pi) < 0.2:
            centre = f"{ci}{_n(oi)} {cj}{_n(oj)}"
    if g == "G2":
        # the same circle clockwise: mirror the sweep (end stays on the circle for either direction)
        pass
    return f"G{plane} {pre}{g} {end} {centre}{turns}{post}\nG17"


@st.composite
def offsets_line(draw):
    k = draw(st.integers(0, 7))
    if k == 0:
        return (f"G10 L2 P{draw(st.integers(1, 9))} X{_n(draw(SMALL))} Y{_n(draw(SMALL))} Z{_n(draw(SMALL))}"
                + (f" R{draw(st.integers(-45, 45))}" if draw(st.booleans()) else ""))
    if k == 1:
        return draw(st.sampled_from(["G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"]))
    if k == 2:
        return f"G92 X{_n(draw(SMALL))} Y{_n(draw(SMALL))}"
    if k == 3:
        return draw(st.sampled_from(["G92.1", "G92.2", "G92.3"]))
    if k == 4:
        return f"G10 L20 P{draw(st.integers(0, 9))} X{_n(draw(SMALL))} Z{_n(draw(SMALL))}"
    if k == 5:
        return draw(st.sampled_from(["G28.1", "G30.1", "G28", "G30", f"G28 Z{_n(draw(SMALL))}",
                                     f"G30 X{_n(draw(SMALL))}"]))
    if k == 6:
        return f"G52 X{_n(draw(SMALL))} Z{_n(draw(SMALL))}"
    return f"G53 G0 X{_n(draw(SMALL))} Z{_n(abs(draw(SMALL)) + 1)}"


@st.composite
def cycle_block(draw):
    c = draw(st.sampled_from([81, 82, 83, 73, 85, 89]))
    extra = {82: " P0.5", 83: f" Q{_n(abs(draw(SMALL)) + 0.5)}", 73: f" Q{_n(abs(draw(SMALL)) + 0.5)}",
             89: " P0.2"}.get(c, "")
    mode = draw(st.sampled_from(["G90", "G91"]))
    rep = f" L{draw(st.integers(1, 3))}" if mode == "G91" and draw(st.booleans()) else ""
    more = f"\nX{_n(draw(SMALL))}" if mode == "G90" and draw(st.booleans()) else ""
    return (f"G90 G0 A0 B0\n{mode} G17 G{draw(st.sampled_from([98, 99]))} G{c} X{_n(draw(SMALL))} "
            f"Y{_n(draw(SMALL))} Z-{_n(abs(draw(SMALL)) + 1)} R{_n(abs(draw(SMALL)) + 0.5)}{extra}{rep}{more}\nG80 G90")


@st.composite
def tool_line(draw):
    k = draw(st.integers(0, 2))
    body = {0: f"G43 H{draw(st.integers(1, 4))}", 1: f"G43.1 Z{_n(draw(SMALL))}", 2: "G49"}[k]
    return f"G90 G0 A0 B0\n{body}"          # a tool offset changes with the tool vertical (see the module doc)


@st.composite
def programs(draw):
    inch = draw(st.booleans()) and not draw(st.booleans())
    lines = [("G20" if inch else "G21") + " G90 G17 G94 F" + ("12" if inch else "300")]
    kinds = [motion_line(), arc_line(), offsets_line(), cycle_block(),
             st.sampled_from(["G91", "G90"]),
             st.tuples(MM, st.integers(-15, 15), st.integers(-15, 15)).map(
                 lambda t: f"G1 X{_n(t[0])} A{t[1]} B{t[2]}")]
    if not inch:
        kinds.append(tool_line())               # rs274 standalone keeps a tool offset in mm after G20
        kinds.append(st.tuples(MM, MM, st.integers(1, 5)).map(lambda t: f"G93 G1 X{_n(t[0])} Y{_n(t[1])} F{t[2]}\nG94"))
    for _ in range(draw(st.integers(1, 10))):
        lines.append(draw(st.one_of(kinds)))
    lines.append("M2")
    return "\n".join(lines)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(programs())
def test_generated_programs_give_rs274s_motion(text):
    same_motion_or_both_refuse(text)


def same_motion_or_both_refuse(text, *, want_motions=0):
    """rs274 and pmctl both accept the program with the same motion (at least ``want_motions``), or
    both refuse it. Returns (rs274's result, pmctl's problems)."""
    res, job, problems = both(text)
    assert res.ok == (not problems), (res.error, [str(p) for p in problems], text)
    if res.ok:
        diffs, n, worst = O.compare(O.pmctl_motions(job), res.motions)
        assert not diffs, "\n".join(diffs) + "\n" + text
        assert n >= want_motions
    return res, problems


@st.composite
def compensated_profiles(draw):
    """A closed profile of lines and arcs around the origin (convex and concave corners), cut with
    G41/G42 (D from the tool table, or G41.1/G42.1 with a diameter) after an entry move, left with G40."""
    side = draw(st.sampled_from(["G41", "G42", "G41.1", "G42.1"]))
    d = draw(st.sampled_from([1, 2, 3, 5])) if "." not in side else draw(st.sampled_from([1.0, 2.5, 4.0, 8.0]))
    n = draw(st.integers(3, 8))
    a0 = draw(st.integers(0, 359))
    pts = []
    for k in range(n):
        a = math.radians(a0 + 360.0 * k / n + draw(st.integers(-15, 15)))
        rad = draw(st.integers(3000, 20000)) / 1000.0 if k % 2 else draw(st.integers(8000, 20000)) / 1000.0
        pts.append((rad * math.cos(a), rad * math.sin(a)))
    if draw(st.booleans()):
        pts.reverse()
    lines = ["G21 G90 G17 G94 F300", "G0 X-30 Y-30 Z5", "G1 Z-1", f"{side} D{d}", f"G1 X{_n(pts[0][0])} Y{_n(pts[0][1])}"]
    for x, y in pts[1:] + [pts[0]]:
        if draw(st.booleans()):
            lines.append(f"G1 X{_n(x)} Y{_n(y)}")
        else:
            r = draw(st.integers(4000, 30000)) / 1000.0 * draw(st.sampled_from([1, -1]))
            lines.append(f"G{draw(st.sampled_from([2, 3]))} X{_n(x)} Y{_n(y)} R{_n(r)}")
    lines += ["G40", "G0 X-30 Y-30", "M2"]
    return "\n".join(lines)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(compensated_profiles())
@example("G21 G90 G17 G94 F300\nG0 X-30 Y-30 Z5\nG1 Z-1\nG42.1 D8.0\nG1 X1.3670 Y10.4843\nG1 X2.5676 Y1.5515\n"
         "G1 X7.5038 Y-2.7736\nG2 X0.9413 Y-2.8485 R4.0000\nG2 X-4.3738 Y-6.6985 R4.0000\nG1 X-7.0534 Y-0.4226\n"
         "G2 X-5.4000 Y6.2120 R-4.0000\nG2 X1.3670 Y10.4843 R4.0000\nG40\nG0 X-30 Y-30\nM2")  # an arc of no radius
def test_cutter_compensation_agrees_with_rs274_moves_and_refusals(text):
    res, problems = same_motion_or_both_refuse(text, want_motions=5)
    if not res.ok:                         # refused at the same line (rs274 prints the line it stopped at)
        bad_line = text.split("\n")[problems[0].line - 1]
        assert res.error.splitlines()[-1].strip() == bad_line.strip(), (res.error, str(problems[0]))
