"""The state journal and position across a power cut: offsets/settings/job round-trip, a damaged
journal is an error naming the file, and after both processes die at once (a power cut) the
daemon comes back in Alarm at the last periodic snapshot, saying its age and that it is not
trusted, until the operator confirms."""

import json
import time

import numpy as np
import pytest

from grbl_sender import Sender, assert_locked_then_unlocked, power_cut_mid_move, start_serve, stop_serve
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.motion.state_store import load_counters
from pmctl.task.journal import Journal

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()


def test_journal_round_trip_and_damaged_file(tmp_path):
    p = tmp_path / "c.json.journal"
    j = Journal(p, M.name)
    off = {"wcs": {"G54": [1, 2, 3, 4, 5]}, "g92": [0, 0, 1, 0, 0], "active": "G55"}
    j.save(offsets=off, settings={"10": 0}, running=True, job="x.ngc", line=12)
    k = Journal(p, M.name).load()
    assert k.loaded and k.data["offsets"] == off and k.data["line"] == 12 and k.data["running"]
    p.write_text("{not json")
    with pytest.raises(InputError) as e:
        Journal(p, M.name).load()
    assert str(p) in str(e.value)
    p.write_text(json.dumps({"format": "pmctl-journal/1", "machine": M.name, "offsets": {"g92": [1, 2]}}))
    with pytest.raises(InputError) as e:
        Journal(p, M.name).load()
    assert "offsets.g92" in str(e.value)
    for key, bad in (("line", -1), ("line", "7"), ("job_start", [1, 2, 3]), ("job", 5), ("homed", "yes")):
        p.write_text(json.dumps({"format": "pmctl-journal/1", "machine": M.name, key: bad}))
        with pytest.raises(InputError) as e:
            Journal(p, M.name).load()
        assert key in str(e.value)
    # offsets and $10 are not guessed either: a bad one is named, never replaced by a default
    for key, d in (("offsets.active", {"offsets": {"active": "G53"}}),
                   ("offsets.wcs.G60", {"offsets": {"wcs": {"G60": [0, 0, 0, 0, 0]}}}),
                   ("offsets.wcs.G55", {"offsets": {"wcs": {"G55": [0, 0, "1", 0, 0]}}}),
                   ("offsets.wcs.G56", {"offsets": {"wcs": {"G56": [0, 0, float("nan"), 0, 0]}}}),
                   ("offsets.g92", {"offsets": {"g92": [0, 0, True, 0, 0]}}),
                   ("settings.10", {"settings": {"10": 256}}), ("settings.10", {"settings": {"10": "1"}})):
        p.write_text(json.dumps({"format": "pmctl-journal/1", "machine": M.name, **d}))
        with pytest.raises(InputError) as e:
            Journal(p, M.name).load()
        assert key in str(e.value) and str(p) in str(e.value)
    j.save(job="/jobs/a.ngc", line=7, job_start=[0, 0, 173, 0, 0, 1], homed=True)
    k = Journal(p, M.name).load()
    assert k.data["job_start"] == [0, 0, 173, 0, 0, 1] and k.data["homed"] is True
    p.write_text(json.dumps({"format": "pmctl-journal/1", "machine": "other"}))
    with pytest.raises(InputError):
        Journal(p, M.name).load()


def test_power_cut_comes_back_in_alarm_at_the_last_snapshot_not_trusted(tmp_path):
    state = tmp_path / "state.json"
    p0 = power_cut_mid_move(tmp_path, state)
    saved = load_counters(state, machine=M.name)
    assert not saved.clean                          # a periodic snapshot
    tip = K.fk_batch((saved.counts / M.resolution.pulses_per_mm)[None], M)[0].tip[0]
    assert -12 < tip[0] - p0[0] < 0 and np.allclose(tip[1:], p0[1:3], atol=2e-3)   # on the programmed line
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        assert np.allclose(s.status()["pos"][:3], tip, atol=1.5e-3)
        assert_locked_then_unlocked(s)
    finally:
        s.close()
        stop_serve(p)
    err = (tmp_path / "serve.err").read_text()
    assert "NOT trusted" in err and " s old" in err


def test_a_journal_without_its_counter_file_comes_back_in_alarm_not_homed(tmp_path):
    """The counter file lost or moved away while the journal of the session stays: the position is not
    known, so the daemon comes up in Alarm (not homed, motion refused) instead of trusting the home
    pose it starts from."""
    state = tmp_path / "state.json"
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        s.reset()
        assert s.send("G21 G91 G1 F600 X-3") == "ok"
        assert s.wait_state(("Idle",), 120)["state"] == "Idle"
    finally:
        s.close()
        assert stop_serve(p) == 0
    assert (tmp_path / "state.json.journal").exists()
    state.unlink()
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        assert_locked_then_unlocked(s)
    finally:
        s.close()
        stop_serve(p)
    assert "the position is NOT known" in (tmp_path / "serve.err").read_text()


# ---------------------------------------------------------------- the counters' resolution

from hypothesis import given, settings, strategies as st  # noqa: E402

from pmctl.motion.state_store import CounterWriter, ResolutionMismatch, save_counters  # noqa: E402

PPM = M.resolution.pulses_per_mm
_counts = st.lists(st.integers(-(2**62), 2**62), min_size=5, max_size=5)
_res = st.floats(0.5, 1e7, allow_nan=False, allow_infinity=False)
_near = st.floats(1e-9, 1e-3)          # a resolution a hair off is still another one


@settings(max_examples=60, deadline=None)
@given(counts=_counts, chain=_res, table=_res, clean=st.booleans())
def test_counters_carry_their_resolution_and_come_back_exact(tmp_path_factory, counts, chain, table, clean):
    f = tmp_path_factory.mktemp("ppm") / "c.json"
    ppm = [chain] * 3 + [table] * 2
    save_counters(f, counts, machine=M.name, clean=clean, tick=7, pulses_per_mm=ppm)
    d = json.loads(f.read_text())
    assert d["pulses_per_mm"] == ppm                     # written as given, per counter
    s = load_counters(f, machine=M.name, pulses_per_mm=ppm)
    assert s.counts.tolist() == counts and s.clean == clean and s.tick == 7
    assert s.pulses_per_mm.tolist() == ppm and s.note == ""


@settings(max_examples=60, deadline=None)
@given(counts=_counts, chain=_res, table=_res, k=st.one_of(st.sampled_from([2, 3, 10, 0.5, 1.25]), _near.map(lambda e: 1 + e)),
       which=st.sampled_from(["chain", "table"]))
def test_counts_saved_at_another_resolution_are_refused_naming_the_file_and_both(
        tmp_path_factory, counts, chain, table, k, which):
    f = tmp_path_factory.mktemp("ppm") / "c.json"
    saved = [chain] * 3 + [table] * 2
    now = [chain * k] * 3 + [table] * 2 if which == "chain" else [chain] * 3 + [table * k] * 2
    save_counters(f, counts, machine=M.name, clean=True, pulses_per_mm=saved)
    before = f.read_bytes()
    with pytest.raises(ResolutionMismatch) as e:
        load_counters(f, machine=M.name, pulses_per_mm=now)
    msg = str(e.value)
    assert isinstance(e.value, InputError) and str(f) in msg and "pulses_per_mm" in msg
    assert f"saved at chain {chain:.12g}, table {table:.12g} pulses/mm" in msg        # what the file holds ...
    assert f"config says chain {now[0]:.12g}, table {now[3]:.12g} pulses/mm" in msg   # ... and the config
    assert f.read_bytes() == before                                        # the file is left alone
    # without a resolution to check against (a reader that does not know it) nothing is refused
    assert load_counters(f, machine=M.name).counts.tolist() == counts


def test_an_older_counter_file_without_resolution_loads_at_the_current_one_and_says_so(tmp_path):
    f = tmp_path / "c.json"
    f.write_text(json.dumps({"format": "pmctl-counters/1", "machine": M.name, "counts": [1, 2, 3, 4, 5],
                             "clean": True, "tick": 3, "wall_time": 1.0}))
    s = load_counters(f, machine=M.name, pulses_per_mm=PPM)
    assert s.counts.tolist() == [1, 2, 3, 4, 5] and s.pulses_per_mm is None
    assert str(f) in s.note and "no resolution" in s.note
    assert f"chain {PPM[0]:.12g}, table {PPM[3]:.12g} pulses/mm" in s.note
    for bad in ([2000, 2000], [2000, 2000, 2000, 0, 2000], [2000, 2000, "2000", 2000, 2000], 2000, [True] * 5):
        f.write_text(json.dumps({"format": "pmctl-counters/1", "machine": M.name, "counts": [1, 2, 3, 4, 5],
                                 "pulses_per_mm": bad}))
        with pytest.raises(InputError) as e:
            load_counters(f, machine=M.name, pulses_per_mm=PPM)
        assert "pulses_per_mm" in str(e.value) and str(f) in str(e.value)


def test_the_counter_writer_writes_the_resolution_in_snapshots_and_at_the_stop(tmp_path):
    f = tmp_path / "c.json"
    w = CounterWriter(f, machine=M.name, pulses_per_mm=PPM)
    w.offer(np.arange(5), 10)
    t0 = time.time()
    while w.writes == 0 and time.time() - t0 < 30:       # the writer thread's first snapshot
        time.sleep(0.01)
    d = json.loads(f.read_text())
    assert d["clean"] is False and d["pulses_per_mm"] == PPM.tolist()
    w.stop(np.arange(5) + 1, 11, clean=True)
    d = json.loads(f.read_text())
    assert d["clean"] is True and d["counts"] == [1, 2, 3, 4, 5] and d["pulses_per_mm"] == PPM.tolist()


def test_serve_refuses_counts_saved_at_another_resolution_and_starts_on_an_older_file(tmp_path):
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    state = tmp_path / "state.json"
    from pmctl.core.job import home_pose
    tip0, axis0 = home_pose(M)
    c0 = [int(x) for x in np.rint(K.ik(np.asarray(tip0) + [1.0, -2.0, 0.5], axis0, M).q * PPM)]
    other = (PPM * 2).tolist()
    save_counters(state, c0, machine=M.name, clean=True, pulses_per_mm=other)
    before = state.read_bytes()
    cmd = [sys.executable, "-m", "pmctl.interfaces.cli", "serve", "--config", "config/prototype.toml",
           "--backend", "sim", "--state", str(state), "--no-realtime"]
    r = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=300)
    assert r.returncode == 1
    err = r.stderr.strip().splitlines()
    assert len(err) == 1, r.stderr                                          # one line: the file, both resolutions
    assert str(state) in err[0] and "pulses_per_mm" in err[0]
    assert f"saved at chain {2 * PPM[0]:g}, table {2 * PPM[3]:g}" in err[0]
    assert f"config says chain {PPM[0]:g}, table {PPM[3]:g}" in err[0]
    assert state.read_bytes() == before                                     # the counters are left alone
    # the same counts in a file without the field (an older pmctl): loaded at the current resolution
    d = json.loads(state.read_text())
    del d["pulses_per_mm"]
    state.write_text(json.dumps(d))
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        st = s.status()
        assert st["state"] == "Idle"
        tip = K.fk_batch((np.array(c0) / PPM)[None], M)[0].tip[0]
        assert np.allclose(st["pos"][:3], tip, atol=1.5e-3)
    finally:
        s.close()
        assert stop_serve(p) == 0
    assert "carries no resolution" in (tmp_path / "serve.err").read_text()
    d = json.loads(state.read_text())                  # the clean stop rewrote it with the resolution
    assert d["clean"] is True and d["pulses_per_mm"] == PPM.tolist()
