"""Write the bundled test-piece jobs (Tachiya et al. 2006, Fig. 7.12), sized for the prototype's workspace.

    python examples/jobs/make_jobs.py          # rewrites the files next to this script

- ``hemisphere.cl``  concave hemisphere (bowl, R 25 mm), two contour passes in CL data (s/w/e), the
  tool tilted toward the surface normal by at most ``MAX_TILT_DEG`` (full 5-axis: the axis precesses);
- ``cone.ngc``       cone frustum (boss, r 13 -> 6 mm over 16 mm height), three contours of G3 arcs
  with the tool at a fixed tilt given by A/B (roll/pitch), "3+2" style;
- ``spiral.ngc``     Archimedean spiral on a flat face, G1 points, the tool pitched outward by a tilt
  growing with the radius (5-axis).

The tool axis between two points is a slerp, so a precessing axis needs closely spaced points (1-3 deg):
every change of direction of the axis motion is a junction the planner must slow down for, and the
chains move ~5.5 mm per degree of tilt (Tachiya et al. 2006, Table 2.1).

All at F600 (10 mm/s); each takes 10-30 s to machine. Work is in W, the table-top frame: the face of the
workpiece is at z_W = 60 mm (the home tool tip is at z_W = 173 mm).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
MAX_TILT_DEG = 15.0
FACE_Z = 60.0
FEED = 600.0           # mm/min
CLEAR = 5.0            # mm above the face for rapids


def tilted_toward(normal, max_tilt_deg=MAX_TILT_DEG):
    """Unit axis in the plane of z and ``normal``, tilted from z toward it by at most max_tilt_deg."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    tilt = min(math.acos(np.clip(n[2], -1, 1)), math.radians(max_tilt_deg))
    h = math.hypot(n[0], n[1])
    if h < 1e-12:
        return np.array([0.0, 0.0, 1.0])
    return np.array([n[0] / h * math.sin(tilt), n[1] / h * math.sin(tilt), math.cos(tilt)])


def roll_pitch_deg(axis):
    """A (roll), B (pitch) in degrees for axis = Rx(A) Ry(B) z (docs/machine.md §3)."""
    b = math.asin(float(np.clip(axis[0], -1, 1)))
    a = math.atan2(-axis[1], axis[2])
    return math.degrees(a), math.degrees(b)


def hemisphere(radius=25.0, polar_deg=(30.0, 55.0), step_deg=1.0):
    """Concave hemisphere: sphere centre at the face (z = FACE_Z), bottom FACE_Z - radius."""
    c = np.array([0.0, 0.0, FACE_Z])
    lines = ["# pmctl bundled job: concave hemisphere (Tachiya et al. 2006, Fig. 7.12 a/b), CL data (Fig. 7.10)",
             f"# sphere centre {c.tolist()} mm in W, radius {radius} mm; contour passes at polar angles {polar_deg} deg",
             "# P = tool tip in W (mm), V = unit tool axis tip -> spindle, tilted toward the surface normal",
             "Px,Py,Pz,Vx,Vy,Vz,flag"]
    for phi_d in polar_deg:
        phi = math.radians(phi_d)
        n_pts = int(round(360.0 / step_deg))
        for k in range(n_pts + 1):
            psi = math.radians(k * step_deg)
            p = c + radius * np.array([math.sin(phi) * math.cos(psi), math.sin(phi) * math.sin(psi), -math.cos(phi)])
            v = tilted_toward(c - p)
            flag = "s" if k == 0 else ("e" if k == n_pts else "w")
            lines.append(",".join(f"{x:.6f}" for x in (*p, *v)) + f",{flag}")
    return "\n".join(lines) + "\n"


def _g(x):
    return f"{x:.4f}".rstrip("0").rstrip(".") if abs(x) > 5e-5 else "0"


def cone(r_bottom=13.0, r_top=6.0, height=16.0, levels=3, pieces=4, tilt_deg=10.0):
    """Cone frustum boss from z = FACE_Z - height (r_bottom) up to FACE_Z (r_top)."""
    out = ["(pmctl bundled job: cone frustum, Tachiya et al. 2006, Fig. 7.12 c)",
           f"(boss r {r_bottom} -> {r_top} mm over {height} mm, top at z {FACE_Z}; fixed tool tilt {tilt_deg} deg)",
           "G17 G21 G90 G94", f"F{FEED:g} S8000 M3"]
    zs = np.linspace(FACE_Z, FACE_Z - height, levels)
    a, b = roll_pitch_deg(tilted_toward([1.0, 0.5, 0.0], tilt_deg))
    for z in zs:
        r = r_top + (r_bottom - r_top) * (FACE_Z - z) / height
        out.append(f"G0 X{_g(r + CLEAR)} Y0 Z{_g(FACE_Z + CLEAR)} A{_g(a)} B{_g(b)}")
        out.append(f"G0 Z{_g(z)}")
        out.append(f"G1 X{_g(r)}")
        for k in range(1, pieces + 1):
            psi = 2 * math.pi * k / pieces
            x, y = r * math.cos(psi), r * math.sin(psi)
            prev = psi - 2 * math.pi / pieces
            out.append(f"G3 X{_g(x)} Y{_g(y)} I{_g(-r * math.cos(prev))} J{_g(-r * math.sin(prev))}")
        out.append(f"G1 X{_g(r + CLEAR)}")
    out += [f"G0 Z{_g(FACE_Z + CLEAR)} A0 B0", "M5", "M30"]
    return "\n".join(out) + "\n"


def spiral(r0=2.0, r1=18.0, turns=3, step_deg=3.0, max_tilt=8.0):
    """Archimedean spiral on the face z = FACE_Z - 0.5 with the tool pitched outward by up to max_tilt."""
    z = FACE_Z - 0.5
    out = ["(pmctl bundled job: spiral, Tachiya et al. 2006, Fig. 7.12 e)",
           f"(Archimedean spiral r {r0} -> {r1} mm, {turns} turns at z {z}; tilt grows with the radius)",
           "G21 G90 G17", f"G0 X{_g(r0)} Y0 Z{_g(FACE_Z + CLEAR)}", "S12000 M3", f"G1 Z{_g(z)} F{FEED:g}"]
    n = int(round(360.0 * turns / step_deg))
    for k in range(1, n + 1):
        t = k / n
        psi = 2 * math.pi * turns * t
        r = r0 + (r1 - r0) * t
        tilt = math.radians(max_tilt * r / r1)
        axis = np.array([math.sin(tilt) * math.cos(psi), math.sin(tilt) * math.sin(psi), math.cos(tilt)])
        a, b = roll_pitch_deg(axis)
        out.append(f"G1 X{_g(r * math.cos(psi))} Y{_g(r * math.sin(psi))} A{_g(a)} B{_g(b)}")
    out += ["G91 G1 Z" + _g(CLEAR), "G90 G0 A0 B0", "M5", "M30"]
    return "\n".join(out) + "\n"


def main():
    (HERE / "hemisphere.cl").write_text(hemisphere())
    (HERE / "cone.ngc").write_text(cone())
    (HERE / "spiral.ngc").write_text(spiral())
    print("wrote", ", ".join(p.name for p in sorted(HERE.glob("*")) if p.suffix in (".cl", ".ngc")))


if __name__ == "__main__":
    main()
