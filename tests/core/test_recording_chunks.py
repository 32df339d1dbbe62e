"""Bounded-memory reading (pmctl.core.recording_chunks) agrees with the whole-file reader."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core.errors import InputError
from pmctl.core.recording import read_recording, write_recording
from pmctl.core.recording_chunks import iter_chunks, read_columns


def _rec(tmp_path, n=500, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))
    cols = {"t": t, **{f"cmd_{a}": rng.normal(0, 50, n) for a in ("L1", "L2", "L3", "X", "Y")},
            "tip_x": np.where(rng.random(n) < 0.3, rng.normal(0, 1, n), np.nan),
            "strain_1": rng.normal(0, 5, n), "odd_col": rng.normal(0, 1, n)}
    return write_recording(tmp_path / "r", cols, sample_rate_hz=1000), cols


@settings(max_examples=15, deadline=None)
@given(st.integers(64, 5000), st.integers(0, 1000))
def test_chunks_in_any_block_size_give_the_whole_file_readers_columns(tmp_path_factory, block, seed):
    folder, _ = _rec(tmp_path_factory.mktemp("c"), 300, seed)
    ref = read_recording(folder)
    meta, machine, cols = read_columns(folder, block_bytes=block, measured_dtype=np.float64)
    assert set(cols) == set(ref.columns) - {"odd_col"}          # unknown columns are not kept
    for k, v in cols.items():
        assert np.array_equal(v, ref.columns[k], equal_nan=True), k
    assert meta["format"] == "pmctl-recording/1" and machine.name == ref.machine.name


@settings(max_examples=25, deadline=None)
@given(st.integers(64, 4000), st.integers(0, 1000), st.lists(st.integers(0, 299), min_size=1, max_size=6, unique=True))
def test_the_direction_of_each_commands_last_motion_before_each_kept_range(tmp_path_factory, block, seed, cuts):
    # commands that dwell (runs of equal values) and move both ways, read in blocks of any size: for
    # each kept range, the sign of the command's last change before its first row (0: none yet)
    rng = np.random.default_rng(seed)
    n = 300
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))
    steps = np.where(rng.random((n, 5)) < 0.15, rng.normal(0, 1, (n, 5)), 0.0)
    cols = {"t": t, **{f"cmd_{a}": np.cumsum(steps[:, i]) for i, a in enumerate(("L1", "L2", "L3", "X", "Y"))}}
    for x in cols.values():          # empty cells: the command holds its value through them
        if x is not t:
            x[rng.random(n) < 0.05] = np.nan
    folder = write_recording(tmp_path_factory.mktemp("d") / "r", cols, sample_rate_hz=1000)
    starts = sorted(cuts)
    rows = [(a, b) for a, b in zip(starts, starts[1:] + [n]) if b > a]
    info = {}
    read_columns(folder, block_bytes=block, rows=rows, info=info)
    for (a, _), got in zip(rows, info["cmd_direction_before"]):
        for name, x in cols.items():
            if name == "t":
                continue
            xs = x[:a][np.isfinite(x[:a])]
            dx = np.diff(xs)
            moved = np.flatnonzero(dx != 0)
            want = float(np.sign(dx[moved[-1]])) if len(moved) else 0.0
            assert got.get(name, 0.0) == want, (a, name)


def test_measured_channels_in_float32_keep_the_commands_exact(tmp_path):
    folder, _ = _rec(tmp_path)
    ref = read_recording(folder)
    _, _, cols = read_columns(folder, block_bytes=1000)
    assert cols["t"].dtype == np.float64 and cols["cmd_X"].dtype == np.float64
    assert np.array_equal(cols["cmd_X"], ref["cmd_X"])
    assert cols["strain_1"].dtype == np.float32
    assert np.allclose(cols["strain_1"], ref["strain_1"], rtol=1e-6)


def test_a_bad_cell_and_a_time_reversal_are_named_by_line_across_block_boundaries(tmp_path):
    folder, _ = _rec(tmp_path, 200)
    p = folder / "data.csv"
    lines = p.read_text().splitlines()
    bad = lines.copy()
    cells = bad[150].split(",")
    cells[3] = "x1"
    bad[150] = ",".join(cells)
    p.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError) as e:
        for _ in iter_chunks(folder, block_bytes=700):
            pass
    assert e.value.line == 151 and e.value.column == 4
    rev = lines.copy()
    rev[120], rev[121] = rev[121], rev[120]          # t goes back at file line 122
    p.write_text("\n".join(rev) + "\n")
    for block in (300, 10_000):
        with pytest.raises(InputError) as e:
            read_columns(folder, block_bytes=block)
        assert e.value.line == 122 and "strictly increasing" in str(e.value)
