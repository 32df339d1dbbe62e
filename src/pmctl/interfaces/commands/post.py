"""`pmctl post JOB --out FILE [--dt S]`: the post-processor (seed 000 ch. 7): the job's tool poses in the
machine's actuator coordinates, chain lengths L1 L2 L3 and table X Y (mm), as CSV with a header.

Without ``--dt``: one row per move that moves, its end pose (``line,L1,L2,L3,X,Y``). With ``--dt S``:
the job planned as pmctl run plans it (the same check first; streamed, bounded memory), one row every
S seconds of the planned motion and its last sample (``t,line,L1,L2,L3,X,Y``); S is a multiple of the
tick period (the service config's rate, or --rate). Numbers are written as the shortest text that
reads back as the same float. See pmctl.task.post and docs/planning.md.
"""

from __future__ import annotations

import math
from pathlib import Path


def add_parser(sub):
    from pmctl.interfaces.commands.check import add_context_args
    p = sub.add_parser("post", help="the job in actuator coordinates (chain lengths, table) as CSV",
                       description="Post-processor: convert a CL-data or G-code job into the machine's actuator "
                                   "coordinates, chain lengths L1 L2 L3 and table X Y in mm, one row per move "
                                   "(its end pose) or, with --dt, one row per time step of the job as pmctl run "
                                   "plans it. CSV with a header.",
                       epilog="docs/planning.md describes the output; the job is checked first as pmctl check does "
                              "(a job that cannot run writes nothing).")
    p.add_argument("job", help="job file: G-code (.ngc .nc .gcode .tap) or CL data (.cl ...)")
    p.add_argument("--out", required=True, metavar="FILE", help="CSV file to write (replaced if it exists)")
    p.add_argument("--dt", type=float, default=None, metavar="S",
                   help="a row every S seconds of the planned motion (a multiple of the tick period) instead of "
                        "one per move")
    add_context_args(p)
    p.set_defaults(func=run)


def _fmt(x) -> str:
    return repr(float(x))          # the shortest text that reads back as the same float


def run(args) -> int:
    from pmctl.core.errors import JobProblems, PmctlError
    from pmctl.interfaces.commands.check import Context
    from pmctl.motion.state_store import atomic_write
    from pmctl.task import post
    from pmctl.task.jobcheck import check_file
    ctx = Context(args)
    every = 1
    if args.dt is not None:
        k = args.dt / ctx.dt if math.isfinite(args.dt) and args.dt > 0 else float("nan")
        if not (k >= 1 and abs(k - round(k)) < 1e-9 * k):
            raise PmctlError(f"--dt {args.dt:g} s must be a positive multiple of the tick period {ctx.dt:g} s")
        every = int(round(k))
    rep = check_file(args.job, ctx.plan_machine, ctx.dt, start=ctx.start, feed_override=ctx.feed_override,
                     batch=ctx.batch, **ctx.reader)
    if not rep.ok:
        raise JobProblems(rep.problems)
    out = Path(args.out)
    rows = [0]

    def text():                     # the CSV, chunk by chunk (a long job is never whole in memory)
        if args.dt is None:
            yield "line," + ",".join(post.COLUMNS) + "\n"
            lines, q = post.per_move(rep.job, ctx.plan_machine)
            yield "".join(f"{int(ln)}," + ",".join(_fmt(x) for x in qq) + "\n" for ln, qq in zip(lines, q))
            rows[0] = len(lines)
            return
        yield "t,line," + ",".join(post.COLUMNS) + "\n"
        for t, ln, q in post.per_step(rep.job, ctx.plan_machine, ctx.dt, every, start=ctx.start,
                                      feed_override=ctx.feed_override):
            yield "".join(f"{_fmt(tt)},{int(ll)}," + ",".join(_fmt(x) for x in qq) + "\n"
                          for tt, ll, qq in zip(t, ln, q))
            rows[0] += len(t)
    try:
        atomic_write(out, text())
    except OSError as e:
        raise PmctlError(f"{out}: cannot write: {e.strerror or e}") from None
    rows = rows[0]
    print(f"{out}: {rows} rows ({'per move' if args.dt is None else f'every {every * ctx.dt:g} s'}), "
          f"columns {'line' if args.dt is None else 't,line'},{','.join(post.COLUMNS)} (mm)")
    return 0
