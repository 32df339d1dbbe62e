"""`pmctl kin ik|fk`: kinematics for outside checks (JSON with --json)."""

from __future__ import annotations

import json
import math

from pmctl.core.errors import PmctlError
from pmctl.core.tolerances import AXIS_TOL      # the same tolerance as CL data's tool vectors


def _triple(text, n, what):
    import numpy as np
    parts = text.split(",")
    try:
        vals = [float(x) for x in parts]
    except ValueError:
        vals = None
    if vals is None or len(vals) != n or not all(math.isfinite(v) and abs(v) <= 1e5 for v in vals):
        raise PmctlError(f"{what} needs {n} comma-separated numbers within +-1e5, got {text[:80]!r}")
    return np.array(vals)


def add_parser(sub):
    p = sub.add_parser("kin", help="inverse/forward kinematics of one pose",
                       description="Kinematics of one pose (mm, degrees). Frames and equations: docs/machine.md.")
    ks = p.add_subparsers(dest="kin_command", metavar="ik|fk", required=True)
    a = ks.add_parser("ik", help="tool tip in W + tool axis -> joints L1,L2,L3,X,Y")
    a.add_argument("--tip", required=True, metavar="X,Y,Z", help="tool tip in the workpiece frame W, mm")
    a.add_argument("--axis", required=True, metavar="I,J,K", help=f"unit tool axis, tip -> spindle (normalised if |v| is within {AXIS_TOL:g} of 1)")
    b = ks.add_parser("fk", help="joints L1,L2,L3,X,Y -> tool tip in W + tool axis")
    b.add_argument("--joints", required=True, metavar="L1,L2,L3,X,Y", help="chain lengths and table, mm")
    for q in (a, b):
        q.add_argument("--config", default="prototype", help="machine config (default: config/prototype.toml)")
        q.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(func=run)


def run(args):
    import numpy as np

    from pmctl.core import kinematics as K
    from pmctl.core.config import load_machine
    m = load_machine(args.config)
    if args.kin_command == "ik":
        tip = _triple(args.tip, 3, "--tip")
        axis = _triple(args.axis, 3, "--axis")
        r = K.ik(tip, axis, m, axis_tol=AXIS_TOL)
        out = {"L": r.q[:3].tolist(), "table": r.q[3:].tolist(), "Z": float(r.P[2]),
               "theta1_deg": float(np.degrees(r.theta1)), "theta2_deg": float(np.degrees(r.theta2))}
    else:
        q = _triple(args.joints, 5, "--joints")
        t = K.fk(q, m, check_limits=True)
        t1, t2 = t.tilt
        out = {"tip": t.tip.tolist(), "axis": t.axis.tolist(), "Z": float(t.Z),
               "theta1_deg": float(np.degrees(t1)), "theta2_deg": float(np.degrees(t2))}
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            if isinstance(v, list):
                v = ", ".join(f"{x:.9f}" for x in v)
            else:
                v = f"{v:.9f}"
            print(f"{k:>11}: {v}")
    return 0
