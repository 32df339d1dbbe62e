"""`pmctl serve`: the controller as a long-running service (the rt motion process + the supervisor).

    pmctl serve --config config/prototype.toml --backend sim --console pty:LINK
                [--record DIR] [--state FILE] [--socket PATH] [--no-realtime]

The machine is driven from the grbl 1.1 console (``--console pty:LINK`` creates a pty and links
LINK to it; ``--console /dev/ttyUSB0`` uses a serial device) and from the control socket. SIGTERM
or Ctrl-C: feed hold on the path, position saved, recording finalised, exit 0.
"""

from __future__ import annotations


def add_parser(sub):
    p = sub.add_parser("serve", help="run the controller as a service: grbl console, control socket, state journal",
                       description="Run the controller: the rt motion process and the supervisor, with the grbl "
                                   "1.1 console and the control socket.",
                       epilog="The systemd unit runs it with --service /etc/pmctl/service.toml --config "
                              "/etc/pmctl/machine.toml (pmctl init-config writes both; docs/service.md). Exit "
                              "status: 0 stopped on request (SIGTERM, Ctrl-C: position saved), 1 refused at "
                              "start-up (a flag, a config, the state file), 2 usage.")
    p.add_argument("--config", default="prototype", help="machine config (default: the bundled prototype)")
    p.add_argument("--service", default=None, help="service config (default: the bundled service.toml)")
    p.add_argument("--backend", default=None, help="HAL backend (default: from the service config; 'sim')")
    p.add_argument("--console", default=None, metavar="pty:LINK|DEVICE",
                   help="grbl console: 'pty:LINK' creates a pty and symlinks LINK to it; a path opens a serial device")
    p.add_argument("--socket", default=None, metavar="PATH", help="control socket (Unix, JSON lines; mode 0660); its folder must exist")
    p.add_argument("--record", metavar="DIR", default=None, help="record the session into this folder")
    p.add_argument("--state", default=None, metavar="FILE",
                   help="pulse-counter state file (default: service config); the journal is FILE.journal")
    p.add_argument("--rate", type=float, default=None, metavar="HZ", help="tick rate (default: service config)")
    p.add_argument("--no-realtime", action="store_true",
                   help="no real-time priority or memory locking (ticks still keep time)")
    p.set_defaults(func=run)


def run(args) -> int:
    from pmctl.core.errors import PmctlError
    from pmctl.motion.service_config import load_service_config
    from pmctl.task.daemon import Daemon

    if args.rate is not None and not 10 <= args.rate <= 20000:
        raise PmctlError(f"--rate must be within 10 .. 20000 Hz, got {args.rate:g}")
    # every flag is checked before anything starts (no rt process, the state file untouched)
    from pmctl import hal
    if args.backend is not None and args.backend not in hal.BACKENDS:
        raise PmctlError(f"--backend {args.backend!r}: unknown backend; known: {', '.join(sorted(hal.BACKENDS))}")
    if args.record:
        from pmctl.core.recording import check_target
        check_target(args.record, force_flag=None)          # serve never replaces a recording (nor a .partial)
    if args.console:
        from pmctl.interfaces.console.port import check_console_spec
        check_console_spec(args.console)
    if args.socket:
        from pmctl.interfaces.console.control import check_socket_path
        check_socket_path(args.socket)
    svc = load_service_config(args.service)
    state = svc.loop.state_file if args.state is None else args.state
    d = Daemon(config=args.config, service=args.service, backend=args.backend, state_file=state,
               record_dir=args.record, console=args.console, realtime=not args.no_realtime and svc.loop.realtime,
               rate_hz=args.rate, socket_path=args.socket)
    d.catch_stop_signals()
    try:
        d.start()
    except BaseException:
        if d.sup is not None and d.sup.ch is not None:
            d.sup.shutdown("start-up failed")
        raise
    return d.serve_forever()
