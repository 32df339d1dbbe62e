"""Look-alikes (issue 12): effects that predict the same data within noise are reported as such, and
the one named is chosen for its physics (pmctl.tools.twin.lookalikes)."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pmctl.core.config import load_machine
from pmctl.tools.twin import calibration
from pmctl.tools.twin import lookalikes as lk
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import diagnose
from pmctl.tools.twin.effects import direction
from pmctl.tools.twin.fix import compensation_from_findings

M = load_machine()


# ---------------------------------------------------------------- the choice, pure

@settings(max_examples=60, deadline=None)
@given(v=st.floats(1e-6, 10.0), eff_par=st.sampled_from(sorted(lk.PLAUSIBLE)))
def test_plausibility_is_one_inside_its_range_and_falls_with_the_distance_outside(v, eff_par):
    lo, hi = lk.PLAUSIBLE[eff_par]
    eff, par = eff_par
    w = lk.plausibility(eff, {par: v})
    if lo <= v <= hi:
        assert w == 1.0
    else:
        assert 0.0 <= w < 1.0
        further = v / 2 if v < lo else v * 2            # twice as far out: lower still
        assert lk.plausibility(eff, {par: further}) < w or w == 0.0
        assert lk.plausibility(eff, {par: -v}) == w     # a magnitude: the sign does not matter


@settings(max_examples=40, deadline=None)
@given(off=st.floats(0.002, 0.025), s1=st.floats(0, 1e4), s2=st.floats(0, 1e4))
def test_a_play_in_its_range_is_named_over_a_length_offset_of_its_half_width(off, s1, s2):
    group = [{"effect": "geometry", "params": {"length_offset_mm": off}, "score": s1},
             {"effect": "backlash", "params": {"width_mm": 2 * off}, "score": s2}]
    k, ws = lk.choose(group)
    assert group[k]["effect"] == "backlash" and ws[k] / sum(ws) == 2 / 3


def test_an_offset_too_large_for_a_play_stays_a_length_offset_or_a_sensor_offset():
    group = [{"effect": "geometry", "params": {"length_offset_mm": 0.11}, "score": 1.0},
             {"effect": "backlash", "params": {"width_mm": 0.22}, "score": 2.0}]
    assert group[lk.choose(group)[0]]["effect"] == "geometry"
    group = [{"effect": "sensor_offset", "params": {"offset": -0.033}, "score": 1.0},
             {"effect": "backlash", "params": {"width_mm": 0.066}, "score": 2.0}]
    assert group[lk.choose(group)[0]]["effect"] == "sensor_offset"


def test_an_offset_is_named_over_a_slope_and_equal_weights_keep_the_ranking():
    group = [{"effect": "sensor_gain", "params": {"gain": 1.04}, "score": 5.0},
             {"effect": "sensor_offset", "params": {"offset": -1.4}, "score": 4.0}]
    assert group[lk.choose(group)[0]]["effect"] == "sensor_offset"
    group = [{"effect": "compliance", "params": {"stiffness_N_per_mm": 1000.0}, "score": 5.0},
             {"effect": "geometry", "params": {"length_offset_mm": -0.08}, "score": 4.0}]
    assert group[lk.choose(group)[0]]["effect"] == "geometry"
    group = [{"effect": "thermal_growth", "params": {"alpha_per_K": 1e-5}, "score": 3.0},
             {"effect": "thermal_growth", "params": {"alpha_per_K": 1.2e-5}, "score": 4.0}]
    assert lk.choose(group)[0] == 0      # equal weights: the selection's own ranking stays


# ---------------------------------------------------------------- a diagnosis

def _reversals(x):
    d = direction(x)
    d = d[d != 0]
    return int(np.sum(d[1:] != d[:-1]))


def test_a_backlash_on_a_leg_that_never_reverses_is_named_with_its_look_alike():
    """In a short pocket run the legs plunge once and never reverse: a backlash of width w is then
    a constant offset of w/2, the same as a length offset of the leg. The report names the backlash
    (its sign follows the travel), lists the length offset as the alternative, says which run
    would separate them, and its confidence is at most 2/3."""
    e = synth.Effect("backlash", {"axis": "L3"}, {"width_mm": 0.022})
    case = synth.synth_case(np.random.default_rng(7), [e], machine=M, seed=7, duration_s=10.0, rate_hz=1000.0,
                            run="raster")
    q = case.columns["cmd_L3"]
    assert _reversals(q) == 0 and np.ptp(q) > 1.0          # the premise: L3 moves, one way only
    rep, ex = diagnose(case.columns, M, cap=2000)
    f = [f for f in rep["findings"] if f.get("axis") == "L3" or f.get("chain") == 3]
    assert len(f) == 1, rep["findings"]
    f = f[0]
    assert f["effect"] == "backlash" and math.isclose(f["parameters"]["width_mm"], 0.022, rel_tol=0.2), f
    alt = [a for a in f["alternatives"] if a["effect"] == "geometry"]
    assert alt and alt[0]["chain"] == 3, f["alternatives"]
    assert math.isclose(abs(alt[0]["parameters"]["length_offset_mm"]), f["parameters"]["width_mm"] / 2, rel_tol=0.02)
    assert "reverses the axis" in f["separate_by"] and "cannot tell it from geometry" in f["evidence"]
    assert f["confidence"] <= round(2 / 3, 2)          # (the report rounds to 2 digits)
    # never compensated: a backlash table on a leg whose error is a length offset adds the play
    comp, notes = compensation_from_findings(M, ex["accepted"])
    assert comp is None and any("L3: backlash -> not written" in n for n in notes), notes


def test_a_compensation_is_written_only_when_every_look_alike_leaves_it_right():
    assert lk.compensation_safe("backlash", [])
    assert lk.compensation_safe("backlash", ["friction"])           # both flip at each reversal
    assert not lk.compensation_safe("backlash", ["geometry"])       # a length offset does not
    assert not lk.compensation_safe("backlash", ["friction", "sensor_offset"])
    assert lk.compensation_safe("pitch_error", ["periodic_error"])
    assert lk.separate_by(["backlash", "friction"]).startswith("encoders on the motor side")


def test_a_gain_on_a_steady_tracker_channel_stays_the_offsets_look_alike():
    """Blind case 12000/sensor_gain/1: a gain of 0.9998 on tip_z in a circle run, where the tip's
    height hardly changes (0.4 µm peak to peak, below the noise the prediction carries). A gain on
    that steady 139 mm level reads exactly as a −28 µm offset: the two are look-alikes, and the
    report must say so. When the gain was refused for a signal that does not vary beyond its noise,
    the offset was named alone with confidence 0.99."""
    seed = 83272
    case = synth.synth_case(np.random.default_rng(seed), ["sensor_gain"], machine=load_machine(), seed=seed,
                            duration_s=10.0, rate_hz=250.0, imperfections=True)
    (e,) = case.answer["effects"]
    assert e["channel"] == "tip_z" and case.answer["run"] == "circle"
    rep, ex = diagnose(case.columns, load_machine(), cap=2000)
    (f,) = [f for f in rep["findings"] if f.get("channel") == "tip_z"]
    assert {a["effect"] for a in f.get("alternatives", [])} | {f["effect"]} == {"sensor_gain", "sensor_offset"}
    assert f["confidence"] <= 0.67 + 1e-9
    # the features a blind evaluation saves give back the confidence the report printed, cap included
    for item, feat in zip(rep["findings"], ex["features"]):
        assert round(calibration.confidence(feat), 2) == item["confidence"]
    assert ex["features"][rep["findings"].index(f)]["weight_share"] <= 0.67 + 1e-9
