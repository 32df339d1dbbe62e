"""The machine as kinematic chains in SU-parameter notation, and back.

The notation is Sheth and Uicker's ("A Generalized Symbolic Notation for Mechanisms", used for
machine tools by Suzuki, Tanaka and Kishinami for virtual machining): the fixed transform across a
link from the previous joint's moving frame O'_{i-1} (u, v, w) to the next joint's frame O_i
(x, y, z) is

    T_{i-1,i} = A3(c) A6(gamma) A1(a) A4(alpha) A3(b) A6(beta)

(A1/A3 translations along x/z, A4/A6 rotations about x/z): a along the common normal t of w_{i-1}
and z_i, alpha from w_{i-1} to z_i about t, b along z_i from t to x_i, beta from t to x_i about
z_i, c along w_{i-1} from u_{i-1} to t, gamma from u_{i-1} to t about w_{i-1}. A joint moves along
or about its z axis: revolute Phi = A6(q), prismatic Phi = A3(q), spherical Phi = A6 A4 A6.

The export (JSON, ``"format": "pmctl-su/1"``) has one loop per chain (base -R- plate link -P-
nut -S- platform), the table loop (bed -P(Y)- Y carriage -P(X)- X table = workpiece frame W) and
the tool (platform -> tool tip frame, z along the tool axis). Lengths in mm, angles in degrees,
every fixed transform taken at the home pose with all joint values zero, so composing a loop with
the joint values of a pose gives that pose. :func:`geometry_from_su` reads it back.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.config import Geometry, Machine
from pmctl.core.errors import InputError

FORMAT = "pmctl-su/1"
KEYS = ("a", "alpha", "b", "beta", "c", "gamma")


def A(kind, v):
    T = np.eye(4)
    if kind in (1, 2, 3):
        T[kind - 1, 3] = v
        return T
    c, s = math.cos(v), math.sin(v)
    i, j = {4: (1, 2), 5: (2, 0), 6: (0, 1)}[kind]
    T[i, i], T[i, j], T[j, i], T[j, j] = c, -s, s, c
    return T


def su_matrix(p) -> np.ndarray:
    """4x4 transform of SU parameters {a, alpha, b, beta, c, gamma} (mm, degrees)."""
    r = math.radians
    return (A(3, p["c"]) @ A(6, r(p["gamma"])) @ A(1, p["a"]) @ A(4, r(p["alpha"]))
            @ A(3, p["b"]) @ A(6, r(p["beta"])))


def su_params(T, eps=1e-12) -> dict:
    """SU parameters of a rigid transform (inverse of :func:`su_matrix`)."""
    R, t = T[:3, :3], T[:3, 3]
    alpha = math.atan2(math.hypot(R[0, 2], R[1, 2]), R[2, 2])
    if math.sin(alpha) > eps:
        gamma = math.atan2(R[0, 2], -R[1, 2])
        beta = math.atan2(R[2, 0], R[2, 1])
    else:
        # z axes parallel: the common normal runs along the offset between them
        total = math.atan2(R[1, 0], R[0, 0])
        if math.cos(alpha) < 0:                      # antiparallel: Rz(g) Rx(pi) Rz(b) = ... Rz(g - b)
            total = math.atan2(R[1, 0], R[0, 0])
        h = math.hypot(t[0], t[1])
        gamma = math.atan2(t[1], t[0]) if h > eps else 0.0
        beta = total - gamma if math.cos(alpha) > 0 else gamma - total
    u1 = np.array([math.cos(gamma), math.sin(gamma), 0.0])
    a = float(t @ u1)
    sa = math.sin(alpha)
    if abs(sa) > eps:
        b = (t[0] * math.sin(gamma) - t[1] * math.cos(gamma)) / sa
    else:
        b = 0.0
    c = t[2] - b * math.cos(alpha)
    d = math.degrees
    return {"a": a, "alpha": d(alpha), "b": b, "beta": d(beta), "c": c, "gamma": d(gamma)}


def frame(origin, z, x) -> np.ndarray:
    z = np.asarray(z, float) / np.linalg.norm(z)
    x = np.asarray(x, float) - (np.asarray(x, float) @ z) * z
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, origin
    return T


def _inv(T):
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def export_machine(machine: Machine) -> dict:
    g = machine.geometry
    P0, R0 = K.forward_platform(_home_lengths(g), g)
    Tp = np.eye(4)
    Tp[:3, :3], Tp[:3, 3] = R0, P0                                    # platform frame at home
    loops = []
    for i in range(3):
        A_i, n_i = g.base_joints[i], g.revolute_axes[i]
        C_i = P0 + R0 @ g.platform_joints[i]
        d = C_i - A_i
        F1 = frame(A_i, n_i, d)                                         # revolute: z = n_i, x along the chain
        F2 = frame(A_i, d, np.cross(n_i, d))                            # prismatic: z along the chain
        s0 = float(np.linalg.norm(d))
        F3 = F2 @ A(3, s0)                                              # spherical joint centre C_i
        links = [
            {"name": "base", "su": su_params(F1), "joint": {"type": "R", "name": f"A{i + 1}"}},
            {"name": f"plate{i + 1}", "su": su_params(_inv(F1) @ F2),
             "joint": {"type": "P", "name": f"L{i + 1}", "value_at_home": s0,
                       "actuator_offset": float(g.length_offsets[i])}},
            {"name": f"nut{i + 1}", "su": su_params(np.eye(4)), "joint": {"type": "S", "name": f"C{i + 1}"}},
            {"name": "platform", "su": su_params(_inv(F3) @ Tp), "joint": None},
        ]
        loops.append({"name": f"chain{i + 1}", "links": links})
    # table: bed -> Y -> X -> workpiece frame W, whose origin is at (X, Y, z_table) in the base frame
    FY = frame([0.0, 0.0, g.z_table], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    FX = frame([0.0, 0.0, g.z_table], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    W = frame([0.0, 0.0, g.z_table], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    loops.append({"name": "table", "links": [
        {"name": "bed", "su": su_params(FY), "joint": {"type": "P", "name": "Y", "value_at_home": 0.0}},
        {"name": "Y carriage", "su": su_params(_inv(FY) @ FX), "joint": {"type": "P", "name": "X", "value_at_home": 0.0}},
        {"name": "X table (workpiece W)", "su": su_params(_inv(FX) @ W), "joint": None}]})
    tip = g.tool_tip_p
    ax = g.tool_axis_p
    Ft = frame(tip, ax, np.cross([0.0, 1.0, 0.0], ax) if abs(ax[1]) < 0.9 else [1.0, 0.0, 0.0])
    loops.append({"name": "tool", "links": [
        {"name": "platform", "su": su_params(Ft), "joint": None, "note": "tool tip frame, z = tool axis"}]})
    return {"format": FORMAT, "machine": machine.name, "units": {"length": "mm", "angle": "deg"},
            "transform": "T = A3(c) A6(gamma) A1(a) A4(alpha) A3(b) A6(beta); R: A6(q), P: A3(q), S: A6 A4 A6",
            "home_platform": {"P": P0.tolist(), "R": R0.tolist()},
            "loops": loops}


def _home_lengths(g: Geometry):
    P, R = K.platform_pose(g.z_home, 0.0, 0.0, g.platform_radius)
    return K.chain_lengths(P, R, g)


def geometry_from_su(doc: dict, base: Machine, *, source="<su>") -> Geometry:
    """The general geometry described by an export (the rest of the machine from ``base``)."""
    try:
        if doc.get("format") != FORMAT:
            raise InputError(source, None, f'format must be "{FORMAT}"')
        loops = {lp["name"]: lp["links"] for lp in doc["loops"]}
        Tp = np.eye(4)
        Tp[:3, :3] = np.array(doc["home_platform"]["R"], float)
        Tp[:3, 3] = np.array(doc["home_platform"]["P"], float)
        Aj, Cj, Nj, off = [], [], [], []
        for i in range(3):
            L = loops[f"chain{i + 1}"]
            F1 = su_matrix(L[0]["su"])
            F2 = F1 @ su_matrix(L[1]["su"])
            s0 = float(L[1]["joint"]["value_at_home"])
            F3 = F2 @ A(3, s0) @ su_matrix(L[2]["su"])
            Fp = F3 @ su_matrix(L[3]["su"])
            Aj.append(F1[:3, 3])
            Nj.append(F1[:3, 2])
            Cj.append((_inv(Fp) @ F3)[:3, 3])                          # C_i in the platform frame
            off.append(float(L[1]["joint"].get("actuator_offset", 0.0)))
            if np.max(np.abs(Fp - Tp)) > 1e-6:
                raise InputError(source, None, f"chain{i + 1} does not close on the platform at home")
        tl = loops["table"]
        z_table = float((su_matrix(tl[0]["su"]) @ su_matrix(tl[1]["su"]) @ su_matrix(tl[2]["su"]))[2, 3])
        Ft = su_matrix(loops["tool"][0]["su"])
        ax = Ft[:3, 2]
        length = float(-(Ft[:3, 3] @ ax))
        alpha = math.degrees(math.atan2(-ax[1], ax[2]))
        beta = math.degrees(math.asin(max(-1.0, min(1.0, ax[0]))))
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise InputError(source, None, f"not a complete SU description: {e!r}") from None
    g = base.geometry
    return replace(g, base_joints=np.array(Aj), platform_joints=np.array(Cj), revolute_axes=np.array(Nj),
                   length_offsets=np.array(off), tool_length=length, tool_tilt_deg=(alpha, beta),
                   z_table=z_table, nominal=False)


def write_su(machine: Machine, path) -> dict:
    doc = export_machine(machine)
    Path(path).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return doc


def read_su(path, base: Machine) -> Geometry:
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    except json.JSONDecodeError as e:
        raise InputError(path, e.lineno, f"not valid JSON: {e.msg}", column=e.colno) from None
    return geometry_from_su(doc, base, source=str(path))
