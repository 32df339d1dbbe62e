"""The stall reason says when the time went to the scheduler (a loaded machine), not to computing."""

from hypothesis import given, strategies as st

from pmctl.motion.loop import stall_hint


@given(gap=st.integers(1, 10**9), share=st.floats(0.0, 1.0))
def test_the_hint_names_the_scheduler_only_when_computing_took_less_than_half(gap, share):
    compute = int(gap * share)
    h = stall_hint(gap, compute)
    assert "\n" not in h
    if compute * 2 >= gap:
        assert h == ""
    else:
        assert h.startswith("; the process was not scheduled for ") and "--no-realtime" in h
        assert f"{(gap - compute) / 1e6:.0f} ms" in h


def test_the_testers_stall():
    # "loop stalled: 68.3 ms between two commands, 0.1 ms of it computing"
    assert "not scheduled for 68 ms: a loaded machine" in stall_hint(68_300_000, 100_000)
