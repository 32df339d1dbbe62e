"""RtStatus (pmctl.motion.status): the one reader of the shared status block reads every slot the
rt side writes, each into its named field, from a real shared-memory channel."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hs

from pmctl.motion import channel as C
from pmctl.motion.probe import ProbeResult
from pmctl.motion.status import F_FAULT, F_NONE, PH_RUNNING, RtStatus, read_status


def test_every_slot_of_the_block_is_one_field():
    """Slot i holds the number i + 2: the fields together read each slot of the block exactly once
    (a slot added to the block and not to RtStatus, or read by two fields, fails here)."""
    block = np.arange(C.STATUS_WIDTH, dtype=float) + 2.0
    s = RtStatus.from_block(block)
    seen = []
    for name in RtStatus.FIELDS:
        v = getattr(s, name)
        if name == "hold":                    # a flag: slot ST_HOLD read as != 0
            assert v is True
            seen.append(block[C.ST_HOLD])
        else:
            seen += np.atleast_1d(np.asarray(v, float)).tolist()
    assert sorted(seen) == block.tolist()
    assert set(RtStatus.FIELDS) == {n for n, v in vars(RtStatus).items()
                                    if isinstance(v, property) and n not in ("running", "stopped")}


@pytest.fixture(scope="module")
def channel():
    ch = C.Channel(create=True, sample_capacity=64, record_capacity=64)
    yield ch
    ch.close(unlink=True)


@settings(max_examples=60, deadline=None)
@given(counts=hs.lists(hs.integers(-2**40, 2**40), min_size=5, max_size=5),
       tick=hs.integers(0, 2**50), line=hs.integers(0, 10**6),
       sigma=hs.floats(0.0, 2.0), feed=hs.floats(0.1, 2.0), hold=hs.booleans(),
       tip=hs.lists(hs.floats(-500, 500), min_size=3, max_size=3),
       fault=hs.sampled_from([C.F_NONE, C.F_STOP, C.F_FAULT]), home_in=hs.integers(-1, 31),
       latch=hs.lists(hs.integers(-2**40, 2**40), min_size=5, max_size=5))
def test_fields_read_what_the_rt_side_wrote(channel, counts, tick, line, sigma, feed, hold, tip, fault, home_in,
                                            latch):
    """Written as the rt side writes (under the sequence counter, by index), read by name: equal,
    integers exactly (pulse counters up to 2^40 survive the float64 block)."""
    st = channel.st
    st[:] = 0.0
    st[C.ST_SEQ] += 1.0
    st[C.ST_TICK], st[C.ST_LINE], st[C.ST_SIGMA], st[C.ST_FEED_OV] = tick, line, sigma, feed
    st[C.ST_HOLD] = 1.0 if hold else 0.0
    st[C.ST_COUNTS:C.ST_COUNTS + 5] = counts
    st[C.ST_TIP:C.ST_TIP + 3] = tip
    st[C.ST_FAULT], st[C.ST_HOME_IN], st[C.ST_PHASE] = fault, home_in, C.PH_RUNNING
    st[C.ST_LATCH:C.ST_LATCH + 5] = latch
    st[C.ST_SEQ] += 1.0
    s = read_status(channel)
    assert s.tick == tick and s.line == line and s.sigma == sigma and s.feed_override == feed
    assert s.hold is hold and s.home_in == home_in and s.running and s.phase == PH_RUNNING
    assert s.counts.dtype == np.int64 and s.counts.tolist() == counts
    assert s.latch.tolist() == latch
    assert s.tip_mm.tolist() == tip
    assert s.stopped == (fault != C.F_NONE) and (s.fault == F_FAULT) == (fault == C.F_FAULT)
    assert (s.fault == F_NONE) == (fault == C.F_NONE)


def test_a_snapshot_does_not_follow_the_block(channel):
    """A snapshot is a copy: the rt side's next write, or a reader changing an array it got, does
    not change what the snapshot holds; its fields cannot be set."""
    channel.st[:] = 0.0
    channel.st[C.ST_COUNTS:C.ST_COUNTS + 5] = [1, 2, 3, 4, 5]
    channel.st[C.ST_TIP:C.ST_TIP + 3] = [1.0, 2.0, 3.0]
    s = read_status(channel)
    channel.st[C.ST_COUNTS:C.ST_COUNTS + 5] = [9, 9, 9, 9, 9]
    s.counts[0] = 7
    s.tip_mm[0] = 7.0
    assert s.counts.tolist() == [1, 2, 3, 4, 5] and s.tip_mm.tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(AttributeError):
        s.tick = 3
    assert RtStatus.from_block(channel.st).counts.tolist() == [9, 9, 9, 9, 9]
    with pytest.raises(ValueError, match="floats"):
        RtStatus.from_block(np.zeros(C.STATUS_WIDTH - 1))


def test_probe_result_round_trips_through_the_block(channel):
    """A probe result the rt side stores (ProbeResult.to_row) comes back whole from the snapshot."""
    r = ProbeResult(line=12, mode=2, contact=True, point=np.array([1.5, -2.25, 3.0]), ab_deg=(4.0, -5.5),
                    stop=np.array([1.5, -2.25, 2.875]), tick=4321, speed_mm_s=2.5, overtravel_mm=0.125,
                    after_trigger_mm=0.0625, bound_mm=0.25, noise_N=0.5, counts=(10, -20, 30, -40, 50))
    channel.st[:] = 0.0
    channel.st[C.ST_PROBE:C.ST_PROBE + C.PROBE_RESULT_WIDTH] = r.to_row()
    channel.st[C.ST_PROBE_SEQ] = 1
    s = read_status(channel)
    assert s.probe_seq == 1
    assert s.probe().as_dict() == r.as_dict()
