"""Writing recordings safely (docs/recording.md, "Writing a recording safely"): an existing
recording is refused unless overwrite; the recording appears whole under its name or not at all;
a killed writer leaves a readable partial recording marked incomplete; numbers round-trip."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmctl.core.errors import InputError
from pmctl.core.recording import (CMD, RecordingWriter, check_target, partial_path, read_recording,
                                  write_recording)

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow


def _columns(n, rate=1000.0):
    t = np.arange(n) / rate
    cols = {"t": t}
    for i, c in enumerate(CMD):
        cols[c] = 393.2495 + 0.5 * np.sin(t + i)
    cols["strain_1"] = np.cos(t)
    return cols


def _meta(folder):
    return json.loads((folder / "recording.json").read_text())


def test_existing_recording_is_refused_unless_overwrite(tmp_path):
    a, b = _columns(50), _columns(80)
    write_recording(tmp_path / "r", a, sample_rate_hz=1000, description="first")
    with pytest.raises(InputError, match="already there.*--force"):
        write_recording(tmp_path / "r", b, sample_rate_hz=1000, description="second")
    rec = read_recording(tmp_path / "r")
    assert rec.n == 50 and rec.description == "first"          # untouched by the refused write
    write_recording(tmp_path / "r", b, sample_rate_hz=1000, description="second", overwrite=True)
    rec = read_recording(tmp_path / "r")
    assert rec.n == 80 and rec.description == "second" and rec.meta["complete"] is True
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]    # no .partial, no .old left


def test_empty_folder_is_a_fine_target_and_other_folders_are_never_replaced(tmp_path):
    (tmp_path / "empty").mkdir()
    write_recording(tmp_path / "empty", _columns(10), sample_rate_hz=1000)
    assert read_recording(tmp_path / "empty").n == 10
    src = tmp_path / "src"
    (src / "pkg").mkdir(parents=True)
    (src / "main.py").write_text("print('mine')\n")
    for overwrite in (False, True):
        with pytest.raises(InputError, match="not a recording"):
            write_recording(src, _columns(10), sample_rate_hz=1000, overwrite=overwrite)
    assert (src / "main.py").read_text() == "print('mine')\n" and (src / "pkg").is_dir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        check_target(tmp_path / "file", overwrite=True)


def test_a_killed_writers_partial_is_refused_before_anything_is_written_unless_replaced(tmp_path):
    target = tmp_path / "rec"
    partial_path(target).mkdir()                     # what a killed run or session leaves
    with pytest.raises(InputError, match=r"rec\.partial exists .*move it away, or --force to replace it"):
        check_target(target)
    with pytest.raises(InputError, match=r"rec\.partial exists .*move it away, or choose another name"):
        check_target(target, force_flag=None)        # (pmctl serve: no --force)
    with pytest.raises(InputError, match=r"rec\.partial exists"):
        RecordingWriter(target, list(_columns(3)), sample_rate_hz=1000)
    assert not target.exists() and not any(partial_path(target).iterdir())
    check_target(target, overwrite=True)             # --force: the writer replaces it


def test_the_target_appears_only_when_complete_and_the_partial_is_readable(tmp_path):
    cols = _columns(300)
    target = tmp_path / "run"
    with RecordingWriter(target, list(cols), sample_rate_hz=1000, description="live") as w:
        w.append({k: v[:100] for k, v in cols.items()})
        assert not target.exists()
        part = partial_path(target)
        assert part == tmp_path / "run.partial"
        mid = read_recording(part)               # a reader can look at it while it is written
        assert mid.n == 100 and mid.meta["complete"] is False
        w.append({k: v[100:] for k, v in cols.items()})
    assert not part.exists()
    rec = read_recording(target)
    assert rec.n == 300 and rec.meta["complete"] is True
    np.testing.assert_array_equal(rec.t, cols["t"])


def test_an_exception_leaves_nothing_under_any_name(tmp_path):
    cols = _columns(20)
    with pytest.raises(RuntimeError):
        with RecordingWriter(tmp_path / "x", list(cols), sample_rate_hz=1000) as w:
            w.append(cols)
            raise RuntimeError("the run crashed")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="strictly increasing"):   # a refused chunk: same
        with RecordingWriter(tmp_path / "y", list(cols), sample_rate_hz=1000) as w:
            w.append(cols)
            w.append(cols)
    assert list(tmp_path.iterdir()) == []


def test_finish_incomplete_keeps_the_samples_marked(tmp_path):
    cols = _columns(40)
    with RecordingWriter(tmp_path / "s", list(cols), sample_rate_hz=1000) as w:
        w.append(cols)
        w.finish(complete=False, reason="session ended by the operator")
    rec = read_recording(tmp_path / "s")
    assert rec.n == 40 and rec.meta["complete"] is False
    assert rec.meta["incomplete_reason"] == "session ended by the operator"


def test_a_partial_left_by_a_killed_writer_blocks_a_new_write_unless_overwrite(tmp_path):
    part = partial_path(tmp_path / "r")
    part.mkdir()
    (part / "recording.json").write_text('{"format": "pmctl-recording/1", "complete": false}')
    with pytest.raises(InputError, match="killed"):
        write_recording(tmp_path / "r", _columns(5), sample_rate_hz=1000)
    write_recording(tmp_path / "r", _columns(5), sample_rate_hz=1000, overwrite=True)
    assert read_recording(tmp_path / "r").n == 5 and not part.exists()


def test_kill_9_mid_write_leaves_a_readable_incomplete_recording(tmp_path):
    """A real process appends 3 chunks and is killed with SIGKILL before it finishes."""
    script = textwrap.dedent(f"""
        import os, signal, numpy as np
        from pmctl.core.recording import CMD, RecordingWriter
        cols = ["t", *CMD, "strain_1"]
        w = RecordingWriter({str(tmp_path / 'run')!r}, cols, sample_rate_hz=1000, description="killed")
        w.__enter__()
        for k in range(3):
            t = (np.arange(100) + 100 * k) / 1000
            w.append(np.column_stack([t] + [393.0 + t] * 5 + [np.sin(t)]))
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert p.returncode == -9, p.stderr
    assert not (tmp_path / "run").exists()
    rec = read_recording(tmp_path / "run.partial")
    assert rec.n == 300 and rec.meta["complete"] is False and rec.description == "killed"
    assert rec.t[-1] == 0.299


def test_times_print_shortest_round_trip(tmp_path):
    cols = _columns(2000)
    write_recording(tmp_path / "r", cols, sample_rate_hz=1000)
    lines = (tmp_path / "r" / "data.csv").read_text().splitlines()
    ts = [ln.split(",", 1)[0] for ln in lines[1:]]
    assert ts[1263] == "1.263"
    assert all(len(s) <= 5 for s in ts), [s for s in ts if len(s) > 5][:3]   # never 1.2630000000000001


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1e9, 1e9, allow_nan=False, allow_infinity=False, width=64), min_size=1, max_size=30))
def test_exact_channels_read_back_bit_for_bit(tmp_path_factory, values):
    d = tmp_path_factory.mktemp("rt") / "r"
    n = len(values)
    cols = {"t": np.arange(n) / 1000.0, **{c: np.zeros(n) for c in CMD}, "tip_x": np.array(values)}
    write_recording(d, cols, sample_rate_hz=1000, exact=True)
    rec = read_recording(d)
    np.testing.assert_array_equal(rec["tip_x"], np.array(values))
    np.testing.assert_array_equal(rec.t, cols["t"])
    assert not os.path.exists(str(d) + ".partial")


def test_values_the_reader_would_refuse_are_refused_at_write_time(tmp_path):
    cols = {"t": np.arange(3) / 1000.0, **{c: np.zeros(3) for c in CMD}, "tip_x": np.array([0.0, 2e9, 0.0])}
    with pytest.raises(InputError, match=r"tip_x.*row 1.*out of range"):
        write_recording(tmp_path / "r", cols, sample_rate_hz=1000)
    assert not (tmp_path / "r").exists() and not (tmp_path / "r.partial").exists()


@settings(max_examples=25, deadline=None)
@given(cut=st.floats(0.0, 1.0, exclude_max=True))
def test_a_row_cut_by_a_kill_is_left_out_of_an_incomplete_recording_only(tmp_path_factory, cut):
    """A writer killed in the middle of a row leaves a last line without its newline: an incomplete
    recording loads without it (whole reader and chunked reader alike, every whole row kept); a
    recording that says it is complete still refuses it, naming the line."""
    from pmctl.core.recording_chunks import read_columns
    tmp = tmp_path_factory.mktemp("torn")
    cols = _columns(30)
    with RecordingWriter(tmp / "s", list(cols), sample_rate_hz=1000) as w:
        w.append(cols)
        w.finish(complete=False, reason="killed")
    data = tmp / "s" / "data.csv"
    text = data.read_bytes()
    last = text[:-1].rfind(b"\n") + 1                 # the last row, cut somewhere before its newline
    data.write_bytes(text[:last + int(cut * (len(text) - 1 - last))])
    rec = read_recording(tmp / "s")
    assert rec.n == 29 and np.array_equal(rec.t, cols["t"][:29])
    _, _, c = read_columns(tmp / "s")
    assert np.array_equal(c["t"], cols["t"][:29]) and np.allclose(c["cmd_L1"], cols["cmd_L1"][:29], atol=1e-9)
    meta = _meta(tmp / "s")
    meta["complete"] = True
    (tmp / "s" / "recording.json").write_text(json.dumps(meta))
    body = data.read_bytes()
    tail = body[body.rfind(b"\n") + 1:]
    if not tail:
        assert read_recording(tmp / "s").n == 29      # nothing was cut (the cut fell on the row's start)
    elif tail.count(b",") < len(cols) - 1:            # a row short of fields: refused, the line named
        with pytest.raises(InputError, match="data.csv"):
            read_recording(tmp / "s")
    else:                                             # cut inside the last number: a CSV reader cannot know
        assert read_recording(tmp / "s").n == 30
