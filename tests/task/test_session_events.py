"""The supervisor's events (pmctl.task.events) and what the parts do with them, without the rt side."""

import threading

import pytest
from hypothesis import given, strategies as st

from pmctl.hal.base import trim_polled
from pmctl.task.job_watch import JobWatch
from pmctl.task.events import EventHub


def test_handlers_get_the_context_in_order_and_listeners_only_events_with_a_detail():
    hub, got = EventHub(), []
    hub.register("item_done", lambda item: got.append(("first", item)))
    hub.register("item_done", lambda item: got.append(("second", item)))
    hub.listeners.append(lambda ev, d: got.append(("listener", ev, d)))
    hub.send("item_done", {"index": 3}, item="job 3")
    assert got == [("listener", "item_done", {"index": 3}), ("first", "job 3"), ("second", "job 3")]
    got.clear()
    hub.send("item_done", item="job 4")              # no detail: the parts' alone
    assert got == [("first", "job 4"), ("second", "job 4")]


def test_a_failing_listener_is_dropped_but_a_failing_part_is_its_threads_error():
    hub, got = EventHub(), []

    def broken_console(ev, d):
        raise OSError("the console went away")
    hub.listeners += [broken_console, lambda ev, d: got.append(ev)]
    hub.send("alarm", {"code": 3, "msg": "x"})
    assert got == ["alarm"]                          # the listener after the broken one still heard it

    def broken_part():
        raise RuntimeError("VFD write failed")
    hub.register("reset_done", broken_part)
    with pytest.raises(RuntimeError, match="VFD write failed"):
        hub.send("reset_done")
    hub.unregister("reset_done", broken_part)
    hub.send("reset_done")                           # gone: nothing raises


@given(st.lists(st.integers(0, 50), max_size=30).map(sorted), st.integers(-1, 60))
def test_trim_polled_keeps_the_last_sample_up_to_the_tick_and_everything_after(ticks, tick):
    samples = [(t, k) for k, t in enumerate(ticks)]
    kept = list(samples)
    trim_polled(kept, tick)
    assert kept == samples[len(samples) - len(kept):]            # a suffix: appends go on at the end
    upto = [s for s in samples if s[0] <= tick]
    if len(upto) > 1:
        assert kept[0] == upto[-1]                   # the sample that holds at ``tick`` stays
    else:
        assert kept == samples                       # nothing before it to drop


def test_the_run_waits_on_its_own_item_and_a_drop_of_the_queue_that_held_it():
    hub = EventHub()
    sup = type("Sup", (), {"events": hub, "ch": None})()        # no rt side yet
    w = JobWatch(sup)
    mine, other = object(), object()
    w.item = mine
    hub.send("item_done", item=other)
    assert not w.left and not w.wake.is_set()
    hub.send("queue_dropped", items=[other])
    assert not w.left
    hub.send("queue_dropped", items=[other, mine])
    assert w.left and w.wake.is_set()
    hub.send("stopped", reason="soft limit: L1", fault=False)
    hub.send("stopped", reason="later", fault=True)
    assert w.stopped == ("soft limit: L1", False)    # the first stop is the run's reason
    w.close()
    hub.send("item_failed", item=mine)
    assert not w.failed                              # unregistered: a later supervisor event is not the run's


def test_handlers_run_in_the_sending_thread():
    hub, where = EventHub(), []
    hub.register("records", lambda rows, tick: where.append(threading.current_thread().name))
    t = threading.Thread(target=lambda: hub.send("records", rows=[], tick=7), name="pmctl-monitor")
    t.start()
    t.join()
    assert where == ["pmctl-monitor"]
