"""The control socket: a Unix stream socket (mode 0660: owner and group only; no TCP) speaking
JSON lines, for scripts and a future UI. One request per line, one JSON answer per line:

    {"cmd": "status"}                          -> {"ok": true, "state": "Idle", "mpos": [...], ...}
    {"cmd": "queue", "add": "FILE"}            -> {"ok": true, "index": n}   (checked before it is queued)
    {"cmd": "queue", "list": true}             -> {"ok": true, "items": [{"index", "kind", "name", "planned"}]}
    {"cmd": "hold"} / {"cmd": "resume"}        -> {"ok": true}   (resume: also cycle start after M0, M1, M6)
    {"cmd": "optional_stop", "on": true}       -> M1 pauses (false: M1 is passed over; the default)
    {"cmd": "override", "feed": 1.2, "rapid": 0.5, "spindle": 1.1}
                                               -> feed 0.1 .. 2.0, rapid 0.25 / 0.5 / 1.0, spindle 0.1 .. 2.0
                                                  (the VFD's set-point, when a [spindle] is configured)
    {"cmd": "stop"}                            -> soft reset: stop on the path, queue dropped, position kept
    {"cmd": "estop"}                           -> immediate halt, Alarm 10 until unlock
    {"cmd": "unlock"}                          -> $X: confirm the position, clear the alarm
    {"cmd": "home"}                            -> $H: the homing cycle; answers when it ends
    {"cmd": "resume_job", "line": n, "clearance_mm": c}
                                               -> resume the job the journal says was interrupted, from
                                                  its line (or line n), with a safe approach
    {"cmd": "record", "start": "DIR"} / {"cmd": "record", "stop": true}
                                               -> start recording the session into DIR / finalise it
    {"cmd": "subscribe", "period_s": 0.2}      -> a status line every period until the client leaves
Errors: {"ok": false, "error": "..."}.
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time


def check_socket_path(path: str) -> None:
    """Refuse a --socket whose folder does not exist (it is not created here: in production
    systemd's RuntimeDirectory= creates /run/pmctl) or that names something other than a socket."""
    import stat

    from pmctl.core.errors import PmctlError
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise PmctlError(f"--socket {path}: the folder {parent} does not exist (create it first; the systemd "
                         f"unit's RuntimeDirectory= does for /run/pmctl)")
    if os.path.lexists(path) and not stat.S_ISSOCK(os.lstat(path).st_mode):
        raise PmctlError(f"--socket {path}: exists and is not a socket; choose another name")


class ControlServer:
    def __init__(self, daemon, path: str):
        self.daemon = daemon
        self.sup = daemon.sup
        self.path = str(path)
        self._stop = threading.Event()
        self._threads = []
        check_socket_path(self.path)
        if os.path.exists(self.path):
            os.unlink(self.path)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o117)
        try:
            self.sock.bind(self.path)
        finally:
            os.umask(old)
        os.chmod(self.path, 0o660)
        self.sock.listen(8)
        self.sock.settimeout(0.2)

    def start(self):
        t = threading.Thread(target=self._accept, name="pmctl-control", daemon=True)
        t.start()
        self._threads.append(t)

    def stop(self):
        self._stop.set()
        try:
            self.sock.close()
        except OSError:
            pass
        try:
            os.unlink(self.path)
        except OSError:
            pass

    def _accept(self):
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except (socket.timeout, OSError):
                continue
            t = threading.Thread(target=self._client, args=(conn,), name="pmctl-control-client", daemon=True)
            t.start()

    def _client(self, conn):
        f = conn.makefile("rwb")
        try:
            for raw in f:
                if self._stop.is_set():
                    break
                if len(raw) > 65536:
                    self._send(f, {"ok": False, "error": "request too long"})
                    continue
                try:
                    req = json.loads(raw)
                    if not isinstance(req, dict):
                        raise ValueError("a request is a JSON object")
                except ValueError as e:
                    self._send(f, {"ok": False, "error": f"bad request: {e}"})
                    continue
                if req.get("cmd") == "subscribe":
                    period = min(10.0, max(0.05, float(req.get("period_s", 0.2))))
                    while not self._stop.is_set():
                        self._send(f, self.status())
                        time.sleep(period)
                    break
                try:
                    self._send(f, self.handle(req))
                except Exception as e:
                    self._send(f, {"ok": False, "error": f"{type(e).__name__}: {e}"})
        except (OSError, ValueError):
            pass
        finally:
            try:
                f.close()
                conn.close()
            except OSError:
                pass

    @staticmethod
    def _send(f, obj):
        f.write((json.dumps(obj) + "\n").encode())
        f.flush()

    def status(self) -> dict:
        from pmctl.interfaces.console.grbl import spindle_rpm
        from pmctl.motion import channel as C
        from pmctl.task.supervisor import roll_pitch_deg
        sup = self.sup
        s = sup.raw()
        tip, axis = sup.pose()
        a, b = roll_pitch_deg(axis)
        return {"ok": True, "state": sup.state_name(), "mpos": [round(float(x), 6) + 0.0 for x in (*tip, a, b)],
                "counts": [int(x) for x in s[C.ST_COUNTS:C.ST_COUNTS + 5]], "line": sup.current_line(),
                "sent": [int(x) for x in s[C.ST_SENT:C.ST_SENT + 5]], "homed": bool(sup.homed),
                "sigma": float(s[C.ST_SIGMA]), "feed_override": float(s[C.ST_FEED_OV]),
                "rapid_override": float(s[C.ST_RAPID_OV]), "spindle_override": float(sup.spindle_ov),
                "spindle_rpm": spindle_rpm(sup), "queued_items": sup.queued_items(),
                "alarm": sup.alarm, "alarm_msg": sup.alarm_msg, "rt_alive": not sup.rt_dead,
                "paused": sup.paused, "coolant": sorted(sup.coolant), "outputs": dict(sup.outputs),
                "optional_stop": bool(sup.optional_stop),
                "tick": int(s[C.ST_TICK]), "dropped_records": int(s[C.ST_DROPPED])}

    def handle(self, req) -> dict:
        from pmctl.task.planner import load_job
        sup = self.sup
        cmd = req.get("cmd")
        if cmd == "status":
            return self.status()
        if cmd == "queue":
            if "add" in req:
                from pmctl.task.gcode import reader_options
                path = str(req["add"])
                console = getattr(self.daemon, "console", None)   # the work offsets in force, as at the console
                offsets = console.interp.offsets() if console is not None else \
                    self.daemon.journal.data.get("offsets")
                job = load_job(path, sup.machine, start=sup.end_pose(),
                               **reader_options(path, sup.svc.interpreter, offsets))
                it = sup.submit(job, kind="job", name=os.path.basename(path), source=os.path.abspath(path))
                return {"ok": True, "index": it.index}
            with sup._lock:
                items = [{"index": i.index, "kind": i.kind, "name": i.name, "planned": i.planned} for i in sup.items]
            return {"ok": True, "items": items}
        if cmd == "hold":
            sup.hold()
        elif cmd == "resume":
            sup.resume()
        elif cmd == "override":
            for key, allowed, error, apply, console_attr in (
                    ("feed", lambda v: 0.1 <= v <= 2.0, "feed override must be within 0.1 .. 2.0",
                     sup.feed_override, "feed_ov"),
                    ("rapid", lambda v: v in (0.25, 0.5, 1.0), "rapid override is 0.25, 0.5 or 1.0",
                     sup.rapid_override, "rapid_ov"),
                    ("spindle", lambda v: 0.1 <= v <= 2.0, "spindle override must be within 0.1 .. 2.0",
                     sup.spindle_override, "spindle_ov")):
                if key not in req:
                    continue
                v = float(req[key])
                if not allowed(v):
                    return {"ok": False, "error": error}
                apply(v)
                if getattr(self.daemon, "console", None) is not None:
                    setattr(self.daemon.console, console_attr, int(round(v * 100)))   # Ov: and its +/- steps
        elif cmd == "optional_stop":
            sup.optional_stop = bool(req.get("on"))
        elif cmd == "stop":
            sup.soft_reset()
        elif cmd == "estop":
            sup.estop("E-stop from the control socket")
        elif cmd == "unlock":
            sup.unlock()
        elif cmd == "record":
            if "start" in req:
                return {"ok": True, "folder": self.daemon.record_start(os.path.abspath(str(req["start"])))}
            if req.get("stop"):
                return {"ok": True, "folder": self.daemon.record_stop()}
            return {"ok": False, "error": "record: 'start': DIR or 'stop': true"}
        elif cmd == "home":
            ok, msg = self.daemon.home()
            return {"ok": bool(ok), "msg": msg} if ok else {"ok": False, "error": msg}
        elif cmd == "resume_job":
            line = req.get("line")
            clearance = float(req.get("clearance_mm", 5.0))
            it = self.daemon.resume_job(line=None if line is None else int(line), clearance_mm=clearance)
            return {"ok": True, "index": it.index, "job": it.source, "line": it.job.moves[3].line
                    if len(it.job.moves) > 3 else 0}
        else:
            return {"ok": False, "error": f"unknown command {cmd!r}"}
        return {"ok": True}
