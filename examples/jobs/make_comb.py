"""Write the vibration test jobs: ``comb.ngc`` (a comb of Z strokes with sharp corners, the bundled
soft-machine K_theta and input-shaper job, docs/vibration.md) and, on demand, generated corner jobs
(zig-zags in the XZ or YZ plane at a chosen feed and corner angle).

    python examples/jobs/make_comb.py [--feed 3000] [--teeth 8] [--out examples/jobs/comb.ngc]
    python examples/jobs/make_comb.py --corners --plane xz --angle 60 --feed 3000 --out zz.ngc

Comb: the tool is vertical; each tooth is a plunge of ``depth`` mm in Z, a sideways step of
``pitch`` mm in X and a retract: every junction is a 90 degree corner, so the planner stops the tip
there (exact stop) and the chains see the full acceleration and deceleration at each end of each
stroke.

Corners: ``strokes`` straight strokes of ``length`` mm in the XZ (or YZ) plane, alternately down and
up, each pair meeting at a corner of interior angle ``angle`` degrees (180 = straight on, 90 = a
right angle, small = a sharp reversal); the strokes lean symmetrically about the vertical, so
every stroke moves Z and with it all three chains.
"""

from __future__ import annotations

import argparse
import math
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


def corners(plane="xz", feed=3000.0, angle=90.0, strokes=10, length=8.0, start=-15.0):
    """A zig-zag of ``strokes`` strokes of ``length`` mm in ``plane`` (xz or yz), corners of interior
    angle ``angle`` degrees (each stroke leans angle/2 from the vertical), starting at ``start`` mm
    along the plane's horizontal axis."""
    plane = plane.lower()
    if plane not in ("xz", "yz"):
        raise ValueError(f"plane must be xz or yz, got {plane!r}")
    if not (0.0 < angle < 180.0):
        raise ValueError(f"corner angle must be within (0, 180) degrees, got {angle!r}")
    h = "X" if plane == "xz" else "Y"
    o = "Y" if plane == "xz" else "X"
    half = math.radians(angle / 2.0)
    dh, dz = length * math.sin(half), length * math.cos(half)
    lines = [f"(pmctl test job: {strokes} strokes of {length:g} mm in the {plane.upper()} plane, "
             f"{angle:g} deg corners, F{feed:g})",
             "G21 G90 G17",
             f"G0 {h}{start:g} {o}0 Z{FACE_Z + 5:g}",
             f"G1 Z{FACE_Z:g} F{feed:g}"]
    u, z = start, FACE_Z
    for k in range(strokes):
        u += dh
        z = FACE_Z - dz if k % 2 == 0 else FACE_Z
        lines.append(f"G1 {h}{u:.4f} Z{z:.4f}")
    lines.append(f"G1 Z{FACE_Z + 5:g}")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--feed", type=float, default=3000.0)
    ap.add_argument("--teeth", type=int, default=8, help="comb: number of Z strokes")
    ap.add_argument("--corners", action="store_true", help="write a zig-zag corner job instead of the comb")
    ap.add_argument("--plane", default="xz", help="corners: xz or yz")
    ap.add_argument("--angle", type=float, default=90.0, help="corners: interior corner angle, degrees")
    ap.add_argument("--strokes", type=int, default=10, help="corners: number of strokes")
    ap.add_argument("--length", type=float, default=8.0, help="corners: stroke length, mm")
    ap.add_argument("--out", default=None, help="default: examples/jobs/comb.ngc (comb); required with --corners")
    a = ap.parse_args(argv)
    if a.corners:
        if not a.out:
            ap.error("--corners needs --out")
        text = corners(a.plane, a.feed, a.angle, a.strokes, a.length)
    else:
        text = comb(a.feed, a.teeth)
    Path(a.out or HERE / "comb.ngc").write_text(text, encoding="utf-8")


if __name__ == "__main__":
    main()
