"""pmctl-recording/1: write -> read round trip, strict validation with file/line/column."""

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core.errors import InputError
from pmctl.core.recording import (CMD, REQUIRED, RecordingWriter, channel_kind, read_recording,
                             write_recording)


def _columns(n, seed=0, extra=()):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(1e-4, 1e-2, n))
    cols = {"t": t}
    for c in CMD:
        cols[c] = rng.normal(300, 50, n)
    for c in extra:
        v = rng.normal(0, 10, n)
        v[rng.random(n) < 0.5] = np.nan
        cols[c] = v
    return cols


@pytest.fixture
def tmp(tmp_path):
    return tmp_path


def test_round_trip_exact_with_unknown_and_sparse_channels(tmp):
    cols = _columns(300, extra=("tip_x", "strain_2", "temp_screw1", "my_probe"))
    write_recording(tmp / "r", cols, sample_rate_hz=1000, exact=True, description="d",
                    channel_notes={"tip_x": {"source": "laser tracker"}})
    rec = read_recording(tmp / "r")
    assert rec.n == 300
    assert list(rec.columns)[:6] == list(REQUIRED)
    for k, v in cols.items():
        assert np.array_equal(rec[k], v, equal_nan=True), k
    assert rec.unknown_columns == ["my_probe"]
    assert rec.channel_notes == {"tip_x": {"source": "laser tracker"}}
    assert rec.machine.name == "prototype" and rec.machine_path.name == "prototype.toml"
    assert rec.sample_rate_hz == 1000 and rec.description == "d"
    assert read_recording(tmp / "r" / "data.csv").n == 300          # a file in the folder works too


names = st.sampled_from(["enc_L1", "enc_X", "tip_x", "tip_z", "tool_k", "strain_1", "load_fz",
                         "temp_room", "spindle_rpm", "x.y"])
finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 40), st.lists(names, unique=True, max_size=5), st.data())
def test_write_read_round_trip_hypothesis(n, extra, data):
    rng_vals = data.draw(st.lists(st.one_of(finite, st.just(float("nan"))),
                                  min_size=n * (5 + len(extra)), max_size=n * (5 + len(extra))))
    dt = data.draw(st.lists(st.floats(min_value=1e-6, max_value=10.0), min_size=n, max_size=n))
    t0 = data.draw(st.floats(min_value=0, max_value=1e4))
    cols = {"t": t0 + np.cumsum(dt)}
    vals = np.array(rng_vals).reshape(n, -1)
    for j, c in enumerate(list(CMD) + extra):
        cols[c] = vals[:, j]
    if np.any(np.diff(cols["t"]) <= 0):
        return                                   # float rounding made t flat: not a valid recording
    d = Path(tempfile.mkdtemp(prefix="rec-"))
    try:
        write_recording(d / "r", cols, sample_rate_hz=100.0)
        rec = read_recording(d / "r")
        assert np.array_equal(rec.t, cols["t"])          # t is written exact
        for k, v in cols.items():
            assert np.array_equal(np.isnan(rec[k]), np.isnan(v)), k
            assert np.allclose(rec[k], v, rtol=1e-9, atol=0, equal_nan=True), k
        assert rec.unknown_columns == [c for c in extra if channel_kind(c) is None]
    finally:
        shutil.rmtree(d)


def _write_raw(folder, header, rows, meta=None):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "recording.json").write_text(json.dumps(meta or {"format": "pmctl-recording/1",
                                                              "machine": "prototype",
                                                              "sample_rate_hz": 1000}))
    (folder / "data.csv").write_text("\n".join([header] + rows) + "\n")


HEADER = "t,cmd_L1,cmd_L2,cmd_L3,cmd_X,cmd_Y,tip_x"


def _rows(n):
    return [f"{0.001 * i!r},393.2,393.3,393.4,{i * 0.01:.3f},0,{'' if i % 3 else 1.5}" for i in range(n)]


bad_tokens = st.sampled_from(["abc", "1.2.3", "0x1F", "1e", "--1", "inf", "-Infinity", "1_000",
                              "\"1\"", "1 2", "1e999", "NaNa", "٣"])


@settings(max_examples=60, deadline=None)
@given(st.integers(5, 30), st.data())
def test_corrupted_cell_reports_line_and_column(n, data):
    rows = _rows(n)
    r = data.draw(st.integers(0, n - 1))
    c = data.draw(st.integers(1, 6))               # not t (column 0): t has its own rule
    tok = data.draw(bad_tokens)
    cells = rows[r].split(",")
    cells[c] = tok
    rows[r] = ",".join(cells)
    d = Path(tempfile.mkdtemp(prefix="rec-"))
    try:
        _write_raw(d, HEADER, rows)
        with pytest.raises(InputError) as ei:
            read_recording(d)
        e = ei.value
        assert e.path.endswith("data.csv")
        assert (e.line, e.column) == (r + 2, c + 1), str(e)
    finally:
        shutil.rmtree(d)


@settings(max_examples=40, deadline=None)
@given(st.integers(5, 30), st.data())
def test_ragged_row_and_non_monotonic_t(n, data):
    rows = _rows(n)
    r = data.draw(st.integers(1, n - 1))
    kind = data.draw(st.sampled_from(["short", "long", "t_equal", "t_back", "t_empty"]))
    cells = rows[r].split(",")
    if kind == "short":
        cells = cells[:-1]
        expect_col = 7
    elif kind == "long":
        cells = cells + ["1"]
        expect_col = 8
    elif kind == "t_equal":
        cells[0] = rows[r - 1].split(",")[0]
        expect_col = 1
    elif kind == "t_back":
        cells[0] = "-1"
        expect_col = 1
    else:
        cells[0] = ""
        expect_col = 1
    rows[r] = ",".join(cells)
    # a blank line before the bad row moves it down one line: the report must follow
    blank = data.draw(st.booleans())
    if blank:
        rows.insert(r, "")
    d = Path(tempfile.mkdtemp(prefix="rec-"))
    try:
        _write_raw(d, HEADER, rows)
        with pytest.raises(InputError) as ei:
            read_recording(d)
        assert (ei.value.line, ei.value.column) == (r + 2 + blank, expect_col), str(ei.value)
    finally:
        shutil.rmtree(d)


def test_missing_required_column_names_it(tmp):
    _write_raw(tmp, "t,cmd_L1,cmd_L2,cmd_X,cmd_Y", ["0,1,2,3,4"])
    with pytest.raises(InputError, match="cmd_L3") as ei:
        read_recording(tmp)
    assert ei.value.line == 1


def test_duplicate_and_empty_header_names(tmp):
    _write_raw(tmp, HEADER + ",tip_x", ["0,1,2,3,4,5,6,7"])
    with pytest.raises(InputError, match="twice") as ei:
        read_recording(tmp)
    assert (ei.value.line, ei.value.column) == (1, 8)
    _write_raw(tmp, HEADER + ",", ["0,1,2,3,4,5,6,7"])
    with pytest.raises(InputError, match="empty channel name"):
        read_recording(tmp)


@pytest.mark.parametrize("meta_text, match", [
    ('{"format": "pmctl-recording/1", "machine": "prototype",', "not valid JSON"),
    ('[1, 2]', "JSON object"),
    ('{"format": "pmctl-recording/2"}', "format"),
    ('{"machine": "prototype"}', "format"),
    ('{"format": "pmctl-recording/1", "machine": "no-such-machine"}', "unknown machine"),
    ('{"format": "pmctl-recording/1", "sample_rate_hz": -5}', "sample_rate_hz"),
    ('{"format": "pmctl-recording/1", "channels": [1]}', "channels"),
])
def test_bad_recording_json(tmp, meta_text, match):
    _write_raw(tmp, HEADER, _rows(3))
    (tmp / "recording.json").write_text(meta_text)
    with pytest.raises(InputError, match=match) as ei:
        read_recording(tmp)
    assert ei.value.path.endswith("recording.json")


def test_bad_json_reports_line(tmp):
    _write_raw(tmp, HEADER, _rows(3))
    (tmp / "recording.json").write_text('{\n  "format": "pmctl-recording/1",\n  "machine": prototype\n}')
    with pytest.raises(InputError) as ei:
        read_recording(tmp)
    assert ei.value.line == 3


def test_json_comments_crlf_bom_and_relative_machine(tmp):
    """Other loggers' quirks load unchanged: the spec's commented JSON, CRLF, a BOM, a machine file."""
    shutil.copy(Path(__file__).resolve().parents[2] / "config" / "prototype.toml", tmp / "mine.toml")
    rec_dir = tmp / "r"
    rec_dir.mkdir()
    (rec_dir / "recording.json").write_text(
        '{\n "format": "pmctl-recording/1",  // the format\n "machine": "../mine.toml",\n'
        ' /* nominal */ "sample_rate_hz": 1000\n}')
    text = "\ufeff" + "\r\n".join([HEADER] + _rows(10)) + "\r\n"
    (rec_dir / "data.csv").write_bytes(text.encode("utf-8"))
    rec = read_recording(rec_dir)
    assert rec.n == 10 and rec.machine_path.name == "mine.toml"
    assert np.isnan(rec["tip_x"][1]) and rec["tip_x"][0] == 1.5
    assert rec.t[3] == 0.003


def test_whitespace_and_nan_cells_are_not_sampled(tmp):
    rows = ["0, 1 ,2,3,4,5, ", "0.1,1,2,3,4,5,nan", "0.2,1,2,3,4,5,NaN"]
    _write_raw(tmp, HEADER, rows)
    rec = read_recording(tmp)
    assert np.all(np.isnan(rec["tip_x"])) and rec["cmd_L1"][0] == 1.0


def test_no_samples_is_an_error(tmp):
    _write_raw(tmp, HEADER, [])
    with pytest.raises(InputError, match="no samples"):
        read_recording(tmp)


def test_writer_refuses_bad_data_and_leaves_nothing(tmp):
    cols = _columns(10)
    bad = dict(cols, t=cols["t"][::-1].copy())
    with pytest.raises(InputError, match="strictly increasing"):
        write_recording(tmp / "w", bad, sample_rate_hz=10)
    assert not (tmp / "w" / "data.csv").exists()
    with pytest.raises(InputError, match="cmd_Y"):
        write_recording(tmp / "w", {k: v for k, v in cols.items() if k != "cmd_Y"}, sample_rate_hz=10)
    with pytest.raises(InputError, match="lengths"):
        write_recording(tmp / "w", dict(cols, cmd_X=cols["cmd_X"][:5]), sample_rate_hz=10)
    with pytest.raises(InputError, match="infinite"):
        write_recording(tmp / "w", dict(cols, tip_x=np.full(10, np.inf)), sample_rate_hz=10)
    with pytest.raises(InputError, match="machine"):
        write_recording(tmp / "w", cols, sample_rate_hz=10, machine="nope")
    assert not (tmp / "w" / "data.csv").exists()


def test_streaming_writer_matches_whole_writer(tmp):
    cols = _columns(1000, extra=("enc_L1",))
    with RecordingWriter(tmp / "s", list(cols), sample_rate_hz=1000) as w:
        for s in range(0, 1000, 97):
            w.append({k: v[s:s + 97] for k, v in cols.items()})
    write_recording(tmp / "w", cols, sample_rate_hz=1000)
    assert (tmp / "s" / "data.csv").read_bytes() == (tmp / "w" / "data.csv").read_bytes()
    # a chunk that goes back in time is refused and the half-written file never appears
    with pytest.raises(InputError):
        with RecordingWriter(tmp / "x", list(cols), sample_rate_hz=1000) as w:
            w.append({k: v[:10] for k, v in cols.items()})
            w.append({k: v[:10] for k, v in cols.items()})
    assert not (tmp / "x" / "data.csv").exists()


# ---------------------------------------------------------------- the fast and the strict path agree

from pmctl.core.recording import _fast_parse, _slow_parse, read_meta  # noqa: E402

NAMES = list(REQUIRED)
_cell = st.one_of(
    st.sampled_from(["", " ", "nan", "NaN", "-nan", "1", "-2.5", "+.5", "1e3", "1E-3", "5.", ".", "e", "1e",
                     "1e400", "-1e999", "inf", "1_0", "0x1", "1 2", "\t3\t", "\u0661", "\uff11", "1\u00a0",
                     "\x0b1", "1\x1c", "nan(1)", "na", "N", "--1", "1.5.5", '"1"']),
    st.text(alphabet="0123456789+-.eEnaN \t\u00b2\u00e9", max_size=6))


@st.composite
def bodies(draw):
    rows = draw(st.lists(st.lists(_cell, min_size=5, max_size=7), min_size=1, max_size=5))
    sep = draw(st.sampled_from(["\n", "\n\n", "\n \n"]))
    return sep.join(",".join(r) for r in rows).encode("utf-8")


def _strict(body):
    try:
        return _slow_parse(body, NAMES, Path("d.csv"), 2)[0]
    except InputError:
        return None


@settings(max_examples=300, deadline=None)
@given(bodies())
def test_fast_path_reads_exactly_what_the_strict_path_reads(body):
    fast = _fast_parse(body, len(NAMES))
    if fast is not None:               # the fast path only ever answers what the strict one would
        strict = _strict(body)
        assert strict is not None, body
        assert fast.shape == strict.shape and np.array_equal(fast, strict, equal_nan=True), body


def test_stray_non_ascii_byte_in_a_number_is_refused_by_both_paths(tmp):
    write_recording(tmp / "r", _columns(5), sample_rate_hz=100)
    data = tmp / "r" / "data.csv"
    lines = data.read_bytes().split(b"\n")
    for bad in (b"3\xc2\xb200.5", "３00.5".encode(), b"300\xa0.5", b"30\xff0.5"):
        cells = lines[3].split(b",")
        cells[1] = bad
        data.write_bytes(b"\n".join(lines[:3] + [b",".join(cells)] + lines[4:]))
        with pytest.raises(InputError) as e:
            read_recording(tmp / "r")
        assert e.value.line == 4 and e.value.column == 2 and "not a number" in e.value.reason
        assert _fast_parse(b"\n".join(lines[1:3] + [b",".join(cells)]), 6) is None


@pytest.mark.parametrize("meta,words", [
    ('{"format": "pmctl-recording/1", "x": ' + "[" * 100_000 + "]" * 100_000 + "}", "nested too deeply"),
    ('{"format": "pmctl-recording/1", "sample_rate_hz": ' + "9" * 5000 + "}", "not valid JSON"),
    ('{"format": "pmctl-recording/1", "sample_rate_hz": ' + "9" * 400 + "}", "sample_rate_hz: must be a positive"),
    ('{"format": "pmctl-recording/1", "sample_rate_hz": NaN}', "NaN is not a JSON number"),
    ('{"format": "pmctl-recording/1", "machine": "a\\u0000b"}', "machine: must be a config name"),
    ('{"format": "pmctl-recording/1", "machine": "' + "x" * 5000 + '"}', "machine: must be a config name"),
    ('{"format": "pmctl-recording/1", "machine": "' + "x/" * 300 + '"}', "unknown machine"),
])
def test_hostile_recording_json_is_an_input_error(tmp, meta, words):
    d = tmp / "r"
    d.mkdir()
    (d / "recording.json").write_text(meta)
    with pytest.raises(InputError) as e:
        read_meta(d)
    assert words in str(e.value)


def test_values_beyond_physical_bounds_are_refused_with_line_and_column(tmp):
    cols = _columns(6, extra=("tip_x",))
    write_recording(tmp / "r", cols, sample_rate_hz=100)
    data = tmp / "r" / "data.csv"
    lines = data.read_text().split("\n")
    cells = lines[4].split(",")
    names = lines[0].split(",")
    cells[names.index("cmd_L2")] = "1e300"
    data.write_text("\n".join(lines[:4] + [",".join(cells)] + lines[5:]))
    with pytest.raises(InputError) as e:
        read_recording(tmp / "r")
    assert e.value.line == 5 and e.value.column == names.index("cmd_L2") + 1
    assert "cmd_L2" in e.value.reason and "1e+300 is out of range (|value| <= 1e+09)" in e.value.reason
