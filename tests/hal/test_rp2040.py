"""The step/dir bridge on the RP2040: the image `make -C firmware_bridge rp2040` builds, checked by
an independent UF2/boot2 reader, and hardware-in-the-loop on that exact binary in the emulated chip
(pmctl.hal.rp2040_emu: rp2040js, simulated time). The counters the backend sees come from the pin
edges the harness records; every check below reads the pins (the edge log), not the firmware.

The emulator runs a fraction of real time: the jobs here are short (a few hundred ticks)."""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmctl import hal
from pmctl.core.config import load_machine
from pmctl.hal import bridge_protocol as bp
from pmctl.hal.rp2040_emu import FIRMWARE_DIR, ensure_built, image_paths
from pmctl.hal.stepdir import BridgeFault, HalError, StepDirBackend
from pmctl.motion.loop import ControlLoop, prepare
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.service_config import LoopConfig
from stepdir_support import EmulatedBridge, per_tick_steps
from test_loop import line_traj, rp
from test_stepdir import Injector, stream

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()
DT = 1e-3

# ---------------------------------------------------------------- an independent UF2 / boot2 reader

UF2_MAGIC0, UF2_MAGIC1, UF2_MAGIC_END = 0x0A324655, 0x9E5D5157, 0x0AB16F30
UF2_FAMILY_PRESENT = 0x00002000
RP2040_FAMILY = 0xE48BFF56
FLASH, SRAM, SRAM_END = 0x10000000, 0x20000000, 0x20042000


def crc32_mpeg2(data: bytes) -> int:
    """CRC-32/MPEG-2 written from its catalogue definition: poly 0x04C11DB7, init 0xFFFFFFFF,
    no reflection, no final xor."""
    crc = 0xFFFFFFFF
    for byte in data:
        for bit in range(7, -1, -1):
            top = (crc >> 31) ^ ((byte >> bit) & 1)
            crc = ((crc << 1) & 0xFFFFFFFF) ^ (0x04C11DB7 if top else 0)
    return crc


def read_uf2(blob: bytes) -> dict[int, bytes]:
    """{flash address: 256-byte payload} of an RP2040 UF2 file; AssertionError on anything a Pico's
    boot ROM would not take."""
    assert len(blob) % 512 == 0 and blob, "UF2 is a whole number of 512-byte blocks"
    n = len(blob) // 512
    out = {}
    for i in range(n):
        b = blob[512 * i:512 * (i + 1)]
        m0, m1, flags, addr, size, block, total, family = struct.unpack_from("<8I", b, 0)
        assert (m0, m1) == (UF2_MAGIC0, UF2_MAGIC1) and struct.unpack_from("<I", b, 508)[0] == UF2_MAGIC_END
        assert flags & UF2_FAMILY_PRESENT and family == RP2040_FAMILY, (hex(flags), hex(family))
        assert size == 256 and addr % 256 == 0 and FLASH <= addr < FLASH + (16 << 20)
        assert block == i and total == n
        assert addr not in out
        out[addr] = b[32:32 + 256]
    return out


def test_the_crc_reference_has_the_catalogue_check_value():
    assert crc32_mpeg2(b"123456789") == 0x0376E6E7


def test_the_uf2_is_an_rp2040_image_with_a_valid_boot2_and_vector_table():
    paths = ensure_built()
    flash = read_uf2(paths["uf2"].read_bytes())
    addrs = sorted(flash)
    assert addrs[0] == FLASH and addrs == list(range(FLASH, FLASH + 256 * len(addrs), 256))   # contiguous
    image = b"".join(flash[a] for a in addrs)
    binary = paths["bin"].read_bytes()
    assert image[:len(binary)] == binary and not any(image[len(binary):])     # the .bin, padded with zeros
    boot2 = image[:256]
    assert crc32_mpeg2(boot2[:252]) == struct.unpack("<I", boot2[252:])[0]    # the boot ROM's check
    sp, reset = struct.unpack_from("<II", image, 0x100)                        # the vector table after boot2
    assert SRAM < sp <= SRAM_END and sp % 8 == 0
    assert reset & 1 and FLASH + 0x100 <= reset - 1 < FLASH + len(binary)      # Thumb code in the image
    # the ELF the emulator runs is the same image: its loadable segments at their flash addresses
    elf = paths["elf"].read_bytes()
    phoff, = struct.unpack_from("<I", elf, 28)
    phentsize, phnum = struct.unpack_from("<HH", elf, 42)
    loaded = 0
    for i in range(phnum):
        ptype, off, _vaddr, paddr, filesz = struct.unpack_from("<5I", elf, phoff + i * phentsize)
        if ptype == 1 and filesz:
            assert image[paddr - FLASH:paddr - FLASH + filesz] == elf[off:off + filesz]
            loaded += filesz
    assert loaded == len(binary)


@settings(max_examples=30, deadline=None)
@given(st.binary(min_size=1, max_size=252), st.integers(0, 251), st.integers(1, 255))
def test_mkimage_boot2_crc_agrees_with_the_reference_and_catches_a_flipped_byte(tmp_path_factory, code, i, x):
    tool = ensure_built()["elf"].parent / "mkimage"
    d = tmp_path_factory.mktemp("boot2")
    (d / "b.bin").write_bytes(code)
    subprocess.run([str(tool), "boot2", str(d / "b.bin"), str(d / "o.bin")], check=True)
    out = (d / "o.bin").read_bytes()
    assert len(out) == 256 and out[:len(code)] == code
    assert struct.unpack("<I", out[252:])[0] == crc32_mpeg2(out[:252])
    bad = bytearray(out)
    bad[i] ^= x
    assert struct.unpack("<I", bad[252:])[0] != crc32_mpeg2(bytes(bad[:252]))   # CRC-32 catches it


def test_a_clean_copy_builds_boot2_and_a_missing_tool_is_named(tmp_path):
    """boot2 with its CRC from a copy without build output, byte for byte the image's first 256 bytes
    (the whole image is built from a clean clone by tests/peers/rp2040.sh); and `make rp2040` names
    the Debian package of each missing tool."""
    fw = tmp_path / "firmware_bridge"
    shutil.copytree(FIRMWARE_DIR, fw, ignore=shutil.ignore_patterns("build", "node_modules"))
    r = subprocess.run(["make", "-C", str(fw), "build/rp2040/boot2_crc.bin"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert (fw / "build/rp2040/boot2_crc.bin").read_bytes() == image_paths()["bin"].read_bytes()[:256]
    bindir = tmp_path / "bin"
    bindir.mkdir()
    for tool in ("make", "cc", "sh", "test"):
        (bindir / tool).symlink_to(shutil.which(tool, path="/usr/bin:/bin"))
    env = {**os.environ, "PATH": str(bindir)}
    r = subprocess.run(["make", "-C", str(fw), "rp2040-tools"], capture_output=True, text=True, env=env)
    assert r.returncode != 0 and "apt-get install gcc-arm-none-eabi" in r.stderr, r.stderr
    for tool in ("arm-none-eabi-gcc",):
        (bindir / tool).symlink_to(shutil.which(tool))
    r = subprocess.run(["make", "-C", str(fw), "rp2040-tools"], capture_output=True, text=True, env=env)
    assert r.returncode != 0 and "apt-get install nodejs" in r.stderr, r.stderr
    (bindir / "node").symlink_to(shutil.which("node"))
    r = subprocess.run(["make", "-C", str(fw), "rp2040-tools"], capture_output=True, text=True, env=env)
    assert r.returncode != 0 and "apt-get install npm" in r.stderr, r.stderr


# ---------------------------------------------------------------- hardware in the loop


@pytest.fixture
def chip(tmp_path):
    b = EmulatedBridge(tmp_path)
    yield b
    b.stop()


def backend(chip, **kw):
    return StepDirBackend(M, DT, chip.options(**kw.pop("options", {})), clock=chip.clock, **kw)


def test_the_chip_identifies_itself_and_a_job_through_the_loop_is_every_pulse_on_the_pins(chip):
    tr = line_traj([-3, -2, 1], [3, 2, 3], rp(2, -1), rp(-1, 2), 5.0, DT)    # within the chip's step rate
    params = NCParams.from_machine(M, DT, kv=0.4 / DT)
    tg = prepare(M, params, tr, DT, None)
    c0 = counts_of(tg.q[0], params)
    be = backend(chip)
    be.open(c0)
    assert be.ident.board == "rp2040" and be.ident.proto_version == bp.PROTO_VERSION
    cfg = LoopConfig(rate_hz=1000.0, realtime=False, stall_timeout_s=30.0)
    res = ControlLoop(M, be, params, tg, cfg, initial_state(M, c0), log=lambda m: None).run()
    be.close()                               # runs out the queue; the counters (from the pins) must match
    assert res.status == "done", res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
    s = chip.status()
    assert s.state == bp.S_IDLE and s.faults == 0
    assert np.array_equal(s.counters, res.state.counts)                # pin counts, as the harness reports them
    log = chip.edges()
    assert np.array_equal(bp.executed_steps(log), res.pulses_sent)      # every pulse sent is on the pins
    assert np.abs(res.pulses_sent).sum() > 1000
    starts = log[log["kind"] == bp.EDGE_TICK]["tick"]
    assert sorted(starts.tolist()) == list(range(len(starts)))         # each tick started once


def test_step_high_and_low_times_and_dir_setup_on_the_pins(chip):
    """From the pins, in simulated time: every pulse is high for at least the step width and low for
    at least as long before the next, the direction changes only after the last falling edge plus a
    width, and settles at least the set-up time before the next rising edge; the steps of each tick
    are exactly its pulses. Random counts with reversals, and bursts of 80 pulses a tick (the chip
    holds about 100 kstep/s in total: benchmarks/bench_rp2040.py)."""
    W, D = 2500, 5000
    be = backend(chip, options={"step_width_ns": W, "dir_setup_ns": D})
    be.open(np.zeros(5, int))
    rng = np.random.default_rng(7)
    ticks = rng.integers(-12, 13, (150, 5))
    ticks[::7] *= -1
    ticks[40:45] = [[80, -10, 5, 0, 0]] * 5                  # dense pulses on one axis ...
    ticks[45] = [-80, 10, -5, 0, 0]                          # ... and a reversal right after
    ticks = np.concatenate([ticks, np.zeros((5, 5), int)])
    stream(be, ticks)
    be.close()
    log = chip.edges()
    per_tick = per_tick_steps(log)
    for k, p in enumerate(ticks):
        assert np.array_equal(per_tick.get(k, np.zeros(5)), p), k
    for a in range(5):
        ev = log[(log["axis"] == a) & (log["kind"] != bp.EDGE_TICK)]
        t = ev["t"].astype(np.int64)
        kind = ev["kind"]
        rise, fall = t[kind == bp.EDGE_HIGH], t[kind == bp.EDGE_LOW]
        assert len(rise) == len(fall) == np.abs(ticks[:, a]).sum()
        assert np.all(fall - rise >= W)                               # high time
        assert np.all(rise[1:] - fall[:-1] >= W)                      # low time
        for j in np.flatnonzero((kind == bp.EDGE_DIR_NEG) | (kind == bp.EDGE_DIR_POS)):
            before = t[:j][kind[:j] == bp.EDGE_LOW]
            after = t[j + 1:][kind[j + 1:] == bp.EDGE_HIGH]
            if len(before):
                assert t[j] - before[-1] >= W                         # DIR held after the last pulse
            if len(after):
                assert after[0] - t[j] >= D                           # set-up before the first step
    assert np.array_equal(bp.executed_steps(log), ticks.sum(0))


def test_the_watchdog_latches_in_simulated_time_when_the_host_goes_silent(chip):
    be = backend(chip, options={"watchdog_ms": 20.0})
    be.open(np.zeros(5, int))
    stream(be, [[30, -30, 10, 5, 0]] * 100)
    # the host goes silent: no END, no STOP, no tick (the backend is simply not called again)
    t_silent = chip.clock()
    while chip.clock() < t_silent + 0.1:           # 100 ms of the chip's time
        time.sleep(0.02)
    s = chip.status()
    assert s.state == bp.S_FAULT and s.faults == bp.F_WATCHDOG and "host timeout" in s.fault_text()
    assert abs(((s.fault_us - s.last_tick_rx_us) % 2**32) - 20_000) <= 1        # the chip's own clock
    log = chip.edges()
    rises = log[log["kind"] == bp.EDGE_HIGH]["t"].astype(np.int64)
    # no step on the pins after the trip (the chip's clock is the TIMER's, within a microsecond)
    assert rises.max() / 1e3 <= s.fault_us + 2
    per_tick = np.array([30, -30, 10, 5, 0])
    assert np.array_equal(s.counters, bp.executed_steps(log))
    assert np.array_equal(np.array(s.counters) + s.not_executed, per_tick * s.next_tick)


def test_the_estop_input_stops_stepping_at_once_and_a_reset_is_refused_while_it_is_open(chip):
    be = backend(chip)
    c0 = np.array([0, 500, 0, -500, 0])
    be.open(c0)
    ticks = np.tile([20, -20, 15, 10, -8], (1000, 1))
    with pytest.raises(BridgeFault, match="E-stop input") as ei:
        for k, p in enumerate(ticks):
            if k == 60:
                chip.ctl("estop 1")
            be.read()
            be.write_pulses(p)
    be.close()
    log = chip.edges()
    executed = bp.executed_steps(log)
    assert np.array_equal(ei.value.counts, c0 + executed)                # the host's counters = the pins
    s = chip.status()
    assert s.state == bp.S_FAULT and s.faults & bp.F_ESTOP
    assert np.array_equal(np.array(s.counters) + s.not_executed, c0 + ticks[:be.next_tick].sum(0))
    rises = log[log["kind"] == bp.EDGE_HIGH]["t"].astype(np.int64)
    t_estop = int(log[(log["axis"] == 13) & (log["kind"] == 6)]["t"][0])   # the E-stop pin opening
    # the edges the loop was writing when the pin opened still go out, then nothing: the last step
    # within 50 us of simulated time after the pin opened (the loop's latency: a frame being handled)
    assert rises.max() - t_estop <= 50_000
    be2 = backend(chip)
    with pytest.raises(HalError, match="refused RESET"):
        be2.open(s.counters)
    chip.ctl("estop 0")
    t = chip.clock()
    while chip.clock() < t + 0.005:
        time.sleep(0.01)
    be2 = backend(chip)
    be2.open(s.counters)
    stream(be2, [[10, 0, 0, 0, 0]] * 20)
    be2.close()
    assert chip.status().counters[0] == s.counters[0] + 200


@pytest.mark.parametrize("seed", [3])
def test_crc_and_sequence_errors_are_retransmitted_and_no_tick_runs_twice(chip, seed):
    inj = Injector(seed, p_drop=0.05, p_dup=0.05, p_crc=0.05, p_noise=0.05, p_rx=0.03)
    be = backend(chip, options={"max_retransmits": 30}, tx_filter=inj.tx, rx_filter=inj.rx)
    c0 = np.array([7, -7, 70, -70, 700])
    be.open(c0)
    rng = np.random.default_rng(seed)
    ticks = rng.integers(-12, 13, (400, 5))
    ticks[-5:] = 0
    stream(be, ticks)
    be.close()
    assert sum(inj.counts.values()) > 40
    assert be.stats["retransmits"] > 0 and be.stats["dup_acks"] > 0          # resent, and duplicates seen
    log = chip.edges()
    starts = log[log["kind"] == bp.EDGE_TICK]["tick"]
    assert sorted(starts.tolist()) == list(range(len(ticks)))                 # each tick started once
    per_tick = per_tick_steps(log)
    for k, p in enumerate(ticks):
        assert np.array_equal(per_tick.get(k, np.zeros(5)), p), k            # with exactly its pulses
    s = chip.status()
    assert s.rx_bad > 0 and np.array_equal(s.counters, c0 + ticks.sum(0))


def test_pmctl_run_machines_a_job_through_the_emulated_chip(tmp_path):
    """pmctl run --backend stepdir --bridge rp2040-emu --no-realtime: done, the pin counts equal the
    pulses sent, and the edge log holds exactly the commanded motion."""
    import sys
    import tomllib

    from pmctl.core.config import CONFIG_DIR
    from test_stepdir_cli import _toml
    job = tmp_path / "short.ngc"
    job.write_text("G17 G21 G91 G94\nG1 X1 Y0.5 F900\nG1 X-1 Y-0.5\n")     # short moves from where it is
    svc = tomllib.loads((CONFIG_DIR / "service.toml").read_text())
    edges = tmp_path / "edges.bin"
    svc["hal"]["stepdir"].update(edge_log=str(edges))
    (tmp_path / "service.toml").write_text(_toml(svc))
    rec = tmp_path / "rec"
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "run", "--backend", "stepdir", "--bridge",
                        "rp2040-emu", "--service", str(tmp_path / "service.toml"), "--job", str(job), "--record",
                        str(rec), "--state", "", "--no-realtime", "--quiet"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "result: done" in r.stdout and "pulses sent = pulse counters: yes" in r.stdout
    from pmctl.core.recording import read_recording
    data = read_recording(rec)
    cmd = np.stack([np.asarray(data.columns[f"cmd_{a}"]) for a in bp.AXES], -1)
    log = bp.read_edge_log(edges)
    assert np.array_equal(bp.executed_steps(log), np.rint((cmd[-1] - cmd[0]) * 2000.0).astype(np.int64))
    assert np.sum(log["kind"] == bp.EDGE_HIGH) > 1000                  # it moved (there and back)
    # the shipped machine (joints to 100 mm/s) is capped to what the chip holds, 20 kstep/s per axis:
    # F900 on X (15 mm/s, 30 steps a tick) runs at 10 mm/s, never over 20 steps in a 1 ms tick
    assert "joint speeds capped at 10 mm/s" in r.stderr, r.stderr
    per_tick = np.abs(np.rint(np.diff(cmd, axis=0) * 2000.0))
    assert per_tick.max() <= 20 and per_tick[:, 3].max() >= 19


def test_rp2040_emu_needs_no_realtime(tmp_path):
    import sys
    job = tmp_path / "j.ngc"
    job.write_text("G1 X1 F100\n")
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "run", "--backend", "stepdir", "--bridge",
                        "rp2040-emu", "--job", str(job), "--state", ""], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "--no-realtime" in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "run", "--backend", "sim", "--bridge",
                        "rp2040-emu", "--job", str(job), "--state", "", "--no-realtime"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "--backend stepdir" in r.stderr, r.stderr
