"""The supervisor's events: named moments of a machining session that the parts of it act on.

The supervisor (pmctl.task.supervisor) owns the queue, the rt process and the machine state; the
parts beside it -- the spindle (pmctl.task.spindle), the strain DAQ (pmctl.task.daq), homing
(pmctl.task.homing) -- and a client such as ``pmctl run`` register handlers for the events they care
about, as Klipper's ``register_event_handler`` and grblHAL's ``on_*`` hooks do. The supervisor sends
an event where the moment happens and knows nothing of what each part does then.

Events (the keyword arguments a handler gets):

==================  ==========================================================================
``item_done``       ``item``: an item of the queue ran to its end and left the queue
``queue_dropped``   ``items``: a reset, an E-stop, a fault, homing or a failed probe dropped them
``item_failed``     ``item``: its planning failed (``item.error`` says why; ``item.planned``:
                    samples of it had reached the rt side)
``stopped``         ``reason``, ``fault``: the rt side stopped on its own (soft limit, path
                    error, stall: ``fault`` False; following error, lost backend: True)
``device_fault``    ``msg``: the spindle's or the DAQ's fault, a controlled stop
``rt_dead``         ``exitcode``: the rt process died
``position_lost``   (none): the counters are not trusted any more (a fault, a dead rt process)
``reset``           (none): a soft reset begins (a homing cycle aborts)
``reset_done``      (none): the soft reset stopped the machine on its path, the queue dropped
``estop``           (none): an E-stop
``shutdown``        (none): the session ends (the rt side is asked to exit)
``records``         ``rows``, ``tick``: a chunk of the rt side's per-tick records was drained
==================  ==========================================================================

The outside listeners (the Grbl console, tests: ``Supervisor.listeners``) get the events that
carry a ``detail`` dict, as ``listener(event, detail)``; an event sent without one is the parts'
alone.
"""

from __future__ import annotations

import collections


class EventHub:
    """Handlers by event name, called in the order they were registered, from the thread that sends
    the event (a handler that blocks holds that thread: a part does slow work in a thread of its
    own). A part's handler that raises is that thread's error, as a call would be; a listener's
    error is dropped (a console gone away must not stop the machine)."""

    def __init__(self):
        self._handlers: dict[str, list] = collections.defaultdict(list)
        self.listeners: list = []         # callables(event: str, detail: dict): the outside's

    def register(self, event: str, handler):
        """Call ``handler(**context)`` each time ``event`` is sent."""
        self._handlers[event].append(handler)

    def unregister(self, event: str, handler):
        try:
            self._handlers[event].remove(handler)
        except ValueError:
            pass

    def send(self, event: str, detail: dict | None = None, **context):
        """The listeners first (with ``detail``, when there is one), then the handlers (with ``context``)."""
        if detail is not None:
            for fn in list(self.listeners):
                try:
                    fn(event, detail)
                except Exception:             # noqa: BLE001 (see the class)
                    pass
        for fn in list(self._handlers.get(event, ())):
            fn(**context)
