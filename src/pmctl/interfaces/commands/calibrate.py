"""`pmctl calibrate identify|plan|rsm`: kinematic calibration (pmctl.tools.calibrate).

Light at import: the numerical modules are imported when a subcommand runs."""

from __future__ import annotations

import json

from pmctl.core.errors import InputError, PmctlError


def add_parser(sub):
    p = sub.add_parser("calibrate", help="kinematic calibration: plan poses, identify the geometry",
                       description="Kinematic calibration of the machine geometry (mm, degrees).")
    cs = p.add_subparsers(dest="calibrate_command", metavar="identify|plan|rsm|from-twin|su-export|su-import", required=True)

    a = cs.add_parser("identify", help="identify the geometry from measured poses; write a calibrated config",
                      description="Identify base/platform joints, revolute axes, length offsets, tool length "
                                  "and tilt by iterative least squares from a recording of static poses "
                                  "(or dwells) with joints cmd_* (or enc_*) and measured tip_* (and tool_*).")
    a.add_argument("recording", help="recording folder (pmctl-recording/1)")
    a.add_argument("--config", default=None,
                   help="reference machine config (default: the recording's machine)")
    a.add_argument("--out", required=True, help="calibrated machine config to write (TOML)")
    a.add_argument("--tip-sigma-um", type=float, default=2.0, help="tool tip measurement noise, um (default 2)")
    a.add_argument("--axis-sigma-urad", type=float, default=10.0,
                   help="tool axis measurement noise, urad (default 10)")
    a.add_argument("--joints", choices=("auto", "cmd", "enc"), default="auto",
                   help="joint channels: enc_* when all are recorded (auto), or force one")
    a.add_argument("--min-dwell-rows", type=int, default=3,
                   help="in a recording with motion, a dwell needs this many rows (default 3)")
    a.add_argument("--max-sigma", type=float, default=0.5,
                   help="a parameter combination known no better than this (mm or deg, 1 sigma) is held "
                        "at the reference value (default 0.5)")
    a.add_argument("--name", default=None, help="machine name in the written config")
    a.add_argument("--json", action="store_true", help="print the report as JSON")
    a.set_defaults(func=run_identify)

    b = cs.add_parser("plan", help="choose well-conditioned measurement poses; write G-code and CSV",
                      description="Choose N poses that make the identification well conditioned "
                                  "(D-optimal exchange on the identification Jacobian); write a G-code "
                                  "job that visits them with dwells and a CSV of the poses.")
    b.add_argument("--config", default="prototype", help="machine config (default: prototype)")
    b.add_argument("-n", "--poses", type=int, default=60, help="number of poses (default 60)")
    b.add_argument("--candidates", type=int, default=1500, help="random candidate poses (default 1500)")
    b.add_argument("--dwell-s", type=float, default=2.0, help="dwell at each pose, s (default 2)")
    b.add_argument("--feed", type=float, default=1500.0, help="feed between poses, mm/min (default 1500)")
    b.add_argument("--tip-only", action="store_true", help="plan for tip-only measurement (no tool axis)")
    b.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    b.add_argument("--out", required=True, help="output stem: writes STEM.ngc and STEM.csv")
    b.set_defaults(func=run_plan)

    c = cs.add_parser("rsm", help="the response-surface method of the 2006 report (ch. 5-6) vs identification",
                      description="Reproduce the response-surface error estimation and calibration on a "
                                  "simulated machine with +-0.5 mm / +-0.5 deg errors and compare it with "
                                  "the model-based identification on the same measurement budget.")
    c.add_argument("--config", default="prototype", help="machine config (default: prototype)")
    c.add_argument("--seed", type=int, default=3, help="random seed of the simulated machine (default 3)")
    c.set_defaults(func=run_rsm)

    d = cs.add_parser("from-twin", help="calibrated config from the geometry findings of a twin diagnosis",
                      description="Apply the geometry findings of a `pmctl twin diagnose` JSON report to a "
                                  "machine config and write the calibrated config.")
    d.add_argument("report", help="twin diagnosis report (JSON)")
    d.add_argument("--config", default="prototype", help="reference machine config (default: prototype)")
    d.add_argument("--out", required=True, help="calibrated machine config to write (TOML)")
    d.set_defaults(func=run_from_twin)

    e = cs.add_parser("su-export", help="the machine as kinematic chains in SU-parameter notation (JSON)",
                      description="Write the machine's kinematic chains (three RPS chains, the table, the tool) "
                                  "with Sheth-Uicker (SU) link parameters, for virtual-machining tools.")
    e.add_argument("--config", default="prototype", help="machine config (default: prototype)")
    e.add_argument("--out", required=True, help="JSON file to write")
    e.set_defaults(func=run_su_export)
    f = cs.add_parser("su-import", help="read an SU-parameter description back into a machine config",
                      description="Read a `pmctl calibrate su-export` file; the geometry comes from it, "
                                  "limits, resolution, masses etc. from --config.")
    f.add_argument("su", help="SU-parameter JSON file")
    f.add_argument("--config", default="prototype", help="machine config for everything but the geometry")
    f.add_argument("--out", required=True, help="machine config to write (TOML)")
    f.set_defaults(func=run_su_import)


def run_identify(args):

    import numpy as np

    from pmctl.core import kinematics as K
    from pmctl.core.config import load_machine
    from pmctl.core.recording import read_recording
    from pmctl.tools.calibrate import configio, data, identify as I, model as Mo

    if not args.tip_sigma_um > 0 or not args.axis_sigma_urad > 0 or not args.max_sigma > 0:
        raise PmctlError("--tip-sigma-um, --axis-sigma-urad and --max-sigma must be > 0")
    rec = read_recording(args.recording)
    base = load_machine(args.config) if args.config else rec.machine
    poses = data.poses_of(rec, joints=args.joints, min_rows=max(1, args.min_dwell_rows))
    rng = np.random.default_rng(0)
    wt, wa = Mo.random_tool_poses(base, 300, rng)
    wq = K.ik_batch(wt, wa, base).q
    res = I.identify(poses.q, poses.tip, poses.axis, base.geometry, tip_sigma_mm=args.tip_sigma_um * 1e-3,
                     axis_sigma_rad=args.axis_sigma_urad * 1e-6, max_sigma=args.max_sigma, workspace_q=wq)
    report = I.format_report(res, ref_name=base.name)
    src = f"{rec.path} ({poses.q.shape[0]} {'dwells' if poses.dwells else 'static poses'}, joints {poses.joints_from}_*)"
    header = (f"Calibrated by `pmctl calibrate identify` from {src}\n"
              f"reference config: {base.source}\n"
              f"residual after: tip RMS {res.tip_rms_um:.3f} um, worst {res.tip_max_um:.3f} um"
              + (f"; axis RMS {res.axis_rms_urad:.2f} urad" if res.has_axis else "") + "\n"
              f"predicted accuracy (1 sigma, workspace sample): tip RMS {res.predicted_tip_um:.3f} um\n"
              f"identified {res.rank} of {Mo.N_PARAMS} parameter combinations; "
              f"{len(res.fixed)} held at the reference values")
    out = configio.write_machine(args.out, configio.calibrated_dict(base, res.geometry, name=args.name), header)
    if args.json:
        print(json.dumps({
            "out": str(args.out), "poses": int(res.n_poses), "joints": poses.joints_from, "dwells": poses.dwells,
            "rank": res.rank, "n_params": Mo.N_PARAMS, "iterations": res.iterations, "chi2_red": res.chi2_red,
            "tip_rms_um": res.tip_rms_um, "tip_max_um": res.tip_max_um,
            "axis_rms_urad": res.axis_rms_urad if res.has_axis else None,
            "axis_max_urad": res.axis_max_urad if res.has_axis else None,
            "before_tip_rms_um": res.before_tip_rms_um, "predicted_tip_um": res.predicted_tip_um,
            "predicted_tip_max_um": res.predicted_tip_max_um,
            "predicted_axis_urad": res.predicted_axis_urad if res.has_axis else None,
            "condition_number": res.cond,
            "parameters": {n: {"change": float(v), "sigma": float(s)}
                           for n, v, s in zip(Mo.PARAM_NAMES, res.dp, res.sigma)},
            "not_identifiable": [{"singular_value": d.singular_value,
                                  "sigma": d.sigma if d.sigma != float("inf") else None,
                                  "exact_symmetry": d.sigma == float("inf"), "terms": d.terms}
                                 for d in res.fixed],
        }))
    else:
        print(f"recording: {src}")
        print(report)
        print(f"\nwrote {args.out} (machine '{out.name}')")
    return 0


def run_plan(args):
    from pmctl.core.config import load_machine
    from pmctl.tools.calibrate import plan

    m = load_machine(args.config)
    print(plan.run(m, args))
    return 0


def run_rsm(args):
    from pmctl.core.config import load_machine
    from pmctl.tools.calibrate import rsm

    print(rsm.run(load_machine(args.config), seed=args.seed))
    return 0


def run_from_twin(args):

    from pmctl.core.config import load_machine
    from pmctl.tools.calibrate import twin_link

    try:
        report = json.loads(open(args.report, encoding="utf-8").read())
    except OSError as e:
        raise InputError(args.report, None, f"cannot read: {e.strerror or e}") from None
    except json.JSONDecodeError as e:
        raise InputError(args.report, e.lineno, f"not valid JSON: {e.msg}", column=e.colno) from None
    m = load_machine(args.config)
    n = len(twin_link._findings(report))
    out = twin_link.write_calibrated(m, report, args.out, source=args.report)
    print(f"applied {n} geometry finding(s); wrote {args.out} (machine '{out.name}')")
    for f in twin_link.lookalike_findings(report):
        alts = ", ".join(str(a.get("effect")) for a in f["alternatives"] if isinstance(a, dict))
        print(f"not applied: the geometry finding for chain {f.get('chain')!r}: the recording could not tell it "
              f"from {alts} ({f.get('separate_by') or 'record a run that separates them'})")
    return 0


def run_su_export(args):
    from pmctl.core.config import load_machine
    from pmctl.tools.calibrate import su

    m = load_machine(args.config)
    try:
        doc = su.write_su(m, args.out)
    except OSError as e:
        raise PmctlError(f"{args.out}: cannot write: {e.strerror or e}") from None
    print(f"wrote {args.out}: {len(doc['loops'])} loops "
          f"({', '.join(lp['name'] for lp in doc['loops'])}) of machine '{m.name}'")
    return 0


def run_su_import(args):
    from pmctl.core.config import load_machine
    from pmctl.tools.calibrate import configio, su

    base = load_machine(args.config)
    geom = su.read_su(args.su, base)
    data = configio.calibrated_dict(base, geom, name=f"{base.name}-su",
                                    description=f"{base.name} with the geometry of {args.su}")
    data["geometry"]["z_table_mm"] = float(geom.z_table)
    out = configio.write_machine(args.out, data, f"Geometry read from the SU-parameter description {args.su}")
    print(f"wrote {args.out} (machine '{out.name}')")
    return 0
