"""How one queued job ends, told by the supervisor's events (pmctl.task.events).

``pmctl run`` submits its one job and waits here: the job is done once its item left the queue
(``item_done``; or ``queue_dropped`` with it, after a failed probe), the rt side passed its end and
the plant settled for ``settle`` ticks; it ended otherwise on a stop request (a signal), the rt
process dead (``rt_dead``), the rt side's own stop (``stopped``), a device fault
(``device_fault``) or its planning failing (``item_failed``) -- in that order when several came
together. The handlers run in the supervisor's threads: they note and wake the waiting thread,
nothing more.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from pmctl.motion.status import F_FAULT


@dataclass
class JobEnd:
    """How a job ended: ``status`` done | stopped | fault, with the reason."""
    status: str
    reason: str = ""
    stop_tick: int | None = None     # the rt tick of the stop request (a signal)
    bad_input: str = ""              # its planning refused it before any of it reached the rt side


class JobWatch:
    """Registered on the events of ``sup`` (a pmctl.task.supervisor.Supervisor) until :meth:`close`;
    ``item``: the job's queue Item, once submitted."""

    def __init__(self, sup):
        self.sup = sup
        self.item = None
        self.left = False                # the item left the queue
        self.failed = False              # its planning failed (item.error)
        self.stopped = None              # (reason, fault) of the rt side's own stop
        self.device_fault = ""
        self.rt_dead = False
        self.wake = threading.Event()
        self._handlers = (("item_done", self._done), ("queue_dropped", self._dropped),
                          ("item_failed", self._failed), ("stopped", self._stopped),
                          ("device_fault", self._device_fault), ("rt_dead", self._rt_dead))
        for event, fn in self._handlers:
            sup.events.register(event, fn)
        if sup.ch is not None:
            s = sup.status()
            if s.stopped:                # the rt side stopped before the watch began (its first ticks)
                self.stopped = (sup.ch.reason(), s.fault == F_FAULT)

    def close(self):
        for event, fn in self._handlers:
            self.sup.events.unregister(event, fn)

    def _done(self, item):
        if item is self.item:
            self.left = True
            self.wake.set()

    def _dropped(self, items):
        if any(it is self.item for it in items):
            self.left = True
            self.wake.set()

    def _failed(self, item):
        if item is self.item:
            self.failed = True
            self.wake.set()

    def _stopped(self, reason, fault):
        if self.stopped is None:
            self.stopped = (reason, fault)
        self.wake.set()

    def _device_fault(self, msg):
        self.device_fault = self.device_fault or msg
        self.wake.set()

    def _rt_dead(self, exitcode):
        self.rt_dead = True
        self.wake.set()

    def wait(self, ended0: int, settle: int, stop_request) -> JobEnd:
        """Until the job ended (see the module). ``ended0``: the rt side's count of passed job ends
        before it was submitted; ``settle``: ticks the plant settles after its end; ``stop_request()``:
        None, or (reason, tick) of a stop asked for."""
        sup, it = self.sup, self.item
        done_tick = None
        while True:
            stop = stop_request()
            if stop is not None:
                return JobEnd("stopped", stop[0], stop_tick=stop[1])
            if self.rt_dead:
                return JobEnd("fault", sup.alarm_msg or "the rt motion process died")
            if self.stopped is not None:
                reason, fault = self.stopped
                return JobEnd("fault" if fault else "stopped", reason)
            if self.device_fault:
                return JobEnd("stopped", self.device_fault)
            if self.failed:
                return JobEnd("fault", f"planning failed: {it.error}",
                              bad_input="" if it.planned else it.error)   # nothing of it moved: bad input
            if self.left:
                s = sup.status()
                if done_tick is None and s.ended > ended0:
                    done_tick = s.tick       # at the job's last sample: the plant settles
                if done_tick is not None and s.tick >= done_tick + settle:
                    return JobEnd("done")
            self.wake.wait(0.005)
            self.wake.clear()
