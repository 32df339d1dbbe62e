"""The calibration's reported uncertainties pinned where a small error would hide (the mutation group
``calibration`` of tools/mutation/run_mutmut.py; the spread of repeated identifications is checked in
tests/tools/test_calibration.py):

- the predicted accuracy at the measured poses is the hat matrix's trace: a least-squares fit of
  ``rank`` combinations to m whitened measurements takes exactly ``rank`` of their m noise
  variances, so the model's predicted variance summed over the measured values (tip in um over the
  stated tip noise, axis in urad over the stated axis noise) is ``rank`` (times chi-square where the
  fit is worse than the stated noise), to rounding, for any machine, poses and noise;
- the identifiability limit ``rcond`` is inclusive: a combination whose relative singular value is
  exactly ``rcond`` is identified, with its finite 1-sigma; at the next float above, it is fixed.
"""

import math

import numpy as np
import pytest
from hypothesis import Phase, given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.tools.calibrate import identify as I, model as Mo

M = load_machine()
G = M.geometry


# (no shrinking: each example is an identification, and a failing one says enough as found)
@settings(max_examples=8, deadline=None, phases=(Phase.explicit, Phase.reuse, Phase.generate))
@given(seed=st.integers(0, 2**31), n=st.integers(12, 40), k=st.sampled_from([0.5, 1.0, 2.0]),
       has_axis=st.booleans(), stated=st.sampled_from([0.5, 1.0, 3.0]))
def test_the_predicted_accuracy_at_the_measured_poses_sums_to_the_identified_rank(seed, n, k, has_axis, stated):
    """n poses of a machine with random geometry errors, measured with k x the usual noise (2 um tip,
    10 urad axis), identified with ``stated`` x it as the stated noise: the sum over the poses of
    the predicted tip variance / stated tip noise^2 (+ the same for the axis when it is measured) is
    rank x max(chi^2, 1) to 1e-8 (measured: 1e-12). A predicted accuracy in um off by 0.1 %, or in
    urad off by one part in a million, breaks it."""
    rng = np.random.default_rng(seed)
    gt = Mo.random_geometry(G, rng)
    tip, ax = Mo.random_tool_poses(M, n, rng)
    q = K.ik_batch(tip, ax, M).q
    mt, ma = Mo.simulate_measurement(q, gt, rng, tip_sigma_mm=k * I.TIP_SIGMA_MM, axis_sigma_rad=k * I.AXIS_SIGMA_RAD)
    ts, as_ = stated * I.TIP_SIGMA_MM, stated * I.AXIS_SIGMA_RAD
    res = I.identify(q, mt, ma if has_axis else None, G, tip_sigma_mm=ts, axis_sigma_rad=as_)
    trace = n * (res.predicted_tip_um / (1e3 * ts)) ** 2
    if has_axis:
        trace += n * (res.predicted_axis_urad / (1e6 * as_)) ** 2
    assert 0 < res.rank <= Mo.N_PARAMS
    assert trace == pytest.approx(res.rank * max(res.chi2_red, 1.0), rel=1e-8), (trace, res.rank, res.chi2_red)
    assert res.predicted_tip_max_um >= res.predicted_tip_um


def test_a_combination_exactly_at_rcond_is_identified_and_one_just_below_it_is_not():
    """Two parameters measured nearly together (columns 4e-6 rad apart, gain 1e8): their difference
    has relative singular value theta/2 = 2e-6 and 1-sigma 1e-8 / (sqrt 2 sin(theta/2)) = 0.0035. With
    rcond equal to that relative singular value (the same float) it is identified with that 1-sigma;
    with rcond the next float above it, it is fixed (1-sigma inf) and the others are not affected."""
    theta = 4e-6
    m = Mo.N_PARAMS + 6
    J = np.zeros((m, Mo.N_PARAMS))
    J[np.arange(Mo.N_PARAMS), np.arange(Mo.N_PARAMS)] = 1e8
    J[:, 1] = 1e8 * (math.cos(theta) * np.eye(m)[0] + math.sin(theta) * np.eye(m)[1])
    *_, dirs = I.analyse(J)
    k = int(np.argmin([d.singular_value for d in dirs]))
    rel = dirs[k].singular_value
    assert rel == pytest.approx(theta / 2, rel=1e-3)
    want = 1e-8 / (math.sqrt(2) * math.sin(theta / 2))
    _, _, s, _, keep, at = I.analyse(J, rcond=rel)
    assert bool(keep[k]) and keep.sum() == Mo.N_PARAMS
    assert at[k].sigma == pytest.approx(want, rel=1e-3)
    _, _, _, _, keep2, above = I.analyse(J, rcond=float(np.nextafter(rel, 1.0)))
    assert not keep2[k] and above[k].sigma == math.inf
    assert keep2.sum() == Mo.N_PARAMS - 1
    assert [d.sigma for i, d in enumerate(above) if i != k] == [d.sigma for i, d in enumerate(at) if i != k]
