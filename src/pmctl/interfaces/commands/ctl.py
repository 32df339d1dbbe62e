"""`pmctl ctl`: talk to a running `pmctl serve` through its control socket (JSON lines).

    pmctl ctl --socket PATH status | hold | resume | stop | estop | unlock | home
    pmctl ctl --socket PATH resume-job [--line N] [--clearance MM]
    pmctl ctl --socket PATH record start DIR | record stop
    pmctl ctl --socket PATH override [--feed F] [--rapid R] [--spindle S]
    pmctl ctl --socket PATH queue add FILE | queue list
    pmctl ctl --socket PATH subscribe [--period S]
    pmctl ctl --socket PATH optional-stop on|off

``status`` prints a table (``--json``: the socket's JSON answer, as every other request prints it).
Exit status: 0 the request was done, 1 refused or failed (the reason on stderr), 2 usage.
"""

from __future__ import annotations


def add_parser(sub):
    p = sub.add_parser("ctl", help="control a running `pmctl serve` through its control socket",
                       description="Send one request to the control socket of `pmctl serve` and print the answer.")
    p.add_argument("--socket", required=True, metavar="PATH", help="the control socket (pmctl serve --socket)")
    p.add_argument("what", choices=("status", "hold", "resume", "stop", "estop", "unlock", "home", "resume-job",
                                    "override", "queue", "record", "subscribe", "optional-stop"),
                   help="home: the homing cycle ($H); resume-job: continue the job a crash interrupted from its "
                        "line, after unlock or home (retract along the tool axis, move over, plunge at feed); "
                        "resume: also cycle start after M0, M1 or a tool change (M6); optional-stop on|off: "
                        "whether M1 pauses")
    p.add_argument("args", nargs="*", help="queue: 'add FILE' or 'list'; record: 'start DIR' or 'stop'; "
                                           "optional-stop: 'on' or 'off'")
    p.add_argument("--json", action="store_true", help="status: the JSON answer instead of the table")
    p.add_argument("--feed", type=float, default=None, help="override: feed factor 0.1 .. 2.0")
    p.add_argument("--rapid", type=float, default=None, help="override: rapid factor 0.25, 0.5 or 1.0")
    p.add_argument("--spindle", type=float, default=None, help="override: spindle speed factor 0.1 .. 2.0 (the VFD's "
                                                                "set-point, when a [spindle] is configured)")
    p.add_argument("--period", type=float, default=0.5, help="subscribe: seconds between status lines")
    p.add_argument("--line", type=int, default=None, help="resume-job: the line to resume from (default: the "
                                                          "line the journal recorded)")
    p.add_argument("--clearance", type=float, default=None, metavar="MM",
                   help="resume-job: retract and approach clearance along the tool axis (default 5 mm)")
    p.set_defaults(func=run)


def request(path, req: dict, *, stream=False, timeout=30.0):
    import json
    import socket
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout)
    s.connect(str(path))
    f = s.makefile("rwb")
    f.write((json.dumps(req) + "\n").encode())
    f.flush()
    if stream:
        return s, f
    line = f.readline()
    s.close()
    return json.loads(line)


def run(args) -> int:
    import json
    import os

    from pmctl.core.errors import PmctlError
    req = {"cmd": args.what.replace("-", "_")}
    if args.what == "resume-job":
        if args.line is not None:
            req["line"] = args.line
        if args.clearance is not None:
            req["clearance_mm"] = args.clearance
    if args.what == "queue":
        if args.args[:1] == ["add"] and len(args.args) == 2:
            req["add"] = os.path.abspath(args.args[1])
        elif args.args == ["list"]:
            req["list"] = True
        else:
            raise PmctlError("queue: use 'queue add FILE' or 'queue list'")
    elif args.what == "record":
        if args.args[:1] == ["start"] and len(args.args) == 2:
            req["start"] = os.path.abspath(args.args[1])
        elif args.args == ["stop"]:
            req["stop"] = True
        else:
            raise PmctlError("record: use 'record start DIR' or 'record stop'")
    elif args.what == "optional-stop":
        if args.args not in (["on"], ["off"]):
            raise PmctlError("optional-stop: use 'optional-stop on' or 'optional-stop off'")
        req["on"] = args.args == ["on"]
    elif args.what == "override":
        if args.feed is not None:
            req["feed"] = args.feed
        if args.rapid is not None:
            req["rapid"] = args.rapid
        if args.spindle is not None:
            req["spindle"] = args.spindle
    try:
        if args.what == "subscribe":
            req["period_s"] = args.period
            s, f = request(args.socket, req, stream=True, timeout=None)
            try:
                for line in f:
                    print(line.decode().strip(), flush=True)
            except KeyboardInterrupt:
                pass
            finally:
                s.close()
            return 0
        ans = request(args.socket, req, timeout=None if args.what == "home" else 30.0)
    except OSError as e:
        raise PmctlError(f"--socket {args.socket}: {e.strerror or e}") from None
    if not ans.get("ok"):
        raise PmctlError(f"{args.what}: {ans.get('error', 'refused')}")
    if args.what == "status" and not args.json:
        print(status_table(ans))
    else:
        print(json.dumps(ans))
    return 0


def status_table(st: dict) -> str:
    """The status answer as a table an operator reads (positions to the micrometre, no -0.000)."""
    def num(v, nd=3):
        return f"{round(float(v), nd) + 0.0:.{nd}f}"
    rows = [("state", st.get("state", "?") + (f" (alarm {st['alarm']}: {st.get('alarm_msg', '')})"
                                               if st.get("alarm") else ""))]
    if st.get("paused"):
        rows.append(("paused", st["paused"]))
    m = st.get("mpos") or []
    if len(m) == 5:
        rows.append(("position", f"X {num(m[0])}  Y {num(m[1])}  Z {num(m[2])} mm   A {num(m[3])}  B {num(m[4])} deg"))
    rows.append(("line", str(st.get("line", 0))))
    rows.append(("overrides", f"feed {num(100 * st.get('feed_override', 1), 0)} %, rapid "
                              f"{num(100 * st.get('rapid_override', 1), 0)} %, spindle "
                              f"{num(100 * st.get('spindle_override', 1), 0)} %"))
    acc = [f"spindle {num(st.get('spindle_rpm', 0), 0)} rpm"] + list(st.get("coolant") or [])
    rows.append(("accessories", ", ".join(acc)))
    if st.get("outputs"):
        rows.append(("outputs", ", ".join(f"{k} = {v}" for k, v in sorted(st["outputs"].items()))))
    rows.append(("queued jobs", str(st.get("queued_items", 0))))
    rows.append(("homed", "yes" if st.get("homed") else "no"))
    rows.append(("rt process", "running" if st.get("rt_alive") else "DOWN"))
    c = st.get("counts") or []
    if c:
        rows.append(("pulse counters", " ".join(str(int(x)) for x in c)))
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)
