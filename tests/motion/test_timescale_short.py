"""Sample rows of very short stretches (0, 1, 2 samples): a dwell of 0 s (G4 P0) or an item that
plans to nothing must give well-formed rows, never an exception in the supervisor's planner."""

import numpy as np
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.motion.nc import NCParams
from pmctl.motion.timescale import FLAG_END, S_CAP, S_FLAGS, S_QT, S_QTT, WIDTH, derivatives, make_rows
from pmctl.core.job import home_pose

M = load_machine()
DT = 1e-3
finite = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=150, deadline=None)
@given(n=st.integers(0, 4), k=st.integers(1, 5), q0=finite, v=st.floats(-100, 100, allow_nan=False),
       before=st.booleans(), after=st.booleans())
def test_derivatives_of_a_straight_line_at_any_length(n, k, q0, v, before, after):
    """Samples of a line at constant speed: q_tau = v and q_tautau = 0 at every length, with or
    without the neighbours outside the stretch -- except one sample alone, which is at rest."""
    lane = np.arange(k, dtype=float)
    line = lambda i: q0 + lane + v * i * DT           # noqa: E731
    q = np.array([line(i) for i in range(n)]).reshape(n, k)
    qb = line(-1) if before else None
    qa = line(n) if after else None
    qt, qtt = derivatives(q, DT, qb, qa)
    assert qt.shape == (n, k) and qtt.shape == (n, k)
    assert np.all(np.isfinite(qt)) and np.all(np.isfinite(qtt))
    if n == 0:
        return
    expect = 0.0 if (n == 1 and not before and not after) else v
    assert np.allclose(qt, expect, atol=1e-6 * (1 + abs(q0)) / DT)
    assert np.allclose(qtt, 0.0, atol=1e-6 * (1 + abs(q0)) / DT ** 2)


def test_rows_of_zero_and_one_sample():
    params = NCParams.from_machine(M, DT, kv=400.0)
    tip, axis = home_pose(M)
    q = K.ik(tip, axis, M).q
    rows = make_rows(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 5)), np.zeros(0), DT, params)
    assert rows.shape == (0, WIDTH)
    one = make_rows(tip[None], axis[None], q[None], np.array([7]), DT, params)
    assert one.shape == (1, WIDTH) and one[0, S_FLAGS] == FLAG_END          # a job end, at rest
    assert np.all(one[0, S_QT:S_QTT + 5] == 0.0) and one[0, S_CAP] > 0
