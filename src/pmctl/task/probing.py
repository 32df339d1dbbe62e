"""Probing (G38.2/G38.3) in the queue: an item with probing moves planned piece by piece.

The item is split at its probes (pmctl.motion.probe.split_at_probes): the motion before a probe,
the probing move alone -- its segment announced in the channel's probe table, its samples flagged
-- then, once the rt side's probe monitor reports the probe ended, the rest of the item from where
the probe stopped. The results land in ``Item.probe_results`` and go out as the ``probe`` event; a
G38.2 without contact drops the queue and raises ALARM 5 (grbl's probe fail).
"""

from __future__ import annotations

import time

import numpy as np

from pmctl.core.alarms import ALARM_PROBE_FAIL_CONTACT
from pmctl.core.job import DWELL
from pmctl.motion.probe import check_probe_feeds, mark_probe_rows, probe_segments, split_at_probes


class Probing:
    """The probing part of a :class:`pmctl.task.supervisor.Supervisor` (``sup``): its planner thread
    hands it the items with probing moves."""

    def __init__(self, sup):
        self.sup = sup

    @staticmethod
    def wanted(job) -> bool:
        return any(m.probe for m in job.moves)

    def prepare(self, it, where: str):
        """At submission: the probing feeds checked against ``[probe]`` (refused, naming ``where``,
        before anything is queued), and the pieces the item is planned in counted (each ends on
        the rt side)."""
        sup = self.sup
        check_probe_feeds(it.job, sup.svc.probe, where, sup.plan_feed_override)
        it.parts = len(split_at_probes(it.job))

    def plan(self, it):
        """Plan and queue item ``it`` piece by piece (the planner thread; a reset meanwhile raises the
        supervisor's abort)."""
        sup = self.sup
        start = (np.asarray(it.start[0], float), np.asarray(it.start[1], float))
        pieces = split_at_probes(it.job)
        for k, (piece, probe) in enumerate(pieces):
            # the spindle: the item's start speed before its first piece (a speed change after a
            # probe inside the same item is not waited for)
            rows_iter = sup._rows_of(piece, start, it if k == 0 else None)
            if probe is None:
                it.planned = True
                if sup._push_rows(rows_iter, it) == 0:
                    sup._ended_without_samples(it)
                last = [m for m in piece.moves if m.kind != DWELL]
                if last:
                    start = (np.asarray(last[-1].tip, float), np.asarray(last[-1].axis, float))
                continue
            seg = probe_segments(piece, sup.machine, start[0])[0]
            seg.feed *= sup.plan_feed_override      # the feed as planned (the monitor's speed and stop)
            seq0 = sup.status().probe_seq
            tab = sup.ch.probe
            tab[1:] = seg.to_row()
            tab[0] += 1.0                    # the announcement last: the rt side takes the whole row
            it.planned = True
            sup._push_rows((mark_probe_rows(r, seg.feed, sup.svc.probe) for r in rows_iter), it)
            s = self._wait(seq0, it)
            res = s.probe()
            it.probe_results.append(res)
            sup._emit("probe", res.as_dict())
            if res.error:
                # grbl's probe fail: the queue is dropped, motion locked until $X
                sup._drop_queue(ended=s.ended)
                sup.raise_alarm(ALARM_PROBE_FAIL_CONTACT, res.error)
                return
            start = (np.asarray(res.stop, float), np.asarray(seg.axis, float))
            if k == len(pieces) - 1 or all(m.kind == DWELL for p, _ in pieces[k + 1:] for m in p.moves):
                # the item ends where the probe stopped: what is queued after it starts from there
                sup._starts_after(it, start)

    def _wait(self, seq0, it):
        """The rt status once the rt side has reported the probe ended (``probe_seq`` past seq0)."""
        sup = self.sup
        while True:
            sup._check_going(it)
            s = sup.status()
            if s.probe_seq > seq0:
                return s
            time.sleep(0.002)
