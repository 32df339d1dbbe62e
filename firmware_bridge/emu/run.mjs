// run.mjs - runs the bridge's RP2040 image (build/rp2040/bridge.elf) in the rp2040js emulator, in
// simulated time, and bridges its UART0 to a pseudo-terminal the stepdir backend opens as its port.
// Started by pmctl.hal.rp2040_emu (which creates the pty); see firmware_bridge/README.md.
//
//   node run.mjs --elf bridge.elf --link-fd FD [--edge-log PATH] [--cpu-log PATH] [--control FIFO]
//                [--home-at AXIS:PULSES]... [--baud N] [--speed X] [--clock-file PATH] [--host-paced MS] [--spin-addr HEX] [--profile PATH] [--trace PATH]
//
// - The ELF's loadable segments are copied to the emulated flash at their physical addresses, VTOR
//   is pointed at the vector table (0x10000100) and the core is reset: rp2040js ships no boot ROM,
//   so boot2 does not run here (it is checked by its CRC only).
// - Time: the emulator's clock, 8 ns per cycle at 125 MHz. The chip runs as fast as this process
//   can emulate it (about half real time while it steps), and never more than 5 ms ahead of real
//   time (--speed 1; 0 = no limit): a host that goes quiet for a while is quiet for the chip too.
// - UART: bytes from the host are fed into the RX FIFO one per character time at --baud (default
//   3 Mbaud, 10 bits a byte); a byte that finds the 32-byte FIFO full is lost (an overrun, counted),
//   as on silicon. Bytes the chip sends go to the host as soon as it writes them.
// - Pins: every change of the STEP (GP2-6) and DIR (GP7-11) outputs and of the TICK strobe (GP25)
//   is recorded with its simulated time (--edge-log: the host build's 16-byte records, u64 t_ns,
//   u32 tick, u8 axis, u8 kind: 0 step low, 1 step high, 2 dir -, 3 dir +, 4 tick start, 5/6 an
//   input pin set low/high by --control (axis = its GPIO number); tick =
//   the tick-start strobes since the last RESET, minus one). The pulse counters are counted from
//   these edges (a rising STEP edge in the direction DIR shows), and every STATUS frame the chip
//   sends is rewritten with them before it reaches the host: the counters the backend sees are the
//   pins', not the firmware's. A STATUS sent at a tick start gets the count at that tick's strobe.
// - --control FIFO: text lines "estop 0|1", "alarm AXIS 0|1", "home AXIS 0|1", "adc CH COUNTS",
//   "quit", as the host build takes them; they set the input pins (E-stop GP13 high = open, alarm
//   GP14 low = any drive in alarm, home GP15-19 low = closed, ADC0-2 counts).
// - --home-at AXIS:PULSES: a simulated home switch, closed while the motor (the counters of the
//   first RESET plus the steps on the pins since) is at or past PULSES; set at the step edge.
// - --cpu-log PATH: per tick start, u64 t_ns, u64 cycles the CPU executed so far (not asleep) and
//   u64 the firmware's count of cycles it spent spinning (the 32-bit SRAM word at --spin-addr HEX,
//   g_spin_cycles, extended), so work = cycles - spin.
// - --clock-file PATH: the simulated time (float64 ns, little-endian, at offset 0), rewritten after
//   every 20 us slice: the host reads it to time its timeouts in the chip's time.
// - --host-paced MS: the chip's time waits for the host: while the chip is stepping (its last
//   STATUS says armed or running) and MS of its time have passed since the host's last byte, the
//   clock stops until the host sends again (or stays silent for 10 s of real time: then it runs
//   on, and the watchdog trips). For offline runs (pmctl run --no-realtime): a host that is not
//   scheduled for a while is not late for the chip. Without it the chip's time runs on, as a real
//   chip's does.
// - --profile PATH: PC samples (JSON {pc: count}), for benchmarks; --trace PATH: every valid frame
//   both ways, one line each: H|C, simulated us, wall ms, hex.
// - On exit (SIGTERM, "quit", or 2 s after stdin closes: the parent died) it prints one JSON line of
//   figures on stdout. It prints "READY" on stdout when the chip runs.
import fs from 'node:fs';
import { RP2040, ConsoleLogger, LogLevel } from 'rp2040js';

const args = process.argv.slice(2);
const opt = { homeAt: [], baud: 3000000, speed: 1 };
for (let i = 0; i < args.length; i++) {
  const a = args[i], v = args[i + 1];
  if (a === '--elf') opt.elf = v;
  else if (a === '--link-fd') opt.fd = parseInt(v, 10);
  else if (a === '--edge-log') opt.edgeLog = v;
  else if (a === '--cpu-log') opt.cpuLog = v;
  else if (a === '--control') opt.control = v;
  else if (a === '--baud') opt.baud = parseInt(v, 10);
  else if (a === '--speed') opt.speed = parseFloat(v);
  else if (a === '--profile') opt.profile = v;
  else if (a === '--clock-file') opt.clockFile = v;
  else if (a === '--trace') opt.trace = v;
  else if (a === '--host-paced') opt.hostPaced = parseFloat(v);
  else if (a === '--spin-addr') opt.spinAddr = parseInt(v, 16);
  else if (a === '--home-at') {
    const m = /^([0-4]):(-?\d+)$/.exec(v || '');
    if (!m) usage();
    opt.homeAt.push([parseInt(m[1], 10), parseInt(m[2], 10)]);
  } else usage();
  i++;
}
if (!opt.elf || !Number.isInteger(opt.fd)) usage();

function usage() {
  process.stderr.write('usage: node run.mjs --elf bridge.elf --link-fd FD [--edge-log PATH] [--cpu-log PATH] ' +
    '[--control FIFO] [--home-at AXIS:PULSES]... [--baud N] [--speed X]\n');
  process.exit(2);
}

const NAXES = 5, PIN_STEP0 = 2, PIN_DIR0 = 7, PIN_ESTOP = 13, PIN_ALARM = 14, PIN_HOME0 = 15, PIN_TICK = 25;
const FLASH = 0x10000000;

// ---------------------------------------------------------------- the chip
const mcu = new RP2040();
mcu.logger = new ConsoleLogger(LogLevel.Error, true);
const elf = fs.readFileSync(opt.elf);
loadElf(elf);
mcu.core.VTOR = FLASH + 0x100;
mcu.core.reset();
const clock = mcu.clock, core = mcu.core, uart = mcu.uart[0];
let resets = 0;
mcu.watchdog = mcu.peripherals[0x40058];
mcu.watchdog.onWatchdogTrigger = () => {          // the hardware watchdog: the chip restarts
  resets++;
  process.stderr.write(`rp2040-emu: hardware watchdog reset at ${(clock.nanos / 1e6).toFixed(3)} ms ` +
    `(the main loop stopped at pc 0x${core.PC.toString(16)})\n`);
  mcu.watchdog.writeUint32(0, 0);                // stopped until the firmware starts it again
  core.VTOR = FLASH + 0x100;
  core.reset();
};

function loadElf(b) {
  if (b.readUInt32BE(0) !== 0x7f454c46 || b[4] !== 1 || b[5] !== 1 || b.readUInt16LE(18) !== 40)
    throw new Error(`${opt.elf}: not a 32-bit little-endian ARM ELF file`);
  const phoff = b.readUInt32LE(28), phentsize = b.readUInt16LE(42), phnum = b.readUInt16LE(44);
  let loaded = 0;
  for (let i = 0; i < phnum; i++) {
    const p = phoff + i * phentsize;
    if (b.readUInt32LE(p) !== 1) continue;            // PT_LOAD
    const off = b.readUInt32LE(p + 4), paddr = b.readUInt32LE(p + 12), filesz = b.readUInt32LE(p + 16);
    if (!filesz) continue;
    if (paddr < FLASH || paddr + filesz > FLASH + mcu.flash.length)
      throw new Error(`${opt.elf}: segment at 0x${paddr.toString(16)} is not in flash`);
    mcu.flash.set(b.subarray(off, off + filesz), paddr - FLASH);
    loaded += filesz;
  }
  if (!loaded) throw new Error(`${opt.elf}: nothing to load`);
}

// ---------------------------------------------------------------- frames (firmware_bridge/PROTOCOL.md)
function crc16(buf, start, end) {                    // CRC-16/CCITT-FALSE
  let c = 0xffff;
  for (let i = start; i < end; i++) {
    c ^= buf[i] << 8;
    for (let k = 0; k < 8; k++) c = (c & 0x8000) ? ((c << 1) ^ 0x1021) & 0xffff : (c << 1) & 0xffff;
  }
  return c;
}

// A resynchronising parser: onFrame(bytes) for each valid frame, onBytes(bytes) for anything else.
class Parser {
  constructor(onFrame, onBytes) { this.buf = []; this.onFrame = onFrame; this.onBytes = onBytes; }
  push(b) {
    const buf = this.buf;
    buf.push(b);
    for (;;) {
      let i = 0;
      while (i < buf.length && buf[i] !== 0x7e) i++;
      if (i) this.onBytes(buf.splice(0, i));
      if (buf.length < 2) return;
      const len = buf[1];
      if (len < 6 || len > 125) { this.onBytes(buf.splice(0, 1)); continue; }
      if (buf.length < len) return;
      const c = crc16(buf, 1, len - 2);
      if (buf[len - 2] !== (c >> 8) || buf[len - 1] !== (c & 0xff)) { this.onBytes(buf.splice(0, 1)); continue; }
      this.onFrame(buf.splice(0, len));
    }
  }
}

// ---------------------------------------------------------------- pins and counters
const pinCount = new Int32Array(NAXES);    // steps counted on the pins since start (signed by DIR)
const base = new Int32Array(NAXES);        // firmware counters = pinCount + base (set at each RESET)
const dirLevel = [1, 1, 1, 1, 1].map((_, a) => 0);
let strobes = 0;                           // tick starts since the last RESET
const snaps = new Map();                   // strobe index -> pin counts at it
const home = new Map(opt.homeAt);          // axis -> switch position (pulses)
let motorBase = null;                      // motor = pinCount + motorBase (from the first RESET)
let lastEdgeNs = 0, edges = 0;

let edgeFd = opt.edgeLog ? fs.openSync(opt.edgeLog, 'w') : -1;
const EDGE_BUF = Buffer.alloc(16 * 8192);
let edgeN = 0;
function edge(axis, kind) {
  if (edgeFd < 0) return;
  const o = 16 * edgeN;
  EDGE_BUF.writeBigUInt64LE(BigInt(Math.round(clock.nanos)), o);
  EDGE_BUF.writeUInt32LE(strobes > 0 ? strobes - 1 : 0xffffffff, o + 8);
  EDGE_BUF[o + 12] = axis; EDGE_BUF[o + 13] = kind; EDGE_BUF[o + 14] = 0; EDGE_BUF[o + 15] = 0;
  if (++edgeN === 8192) flushEdges();
}
function flushEdges() {
  if (edgeFd >= 0 && edgeN) fs.writeSync(edgeFd, EDGE_BUF, 0, 16 * edgeN);
  edgeN = 0;
}

const cpuFd = opt.cpuLog ? fs.openSync(opt.cpuLog, 'w') : -1;
const CPU_REC = Buffer.alloc(24);
let busyCycles = 0, spin32 = 0, spin = 0;
function spinCycles() {                    // the firmware's 32-bit counter, extended
  if (!opt.spinAddr) return 0;
  const v = mcu.sramView.getUint32(opt.spinAddr - 0x20000000, true);
  spin += (v - spin32) >>> 0;
  spin32 = v;
  return spin;
}

for (let a = 0; a < NAXES; a++) {
  mcu.gpio[PIN_STEP0 + a].addListener((v, old) => {
    if (old > 1) return;                   // the pin becoming an output at boot
    edges++;
    lastEdgeNs = clock.nanos;
    if (v === 1) {
      pinCount[a] += dirLevel[a] ? 1 : -1;
      if (motorBase && home.has(a)) setHome(a);
    }
    edge(a, v === 1 ? 1 : 0);
  });
  mcu.gpio[PIN_DIR0 + a].addListener((v, old) => {
    dirLevel[a] = v === 1 ? 1 : 0;
    if (old <= 1) edge(a, v === 1 ? 3 : 2);
  });
}
// input pins as the harness sets them: kind 5 (low) / 6 (high), axis = the GPIO number
function setInput(pin, high) {
  if (mcu.gpio[pin].rawInputValue !== high) edge(pin, high ? 6 : 5);
  mcu.gpio[pin].setInputValue(high);
}
mcu.gpio[PIN_TICK].addListener((v, old) => {
  if (old > 1) return;
  snaps.set(strobes, Int32Array.from(pinCount));
  snaps.delete(strobes - 64);
  strobes++;
  edge(255, 4);
  if (cpuFd >= 0) {
    CPU_REC.writeBigUInt64LE(BigInt(Math.round(clock.nanos)), 0);
    CPU_REC.writeBigUInt64LE(BigInt(busyCycles), 8);
    CPU_REC.writeBigUInt64LE(BigInt(spinCycles()), 16);
    fs.writeSync(cpuFd, CPU_REC);
  }
});

function setHome(a) {                      // closed (pin low) while the motor is at or past the switch
  mcu.gpio[PIN_HOME0 + a].setInputValue(!(pinCount[a] + motorBase[a] >= home.get(a)));
}

// idle levels: E-stop chain closed (low), no drive alarm (high), home switches open (high)
mcu.gpio[PIN_ESTOP].setInputValue(false);
let alarms = 0;
mcu.gpio[PIN_ALARM].setInputValue(true);
for (let a = 0; a < NAXES; a++) mcu.gpio[PIN_HOME0 + a].setInputValue(true);

// ---------------------------------------------------------------- the link
const T_RESET = 0x03, T_ACK = 0x81, T_STATUS = 0x82, ACK_NAK = 1, ACK_FULL = 2, ACK_REJECT = 4, ACK_DUP = 8;
const E_FAULT = 3;
const resetsSent = new Map();              // host SEQ of a RESET -> its counters
const traceFd = opt.trace ? fs.openSync(opt.trace, 'w') : -1;   // --trace: every frame, both ways
function traceFrame(dir, f) {
  if (traceFd >= 0) fs.writeSync(traceFd, `${dir} ${(clock.nanos / 1e3).toFixed(1)} ${(performance.now() - wall0).toFixed(1)} ${Buffer.from(f).toString('hex')}\n`);
}
const fromHost = new Parser((f) => {
  traceFrame('H', f);
  if (f[3] === T_RESET && f.length === 26) {
    const b = Buffer.from(f);
    resetsSent.set(f[2], Array.from({ length: NAXES }, (_, a) => b.readInt32LE(4 + 4 * a)));
  }
}, () => {});
const toHost = [];                         // bytes for the host
const fromChip = new Parser((f) => {
  traceFrame('C', f);
  if (f[3] === T_ACK && f.length === 9 && f[6] === T_RESET) {
    const flags = f[4], code = f[5];
    const seq = (f[2] - 1) & 0xff;
    const ok = !(flags & (ACK_NAK | ACK_FULL | ACK_DUP)) && (!(flags & ACK_REJECT) || code === E_FAULT);
    if (ok && resetsSent.has(seq)) {      // the firmware took the RESET: counters re-referenced
      const c = resetsSent.get(seq);
      for (let a = 0; a < NAXES; a++) base[a] = c[a] - pinCount[a];
      strobes = 0;
      snaps.clear();
      if (!motorBase) {
        motorBase = Int32Array.from(c, (x, a) => x - pinCount[a]);
        for (const a of home.keys()) setHome(a);
      }
    }
  } else if (f[3] === T_STATUS && f.length === 118) {
    const b = Buffer.from(f);
    chipStepping = b[4] === 1 || b[4] === 2;          // armed or running: waiting for or executing ticks
    const started = b.readUInt32LE(4 + 8), why = b[4 + 84];
    const counts = why === 0 && started >= 1 && snaps.has(started - 1) ? snaps.get(started - 1) : pinCount;
    for (let a = 0; a < NAXES; a++) b.writeInt32LE((counts[a] + base[a]) | 0, 4 + 20 + 4 * a);
    const c = crc16(b, 1, 116);
    b[116] = c >> 8; b[117] = c & 0xff;
    f = Array.from(b);
  }
  for (const x of f) toHost.push(x);
}, (bytes) => { for (const x of bytes) toHost.push(x); });
uart.onByte = (b) => fromChip.push(b);

let chipStepping = false, hostSim = 0, hostWall = performance.now();
const rxQ = [];                            // bytes from the host, not yet in the FIFO
let rxHead = 0, rxNext = 0, rxOverruns = 0, txDropped = 0;
const byteNs = 10 * 1e9 / opt.baud;
function feedRx() {
  while (rxHead < rxQ.length && clock.nanos >= rxNext) {
    const b = rxQ[rxHead++];
    if (uart.rxFIFO.full) rxOverruns++; else uart.feedByte(b);
    rxNext = Math.max(rxNext, clock.nanos - byteNs) + byteNs;
  }
  if (rxHead === rxQ.length) { rxQ.length = 0; rxHead = 0; }
}

const inBuf = Buffer.alloc(4096);
function pollHost() {
  for (;;) {
    let n;
    try { n = fs.readSync(opt.fd, inBuf, 0, inBuf.length, null); } catch (e) {
      if (e.code === 'EAGAIN' || e.code === 'EWOULDBLOCK') return;
      if (e.code === 'EIO') return;          // no slave open at the moment
      throw e;
    }
    if (!n) return;
    hostSim = clock.nanos;
    hostWall = performance.now();
    if (!rxQ.length) rxNext = Math.max(rxNext, clock.nanos);
    for (let i = 0; i < n; i++) { rxQ.push(inBuf[i]); fromHost.push(inBuf[i]); }
  }
}
function flushHost() {
  if (!toHost.length) return;
  const b = Buffer.from(toHost);
  toHost.length = 0;
  try { fs.writeSync(opt.fd, b); } catch (e) {
    if (e.code === 'EAGAIN' || e.code === 'EWOULDBLOCK' || e.code === 'EIO') txDropped += b.length;
    else throw e;
  }
}

// ---------------------------------------------------------------- control
let ctlFd = -1, ctlText = '';
if (opt.control) {
  try { fs.statSync(opt.control); } catch { throw new Error(`--control ${opt.control}: no such FIFO`); }
  ctlFd = fs.openSync(opt.control, fs.constants.O_RDWR | fs.constants.O_NONBLOCK);
}
let quit = false;
function pollControl() {
  if (ctlFd < 0) return;
  let n;
  try { n = fs.readSync(ctlFd, inBuf, 0, inBuf.length, null); } catch (e) {
    if (e.code === 'EAGAIN' || e.code === 'EWOULDBLOCK') return;
    throw e;
  }
  ctlText += inBuf.toString('latin1', 0, n);
  let nl;
  while ((nl = ctlText.indexOf('\n')) >= 0) {
    const line = ctlText.slice(0, nl).trim().split(/\s+/);
    ctlText = ctlText.slice(nl + 1);
    const [cmd, x, y] = line, a = parseInt(x, 10), v = parseInt(y, 10);
    if (cmd === 'quit') quit = true;
    else if (cmd === 'estop' && (a === 0 || a === 1)) setInput(PIN_ESTOP, a === 1);
    else if (cmd === 'alarm' && a >= 0 && a < NAXES && (v === 0 || v === 1)) {
      alarms = v ? alarms | (1 << a) : alarms & ~(1 << a);
      setInput(PIN_ALARM, alarms === 0);                   // the drives' alarm outputs in parallel
    } else if (cmd === 'home' && a >= 0 && a < NAXES && (v === 0 || v === 1)) setInput(PIN_HOME0 + a, v === 0);
    else if (cmd === 'adc' && a >= 0 && a < 3 && Number.isFinite(v)) mcu.adc.channelValues[a] = Math.max(0, Math.min(4095, v));
    else if (line[0]) process.stderr.write(`rp2040-emu: control: ignored line '${line.join(' ')}'\n`);
  }
}

// ---------------------------------------------------------------- the run loop, in simulated time
const SLICE_NS = 20000;                    // emulate 20 us, then look at the host and the control FIFO
const AHEAD_MS = 5;                        // simulated time may lead real time by this much (--speed 1)
const wall0 = performance.now();
let anchorWall = wall0, anchorSim = 0;
const sleeper = new Int32Array(new SharedArrayBuffer(4));
const clockFd = opt.clockFile ? fs.openSync(opt.clockFile, 'r+') : -1;   // made by the harness, 8 bytes
const clockBuf = Buffer.alloc(8);
function publishClock() {
  if (clockFd < 0) return;
  clockBuf.writeDoubleLE(clock.nanos, 0);
  fs.writeSync(clockFd, clockBuf, 0, 8, 0);
}
let orphanAt = Infinity, lastFlush = wall0;
process.on('SIGTERM', () => { quit = true; });
process.on('SIGINT', () => { quit = true; });
process.stdin.on('end', () => { orphanAt = performance.now() + 2000; });
process.stdin.on('error', () => { orphanAt = performance.now() + 2000; });
process.stdin.resume();

const prof = opt.profile ? new Map() : null;   // --profile PATH: PC samples (for benchmarks)
function runSlice(target) {
  while (clock.nanos < target) {
    if (core.waiting) {
      // WFI does not sleep while an enabled interrupt is pending (ARMv6-M), PRIMASK or not
      if (core.pendingInterrupts & core.enabledInterrupts) { core.waiting = false; core.interruptsUpdated = true; continue; }
      let t = clock.nextAlarm ? Math.min(clock.nextAlarm.nanos, target) : target;
      if (rxHead < rxQ.length) t = Math.min(t, Math.max(rxNext, clock.nanos));
      if (t > clock.nanos) clock.tick(t - clock.nanos);
      feedRx();
    } else {
      if (prof && (busyCycles & 63) === 0) prof.set(core.PC, (prof.get(core.PC) || 0) + 1);
      const c = core.executeInstruction();
      busyCycles += c;
      clock.tick(c * 8);
      if (rxHead < rxQ.length && clock.nanos >= rxNext) feedRx();
    }
  }
}

process.stdout.write('READY\n');
function loop() {
  const t0 = performance.now();
  while (!quit && performance.now() - t0 < 5) {
    pollHost();
    if (opt.hostPaced > 0 && chipStepping && rxHead === rxQ.length && clock.nanos - hostSim > opt.hostPaced * 1e6 &&
        performance.now() - hostWall < 10000) {
      Atomics.wait(sleeper, 0, 0, 0.2);      // the chip's time waits for the host
      anchorWall = performance.now(); anchorSim = clock.nanos;
      pollControl();
      continue;
    }
    runSlice(clock.nanos + SLICE_NS);
    publishClock();
    flushHost();
    pollControl();
    if (opt.speed > 0) {                   // no faster than real time (x speed)
      const wall = performance.now();
      const ahead = (clock.nanos - anchorSim) / 1e6 / opt.speed - (wall - anchorWall);
      if (ahead < -AHEAD_MS) { anchorWall += -ahead - AHEAD_MS; }   // behind: the lead is not banked
      else if (ahead > 0.2) Atomics.wait(sleeper, 0, 0, Math.min(ahead, 1));
    }
  }
  const now = performance.now();
  if (now - lastFlush > 50 || clock.nanos - lastEdgeNs > 2e6) { flushEdges(); lastFlush = now; }
  if (quit || now > orphanAt) return finish();
  setImmediate(loop);
}

function finish() {
  flushHost();
  flushEdges();
  if (edgeFd >= 0) fs.closeSync(edgeFd);
  if (cpuFd >= 0) fs.closeSync(cpuFd);
  if (prof) fs.writeFileSync(opt.profile, JSON.stringify(Object.fromEntries(prof)));
  const wall = (performance.now() - wall0) / 1e3;
  process.stdout.write(JSON.stringify({ sim_s: clock.nanos / 1e9, wall_s: wall, busy_cycles: busyCycles,
    cpu_share: busyCycles * 8 / clock.nanos, edges, rx_overruns: rxOverruns, tx_dropped: txDropped,
    watchdog_resets: resets, pin_counts: Array.from(pinCount) }) + '\n');
  process.exit(0);
}
setImmediate(loop);
