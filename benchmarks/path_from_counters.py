"""How far the machined path lies from a CL job, from a recording's pulse counters alone.

    .venv/bin/python benchmarks/path_from_counters.py RECORDING examples/jobs/hemisphere.cl

Independent of the run's own figures: it reads the CL points straight from the job file (Px Py Pz
per line, flags 's' and 'w'), turns every recorded tick's counters (cmd_L1 .. cmd_Y, the pulse
counters x resolution) into a tool tip with the batch forward kinematics (pmctl.core.kinematics.
fk_batch, Newton on the nominal geometry; not the loop's model), and measures, for each CL point,
its distance to the polyline of those tips. Prints the RMS, the 95th percentile and the maximum, in
micrometres. For a stepdir run the counters are the bridge's (on --bridge rp2040-emu, counted on
the emulated chip's pins), so this is the path the pulses describe.
"""

from __future__ import annotations

import argparse

import pmctl  # noqa: F401,I001
import numpy as np
from scipy.spatial import cKDTree

from pmctl.core.config import load_machine
from pmctl.core.kinematics import fk_batch
from pmctl.core.recording import read_recording

AXES = ("L1", "L2", "L3", "X", "Y")


def cl_points(path) -> np.ndarray:
    pts = []
    for line in open(path, encoding="utf-8"):
        f = line.strip().split(",")
        if len(f) == 7 and f[6] in ("s", "w"):
            pts.append([float(x) for x in f[:3]])
    return np.array(pts)


def distances(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distance of each point to the polyline `path` (the nearest of the segments around its nearest
    vertex, and a few more)."""
    tree = cKDTree(path)
    _, idx = tree.query(points, k=8)
    best = np.full(len(points), np.inf)
    for j in range(idx.shape[1]):
        for s in (-1, 0):
            i0 = np.clip(idx[:, j] + s, 0, len(path) - 2)
            a, b = path[i0], path[i0 + 1]
            ab = b - a
            t = np.clip(np.einsum("ij,ij->i", points - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-30), 0, 1)
            d = np.linalg.norm(points - (a + t[:, None] * ab), axis=1)
            best = np.minimum(best, d)
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recording")
    ap.add_argument("job", help="the CL job (.cl) the recording machined")
    ap.add_argument("--config", default="prototype")
    a = ap.parse_args()
    m = load_machine(a.config)
    rec = read_recording(a.recording)
    q = np.stack([np.asarray(rec.columns[f"cmd_{x}"], float) for x in AXES], -1)
    pose, ok = fk_batch(q, m)
    if not np.all(ok):
        raise SystemExit(f"forward kinematics failed at {int(np.sum(~ok))} ticks")
    tips = pose.tip
    pts = cl_points(a.job)
    d = distances(pts, tips) * 1e3
    print(f"{len(pts)} CL points, {len(tips)} ticks: distance to the path of the counters (FK): RMS {np.sqrt(np.mean(d ** 2)):.2f} um, "
          f"95 % {np.percentile(d, 95):.2f} um, max {d.max():.2f} um")


if __name__ == "__main__":
    main()
