"""The hardware abstraction layer: one small interface every backend implements.

The loop talks only to :class:`Backend`. A backend reports motor-side positions (drive encoders,
or the pulse counters of a step/dir bridge) and plate-link strain, and takes either pulses per
tick (step/dir bridges, the loopback simulation) or position targets (CANopen CSP drives).
Backends are chosen by name from the service config (``pmctl.hal.create``), so a new one plugs in
without touching the loop.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from pmctl.core.errors import ConfigError, PmctlError

AXES = ("L1", "L2", "L3", "X", "Y")


class HalError(PmctlError):
    """A backend fault (drive alarm, bus error); the message says which device and why."""


class HalTimeout(HalError):
    """The backend did not answer within its deadline."""


class Feedback:
    """One sample of feedback. Backends reuse one instance (no allocation per tick); the loop
    copies what it keeps before the next read.

    seq: increments with every fresh sample (a stale seq means the device did not update);
    enc: (5,) motor-side positions, mm (L1, L2, L3, X, Y);
    strain: (3,) plate-link strain of chains 1-3, microstrain, tension positive;
    counts: (5,) pulse counters the device holds, or None when it has none."""

    __slots__ = ("seq", "enc", "strain", "counts")

    def __init__(self):
        self.seq = 0
        self.enc = np.zeros(5)
        self.strain = np.zeros(3)
        self.counts = None


class Inputs:
    """Switch inputs, sampled with the last ``read``: ``home`` a tuple of 5 booleans (the home
    switch of each axis L1 L2 L3 X Y closed), or None when the backend has no home switches;
    ``estop`` True while the E-stop is pressed; ``latch`` None, or the device's own latch of each
    home switch's last transition: per axis (transitions so far, any counter that changes with each,
    closed after it, the pulse counter at it in the controller's frame). A device that latches
    where the switch changed (a step generator counting steps, a drive sampling its input with its
    position) is more exact than the tick at which the host sees the input."""

    __slots__ = ("home", "estop", "latch")

    def __init__(self, home=None, estop=False, latch=None):
        self.home = home
        self.estop = estop
        self.latch = latch


NO_INPUTS = Inputs()


def as_inputs(x) -> Inputs:
    """A backend's ``inputs()`` answer as :class:`Inputs`: an Inputs as it is; an int as a bridge's bit
    mask (bits 0-4 the home switches of L1 L2 L3 X Y, bit 5 the E-stop)."""
    if isinstance(x, Inputs):
        return x
    bits = int(x)
    return Inputs(tuple(bool(bits >> i & 1) for i in range(5)), bool(bits >> 5 & 1))


def switch_positions(value, where: str, key: str) -> tuple:
    """A backend option giving simulated home switches: 5 joint positions in mm (L1 L2 L3 X Y), or
    an empty list for none; ConfigError naming ``where`` and ``key`` otherwise."""
    if not isinstance(value, (list, tuple)) or len(value) not in (0, 5) or any(
            isinstance(x, bool) or not isinstance(x, (int, float)) or not abs(x) <= 1e4 for x in value):
        raise ConfigError(where, key, f"must be 5 joint positions in mm (L1 L2 L3 X Y) or [] for none, got {value!r}")
    return tuple(float(x) for x in value)


def trim_polled(samples: list, tick: int):
    """Drop the tick-stamped samples of a polled device (``[(tick, ...), ...]``, in tick order) up to
    ``tick`` but the last of them (it holds on until the next): memory does not grow with the
    session. Appends by the polling thread go on at the end (one list operation each)."""
    i = 0
    while i + 1 < len(samples) and samples[i + 1][0] <= tick:
        i += 1
    if i:
        del samples[:i]

@dataclass
class Status:
    ok: bool = True
    fault: str = ""


class Backend(ABC):
    """What the loop needs from a machine. ``accepts`` is "pulses" or "positions"."""

    name = "abstract"
    accepts = "pulses"
    can_rereference = False       # True: rereference() is implemented, homing is possible
    # How long the device rides out a host that does not command it (a late wake-up or a long
    # tick), seconds; the loop stops at the longer of this and its own stall limit. 0: the loop's
    # limit. Devices that hold by themselves (CSP drives keep their last target and fault on their
    # own when the host's heartbeat stays away) tolerate more than a device that runs dry.
    stall_tolerance_s = 0.0
    # Whether a stall beyond that (a moment without ticks) can be ridden out by a feed hold on the
    # path that resumes once the ticks are on time again, instead of a controlled stop and an alarm:
    # only a device that cannot have moved, nor stopped abruptly, without commands (the simulation,
    # whose plant advances with the ticks). A step/dir bridge runs dry within its few queued ticks
    # (its motors stop without deceleration: steps may be lost) and CSP drives fault by themselves
    # past their host timeout: those stop and raise the alarm.
    stall_hold = False

    @classmethod
    def validate_options(cls, table: dict, where: str):
        """Check this backend's ``[hal.<name>]`` options table at config load (file, key and reason
        on any problem) and return the validated options. The service config calls it for every
        backend's table, so a typo in an unused backend's options is found too."""
        if table:
            raise ConfigError(where, next(iter(table)), f"backend {cls.name!r} takes no options")
        return table

    @abstractmethod
    def open(self, counts: np.ndarray) -> None:
        """Connect; ``counts`` are the controller's pulse counters at start (the sim places its
        plant there; hardware may check them against its own counters)."""

    @abstractmethod
    def read(self) -> Feedback:
        """The latest feedback; raises HalTimeout if the device does not answer in time, HalError
        on a device fault. Contract: ``read`` never blocks longer than its own timeout (a small
        fraction of the tick): the loop turns a timeout into a controlled stop with the reason, and
        a tick that overruns the stall limit into a braked stop. A device must also stop by itself
        when the heartbeat of ticks stops (a hung host cannot command a stop)."""

    def write_pulses(self, pulses: np.ndarray) -> None:
        """Signed pulses for this tick per axis (spread evenly over the tick by the device)."""
        raise HalError(f"backend {self.name!r} does not take pulses")

    def write_positions(self, q_mm: np.ndarray) -> None:
        """Position targets for the end of this tick (CSP), mm."""
        raise HalError(f"backend {self.name!r} does not take position targets")

    def status(self) -> Status:
        return Status()

    def inputs(self) -> Inputs:
        """Home switches and E-stop (see :class:`Inputs`). Default: a backend without either."""
        return NO_INPUTS

    def rereference(self, counts: np.ndarray) -> None:
        """Homing set the controller's pulse counters to ``counts`` (the motors did not move): the
        device's own counters or position targets must read ``counts`` from now on. Only a backend with
        ``can_rereference`` True implements it (homing is refused on the others)."""
        raise HalError(f"backend {self.name!r} cannot re-reference its counters")

    def reference_offset(self) -> np.ndarray | None:
        """A backend whose ``rereference`` keeps an offset (pulses per axis) between its devices' own
        positions and the controller's counters, instead of setting the devices' counters: that offset,
        saved with the counters so that after a restart counters and devices still agree. None: none."""
        return None

    def set_reference_offset(self, offset) -> None:
        """Restore a saved ``reference_offset`` (before ``open``)."""
        raise HalError(f"backend {self.name!r} keeps no reference offset")

    def truth(self) -> np.ndarray | None:
        """Load-side joint positions (mm), known only to a simulation; None for hardware."""
        return None

    def close(self) -> None:
        pass
