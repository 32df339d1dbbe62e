"""Command-line registration of the analyses (``pmctl analyze ...``), importable without numpy:
each subcommand's ``func`` imports its analysis module only when it runs, so ``pmctl --help``
stays fast. Sources are cited by their published titles (docs/README.md, "Sources")."""

from __future__ import annotations

from pmctl.interfaces.cli import lazy

TACHIYA = "Tachiya et al. 2006"
KAMIYA = "Kamiya et al. 2005"


def add_mechanism_parsers(sub):
    """``io-ratio``, ``drive``, ``path-error`` and ``compliance`` (pmctl.tools.analysis.mechanism)."""
    mod = "pmctl.tools.analysis.mechanism"
    specs = [
        ("io-ratio", "_cmd_io_ratio",
         f"input-output ratio maps dZ^2 over theta1 x theta2 ({TACHIYA}, Fig. 4.1-4.3)"),
        ("drive", "_cmd_drive",
         f"drive characteristics G_T, G_R, omega_T, omega_R against {TACHIYA}, Table 2.1"),
        ("path-error", "_cmd_path_error",
         f"joint-interpolation path error ({TACHIYA}, Fig. 4.4-4.6) and adaptive spacing"),
        ("compliance", "_cmd_compliance",
         f"output displacement error for unit loads ({TACHIYA}, sec. 2.4.1)"),
    ]
    for name, func, text in specs:
        p = sub.add_parser(name, help=text, description=text + ". See docs/machine.md.")
        p.add_argument("--config", default="prototype", help="machine config (default: prototype)")
        p.add_argument("--out", default="out/analyze", help="directory for the PNGs (default: out/analyze)")
        if name == "path-error":
            p.add_argument("--tol-um", type=float, default=1.0,
                           help="path tolerance of the adaptive spacing, micrometres (default 1)")
        p.set_defaults(func=lazy(f"{mod}:{func}"))


def add_vibration_parsers(sub):
    """``vibration`` and ``vf`` (pmctl.tools.analysis.vibration)."""
    mod = "pmctl.tools.analysis.vibration"
    p = sub.add_parser("vibration", help=f"{KAMIYA} ch. 3: eq. 3.1 roots/factors, step and ramp "
                       "responses with and without strain feedback K_θ (PNG)",
                       description=f"Reproduces eq. 3.1-3.5 and Figs. 3.3/3.5 of {KAMIYA} by simulation "
                                   "with the software V-F converter. See docs/machine.md.")
    p.add_argument("--out", default="out/analyze", help="directory for the PNG figures (default out/analyze)")
    p.set_defaults(func=lazy(f"{mod}:cmd_vibration"))
    q = sub.add_parser("vf", help=f"{KAMIYA} ch. 2: V-F minimum-amplitude law (eq. 2.2), three-region "
                       "map (Fig. 2.9) and the sec. 3.6 noise claim, by simulation (PNG)",
                       description="The software V-F converter's dead region and regions, by simulation. "
                                   "See docs/machine.md.")
    q.add_argument("--out", default="out/analyze", help="directory for the PNG figures (default out/analyze)")
    q.set_defaults(func=lazy(f"{mod}:cmd_vf"))


def add_resonance_parser(sub):
    """``resonance`` (pmctl.tools.analysis.resonance)."""
    p = sub.add_parser("resonance", help="chain modes from the strain gauges: PSD, frequency and damping, "
                       "input-shaper and K_theta advice (PNG); --make-job writes the test move; an accelerometer "
                       "CSV (Klipper's) gets a shaper and its frequency",
                       description="Resonance measurement from the strain gauges of a recorded test move.")
    p.add_argument("recording", nargs="?",
                   help="recording folder of the test move (pmctl run --record); or an accelerometer log: a "
                        "Klipper CSV (raw '#time,accel_x,accel_y,accel_z' or a resonance PSD 'freq,psd_x,...'), or "
                        "a recording of independent axes with acc_<A> channels, analysed the way Klipper's "
                        "calibrate_shaper does (docs/vibration.md)")
    p.add_argument("--accel-axis", choices=("x", "y", "z", "all"), default=None,
                   help="accelerometer CSV: fit the shapers to this axis' PSD (default: the sum of all three)")
    p.add_argument("--make-job", metavar="OUT.ngc", help="write the impulse test move (G-code) and exit")
    p.add_argument("--axis", default="z", help="test-move axis x, y or z (default z: all three chains)")
    p.add_argument("--strokes", type=int, default=4, help="number of strokes (default 4)")
    p.add_argument("--stroke-mm", type=float, default=1.0, help="stroke length, mm (default 1)")
    p.add_argument("--dwell-s", type=float, default=0.5, help="dwell after each stroke, s (default 0.5)")
    p.add_argument("--feed", type=float, default=3000.0, help="feed, mm/min (default 3000)")
    p.add_argument("--fmin", type=float, default=5.0, help="lowest mode frequency searched, Hz (default 5)")
    p.add_argument("--fmax", type=float, default=None, help="highest, Hz (default 0.45 x sample rate)")
    p.add_argument("--modes", type=int, default=1, help="modes fitted per chain (default 1)")
    p.add_argument("--kv", type=float, default=400.0, help="NC pose gain for the K_theta advice, 1/s (default 400)")
    p.add_argument("--out", default="out/analyze", help="directory for resonance.png/json (default out/analyze)")
    p.add_argument("--write", metavar="SERVICE.toml", default=None,
                   help="also put the modes found into that service config's [nc] (mode_hz, mode_damping_ratio, "
                        "modal_stiffness_N_per_mm): the source of --k-theta auto and --shaper auto")
    p.set_defaults(func=lazy("pmctl.tools.analysis.resonance:cmd_resonance"))


def add_parsers(sub):
    add_mechanism_parsers(sub)
    add_vibration_parsers(sub)
    add_resonance_parser(sub)
