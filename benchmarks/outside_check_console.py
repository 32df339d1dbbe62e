"""The console's outside check (issue 26): `pmctl serve --backend sim` in real time on a pty, driven
as a sender would, with the figures printed (times are wall-clock on a shared machine: the load
average is printed with them).

1. a lone M5 stops the spindle (FS: and A: of the status), a lone M3 S7000 starts it: seconds from
   the ok to the status showing it (the check: within 2 s);
2. flow control: a character-counting stream of 3 x depth moves of 0.1 s (G91 G1 X/Y 1 mm at
   F600 around a square): the oks received in its first 0.5 s against the depth advertised in
   [OPT:] (the check: at most depth + 10), and when the last ok came as a share of the motion
   (the check: after 60 %);
3. bCNC's reset sequence (ctrl-X, $X, the $G modes, G43.1Z0.0, $G, $#) answers ok.

    .venv/bin/python benchmarks/outside_check_console.py
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from grbl_sender import Sender, start_serve, stop_serve  # noqa: E402


def spindle(st):
    return float(st["FS"].split(",")[1])


def main() -> int:
    tmp = Path(tempfile.mkdtemp(prefix="pmctl-outside-"))
    p, link = start_serve(tmp, realtime=True)
    s = Sender(link)
    ok = True
    try:
        print(f"load average at start: {os.getloadavg()[0]:.2f}")
        n = len(s.pushed)
        s.send("$I")
        depth = int(re.match(r"\[OPT:[A-Z]*,(\d+),", [x for x in s.pushed[n:] if x.startswith("[OPT:")][0]).group(1))
        # 1. lone M3 / M5
        for line, want in (("M3 S7000", 7000.0), ("M5", 0.0)):
            t0 = time.monotonic()
            assert s.send(line) == "ok"
            t_ok = time.monotonic()
            while spindle(s.status()) != want and time.monotonic() - t0 < 30:
                time.sleep(0.01)
            dt = time.monotonic() - t_ok
            st = s.status()
            good = spindle(st) == want and dt < 2.0
            ok &= good
            print(f"lone {line:8s}: ok after {t_ok - t0:.3f} s, status FS spindle {spindle(st):g} rpm, A:{st.get('A', '')!s:3s}"
                  f" {dt:.2f} s after the ok -> {'PASS' if good else 'FAIL'}")
        s.wait_state(("Idle",), 30)
        # 2. flow control
        assert s.send("G21 G91 F600") == "ok"
        steps = ["X1", "Y1", "X-1", "Y-1"]
        lines = [f"G1 {steps[k % 4]}" for k in range(3 * depth)]
        p0 = s.status()["pos"]
        n0 = len(s.answers)
        t_ok = []
        t0 = time.monotonic()
        for line in lines:
            s.send(line, wait=False)
            while len(t_ok) < len(s.answers) - n0:
                t_ok.append(time.monotonic() - t0)
        s.wait_for(lambda: len(s.answers) - n0 >= len(lines), 120)
        while len(t_ok) < len(s.answers) - n0:
            t_ok.append(time.monotonic() - t0)
        t_last = t_ok[-1]
        s.wait_state(("Idle",), 120)
        t_end = time.monotonic() - t0
        assert s.send("G90") == "ok"
        early = sum(1 for t in t_ok if t <= 0.5)
        share = t_last / t_end
        good = early <= depth + 10 and share > 0.6
        ok &= good
        print(f"flow control: depth {depth} ([OPT:]), stream of {len(lines)} moves of 0.1 s: {early} oks in the first "
              f"0.5 s (limit {depth + 10}); last ok at {t_last:.2f} s of {t_end:.2f} s of motion ({100 * share:.0f} %, "
              f"limit > 60 %) -> {'PASS' if good else 'FAIL'}; back at the start: "
              f"{max(abs(a - b) for a, b in zip(s.status()['pos'], p0)):.4f} mm")
        # 3. bCNC's reset sequence
        n = len(s.pushed)
        s.pending.clear()
        s.realtime(b"\x18")
        s.wait_for(lambda: any(x.startswith("Grbl ") for x in s.pushed[n:]), 30)
        seq = ["$X", "G0 G54 G17 G21 G90 G94", "G43.1Z0.0", "$G", "$#"]
        answers = [s.send(x) for x in seq]
        good = answers == ["ok"] * len(seq)
        ok &= good
        print(f"bCNC reset sequence {seq}: {answers} -> {'PASS' if good else 'FAIL'}")
        print(f"load average at the end: {os.getloadavg()[0]:.2f}")
    finally:
        s.close()
        stop_serve(p)
    print("outside check (console part):", "PASS" if ok else "FAIL",
          "(CNCjs streaming the spiral with a hold: tests/integration/test_sender_cncjs.py)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
