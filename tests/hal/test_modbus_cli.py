"""The simulated spindle VFD and strain DAQ checked with an independent Modbus client: the `modbus`
command of the modbus-cli package (a separate process, on the uModbus protocol library, which shares
no code with pymodbus), against the same registers read with pymodbus's own client.

Asserted (protocol facts, loopback only): the Huanyang GT map read by both clients gives the same
values, and the values a VFD at 8000 rpm must hold (set-point 3333 of 10000 x 400 Hz, output
frequency 133.32 Hz in 0.01 Hz, speed 7999 rpm, no fault, command = run forward); commands written
by modbus-cli (function 06) stop and reverse the VFD; a register outside the map is exception 2
(illegal data address) for both clients; the DAQ's input registers (function 04) hold the three
gauges as signed counts of 0.01 microstrain, the same for both clients, and a sample counter that
modbus-cli reads between two pymodbus reads lies between them."""

from __future__ import annotations

import ast
import subprocess
import sys
import time

import pytest

from pmctl.hal.modbus_daq import DaqOptions, DaqSession
from pmctl.hal.modbus_vfd import SpindleVFD, VfdOptions, simulated

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

try:
    import modbus_cli  # noqa: F401
except ImportError:                     # pragma: no cover -- the test extra was not installed
    pytest.fail("modbus-cli is in the test extra: pip install -e '.[test]'", pytrace=False)


def modbus(port: int, *access: str, verbose=False) -> list[str]:
    """The `modbus` command on 127.0.0.1:port, unit 1: one line per access (its value, -S), or the
    wire bytes too (-v)."""
    flags = ["-v"] if verbose else ["-S"]
    r = subprocess.run([sys.executable, "-m", "modbus", *flags, "-s", "1", "-t", "5", f"127.0.0.1:{port}", *access],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    return [ln for ln in r.stdout.splitlines() if not ln.startswith("Parsed ")]


def values(lines: list[str]):
    return [ln if ln == "Invalid address" else ast.literal_eval(ln) for ln in lines]


def each(port: int, *access: str) -> list:
    """One `modbus` call per access. Several accesses in one call are sent as pipelined requests
    (all before the first answer), and the simulated servers (pymodbus 3.11's TCP server) answer
    only the first request of what arrives at once: the others wait for more bytes (docs/fieldbus.md)."""
    out = []
    for a in access:
        out += values(modbus(port, a))
    return out


@pytest.fixture
def vfd():
    o = VfdOptions.from_dict({"simulate": True, "port": 0, "sim_ramp_rpm_per_s": 40000.0})
    srv, dev = simulated(o)
    yield o, dev
    srv.stop()


@pytest.fixture
def pymodbus_client():
    from pymodbus.client import ModbusTcpClient
    clients = []

    def connect(port):
        c = ModbusTcpClient("127.0.0.1", port=port, timeout=2.0)
        assert c.connect()
        clients.append(c)
        return c
    yield connect
    for c in clients:
        c.close()


def _holding(c, addr):
    rr = c.read_holding_registers(addr, count=1, device_id=1)
    return ("exception", rr.exception_code) if rr.isError() else rr.registers[0]


def _wait_rpm(dev, rpm, timeout_s=10.0):
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end and abs(dev.rpm - rpm) > 0.5:
        time.sleep(0.02)


def test_vfd_registers_by_modbus_cli_equal_pymodbus(vfd, pymodbus_client):
    o, dev = vfd
    r = o.registers
    v = SpindleVFD(o).connect()
    try:
        v.start(8000)
        assert abs(v.wait_at_speed() - 8000) <= 0.02 * 8000
        _wait_rpm(dev, 3333 / 10000 * 400 * 60)            # the ramp's end: 133.32 Hz, 7999.2 rpm
        regs = [r.command, r.setpoint, r.output_freq, r.speed_rpm, r.fault]
        by_cli = each(o.port, *(f"h@{a:#x}" for a in regs))
        c = pymodbus_client(o.port)
        by_pymodbus = [_holding(c, a) for a in regs]
        assert by_cli == by_pymodbus == [r.run_forward, 3333, 13332, 7999, 0]
        # outside the map (below the speed register): illegal data address for both
        assert values(modbus(o.port, f"h@{r.speed_rpm - 1:#x}")) == ["Invalid address"]
        assert _holding(c, r.speed_rpm - 1) == ("exception", 2)
        # the request on the wire: MBAP (protocol 0, length 6, unit 1), function 03, address, count 1
        wire = modbus(o.port, f"h@{r.speed_rpm:#x}", verbose=True)
        sent = next(ln for ln in wire if ln.startswith("→"))
        assert sent.split("<")[1].split(">")[0].split()[2:] == "00 00 00 06 01 03 30 05 00 01".split()

        # commands written by modbus-cli (function 06): stop, then reverse at half the maximum frequency
        modbus(o.port, f"h@{r.command:#x}={r.stop}")
        assert dev.run == 0 and _holding(c, r.command) == r.stop
        _wait_rpm(dev, 0.0)
        modbus(o.port, f"h@{r.setpoint:#x}=5000")
        modbus(o.port, f"h@{r.command:#x}={r.run_reverse}")
        assert dev.run == -1 and dev.setpoint == 5000
        _wait_rpm(dev, 12000.0)
        by_cli = each(o.port, *(f"h@{a:#x}" for a in regs))
        assert by_cli == [_holding(c, a) for a in regs] == [r.run_reverse, 5000, 20000, 12000, 0]
        assert dev.direction == -1
    finally:
        v.close()


def test_daq_registers_by_modbus_cli_equal_pymodbus(pymodbus_client):
    strain = [12.34, -5.67, 300.0]
    o = DaqOptions.from_dict({"simulate": True, "port": 0, "timeout_ms": 100.0, "poll_ms": 10.0,
                              "max_age_ms": 60.0, "sim_sample_hz": 200.0})
    ses = DaqSession(o, lambda: strain, log=lambda m: None).connect()
    try:
        port = ses.opt.port
        c = pymodbus_client(port)

        def by_pymodbus():
            rr = c.read_input_registers(o.base, count=4, device_id=1)
            assert not rr.isError(), rr
            g = [x - 65536 if x >= 32768 else x for x in rr.registers[:3]]
            return g, rr.registers[3]

        g0, n0 = by_pymodbus()
        # gauges (signed) and counter (unsigned): contiguous, so one request, function 04, 4 registers
        gauges, counter = values(modbus(port, f"i@{o.base}/3h", f"i@{o.base + 3}/H"))
        g1, n1 = by_pymodbus()
        assert list(gauges) == g0 == g1 == [1234, -567, 30000]          # 0.01 ue counts, signed
        assert (counter - n0) % 65536 <= (n1 - n0) % 65536               # read between the two
        wire = modbus(port, f"i@{o.base}/3h", f"i@{o.base + 3}/H", verbose=True)
        sent = [ln for ln in wire if ln.startswith("→")]
        assert len(sent) == 1 and sent[0].split("<")[1].split(">")[0].split()[2:] == \
            "00 00 00 06 01 04 00 00 00 04".split()
        # past the counter: illegal data address for both
        assert values(modbus(port, f"i@{o.base + 4}")) == ["Invalid address"]
        rr = c.read_input_registers(o.base + 4, count=1, device_id=1)
        assert rr.isError() and rr.exception_code == 2
    finally:
        ses.close()
