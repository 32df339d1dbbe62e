"""A program streamed through the console runs as one job, over the real pty, the real rt process and
the sim: `pmctl serve --record`, a character-counting sender (tests/grbl_sender.py), then the recording.

1. A 120-sided polygon of 1 mm blocks at F600 (0.1 s a block), streamed line by line: the commanded
   tool tip (forward kinematics of the recorded pulse counters, tick by tick) never slows to a stop
   between the lines, and it is plan() of the same program from the same start, sample for sample
   (one tick offset for the whole program: no time was inserted anywhere), to the pulse resolution.
2. A sender that pauses mid-program: the machine stops on the path exactly at the last block it
   has (never past it), and goes on from there when the rest comes.
3. A feed hold in the middle of a stream holds the tool on the path, cycle start goes on, and the
   program ends exactly at its last point; a soft reset in the middle of a stream stops the tool on
   the path and drops the rest, and the next line runs from there.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from grbl_sender import Sender, hold_still_resume, start_serve, stop_serve
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.recording import read_recording
from pmctl.task.gcode import parse_gcode
from pmctl.task.planner import plan

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

FEED = 600.0                      # mm/min: 1 mm blocks take 0.1 s


def polygon(n=60, r=None, z=60.0, head=True):
    """A polygon of ``n`` sides of 1 mm (0.1 s each at FEED) after a rapid to its first corner."""
    r = n / (2 * math.pi) if r is None else r
    lines = ["G21 G90 G17", f"G0 X{r:g} Y0 Z{z:g}", f"G1 F{FEED:g}"] if head else []
    for k in range(1, n + 1):
        a = 2 * math.pi * k / n
        lines.append(f"G1 X{r * math.cos(a):.4f} Y{r * math.sin(a):.4f}")
    return lines


def on_second_quarter(s, timeout=120):
    """Wait until the machine runs the second quarter of a polygon around the Z axis (from 90 deg)."""
    def there():
        st = s.status()
        return st is not None and st["state"] == "Run" and np.pi / 2 <= math.atan2(st["pos"][1], st["pos"][0]) <= np.pi
    return s.wait_for(there, timeout)


def corners(lines):
    """The polygon's corners in order, X Y Z (its Z from the rapid to it)."""
    z = float(lines[1].split()[3][1:])
    pts = [(float(lines[1].split()[1][1:]), 0.0)] + [tuple(float(w[1:]) for w in ln.split()[1:]) for ln in lines[3:]]
    return np.array([[x, y, z] for x, y in pts])


def distance_to_path(p, pts):
    """Distance of the point ``p`` to the polyline through ``pts``."""
    a, b = pts[:-1], pts[1:]
    ab = b - a
    t = np.clip(((p - a) * ab).sum(1) / (ab * ab).sum(1), 0.0, 1.0)
    return float(np.linalg.norm(a + t[:, None] * ab - p, axis=1).min())


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Runs the four programs through `pmctl serve` and returns what the sender saw and the recording.
    The console counts the G-code lines it executes: the recording's ``line`` is that count."""
    tmp = tmp_path_factory.mktemp("console_stream")
    p, link = start_serve(tmp, record=tmp / "rec")
    s = Sender(link)
    out = {}
    try:
        a = polygon()
        assert s.stream(a) == ["ok"] * len(a)
        out["a_end"] = s.wait_state(("Idle",), 300)
        b = polygon(n=30, z=62.0)
        half = 18                                         # the header and 15 blocks
        assert s.stream(b[:half]) == ["ok"] * half
        out["paused"] = s.wait_state(("Idle",), 300)      # the sender starved the queue: the machine stops
        assert s.stream(b[half:]) == ["ok"] * (len(b) - half)
        out["b_end"] = s.wait_state(("Idle",), 300)
        out.update(a=a, b=b, half=half)
        # a feed hold while the tool is on the polygon's second quarter (the stream open, its blocks
        # queued), then cycle start
        c = polygon(n=30, z=64.0)
        assert s.stream(c) == ["ok"] * len(c)
        assert on_second_quarter(s)
        out.update(c=c, held=hold_still_resume(s), c_end=s.wait_state(("Idle",), 300))
        # a soft reset there; then a line from where it stopped
        d = polygon(n=30, z=66.0)
        assert s.stream(d) == ["ok"] * len(d)
        assert on_second_quarter(s)
        pushed = s.reset()
        out.update(d=d, reset=s.wait_state(("Idle",), 60), reset_pushed=pushed)
        assert s.send("G90 G1 X0 Y0 Z66 F600") == "ok"
        out["after_reset"] = s.wait_state(("Idle",), 120)
    finally:
        s.close()
        stop_serve(p)
    out["rec"] = read_recording(tmp / "rec")
    return out


def commanded(rec, machine):
    """The commanded tool tip and axis of every tick: FK of the recorded pulse counters."""
    q = np.column_stack([rec.get(f"cmd_{a}") for a in ("L1", "L2", "L3", "X", "Y")])
    pose, ok = K.fk_batch(q, machine)
    assert ok.all()
    return pose.tip, pose.axis / np.linalg.norm(pose.axis, axis=1)[:, None]


def test_a_streamed_program_does_not_stop_between_its_lines_and_is_the_plan_of_the_program(session):
    m = load_machine()
    rec, a = session["rec"], session["a"]
    assert session["a_end"]["state"] == "Idle"
    tip, axis = commanded(rec, m)
    line = rec.get("line")
    ticks = np.nonzero((line >= 1) & (line <= len(a)))[0]
    # the polygon's blocks (console lines 4 .. 63): the speed over 5 ticks, from the counters
    g1 = np.nonzero((line >= 4) & (line <= len(a)))[0]
    there = np.nonzero(np.linalg.norm(tip[g1] - corners(a)[-1], axis=1) <= 1e-3)[0]    # (= its first point)
    g1 = g1[:there[there > len(g1) // 2][0] + 1]          # (until the tool is back there at the end: then it rests)
    v = np.linalg.norm(tip[g1[5:]] - tip[g1[:-5]], axis=1) / 5e-3
    inner = v[150:-150]                                   # (the start from the rapid's corner, the end)
    assert inner.min() > 0.4 * FEED / 60, inner.min()     # never a stop (the corners' junction speed)
    # plan() of the same program from the pose the stream started at: one offset for all of it
    t0 = ticks[0] - 1
    job = parse_gcode("\n".join(a), "a.ngc", tip[t0], axis[t0])
    traj = plan(job, m, 1e-3, start=(tip[t0], axis[t0]))
    moved = np.nonzero(np.linalg.norm(tip[t0:] - tip[t0], axis=1) > 1e-3)[0][0] + t0
    first = np.nonzero(np.linalg.norm(traj.tip - traj.tip[0], axis=1) > 1e-3)[0][0]
    errs = []
    for off in range(moved - first - 20, moved - first + 21):
        k = np.arange(off, off + len(traj))
        errs.append(np.linalg.norm(tip[k] - traj.tip[k - off], axis=1).max())
    pulse = 1.0 / float(np.max(m.resolution.pulses_per_mm))
    assert min(errs) <= 3 * pulse, (min(errs), pulse)     # the plan, sample for sample, to the pulses


def test_a_sender_that_pauses_stops_the_machine_at_its_last_block_and_it_goes_on(session):
    m = load_machine()
    rec, b, half = session["rec"], session["b"], session["half"]
    last = corners(b)[half - 3]                           # the last block's point
    paused = session["paused"]
    assert paused["state"] == "Idle"
    assert np.allclose(paused["pos"][:3], last, atol=1.5e-3), (paused["pos"], last)
    end = corners(b)[-1]
    assert np.allclose(session["b_end"]["pos"][:3], end, atol=1.5e-3)
    # in the recording: the tip came to rest at that point and not past it, then went on from it
    tip, _ = commanded(rec, m)
    line = rec.get("line")
    n_a = len(session["a"])
    first = np.nonzero((line > n_a) & (line <= n_a + half))[0]
    second = np.nonzero(line > n_a + half)[0]
    assert len(first) and len(second)
    d_first = np.linalg.norm(tip[first] - last, axis=1)
    pulse = 1.0 / float(np.max(m.resolution.pulses_per_mm))
    assert d_first[-1] <= 2 * pulse                        # at rest on the last block's point
    # approaching it along the last block: the distance only shrinks (never past it and back)
    approach = d_first[-300:]
    assert np.all(np.diff(approach) <= pulse), np.diff(approach).max()
    assert np.linalg.norm(tip[second[0]] - last) <= 2 * pulse    # the rest starts from there


def test_a_feed_hold_mid_stream_holds_on_the_path_and_the_program_ends_at_its_last_point(session):
    pts = corners(session["c"])
    held = session["held"]
    assert held["state"] == "Hold:0"
    p = np.array(held["pos"][:3])
    assert distance_to_path(p, pts) <= 1.5e-3, (p, distance_to_path(p, pts))     # on the polygon
    assert np.linalg.norm(p - pts[-1]) > 1.0                                       # in the middle of it
    assert session["c_end"]["state"] == "Idle"
    assert np.allclose(session["c_end"]["pos"][:3], pts[-1], atol=1.5e-3)


def test_a_soft_reset_mid_stream_stops_on_the_path_and_the_next_line_runs_from_there(session):
    pts = corners(session["d"])
    assert any(x.startswith("Grbl ") for x in session["reset_pushed"])
    st = session["reset"]
    assert st["state"] == "Idle", st
    p = np.array(st["pos"][:3])
    assert distance_to_path(p, pts) <= 1.5e-3, (p, distance_to_path(p, pts))     # stopped on the polygon
    assert np.linalg.norm(p - pts[-1]) > 1.0                                       # the rest was dropped
    assert np.allclose(session["after_reset"]["pos"][:3], [0.0, 0.0, 66.0], atol=1.5e-3)


def test_with_an_input_shaper_the_stream_is_planned_whole_and_ends_on_its_last_point(tmp_path):
    """With [nc] shaper set the shaper plans whole jobs: the console's stream (Supervisor.stream) is
    collected until it closes and planned from rest to rest; the machine ends on its last point and
    the rt side counts every pulse."""
    from pathlib import Path

    from pmctl.motion import channel as C
    from pmctl.motion.nc import counts_of
    from pmctl.task.interp import LineInterpreter
    from pmctl.core.job import home_pose
    from pmctl.task.supervisor import Supervisor
    svc = tmp_path / "service.toml"
    base = (Path(__file__).resolve().parents[2] / "config" / "service.toml").read_text()
    svc.write_text(base.replace('shaper = "none"', 'shaper = "ZVD"\nshaper_hz = 40.0', 1))
    sup = Supervisor("prototype", service=str(svc), realtime=False)
    assert sup.nc_setup.shaper is not None
    tip, ax = home_pose(sup.machine)
    sup.start(counts_of(K.ik(tip, ax, sup.machine).q, sup.params))
    try:
        li = LineInterpreter(sup.machine, tip, ax)
        lines = polygon(n=8, z=60.0)
        for k, ln in enumerate(lines, 1):
            moves, _, _ = li.execute(ln, k)
            if moves:
                sup.stream(moves, {k: 0})
        assert sup.wait_idle(120) and not sup.alarm          # the stream starved and closed: it ran
        r = sup.raw()
        assert np.array_equal(r[C.ST_COUNTS:C.ST_COUNTS + 5], r[C.ST_COUNTS0:C.ST_COUNTS0 + 5] + r[C.ST_SENT:C.ST_SENT + 5])
        assert np.linalg.norm(sup.pose()[0] - corners(lines)[-1]) < 2e-3
    finally:
        sup.shutdown()
