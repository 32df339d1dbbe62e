"""Per-tick records: the loop writes one row per tick into a bounded ring; a recorder drains it.

The loop's memory is the ring (``capacity`` rows, whatever the length of the job). The recorder
copies rows out in chunks: into memory (``keep=True``: the arrays a one-shot run returns) and/or
into a recording folder through :class:`pmctl.core.recording.RecordingWriter` (bounded memory).
If the ring is full the loop counts a drop and goes on (it never waits); with ``realtime=False``
it drains the ring itself instead, so an offline run loses nothing.
"""

from __future__ import annotations

import threading

import numpy as np

from pmctl.motion.ring import Ring

# record row layout
R_TICK, R_S, R_SIGMA, R_LINE, R_MODE, R_FOLLOW = 0, 1, 2, 3, 4, 5
R_COUNTS, R_ENC, R_STRAIN, R_TRUTH, R_TARGET = 6, 11, 16, 19, 24
R_LATE_NS, R_PREV_COMPUTE_NS = 30, 31       # this tick's wake-up lateness, the previous tick's compute time
R_CHAIN_OFFSET = 32                         # (3) chain-length offset the NC applied this tick, mm (slow compensation)
REC_WIDTH = 35                              # new columns go at the end of the row
REC_CAPACITY = 4096            # rows: 4 s at 1 kHz, ~1 MB


class Recorder:
    """Drains a record ring. ``keep``: hold the rows in memory (chunks) for :meth:`arrays`;
    ``sink(rows)``: called with every drained chunk (e.g. a recording writer)."""

    def __init__(self, ring: Ring, *, keep: bool = True, sink=None):
        self.ring = ring
        self.keep = keep
        self.sink = sink
        self.chunks: list[np.ndarray] = []
        self.rows = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None
        self.error = ""

    def drain(self) -> int:
        with self._lock:
            rows = self.ring.pop()
            if len(rows):
                self.rows += len(rows)
                if self.keep:
                    self.chunks.append(rows)
                if self.sink is not None:
                    try:
                        self.sink(rows)
                    except Exception as e:     # a recording problem must not stop the machine
                        self.error = self.error or f"{type(e).__name__}: {e}"
                        self.sink = None
            return len(rows)

    def start(self, period_s: float = 0.02):
        def run():
            while not self._stop.wait(period_s):
                self.drain()
        self._thread = threading.Thread(target=run, name="pmctl-recorder", daemon=True)
        self._thread.start()

    def stop(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self.drain()

    def arrays(self) -> np.ndarray:
        if not self.chunks:
            return np.zeros((0, self.ring.width))
        if len(self.chunks) > 1:
            self.chunks = [np.concatenate(self.chunks)]
        return self.chunks[0]
