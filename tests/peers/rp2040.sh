#!/usr/bin/env bash
# Builds the RP2040 image the HIL tests run (the exact image a Pico is flashed with) and installs the
# pinned emulator (npm ci in firmware_bridge/emu): `make -C firmware_bridge rp2040`.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
make -s -C "$root/firmware_bridge" rp2040 >/dev/null
