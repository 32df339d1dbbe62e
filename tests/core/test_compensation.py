"""Per-axis backlash and screw compensation (pmctl.core.compensation, docs/machine.md §6): the
[compensation] table read strictly, its tick function, the NC applying it in a closed loop against
a plant with play and pitch error, and the table written from a diagnosis.

The plant here is the loopback sim with a load-side play and pitch error added to its truth
(:class:`PlayPitchSim`, a thin test plant through the Backend interface): the encoders see the
motor side, the true tool tip comes from the load side."""

import dataclasses
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.compensation import (AxisComp, Compensation, comp_tick, compensated_columns, parse_compensation,
                                     read_compensation_file, replay)
from pmctl.core.config import load_machine
from pmctl.core.errors import ConfigError
from pmctl.hal.sim import SimBackend, SimOptions
from pmctl.motion.loop import ControlLoop, prepare, tracking_stats
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.service_config import LoopConfig
from pmctl.motion.trajectory import Trajectory
from pmctl.tools.twin import effects as fx
from pmctl.tools.twin.effects import play_error
from pmctl.tools.twin.fix import compensation_from_findings, write_compensation

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()
PROTO = M.source


# ---------------------------------------------------------------- the table in the machine config

GOOD = """
[compensation.L1]
backlash_mm = 0.02
backlash_rate_mm_s = 8.0
positions_mm = [150.0, 300.0, 570.0]
forward_mm = [0.0, 0.004, -0.002]
reverse_mm = [0.001, 0.005, -0.001]

[compensation.X]
backlash_mm = 0.01
"""


def machine_with(tmp_path, text, name="m.toml"):
    p = tmp_path / name
    p.write_text(open(PROTO, encoding="utf-8").read() + text, encoding="utf-8")
    return load_machine(p)


def test_the_machine_config_reads_a_compensation_table(tmp_path):
    m = machine_with(tmp_path, GOOD)
    c = m.compensation
    assert c.axes[0] == AxisComp(0.02, 8.0, (150.0, 300.0, 570.0), (0.0, 0.004, -0.002), (0.001, 0.005, -0.001))
    assert c.axes[3].backlash_mm == 0.01 and c.axes[3].positions_mm == ()
    assert c.axes[1] == AxisComp()
    assert load_machine().compensation is None          # the shipped config compensates nothing
    # forward only: the same table both ways
    m = machine_with(tmp_path, "[compensation.Y]\npositions_mm = [-80.0, 80.0]\nforward_mm = [0.0, 0.01]\n")
    assert m.compensation.axes[4].reverse_mm == (0.0, 0.01)


def test_the_table_may_live_in_its_own_file(tmp_path):
    (tmp_path / "comp.toml").write_text(GOOD, encoding="utf-8")
    m = machine_with(tmp_path, '[compensation]\nfile = "comp.toml"\n')
    assert m.compensation.axes[0].backlash_mm == 0.02
    assert read_compensation_file(tmp_path / "comp.toml") == dataclasses.replace(m.compensation)


@pytest.mark.parametrize("text, key, words", [
    ("[compensation.L1]\npositions_mm = [1.0, 3.0, 2.0]\nforward_mm = [0.0, 0.0, 0.0]\n",
     "compensation.L1.positions_mm", "increase strictly: item 2 is 2 after 3"),
    ("[compensation.L1]\npositions_mm = [1.0, 1.0]\nforward_mm = [0.0, 0.0]\n",
     "compensation.L1.positions_mm", "increase strictly"),
    ("[compensation.L2]\npositions_mm = [1.0, 2.0]\nforward_mm = [0.0]\n", "compensation.L2.forward_mm", "2 to"),
    ("[compensation.L2]\npositions_mm = [1.0, 2.0, 3.0]\nforward_mm = [0.0, 0.1]\n",
     "compensation.L2.forward_mm", "2 values for 3 positions"),
    ("[compensation.L2]\npositions_mm = [1.0, 2.0]\nforward_mm = [0.0, 0.1]\nreverse_mm = [0.0, 0.1, 0.2]\n",
     "compensation.L2.reverse_mm", "3 values for 2 positions"),
    ("[compensation.X]\nforward_mm = [0.0, 0.1]\n", "compensation.X.positions_mm", "missing"),
    ("[compensation.X]\npositions_mm = [0.0, 0.1]\n", "compensation.X.forward_mm", "missing"),
    ("[compensation.X]\nbacklash_mm = -0.01\n", "compensation.X.backlash_mm", "within [0, 5], got -0.01"),
    ("[compensation.X]\nbacklash_mm = \"0.01\"\n", "compensation.X.backlash_mm", "must be a number"),
    ("[compensation.X]\nbacklash_rate_mm_s = 0.0\n", "compensation.X.backlash_rate_mm_s", "within (0, 10000]"),
    ("[compensation.X]\nbacklash = 0.01\n", "compensation.X.backlash", "unknown key"),
    ("[compensation.X]\npositions_mm = [0.0, true]\nforward_mm = [0.0, 0.1]\n", "compensation.X.positions_mm",
     "item 1 must be a number"),
    ("[compensation.X]\npositions_mm = [0.0, 1.0]\nforward_mm = [0.0, 7.0]\n", "compensation.X.forward_mm",
     "item 1 must be within"),
    ("[compensation.Z]\nbacklash_mm = 0.01\n", "compensation.Z", "unknown axis"),
    ("[compensation]\nfile = \"nope.toml\"\n", None, "cannot read"),
])
def test_a_bad_table_is_refused_with_file_line_and_key(tmp_path, text, key, words):
    with pytest.raises(ConfigError) as ei:
        machine_with(tmp_path, text)
    e = ei.value
    if key is not None:
        assert e.key == key and str(tmp_path / "m.toml") in str(e)
        mine = [ln for ln in text.splitlines() if ln.startswith(key.rsplit(".", 1)[1] + " =")]
        if key.count(".") == 2 and mine:                     # the line of the key in the file
            line = 1 + (open(PROTO, encoding="utf-8").read() + text).splitlines().index(mine[0])
            assert f"line {line}:" in e.reason, e.reason
    assert words in str(e)


def test_a_compensation_file_cannot_name_another(tmp_path):
    (tmp_path / "a.toml").write_text('[compensation]\nfile = "b.toml"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match="cannot name another"):
        read_compensation_file(tmp_path / "a.toml")


def test_the_written_toml_reads_back_to_the_same_table(tmp_path):
    c = parse_compensation("x", {"L3": {"backlash_mm": 0.013, "positions_mm": [1.0, 2.5, 4.0],
                                        "forward_mm": [0.001, -0.002, 1e-9], "reverse_mm": [0.0, 0.0, 0.003]},
                                 "Y": {"backlash_mm": 0.004, "backlash_rate_mm_s": 2.0}})
    (tmp_path / "c.toml").write_text(c.to_toml("a header\nof two lines"), encoding="utf-8")
    assert read_compensation_file(tmp_path / "c.toml").axes == c.axes


# ---------------------------------------------------------------- the tick


@settings(max_examples=60, deadline=None)
@given(pos=st.lists(st.floats(-100, 100), min_size=2, max_size=12, unique=True),
       vals=st.lists(st.floats(-0.05, 0.05), min_size=12, max_size=12), x=st.floats(-150, 150))
def test_the_screw_table_interpolates_linearly_and_holds_its_ends(pos, vals, x):
    pos = sorted(pos)
    if min(np.diff(pos)) < 1e-6:
        return
    y = vals[:len(pos)]
    a = AxisComp(0.0, 1.0, tuple(pos), tuple(y), tuple(-v for v in y))
    assert a.screw(x, 1.0) == pytest.approx(float(np.interp(x, pos, y)), abs=1e-12)
    assert a.screw(x, -1.0) == pytest.approx(-float(np.interp(x, pos, y)), abs=1e-12)
    assert a.screw(x, 0.0) == pytest.approx(0.0, abs=1e-12)       # before the first move: the mean
    for p, v in zip(pos, y):
        assert a.screw(p, 1.0) == pytest.approx(v, abs=1e-15)


@settings(max_examples=40, deadline=None)
@given(b=st.floats(0.001, 0.1), rate=st.floats(0.5, 50.0), dt=st.sampled_from([5e-4, 1e-3]),
       moves=st.lists(st.tuples(st.sampled_from([-1.0, 1.0]), st.integers(1, 300)), min_size=1, max_size=6))
def test_backlash_term_is_half_the_play_against_the_motion_taken_up_at_its_rate(b, rate, dt, moves):
    comp = Compensation(tuple(AxisComp(b, rate) for _ in range(5)))
    d, bl = [0.0] * 5, [0.0] * 5
    x = [0.0] * 5
    for sign, n in moves:
        for _ in range(n):
            before = bl[0]
            c, d, bl = comp_tick(comp, x, [sign] * 5, d, bl, dt)
            assert abs(bl[0] - before) <= rate * dt * (1 + 1e-12)        # the take-up rate
            assert abs(bl[0]) <= b / 2 + 1e-15 and c[0] == bl[0]
        assert d[0] == sign
        if n * rate * dt >= b:                  # long enough to cross the play
            assert bl[0] == -sign * b / 2
    # standing still keeps the direction; the take-up goes on toward the same side
    c2, d2, bl2 = comp_tick(comp, x, [0.0] * 5, d, bl, dt)
    assert d2 == d and abs(bl2[0] + d[0] * b / 2) <= abs(bl[0] + d[0] * b / 2)


def test_replay_of_a_recorded_motion_matches_the_play_operator():
    """Along a recorded back-and-forth motion, the replayed backlash term equals the twin's play
    operator (the load-side error) once the play is crossed: the compensation cancels it."""
    t = np.arange(4000) * 1e-3
    x = 10.0 * np.sin(2 * np.pi * 0.5 * t)
    X = np.zeros((len(t), 5))
    X[:, 0] = x
    comp = Compensation((AxisComp(0.02, 1e3),) + (AxisComp(),) * 4)
    c = replay(comp, t, X)[:, 0]
    e = play_error(x, 0.02, 0.0)
    settled = np.abs(np.abs(e) - 0.01) < 1e-12
    assert settled.mean() > 0.9
    assert np.allclose(c[settled], e[settled], atol=1e-12)
    cols = {"t": t, **{f"cmd_{a}": X[:, i] for i, a in enumerate(("L1", "L2", "L3", "X", "Y"))},
            "enc_L1": X[:, 0].copy()}
    out = compensated_columns(cols, comp)
    assert np.allclose(out["cmd_L1"] - x, c) and np.allclose(out["enc_L1"] - x, c)
    assert compensated_columns(cols, None) is cols


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), b=st.sampled_from([0.0, 0.004, 0.05]), rate=st.floats(0.5, 30.0),
       points=st.sampled_from([0, 2, 9]))
def test_replay_is_the_tick_function_in_closed_form(seed, b, rate, points):
    """replay (vectorised) = comp_tick run sample by sample with the position increments as rates,
    on a motion with stops, reversals, uneven sampling and the table ends crossed."""
    rng = np.random.default_rng(seed)
    n = 600
    t = np.cumsum(rng.uniform(5e-4, 2e-3, n))
    v = np.repeat(rng.choice([-1.0, 0.0, 1.0], 30) * rng.uniform(0.5, 20.0, 30), n // 30)
    x = np.cumsum(v * np.diff(t, prepend=t[0]))[:, None] + np.zeros((1, 5))
    pos = tuple(np.sort(rng.uniform(-5, 5, points)).tolist())
    f = tuple(rng.uniform(-0.01, 0.01, points).tolist())
    comp = Compensation(tuple(AxisComp(b, rate, pos, f, tuple(-np.array(f))) for _ in range(5)))
    d, bl, ref = [0.0] * 5, [0.0] * 5, []
    for k in range(n):
        c, d, bl = comp_tick(comp, x[k].tolist(), (x[k] - x[k - 1] if k else np.zeros(5)).tolist(), d, bl,
                             float(t[k] - t[k - 1]) if k else 0.0)
        ref.append(c)
    assert np.allclose(replay(comp, t, x), np.array(ref), atol=1e-12, rtol=0)


# ---------------------------------------------------------------- the closed loop against play and pitch


class PlayPitchSim(SimBackend):
    """The loopback sim whose load side also carries a play (backlash, a play operator on the
    motor position) and a pitch error A sin(2 pi x / p + phi) of the motor position x: the
    encoders see the motor side, :meth:`truth` (the true tool tip) the load side."""

    def __init__(self, machine, dt, *, backlash, amp, period, phase, options=None):
        super().__init__(machine, dt, options)
        self.h = 0.5 * np.broadcast_to(np.asarray(backlash, float), (5,))
        self.amp = np.broadcast_to(np.asarray(amp, float), (5,))
        self.period = np.broadcast_to(np.asarray(period, float), (5,))
        self.phase = np.broadcast_to(np.asarray(phase, float), (5,))

    def _motor(self):
        L = self._lib
        return self._d[L.D_MOTOR:L.D_MOTOR + 5].copy()

    def open(self, counts):
        super().open(counts)
        self._x = self._motor()
        self.play = np.zeros(5)                  # load - motor in the play, starting in the middle

    def write_pulses(self, pulses):
        super().write_pulses(pulses)
        x = self._motor()
        self.play = np.clip(self.play - (x - self._x), -self.h, self.h)
        self._x = x

    def error(self):
        return self.play + self.amp * np.sin(2 * np.pi * self._x / self.period + self.phase)

    def truth(self):
        return super().truth() + self.error()


PLANT = dict(backlash=[0.02, 0.015, 0.025, 0.02, 0.01], amp=[0.006, 0.004, 0.005, 0.005, 0.003],
             period=5.0, phase=[0.3, 1.2, 2.0, -0.7, 2.8])


def findings_of(plant):
    """The diagnosis' accepted findings (as pmctl.tools.twin.diagnose returns them) that name the
    plant's play and pitch error exactly, in the twin's conventions (effects.Backlash, PitchError)."""
    acc = []
    for a, name in enumerate(("L1", "L2", "L3", "X", "Y")):
        if plant["backlash"][a]:
            acc.append({"cand": fx.Backlash(name), "fit": fx.Fit({"width_mm": plant["backlash"][a]}, None, 1)})
        if plant["amp"][a]:
            acc.append({"cand": fx.PitchError(name),
                        "fit": fx.Fit({"period_mm": plant["period"], "amplitude_mm": abs(plant["amp"][a])}, None, 3,
                                      internal={"phase_rad": plant["phase"][a] + (math.pi if plant["amp"][a] < 0
                                                                                   else 0.0)})})
    return acc


def plant_table(machine, plant) -> Compensation:
    """The table `pmctl twin diagnose --write-compensation` writes for findings that match the plant
    exactly (pmctl.tools.twin.fix)."""
    comp, notes = compensation_from_findings(machine, findings_of(plant))
    return comp


def there_and_back(dt, feed=15.0):
    """A tilted tool tip path out and back twice (every axis reverses), trapezoidal speed."""
    pts = [np.array(p, float) for p in ([-12, -8, 3], [12, 9, 7], [-6, 10, 1], [10, -9, 6], [-12, -8, 3])]
    ax = [K.axis_from_roll_pitch(math.radians(r), math.radians(p)) for r, p in ((5, -3), (-4, 5), (3, 4), (-5, -4),
                                                                                (5, -3))]
    tips, axes = [], []
    for i in range(len(pts) - 1):
        d = float(np.linalg.norm(pts[i + 1] - pts[i]))
        n = int(d / feed / dt) + 1
        u = np.linspace(0, 1, n)
        s = u * u * (3 - 2 * u)
        tips.append(pts[i] + s[:, None] * (pts[i + 1] - pts[i]))
        a = (1 - s)[:, None] * ax[i] + s[:, None] * ax[i + 1]
        axes.append(a / np.linalg.norm(a, axis=1, keepdims=True))
    tip, axis = np.concatenate(tips), np.concatenate(axes)
    z = np.zeros_like(tip)
    return Trajectory(dt, tip, axis, z, z.copy(), np.ones(len(tip), int), np.zeros(len(tip)))


def run_on_plant(machine, impl, plant=PLANT, rate=1000.0):
    dt = 1.0 / rate
    params = NCParams.from_machine(machine, dt, kv=0.4 / dt, implementation=impl)
    tg = prepare(machine, params, there_and_back(dt), dt)
    c0 = counts_of(tg.q[0], params)
    be = PlayPitchSim(machine, dt, **plant)
    be.open(c0)
    res = ControlLoop(machine, be, params, tg, LoopConfig(rate_hz=rate, realtime=False, stall_timeout_s=5.0),
                      initial_state(machine, c0), log=lambda m: None).run()
    assert res.status == "done", res.reason
    return tracking_stats(res, machine), res, be


@pytest.mark.parametrize("impl", ["compiled", "python"])
def test_the_table_removes_play_and_pitch_from_the_tool_tip(impl):
    """Against a plant with 10-25 µm of play and 3-6 µm of pitch error per axis, the machine config's
    [compensation] (the plant's own values) brings the true tool tip's RMS error against the
    programmed path down by more than 5x; the NC takes it from the machine config
    (NCParams.from_machine), as `pmctl run` and the daemon do."""
    off, _, _ = run_on_plant(M, impl)
    on, res, be = run_on_plant(replace(M, compensation=plant_table(M, PLANT)), impl)
    print(f"{impl}: tip RMS {off['tip_rms_um']:.2f} -> {on['tip_rms_um']:.2f} µm, "
          f"max {off['tip_max_um']:.2f} -> {on['tip_max_um']:.2f} µm")
    assert off["tip_rms_um"] > 8.0                           # the plant's error is there
    assert on["tip_rms_um"] < off["tip_rms_um"] / 5.0
    assert on["tip_rms_um"] < 2.0
    # the encoders see the motor side: it moved away from the programmed joints by the correction
    assert np.max(np.abs(res.enc[-1] - res.truth[-1])) > 1e-3


def test_the_table_of_another_plant_does_not_help():
    """A table with the wrong sign (a compensation that doubles the error) makes the tip worse: the
    correction acts in the direction the convention says."""
    bad = plant_table(M, dict(PLANT, backlash=[0.0] * 5, amp=[-a for a in PLANT["amp"]]))
    assert bad.axes[0].backlash_mm == 0.0
    off, _, _ = run_on_plant(M, "compiled")
    worse, _, _ = run_on_plant(replace(M, compensation=bad), "compiled")
    assert worse["tip_rms_um"] > off["tip_rms_um"]


# ---------------------------------------------------------------- the writer


def test_the_writer_turns_findings_into_a_table_that_reads_back(tmp_path):
    """Backlash -> backlash_mm; a pitch error A sin(2 pi x / p + phi) -> a screw table over the
    axis' travel that reproduces it within the linear interpolation's error (lead/16 spacing:
    < 2 % of A); geometry and other effects are named and left out; an existing table is added to."""
    plant = dict(backlash=[0.0, 0.0, 0.02, 0.0, 0.0], amp=[0.0, 0.0, 0.0, 0.007, 0.0], period=5.0,
                 phase=[0.0, 0.0, 0.0, 1.09, 0.0])
    acc = findings_of(plant) + [
        {"cand": fx.ServoLag("Y"), "fit": fx.Fit({"tau_s": 0.002}, None, 1)}]
    geo = type("Geo", (), {"effect": "geometry", "target": "L2", "target_key": "axis"})()
    acc.append({"cand": geo, "fit": fx.Fit({}, None, 1)})
    comp, notes = compensation_from_findings(M, acc)
    assert comp.axes[2].backlash_mm == 0.02 and comp.axes[2].positions_mm == ()
    x = np.linspace(M.limits.table_x[0], M.limits.table_x[1], 997)
    want = 0.007 * np.sin(2 * np.pi * x / 5.0 + 1.09)
    for d in (1.0, -1.0, 0.0):
        assert np.max(np.abs(comp.screw_error(3, x, d) - want)) < 0.02 * 0.007
    assert any("pmctl calibrate from-twin" in n for n in notes)
    assert any("servo_lag" in n and "not written" in n for n in notes)
    path = tmp_path / "out" / "comp.toml"
    text = write_compensation(path, comp, recording="rec", machine_source="m.toml", notes=notes)
    assert 'file = "comp.toml"' in text
    back = read_compensation_file(path)
    assert back.axes[2] == comp.axes[2] and back.axes[3] == comp.axes[3]
    # a second diagnosis (of a compensated run) adds what is left
    more, _ = compensation_from_findings(M, findings_of(dict(plant, backlash=[0, 0, 0.003, 0, 0.004],
                                                             amp=[0.0, 0.0, 0.0, 0.001, 0.0])), back)
    assert more.axes[2].backlash_mm == pytest.approx(0.023) and more.axes[4].backlash_mm == 0.004
    assert np.max(np.abs(more.screw_error(3, x) - want * 8 / 7)) < 0.02 * 0.008
    assert compensation_from_findings(M, acc[-2:])[0] is None          # nothing compensable


# ---------------------------------------------------------------- end to end through the sim's own effects

SIM_HAS_EFFECTS = {"backlash_mm", "pitch_error_amp_mm"} <= {f.name for f in dataclasses.fields(SimOptions)}


@pytest.mark.skipif(not SIM_HAS_EFFECTS, reason="waits for the sim backend's effect catalogue "
                                                "([hal.sim] backlash_mm, pitch_error_*): not on this branch yet")
def test_run_diagnose_write_table_rerun_removes_the_mismatch(tmp_path):
    """pmctl run on a sim with 20 µm of backlash on L2 and a 6 µm pitch error on X -> pmctl twin
    diagnose --write-compensation -> the machine config names the table -> the re-run's true tool
    tip RMS error against the programmed path drops by more than 3x, and the diagnosis of the
    re-run finds neither effect. (With the test plant of this file in place of the sim,
    benchmarks/eval_compensation.py measured 5.6 -> 0.32 µm RMS, both effects found, then
    neither.) Two diagnoses: about a minute on a quiet machine."""
    import json
    import shutil

    from pmctl.interfaces.cli import main
    svc = tmp_path / "service.toml"
    svc.write_text("[hal.sim]\nseed = 4\nenc_noise_mm = 0.0002\nstrain_noise_ue = 0.02\n"
                   "backlash_mm = [0.0, 0.02, 0.0, 0.0, 0.0]\n"
                   "pitch_error_amp_mm = [0.0, 0.0, 0.0, 0.006, 0.0]\n"
                   "pitch_error_period_mm = 5.0\npitch_error_phase_rad = [0.3, 1.2, 2.0, -0.7, 2.8]\n",
                   encoding="utf-8")
    job = tmp_path / "job.ngc"
    job.write_text("G21 G90 G17\nG0 X-12 Y-8 Z60\nG1 F900 X12 Y9 Z62\nX-6 Y10 Z57\nX10 Y-9 Z61\nX-12 Y-8 Z60\n"
                   "X12 Y9 Z62\nX-6 Y10 Z57\nX10 Y-9 Z61\nX-12 Y-8 Z60\nM2\n", encoding="utf-8")
    machine = tmp_path / "machine.toml"
    shutil.copy(PROTO, machine)

    def run_and_diagnose(tag, extra=()):
        rec = tmp_path / f"rec-{tag}"
        assert main(["run", "--job", str(job), "--config", str(machine), "--service", str(svc), "--record",
                     str(rec), "--state", "", "--no-realtime", "--quiet"]) == 0
        rep = tmp_path / f"diag-{tag}.json"
        assert main(["twin", "diagnose", str(rec), "--json", str(rep), "--no-progress", *extra]) == 0
        return json.loads((rec / "recording.json").read_text()), json.loads(rep.read_text())

    meta0, diag0 = run_and_diagnose("before", ["--write-compensation", str(tmp_path / "comp.toml")])
    found0 = {(f["effect"], f.get("axis")) for f in diag0["findings"]}
    # the two, and nothing else: the tool direction of this job without tilts is predicted from
    # the encoders with their noise, and a "gain" of 0 on tool_i would explain that noise
    assert found0 == {("backlash", "L2"), ("pitch_error", "X")}, diag0["findings"]
    comp = read_compensation_file(tmp_path / "comp.toml")
    assert comp.axes[1].backlash_mm == pytest.approx(0.02, rel=0.2)
    x = np.linspace(-20.0, 20.0, 401)
    assert np.max(np.abs(comp.screw_error(3, x) - 0.006 * np.sin(2 * np.pi * x / 5.0 - 0.7))) < 0.0015
    with open(machine, "a", encoding="utf-8") as f:
        f.write('\n[compensation]\nfile = "comp.toml"\n')
    meta1, diag1 = run_and_diagnose("after")
    rms0 = meta0["run"]["tracking"]["tip_rms_um"]
    rms1 = meta1["run"]["tracking"]["tip_rms_um"]
    assert rms1 < rms0 / 3.0, (rms0, rms1)
    found1 = {f["effect"] for f in diag1["findings"]}
    assert not found1 & {"backlash", "pitch_error"}, found1
