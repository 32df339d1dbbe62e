"""CANopen / CiA 402 protocol facts shared by the master backend (pmctl.hal.canopen_csp) and the
simulated drives (pmctl.hal.cia402_sim): the drive state machine (0x6040 controlword, 0x6041
statusword), the objects and COB-IDs used, the EMCY code classes, and the bit count of a CAN 2.0A
frame on the wire (with its real stuff bits), from which the bus load of a PDO map follows.

Pure: no bus, no threads.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass

DEVICE_TYPE_402 = 0x00020192       # 0x1000: CiA 402 drive, servo (0x0002 in the high word), profile 402
MODE_CSP = 8                       # 0x6060 cyclic synchronous position
CSP_SUPPORTED_BIT = 1 << 7         # 0x6502 bit 7

# objects
OD_DEVICE_TYPE, OD_ERROR_REGISTER, OD_COMM_CYCLE = 0x1000, 0x1001, 0x1006
OD_HB_CONSUMER, OD_HB_PRODUCER = 0x1016, 0x1017
OD_RPDO1_COMM, OD_RPDO1_MAP, OD_TPDO1_COMM, OD_TPDO1_MAP = 0x1400, 0x1600, 0x1800, 0x1A00
OD_ERROR_CODE, OD_CONTROLWORD, OD_STATUSWORD = 0x603F, 0x6040, 0x6041
OD_MODE, OD_MODE_DISPLAY = 0x6060, 0x6061
OD_POSITION_ACTUAL, OD_FOLLOWING_WINDOW, OD_TARGET = 0x6064, 0x6065, 0x607A
OD_INTERP_PERIOD, OD_FOLLOWING_ACTUAL, OD_SUPPORTED_MODES = 0x60C2, 0x60F4, 0x6502
OD_DIGITAL_INPUTS = 0x60FD         # bit 0 negative limit, 1 positive limit, 2 home switch, 3 interlock
DI_HOME_SWITCH = 1 << 2

# COB-IDs (pre-defined connection set)
COB_NMT, COB_SYNC = 0x000, 0x080


def cob_emcy(node):
    return 0x080 + node


def cob_tpdo1(node):
    return 0x180 + node


def cob_rpdo1(node):
    return 0x200 + node


def cob_heartbeat(node):
    return 0x700 + node


# controlword commands (CiA 402 Table "device control commands")
CW_DISABLE_VOLTAGE = 0x0000
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_QUICK_STOP = 0x0002
CW_FAULT_RESET = 0x0080            # acts on the rising edge of bit 7

# statusword bits
SW_READY, SW_SWITCHED_ON, SW_OP_ENABLED, SW_FAULT = 1 << 0, 1 << 1, 1 << 2, 1 << 3
SW_VOLTAGE, SW_QUICK_STOP, SW_SWITCH_ON_DISABLED, SW_WARNING = 1 << 4, 1 << 5, 1 << 6, 1 << 7
SW_REMOTE, SW_TARGET_REACHED, SW_FOLLOWING_ERROR = 1 << 9, 1 << 10, 1 << 13

# states, as (mask, value) on the statusword
NOT_READY = "Not ready to switch on"
SWITCH_ON_DISABLED = "Switch on disabled"
READY_TO_SWITCH_ON = "Ready to switch on"
SWITCHED_ON = "Switched on"
OPERATION_ENABLED = "Operation enabled"
QUICK_STOP_ACTIVE = "Quick stop active"
FAULT_REACTION_ACTIVE = "Fault reaction active"
FAULT = "Fault"

_STATES = (
    (0x4F, 0x00, NOT_READY), (0x4F, 0x40, SWITCH_ON_DISABLED), (0x6F, 0x21, READY_TO_SWITCH_ON),
    (0x6F, 0x23, SWITCHED_ON), (0x6F, 0x27, OPERATION_ENABLED), (0x6F, 0x07, QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, FAULT_REACTION_ACTIVE), (0x4F, 0x08, FAULT),
)

# statusword value a drive reports in each state (voltage present, remote)
STATUSWORD_OF = {
    NOT_READY: 0x0000, SWITCH_ON_DISABLED: 0x0240 | SW_VOLTAGE, READY_TO_SWITCH_ON: 0x0221 | SW_VOLTAGE,
    SWITCHED_ON: 0x0223 | SW_VOLTAGE, OPERATION_ENABLED: 0x0227 | SW_VOLTAGE, QUICK_STOP_ACTIVE: 0x0207 | SW_VOLTAGE,
    FAULT_REACTION_ACTIVE: 0x020F | SW_VOLTAGE, FAULT: 0x0208 | SW_VOLTAGE,
}


def state_of(statusword: int) -> str:
    for mask, value, name in _STATES:
        if statusword & mask == value:
            return name
    return f"unknown (statusword 0x{statusword:04X})"


def next_state(state: str, controlword: int, prev_controlword: int) -> str:
    """The drive's transition for a controlword (CiA 402 state machine; fault reset on the rising
    edge of bit 7). Used by the simulated drive; the master only commands."""
    if state in (FAULT, FAULT_REACTION_ACTIVE):
        if controlword & 0x80 and not prev_controlword & 0x80 and state == FAULT:
            return SWITCH_ON_DISABLED
        return state
    cmd = controlword & 0x8F
    if cmd & 0x80:
        return state
    if cmd & 0x02 == 0:                      # disable voltage (x x 0 x)
        return SWITCH_ON_DISABLED
    if cmd & 0x06 == 0x02:                   # quick stop (x 0 1 x)
        return QUICK_STOP_ACTIVE if state == OPERATION_ENABLED else SWITCH_ON_DISABLED
    if state == QUICK_STOP_ACTIVE:           # leaves quick stop only by disable voltage
        return state
    if cmd & 0x07 == 0x06:                   # shutdown (0 1 1 0)
        return READY_TO_SWITCH_ON if state in (SWITCH_ON_DISABLED, READY_TO_SWITCH_ON, SWITCHED_ON,
                                               OPERATION_ENABLED) else state
    if cmd & 0x0F == 0x07:                   # switch on / disable operation (0 1 1 1)
        return SWITCHED_ON if state in (READY_TO_SWITCH_ON, SWITCHED_ON, OPERATION_ENABLED) else state
    if cmd & 0x0F == 0x0F:                   # enable operation (1 1 1 1)
        if state in (SWITCHED_ON, OPERATION_ENABLED):
            return OPERATION_ENABLED
        if state == READY_TO_SWITCH_ON:      # switch on + enable in one (transition 3 + 4)
            return OPERATION_ENABLED
        return state
    return state


# EMCY error code classes (CiA 301 Table 21, CiA 402 additions)
EMCY_CLASSES = (
    (0xFF00, 0x0000, "error reset / no error"), (0xFF00, 0x1000, "generic error"),
    (0xF000, 0x2000, "current"), (0xF000, 0x3000, "voltage"), (0xF000, 0x4000, "temperature"),
    (0xFF00, 0x5000, "device hardware"), (0xF000, 0x6000, "device software"),
    (0xFF00, 0x7000, "additional modules"), (0xFFFF, 0x8130, "life guard / heartbeat error"),
    (0xFFFF, 0x8611, "following error"), (0xF000, 0x8000, "monitoring"),
    (0xFF00, 0x9000, "external error"), (0xFF00, 0xF000, "additional functions"),
    (0xFF00, 0xFF00, "device specific"),
)

EMCY_HEARTBEAT = 0x8130
EMCY_FOLLOWING_ERROR = 0x8611


def emcy_text(code: int) -> str:
    for mask, value, text in EMCY_CLASSES:
        if code & mask == value:
            return text
    return "unknown class"


# ---------------------------------------------------------------- bits on the wire

STUFF_FACTOR = 1.2          # worst-case budget for stuff bits in bus-load planning
MAX_BUS_LOAD = 0.70         # a config above this is refused


def frame_bits_nominal(n_data: int) -> int:
    """Bits of a CAN 2.0A data frame with n data bytes before stuffing: SOF 1, identifier 11, RTR 1,
    IDE 1, r0 1, DLC 4, data 8n, CRC 15, CRC delimiter 1, ACK 2, EOF 7, intermission 3 = 47 + 8n."""
    if not 0 <= n_data <= 8:
        raise ValueError(f"a CAN 2.0A frame carries 0..8 data bytes, not {n_data}")
    return 47 + 8 * n_data


def _crc15(bits) -> int:
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return crc


def frame_bitstream(can_id: int, data: bytes) -> tuple[list[int], list[int]]:
    """(bits SOF .. CRC before stuffing, the same bits as sent with stuff bits) of a CAN 2.0A data
    frame: after five equal bits the transmitter inserts one of the opposite value (stuff bits count
    in the next run)."""
    if not 0 <= can_id < 0x800:
        raise ValueError(f"11-bit identifier expected, got 0x{can_id:X}")
    n = len(data)
    if n > 8:
        raise ValueError(f"a CAN 2.0A frame carries 0..8 data bytes, not {n}")
    bits = [0]                                               # SOF
    bits += [(can_id >> (10 - i)) & 1 for i in range(11)]
    bits += [0, 0, 0]                                        # RTR (data frame), IDE, r0
    bits += [(n >> (3 - i)) & 1 for i in range(4)]
    for byte in bytes(data):
        bits += [(byte >> (7 - i)) & 1 for i in range(8)]
    crc = _crc15(bits)
    bits += [(crc >> (14 - i)) & 1 for i in range(15)]
    out = []
    run_bit, run = None, 0
    for b in bits:
        out.append(b)
        if b == run_bit:
            run += 1
        else:
            run_bit, run = b, 1
        if run == 5:
            out.append(1 - b)
            run_bit, run = 1 - b, 1
    return bits, out


def frame_bits_stuffed(can_id: int, data: bytes) -> int:
    """Exact bits of this CAN 2.0A data frame on the wire (nominal 47 + 8n plus its stuff bits)."""
    bits, sent = frame_bitstream(can_id, data)
    return frame_bits_nominal(len(data)) + len(sent) - len(bits)


@dataclass
class BusLoad:
    bits_per_cycle: int          # nominal bits of the per-cycle frames (SYNC + RPDOs + TPDOs)
    planned_bits_per_cycle: float  # with the stuffing budget
    heartbeat_bits_per_s: float
    cycle_s: float
    bitrate: int
    load: float                  # fraction of the bus
    text: str


def bus_load(n_drives: int, rpdo_bytes: int, tpdo_bytes: int, cycle_s: float, bitrate: int,
             sync_bytes: int = 0, heartbeat_s: float = 0.0, host_heartbeat_s: float = 0.0) -> BusLoad:
    """Planned bus load of a CSP cycle: one SYNC, one RPDO and one TPDO per drive per cycle, plus
    the 1-byte heartbeats of the drives (and of the host), each frame 47 + 8n bits with the 20 %
    stuffing budget."""
    per = frame_bits_nominal(sync_bytes) + n_drives * (frame_bits_nominal(rpdo_bytes) + frame_bits_nominal(tpdo_bytes))
    planned = per * STUFF_FACTOR
    hb = 0.0
    if heartbeat_s > 0:
        hb += n_drives * frame_bits_nominal(1) * STUFF_FACTOR / heartbeat_s
    if host_heartbeat_s > 0:
        hb += frame_bits_nominal(1) * STUFF_FACTOR / host_heartbeat_s
    load = (planned / cycle_s + hb) / bitrate
    text = (f"{load * 100:.1f} % of {bitrate / 1000:g} kbit/s with a {cycle_s * 1e3:g} ms cycle: "
            f"SYNC {frame_bits_nominal(sync_bytes)} + {n_drives} x RPDO {frame_bits_nominal(rpdo_bytes)} + "
            f"{n_drives} x TPDO {frame_bits_nominal(tpdo_bytes)} = {per} bits per cycle, x{STUFF_FACTOR:g} for "
            f"stuffing = {planned:.0f} bits per cycle, plus heartbeats {hb / bitrate * 100:.2f} %")
    return BusLoad(per, planned, hb, cycle_s, bitrate, load, text)


def boost_bus_threads(network, priority: int) -> bool:
    """Give the receive thread(s) of a canopen Network's python-can Notifier SCHED_FIFO ``priority``,
    so that frames are handled promptly next to a real-time loop (an answer that waits behind
    ordinary processes arrives after its cycle). False when not permitted or not applicable
    (the one OS call in this module, in boost_thread)."""
    if priority <= 0 or network is None or network.notifier is None:
        return False
    ok = False
    for t in getattr(network.notifier, "_readers", []):
        if not boost_thread(t, priority):
            return False
        ok = True
    return ok


def boost_thread(t, priority: int) -> bool:
    """SCHED_FIFO ``priority`` for one running thread, when permitted."""
    if priority <= 0 or not isinstance(t, threading.Thread) or not t.native_id:
        return False
    try:
        os.sched_setscheduler(t.native_id, os.SCHED_FIFO, os.sched_param(priority))
        return True
    except (PermissionError, OSError, AttributeError):
        return False
