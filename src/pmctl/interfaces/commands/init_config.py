"""`pmctl init-config`: a commented starting configuration for real hardware.

    pmctl init-config --backend stepdir|canopen DIR [--force]

Writes DIR/service.toml (the bundled service config turned to real devices: the chosen backend, the
step/dir bridge or the CAN adapter under the stable device names of docs/service.md's udev rules,
no simulated devices, the spindle VFD and the strain DAQ off until their addresses are filled in,
the state file under /var/lib/pmctl), DIR/machine.toml (the bundled machine config, to be measured
and edited; ``pmctl calibrate`` writes a calibrated one) and DIR/pmctl.env (the console device for the
systemd unit). Each file starts with what to check before the first run. Both configs are loaded
back and validated before anything is written; existing files are refused unless --force.
"""

from __future__ import annotations

BACKENDS = ("stepdir", "canopen")
CONSOLE_DEVICE = "/dev/pmctl-console"     # docs/service.md: the udev rule's stable names
BRIDGE_DEVICE = "/dev/pmctl-bridge"


def add_parser(sub):
    p = sub.add_parser("init-config", help="write a commented starting config for real hardware (stepdir or canopen)",
                       description="Write DIR/service.toml, DIR/machine.toml and DIR/pmctl.env: a starting "
                                   "configuration for a controller PC with real drives, to be checked and edited "
                                   "(docs/service.md). Install it as /etc/pmctl/ for the systemd unit.",
                       epilog="Exit status: 0 written, 1 refused (files exist without --force, or DIR missing), 2 usage.")
    p.add_argument("--backend", required=True, choices=BACKENDS,
                   help="stepdir: the step/dir bridge on a serial port; canopen: CiA 402 drives on a CAN adapter")
    p.add_argument("dir", metavar="DIR", help="folder to write into (e.g. /etc/pmctl); it must exist")
    p.add_argument("--force", action="store_true", help="replace files that exist")
    p.set_defaults(func=run)


def _replace(text: str, section: str, key: str, value: str, note: str = "") -> str:
    """``key = value`` in ``[section]`` of the bundled file, the rest of the line's comment replaced
    by ``note`` when given (the line must exist: a changed bundled file fails loudly here)."""
    import re
    head = re.search(rf"^\[{re.escape(section)}\][^\n]*\n", text, re.M)
    if head is None:
        raise ValueError(f"[{section}] not in the bundled service config")
    end = re.search(r"^\[", text[head.end():], re.M)
    stop = head.end() + (end.start() if end else len(text[head.end():]))
    body = text[head.end():stop]
    m = re.search(rf"^{re.escape(key)}\s*=\s*[^#\n]*?(\s*#[^\n]*)?$", body, re.M)
    if m is None:
        raise ValueError(f"{section}.{key} not in the bundled service config")
    comment = m.group(1) or ""
    if note:
        comment = f"  # {note}"
    line = f"{key} = {value}{comment}"
    return text[:head.end()] + body[:m.start()] + line + body[m.end():] + text[stop:]


def service_text(backend: str, bundled: str) -> str:
    import datetime
    t = bundled
    t = _replace(t, "loop", "state_file", '"/var/lib/pmctl/counters.json"',
                 "the unit passes --state with the same file (StateDirectory=pmctl)")
    t = _replace(t, "hal", "backend", f'"{backend}"', "real drives: see the section of this backend below")
    # both real backends, whichever is selected (switching [hal] backend later finds no simulation)
    t = _replace(t, "hal.stepdir", "port", f'"{BRIDGE_DEVICE}"',
                 "the bridge's serial port, a stable name from the udev rule (docs/service.md)")
    t = _replace(t, "hal.stepdir", "bridge_rt_priority", "0", "host-pty only (a board runs on its own)")
    t = _replace(t, "hal.stepdir", "home_switch_mm", "[]", "host-pty only: a board reads its home inputs")
    t = _replace(t, "hal.canopen", "interface", '"socketcan"',
                 "a CAN adapter with a kernel driver (slcan: a serial adapter, channel = its device)")
    t = _replace(t, "hal.canopen", "channel", '"can0"',
                 "ip link set can0 up type can bitrate 1000000 (docs/service.md)")
    t = _replace(t, "hal.canopen", "simulate", "false", "real drives on the bus")
    t = _replace(t, "spindle", "enabled", "false", "true once transport/host/serial_port below are your VFD's")
    t = _replace(t, "spindle", "simulate", "false", "a real VFD")
    t = _replace(t, "spindle", "port", "502", "Modbus TCP's port")
    t = _replace(t, "daq", "enabled", "false", "true once host/port below are your DAQ's")
    t = _replace(t, "daq", "simulate", "false", "a real DAQ")
    t = _replace(t, "daq", "port", "502", "Modbus TCP's port")
    head = (f"# pmctl service config for backend {backend}, written by `pmctl init-config` on "
            f"{datetime.date.today().isoformat()}.\n"
            "# A starting point, not a tested machine. Before the first run (docs/service.md):\n"
            "#  - the device names: the udev rules give the console, the bridge and the CAN adapter stable names;\n"
            "#  - [nc] gains and [loop] rate_hz: measure the loop's latency on this PC first;\n"
            "#  - [homing]: where your switches are (reference_mm) and which way they close;\n"
            "#  - [spindle] and [daq]: enable them with your devices' addresses (Modbus TCP or RTU);\n"
            "#  - the machine config next to this file: measure it (pmctl calibrate writes a calibrated one).\n"
            "# The [hal.sim] table is kept for `pmctl run --backend sim --service THIS` dry runs.\n\n")
    return head + t


def run(args) -> int:
    import os
    from pathlib import Path

    from pmctl.core.config import CONFIG_DIR, load_machine
    from pmctl.core.errors import PmctlError
    from pmctl.motion.service_config import load_service_config
    out = Path(args.dir)
    if not out.is_dir():
        raise PmctlError(f"{out}: no such folder (create it first, e.g. mkdir -p /etc/pmctl)")
    files = {"service.toml": service_text(args.backend, (CONFIG_DIR / "service.toml").read_text()),
             "machine.toml": ("# pmctl machine config, written by `pmctl init-config` from the bundled prototype.\n"
                              "# Its geometry, limits and resolutions are the prototype's: measure and edit them for\n"
                              "# your machine (docs/machine.md); `pmctl calibrate` writes a calibrated config.\n\n"
                              + (CONFIG_DIR / "prototype.toml").read_text()),
             "pmctl.env": ("# Settings of the systemd unit (systemd/pmctl.service), read as EnvironmentFile.\n"
                           f"# The console: a serial device (a stable name from the udev rule), or pty:/run/pmctl/tty\n"
                           f"# (a pty under RuntimeDirectory=, visible to senders outside the unit: docs/service.md).\n"
                           f"PMCTL_CONSOLE={CONSOLE_DEVICE}\n")}
    existing = [n for n in files if (out / n).exists()]
    if existing and not args.force:
        raise PmctlError(f"{out}: {', '.join(existing)} exist; add --force to replace them")
    tmp = {}
    try:
        for name, text in files.items():          # checked before anything is written
            tmp[name] = out / f".{name}.init-config"
            tmp[name].write_text(text)
        svc = load_service_config(tmp["service.toml"])
        machine = load_machine(tmp["machine.toml"])
        if svc.backend != args.backend:
            raise PmctlError(f"internal: the written service config selects {svc.backend}")
        for name, p in tmp.items():
            os.replace(p, out / name)
    finally:
        for p in tmp.values():
            if p.exists():
                p.unlink()
    print(f"wrote {out / 'service.toml'} (backend {args.backend}), {out / 'machine.toml'} ({machine.name}) and "
          f"{out / 'pmctl.env'}: check them before the first run (docs/service.md)")
    return 0
