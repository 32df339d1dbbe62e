"""Single-producer single-consumer rings of fixed-width float64 rows, lock-free.

One ring carries planned samples into the loop, another carries per-tick records out of it. The
memory is fixed at construction (``capacity`` rows), whatever the length of the job, so the loop
can lock it (mlockall) without locking gigabytes. A ring lives either in a private numpy array or
in a shared-memory buffer (``multiprocessing.shared_memory``), so the same class joins the two
processes of the daemon.

Layout of the buffer: two int64 counters (rows ever written, rows ever read), then
``capacity x width`` float64. Only the producer writes the first counter, only the consumer the
second; each publishes its counter after the rows, so a reader never sees a row before it is
complete (x86-64 and AArch64 with the store order of single aligned 8-byte writes the rings use;
there is no lock either side could wait on). A full ring refuses rows (``push`` returns how many it
took): the producer decides whether to retry (planner) or to count a drop (the loop never waits).
"""

from __future__ import annotations

import numpy as np

HEADER_BYTES = 16


def ring_bytes(capacity: int, width: int) -> int:
    """Buffer size a ring of ``capacity`` rows of ``width`` floats needs."""
    return HEADER_BYTES + 8 * int(capacity) * int(width)


class Ring:
    """SPSC ring. ``buf``: a writable buffer of at least ring_bytes(capacity, width) bytes (a
    SharedMemory's ``buf``), or None for a private one. ``reset=True`` zeroes the counters (the
    creator does that; the other side attaches with reset=False)."""

    def __init__(self, capacity: int, width: int, buf=None, *, reset: bool = True):
        if capacity < 2 or width < 1:
            raise ValueError("ring needs capacity >= 2 and width >= 1")
        self.capacity, self.width = int(capacity), int(width)
        if buf is None:
            buf = bytearray(ring_bytes(capacity, width))
        self._ctr = np.ndarray((2,), np.int64, buf, 0)
        self.data = np.ndarray((self.capacity, self.width), np.float64, buf, HEADER_BYTES)
        if reset:
            self._ctr[:] = 0

    @property
    def nbytes(self) -> int:
        return ring_bytes(self.capacity, self.width)

    # ---- both sides
    def count(self) -> int:
        """Rows written and not yet consumed."""
        return int(self._ctr[0] - self._ctr[1])

    def free(self) -> int:
        return self.capacity - self.count()

    @property
    def written(self) -> int:
        return int(self._ctr[0])

    @property
    def consumed(self) -> int:
        return int(self._ctr[1])

    # ---- producer
    def push(self, rows) -> int:
        """Append as many of ``rows`` ((n, width) or (width,)) as fit; returns how many."""
        rows = np.asarray(rows, np.float64)
        if rows.ndim == 1:
            rows = rows[None]
        head, tail = int(self._ctr[0]), int(self._ctr[1])
        n = min(len(rows), self.capacity - (head - tail))
        if n <= 0:
            return 0
        i = head % self.capacity
        first = min(n, self.capacity - i)
        self.data[i:i + first] = rows[:first]
        if n > first:
            self.data[:n - first] = rows[first:n]
        self._ctr[0] = head + n            # publish after the rows
        return n

    def push_row(self, values) -> bool:
        """One row from a sequence of floats (the per-tick path: no array is built)."""
        head = int(self._ctr[0])
        if head - int(self._ctr[1]) >= self.capacity:
            return False
        self.data[head % self.capacity] = values
        self._ctr[0] = head + 1
        return True

    # ---- consumer
    def row(self, i: int) -> np.ndarray:
        """The i-th unconsumed row (0 = oldest); a view, valid until it is consumed."""
        return self.data[(int(self._ctr[1]) + i) % self.capacity]

    def advance(self, n: int) -> None:
        """Mark the oldest n rows consumed."""
        n = min(int(n), self.count())
        if n > 0:
            self._ctr[1] = int(self._ctr[1]) + n

    def pop(self, max_rows: int | None = None) -> np.ndarray:
        """Copy out and consume up to max_rows (default all) of the oldest rows."""
        tail = int(self._ctr[1])
        n = int(self._ctr[0]) - tail
        if max_rows is not None:
            n = min(n, int(max_rows))
        if n <= 0:
            return np.zeros((0, self.width))
        i = tail % self.capacity
        first = min(n, self.capacity - i)
        out = np.empty((n, self.width))
        out[:first] = self.data[i:i + first]
        if n > first:
            out[first:] = self.data[:n - first]
        self._ctr[1] = tail + n
        return out

    def clear(self) -> None:
        """Consumer: drop everything unconsumed."""
        self._ctr[1] = int(self._ctr[0])


class ArraySource:
    """The sample-source interface of a Ring over a whole array (a one-shot run's planned job):
    ``count() row(i) advance(n)``. Rows are not copied. Its counters are a Ring's (``_ctr``: rows,
    rows consumed), so the compiled path follower reads it as it reads a Ring."""

    def __init__(self, rows: np.ndarray):
        self.data = rows
        self._ctr = np.array([len(rows), 0], np.int64)

    def count(self) -> int:
        return int(self._ctr[0] - self._ctr[1])

    def row(self, i: int) -> np.ndarray:
        return self.data[int(self._ctr[1]) + i]

    def advance(self, n: int) -> None:
        self._ctr[1] = min(len(self.data), int(self._ctr[1]) + int(n))

    def clear(self) -> None:
        self._ctr[1] = len(self.data)
