"""A program streamed through the console runs as one job, over the real pty, the real rt process and
the sim: `pmctl serve --record`, a character-counting sender (tests/grbl_sender.py), then the recording.

1. A 120-sided polygon of 1 mm blocks at F600 (0.1 s a block), streamed line by line: the commanded
   tool tip (forward kinematics of the recorded pulse counters, tick by tick) never slows to a stop
   between the lines, and it is plan() of the same program from the same start, sample for sample
   (one tick offset for the whole program: no time was inserted anywhere), to the pulse resolution.
2. A sender that pauses mid-program: the machine stops on the path exactly at the last block it
   has (never past it), and goes on from there when the rest comes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from grbl_sender import Sender, start_serve, stop_serve
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.recording import read_recording
from pmctl.task.gcode import parse_gcode
from pmctl.task.planner import plan

FEED = 600.0                      # mm/min: 1 mm blocks take 0.1 s


def polygon(n=120, r=30.0, z=60.0, head=True):
    lines = ["G21 G90 G17", f"G0 X{r:g} Y0 Z{z:g}", f"G1 F{FEED:g}"] if head else []
    for k in range(1, n + 1):
        a = 2 * math.pi * k / n
        lines.append(f"G1 X{r * math.cos(a):.4f} Y{r * math.sin(a):.4f}")
    return lines


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Runs the two programs through `pmctl serve` and returns what the sender saw and the recording.
    The console counts the G-code lines it executes: the recording's ``line`` is that count."""
    tmp = tmp_path_factory.mktemp("console_stream")
    p, link = start_serve(tmp, record=tmp / "rec")
    s = Sender(link)
    out = {}
    try:
        a = polygon()
        assert s.stream(a) == ["ok"] * len(a)
        out["a_end"] = s.wait_state(("Idle",), 300)
        b = polygon(n=60, r=20.0, z=62.0)
        half = 33                                         # the header and 30 blocks
        assert s.stream(b[:half]) == ["ok"] * half
        out["paused"] = s.wait_state(("Idle",), 300)      # the sender starved the queue: the machine stops
        assert s.stream(b[half:]) == ["ok"] * (len(b) - half)
        out["b_end"] = s.wait_state(("Idle",), 300)
        out.update(a=a, b=b, half=half)
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
    # the polygon's blocks (console lines 4 .. 123): the speed over 5 ticks, from the counters
    g1 = np.nonzero((line >= 4) & (line <= len(a)))[0]
    v = np.linalg.norm(tip[g1[5:]] - tip[g1[:-5]], axis=1) / 5e-3
    inner = v[200:-200]                                   # (the start from the rapid's corner, the end)
    assert inner.min() > 0.4 * FEED / 60, inner.min()     # never a stop (the corners' junction speed: 7.5 mm/s)
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
    last = np.array([float(w[1:]) for w in b[half - 1].split()[1:]] + [62.0])   # X Y of the last block, Z
    paused = session["paused"]
    assert paused["state"] == "Idle"
    assert np.allclose(paused["pos"][:3], last, atol=1.5e-3), (paused["pos"], last)
    end = np.array([float(w[1:]) for w in b[-1].split()[1:]] + [62.0])
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
