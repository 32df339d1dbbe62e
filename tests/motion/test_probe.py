"""Strain touch-off in the loop (G38.2 / G38.3, pmctl.motion.probe) and the load estimate in the
recordings, on the sim plant: the whole loop, ticks back to back."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pmctl import hal
from pmctl.core import kinematics as K
from pmctl.core import strain_sensing as SS
from pmctl.core.config import load_machine
from pmctl.core.errors import ConfigError, InputError
from pmctl.core.recording import read_recording
from pmctl.motion.loop import ControlLoop, prepare
from pmctl.motion.nc import counts_of, initial_state
from pmctl.motion.probe import ProbeConfig, ProbeMonitor, check_probe_job, probe_segments
from pmctl.motion.service_config import LoopConfig, NCConfig, service_from_dict
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import home_pose
from pmctl.task.planner import plan
from service_support import service_toml

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine("prototype")
DT = 1e-3
ROOT = Path(__file__).resolve().parents[2]
PMCTL = [sys.executable, "-m", "pmctl.interfaces.cli"]
KC = 2000.0                     # contact stiffness of the simulated surface, N/mm
HOME_Z = float(home_pose(M)[0][2])


def probe_run(text, sim, cfg=ProbeConfig(), k_theta=200.0):
    """pmctl run's path without the CLI: parse, plan, preflight, the loop with a probe monitor."""
    params = NCConfig(k_theta_per_s=(k_theta,) * 3).params(M, DT)
    tip, axis = home_pose(M)
    c0 = counts_of(K.ik(tip, axis, M).q, params)
    st = initial_state(M, c0)
    job = parse_gcode(text, "p.ngc", st.tip, st.axis)
    traj = plan(job, M, DT, start=(st.tip, st.axis))
    be = hal.create("sim", M, DT, sim)
    be.open(c0)
    mon = ProbeMonitor(M, probe_segments(job, M, st.tip), cfg, DT, params)
    lp = ControlLoop(M, be, params, prepare(M, params, traj, DT, c0), LoopConfig(realtime=False, state_file="",
                                                                                  stall_timeout_s=10.0),
                     st, probe=mon)
    return lp.run(), mon, be


def _z_share():
    """Largest chain force per N of tip force along -z at home (the chain that triggers first)."""
    t, a = home_pose(M)
    P, R = K.forward_platform(K.ik(t, a, M).q[:3], M.geometry)
    return float(np.abs(SS.chain_share(P, R, M, [0, 0, 1.0])).max())


def test_g38_2_finds_a_plane_repeatably_with_a_bounded_overtravel():
    cfg = ProbeConfig()
    rng = np.random.default_rng(3)
    feed = 60.0                                       # mm/min: 1 mm/s
    v = feed / 60.0
    errs, overs = [], []
    for _ in range(6):
        zc = HOME_Z - 1.0 - rng.uniform(0.0, 0.01)   # the surface at a random phase of the pulses
        res, mon, be = probe_run(f"G21 G90\nG0 Z{zc + 0.12:.4f}\nG38.2 Z{zc - 1:.4f} F{feed:g}\n",
                                 {"flex": True, "strain_noise_ue": 0.01, "contact_z_mm": zc,
                                  "contact_stiffness_N_per_mm": KC})
        assert res.status == "done", res.reason
        (r,) = mon.results
        assert r.contact and not r.error and r.line == 3 and r.mode == 2
        rest = K.fk(be.truth(), M).tip                # where the true (load-side) tool tip came to rest
        errs.append(r.point[2] - zc)
        overs.append(zc - rest[2])
        # past the threshold crossing: the debounce, acting, the stop's ramp and its braking distance
        assert 0 <= r.after_trigger_mm <= r.bound_mm
        assert r.bound_mm == pytest.approx(v * (cfg.debounce_ticks + 5) * DT + v * v / (2 * cfg.decel_mm_s2))
        # past the true surface add the force's rise to the threshold, seen through the moving average
        bound_true = cfg.threshold_N / (_z_share() * KC) + 0.5 * (cfg.filter_ticks - 1) * v * DT + r.bound_mm
        assert 0 < overs[-1] <= bound_true
        assert np.allclose(r.point[:2], 0.0, atol=1e-6) and np.allclose(r.stop[:2], 0.0, atol=1e-6)
        assert r.prb().startswith("[PRB:0.000,0.000,") and r.prb().endswith(":1]")
    errs = np.array(errs)
    # contact point within 3 um of the plane, repeatable to 1 um (the pulse is 0.5 um, a tick 1 um;
    # benchmarks/bench_probe.py: max 2.3 um over 20 probes)
    assert np.abs(errs).max() < 3e-3, errs
    assert errs.std() < 1e-3, errs


@pytest.mark.parametrize("mode", [2, 3])
def test_no_contact_g38_2_fails_g38_3_does_not_and_nothing_goes_past_the_target(mode):
    target = HOME_Z - 0.3
    res, mon, be = probe_run(f"G21 G90\nG38.{mode} Z{target:.4f} F120\n",
                             {"flex": True, "strain_noise_ue": 0.01, "contact_z_mm": HOME_Z - 5.0})
    assert res.status == "done"
    (r,) = mon.results
    assert not r.contact and r.tick == -1
    assert bool(r.error) == (mode == 2)
    if mode == 2:
        assert "probe fail" in r.error and "line 2" in r.error
    tips, ok = K.fk_batch(res.truth, M)
    assert ok.all()
    assert tips.tip[:, 2].min() >= target - 2e-3          # within the chain modes' ringing of the target
    assert abs(r.stop[2] - target) < 1e-6 and r.prb().endswith(":0]")


def test_probe_config_is_validated_and_named():
    assert service_from_dict({}).probe == ProbeConfig()
    c = service_from_dict({"probe": {"threshold_N": 2.5, "max_feed_mm_min": 100}}).probe
    assert c.threshold_N == 2.5 and c.max_feed_mm_min == 100
    for bad, key in (({"threshold_N": 0}, "threshold_N"), ({"debounce_ticks": 0}, "debounce_ticks"),
                     ({"decel_mm_s2": "fast"}, "decel_mm_s2"), ({"tresh_N": 1.0}, "tresh_N")):
        with pytest.raises(ConfigError, match=key):
            service_from_dict({"probe": bad}, "svc.toml")


def test_pmctl_run_refuses_a_fast_probe_and_motion_after_a_probe():
    cfg = ProbeConfig(max_feed_mm_min=100)
    t, a = home_pose(M)
    fast = parse_gcode("G21 G90\nG38.2 Z150 F200\n", "p.ngc", t, a)
    with pytest.raises(InputError, match=r"p.ngc:2: .*faster than the probing limit"):
        check_probe_job(fast, cfg, "p.ngc")
    slow = parse_gcode("G21 G90\nG38.2 Z150 F80\n", "p.ngc", t, a)
    check_probe_job(slow, cfg, "p.ngc")
    with pytest.raises(InputError, match=r"p.ngc:2: .*feed override x1.5"):
        check_probe_job(slow, cfg, "p.ngc", 1.5)
    after = parse_gcode("G21 G90\nG38.3 Z150 F50\nG4 P1\nG0 Z160\n", "p.ngc", t, a)
    with pytest.raises(InputError, match=r"p.ngc:4: motion after the probing move of line 2"):
        check_probe_job(after, cfg, "p.ngc")
    check_probe_job(parse_gcode("G38.3 Z150 F50\nG4 P1\n", "p.ngc", t, a), cfg, "p.ngc")


def test_sim_contact_and_tip_force_options_are_validated():
    from pmctl.hal.sim import SimOptions
    o = SimOptions.from_dict({"contact_z_mm": 100.0, "tip_force_N": [1, 2, 3]}, M)
    assert o.contact_z_mm == 100.0 and o.tip_force_N == (1.0, 2.0, 3.0)
    for bad, key in (({"contact_z_mm": "low"}, "contact_z_mm"), ({"contact_stiffness_N_per_mm": 0}, "contact_stiffness"),
                     ({"tip_force_N": [1, 2]}, "tip_force_N")):
        with pytest.raises(ConfigError, match=key):
            SimOptions.from_dict(bad, M)


def _service(tmp_path, sim: str):
    return service_toml(tmp_path, k_theta=200, sim=sim)


def _run(tmp_path, job_text, sim, name="rec"):
    job = tmp_path / "job.ngc"
    job.write_text(job_text)
    args = [*PMCTL, "run", "--job", str(job), "--service", str(_service(tmp_path, sim)), "--state", "",
            "--record", str(tmp_path / name), "--quiet", "--no-realtime"]
    return subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=300)


def test_pmctl_run_reports_the_contact_on_stdout_and_in_the_recording(tmp_path):
    zc = HOME_Z - 0.5
    r = _run(tmp_path, f"G21 G90\nG0 Z{zc + 0.1:.3f}\nG38.2 Z{zc - 1:.3f} F60\n",
             f"flex = true\nstrain_noise_ue = 0.01\ncontact_z_mm = {zc}\ncontact_stiffness_N_per_mm = {KC}")
    assert r.returncode == 0, r.stdout + r.stderr
    prb = [ln.strip() for ln in r.stdout.splitlines() if ln.strip().startswith("[PRB:")]
    assert len(prb) == 1 and prb[0].endswith(":1]")
    x, y, z, a, b = (float(v) for v in prb[0][5:].split(":")[0].split(","))
    assert abs(z - zc) < 5e-3 and x == y == 0.0
    rec = read_recording(tmp_path / "rec")
    (p,) = rec.meta["run"]["probe"]
    assert p["mode"] == "G38.2" and p["contact"] is True and p["line"] == 3
    assert abs(p["point_mm"][2] - zc) < 5e-3 and p["after_trigger_mm"] <= p["after_trigger_bound_mm"]
    # the contact force shows in the recorded load estimate at the end (the tool rests in the surface)
    fz = rec.columns["load_fz"][-20:].mean()
    tip_z = rec.columns["tip_z"][-20:].mean()
    assert fz == pytest.approx(KC * (zc - tip_z), abs=3.0)


def test_pmctl_run_g38_2_without_contact_is_a_fault(tmp_path):
    r = _run(tmp_path, f"G21 G90\nG38.2 Z{HOME_Z - 0.2:.3f} F120\n", "flex = false")
    assert r.returncode == 4, r.stdout + r.stderr
    assert "probe fail" in r.stdout and "[PRB:" in r.stdout and r.stdout.count(":0]") == 1
    rec = read_recording(tmp_path / "rec")
    assert rec.meta["run"]["status"] == "fault" and "probe fail" in rec.meta["run"]["reason"]


@pytest.mark.parametrize("flex", [False, True])
def test_recorded_load_equals_a_known_tip_force(tmp_path, flex):
    f = np.array([30.0, -20.0, 80.0])
    r = _run(tmp_path, f"G21 G90\nG1 X2 Z{HOME_Z - 2:.3f} F300\nG1 X0 F300\n",
             f"flex = {'true' if flex else 'false'}\nstrain_noise_ue = 0.01\ntip_force_N = [30.0, -20.0, 80.0]")
    assert r.returncode == 0, r.stdout + r.stderr
    rec = read_recording(tmp_path / "rec")
    load = np.column_stack([rec.columns[c] for c in ("load_fx", "load_fy", "load_fz")])
    assert np.all(np.isfinite(load))
    assert "strain_sensing" in rec.meta["channels"]["load_fz"]["source"]
    if not flex:
        # rigid chains: on average within 0.05 N, every sample within 0.5 N (gauge noise 0.02 N a
        # chain, amplified into the lateral components; the model pose vs the plant's within a pulse;
        # the plant's per-N map refreshed every 10 ticks)
        assert np.abs(load.mean(0) - f).max() < 0.05
        assert np.abs(load - f).max() < 0.5
    else:
        # the chain modes the pulses excite ring through the gauges (tens of N); on average the
        # estimate is the applied force
        assert np.abs(load.mean(0) - f).max() < 1.0


def test_serve_record_has_the_load_estimate_of_a_known_tip_force(tmp_path):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from grbl_sender import Sender, start_serve, stop_serve
    f = np.array([-25.0, 40.0, 60.0])
    svc = _service(tmp_path, "flex = false\nstrain_noise_ue = 0.01\ntip_force_N = [-25.0, 40.0, 60.0]")
    rec = tmp_path / "serve-rec"
    p, link = start_serve(tmp_path, record=rec, extra=("--service", str(svc)))
    s = Sender(link)
    try:
        s.reset()
        assert s.send(f"G1 Z{HOME_Z - 2:.3f} F120") == "ok"        # 1 s of motion
        s.wait_state(("Run",), 60)
        assert s.wait_state(("Idle",), 120)["state"] == "Idle"
    finally:
        s.close()
        assert stop_serve(p) == 0
    r = read_recording(rec)
    load = np.column_stack([r[c] for c in ("load_fx", "load_fy", "load_fz")])
    assert r.n > 100 and np.all(np.isfinite(load))
    assert np.abs(load.mean(0) - f).max() < 0.05 and np.abs(load - f).max() < 0.5
    assert np.ptp(r["tip_z"]) > 0.9                  # it moved: the estimate follows the pose


def test_a_probe_started_too_close_is_still_stopped_on_contact():
    """Contact while the monitor is still taking its reference (20 um in, at F60): the growing force
    is seen against the running reference (twice the threshold) and the move stops within the bounds."""
    cfg = ProbeConfig()
    zc = HOME_Z - 1.0
    res, mon, be = probe_run(f"G21 G90\nG0 Z{zc + 0.02:.4f}\nG38.2 Z{zc - 1:.4f} F60\n",
                             {"flex": True, "strain_noise_ue": 0.01, "contact_z_mm": zc,
                              "contact_stiffness_N_per_mm": KC})
    (r,) = mon.results
    assert res.status == "done" and r.contact
    rest = K.fk(be.truth(), M).tip
    v = 1.0
    bound_true = 2 * cfg.threshold_N / (_z_share() * KC) + 0.5 * (cfg.filter_ticks - 1) * v * DT + r.bound_mm
    assert 0 < zc - rest[2] <= bound_true
    assert abs(r.point[2] - zc) < 10e-3          # the reference holds some of the contact: less certain
