"""Cutter radius compensation G41/G42 (G41.1/G42.1) in the XY plane, by LinuxCNC's rules.

With compensation on, the tool centre runs at the tool radius to the left (G41) or right (G42) of the
programmed path (looking along the motion). In program coordinates:

- **Entry move** (the first move after G41/G42): a straight move to the programmed end point offset
  by the radius perpendicular to the entry move itself; it must be longer than the radius. An entry
  arc ends offset radially from the programmed arc and becomes a spiral about the programmed centre.
- **Convex corners** (the tool on the outside): an arc of the tool radius about the programmed corner
  joins the two offset paths (for G0, a straight traverse: there is no rapid arc).
- **Concave corners** (the tool on the inside): the previous offset move is cut short where it meets
  the next one (line-line, line-arc, arc-line, arc-arc intersections), so the end of each move is
  known only when the next one is read: moves wait in a queue, as in LinuxCNC.
- Turns within 0.05 rad count as straight (no corner arc).
- **Errors** (the block is refused): an entry move not longer than the radius; a tool that does not
  fit inside an arc; a concave corner the tool cannot reach without gouging (a previous move that
  would have to run backwards); G41/G42 while on; compensation outside G17; G53, G28, G30, G92, a
  coordinate system change, a plane change or a tool change while on; an arc right after G40.
- **Exit** (G40): the queued moves end where they are; the next move (which must be straight) goes
  from the compensated position to its programmed end.

A negative tool diameter switches the side (LinuxCNC's nominal-diameter convention); a zero radius
leaves the path as programmed.
"""

from __future__ import annotations

import math

import numpy as np

from pmctl.task.job import ARC, EVENT, LINE, RAPID, Move
from pmctl.task.rs274 import arcs as A
from pmctl.task.rs274.execute import Refusal

SMALL = 0.05                  # LinuxCNC's TOLERANCE_CONCAVE_CORNER, radians
LEFT, RIGHT = 1, 2
PI = math.pi


class CompFit(Refusal):
    """The configured tool does not fit the programmed path here (entry move too short, tool wider than
    an arc, a concave corner it cannot reach without gouging): the program is understood, this machine
    cannot cut it with this tool (a ``machine`` problem). The executor then carries on as if the move
    were made, so that the lines after it are read as meant."""

    def __init__(self, message, column=None):
        super().__init__("machine", message, column)


class _Rec:
    """A queued move (ends in program coordinates; an arc's centre and turn) or other output."""

    __slots__ = ("kind", "x", "y", "z", "a", "b", "line", "feed", "duration", "dx", "dy", "cx", "cy", "turn",
                 "l1", "move", "rpm", "tlo", "tol", "file")

    def copy(self):
        r = _Rec.__new__(_Rec)
        for k in _Rec.__slots__:
            setattr(r, k, getattr(self, k, None))
        return r


def _inside(side, turn):
    return (side == LEFT and turn > 0) or (side == RIGHT and turn < 0)


class CutterComp:
    """The compensation engine of an executor. Its state lives in the executor's State (``cq``: the
    queue, ``cq_end``: the queue's start point, ``cq_start``: where the first queued move starts,
    ``comp_prog``/``comp_cur``: the last programmed point and the tool centre, program XYZ)."""

    def __init__(self, ex):
        self.ex = ex

    # ---------------------------------------------------------------- queue
    def pending(self, st):
        return bool(getattr(st, "cq", ()))

    def queue_other(self, st, move):
        r = _Rec()
        r.kind, r.move = "other", move
        st.cq = st.cq + (r,)

    def _enqueue(self, st, kind, x, y, z, a, b, feed=0.0, duration=0.0, dx=0.0, dy=0.0, cx=None, cy=None, turn=0,
                 l1=0.0):
        r = _Rec()
        r.kind, r.x, r.y, r.z, r.a, r.b = kind, x, y, z, a, b
        r.line, r.feed, r.duration, r.dx, r.dy = self.ex.line, feed, duration, dx, dy
        r.cx, r.cy, r.turn, r.l1, r.move = cx, cy, turn, l1, None
        r.rpm, r.tlo, r.tol, r.file = self.ex.rpm(st), st.tlo, self.ex.tolerance(st), self.ex.file
        st.cq = st.cq + (r,)

    def _set_endpoint(self, st, x, y):
        st.cq_end = (x, y)

    def dequeue(self, st):
        """Emit the queued records as Moves (arcs get their sweep from where they really start)."""
        ex = self.ex
        sx, sy = st.cq_start
        z = None
        for r in st.cq:
            if r.kind == "other":
                m = r.move
                w = ex.to_w(st, [sx, sy, z if z is not None else ex.to_prog(st, st.pos)[2], 0.0, 0.0])
                ex.moves.append(Move(m.kind, np.array(w[:3]), m.axis, line=m.line, spindle_rpm=m.spindle_rpm,
                                     dwell=m.dwell, tool_offset=m.tool_offset, events=m.events, file=m.file))
                continue
            w = ex.to_w(st, [r.x, r.y, r.z, r.a, r.b])
            kw = dict(line=r.line, spindle_rpm=r.rpm, tool_offset=r.tlo, tolerance=r.tol, file=r.file)
            if r.kind == "arc":
                sw = A.sweep((sx, sy), (r.cx, r.cy), (r.x, r.y), r.turn)
                c = ex.to_w(st, [r.cx, r.cy, r.z, r.a, r.b])
                feed = r.feed
                if r.duration:
                    r0 = math.hypot(sx - r.cx, sy - r.cy)
                    r1 = math.hypot(r.x - r.cx, r.y - r.cy)
                    feed = A.helix_length(r0, r1, sw, 0.0) / r.duration
                m = Move(ARC, np.array(w[:3]), ex.axis(w[3], w[4]), feed=feed, center=np.array(c[:2]), sweep=sw,
                         duration=r.duration, **kw)
            elif r.kind == "line":
                m = Move(LINE, np.array(w[:3]), ex.axis(w[3], w[4]), feed=r.feed, duration=r.duration, **kw)
            else:
                m = Move(RAPID, np.array(w[:3]), ex.axis(w[3], w[4]), **kw)
            ex.moves.append(m)
            sx, sy, z = r.x, r.y, r.z
        st.cq = ()
        st.cq_start = (sx, sy)
        st.cq_end = None

    def _move_endpoint_and_flush(self, st, x, y):
        """Move the end of every queued move to (x, y) (a concave corner cuts it short); refuse when a
        move would run backwards (gouging)."""
        if not st.cq:
            return
        inch = st.units != 1.0
        new = []
        ep = st.cq_end
        for r in st.cq:
            if r.kind == "other":
                new.append(r)
                continue
            r = r.copy()
            if r.kind == "arc":
                r1 = math.hypot(r.x - r.cx, r.y - r.cy)
                r2 = math.hypot(x - r.cx, y - r.cy)
                if abs(r1 - r2) > 0.01 * st.units:
                    raise CompFit("cutter compensation: the corner cannot be reached on the compensated arc "
                                            f"(radii {r1:.4f} and {r2:.4f} mm): check the path", None)
                if ep is not None and r.l1 != 0.0:
                    l2 = A.sweep(ep, (r.cx, r.cy), (x, y), r.turn)
                    if abs(l2) > abs(r.l1) + (0.001 * 25.4 if inch else 0.0254):
                        raise CompFit("cutter compensation: the arc move in a concave corner cannot be "
                                                "reached by the tool without gouging (the tool is too big for the "
                                                "corner: use a smaller tool or change the path)", None)
            else:
                if ep is not None and r.dx * (x - ep[0]) + r.dy * (y - ep[1]) < 0:
                    what = "straight traverse" if r.kind == "rapid" else "straight feed"
                    raise CompFit(f"cutter compensation: the {what} in a concave corner cannot be reached "
                                            "by the tool without gouging (the move is shorter than the tool needs: "
                                            "use a smaller tool or change the path)", None)
            r.x, r.y = x, y
            new.append(r)
        st.cq = tuple(new)
        self.dequeue(st)
        self._set_endpoint(st, x, y)

    def _front(self, st):
        for r in st.cq:
            if r.kind != "other":
                return r
        return None

    # ---------------------------------------------------------------- G41 on / G40 off
    def off(self, st):
        if st.comp_radius > 0 and not st.comp_first:
            cx, cy, _ = st.comp_cur
            self._move_endpoint_and_flush(st, cx, cy)
            self.dequeue(st)
            st.comp_base = st.comp_prog
        st.comp_first = True

    def _start(self, st):
        if not hasattr(st, "cq") or st.cq is None:
            st.cq = ()
        if not st.cq:
            p = self.ex.to_prog(st, st.pos)
            st.cq_start = (p[0], p[1])

    # ---------------------------------------------------------------- straight moves
    def straight(self, st, blk, motion, end_w):
        ex = self.ex
        if st.comp_radius <= 0:
            return self._plain(st, blk, motion, end_w)
        self._start(st)
        pe = ex.to_prog(st, end_w)
        px, py, pz, pa, pb = pe
        feed, duration = (0.0, 0.0) if motion == 0 else ex.feed_for(st, blk, "G1")
        if duration:                  # G93: the programmed move's speed, for a corner arc added to it too
            p0 = st.comp_prog if st.comp_prog is not None else ex.to_prog(st, st.pos)[:3]
            feed = math.dist(p0[:3], (px, py, pz)) / duration
        kind = "rapid" if motion == 0 else "line"
        side, radius = st.comp, st.comp_radius
        if st.comp_first:
            p0 = ex.to_prog(st, st.pos)
            cx, cy = p0[0], p0[1]
            dist = math.hypot(px - cx, py - cy)
            if dist <= radius:
                raise CompFit(f"cutter compensation entry move ({dist / st.units:.4f}) is not longer than "
                                        f"the tool radius ({radius / st.units:.4f}): start farther from the path",
                              None)
            alpha = math.atan2(py - cy, px - cx) + (PI / 2 if side == LEFT else -PI / 2)
            ex_, ey = px + radius * math.cos(alpha), py + radius * math.sin(alpha)
            self._set_endpoint(st, cx, cy)
            if duration:
                feed = math.dist((cx, cy, p0[2]), (ex_, ey, pz)) / duration
            self._enqueue(st, kind, ex_, ey, pz, pa, pb, feed, duration, math.cos(alpha), math.sin(alpha))
            st.comp_first = False
            st.comp_cur = (ex_, ey, pz)
            st.comp_prog = (px, py, pz)
            st.pos = ex.to_w(st, [ex_, ey, pz, pa, pb])
            return
        cx, cy, cz = st.comp_cur
        opx, opy, opz = st.comp_prog
        if px == opx and py == opy:
            if duration:
                feed = abs(pz - cz) / duration if pz != cz else feed
            self._enqueue(st, kind, cx, cy, pz, pa, pb, feed, duration, 0.0, 0.0)
            st.comp_cur = (cx, cy, pz)
            st.comp_prog = (px, py, pz)
            st.pos = ex.to_w(st, [cx, cy, pz, pa, pb])
            return
        theta = math.atan2(cy - opy, cx - opx)
        alpha = math.atan2(py - opy, px - opx)
        if side == LEFT:
            if theta < alpha:
                theta += 2 * PI
            beta = theta - alpha - PI / 2
            gamma = PI / 2
        else:
            if alpha < theta:
                alpha += 2 * PI
            beta = alpha - theta - PI / 2
            gamma = -PI / 2
        end_x = px + radius * math.cos(alpha + gamma)
        end_y = py + radius * math.sin(alpha + gamma)
        mid_x = opx + radius * math.cos(alpha + gamma)
        mid_y = opy + radius * math.sin(alpha + gamma)
        front = self._front(st)
        concave = False
        if beta < -SMALL or beta > PI + SMALL:
            concave = True
        elif beta > PI - SMALL and front is not None and front.kind == "arc" and \
                ((side == RIGHT and front.turn > 0) or (side == LEFT and front.turn < 0)):
            concave = True
        start = (cx, cy)
        if not concave and beta > SMALL:
            self._move_endpoint_and_flush(st, cx, cy)
            if motion == 10:
                t = -1 if side == LEFT else 1
                self._enqueue(st, "arc", mid_x, mid_y, cz, pa, pb, feed, 0.0, cx=opx, cy=opy, turn=t)
            else:
                self._enqueue(st, "rapid", mid_x, mid_y, cz, pa, pb)
            self.dequeue(st)
            self._set_endpoint(st, mid_x, mid_y)
            start = (mid_x, mid_y)
        elif concave:
            if front is None or front.kind != "arc":
                half = (beta + PI) / 2.0
                if half == 0.0:
                    raise CompFit("cutter compensation: a zero-degree inside corner is invalid", None)
                retreat = radius / math.tan(half)
                mx = cx + retreat * math.cos(theta + gamma)
                my = cy + retreat * math.sin(theta + gamma)
            else:
                oldrad = math.hypot(front.cy - front.y, front.cx - front.x)
                if oldrad < 1e-9:     # a compensated arc of no radius (left after an earlier problem)
                    raise CompFit("cutter compensation: the tool radius is not less than the arc radius", None)
                base = math.atan2(py - opy, px - opx)
                th = base + PI / 2 if front.turn > 0 else base - PI / 2
                phi = math.atan2(front.cy - opy, front.cx - opx)
                uncomp = oldrad + radius if _inside(side, front.turn) else oldrad - radius
                d = uncomp * math.cos(th - phi)
                if _inside(side, front.turn):
                    ll = (d - radius) / oldrad
                else:
                    ll = (d + radius) / oldrad
                if not -1.0 <= ll <= 1.0:
                    raise CompFit("cutter compensation: the arc-to-line corner is one the compensated tool "
                                            "cannot fit in without gouging: use a smaller tool or change the path",
                                  None)
                if _inside(side, front.turn):
                    ang = (-math.acos(ll) if front.turn > 0 else math.acos(ll)) + th + PI
                else:
                    ang = (math.acos(ll) if front.turn > 0 else -math.acos(ll)) + th + PI
                mx = front.cx + oldrad * math.cos(ang)
                my = front.cy + oldrad * math.sin(ang)
            self._move_endpoint_and_flush(st, mx, my)
            start = (mx, my)
        else:
            self.dequeue(st)
            self._set_endpoint(st, cx, cy)
        if duration:
            feed = math.dist((start[0], start[1], cz), (end_x, end_y, pz)) / duration
        self._enqueue(st, kind, end_x, end_y, pz, pa, pb, feed, duration, px - opx, py - opy)
        st.comp_cur = (end_x, end_y, pz)
        st.comp_prog = (px, py, pz)
        st.pos = ex.to_w(st, [end_x, end_y, pz, pa, pb])

    def carry_on(self, st, blk, motion, end_w, c2=None, turn=0):
        """After a CompFit: the queued moves end where they are, and the tool goes straight to the
        programmed end offset by the radius (perpendicular to the move, or radially for an arc), so the
        programmed point -- from which the next moves are computed -- is where the program says."""
        ex = self.ex
        pe = ex.to_prog(st, end_w)
        px, py = pe[0], pe[1]
        if st.cq:
            self.dequeue(st)
        prev = st.comp_prog if st.comp_prog is not None else ex.to_prog(st, st.pos)[:3]
        if c2 is not None:
            dx, dy = px - c2[0], py - c2[1]
            k = 1.0 if (st.comp == RIGHT) == (turn > 0) else -1.0
            n = math.hypot(dx, dy) or 1.0
            ox, oy = k * dx / n, k * dy / n
        else:
            dx, dy = px - prev[0], py - prev[1]
            n = math.hypot(dx, dy) or 1.0
            ox, oy = (-dy / n, dx / n) if st.comp == LEFT else (dy / n, -dx / n)
        cx, cy = px + st.comp_radius * ox, py + st.comp_radius * oy
        w = ex.to_w(st, [cx, cy, pe[2], pe[3], pe[4]])
        if motion == 0:
            ex.move(st, RAPID, w)
        else:
            feed = st.feed / 60.0 if st.feed else 1.0
            ex.move(st, LINE, w, feed=feed)
        st.comp_first = False
        st.comp_prog = (px, py, pe[2])
        st.comp_cur = (cx, cy, pe[2])
        st.cq, st.cq_start, st.cq_end = (), (cx, cy), None

    def _plain(self, st, blk, motion, end_w):
        ex = self.ex
        if motion == 0:
            ex.move(st, RAPID, end_w)
        else:
            feed, duration = ex.feed_for(st, blk, "G1")
            if duration:
                feed = math.dist(st.pos[:3], end_w[:3]) / duration
            ex.move(st, LINE, end_w, feed=feed, duration=duration)

    # ---------------------------------------------------------------- arcs
    def arc(self, st, blk, motion, end_w, c2, turn, feed, duration):
        """An arc with compensation on; ``c2``: its centre computed from the programmed start (the
        tool centre for the entry arc), ``turn``: signed turns."""
        ex = self.ex
        if st.comp_radius <= 0:
            ps, pe = ex.to_prog(st, st.pos), ex.to_prog(st, end_w)
            return ex.emit_arc(st, ps, pe, c2, A.sweep((ps[0], ps[1]), c2, (pe[0], pe[1]), turn), end_w, feed,
                               duration)
        self._start(st)
        side, radius = st.comp, st.comp_radius
        pe = ex.to_prog(st, end_w)
        end_x, end_y, end_z, pa, pb = pe
        v = blk.v
        if st.comp_first:
            p0 = ex.to_prog(st, st.pos)
            cx, cy, cz = p0[0], p0[1], p0[2]
            if math.hypot(end_x - cx, end_y - cy) <= radius:
                raise CompFit("cutter compensation entry arc: its radius is not greater than the tool "
                                        "radius", None)
            center_x, center_y = c2
            arc_r = math.hypot(center_x - cx, center_y - cy)
            if _inside(side, turn) and ("r" in v and abs(v["r"]) * st.units <= radius or arc_r <= radius):
                raise CompFit("cutter compensation: the tool radius is not less than the arc radius",
                              None)
            if _inside(side, turn):
                gamma = math.atan2(center_y - end_y, center_x - end_x)
            else:
                gamma = math.atan2(end_y - center_y, end_x - center_x)
            st.comp_first = False
            st.comp_prog = (end_x, end_y, end_z)
            ex2 = end_x + radius * math.cos(gamma)
            ey2 = end_y + radius * math.sin(gamma)
            b_len = math.hypot(cy - ey2, cx - ex2) / 2.0
            ab = math.atan2(center_y - ey2, center_x - ex2)
            a_ang = math.atan2(cy - ey2, cx - ex2) - ab
            if abs(math.cos(a_ang)) < 1e-6:
                raise CompFit("cutter compensation: the tool radius is not less than the arc radius", None)
            c_len = b_len / math.cos(a_ang)
            ncx, ncy = ex2 + c_len * math.cos(ab), ey2 + c_len * math.sin(ab)
            self._set_endpoint(st, cx, cy)
            l1 = A.sweep((cx, cy), (ncx, ncy), (ex2, ey2), turn)
            if duration:
                feed = A.helix_length(math.hypot(cx - ncx, cy - ncy), math.hypot(ex2 - ncx, ey2 - ncy), l1,
                                      end_z - cz) / duration
            self._enqueue(st, "arc", ex2, ey2, end_z, pa, pb, feed, duration, cx=ncx, cy=ncy, turn=turn, l1=l1)
            st.comp_cur = (ex2, ey2, end_z)
            st.pos = ex.to_w(st, [ex2, ey2, end_z, pa, pb])
            return
        opx, opy, opz = st.comp_prog
        cx, cy, cz = st.comp_cur
        centerx, centery = c2
        arc_radius = math.hypot(centerx - end_x, centery - end_y)
        if duration:                  # G93: the programmed arc's speed, for a corner arc added to it too
            feed = A.helix_length(arc_radius, arc_radius, A.sweep((opx, opy), c2, (end_x, end_y), turn),
                                  end_z - opz) / duration
        theta = math.atan2(cy - opy, cx - opx)
        theta = theta - PI / 2 if side == LEFT else theta + PI / 2
        delta = math.atan2(centery - opy, centerx - opx)
        alpha = delta - PI / 2 if motion == 30 else delta + PI / 2
        beta = theta - alpha if side == LEFT else alpha - theta
        if beta > 1.5 * PI:
            beta -= 2 * PI
        elif beta < -PI / 2:
            beta += 2 * PI
        if (side == LEFT and motion == 30) or (side == RIGHT and motion == 20):
            gamma = math.atan2(centery - end_y, centerx - end_x)
            if arc_radius <= radius:
                raise CompFit("cutter compensation: the tool radius is not less than the arc radius "
                                        "(the tool does not fit inside the arc)", None)
        else:
            gamma = math.atan2(end_y - centery, end_x - centerx)
            delta = delta + PI
        nx = end_x + radius * math.cos(gamma)
        ny = end_y + radius * math.sin(gamma)
        front = self._front(st)
        l_orig = A.sweep((opx, opy), (centerx, centery), (end_x, end_y), turn)
        if beta < -SMALL or beta > PI + SMALL or (abs(beta - PI) < SMALL and not _inside(side, turn)):
            if front is None or front.kind != "arc":
                cyy = arc_radius * math.sin(beta - PI / 2)
                if _inside(side, turn):
                    dist = arc_radius - radius
                    ll = (cyy + radius) / dist
                    if not -1.0 <= ll <= 1.0:
                        raise CompFit("cutter compensation: the arc move in a concave corner cannot be "
                                                "reached by the tool without gouging", None)
                    ang = theta + math.asin(ll) if turn > 0 else theta - math.asin(ll)
                else:
                    dist = arc_radius + radius
                    ll = (cyy - radius) / dist
                    if not -1.0 <= ll <= 1.0:
                        raise CompFit("cutter compensation: the arc move in a concave corner cannot be "
                                                "reached by the tool without gouging", None)
                    ang = theta + PI - math.asin(ll) if turn > 0 else theta + PI + math.asin(ll)
                mx, my = centerx + dist * math.cos(ang), centery + dist * math.sin(ang)
            else:
                oldrad = math.hypot(front.cy - front.y, front.cx - front.x)
                newrad = arc_radius - radius if _inside(side, turn) else arc_radius + radius
                arc_cc = math.hypot(front.cy - centery, front.cx - centerx)
                if oldrad == 0 or arc_cc == 0:
                    raise CompFit("cutter compensation: arc to arc motion with the same centre", None)
                a = (oldrad ** 2 + arc_cc ** 2 - newrad ** 2) / (2 * oldrad * arc_cc)
                if not -1.0 <= a <= 1.0:
                    raise CompFit("cutter compensation: the arc-to-arc corner is one the compensated tool "
                                            "cannot fit in without gouging", None)
                pull = math.acos(a)
                ccd = math.atan2(centery - front.cy, centerx - front.cx)
                if _inside(side, front.turn):
                    d = ccd + pull if turn > 0 else ccd - pull
                else:
                    d = ccd - pull if turn > 0 else ccd + pull
                mx, my = front.cx + oldrad * math.cos(d), front.cy + oldrad * math.sin(d)
            self._move_endpoint_and_flush(st, mx, my)
            start = (mx, my)
            self._arc_rec(st, nx, ny, end_z, pa, pb, centerx, centery, turn, l_orig, feed, duration, start)
        elif beta > SMALL:
            midx, midy = opx + radius * math.cos(delta), opy + radius * math.sin(delta)
            self.dequeue(st)
            self._enqueue(st, "arc", midx, midy, cz, pa, pb, feed, 0.0, cx=opx, cy=opy,
                          turn=-1 if side == LEFT else 1)
            self.dequeue(st)
            self._set_endpoint(st, midx, midy)
            self._arc_rec(st, nx, ny, end_z, pa, pb, centerx, centery, turn, l_orig, feed, duration, (midx, midy))
        else:
            self.dequeue(st)
            self._set_endpoint(st, cx, cy)
            self._arc_rec(st, nx, ny, end_z, pa, pb, centerx, centery, turn, l_orig, feed, duration, (cx, cy))
        st.comp_prog = (end_x, end_y, end_z)
        st.comp_cur = (nx, ny, end_z)
        st.pos = ex.to_w(st, [nx, ny, end_z, pa, pb])

    def _arc_rec(self, st, x, y, z, a, b, cx, cy, turn, l_orig, feed, duration, start):
        if duration:
            sw = A.sweep(start, (cx, cy), (x, y), turn)
            feed = A.helix_length(math.hypot(start[0] - cx, start[1] - cy), math.hypot(x - cx, y - cy), sw,
                                  0.0) / duration
        self._enqueue(st, "arc", x, y, z, a, b, feed, duration, cx=cx, cy=cy, turn=turn, l1=l_orig)


def comp_radius_of(tool_diameter):
    return tool_diameter / 2.0


__all__ = ["CutterComp", "CompFit", "EVENT"]
