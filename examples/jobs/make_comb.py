"""Write ``comb.ngc``: a comb of Z strokes with sharp corners, the vibration test job (soft-machine
K_theta and input-shaper tests, docs/vibration.md).

    python examples/jobs/make_comb.py [--feed 3000] [--teeth 8] [--out examples/jobs/comb.ngc]

The tool is vertical; each tooth is a plunge of ``depth`` mm in Z, a sideways step of ``pitch`` mm in
X and a retract: every junction is a 90 degree corner, so the planner stops the tip there (exact stop)
and the chains see the full acceleration and deceleration at each end of each stroke.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HERE = Path(__file__).resolve().parent
FACE_Z = 60.0


def comb(feed=3000.0, teeth=8, depth=8.0, pitch=3.0, x0=-12.0, y=0.0):
    lines = [f"(pmctl test job: comb of {teeth} Z strokes {depth:g} mm deep, pitch {pitch:g} mm, F{feed:g}, sharp corners)",
             "G21 G90 G17",
             f"G0 X{x0:g} Y{y:g} Z{FACE_Z + 5:g}",
             f"G1 Z{FACE_Z:g} F{feed:g}"]
    x = x0
    top = True
    for _ in range(teeth):
        z = FACE_Z - depth if top else FACE_Z
        lines.append(f"G1 Z{z:g}")
        x += pitch
        lines.append(f"G1 X{x:g}")
        top = not top
    lines.append(f"G1 Z{FACE_Z + 5:g}")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--feed", type=float, default=3000.0)
    ap.add_argument("--teeth", type=int, default=8)
    ap.add_argument("--out", default=str(HERE / "comb.ngc"))
    a = ap.parse_args(argv)
    Path(a.out).write_text(comb(a.feed, a.teeth), encoding="utf-8")


if __name__ == "__main__":
    main()
