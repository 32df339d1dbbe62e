"""The twin on a machine of independent axes ("machine": "axes"): the recording format with units,
and the diagnosis of synth bench runs of a ball-screw axis made by the one plant
(pmctl.core.plant_effects through pmctl.tools.twin.synth_axes): each effect named, located, its
parameters within tolerance, the fit improved on held-out samples; a clean run clean; a push from
outside left unexplained where it happened."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmctl.core.errors import InputError
from pmctl.core.recording import read_recording, write_recording
from pmctl.core.recording_axes import axes_machine, convert
from pmctl.core.recording_chunks import read_columns
from pmctl.tools.twin.diagnose import diagnose
from pmctl.tools.twin.synth_axes import synth_axes_case, write_axes_case


def _diagnose(case):
    cols, notes, answer = case
    m, conv = axes_machine(list(cols), {"channels": notes})
    cols = convert({k: np.asarray(v, float) for k, v in cols.items()}, conv)
    rep, _ = diagnose(cols, m, name="bench")
    return rep, answer


def _found(rep, effect, **loc):
    hits = [f for f in rep["findings"] if f["effect"] == effect and all(f.get(k) == v for k, v in loc.items())]
    assert hits, f"{effect} {loc} not named: {[(f['effect'], f.get('axis') or f.get('channel')) for f in rep['findings']]}"
    return hits[0]


def _truth(answer, effect):
    return next(e["parameters"] for e in answer["effects"] if e["effect"] == effect)


def _improved(rep, ch, factor):
    """The held-out rms of channel ``ch`` after the findings (cumulative: the last finding that
    touches it) is ``factor`` times below the nominal twin's."""
    on = [f for f in rep["findings"] if ch in f["rms_after"]]
    before, after = on[0]["rms_before"][ch], on[-1]["rms_after"][ch]
    assert after * factor < before, (ch, before, after)


# ---------------------------------------------------------------- the format

def test_units_are_converted_on_read_and_the_axis_kind_follows_the_command(tmp_path):
    t = np.arange(50) / 1000.0
    cols = {"t": t * 1000.0, "cmd_X": np.sin(t) * 0.1, "enc_X": np.sin(t) * 0.1, "effort_X": np.cos(t),
            "cmd_A": t * 2.0, "enc_A": t * 2.0, "effort_A": np.cos(t) * 50.0, "acc_X": np.cos(t) * 9.0,
            "temp_motor": 300.0 + t}
    notes = {"t": {"unit": "ms"}, "cmd_X": {"unit": "m"}, "enc_X": {"unit": "m"}, "effort_X": {"unit": "kN"},
             "cmd_A": {"unit": "rad"}, "enc_A": {"unit": "rad"}, "effort_A": {"unit": "mN m"},
             "acc_X": {"unit": "m/s^2"}, "temp_motor": {"unit": "K"}}
    write_recording(tmp_path / "r", cols, machine="axes", sample_rate_hz=1000, channel_notes=notes, exact=True)
    rec = read_recording(tmp_path / "r")
    m = rec.machine
    assert m.axes == ("X", "A") and m.rotary == {"X": False, "A": True}
    np.testing.assert_allclose(rec.t, t, rtol=1e-12)                       # ms -> s
    np.testing.assert_allclose(rec["cmd_X"], np.sin(t) * 100.0, rtol=1e-12)    # m -> mm
    np.testing.assert_allclose(rec["effort_X"], np.cos(t) * 1000.0, rtol=1e-12)  # kN -> N
    np.testing.assert_allclose(rec["cmd_A"], np.degrees(t * 2.0), rtol=1e-12)   # rad -> deg
    np.testing.assert_allclose(rec["effort_A"], np.cos(t) * 0.05, rtol=1e-12)   # mN m -> N m
    np.testing.assert_allclose(rec["acc_X"], np.cos(t) * 9000.0, rtol=1e-12)    # m/s^2 -> mm/s^2
    np.testing.assert_allclose(rec["temp_motor"], 300.0 + t - 273.15, rtol=1e-12)
    assert m.units["effort_A"] == "N m" and m.units["acc_X"] == "mm/s^2"
    # the bounded reader the diagnosis uses converts the same way
    _, m2, c2 = read_columns(tmp_path / "r")
    np.testing.assert_allclose(c2["cmd_A"], rec["cmd_A"], rtol=1e-12)
    np.testing.assert_allclose(c2["effort_X"], rec["effort_X"], rtol=1e-6)


@pytest.mark.parametrize("notes, field, words", [
    ({"cmd_X": {"unit": "furlong"}}, "channels.cmd_X.unit", "length"),
    ({"cmd_X": {"unit": "deg"}, "enc_X": {"unit": "mm"}}, "channels.enc_X.unit", "angle"),
    ({"effort_X": {"unit": "N m"}}, "channels.effort_X.unit", "force"),
    ({"cmd_X": {"unit": "rad"}, "effort_X": {"unit": "N"}}, "channels.effort_X.unit", "torque"),
    ({"acc_X": {"unit": "g"}, "cmd_X": {"unit": "deg"}}, "channels.acc_X.unit", "rotary"),
])
def test_a_unit_of_the_wrong_kind_is_refused_naming_the_field(tmp_path, notes, field, words):
    t = np.arange(20) / 100.0
    cols = {"t": t, "cmd_X": t, "enc_X": t, "effort_X": t, "acc_X": t}
    write_recording(tmp_path / "r", cols, machine="axes", sample_rate_hz=100, channel_notes=notes)
    with pytest.raises(InputError) as e:
        read_recording(tmp_path / "r")
    assert field in str(e.value) and words in str(e.value) and "recording.json" in str(e.value)


def test_an_axis_channel_without_its_command_is_refused_naming_the_column(tmp_path):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "recording.json").write_text(json.dumps({"format": "pmctl-recording/1", "machine": "axes"}))
    (tmp_path / "r" / "data.csv").write_text("t,cmd_X,enc_Y\n0,0,0\n0.1,1,1\n")
    with pytest.raises(InputError) as e:
        read_recording(tmp_path / "r")
    assert "enc_Y" in str(e.value) and "cmd_Y" in str(e.value) and e.value.column == 3


@settings(max_examples=30, deadline=None)
@given(scale=st.sampled_from(["m", "mm", "um", "in", "cm"]), x=st.floats(-1e3, 1e3, allow_nan=False))
def test_a_length_reads_back_as_the_same_length_in_mm(scale, x):
    factor = {"m": 1e3, "mm": 1.0, "um": 1e-3, "in": 25.4, "cm": 10.0}[scale]
    m, conv = axes_machine(["t", "cmd_X"], {"channels": {"cmd_X": {"unit": scale}}})
    cols = convert({"t": np.zeros(1), "cmd_X": np.array([x])}, conv)
    assert math.isclose(cols["cmd_X"][0], x * factor, rel_tol=1e-12, abs_tol=1e-300)
    assert m.pos_unit("X") == "mm"


# ---------------------------------------------------------------- the diagnosis of bench runs

DRIVE = {"inertia": {"mass_kg": 60.0}, "friction": {"coulomb_N": 25.0, "viscous_N_s_per_m": 180.0}}


def test_the_drive_force_model_is_named_with_its_physical_parameters():
    rep, ans = _diagnose(synth_axes_case(np.random.default_rng(11), ["inertia", "friction", "force_offset"],
                                         params={**DRIVE, "force_offset": {"offset_N": -12.0}}, duration_s=12.0))
    inertia, fric, off = _found(rep, "inertia", axis="X"), _found(rep, "friction", axis="X"), \
        _found(rep, "force_offset", axis="X")
    assert inertia["parameters"]["mass_kg"] == pytest.approx(60.0, rel=0.02)
    assert fric["parameters"]["coulomb_N"] == pytest.approx(25.0, rel=0.03)
    assert fric["parameters"]["viscous_N_s_per_m"] == pytest.approx(180.0, rel=0.03)
    assert off["parameters"]["offset_N"] == pytest.approx(-12.0, rel=0.05)
    assert fric["where"]["channels"] == ["effort_X"]
    _improved(rep, "effort_X", 10.0)            # held out: rms of effort_X cut tenfold and more
    assert rep["verdict"] == "unmodelled physics found" and rep["unexplained"] == []


def test_asymmetric_viscous_friction_is_reported_by_direction():
    p = {**DRIVE, "friction": {"coulomb_N": 25.0, "viscous_N_s_per_m": 120.0, "viscous_neg_N_s_per_m": 240.0}}
    rep, _ = _diagnose(synth_axes_case(np.random.default_rng(12), ["inertia", "friction"], params=p,
                                       duration_s=12.0))
    f = _found(rep, "friction", axis="X")["parameters"]
    assert f["viscous_pos_N_s_per_m"] == pytest.approx(120.0, rel=0.05)
    assert f["viscous_neg_N_s_per_m"] == pytest.approx(240.0, rel=0.05)
    assert f["coulomb_N"] == pytest.approx(25.0, rel=0.05)


def test_servo_lag_backlash_and_compliance_of_the_load_encoder():
    p = {**DRIVE, "servo_tracking": {"lag_s": 0.006}, "backlash": {"width_mm": 0.02},
         "compliance": {"stiffness_N_per_mm": 5000.0}}
    rep, _ = _diagnose(synth_axes_case(np.random.default_rng(13), list(p), params=p, duration_s=12.0))
    assert _found(rep, "servo_tracking", axis="X")["parameters"]["lag_s"] == pytest.approx(0.006, rel=0.05)
    b = _found(rep, "backlash", axis="X")
    assert b["parameters"]["width_mm"] == pytest.approx(0.02, rel=0.1) and b["where"]["channels"] == ["load_X"]
    k = _found(rep, "compliance", axis="X")
    assert k["parameters"]["stiffness_N_per_mm"] == pytest.approx(5000.0, rel=0.1)
    _improved(rep, "load_X", 3.0)
    assert _found(rep, "inertia", axis="X")["parameters"]["mass_kg"] == pytest.approx(60.0, rel=0.03)


def test_a_carriage_mode_in_the_accelerometer_and_cogging_in_the_force():
    p = {**DRIVE, "resonance": {"freq_hz": 70.0, "damping_ratio": 0.05},
         "cogging": {"period_mm": 5.0, "amplitude_N": 4.0}}
    rep, _ = _diagnose(synth_axes_case(np.random.default_rng(14), list(p), params=p, duration_s=12.0))
    r = _found(rep, "resonance", channel="acc_X")
    assert r["parameters"]["freq_hz"] == pytest.approx(70.0, rel=0.02)
    assert r["parameters"]["damping_ratio"] == pytest.approx(0.05, rel=0.2)
    _improved(rep, "acc_X", 1.5)
    c = _found(rep, "cogging", axis="X")["parameters"]
    assert c["period_mm"] == pytest.approx(5.0, rel=0.02) and c["amplitude_N"] == pytest.approx(4.0, rel=0.1)


def test_a_clean_bench_run_is_consistent_with_the_nominal_twin():
    rep, _ = _diagnose(synth_axes_case(np.random.default_rng(15), [], clean=True, duration_s=12.0))
    assert rep["findings"] == [] and rep["unexplained"] == []
    assert rep["verdict"] == "consistent with the nominal twin"


def test_a_push_from_outside_is_unexplained_where_it_happened():
    rep, ans = _diagnose(synth_axes_case(np.random.default_rng(16), ["inertia", "friction"], params=DRIVE,
                                         oddities=["external_force"], duration_s=12.0))
    t0 = ans["oddities"][0]["t_s"]
    u = [e for e in rep["unexplained"] if "effort_X" in e["channels"]]
    assert u and any(a - 0.2 <= t0 <= b + 0.2 for a, b in u[0]["time_windows_s"]), (t0, rep["unexplained"])
    assert rep["verdict"] == "unexplained mismatch"
    assert {f["effect"] for f in rep["findings"]} <= {"inertia", "friction", "force_offset"}


def test_a_rotary_axis_reports_inertia_and_torques(tmp_path):
    cols, notes, ans = synth_axes_case(np.random.default_rng(17), ["inertia", "friction"], params=DRIVE,
                                       duration_s=10.0)
    # the same bench as a rotary axis: positions in rad (1 mm of the case -> 1 mrad), torque in N m
    rot = {"t": cols["t"], "cmd_B": cols["cmd_X"], "enc_B": cols["enc_X"], "effort_B": cols["effort_X"]}
    notes = {"cmd_B": {"unit": "rad"}, "enc_B": {"unit": "rad"}, "effort_B": {"unit": "N m"}}
    write_axes_case(tmp_path, "rot", (rot, notes, ans))
    rec = read_recording(tmp_path / "rot" / "recording")
    rep, _ = diagnose(rec.columns, rec.machine)
    inertia = _found(rep, "inertia", axis="B")["parameters"]
    fric = _found(rep, "friction", axis="B")["parameters"]
    # 60 kg at 1 m per rad (1 mm <-> 1 mrad) is 60 kg m^2; 180 N s/m is 180 N m s/rad
    assert inertia["inertia_kg_m2"] == pytest.approx(60.0, rel=0.03)
    assert fric["coulomb_Nm"] == pytest.approx(25.0, rel=0.03)
    assert fric["viscous_Nm_s_per_rad"] == pytest.approx(180.0, rel=0.03)


def test_diagnose_json_alone_prints_the_report_on_stdout(tmp_path, capsys):
    from pmctl.interfaces.cli import main
    write_axes_case(tmp_path, "c", synth_axes_case(np.random.default_rng(18), [], clean=True, duration_s=6.0))
    assert main(["twin", "diagnose", str(tmp_path / "c" / "recording"), "--json"]) == 0
    cap = capsys.readouterr()
    rep = json.loads(cap.out)                     # stdout is the JSON report only
    assert rep["verdict"] == "consistent with the nominal twin" and rep["units"]["enc_X"] == "mm"
    assert "WHERE the recording differs" in cap.err


def test_synth_machine_axes_writes_cases_with_their_answers_outside(tmp_path, capsys):
    from pmctl.interfaces.cli import main
    assert main(["twin", "synth", str(tmp_path / "o"), "--machine", "axes", "--effects", "inertia,backlash",
                 "--duration", "3", "--count", "2", "--seed", "5"]) == 0
    for k in ("case-000", "case-001"):
        ans = json.loads((tmp_path / "o" / k / "answer.json").read_text())
        assert [e["effect"] for e in ans["effects"]] == ["inertia", "backlash"]
        rec = read_recording(tmp_path / "o" / k / "recording")
        assert rec.machine.axes == ("X",) and "load_X" in rec and "answer.json" not in \
            [p.name for p in (tmp_path / "o" / k / "recording").iterdir()]
    capsys.readouterr()
    assert main(["twin", "synth", str(tmp_path / "p"), "--machine", "axes", "--effects", "geometry"]) != 0
    assert "not an effect of a bench axis" in capsys.readouterr().err and not (tmp_path / "p").exists()
