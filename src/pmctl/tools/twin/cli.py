"""Command-line registration of the twin tools (``pmctl twin diagnose|synth``), importable without
numpy: each ``func`` imports its module only when it runs, so ``pmctl --help`` stays fast."""

from __future__ import annotations

from pmctl.interfaces.cli import lazy
from pmctl.tools.twin.catalogue import DEFAULT_CAP, EFFECTS, RUNS


def add_diagnose_parser(sub):
    p = sub.add_parser("diagnose", help="where and why a recording differs from the nominal twin",
                       description="Locate the mismatch between a recording and the nominal twin, name the "
                                   "physics it left out, fit it and show the held-out fit improve. A recording of "
                                   "independent axes (\"machine\": \"axes\", e.g. from pmctl twin import) gets the "
                                   "drive's force model (mass, friction, constant load), servo tracking, backlash and "
                                   "compliance of a load encoder, cogging and resonances. "
                                   "The report and its JSON form are described in docs/diagnosis-report.md.")
    p.add_argument("folder", help="recording folder (holding recording.json and data.csv); a folder with "
                                  "one recording in a sub-folder is accepted too")
    p.add_argument("--json", metavar="PATH", nargs="?", const="-",
                   help="also write the report as JSON here (docs/diagnosis-report.md); --json alone (or "
                        "--json -) prints the JSON on stdout and the text report on stderr")
    p.add_argument("--plots", metavar="DIR", help="write PNG plots here")
    p.add_argument("--config", metavar="PATH", help="machine config (default: the one the recording names)")
    p.add_argument("--cap", type=int, default=DEFAULT_CAP,
                   help=f"max analysis samples per channel (default {DEFAULT_CAP})")
    p.add_argument("--progress", action="store_true",
                   help="progress bar on stderr even when stderr is not a terminal")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (default: one on stderr on long work when it is a terminal)")
    p.add_argument("--write-compensation", metavar="FILE",
                   help="write the backlash and screw compensation table of the accepted per-axis findings "
                        "(backlash, pitch and periodic errors) to FILE, for the machine config's [compensation] "
                        "(docs/machine.md §6); geometry findings go to 'pmctl calibrate from-twin'")
    p.set_defaults(func=lazy("pmctl.tools.twin.diagnose:_run"))
    return p


def add_synth_parser(sub):
    p = sub.add_parser("synth", help="make recordings with concealed effects and separate answer keys",
                       description="Write OUT_DIR/case-NNN/recording/ (a recording, docs/recording.md) and "
                                   "OUT_DIR/case-NNN/answer.json (the hidden effects, outside the recording), "
                                   "to test the diagnosis blind. An existing case is refused unless --force.")
    p.add_argument("out_dir", metavar="OUT_DIR", help="folder for the cases (created if missing)")
    p.add_argument("--effects", default="random",
                   help=f"comma list of catalogue effects hidden together in every case, or 'random' "
                        f"(one per case). Catalogue: {', '.join(EFFECTS)}")
    p.add_argument("--count", type=int, default=1, metavar="N", help="number of cases (default 1)")
    p.add_argument("--seed", type=int, default=0, metavar="S",
                   help="random seed: the same seed gives the same cases (default 0)")
    p.add_argument("--clean", action="store_true", help="no effects: noise only")
    p.add_argument("--max-effects", type=int, default=1, metavar="K",
                   help="with --effects random: up to K distinct effects per case (default 1)")
    p.add_argument("--run", choices=RUNS, default=None, help="trajectory kind (default: one that shows the effects)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="seconds (default 60; warmup 600)")
    p.add_argument("--rate", type=float, default=None, metavar="HZ", help="log rate Hz (default 1000; warmup 100)")
    p.add_argument("--magnitude-scale", type=float, default=1.0, metavar="F",
                   help="make the hidden effects this many times stronger (<1: harder cases; default 1)")
    p.add_argument("--noise-scale", type=float, default=1.0, metavar="F",
                   help="multiply every measurement noise (default 1)")
    p.add_argument("--plant", choices=("batch", "loop"), default="batch",
                   help="batch (default): the effects computed over the whole run at once (fast, the whole "
                        "catalogue); loop: the run machined by the real control loop (no real time) on the sim "
                        "backend carrying the effects (backlash, pitch/periodic error, friction, servo lag; "
                        "plus the sensor, geometry and compliance effects)")
    p.add_argument("--machine", choices=("prototype", "axes"), default="prototype",
                   help="prototype (default): runs of the machine; axes: bench runs of one ball-screw axis, a "
                        "recording of independent axes (cmd, enc, effort, load, acc) with the physics of real drives: "
                        "inertia, friction, force_offset, servo_tracking, backlash, compliance, resonance, cogging "
                        "(--effects from those; random: the force model and --max-effects others)")
    p.add_argument("--force", action="store_true", help="replace cases that already exist in OUT_DIR")
    p.set_defaults(func=lazy("pmctl.tools.twin.synth:_cmd"))
    return p


def add_import_parser(sub):
    p = sub.add_parser("import", help="turn a bench log (CSV/TSV, halsampler, halscope, .mat, Klipper) into a "
                                      "recording of independent axes",
                       description="Write OUT_DIR as a recording of independent axes (\"machine\": \"axes\", "
                                   "docs/recording.md) from SRC: a CSV or TSV with a header row, LinuxCNC halsampler "
                                   "output or a halscope log, a MATLAB .mat file, or Klipper's raw accelerometer CSV. "
                                   "Then: pmctl twin diagnose OUT_DIR.")
    p.add_argument("src", metavar="SRC", help="the log to import")
    p.add_argument("out_dir", metavar="OUT_DIR", help="the recording folder to write (refused if it exists, "
                                                     "unless --force)")
    p.add_argument("--format", choices=("csv", "halsampler", "halscope", "mat", "klipper"), default=None,
                   help="the source's format (default: told by the file)")
    p.add_argument("--map", action="append", metavar="CH=SRC[,CH=SRC]",
                   help="which source column (name, or 1-based number) or .mat variable becomes which channel: "
                        "cmd_<A> (required per axis), enc_<A>, load_<A>, effort_<A>, acc_<A>, temp_<name>; "
                        "SRC*K or SRC/K scales it (K a number or a scalar variable of the .mat file)")
    p.add_argument("--unit", action="append", metavar="CH=UNIT[,CH=UNIT]",
                   help="each channel's unit as logged (mm, m, um, deg, rad, N, N m, A, m/s^2, g ...; "
                        "default mm, deg for an axis whose command is an angle, N, mm/s^2)")
    p.add_argument("--time", metavar="COLUMN", help="the time column (default: --rate)")
    p.add_argument("--time-unit", metavar="UNIT", help="unit of --time (s, ms, us; default s)")
    p.add_argument("--rate", type=float, metavar="HZ", help="sample rate when the log has no time column "
                                                            "(halsampler: the sampled thread's rate)")
    p.add_argument("--force", action="store_true", help="replace OUT_DIR if it holds a recording")
    p.set_defaults(func=lazy("pmctl.tools.twin.importers:_cmd"))
    return p


def add_parser(sub):
    add_diagnose_parser(sub)
    add_synth_parser(sub)
    add_import_parser(sub)
