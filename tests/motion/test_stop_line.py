"""The rt process's last line says whether the devices agree with the counters it saved: exactly for
a backend with pulse counters (the step/dir bridge, the sim), within a pulse for drives that report
positions only (canopen). A disagreement names the axis and the pulses."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from pmctl.hal.base import Feedback
from pmctl.motion.rtproc import device_agreement

PPM = np.array([1000.0, 1000.0, 1000.0, 200.0, 200.0])
COUNTS = np.array([786499, 786501, 786503, -1200, 4000], np.int64)


def test_counters_held_by_the_device_must_be_the_saved_ones():
    fb = Feedback()
    fb.counts = COUNTS.copy()
    assert device_agreement(fb, COUNTS, PPM) == "device counters = counters: yes"
    fb.counts[4] += 1
    assert device_agreement(fb, COUNTS, PPM) == "device counters = counters: NO"
    assert device_agreement(None, COUNTS, PPM) == "device counters: none read"


@given(axis=st.integers(0, 4), off=st.integers(-5000, 5000), frac=st.floats(-0.49, 0.49))
def test_drive_positions_within_a_pulse_agree_and_further_names_the_axis(axis, off, frac):
    fb = Feedback()                                # counts None: drives with position feedback only
    fb.enc = COUNTS / PPM + frac / PPM             # within half a pulse everywhere
    assert device_agreement(fb, COUNTS, PPM) == "drive positions = counters: yes (within a pulse)"
    fb.enc[axis] += off / PPM[axis]
    line = device_agreement(fb, COUNTS, PPM)
    if abs(off) <= 1:
        assert line.endswith("yes (within a pulse)"), line
    else:
        assert line.startswith(f"drive positions = counters: NO ({('L1', 'L2', 'L3', 'X', 'Y')[axis]} {off:+d} pulses"), line
    fb.enc[axis] = np.nan
    assert device_agreement(fb, COUNTS, PPM) == "drive positions = counters: unknown (no position read)"
