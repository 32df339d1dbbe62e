"""The strain DAQ of a session (``[daq]``, pmctl.hal.modbus_daq) as the supervisor's events drive it.

Connected before the drives enable and polled for the whole session by its own thread (samples
stamped with the rt tick). A simulated DAQ serves the plant's strain of the last drained record
(``records``), and before the first record the platform's weight at the start pose (not a zero
that a slow estimate would take for the truth). With ``[daq] compensate`` each slow estimate
becomes the NC's chain-length offsets (``Supervisor.set_chain_offset``). A fault or lost link is
the supervisor's controlled stop (``Supervisor.controlled_stop``).
"""

from __future__ import annotations

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.statics import static_strain
from pmctl.hal.base import trim_polled
from pmctl.hal.modbus_daq import DaqSession
from pmctl.motion.recorder import R_STRAIN


class Daq:
    """The DAQ part of a :class:`pmctl.task.supervisor.Supervisor` (``sup``)."""

    def __init__(self, sup):
        self.sup = sup
        self.session = None               # pmctl.hal.modbus_daq.DaqSession, once open
        self._opened = False
        self.strain = None                # the plant's strain of the last drained record
        self.rest_strain = [0.0, 0.0, 0.0]    # before the first record: the plant at rest at its start pose
        sup.events.register("records", self._records)

    def at_rest(self, counts):
        """Before the first record: serve the static strain of the platform's weight at pulse
        counters ``counts`` (the pose the machine starts at)."""
        if self.strain is None:
            self.rest_strain = strain_at_rest(counts, self.sup.params.pulses_per_mm, self.sup.machine)

    def open(self):
        """Connect and watch the DAQ (once a session; nothing without ``[daq]``)."""
        if self._opened:
            return
        self._opened = True
        sup = self.sup
        if sup.svc.daq is None:
            return
        # slow compensation ([daq] compensate): each estimate becomes the NC's chain-length offsets
        self.session = DaqSession(sup.svc.daq, lambda: self.strain or self.rest_strain, sup.log, sup.machine,
                                  self._set_offsets).connect()
        self.session.watch(sup.rt_tick, sup.controlled_stop)

    def close(self):
        if self.session is not None:
            self.session.close()

    def _set_offsets(self, offsets_mm):
        for i, mm in enumerate(offsets_mm):
            self.sup.set_chain_offset(i, float(mm))

    def _records(self, rows, tick):
        self.strain = rows[-1, R_STRAIN:R_STRAIN + 3].tolist()
        if self.session is not None and self.session.daq is not None:
            trim_polled(self.session.daq.samples, tick)


def strain_at_rest(counts, pulses_per_mm, machine) -> list[float]:
    """The static strain (microstrain per chain) of the platform's weight at pulse counters ``counts``."""
    try:
        pose = K.fk(np.asarray(counts, float) / pulses_per_mm, machine)
        return [float(x) for x in static_strain(pose.P, pose.R, machine)]
    except Exception:                  # noqa: BLE001 -- no pose there: the first record says
        return [0.0, 0.0, 0.0]
