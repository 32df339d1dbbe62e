"""pmctl's RS-274 interpreter on what LinuxCNC's rs274 cannot tell us: this machine's meaning (tool
length along the tilted tool axis, G53 as W without offsets, events in program order, Move fields),
its settings ([interpreter], the tool table), its problems (kinds, columns, messages, limits) and the
console's line interpreter built on it. The differential tests against rs274: tests/integration/test_rs274_oracle.py."""

from __future__ import annotations

import copy
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import ConfigError
from pmctl.motion.service_config import InterpreterConfig, service_from_dict
from pmctl.task.interp import LineError, LineInterpreter
from pmctl.core.job import ARC, DWELL, EVENT, LINE, RAPID
from pmctl.task.journal import Journal
from pmctl.task.rs274 import interpret, make_config, start_position
from pmctl.task.rs274 import program as PR
from pmctl.task.rs274.tools import Tool, ToolTable, load_tool_table, parse_tool_table

TT = ToolTable([Tool(1, 1, 10.0, 6.0), Tool(2, 2, -5.5, 3.0), Tool(7, 7, 42.0, 12.0)], "tools.tbl")
START = ((0.0, 0.0, 100.0), (0.0, 0.0, 1.0))


def run(text, cfg=None, **kw):
    return interpret(text, "t.ngc", start=kw.pop("start", START), cfg=cfg or make_config(tools=TT), **kw)


def ok(text, **kw):
    job, problems = run(text, **kw)
    assert not problems, [str(p) for p in problems]
    return job


def events(job):
    return [e for m in job.moves if m.kind == EVENT for e in m.events]


# ---------------------------------------------------------------- order of execution, events

def test_a_block_runs_in_linuxcncs_order_and_its_events_go_where_the_path_is():
    job = ok("G21 G90 F600\nG0 X5 Y0 Z90\nS1000 M3\nM0 G1 X10 M8 G4 P0.5 T7 M6\nM30")
    kinds = [m.kind for m in job.moves]
    assert kinds == [RAPID, EVENT, EVENT, DWELL, LINE, EVENT, EVENT]
    on, change, dwell, line, pause, end = job.moves[1:]
    assert on.events == (("spindle", 1000.0),) and on.line == 3
    # T before M6 (a tool change stops the spindle), M8 after, all before the dwell and the motion
    assert change.events == (("spindle", 0.0), ("tool_change", 7), ("coolant", "flood"))
    assert dwell.dwell == 0.5 and line.spindle_rpm == 0.0        # M6 stopped the spindle: no M3 again yet
    assert pause.events == (("pause", "M0"),) and np.array_equal(pause.tip, line.tip)   # M0: after the motion
    assert end.events == (("coolant", "off"),) and end.line == 5                      # M30 stops what runs
    for k in (2, 5):
        assert np.array_equal(job.moves[k].tip, job.moves[k - 1].tip)                 # an event does not jump


def test_optional_stop_block_delete_and_user_m_codes_follow_the_interpreter_settings():
    text = "G0 X1\n/G0 X2\nM1\nM101 P3 Q4.5\nG0 X3\n"
    job, problems = run(text)
    assert [p.kind for p in problems] == ["unsupported"] and "user_m_codes" in problems[0].message
    assert [float(m.tip[0]) for m in job.moves if m.kind == RAPID] == [1, 2, 3]       # '/' lines run by default
    assert ("pause", "M1") in events(job)
    cfg = make_config(InterpreterConfig(optional_stop=False, block_delete=True, user_m_codes=(101,)), tools=TT)
    job = ok(text, cfg=cfg)
    assert [float(m.tip[0]) for m in job.moves if m.kind == RAPID] == [1, 3]
    assert events(job) == [("user_m", (101, 3.0, 4.5))]


def test_messages_keep_msg_as_written_and_substitute_parameters_in_debug_and_print():
    job = ok("#1 = 3.5\n#<depth> = -2\n(MSG, depth #1 here)\n(DEBUG, d=#<depth> p=#1 n=#<nope>)\n"
             "(PRINT, x=#<_x>)\n( plain comment, #1 )\n")
    assert job.messages == ((3, "depth #1 here"), (4, "d=-2.000000 p=3.500000 n=######"), (5, "x=0.000000"))
    assert events(job) == [("message", "depth #1 here"), ("message", "d=-2.000000 p=3.500000 n=######")]


# ---------------------------------------------------------------- tool length along the tool axis

def test_a_tool_offset_change_moves_the_tip_along_the_tilted_axis_and_keeps_the_platform():
    a, b = 12.0, -7.5
    job = ok(f"G21 G90 F300\nG1 X10 Y-4 Z80 A{a} B{b}\nG43 H7\nG1 X11\nG43 H2\nG49\n")
    axis = K.axis_from_roll_pitch(math.radians(a), math.radians(b))
    mv = [m for m in job.moves if m.kind != EVENT]
    ev = [m for m in job.moves if m.kind == EVENT]
    assert [m.events for m in ev] == [(("tool_offset", 42.0),), (("tool_offset", -5.5),), (("tool_offset", 0.0),)]
    ref = mv[0].tip + 0.0 * axis                       # the reference tool's tip: the platform's point
    for m, length in zip(ev, (42.0, -5.5, 0.0)):
        if m is ev[0]:
            np.testing.assert_allclose(m.tip + length * axis, ref, atol=1e-12)
        assert m.tool_offset == length
    # the line after G43 H7 is programmed at the tip, with the 42 mm longer tool
    assert mv[1].tool_offset == 42.0 and mv[1].tip[0] == 11.0
    np.testing.assert_allclose(mv[1].tip[1:], (ev[0].tip)[1:], atol=1e-12)


def test_g53_is_w_without_work_offsets_for_the_reference_tool():
    job = ok("G21 G10 L2 P1 X5 Y6 Z7\nG43.1 Z10\nG53 G0 X1 Y2 Z50\nG0 X0 Y0 Z0")
    g53, g54 = [m for m in job.moves if m.kind == RAPID]
    np.testing.assert_allclose(g53.tip, [1, 2, 40], atol=1e-12)        # Z50 is the reference tool's point
    np.testing.assert_allclose(g54.tip, [5, 6, 7], atol=1e-12)
    job, problems = run("G53 G0 Z0\nG0 X1")
    assert [p.kind for p in problems] == ["machine"] and "table top" in problems[0].message
    assert len([m for m in job.moves if m.kind == RAPID]) == 2          # noted: the program reads on


# ---------------------------------------------------------------- Move fields

def test_inverse_time_feed_per_rev_and_path_tolerance_fill_the_move():
    job = ok("G21 G90 G0 X0 Y0 Z100\nG93 G1 X30 Y40 F2\nG3 X40 Y30 R50 F6\nG94 F600\nS1200 M3\nG95 F0.1\nG1 X0\n"
             "G64 P0.05\nG94 F300 G1 Y0\nG61 G1 X1")
    inv, arc, per_rev, blended, exact = [m for m in job.moves if m.kind in (LINE, ARC)]
    assert inv.duration == pytest.approx(30.0) and inv.feed == pytest.approx(50.0 / 30.0)   # 50 mm in 1/2 min
    assert arc.duration == pytest.approx(10.0) and arc.kind == ARC
    assert per_rev.duration == 0 and per_rev.feed == pytest.approx(0.1 * 1200 / 60)       # mm/rev x rpm
    assert blended.tolerance == 0.05 and exact.tolerance == 0.0


def test_arcs_in_every_plane_carry_their_normal_and_a_point_on_the_axis():
    job = ok("G21 G90 F100 G0 X10 Y0 Z0\nG17 G3 X0 Y10 I-10\nG18 G2 X10 Z10 I10 K0\nG19 G3 Y0 Z0 R7.0711")
    xy, xz, yz = [m for m in job.moves if m.kind == ARC]
    assert xy.normal is None and xy.center.shape == (2,)
    np.testing.assert_allclose(xz.normal, [0, 1, 0]) and np.testing.assert_allclose(yz.normal, [1, 0, 0])
    for m, prev in ((xz, xy), (yz, xz)):
        n = np.asarray(m.normal)
        r0 = np.linalg.norm((prev.tip - m.center) - n * ((prev.tip - m.center) @ n))
        r1 = np.linalg.norm((m.tip - m.center) - n * ((m.tip - m.center) @ n))
        assert abs(r0 - r1) < 1e-4 and r0 > 1


def test_an_off_plane_centre_word_names_a_point_on_the_arc_axis_and_changes_nothing():
    # grbl ignores K on a G17 arc, LinuxCNC refuses it; CAM writes K0: pmctl takes any value (every point
    # (I, J, K) lies on the arc's axis) and the arc is the one without it (docs/gcode.md)
    plain = ok("G21 F100 G0 X10 Y0 Z0\nG2 X0 Y-10 I-10 J0")
    for k in ("K0", "K5", "K-3"):
        with_k = ok(f"G21 F100 G0 X10 Y0 Z0\nG2 X0 Y-10 I-10 J0 {k}")
        a, b = plain.moves[-1], with_k.moves[-1]
        assert np.array_equal(a.center, b.center) and a.sweep == b.sweep and np.array_equal(a.tip, b.tip)


def test_splines_are_flattened_within_a_micrometre_and_a_g5_series_stays_smooth():
    from pmctl.task.rs274.splines import CHORD_TOL_MM, _point
    job = ok("G21 G90 F600 G0 X0 Y0 Z90\nG5 I0 J30 P40 Q-30 X10 Y10\nG5 P0 Q-30 X20 Y0\nG5.1 X30 Y0 I5 J-10")
    lines = [m for m in job.moves if m.kind == LINE]
    a = [m for m in lines if m.line == 2]
    assert np.allclose(a[-1].tip, [10, 10, 90]) and all(m.feed == 10.0 for m in lines)
    # every vertex lies on the curve and every chord within the tolerance of it
    ctrl = [(0, 0), (0, 30), (50, -20), (10, 10)]
    t = np.linspace(0, 1, 200001)[:, None]
    c = np.array(ctrl, float)
    curve = (1 - t) ** 3 * c[0] + 3 * (1 - t) ** 2 * t * c[1] + 3 * (1 - t) * t * t * c[2] + t ** 3 * c[3]
    assert np.allclose(curve[77], _point(ctrl, float(t[77, 0])))
    pts = np.array([[0, 0]] + [m.tip[:2] for m in a])
    k = [0]                                      # each vertex's sample on the curve, in order along it
    for p in pts[1:]:
        j = k[-1] + int(np.argmin(np.linalg.norm(curve[k[-1]:k[-1] + 20000] - p, axis=1)))
        assert np.linalg.norm(curve[j] - p) < 5e-4
        k.append(j)
    for (p0, p1), (i0, i1) in zip(zip(pts[:-1], pts[1:]), zip(k[:-1], k[1:])):
        d = p1 - p0
        seg = curve[i0:i1 + 1]
        dev = np.abs((seg[:, 0] - p0[0]) * d[1] - (seg[:, 1] - p0[1]) * d[0]) / np.linalg.norm(d)
        assert dev.max() <= CHORD_TOL_MM * 1.05
    # the second G5 starts along the first one's end tangent (its first control point is the reflection)
    b = [m for m in lines if m.line == 3]
    t_in = a[-1].tip[:2] - a[-2].tip[:2]
    t_out = b[0].tip[:2] - a[-1].tip[:2]
    assert float(t_in @ t_out) / (np.linalg.norm(t_in) * np.linalg.norm(t_out)) > 0.999
    job, problems = run("G21 F100\nG5 P1 Q1 X5 Y5\nG18 G5.1 X1 I1 J1")
    assert ["I and J (the first control point) at the start" in problems[0].message,
            "XY plane (G17) only" in problems[1].message] == [True, True]


# ---------------------------------------------------------------- problems and limits

def test_m73_restores_the_callers_modes_and_events_on_m99_and_m72_needs_a_saved_state():
    job = ok("G21 G90 F600 S1000 M3\nM98 P1000\nG1 X2\nM2\nO1000\nM73\nG20 G91\nF5 S200\nG1 X1\nM9 M5\nM99")
    lines = [m for m in job.moves if m.kind == LINE]
    assert lines[0].tip[0] == pytest.approx(25.4) and lines[0].feed == pytest.approx(127.0 / 60)
    # back in the caller: mm, absolute, F600 and the spindle at 1000 rpm again (an event says so)
    assert lines[1].tip[0] == pytest.approx(2.0) and lines[1].feed == pytest.approx(10.0)
    assert lines[1].spindle_rpm == 1000.0 and ("spindle", 1000.0) in events(job)
    _, problems = run("G21\no1 sub\nM72\no1 endsub\no1 call\nM2")
    assert [(p.kind, p.line) for p in problems] == [("syntax", 3)] and "M70" in problems[0].message


def test_a_fault_inside_the_interpreter_is_a_problem_of_its_line_and_the_rest_runs(monkeypatch):
    from pmctl.task.rs274 import execute as EX

    def broken(self, *a, **k):          # stands for a numeric case the interpreter's own checks missed
        raise ZeroDivisionError("float division by zero")
    monkeypatch.setattr(EX.Executor, "arc", broken)
    job, problems = run("G21 G90 F300\nG1 X10\nG2 X20 Y0 I5 J0\nG1 X30\nM2")
    assert [(p.line, p.kind) for p in problems] == [(3, "unsupported")] and "fault in pmctl" in problems[0].message
    assert [m.tip[0] for m in job.moves if m.kind == LINE] == [10.0, 30.0]


def test_every_problem_has_file_line_column_kind_and_says_what_to_do():
    job, problems = run("G0 X1\nG1 X2\nG43 H99\nT1 M6 G43\nG41 D44 G1 X5\nM66 P0 L0\nG0 X1 C3\nM3 S-5\n")
    got = [(p.line, p.kind) for p in problems]
    assert got == [(2, "syntax"), (3, "machine"), (5, "machine"), (5, "syntax"), (6, "machine"), (7, "machine"),
                   (8, "syntax")]
    msg = {p.line: p.message for p in problems}
    assert "G43 H99: tool 99 is not in the tool table tools.tbl; add it, or use G43.1" in msg[3]
    assert all(p.file == "t.ngc" and p.column for p in problems if "cutter compensation" not in p.message)


def test_problems_are_capped_and_an_endless_loop_is_a_problem_not_a_hang(monkeypatch):
    job, problems = run("\n".join(["G1 X1 Q5"] * (PR.MAX_PROBLEMS + 20)))
    assert len(problems) == PR.MAX_PROBLEMS + 1 and "only the first 500" in problems[-1].message
    monkeypatch.setattr(PR, "MAX_BLOCKS", 2000)
    job, problems = run("F100\no1 while [1]\nG91 G1 X1\no1 endwhile\n")
    assert len(problems) == 1 and "endless loop" in problems[0].message and problems[0].kind == "unsupported"
    assert len(job.moves) == 2000 // 3              # a block each of while, G1, endwhile


def test_a_probe_result_is_unknown_to_a_job_file_read_before_it_runs():
    job, problems = run("G21 F50\nG38.2 Z80\nG0 Z[#5063 + 5]\n")
    assert [p.kind for p in problems] == ["syntax"] and "known only when the probe has run" in problems[0].message


def test_subroutine_files_come_from_the_search_path_and_their_moves_name_the_file(tmp_path):
    (tmp_path / "slot.ngc").write_text("o<slot> sub\nG1 X[#1] F100\nG1 Y[#2]\no<slot> endsub\n")
    cfg = make_config(InterpreterConfig(subroutine_path=(str(tmp_path),)), tools=TT)
    job = ok("G0 X0 Y0 Z90\no<slot> call [4] [5]\nG0 Z95\n", cfg=cfg)
    assert [(float(m.tip[0]), float(m.tip[1]), m.line, Path(m.file).name) for m in job.moves] == [
        (0.0, 0.0, 1, ""), (4.0, 0.0, 2, "slot.ngc"), (4.0, 5.0, 3, "slot.ngc"), (4.0, 5.0, 3, "")]
    job, problems = run("o<missing> call\n")
    assert problems[0].kind == "syntax" and "missing.ngc on the subroutine path (none configured" in problems[0].message


def test_grbl_queries_in_a_job_file_are_skipped_and_its_other_commands_refused():
    job, problems = run("$I ; build info\n$$\n?\nG0 X1\n$H\n")
    assert len(job.moves) == 1 and [(p.line, p.kind) for p in problems] == [(5, "unsupported")]


def test_memory_per_move_stays_small_and_there_is_no_move_cap():
    text = "G21 G90 F600\n" + "\n".join(f"G1 X{k % 100 * 0.01:.2f} Y{k % 37 * 0.01:.2f} Z{k % 13 * 0.01:.2f}"
                                        for k in range(15000))
    tracemalloc.start()
    try:
        job = ok(text)
        size, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(job.moves) == 15000
    assert size / len(job.moves) < 700          # bytes a move (a Move, its tip array, a shared axis)


# ---------------------------------------------------------------- tool table and settings

def test_the_bundled_tool_table_and_service_config_load():
    cfg = service_from_dict({}).interpreter
    table = load_tool_table(cfg.tool_table)
    assert Path(cfg.tool_table).name == "tools.tbl" and len(table) >= 1
    assert all(t.number >= 0 and t.diameter > 0 for t in table.tools.values())


@pytest.mark.parametrize("text,words", [
    ("T1 P1 Z0 D6\nT1 P2 Z0 D3", "tool 1 is listed twice"),
    ("T1 X0.5 Z0", "X0.5: this machine's tool table holds a length offset (Z) and a diameter (D)"),
    ("P1 Z0", "a tool line needs its number T"),
    ("T1.5", "must be an integer"),
    ("T1 D-3", "diameter D-3 mm must be within 0 .. 1000"),
    ("T1 Z1 Z2", "word Z appears twice"),
    ("T1 R5", "unknown word R"),
    ("T1 Z1 garbage", "cannot read 'garbage'"),
])
def test_bad_tool_tables_are_refused_with_file_line_and_word(text, words):
    with pytest.raises(ConfigError) as e:
        parse_tool_table("; header\n" + text, "my.tbl")
    assert "my.tbl" in str(e.value) and "line " in str(e.value) and words in str(e.value)


def test_the_interpreter_section_resolves_paths_and_refuses_bad_values(tmp_path):
    p = tmp_path / "service.toml"
    p.write_text("[interpreter]\ntool_table = \"t.tbl\"\nsubroutine_path = [\"subs\", \"/abs\"]\n"
                 "user_m_codes = [101, 150]\noptional_stop = false\n")
    from pmctl.motion.service_config import load_service_config
    cfg = load_service_config(p).interpreter
    assert cfg.tool_table == str(tmp_path / "t.tbl") and cfg.subroutine_path == (str(tmp_path / "subs"), "/abs")
    assert cfg.user_m_codes == (101, 150) and cfg.optional_stop is False and cfg.block_delete is False
    p.write_text("[loop]\nrate_hz = 1000\n")            # no [interpreter]: the bundled tool table, wherever the file is
    assert Path(load_service_config(p).interpreter.tool_table) == Path(InterpreterConfig().tool_table)
    assert load_tool_table(load_service_config(p).interpreter.tool_table).get(1) is not None
    for body, words in (("user_m_codes = [99]", "99 is not a user M-code"), ("user_m_codes = 101", "list of"),
                        ("subroutine_path = \"x\"", "list of folder"), ("optional_stop = 1", "true or false"),
                        ("digital_outputs = 100", "digital_outputs"), ("toolz = 1", "unknown key")):
        with pytest.raises(ConfigError) as e:
            service_from_dict({"interpreter": dict([_kv(body)])}, "s.toml")
        assert words in str(e.value), str(e.value)


def _kv(body):
    import tomllib
    return next(iter(tomllib.loads(body).items()))


# ---------------------------------------------------------------- the console's line interpreter

@pytest.fixture
def console():
    m = load_machine()
    from pmctl.core.job import home_pose
    tip, axis = home_pose(m)
    return LineInterpreter(m, tip, axis)


def test_console_accepts_what_senders_send_on_reset_and_probing(console):
    for line in ("G43.1Z0.000", "G43.1 Z-1.5", "G49", "$$" if False else "G21 G90", "T1 M6", "M7 M8", "M9"):
        console.execute(line, 1)
    moves, _, _ = console.execute("G43.1 Z2", 2)
    assert [m.events for m in moves] == [(("tool_offset", 2.0),)] and console.tlo() == 2.0
    moves, _, _ = console.execute("G49", 3)
    assert moves[0].events == (("tool_offset", 0.0),)


def test_console_lines_without_motion_give_their_events(console):
    moves, n, flags = console.execute("N12 M3 S6000", 5)
    assert n == 12 and [(m.kind, m.events, m.line) for m in moves] == [(EVENT, (("spindle", 6000.0),), 5)]
    assert console.execute("M5", 6)[0][0].events == (("spindle", 0.0),)
    assert console.execute("M62 P1", 7)[0][0].events == (("output", ("digital", 1, 1.0)),)
    assert console.execute("G21", 8)[0] == []


@pytest.mark.parametrize("line,code", [
    ("G1 X", 2), ("G0 G1 X1", 21), ("G1 X1 X2", 25), ("G4", 28), ("G41 D1", 20), ("Q7", 36),
    ("o100 while [1]", 20), ("G5.2 X1 P1 L3", 20), ("G43.4 H1", 20), ("G1 F0 X1", 22), ("N1.5 G0 X1", 27),
    ("G0 X900", 33),
])
def test_console_errors_carry_grbl_codes_and_change_nothing(console, line, code):
    console.execute("G1 X0 F100", 1)
    before = (console.parser_state(), console.offsets(), console.position_w())
    with pytest.raises(LineError) as e:
        console.execute(line, 2)
    assert e.value.code == code, (line, str(e.value))
    assert (console.parser_state(), console.offsets(), console.position_w()) == before


def test_console_offsets_persist_in_the_journal_format_and_old_journals_load(tmp_path):
    m = load_machine()
    old = {"wcs": {"G54": [1, 2, 3, 0, 0], "G55": [0, 0, 0, 0, 0], "G56": [0, 0, 0, 0, 0], "G57": [0, 0, 0, 0, 0],
                   "G58": [0, 0, 0, 0, 0], "G59": [4, 5, 6, 0, 0]}, "g92": [0.5, 0, 0, 0, 0], "active": "G59"}
    it = LineInterpreter(m, (0, 0, 150), (0, 0, 1), old)
    assert it.wco() == [4.5, 5, 6, 0, 0] and it.active == "G59"
    moves, _, flags = it.execute("G10 L20 P1 X0", 1)
    assert flags.get("sync") and it.changed
    saved = it.offsets()
    assert saved["wcs"]["G54"][0] == pytest.approx(0.0 - 0.5) and saved["active"] == "G59"
    again = LineInterpreter(m, (0, 0, 150), (0, 0, 1), saved)
    assert again.offsets() == saved
    # the new systems, rotations and G28/G30 positions go through the daemon's journal file and back
    again.execute("G10 L2 P9 X3 R15", 2)
    again.execute("G59.3 G28.1", 3)
    j = Journal(tmp_path / "state.json.journal", m.name)
    j.save(offsets=again.offsets())
    loaded = Journal(tmp_path / "state.json.journal", m.name).load().data["offsets"]
    assert loaded["active"] == "G59.3" and loaded["rotation"] == {"G59.3": 15.0} and loaded["g28"][2] == 150.0
    assert LineInterpreter(m, (0, 0, 150), (0, 0, 1), loaded).offsets() == again.offsets()


def test_console_state_snapshot_restores_everything(console):
    console.execute("G91 G20 G1 X0.1 F10", 1)
    saved = copy.deepcopy(console.st)
    assert saved.units == 25.4 and saved.absolute is False
    console.execute("G90 G21 G10 L2 P1 X7", 2)
    console.st = saved
    assert console.st.units == 25.4 and console.offsets()["wcs"]["G54"][0] == 0.0
    console.st.probe_ok = False
    with pytest.raises(LineError) as e:
        console.execute("G38.2 Z90 F60", 3)
    assert e.value.code == 20 and "probing is not available here" in str(e.value)


def test_start_position_round_trips_the_tool_axis():
    axis = K.axis_from_roll_pitch(math.radians(8.0), math.radians(-13.0))
    x, y, z, a, b = start_position((1, 2, 3), axis)
    assert (x, y, z) == (1, 2, 3) and a == pytest.approx(8.0, abs=1e-12) and b == pytest.approx(-13.0, abs=1e-12)
