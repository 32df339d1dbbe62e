"""`pmctl twin import`: bench logs in the formats users have become recordings of independent axes
whose channels, read back, hold the logged values in the twin's units."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import io as sio

from pmctl.core.errors import InputError, PmctlError
from pmctl.core.recording import read_recording
from pmctl.interfaces.cli import main
from pmctl.tools.twin.importers import detect_format, import_source

T = np.arange(200) * 0.002
POS = 0.05 * np.sin(2 * np.pi * T)            # m
CUR = 1.5 * np.cos(2 * np.pi * T)             # A


def test_a_csv_with_a_column_map_and_units(tmp_path, capsys):
    rows = "\n".join(f"{t * 1000:.3f}\t{p:.9f}\t{p + 1e-5:.9f}\t{c:.6f}" for t, p, c in zip(T, POS, CUR))
    (tmp_path / "bench.tsv").write_text("# scope export\ntime_ms\tpos_ref\tpos_act\tiq\n" + rows + "\n")
    assert main(["twin", "import", str(tmp_path / "bench.tsv"), str(tmp_path / "rec"),
                 "--map", "cmd_Z=pos_ref,enc_Z=pos_act", "--map", "effort_Z=iq",
                 "--unit", "cmd_Z=m,enc_Z=m", "--unit", "effort_Z=A", "--time", "time_ms", "--time-unit", "ms"]) == 0
    assert "pmctl twin diagnose" in capsys.readouterr().out
    rec = read_recording(tmp_path / "rec")
    assert rec.meta["machine"] == "axes" and rec.machine.axes == ("Z",)
    np.testing.assert_allclose(rec.t, T, atol=1e-9)
    np.testing.assert_allclose(rec["cmd_Z"], POS * 1000, atol=1e-6)
    np.testing.assert_allclose(rec["enc_Z"] - rec["cmd_Z"], 0.01, atol=1e-6)        # 1e-5 m = 0.01 mm
    np.testing.assert_allclose(rec["effort_Z"], CUR, atol=1e-6)
    assert rec.machine.units["effort_Z"] == "A" and rec.channel_notes["enc_Z"]["source"] == "bench.tsv: pos_act"


def test_halsampler_with_sample_numbers_and_a_thread_rate(tmp_path):
    lines = "\n".join(f"{k + 7} {p:.6f} {p * 0.999:.6f} 1" for k, p in enumerate(POS * 1000))
    (tmp_path / "hs.txt").write_text(lines + "\n")
    assert detect_format(tmp_path / "hs.txt") == "halsampler"
    folder, s = import_source(tmp_path / "hs.txt", tmp_path / "rec", mapping={"cmd_X": "1", "enc_X": "2"}, rate=500.0)
    rec = read_recording(folder)
    np.testing.assert_allclose(rec.t, T, atol=1e-12)          # sample numbers 7, 8, ... at 500 Hz from 0
    np.testing.assert_allclose(rec["enc_X"], np.round(POS * 1000 * 0.999, 6), atol=1e-9)


def test_a_halscope_log(tmp_path):
    body = "\n".join(f"joint.0.cmd {p:+.14f} joint.0.fb {p - 0.001:+.14f} " for p in POS * 1000)
    (tmp_path / "scope.log").write_text("Sampling period is 2000000 ns \n\n" + body + "\n")
    folder, s = import_source(tmp_path / "scope.log", tmp_path / "rec",
                              mapping={"cmd_A": "joint.0.cmd", "enc_A": "2"}, units={"cmd_A": "deg", "enc_A": "deg"})
    rec = read_recording(folder)
    assert s["format"] == "halscope" and rec.machine.rotary["A"]
    np.testing.assert_allclose(rec.t, T, atol=1e-12)
    np.testing.assert_allclose(rec["cmd_A"] - rec["enc_A"], 0.001, atol=1e-9)


def test_a_mat_file_with_a_scaled_variable(tmp_path):
    sio.savemat(tmp_path / "d.mat", {"t": T[:, None], "qg": POS[:, None], "qm": POS[:, None], "vir": CUR[:, None],
                                     "gtau": np.array([[35.15]])})
    folder, _ = import_source(tmp_path / "d.mat", tmp_path / "rec",
                              mapping={"cmd_X": "qg", "enc_X": "qm", "effort_X": "vir*gtau"},
                              units={"cmd_X": "m", "enc_X": "m", "effort_X": "N"}, time="t")
    rec = read_recording(folder)
    np.testing.assert_allclose(rec["effort_X"], CUR * 35.15, rtol=1e-12)
    np.testing.assert_allclose(rec["cmd_X"], POS * 1000, rtol=1e-12)


def test_klippers_raw_accelerometer_csv(tmp_path):
    rows = "\n".join(f"{100 + t:.6f},{1000 * np.sin(2 * np.pi * 40 * t):.3f},0.000,9810.000" for t in T)
    (tmp_path / "adxl.csv").write_text("#time,accel_x,accel_y,accel_z\n" + rows + "\n")
    folder, s = import_source(tmp_path / "adxl.csv", tmp_path / "rec")
    rec = read_recording(folder)
    assert s["format"] == "klipper" and set(rec.machine.axes) == {"X", "Y", "Z"}
    np.testing.assert_allclose(rec["acc_Z"], 9810.0) and np.testing.assert_allclose(rec["cmd_X"], 0.0)
    assert "held at 0" in rec.channel_notes["cmd_X"]["source"]
    (tmp_path / "psd.csv").write_text("freq,psd_x,psd_y,psd_z,psd_xyz\n" + "".join(f"{k},1,1,1,3\n" for k in range(20)))
    with pytest.raises(InputError, match="pmctl analyze resonance"):
        import_source(tmp_path / "psd.csv", tmp_path / "rec2")


def test_bad_input_is_refused_naming_the_file_the_line_or_the_option(tmp_path):
    (tmp_path / "b.csv").write_text("t,pos\n0,1\n0.1,x\n")
    with pytest.raises(InputError) as e:
        import_source(tmp_path / "b.csv", tmp_path / "r", mapping={"cmd_X": "pos"}, time="t")
    assert e.value.line == 3 and "'x' is not a number" in str(e.value)
    (tmp_path / "g.csv").write_text("t,pos\n0,1\n0.1,2\n0.2,3\n")
    with pytest.raises(InputError, match="no column or variable 'nope'"):
        import_source(tmp_path / "g.csv", tmp_path / "r", mapping={"cmd_X": "nope"}, time="t")
    with pytest.raises(PmctlError, match="needs its commanded position cmd_X"):
        import_source(tmp_path / "g.csv", tmp_path / "r", mapping={"enc_X": "pos"}, time="t")
    with pytest.raises(InputError, match="channels.cmd_X.unit"):
        import_source(tmp_path / "g.csv", tmp_path / "r", mapping={"cmd_X": "pos"}, units={"cmd_X": "N"}, time="t")
    with pytest.raises(PmctlError, match="--time COLUMN, or --rate HZ"):
        import_source(tmp_path / "g.csv", tmp_path / "r", mapping={"cmd_X": "pos"})
    assert not (tmp_path / "r").exists()            # nothing half-written
