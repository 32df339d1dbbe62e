"""Homing ($H) on the real backends: the step/dir bridge (its host build on a pty, simulated home
switches that close when the motor passes a configured edge) and CiA 402 drives (simulated in the
device simulator process, the home switch in 0x60FD of each TPDO).

- the bridge's own latch (hypothesis: random approach speeds, starting points and re-references):
  the latched counter is the counter of the very step at which the motor crossed the switch edge,
  whatever the tick; a RESET at rest (the re-reference) moves the latch with the counters and does
  not move the motor;
- `pmctl serve` + `$H` on each backend: the counter then equals the switch-edge reference (bridge:
  exactly; drives: within the latch speed x one CAN cycle + 1 pulse), pulses counted = pulses sent,
  the machine at rest off the switch at the pull-off; `$H` refused while a move runs;
- the drives' reference offset survives a restart in the state file: homing again corrects less than
  the latch bound;
- a switch out of reach: a controlled stop and ALARM 9 naming the axis, on both backends;
- the switch options and the state file's offsets are checked (file, key).
"""

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from grbl_sender import Sender, start_serve, stop_serve
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.interfaces.commands.ctl import request
from pmctl.motion.state_store import load_counters, save_counters
from pmctl.core.job import home_pose

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()
PPM = np.asarray(M.resolution.pulses_per_mm, float)
TIP, AX = home_pose(M)
Q0 = K.ik(TIP, AX, M).q
C0 = np.rint(Q0 * PPM).astype(np.int64)
REF = np.array([400.0, 400.0, 400.0, 5.0, 5.0])           # [homing] reference_mm (shipped)
SW = Q0 + np.array([1.0, 0.7, 1.3, 0.9, 1.1])             # where the switches really are (motor frame, mm)
SW_PULSES = np.rint(SW * PPM).astype(np.int64)
FAST = {"seek_mm_s": 20.0, "latch_mm_s": 4.0, "pull_off_mm": 0.5}     # bounds below scale with latch_mm_s
CYCLE_S = 2e-3                                            # the shipped CAN cycle


def service_file(tmp_path, backend, switch=SW, order=("L1", "X"), homing=FAST):
    from pathlib import Path
    text = (Path(__file__).resolve().parents[2] / "config" / "service.toml").read_text()
    sw = [float(x) for x in switch]
    assert 'backend = "sim"' in text
    text = text.replace('backend = "sim"', f'backend = "{backend}"', 1)
    # generous link timeouts: these tests check positions, not timing, on a shared loaded machine
    keys = ({"home_switch_mm": sw, "watchdog_ms": 5000, "read_timeout_ms": 1000, "link_timeout_ms": 4000}
            if backend == "stepdir" else {"sim_home_switch_mm": sw, "heartbeat_timeout_ms": 1000,
                                          "host_timeout_ms": 3000})
    for section, table in ((f"[hal.{backend}]", keys), ("[homing]", {"order": list(order), **homing})):
        head, _, body = text.partition(section)
        assert body, section
        for k, v in table.items():                       # the key's first line in that section
            line = next(ln for ln in body.splitlines() if ln.startswith(f"{k} ="))
            body = body.replace(line, f"{k} = {json.dumps(v)}", 1)
        text = head + section + body
    p = tmp_path / f"service-{backend}.toml"
    p.write_text(text)
    return p


# ---------------------------------------------------------------- the bridge's latch

@pytest.fixture
def bridge_backend():          # one bridge for all the examples of the test (hypothesis runs it once)
    from pmctl.hal.stepdir import StepDirBackend
    be = StepDirBackend(M, 1e-3, {"home_switch_mm": [float(x) for x in SW], "bridge_rt_priority": 0,
                                  "read_timeout_ms": 1000.0, "link_timeout_ms": 4000.0, "watchdog_ms": 5000.0})
    be.open(C0)
    state = {"counts": C0.copy(), "motor": C0.copy()}       # counters and true motor steps, per axis
    yield be, state
    be.close()


def _run(be, state, pulses_per_tick):
    """Ticks through the backend (paced by the bridge), then idle ticks until the bridge executed all."""
    for p in list(pulses_per_tick) + [np.zeros(5, np.int64)] * 8:
        be.read()
        be.write_pulses(p)
        state["counts"] += p
        state["motor"] += p
    while not np.array_equal(be.read().counts, state["counts"]):
        be.write_pulses(np.zeros(5, np.int64))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(0, 4), st.integers(1, 150), st.integers(1, 300), st.integers(-5000, 5000))
def test_bridge_latches_the_counter_of_the_step_that_crossed_the_switch(bridge_backend, axis, speed, start, shift):
    be, state = bridge_backend
    edge = int(SW_PULSES[axis])
    # from `start` pulses below the edge, up past it at `speed` pulses per tick, then back down
    def move_to(target, speed=speed):
        d = int(target - state["motor"][axis])
        n, rest = divmod(abs(d), speed)
        steps = [speed] * n + ([rest] if rest else [])
        ticks = []
        for s in steps:
            p = np.zeros(5, np.int64)
            p[axis] = s * (1 if d > 0 else -1)
            ticks.append(p)
        _run(be, state, ticks)
    move_to(edge - start, 150)
    assert not be.inputs().home[axis]
    e0 = be.inputs().latch[axis][0]
    off = int(state["counts"][axis] - state["motor"][axis])     # counters - motor (re-references so far)
    move_to(edge + start)
    inp = be.inputs()
    assert inp.home[axis] and inp.latch[axis][0] == (e0 + 1) % 256 and inp.latch[axis][1]
    assert inp.latch[axis][2] == edge + off                     # the step that reached the edge, exactly
    move_to(edge - start)
    inp = be.inputs()
    assert not inp.home[axis] and inp.latch[axis][0] == (e0 + 2) % 256 and not inp.latch[axis][1]
    assert inp.latch[axis][2] == edge - 1 + off                 # the step that left it
    # a re-reference at rest: the counters move, the motor does not, the latch moves with the counters
    new = state["counts"].copy()
    new[axis] += shift
    be.rereference(new)
    state["counts"] = new
    _run(be, state, [np.zeros(5, np.int64)])                    # ticks run again after the RESET
    assert be.inputs().latch[axis][2] == edge - 1 + off + shift and not be.inputs().home[axis]


# ---------------------------------------------------------------- $H through pmctl serve

def _serve(tmp_path, backend, svc, state=None):
    sock = tmp_path / "ctl.sock"
    p, link = start_serve(tmp_path, state=state, extra=("--service", str(svc), "--socket", str(sock),
                                                       "--backend", backend))
    return p, Sender(link), sock


def _home(s, sock):
    """$H; returns the counters, the pulses sent since the rt side started, and its start counters."""
    before = request(sock, {"cmd": "status"})
    assert s.send("$H", timeout=300) == "ok"
    assert s.wait_state(("Idle",), 60)["state"] == "Idle"
    ans = request(sock, {"cmd": "status"})
    assert ans["homed"] and not ans["alarm"]
    return np.array(ans["counts"]), np.array(ans["sent"]), np.array(before["counts"]) - np.array(before["sent"])


def _check_homed(backend, s, order, counts, sent, start):
    """The counter of each homed axis = motor + reference - switch edge (bridge: exactly; drives: up
    to the latch bound below), the others untouched; at rest off the switch at the pull-off; $H refused
    while a move runs."""
    motor = start + sent              # the motors' frame is the counters' at start (no pulse lost)
    homed = [("L1", "L2", "L3", "X", "Y").index(a) for a in order]
    want = motor + np.where(np.isin(np.arange(5), homed), np.rint(REF * PPM).astype(np.int64) - SW_PULSES, 0)
    err = counts - want                                         # switch edge (truth) - latched, pulses
    bound = np.zeros(5) if backend == "stepdir" else np.floor(FAST["latch_mm_s"] * CYCLE_S * PPM) + 1
    print(f"{backend}: counter - switch-edge reference after $H: {err.tolist()} pulses (bound {bound.tolist()})")
    assert np.all(err <= 0) and np.all(-err <= bound), err
    q = counts / PPM
    print(f"{backend}: at rest {[round(REF[i] - q[i], 4) for i in homed]} mm below the switch edges")
    for i in homed:       # at rest off the switch: the pull-off past its opening edge (+ the stop from seek speed)
        assert REF[i] - FAST["pull_off_mm"] - 2.5 < q[i] <= REF[i] - FAST["pull_off_mm"] + 1e-3, q[i]
    assert s.status()["state"] == "Idle"
    assert s.send("G21 G91 G1 F120 X-3") == "ok"               # $H is refused while a move runs
    s.wait_state(("Run",), 60)
    assert s.send("$H") == "error:8"
    s.wait_state(("Idle",), 120)


def test_serve_home_on_the_bridge_references_the_counters_to_the_switch_edges_exactly(tmp_path):
    svc = service_file(tmp_path, "stepdir", order=("L1", "X"))
    p, s, sock = _serve(tmp_path, "stepdir", svc)
    try:
        _check_homed("stepdir", s, ("L1", "X"), *_home(s, sock))
    finally:
        s.close()
        assert stop_serve(p) == 0
    assert "pulses sent = counter change: yes; device counters = counters: yes" in (tmp_path / "serve.err").read_text()


def test_serve_home_on_drives_then_the_reference_offset_survives_a_restart(tmp_path):
    svc = service_file(tmp_path, "canopen", order=("L1",))
    state = tmp_path / "state.json"
    save_counters(state, C0, machine=M.name, clean=True)
    bound = np.floor(FAST["latch_mm_s"] * CYCLE_S * PPM[0]) + 1
    p, s, sock = _serve(tmp_path, "canopen", svc, state)
    try:
        counts, sent, start = _home(s, sock)
        shift1 = int(counts[0] - (start[0] + sent[0]))
        _check_homed("canopen", s, ("L1",), counts, sent, start)
    finally:
        s.close()
        assert stop_serve(p) == 0
    err = (tmp_path / "serve.err").read_text()
    assert "pulses sent = counter change: yes" in err
    assert "K_theta off: backend canopen carries no strain gauges in its cyclic data" in err
    assert "drive positions = counters: yes (within a pulse)" in err        # the drives hold no counters
    saved = load_counters(state, machine=M.name)
    assert saved.clean and saved.offsets is not None and saved.offsets[0] == shift1 and not saved.offsets[1:].any()
    # restart: the drives' positions (counters - offset) and the counters agree; the switch is where
    # the counters say the reference is, so homing again corrects by less than the latch bound
    p, s, sock = _serve(tmp_path, "canopen", svc, state)
    try:
        assert s.status()["state"] == "Idle"
        counts2, sent2, start2 = _home(s, sock)
        assert np.array_equal(start2, saved.counts)
        shift2 = int(counts2[0] - (start2[0] + sent2[0]))
    finally:
        s.close()
        assert stop_serve(p) == 0
    print(f"canopen L1: first $H corrected {shift1} pulses, after the restart {shift2} pulses (bound {bound:g})")
    assert abs(shift1) > 1000 and abs(shift2) <= bound
    assert load_counters(state, machine=M.name).offsets[0] == shift1 + shift2


# ---------------------------------------------------------------- a missing switch

@pytest.mark.parametrize("backend", ["stepdir", "canopen"])
def test_switch_out_of_reach_stops_with_alarm_9_naming_the_axis(tmp_path, backend):
    from pmctl.motion.nc import counts_of
    from pmctl.task.supervisor import Supervisor
    far = SW.copy()
    far[0] = Q0[0] + 10.0
    svc = service_file(tmp_path, backend, switch=far, order=("L1",), homing={**FAST, "search_mm": 3.0})
    s = Supervisor("prototype", service=str(svc), backend=backend, realtime=False)
    s.start(counts_of(Q0, s.params))
    try:
        ok, msg = s.home()
        assert not ok and s.alarm == 9 and "switch not found" in s.alarm_msg and "L1" in s.alarm_msg
        assert s.state_name() == "Alarm" and not s.homed
        moved = s.counts()[0] / PPM[0] - Q0[0]
        assert 3.0 <= moved < 4.0                                 # the whole search, then a stop
    finally:
        s.shutdown()


# ---------------------------------------------------------------- config and state file

@pytest.mark.parametrize("backend, key", [("stepdir", "home_switch_mm"), ("canopen", "sim_home_switch_mm")])
@pytest.mark.parametrize("value", [[1.0, 2.0], [1, 2, 3, 4, True], "400", [1, 2, 3, 4, float("nan")]])
def test_bad_switch_positions_are_refused_naming_the_key(backend, key, value):
    from pmctl.core.errors import ConfigError
    from pmctl.hal.canopen_csp import CanopenOptions
    from pmctl.hal.stepdir import StepDirOptions
    cls = StepDirOptions if backend == "stepdir" else CanopenOptions
    with pytest.raises(ConfigError) as e:
        cls.from_dict({key: value}, f"svc.toml: hal.{backend}")
    assert key in str(e.value) and f"hal.{backend}" in str(e.value)


def test_state_file_keeps_the_offsets_with_their_counters(tmp_path):
    from pmctl.core.errors import InputError
    p = tmp_path / "state.json"
    save_counters(p, C0, machine=M.name, clean=True, offsets=[11500, 0, -3, 0, 7])
    assert load_counters(p, machine=M.name).offsets.tolist() == [11500, 0, -3, 0, 7]
    save_counters(p, C0 + 1, machine=M.name, clean=False)          # a writer that does not know them
    s = load_counters(p, machine=M.name)
    assert s.offsets.tolist() == [11500, 0, -3, 0, 7] and np.array_equal(s.counts, C0 + 1)
    d = json.loads(p.read_text())
    d["device_offsets"] = [1, 2, 3]
    p.write_text(json.dumps(d))
    with pytest.raises(InputError) as e:
        load_counters(p, machine=M.name)
    assert "device_offsets" in str(e.value) and str(p) in str(e.value)
