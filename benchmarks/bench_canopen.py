"""Benchmark of the CANopen backend: bus load of the shipped [hal.canopen] config, computed from the
PDO map and measured on the wire, and the answer time of the simulated drives.

    .venv/bin/python benchmarks/bench_canopen.py [--seconds 5] [--link tcp|pty|virtual]
                                                 [--service config/service.toml]
    .venv/bin/python benchmarks/bench_canopen.py --tick [--rounds 3] [--link tcp|pty|virtual]

``--link``: the simulated drives in the device-simulator process on an slcan link over loopback
TCP (default, as shipped) or a pty, or in this process on the python-can virtual bus.

1. Computed: the backend's own figure (SYNC + RPDO + TPDO per drive per cycle, 47 + 8n bits per
   frame, 20 % stuffing budget, plus heartbeats) for the shipped cycle, and the same map at every
   cycle of 1 .. 4 NC ticks.
2. Measured: the backend holds its position at the shipped tick rate in real time (SCHED_FIFO when
   permitted) for --seconds, driving the simulated drives; a listener on the same wire (a second
   slcan link of the device simulator, or the virtual channel) records every frame. Per CAN cycle: frames, nominal bits, and the exact bits on the
   wire (each frame's real stuff bits), and the load they make at the configured bit rate.
3. Answer time: SYNC to the last drive's TPDO, as seen by the listener (median, p99, max).
4. ``--tick``: instead, the control loop's tick compute (read -> follower -> NC -> write -> record,
   ``pmctl run``'s figure) on this backend in real time at the service's rate, a ~5 s job near home,
   for the backend's cycle as it is ("after": RPDOs packed with struct into can.Messages built
   once; on an slcan link the cycle's frames in one write by the backend's writer thread) and as
   it was ("before": each RPDO
   through the canopen PDO map's variables and transmit, the SYNC through canopen's SYNC
   producer, one send per frame), alternating, --rounds each, in one run: median / p99 per
   variant over all rounds and per round, with the load average.
5. ``--rtt``: instead, the round trip of one slcan line between two processes at SCHED_FIFO (when
   permitted) over a pty and over loopback TCP: why the device simulator's link is TCP.
Prints the figures and the load average; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from collections import Counter

import can
import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

from pmctl import hal
from pmctl.core.config import load_machine
from pmctl.hal import cia402 as C
from pmctl.hal.canopen_csp import HISTORY, RPDO_BYTES, TPDO_BYTES, CanopenCSP, CanopenOptions
from pmctl.hal.slcan_link import SlcanLinkBus
from pmctl.motion.loop import AbsoluteSleeper, setup_realtime, undo_realtime
from pmctl.motion.service_config import load_service_config


def link_rtt(kind: str, n: int = 3000) -> np.ndarray:
    """Round trips (ms) of an 18-byte slcan line echoed by a child process, over a pty or TCP."""
    import socket
    import tty
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(52))
    except OSError:
        pass
    if kind == "pty":
        a_fd, b_fd = os.openpty()
        tty.setraw(b_fd)
        keep = ()
    else:
        srv = socket.create_server(("127.0.0.1", 0))
        c = socket.create_connection(srv.getsockname())
        d, _ = srv.accept()
        for x in (c, d):
            x.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        a_fd, b_fd, keep = c.fileno(), d.fileno(), (srv, c, d)
    pid = os.fork()
    if pid == 0:
        while True:
            x = os.read(b_fd, 100)
            if not x or x == b"q":
                os._exit(0)
            os.write(b_fd, x)
    line = b"t1816AABBCCDDEEFF\r"
    rt = []
    for _ in range(n):
        t0 = time.perf_counter()
        os.write(a_fd, line)
        got = 0
        while got < len(line):
            got += len(os.read(a_fd, 100))
        rt.append(time.perf_counter() - t0)
        time.sleep(0.001)
    os.write(a_fd, b"q")
    os.waitpid(pid, 0)
    del keep
    return np.array(rt) * 1e3


class PdoMachineryCSP(CanopenCSP):
    """The backend with its cycle sent the way it was before the direct frame packing (the
    "before" of --tick): each RPDO through its canopen PdoMap (variables, transmit), the SYNC
    through canopen's SyncProducer, the host heartbeat by Network.send_message; one bus send per
    frame. The same frames on the wire."""

    def _send_cycle(self):
        import struct
        net = self.network
        self._sent[(self._syncs + 1) % HISTORY] = self._targets
        for i, d in enumerate(self.drives):
            rp = d.rpdo
            struct.pack_into("<iH", rp.data, 0, int(self._targets[i]), self._cw)
            rp.transmit()
        net.sync.transmit()
        self._syncs += 1
        self.frames_sent += len(self.drives) + 1
        self._host_heartbeat()


BENCH_JOB = """G21 G90 G94 F900
G1 X6 Y0
G3 X0 Y6 I-6 J0
G3 X-6 Y0 I0 J-6
G3 X0 Y-6 I6 J0
G3 X6 Y0 I0 J6
G1 X0 Y0
"""


def tick_compute(a, o, svc) -> int:
    """§4: the loop's tick compute with the backend's cycle as it is and as it was."""
    from pmctl.core import kinematics as K
    from pmctl.motion.loop import ControlLoop, prepare
    from pmctl.motion.nc import counts_of, initial_state
    from pmctl.motion.service_config import nc_setup
    from pmctl.task.gcode import parse_gcode
    from pmctl.task.planner import home_pose, plan
    m = load_machine()
    dt = svc.loop.dt
    setup = nc_setup(svc, m, dt, "canopen")     # K_theta off: this backend carries no strain
    params = svc.nc.params(m, dt, where=svc.source, modes=setup.modes)
    tip, axis = home_pose(m)
    tr = plan(parse_gcode(BENCH_JOB, "bench.ngc", tip, axis), m, dt, start=(tip, axis))
    c0 = counts_of(K.ik(tip, axis, m).q, params)
    tg = prepare(m, params, tr, dt, c0)
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f} on "
          f"{os.cpu_count()} CPUs; link {a.link}; NC tick {dt * 1e3:g} ms, CAN cycle {o.cycle_ms:g} ms; "
          f"job {len(tg.rows) * dt:.1f} s, {a.rounds} rounds per variant, alternating")
    out = {"before": [], "after": []}
    for r in range(a.rounds):
        for name, cls in (("before", PdoMachineryCSP), ("after", CanopenCSP)):
            be = cls(m, dt, o)
            be.open(c0)
            cfg = svc.loop
            cfg.realtime, cfg.settle_s, cfg.state_file = True, 0.0, ""
            msgs = []
            la0 = os.getloadavg()[0]
            try:
                res = ControlLoop(m, be, params, tg, cfg, initial_state(m, c0), log=msgs.append).run()
            finally:
                be.close()
            c = res.timing.compute_ns / 1e3
            out[name].append(c)
            cyc = c[0::be.cycle_ticks]           # the ticks that send a cycle (and take its answers)
            print(f"  round {r + 1} {name:6s}: {res.status}; tick compute median {np.median(c):6.1f} us, "
                  f"p99 {np.percentile(c, 99):7.1f} us, max {c.max():7.0f} us (ticks with a CAN cycle: median "
                  f"{np.median(cyc):6.1f} us); overruns {res.timing.overruns}; "
                  f"load average {la0:.2f} -> {os.getloadavg()[0]:.2f}")
    for name in ("before", "after"):
        c = np.concatenate(out[name])
        print(f"{name:6s} ({'canopen PDO map + SyncProducer, a send per frame' if name == 'before' else 'direct packing; slcan: one write per cycle by the writer thread'}): "
              f"tick compute median {np.median(c):6.1f} us, p99 {np.percentile(c, 99):7.1f} us over {len(c)} ticks")
    b, f = (np.concatenate(out[k]) for k in ("before", "after"))
    print(f"after / before: median {np.median(f) / np.median(b):.2f}, p99 {np.percentile(f, 99) / np.percentile(b, 99):.2f}; "
          f"load average after {os.getloadavg()[0]:.2f}")
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--service", default=None)
    ap.add_argument("--link", choices=("tcp", "pty", "virtual"), default="tcp")
    ap.add_argument("--rtt", action="store_true", help="round trip of an slcan line over a pty and over TCP")
    ap.add_argument("--tick", action="store_true",
                    help="the loop's tick compute with the backend's cycle as it is and as it was")
    ap.add_argument("--rounds", type=int, default=3, help="--tick: rounds per variant (default 3)")
    a = ap.parse_args(argv)
    if a.rtt:
        print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f} on "
              f"{os.cpu_count()} CPUs")
        for kind in ("pty", "tcp"):
            r = link_rtt(kind)
            print(f"{kind}: round trip of one slcan line between two processes: median {np.median(r):.3f} ms, "
                  f"p99 {np.percentile(r, 99):.2f} ms, p99.9 {np.percentile(r, 99.9):.2f} ms, max {r.max():.2f} ms "
                  f"({len(r)} trips)")
        return 0
    svc = load_service_config(a.service)
    table = dict(svc.backend_tables.get("canopen", {}))
    if a.link == "virtual":
        table.update(simulate=True, channel="pmctl-bench-canopen", interface="virtual")
    else:
        table.update(simulate=True, channel="devsim", interface="slcan", sim_link=a.link)
    o = CanopenOptions.from_dict(table)
    if a.tick:
        return tick_compute(a, o, svc)
    dt = svc.loop.dt
    bl = o.bus_load()
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f} on "
          f"{os.cpu_count()} CPUs")
    print(f"shipped config: {len(o.node_ids)} drives, {o.bitrate / 1000:g} kbit/s, NC tick {dt * 1e3:g} ms, "
          f"CAN cycle {o.cycle_ms:g} ms = {o.cycle_ms / (dt * 1e3):g} ticks")
    print(f"computed: {bl.text}")
    for k in (1, 2, 3, 4):
        b = C.bus_load(len(o.node_ids), RPDO_BYTES, TPDO_BYTES, k * dt, o.bitrate, heartbeat_s=o.heartbeat_ms / 1e3,
                       host_heartbeat_s=o.host_heartbeat_ms / 1e3)
        verdict = "refused (> 70 %)" if b.load > C.MAX_BUS_LOAD else "accepted"
        print(f"  cycle {k * dt * 1e3:g} ms ({k} ticks): {b.load * 100:6.1f} %  {verdict}")

    m = load_machine()
    be = hal.create("canopen", m, dt, o)
    counts = np.rint(np.array([250.0, 250.0, 250.0, 0.0, 0.0]) * m.resolution.pulses_per_mm).astype(np.int64)
    be.open(counts)
    if a.link == "virtual":
        lis = can.Bus(interface="virtual", channel=o.channel)
        where = "the virtual bus (one process)"
    else:
        # a second loopback TCP link into the device simulator's hub, like the backend's own
        lis = SlcanLinkBus(f"socket://127.0.0.1:{be.devsim.info['can_tcp_port']}", o.bitrate)
        where = (f"slcan links between processes (the backend's over {a.link}, the listener's over tcp; "
                 f"device simulator at SCHED_FIFO {o.sim_rt_priority} when permitted)")
    frames = []
    stop = threading.Event()

    def rx():
        while not stop.is_set():
            msg = lis.recv(0.05)
            if msg is not None:
                frames.append((time.monotonic(), msg.arbitration_id, bytes(msg.data)))
    t = threading.Thread(target=rx, daemon=True)
    t.start()
    time.sleep(0.2)
    q = counts / m.resolution.pulses_per_mm
    n_ticks = int(a.seconds / dt)
    msgs = setup_realtime(50, lock_memory=False)
    sleeper = AbsoluteSleeper()
    t_start = time.monotonic()
    i0 = len(frames)
    faults = ""
    try:
        deadline = time.monotonic_ns() + int(dt * 1e9)
        for k in range(n_ticks):
            sleeper.until(deadline)
            deadline += int(dt * 1e9)
            be.read()
            be.write_positions(q)
    except hal.HalError as e:
        faults = str(e)
    finally:
        undo_realtime(False)
        t_end = time.monotonic()
        be.close()
        time.sleep(0.1)
        stop.set()
        t.join()
        lis.shutdown()
    print(msgs[0])
    run = [f for f in frames[i0:] if t_start <= f[0] <= t_end]
    syncs = [i for i, f in enumerate(run) if f[1] == C.COB_SYNC]
    if len(syncs) < 3:
        print(f"too few SYNCs measured ({len(syncs)}); fault: {faults}")
        return 1
    body = run[syncs[0]:syncs[-1]]
    cycles = len(syncs) - 1
    kinds = Counter()
    for _, cid, _d in body:
        kinds["SYNC" if cid == 0x80 else "RPDO" if 0x200 < cid < 0x280 else "TPDO" if 0x180 < cid < 0x200
              else "heartbeat" if 0x700 < cid < 0x780 else "EMCY" if 0x80 < cid < 0x100 else "other"] += 1
    nominal = sum(C.frame_bits_nominal(len(d)) for _, _, d in body)
    exact = sum(C.frame_bits_stuffed(cid, d) for _, cid, d in body)
    wall = body[-1][0] - body[0][0]
    cyc_s = o.cycle_ms / 1e3
    print(f"measured on {where} over {cycles} cycles ({wall:.2f} s wall): "
          + ", ".join(f"{v / cycles:.2f} {k}" for k, v in sorted(kinds.items())) + " per cycle")
    print(f"  {len(body) / cycles:.2f} frames per cycle, {nominal / cycles:.1f} nominal bits per cycle, "
          f"{exact / cycles:.1f} bits per cycle with the real stuff bits (+{(exact / nominal - 1) * 100:.1f} %)")
    print(f"  load at {o.bitrate / 1000:g} kbit/s and a {o.cycle_ms:g} ms cycle: {exact / cycles / cyc_s / o.bitrate * 100:.1f} % "
          f"(computed budget {bl.load * 100:.1f} %); the same frames in a 1 ms cycle: "
          f"{exact / cycles / 1e-3 / o.bitrate * 100:.1f} %")
    print(f"  SYNC rate on the wire: {cycles / wall:.1f} Hz (nominal {1 / cyc_s:g} Hz)")
    lat = []
    for a_, b_ in zip(syncs[:-1], syncs[1:]):
        tp = [f[0] for f in run[a_ + 1:b_] if 0x180 < f[1] < 0x200]
        if len(tp) == len(o.node_ids):
            lat.append(max(tp) - run[a_][0])
    if lat:
        la = np.array(lat) * 1e3
        print(f"answer time SYNC -> last TPDO (listener clock): median {np.median(la):.3f} ms, "
              f"p99 {np.percentile(la, 99):.3f} ms, max {la.max():.3f} ms over {len(la)} cycles")
    if faults:
        print(f"run ended early: {faults}")
    print(f"load average after {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
