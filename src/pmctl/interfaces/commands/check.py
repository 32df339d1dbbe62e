"""`pmctl check JOB [--json]`: is the job able to run? Everything pmctl run checks before anything
moves, without a machine: the job read and parsed (every problem the reader reports), every pose and
the path between them against the machine (workspace, tilt, joint limits: all of them), and the whole
job planned by the planner the run uses (streamed, bounded memory, no samples kept). See
pmctl.task.jobcheck and docs/planning.md.

Prints every problem as ``file:line: column C: kind: message`` and a summary; with ``--json`` one JSON
object: ``{"ok": bool, "problems": [{"file", "line", "column", "kind", "message"}], "summary": {...}}``.
Exit status: 0 the job can run, 1 it cannot, 2 usage.

The start pose is the run's: the saved pulse counters of the state file (the service config's
``state_file``, or ``--state FILE``; ``--state ''`` or no saved counters: home), so that G91 moves and
arcs start where pmctl run would start them.
"""

from __future__ import annotations

import json
import math


def add_parser(sub):
    p = sub.add_parser("check", help="check a job before anything moves: every problem, and a summary",
                       description="Check a job as pmctl run does before anything moves: read and parse it, "
                                   "check every pose and the path between them against the machine (workspace, "
                                   "tilt, joint limits), and plan the whole job with the planner the run uses. "
                                   "Lists every problem with file, line, column, kind (syntax, unsupported, "
                                   "machine, planning) and what to do. Exit status: 0 the job can run, 1 it "
                                   "cannot, 2 usage.",
                       epilog="docs/planning.md describes the checks, the JSON and how the planner treats CAM "
                              "output (runs of short lines, G64 P tolerances).")
    p.add_argument("job", help="job file: G-code (.ngc .nc .gcode .tap) or CL data (.cl ...)")
    p.add_argument("--json", action="store_true",
                   help='print {"ok", "problems": [{"file", "line", "column", "kind", "message"}], "summary"} '
                        "as one JSON object")
    add_context_args(p)
    p.set_defaults(func=run)


def add_context_args(p):
    """The options that decide how a job is planned, as pmctl run takes them."""
    p.add_argument("--config", default="prototype", help="machine config (default: config/prototype.toml)")
    p.add_argument("--service", default=None, help="service config (default: config/service.toml)")
    p.add_argument("--backend", default=None, help="HAL backend whose V-F limits apply (default: the service config's)")
    p.add_argument("--rate", type=float, default=None, metavar="HZ", help="tick rate (default: service config)")
    p.add_argument("--feed-override", type=float, default=1.0, help="feed override factor (default 1)")
    p.add_argument("--state", default=None, metavar="FILE",
                   help="pulse-counter state file the job starts from (default: the service config's state_file, "
                        "as pmctl run; '' for home)")


class Context:
    """What planning a job needs, resolved as pmctl run resolves it: the machine, the machine the planner
    plans for (V-F caps), the tick period, the start pose, whether an input shaper plans it whole."""

    def __init__(self, args):
        from pmctl import hal
        from pmctl.core.config import load_machine
        from pmctl.core.errors import PmctlError
        from pmctl.motion.nc import initial_state
        from pmctl.motion.service_config import load_service_config, nc_setup
        from pmctl.motion.state_store import load_counters
        from pmctl.task.jobcheck import machine_for_planning
        if args.rate is not None and not (math.isfinite(args.rate) and 10 <= args.rate <= 20000):
            raise PmctlError(f"--rate must be within 10 .. 20000 Hz, got {args.rate:g}")
        if not (math.isfinite(args.feed_override) and 0 < args.feed_override <= 10):
            raise PmctlError(f"--feed-override must be within (0, 10], got {args.feed_override:g}")
        if args.backend is not None and args.backend not in hal.BACKENDS:
            raise PmctlError(f"--backend {args.backend!r}: unknown backend; known: {', '.join(sorted(hal.BACKENDS))}")
        self.machine = machine = load_machine(args.config)
        svc = load_service_config(args.service)
        if args.rate is not None:
            svc.loop.rate_hz = float(args.rate)
        self.dt = svc.loop.dt
        backend = args.backend or svc.backend
        setup = nc_setup(svc, machine, self.dt, backend)
        params = svc.nc.params(machine, self.dt, where=svc.source, modes=setup.modes)
        self.plan_machine = machine_for_planning(machine, params)
        self.batch = setup.shaper is not None
        self.feed_override = args.feed_override
        from pmctl.task.gcode import reader_options
        self.reader = reader_options(args.job, svc.interpreter)    # the [interpreter] settings (tool table...)
        state_file = svc.loop.state_file if args.state is None else args.state
        saved = (load_counters(state_file, machine=machine.name, pulses_per_mm=machine.resolution.pulses_per_mm)
                 if state_file else None)
        if saved is not None:
            st = initial_state(machine, saved.counts)
            self.start = (st.tip, st.axis)
        else:
            from pmctl.task.job import home_pose
            self.start = home_pose(machine)


def run(args) -> int:
    from pmctl.task.jobcheck import check_file
    ctx = Context(args)
    rep = check_file(args.job, ctx.plan_machine, ctx.dt, start=ctx.start, feed_override=ctx.feed_override,
                     batch=ctx.batch, **ctx.reader)
    if args.json:
        print(json.dumps(rep.as_dict(), indent=1))
        return 0 if rep.ok else 1
    for p in rep.problems:
        print(p)
    s = rep.summary
    if s:
        parts = [f"{s['moves']} moves"]
        if "length_mm" in s:
            parts.append(f"tool tip path {s['length_mm']:.6g} mm")
        if "machining_time_s" in s:
            parts.append(f"machining time {s['machining_time_s']:.6g} s as planned")
        if s.get("tools"):
            parts.append("tools " + " ".join(f"T{t}" for t in s["tools"]))
        print("summary: " + ", ".join(parts))
        e = s.get("extents")
        if e:
            print("extents: " + ", ".join(f"{k[0].upper()} {v[0]:.6g} .. {v[1]:.6g} mm" for k, v in e.items()
                                          if k.endswith("_mm")) + f", tilt up to {e['tilt_deg_max']:.4g} deg")
        pl = s.get("planner")
        if pl:
            print(f"planner: {pl['segments']} segments ({pl['merged_moves']} short lines merged within the path "
                  f"tolerance), {pl['fallbacks']} fallbacks")
    n = len(rep.problems)
    print("ok: the job can run" if rep.ok else f"{n} problem{'s' * (n > 1)}: the job cannot run")
    return 0 if rep.ok else 1
