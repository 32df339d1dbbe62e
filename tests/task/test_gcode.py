"""The G-code job reader (pmctl.task.gcode over pmctl.task.rs274): modal state, arcs, units, events, problems
with line/column/kind, hypothesis round trips. The LinuxCNC differential tests are in tests/integration/test_rs274_oracle.py."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError, JobProblems
from pmctl.task.gcode import ARC_RADIUS_TOL_MM, interpret, parse_gcode, read_gcode
from pmctl.task.job import load_job
from pmctl.core.job import ARC, DWELL, EVENT, LINE, RAPID

JOBS = Path(__file__).resolve().parents[2] / "examples" / "jobs"
START = (0.0, 0.0, 100.0)


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def parse(text, path="t.ngc"):
    return parse_gcode(text, path, START, (0.0, 0.0, 1.0))


def error_of(text):
    with pytest.raises(InputError) as e:
        parse(text)
    return e.value


def motion(job):
    """The moves that go somewhere or wait (EVENT moves carry what happens on the way)."""
    return [m for m in job.moves if m.kind != EVENT]


# ---------------------------------------------------------------- bundled programs

@pytest.mark.parametrize("name", ["cone.ngc", "spiral.ngc"])
def test_bundled_programs_parse_and_are_reachable(machine, name):
    job = read_gcode(JOBS / name, machine)
    assert len(job.moves) > 10
    assert len(job.points) == len([m for m in job.moves if m.kind not in (DWELL, EVENT)])
    # every programmed axis is a unit vector pointing up, within the tilt limit
    axes = np.array([m.axis for m in job.moves])
    assert np.allclose(np.linalg.norm(axes, axis=1), 1.0, atol=1e-12)
    assert np.all(np.degrees(np.arccos(axes[:, 2])) <= 20.0 + 1e-9)
    assert load_job(JOBS / name, machine).moves[0].line == job.moves[0].line


def test_cone_arcs_keep_their_radius(machine):
    job = read_gcode(JOBS / "cone.ngc", machine)
    arcs = [(m, prev) for prev, m in zip(job.moves, job.moves[1:]) if m.kind == ARC]
    assert arcs
    for m, prev in arcs:
        r0 = np.hypot(*(prev.tip[:2] - m.center))
        r1 = np.hypot(*(m.tip[:2] - m.center))
        assert abs(r1 - r0) <= ARC_RADIUS_TOL_MM
        assert m.sweep > 0                      # G3: counter-clockwise


# ---------------------------------------------------------------- semantics

def test_modal_state_and_words():
    job = parse("%\nN10 G21 G90 G17 (set up) ; comment\nG0 X10 Y0 Z50\nF600 S9000 M3\nG1 X20\n"
                "Y5 A10 B-5\nG4 P0.25\nM5\nG0 Z60\nM30\nG1 X1000 (never read)\n%")
    kinds = [m.kind for m in job.moves]
    assert kinds == [RAPID, EVENT, LINE, LINE, DWELL, EVENT, RAPID]
    rap, on, l1, l2, dw, off, r2 = job.moves
    assert on.events == (("spindle", 9000.0),) and on.line == 4 and np.array_equal(on.tip, rap.tip)
    assert off.events == (("spindle", 0.0),) and off.line == 8
    assert np.allclose(rap.tip, [10, 0, 50]) and rap.line == 3
    assert l1.feed == pytest.approx(10.0) and l1.spindle_rpm == 9000 and l1.line == 5
    assert np.allclose(l2.tip, [20, 5, 50])                  # G1 stays modal
    assert np.allclose(l2.axis, K.axis_from_roll_pitch(math.radians(10), math.radians(-5)), atol=1e-15)
    assert dw.dwell == 0.25 and np.allclose(dw.tip, l2.tip)
    assert r2.spindle_rpm == 0.0                              # M5
    assert np.allclose(r2.axis, l2.axis)                      # A/B modal too
    assert job.point_lines.tolist() == [3, 5, 6, 9]


def test_spaces_inside_words_and_leading_zeros():
    a = parse("G01 F600 X1 0.5 Y-.5 Z+3")
    b = parse("G1F600X10.5Y-0.5Z3")
    assert np.allclose(a.moves[0].tip, [10.5, -0.5, 3]) and np.allclose(a.moves[0].tip, b.moves[0].tip)


def test_g91_equals_g90():
    absolute = parse("G90 G0 X10 Y5 Z80 A5\nF300 G1 X20 Y5 Z70 B3\nG2 X30 Y5 I5 J0\nG3 X20 Y15 R10\nG1 X0 Y0 Z90 A0 B0")
    incremental = parse("G91 G0 X10 Y5 Z-20 A5\nF300 G1 X10 Y0 Z-10 B3\nG2 X10 Y0 I5 J0\nG3 X-10 Y10 R10\n"
                        "G1 X-20 Y-15 Z20 A-5 B-3")
    assert len(absolute.moves) == len(incremental.moves) == 5
    for a, b in zip(absolute.moves, incremental.moves):
        assert a.kind == b.kind
        assert np.allclose(a.tip, b.tip, atol=1e-12) and np.allclose(a.axis, b.axis, atol=1e-12)
        if a.kind == ARC:
            assert np.allclose(a.center, b.center, atol=1e-12) and a.sweep == pytest.approx(b.sweep)


def test_g20_inches():
    inch = parse("G20 G90 G0 X1 Y0.5 Z3\nG1 F10 X2\nG2 X3 Y0.5 I0.5 J0\nG3 X2 Y1.5 R1\nG21 G1 X10")
    mm = parse("G21 G90 G0 X25.4 Y12.7 Z76.2\nG1 F254 X50.8\nG2 X76.2 Y12.7 I12.7 J0\nG3 X50.8 Y38.1 R25.4\nG1 X10")
    for a, b in zip(inch.moves, mm.moves):
        assert np.allclose(a.tip, b.tip, atol=1e-12) and a.feed == pytest.approx(b.feed)
    assert inch.moves[1].feed == pytest.approx(254.0 / 60.0)       # 10 in/min in mm/s
    assert np.allclose(inch.moves[2].center, [63.5, 12.7])


def test_arc_centres_and_sweeps():
    # quarter turns around (0, 0) from (10, 0)
    g3 = parse("G0 X10 Y0 Z100\nF60 G3 X0 Y10 I-10 J0").moves[1]
    g2 = parse("G0 X10 Y0 Z100\nF60 G2 X0 Y10 I-10 J0").moves[1]
    assert g3.sweep == pytest.approx(math.pi / 2) and g2.sweep == pytest.approx(-1.5 * math.pi)
    # R format: R > 0 the short way, R < 0 the long way; G2 and G3 put the centre on opposite sides
    short3 = parse("G0 X10 Y0 Z100\nF60 G3 X0 Y10 R10").moves[1]
    long3 = parse("G0 X10 Y0 Z100\nF60 G3 X0 Y10 R-10").moves[1]
    short2 = parse("G0 X10 Y0 Z100\nF60 G2 X0 Y10 R10").moves[1]
    assert np.allclose(short3.center, [0, 0], atol=1e-12) and short3.sweep == pytest.approx(math.pi / 2)
    assert np.allclose(long3.center, [10, 10], atol=1e-12) and long3.sweep == pytest.approx(1.5 * math.pi)
    assert np.allclose(short2.center, [10, 10], atol=1e-12) and short2.sweep == pytest.approx(-math.pi / 2)
    # full circle, and P turns
    full = parse("G0 X10 Y0 Z100\nF60 G2 X10 Y0 I-10 J0").moves[1]
    assert full.sweep == pytest.approx(-2 * math.pi)
    helix = parse("G0 X10 Y0 Z100\nF60 G3 X10 Y0 Z90 I-10 P3").moves[1]
    assert helix.sweep == pytest.approx(6 * math.pi) and helix.tip[2] == 90


@pytest.mark.parametrize("text,line,words,kind", [
    ("G0 X1\nG1 X5", 2, "no F", "syntax"),
    ("G0 X1\nG0 X1 W2", 2, "W2: axis W is not on this machine", "machine"),
    ("G1 F100 X", 1, "missing value after 'X'", "syntax"),
    ("G0 X1\n\nG5.2 X1 Y1 P1 L3", 3, "G5.2 NURBS blocks are not supported", "unsupported"),
    ("G0 X1 (abc", 1, "never closed", "syntax"),
    ("G0 X1 (a (b) c)", 1, "nested", "syntax"),
    ("X5", 1, "no motion mode", "syntax"),
    ("G0 G1 X1", 1, "two G-codes of the same modal group on one line (G0 and G1)", "syntax"),
    ("F600\nG0 X10 Y0\nG2 X10 Y6 I3 J0", 3, "differs from the radius to its start", "syntax"),
    ("G0 X1 X2", 1, "appears twice", "syntax"),
    ("F600 G0 X0 Y0\nG2 X30 Y0 R5", 2, "too small", "syntax"),
    ("G4", 1, "needs P", "syntax"),
    ("G1 F0 X1", 1, "must be > 0", "syntax"),
    ("M7 M48", 1, "M48 (enable overrides) is not supported", "unsupported"),
    ("G0 X1 I2", 1, "I2 has nothing to use it: I is an arc centre (G2/G3)", "syntax"),
    ("G0 X1\nG1 F600 X2 P3", 2, "P3 has nothing to use it", "syntax"),
    ("F600 G2 X0 Y0 I0 J0", 1, "zero-radius arc", "syntax"),
    ("F600 G3 X5 Y5", 1, "needs its centre: I J K (offsets) or R (radius)", "syntax"),
    ("G0 X1 Y1\nF600 G2 X1 Y1 R5", 2, "full circle", "syntax"),
    ("G20 G21", 1, "same modal group", "syntax"),
    ("G0 X1\nG1 X2 F-3", 2, "must be > 0", "syntax"),
    ("G0 X1 $", 1, "expected a word letter", "syntax"),
    ("N1.5 G0 X1", 1, "line number", "syntax"),
    ("G0 X1 C5", 1, "C5: axis C is not on this machine", "machine"),
    ("M428", 1, "M428 (tool centre point control of another controller)", "machine"),
    ("G43.4 H1", 1, "G43.4 (tool centre point control of another machine)", "machine"),
    ("G68.2 X0 Y0 Z0 I0 J30 K0", 1, "G68.2 (tilted working plane)", "machine"),
    ("M101", 1, "user M-codes (M100-M199) run only when configured", "unsupported"),
])
def test_bad_lines_are_reported_with_their_line(text, line, words, kind):
    e = error_of(text)
    assert e.line == line and e.path == "t.ngc"
    assert words in e.reason, e.reason
    assert isinstance(e, JobProblems) and e.problems[0].kind == kind


def test_error_column_points_at_the_word():
    e = error_of("G0 X1 Y2 Q7")
    assert e.column == 10 and "t.ngc:1: column 10" in str(e)


def test_nothing_from_a_program_with_a_bad_last_line(tmp_path, machine):
    good = (JOBS / "spiral.ngc").read_text().replace("M30", "")
    p = tmp_path / "bad.ngc"
    p.write_text(good + "G1 X1 Y1 Q3\n")
    with pytest.raises(InputError) as e:
        load_job(p, machine)
    assert e.value.line == good.count("\n") + 1 and "Q3 has nothing to use it" in str(e.value)


def test_every_problem_is_listed_with_its_kind_and_the_program_goes_on():
    text = ("G21 G90\nG0 X1 Y1 Z90\nG1 X2 C4 F600\nG1 X3 Q1\nG2 X9 Y9 I0 J0\nG5.2 X1 Y1 P1 L3\nG43 H77\n"
            "G1 X4\nM30\n")
    job, problems = interpret(text, "t.ngc", start=(START, (0.0, 0.0, 1.0)))
    got = [(p.line, p.kind) for p in problems]
    assert got == [(3, "machine"), (4, "syntax"), (5, "syntax"), (6, "unsupported"), (7, "machine")], problems
    assert "tool 77 is not in the tool table" in problems[4].message and "add it, or use G43.1" in problems[4].message
    # the machine problems leave the line's meaning: C is dropped, the move to X2 is made; the bad lines are not
    ends = [float(m.tip[0]) for m in motion(job) if m.kind != DWELL]
    assert ends == [1.0, 2.0, 4.0]
    e = error_of(text)
    assert "(and 4 more problems: pmctl check lists them)" in e.reason and len(e.problems) == 5


def test_unreachable_programmed_pose_is_reported(tmp_path, machine):
    p = tmp_path / "far.ngc"
    p.write_text("G0 X0 Y0 Z60\nG1 F600 X10\nG1 X200\n")
    with pytest.raises(InputError) as e:
        read_gcode(p, machine)
    assert e.value.line == 3 and "unreachable" in e.value.reason
    p.write_text("G0 X0 Y0 Z60\nG1 F600 X10 B25\n")
    with pytest.raises(InputError) as e:
        read_gcode(p, machine)
    assert e.value.line == 2 and "tilted" in e.value.reason


# ---------------------------------------------------------------- hypothesis

coord = st.integers(-40000, 40000).map(lambda k: k / 1000.0)
angle = st.integers(-150, 150).map(lambda k: k / 10.0)


@st.composite
def programs(draw):
    """A random program and the moves it must produce (absolute, mm)."""
    inch = draw(st.booleans())
    unit = 25.4 if inch else 1.0
    q = 1e-4 if inch else 1e-3
    fmt = lambda v: f"{v:.4f}"  # noqa: E731
    lines = ["G20" if inch else "G21", "F100"]
    pos = np.array(START)
    ab = [0.0, 0.0]
    expect = []
    absolute = True
    for _ in range(draw(st.integers(1, 8))):
        mode = draw(st.sampled_from(["G90", "G91"]))
        absolute = mode == "G90"
        kind = draw(st.sampled_from(["G0", "G1", "G2", "G3"]))
        a, b = draw(angle), draw(angle)
        if kind in ("G0", "G1"):
            vals = [round(draw(coord) / unit / q) * q for _ in range(3)]
            target = np.array(vals) * unit if absolute else pos + np.array(vals) * unit
            words = f"X{fmt(vals[0])} Y{fmt(vals[1])} Z{fmt(vals[2])}"
            arc = None
        else:
            i = round(draw(st.integers(-20000, 20000)) / 1000.0 / unit / q) * q
            j = round(draw(st.integers(-20000, 20000)) / 1000.0 / unit / q) * q
            if math.hypot(i, j) * unit < 0.5:
                i = round(1.0 / unit / q) * q
            th = draw(st.floats(0.1, 6.2))
            c = pos[:2] + np.array([i, j]) * unit
            r = math.hypot(i, j) * unit
            th0 = math.atan2(pos[1] - c[1], pos[0] - c[0])
            end = c + r * np.array([math.cos(th0 + th), math.sin(th0 + th)])
            dz = draw(coord) / 4
            end_prog = [round(v / unit / q) * q for v in (end[0], end[1], pos[2] + dz)]
            if not absolute:
                end_prog = [round((e * unit - p) / unit / q) * q for e, p in zip(end_prog, pos)]
            target = np.array(end_prog) * unit if absolute else pos + np.array(end_prog) * unit
            words = f"X{fmt(end_prog[0])} Y{fmt(end_prog[1])} Z{fmt(end_prog[2])} I{fmt(i)} J{fmt(j)}"
            arc = (c, kind)
        ab_new = [a, b] if absolute else [ab[0] + a, ab[1] + b]
        lines.append(f"{mode} {kind} {words} A{a:g} B{b:g}")
        expect.append((kind, target, ab_new, arc, len(lines)))
        pos, ab = target, ab_new
    lines.append("M30")
    return "\n".join(lines), expect


@settings(max_examples=60, deadline=None)
@given(programs())
def test_round_trip_of_generated_programs(prog):
    text, expect = prog
    job = parse(text)
    moves = [m for m in job.moves if m.kind != DWELL]
    assert len(moves) == len(expect)
    for m, (kind, target, ab, arc, line) in zip(moves, expect):
        assert m.kind == {"G0": RAPID, "G1": LINE, "G2": ARC, "G3": ARC}[kind]
        assert m.line == line
        assert np.allclose(m.tip, target, atol=1e-9)
        assert np.allclose(m.axis, K.axis_from_roll_pitch(*np.radians(ab)), atol=1e-12)
        if arc is not None:
            assert np.allclose(m.center, arc[0], atol=1e-9)
            assert (m.sweep < 0) == (arc[1] == "G2")


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.text(max_size=80),
                 st.text(alphabet="GXYZABIJRFSMNP0123456789.-+ ();%\n\t", max_size=80)))
def test_junk_raises_only_input_error(text):
    try:
        job = parse(text)
    except InputError as e:
        assert e.path == "t.ngc" and (e.line is None or 1 <= e.line <= text.count("\n") + 1)
    else:
        for m in job.moves:
            assert np.all(np.isfinite(m.tip)) and np.all(np.isfinite(m.axis))


# ---------------------------------------------------------------- numbers, refusals by name, %, M3, MSG

@pytest.mark.parametrize("text,col,words", [
    ("G0 X" + "9" * 400, 4, "X999"),                     # hundreds of digits: out of range, no OverflowError
    ("N" + "1" * 300 + " G0 X1", 1, "out of range"),
    ("G" + "1" * 300 + " X1", 1, "out of range"),
    ("M" + "3" * 300, 1, "out of range"),
    ("G0 X1\nG1 X2 F" + "1" * 401, 7, "out of range"),     # 1e400 would be infinity
    ("S" + "9" * 401 + " M3", 1, "out of range"),
    ("G4 P" + "9" * 400, 4, "out of range"),
    ("G4 P100000", 4, "dwell P100000 must be within 0 .. 3600 s"),
    ("G0 X10 Y0 Z100\nF60 G2 X10 Y0 I-10 P100000", 20, "arc turns P100000"),
    ("G0 X1\nG1 F600 X2 Y[1/0]", 15, "division by zero"),
    ("#1 = [2 + ]", 11, "missing value after '+'"),
    ("G0 X#<nothing>", 4, "named parameter #<nothing> is not defined"),
    ("o100 endsub", 1, "o100 endsub without a matching o100 sub"),
    ("O<probe> call", 1, "no subroutine o<probe> in this file nor probe.ngc on the subroutine path"),
    ("G0 X0 Y0 Z100\nG81 X1 Y1 Z-1 F100", 1, "G81 needs R (the retract plane)"),
    ("G33 Z-10 K1", 1, "G33 (spindle-synchronised motion) needs a spindle encoder"),
    ("G42.1 D6 G18", 1, "cutter compensation runs in the XY plane (G17) only"),
    ("G38.5 Z1 F10", 1, "G38.5 (probe away from the workpiece) is not supported"),
    ("G0 X\u0661", 4, "missing value"),                   # an Arabic-Indic digit is not a digit here
])
def test_numbers_and_unsupported_features_are_refused_by_name(text, col, words):
    e = error_of(text)
    assert e.column == col and e.line == text.count("\n") + 1           # always the last line here
    assert words in e.reason, e.reason


def test_accepted_no_op_codes_change_nothing():
    plain = parse("G0 X10 Y5 Z80\nF300 G1 X20")
    preamble = parse("G17 G21 G90 G94 G40 G49 G54 G80 G97 G61\nG64\nG0 X10 Y5 Z80\nF300 G1 X20\nM9")
    assert [m.kind for m in plain.moves] == [m.kind for m in preamble.moves]
    for a, b in zip(plain.moves, preamble.moves):
        assert np.array_equal(a.tip, b.tip) and a.feed == b.feed and b.tolerance == 0.0
    blended = parse("G64 P0.01 Q0.02\nG0 X10 Y5 Z80\nF300 G1 X20\nG61\nG1 X30")
    assert [m.tolerance for m in blended.moves] == [0.01, 0.01, 0.0]          # G64 P -> Move.tolerance


def test_percent_delimited_program_stops_at_the_closing_percent():
    job = parse("%\nG0 X1 Y1 Z90\n%\nthis is not G-code at all [#1]\n")
    assert len(job.moves) == 1 and np.allclose(job.moves[0].tip, [1, 1, 90])
    e = error_of("%\nG0 X1 Y1 Z90\n")
    assert e.line == 1 and "no closing '%'" in e.reason
    e = error_of("G0 X1 Y1 Z90\n%\nG0 X5\n")
    assert e.line == 2 and "did not start with '%'" in e.reason
    assert len(parse("%\nG0 X1 Y1 Z90\nM2\n").moves) == 1          # M2 ends it before any closing %


def test_spindle_changes_are_events_in_program_order():
    # LinuxCNC's meaning (the old reader refused M3 without S and S0 while turning): M3 with S0 turns at 0 rpm
    # until an S comes; every change of the commanded spindle is an event where the path reaches it
    job = parse("G0 X1 Y1 Z90\nM3\nS1000 F600 G1 X5\nS0\nG1 X6\nS500 M4\nG1 X7\nM5\n")
    assert [(m.kind, m.events) for m in job.moves if m.kind == EVENT] == [
        (EVENT, (("spindle", 0.0),)), (EVENT, (("spindle", 1000.0),)), (EVENT, (("spindle", 0.0),)),
        (EVENT, (("spindle", -500.0),)), (EVENT, (("spindle", 0.0),))]
    assert [m.spindle_rpm for m in job.moves if m.kind == LINE] == [1000.0, 0.0, -500.0]


def test_msg_comments_are_kept_for_the_operator():
    job = parse("(MSG, clamp the part)\nG0 X1 Y1 Z90 (msg,check the tool)\n(not a message)\n;(MSG, behind ;)")
    assert job.messages == ((1, "clamp the part"), (2, "check the tool"))


def test_non_utf8_job_file_names_line_and_column(tmp_path, machine):
    p = tmp_path / "bad.ngc"
    p.write_bytes(b"G0 X1 Y1 Z90\nG1 F600 X2\xff\n")
    with pytest.raises(InputError) as e:
        read_gcode(p, machine)
    assert e.value.line == 2 and e.value.column == 11 and "0xff is not UTF-8" in e.value.reason


def test_no_move_count_cap_and_the_tool_axis_is_shared():
    n = 50_010                               # the old reader refused the line that crossed 50 000 moves
    text = "G0 X0 Y0 Z90\nF600\n" + "\n".join(f"G1 X{(i % 200) * 0.1:.1f}" for i in range(n))
    job = parse(text)
    assert len(job.moves) == n + 1 and job.moves[-1].line == n + 2
    assert len({id(m.axis) for m in job.moves}) == 1           # one axis array while the tilt stays the same


def test_job_files_beyond_the_size_bounds_are_refused_before_parsing(tmp_path, monkeypatch, machine):
    import pmctl.core.job as J
    p = tmp_path / "long.ngc"
    p.write_text("N1\n" * 30)
    monkeypatch.setattr(J, "MAX_JOB_LINES", 20)
    with pytest.raises(InputError) as e:
        load_job(p, machine)
    assert e.value.line == 21 and "31 lines; the limit is 20" in e.value.reason
    monkeypatch.setattr(J, "MAX_JOB_BYTES", 50)
    with pytest.raises(InputError, match="larger than the limit"):
        load_job(p, machine)


# ---------------------------------------------------------------- G38.2 / G38.3 probing

@settings(max_examples=60, deadline=None)
@given(mode=st.sampled_from([2, 3]), target=st.lists(st.floats(-50, 50).map(lambda v: round(v, 3)), min_size=1,
                                                     max_size=3),
       axes=st.permutations("XYZ"), feed=st.floats(1, 3000).map(lambda v: round(v, 2)),
       feed_first=st.booleans(), inch=st.booleans())
def test_g38_is_a_probing_feed_line_to_its_target(mode, target, axes, feed, feed_first, inch):
    u = 25.4 if inch else 1.0
    words = " ".join(f"{a}{v:g}" for a, v in zip(axes, target))
    if all(abs(v * u - START["XYZ".index(a)]) < 1e-6 for a, v in zip(axes, target)):
        return                                             # the target is the start: refused (tested below)
    pre = ("G20" if inch else "G21") + " G90\n" + (f"F{feed:g}\n" if feed_first else "")
    job = parse(pre + f"G38.{mode} {words}" + ("" if feed_first else f" F{feed:g}") + "\n")
    (m,) = job.moves
    expect = np.array(START, float)
    for a, v in zip(axes, target):
        expect["XYZ".index(a)] = v * u
    assert m.kind == LINE and m.probe == mode and m.line == (3 if feed_first else 2)
    np.testing.assert_allclose(m.tip, expect, atol=1e-9)
    assert m.feed == pytest.approx(feed * u / 60.0)
    np.testing.assert_allclose(m.axis, [0, 0, 1], atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(mode=st.sampled_from([2, 3]), pre_lines=st.integers(0, 5), z=st.floats(-50, 50).map(lambda v: round(v, 2)))
def test_g38_needs_an_axis_word_and_a_feed_and_names_the_line(mode, pre_lines, z):
    pre = "(comment)\n" * pre_lines
    e = error_of(pre + f"G38.{mode} F100\n")
    assert e.path == "t.ngc" and e.line == pre_lines + 1 and "needs an axis word" in e.reason
    e = error_of(pre + f"G38.{mode} Z{z + 200:g}\n")
    assert e.line == pre_lines + 1 and "no F" in e.reason
    assert str(e).startswith(f"t.ngc:{pre_lines + 1}:")


@pytest.mark.parametrize("text,words", [
    ("G38.4 Z1 F10", "G38.4 (probe away from the workpiece) is not supported"),
    ("G38.5 Z1 F10", "G38.5 (probe away from the workpiece) is not supported"),
    ("G38.2 G1 Z1 F10", "same modal group"),
    ("G38.2 Z99 A5 F10", "tool axis must stay put"),
    ("G38.3 Z100 F10", "target is the current position"),
    ("G38.2 X5 Y5 I1 J1 F10", "I1 has nothing to use it"),
])
def test_g38_refusals_are_named(text, words):
    e = error_of(text)
    assert e.line == 1 and words in e.reason, e.reason


def test_g38_is_modal_and_refused_where_there_is_no_stop_on_contact():
    job = parse("G38.3 Z90 F60\nZ80\nG1 Z70\n")
    assert [m.probe for m in job.moves] == [3, 3, 0]
    from pmctl.task.interp import LineError, LineInterpreter
    it = LineInterpreter(load_machine(), START, (0.0, 0.0, 1.0))
    it.st.probe_ok = False                        # a reader with no stop on contact
    with pytest.raises(LineError) as e:
        it.execute("G38.2 Z90 F60", 1)
    assert e.value.code == 20 and "probing is not available here" in str(e.value)
    assert it.execute("G1 Z90 F60", 2)[0][0].probe == 0      # the failed line changed nothing
