"""Stops of a program streamed through the console: `pmctl serve --backend sim --no-realtime --record` on
a pty, a character-counting sender (tests/grbl_sender.py) streams a program of short lines, and the
commanded tool tip of the recording (forward kinematics of the pulse counters, tick by tick) gives
the speed along the path. Reported: the blocks, the ticks, the speed where the program has no stop
(its minimum and median) and the number of stops there (the speed below 0.5 mm/s). The figures of
docs/console.md on the queue's depth come from this script.

    .venv/bin/python benchmarks/console_stream_stops.py [--feed 3000] [--side 1.0] [--shape square|polygon]

``square``: a square of 60 mm sides in lines of ``--side`` mm (the speed is judged on the sides, 5 mm
and more from a corner, where the planner makes its exact stops); ``polygon``: a polygon of sides of
``--side`` mm around a circle of R 30 mm (judged between 15 % and 85 % of its ticks). Offline ticks:
the figures do not depend on the machine's load (printed with them); the wall times do.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from grbl_sender import Sender, start_serve, stop_serve  # noqa: E402
from pmctl.core import kinematics as K  # noqa: E402
from pmctl.core.config import load_machine  # noqa: E402
from pmctl.core.recording import read_recording  # noqa: E402


def program(shape, feed, side):
    if shape == "square":
        n = int(round(60 / side))
        lines = ["G21 G90 G17", "G0 X-30 Y-30 Z60", f"G1 F{feed:g}"]
        c = [(-30, -30), (30, -30), (30, 30), (-30, 30), (-30, -30)]
        for (x0, y0), (x1, y1) in zip(c, c[1:]):
            lines += [f"G1 X{x0 + (x1 - x0) * k / n:.4f} Y{y0 + (y1 - y0) * k / n:.4f}" for k in range(1, n + 1)]
        return lines
    n = int(round(2 * math.pi * 30 / side))
    return ["G21 G90 G17", "G0 X30 Y0 Z60", f"G1 F{feed:g}"] + [
        f"G1 X{30 * math.cos(2 * math.pi * k / n):.4f} Y{30 * math.sin(2 * math.pi * k / n):.4f}"
        for k in range(1, n + 1)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--feed", type=float, default=3000.0, help="mm/min")
    ap.add_argument("--side", type=float, default=1.0, help="the lines' length, mm")
    ap.add_argument("--shape", choices=("square", "polygon"), default="square")
    a = ap.parse_args()
    lines = program(a.shape, a.feed, a.side)
    tmp = Path(tempfile.mkdtemp(prefix="pmctl-stream-stops-"))
    t0 = time.time()
    p, link = start_serve(tmp, record=tmp / "rec")
    s = Sender(link)
    try:
        t1 = time.time()
        answers = s.stream(lines)
        assert answers == ["ok"] * len(lines), [x for x in answers if x != "ok"][:3]
        st = s.wait_state(("Idle",), 600)
        t2 = time.time()
        assert st and st["state"] == "Idle", st
    finally:
        s.close()
        stop_serve(p)
    m = load_machine()
    rec = read_recording(tmp / "rec")
    q = np.column_stack([rec.get(f"cmd_{x}") for x in ("L1", "L2", "L3", "X", "Y")])
    tip = K.fk_batch(q, m)[0].tip
    line = rec.get("line")
    g1 = np.nonzero((line >= 4) & (line <= len(lines)))[0]
    v = np.linalg.norm(tip[g1[5:]] - tip[g1[:-5]], axis=1) / (5 * float(np.median(np.diff(rec.get("t")))))
    if a.shape == "square":
        p5 = tip[g1[5:]]
        corner = (np.abs(np.abs(p5[:, 0]) - 30) < 5) & (np.abs(np.abs(p5[:, 1]) - 30) < 5)
        on_side = np.maximum(np.abs(p5[:, 0]), np.abs(p5[:, 1])) > 29.9
        inner = v[on_side & ~corner]
    else:
        inner = v[int(0.15 * len(v)):int(0.85 * len(v))]
    slow = inner < 0.5
    stops = int(np.count_nonzero(np.diff(slow.astype(int)) == 1) + (1 if len(slow) and slow[0] else 0))
    print(f"{a.shape} of {len(lines) - 3} lines of {a.side:g} mm at F{a.feed:g}: {len(g1)} ticks; where the program "
          f"has no stop: speed min {inner.min():.2f} mm/s, median {np.median(inner):.2f} mm/s, stops {stops}")
    print(f"wall: serve start {t1 - t0:.1f} s, stream to Idle {t2 - t1:.1f} s; load average "
          + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
