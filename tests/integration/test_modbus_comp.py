"""Slow compensation from the strain DAQ (issue 11, deliverable 4), with real parts: the simulated
DAQ is a pymodbus server on 127.0.0.1 (in the device simulator) serving the sim plant's gauges,
polled over Modbus TCP; the loop runs the compiled NC against the sim plant, paced in real time
(the DAQ polls on the wall clock).

The plant here has chains that stretch under load: load-side length = motor side + tension /
stiffness (tension from the plant's own gauges: the platform's weight and a constant force on the
tool tip). With ``compensate = true`` the NC takes offset = -deflection per chain: the commanded
chain lengths move by the deflection and the true tool tip comes back onto the target."""

import time

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import ConfigError
from pmctl.hal.modbus_daq import DaqOptions, DaqSession, chain_deflection_mm
from pmctl.hal.sim import SimBackend
from pmctl.motion.loop import ControlLoop, build_targets
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.recorder import R_CHAIN_OFFSET, R_COUNTS, R_TICK, R_TRUTH
from pmctl.motion.service_config import LoopConfig, service_from_dict

from test_modbus import run_with_daq

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()
DT = 1e-3
TIP_FORCE = (300.0, 0.0, 1000.0)       # N on the tool tip: chains stretched by 10-15 um


class CompliantChains(SimBackend):
    """The sim plant with the static compliance of its chains: each chain's load-side length is
    the motor side plus its elongation, tension / axial stiffness (tension = gauge strain / gain)."""

    def truth(self):
        q = super().truth()
        q[:3] += chain_deflection_mm(self._fb.strain, self.machine)
        return q


def dwell(seconds):
    """Targets holding the home pose (tool vertical) for ``seconds``."""
    tip, axis = K.tool_of_platform(*K.forward_platform(np.full(3, M.geometry.z_home), M.geometry),
                                   np.zeros(2), M.geometry)
    n = int(round(seconds / DT))
    p = params()
    return build_targets(np.repeat([tip], n, 0), np.repeat([axis], n, 0), np.zeros(n, int), DT, M, p)


def params(**kw):
    return NCParams.from_machine(M, DT, kv=400.0, **kw)


def run_compensated(daq_opts, seconds, *, inject_at=None, inject=None, p=None, when=None):
    """One paced run of a dwell on the compliant plant with the DAQ's slow compensation wired to
    the loop as ``pmctl run`` does. Returns (result, rows, c0, session, log lines). ``when(lp, ses, logs)``:
    ``inject`` waits for that evidence instead of a tick (the tick it came at is ``session.injected_at``)."""
    p = p or params(chain_offset_max_mm=daq_opts.comp_max_mm, chain_offset_rate_mm_s=daq_opts.comp_rate_mm_s)
    tg = dwell(seconds)
    c0 = counts_of(tg.q[0], p)
    be = CompliantChains(M, DT, {"tip_force_N": list(TIP_FORCE)})
    be.open(c0)
    logs = []
    cfg = LoopConfig(rate_hz=1000, realtime=True, lock_memory=False, stall_timeout_s=5.0, max_overruns_in_row=10**6,
                     settle_s=0.0)
    holder = {}
    # the DAQ serves the gauges as the loop last read them, copied in the loop's thread after each
    # tick (the sim adds the tip force's strain after its C step: read from another thread, its
    # feedback can be caught half-updated)
    gauges = [be._fb.strain.copy()]

    def copy_gauges(lp, k, st):
        gauges[0] = be._fb.strain.copy()
        return st
    ses = DaqSession(daq_opts, lambda: gauges[0].tolist(), logs.append, M,
                     lambda off: holder["lp"].set_chain_offsets(off)).connect()
    lp = ControlLoop(M, be, p, tg, cfg, initial_state(M, c0), log=logs.append, hook=copy_gauges)
    holder["lp"] = lp
    if when is not None:                  # inject on evidence, not at a tick (a loaded machine polls late)
        first = inject

        def inject(dev):
            while not when(lp, ses, logs) and lp.mode == 0:
                time.sleep(0.002)
            ses.injected_at = lp.tick
            first(dev)
        inject_at = 0
    res = run_with_daq(lp, ses, inject_at, inject)
    return res, lp.recorder.arrays(), c0, ses, logs, p


def tip_error_um(rows, p, tg_tip):
    pose, ok = K.fk_batch(rows[:, R_TRUTH:R_TRUTH + 5], M)
    assert np.all(ok)
    return np.linalg.norm(pose.tip - tg_tip, axis=-1) * 1e3


def test_compensation_shifts_the_chains_by_the_deflection_and_the_tip_error_falls():
    opt = DaqOptions.from_dict({"simulate": True, "port": 0, "timeout_ms": 100.0, "poll_ms": 10.0,
                                "max_age_ms": 60.0, "comp_tau_s": 0.05, "compensate": True,
                                "comp_max_mm": 0.05, "comp_rate_mm_s": 0.1})
    seen = []                             # (tick, estimate) as the DAQ session applied it

    def converged(lp, ses, logs):               # the estimate steady for 300 ticks, the slew long done
        if ses.offsets is not None and (not seen or seen[-1][0] != lp.tick):
            seen.append((lp.tick, np.array(ses.offsets, float)))
        big = [k for k, o in seen if np.all(np.abs(o) > 0.008)]
        recent = [o for k, o in seen if k >= lp.tick - 300]
        return bool(big) and lp.tick - big[0] > 600 and len(recent) > 20 and np.ptp(recent, axis=0).max() < 3e-4
    res, rows, c0, ses, logs, p = run_compensated(opt, 30.0, inject=lambda dev: dev.freeze(), when=converged)
    # the stale DAQ stops the run as without compensation; every pulse is counted
    assert res.status == "stopped" and "stale data" in res.reason and "strain DAQ" in res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
    assert np.array_equal(rows[:, R_TICK], np.arange(len(rows)))
    # the deflection the plant's chains have (tension / stiffness) and the offset that cancels it
    inj = ses.injected_at
    k = inj - 20                               # just before the DAQ froze: the estimate had settled
    strain = res.strain[k]
    want = -chain_deflection_mm(strain, M)
    assert np.all(np.abs(want) > 0.008)                     # 10-15 um: well above a pulse (0.5 um)
    off = rows[:, R_CHAIN_OFFSET:R_CHAIN_OFFSET + 3]
    # slew-limited: no jump of the applied offset, ever; at 0.1 mm/s the 15 um take 150 ms
    assert np.max(np.abs(np.diff(off, axis=0))) <= 0.1 * DT + 1e-12
    assert np.all(np.abs(off[0]) <= 0.1 * DT + 1e-12)
    np.testing.assert_allclose(off[k], want, atol=0.5e-3)      # the estimate (0.01 ue counts, tau 50 ms)
    # the commanded chain lengths moved by the offset (within the servo's pulse or two of dither)
    cmd = rows[:, R_COUNTS:R_COUNTS + 5] / p.pulses_per_mm
    shift = cmd[k, :3] - c0[:3] / p.pulses_per_mm[:3]
    np.testing.assert_allclose(shift, off[k], atol=2.0 / p.pulses_per_mm[0])
    # the physical fact: the true tool tip (FK of the stretched chains) comes back onto the target
    tg = dwell(0.01).rows[0, :3]
    e = tip_error_um(rows, p, tg)
    before, after = float(np.max(e[:5])), float(np.max(e[inj - 300:inj - 50]))
    assert before > 8.0 and after < 0.25 * before, (before, after)
    # stale data: the last offset is held through the stop (no more estimates, no decay)
    assert len(rows) > inj + 50 and np.max(np.ptp(off[inj - 50:], axis=0)) < 1e-5
    assert ses.offsets is not None and np.allclose(ses.offsets, off[-1], atol=1e-6)


def test_an_offset_over_the_bound_is_refused_with_the_reason_and_nothing_moves():
    opt = DaqOptions.from_dict({"simulate": True, "port": 0, "timeout_ms": 100.0, "poll_ms": 10.0,
                                "max_age_ms": 60.0, "comp_tau_s": 0.05, "compensate": True,
                                "comp_max_mm": 0.005, "comp_rate_mm_s": 0.1})
    got = []

    def evidence(lp, ses, logs):                # the three refusals, then 30 more DAQ samples without another
        got[:] = [lp]
        refused = [m for m in logs if m.startswith("chain offset refused")]
        if len(refused) >= 3 and not hasattr(ses, "mark"):
            ses.mark = len(ses.daq.samples)
        return hasattr(ses, "mark") and len(ses.daq.samples) >= ses.mark + 30

    def stop(dev):
        got[0].stop_request = "the test has its evidence"
    res, rows, c0, ses, logs, p = run_compensated(opt, 60.0, inject=stop, when=evidence)
    assert res.status == "stopped" and res.reason == "the test has its evidence", res.reason
    refused = [m for m in logs if m.startswith("chain offset refused")]
    assert len(refused) == 3                                 # once per chain, not at every estimate
    assert "beyond the bound +-0.005 mm" in refused[0] and "L1 -0.01" in refused[0]
    assert np.all(rows[:, R_CHAIN_OFFSET:R_CHAIN_OFFSET + 3] == 0.0)
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
    assert np.all(np.abs(res.state.counts[:3] - c0[:3]) <= 2)


def test_without_compensate_the_estimate_is_kept_but_not_applied():
    opt = DaqOptions.from_dict({"simulate": True, "port": 0, "poll_ms": 10.0, "comp_tau_s": 0.05})
    assert opt.compensate is False
    res, rows, c0, ses, logs, p = run_compensated(opt, 0.3)
    assert len(ses.daq.deflection) > 5 and ses.offsets is None
    assert np.all(rows[:, R_CHAIN_OFFSET:R_CHAIN_OFFSET + 3] == 0.0)


@pytest.mark.parametrize("table,key", [
    ({"compensate": "yes"}, "compensate"), ({"compensate": 1}, "compensate"),
    ({"comp_max_mm": -0.1}, "comp_max_mm"), ({"comp_max_mm": 50.0}, "comp_max_mm"),
    ({"comp_rate_mm_s": 0}, "comp_rate_mm_s"), ({"comp_rate_mm_s": "0.05"}, "comp_rate_mm_s"),
    ({"comp_tau_s": float("inf")}, "comp_tau_s"), ({"port": 1.5}, "port"), ({"poll_ms": True}, "poll_ms"),
    ({"k_theta_source": "fast"}, "k_theta_source"), ({"compensat": True}, "compensat"),
    ({"host": ""}, "host")])
def test_daq_option_errors_name_the_field(table, key):
    with pytest.raises(ConfigError) as e:
        service_from_dict({"daq": {"port": 502, **table}}, "service.toml")
    assert e.value.key == key and f"service.toml: daq: {key}: " in str(e.value)


def test_daq_bound_and_slew_reach_the_nc():
    svc = service_from_dict({"daq": {"port": 502, "compensate": True, "comp_max_mm": 0.03, "comp_rate_mm_s": 0.02}})
    p = svc.nc.params(M, DT)
    assert p.chain_offset_max_mm == 0.03 and p.chain_offset_rate_mm_s == 0.02
    assert service_from_dict({}).nc.params(M, DT).chain_offset_max_mm == 0.2     # the default bound


def test_supervisor_sets_a_chain_offset_through_the_rt_process(tmp_path):
    """The daemon's path: Supervisor.set_chain_offset -> C_CHAIN_OFFSET on the channel -> the rt
    process's loop: at rest the L2 counter moves by the offset, recorded per tick; over the bound
    is refused in the supervisor with the reason."""
    from pmctl.motion import channel as C
    from pmctl.task.supervisor import Supervisor
    logs = []
    s = Supervisor("prototype", realtime=False, log=logs.append)
    tip, ax = K.tool_of_platform(*K.forward_platform(np.full(3, M.geometry.z_home), M.geometry), np.zeros(2),
                                 M.geometry)
    c0 = counts_of(K.ik(tip, ax, s.machine).q, s.params)
    rows = []
    s.record_sink = rows.append
    s.start(c0)
    try:
        assert not s.set_chain_offset(1, 0.5)                 # bound 0.2 mm (the default)
        assert "chain offset refused" in logs[-1] and "0.2 mm" in logs[-1]
        seq0 = s.ch._cmd_seq
        assert s.set_chain_offset(1, 0.02)
        assert s.wait_ack(seq0 + 1, 30.0)
        t0 = time.monotonic()            # 0.02 mm at 0.05 mm/s: 0.4 s of ramp, then the servo settles
        while time.monotonic() - t0 < 30.0 and not (rows and rows[-1][-1, R_CHAIN_OFFSET + 1] == 0.02):
            time.sleep(0.05)
        time.sleep(0.3)
        d = (s.counts() - c0) / s.params.pulses_per_mm
        assert abs(d[1] - 0.02) <= 2.0 / s.params.pulses_per_mm[1] + 1e-9, d
        assert np.all(np.abs(d[[0, 2]]) <= 2.0 / s.params.pulses_per_mm[0] + 1e-9), d
    finally:
        s.shutdown()
    a = np.concatenate(rows)
    off = a[:, R_CHAIN_OFFSET:R_CHAIN_OFFSET + 3]
    assert off[-1, 1] == pytest.approx(0.02) and np.all(off[:, [0, 2]] == 0.0)
    assert np.max(np.abs(np.diff(off[:, 1]))) <= s.params.chain_offset_rate_mm_s * s.dt + 1e-12
    assert C.C_CHAIN_OFFSET > C.C_HOME_ARM


def test_pmctl_run_with_compensate_records_the_applied_offsets(tmp_path):
    """`pmctl run --record` on the sim with the shipped service config and compensate = true: the
    recording has comp_L1..3, slew-limited, bounded, on the side that cancels the chains' static
    deflection (the platform's weight compresses them: the offset is positive), and loads as
    before with them as extra columns."""
    import subprocess
    import sys

    from pmctl.core.config import CONFIG_DIR
    from pmctl.core.recording import read_recording
    job = tmp_path / "j.ngc"
    job.write_text("G17 G21 G90 G94\nF300\nG1 X2 Y0 Z172\nG4 P1\nG1 X0\nM2\n")      # near home (z 172.75)
    svc = tmp_path / "service.toml"
    text = (CONFIG_DIR / "service.toml").read_text()
    assert "compensate = false" in text and "stall_timeout_ms = 50 " in text
    svc.write_text(text.replace("compensate = false", "compensate = true")
                   .replace("stall_timeout_ms = 50 ", "stall_timeout_ms = 5000 "))
    rec = tmp_path / "rec"
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "run", "--backend", "sim", "--job", str(job),
                        "--record", str(rec), "--state", "", "--quiet", "--no-realtime", "--service", str(svc)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    R = read_recording(rec)
    assert {"comp_L1", "comp_L2", "comp_L3"} <= set(R.unknown_columns)
    off = np.stack([R.columns[f"comp_L{i}"] for i in (1, 2, 3)], -1)
    assert np.max(np.abs(np.diff(off, axis=0))) <= 0.05 / 1000 + 1e-12       # comp_rate_mm_s at 1 kHz
    assert np.all(np.abs(off) <= 0.2)
    want = -chain_deflection_mm([-40.887] * 3, M)                          # the weight: 4.1 um of compression
    np.testing.assert_allclose(off[-1], want, atol=0.3e-3)
