"""The spindle VFD's Modbus register map (defaults: Huanyang GT): the addresses and command values the
driver (pmctl.hal.modbus_vfd) writes and reads and the simulated VFD (pmctl.hal.modbus_sim) answers."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class VfdRegisters:
    command: int = 0x1000
    setpoint: int = 0x2000
    output_freq: int = 0x3000
    speed_rpm: int = 0x3005
    fault: int = 0x5000
    run_forward: int = 1
    run_reverse: int = 2
    stop: int = 5

    NAMES = {"command": "command", "setpoint": "frequency set-point", "output_freq": "output frequency",
             "speed_rpm": "speed, rpm", "fault": "fault"}

    def name(self, addr):
        for k, text in self.NAMES.items():
            if getattr(self, k) == addr:
                return f"register 0x{addr:04X} ({text})"
        return f"register 0x{addr:04X}"
