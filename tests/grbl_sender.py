"""A small grbl 1.1 sender for the tests: runs `pmctl serve` on the sim with its console on a real
pty and talks to it as a character-counting sender does (grbl's stream.py protocol)."""

from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import sys
import time
import tty
from pathlib import Path

RX_BUFFER = 128
STATUS = re.compile(r"<([^|>]+)\|(MPos|WPos):([^|>]+)(.*)>")


def start_serve(tmp: Path, *, state=None, record=None, env=None, extra=(), realtime=False):
    """`pmctl serve` on the sim with its console on a pty at tmp/tty; offline ticks (--no-realtime)
    unless realtime, which runs it as an operator or an outside sender would."""
    link = tmp / "tty"
    if link.exists() or link.is_symlink():
        link.unlink()
    cmd = [sys.executable, "-m", "pmctl.interfaces.cli", "serve", "--config", "config/prototype.toml", "--backend",
           "sim", "--console", f"pty:{link}", "--state", str(state or tmp / "state.json"), *([] if realtime else ["--no-realtime"]), *extra]
    if record:
        cmd += ["--record", str(record)]
    err = open(tmp / "serve.err", "ab")
    e = dict(os.environ)
    e.update(env or {})
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, cwd=Path(__file__).resolve().parents[1], env=e)
    t0 = time.time()
    while not link.exists():
        if p.poll() is not None:
            raise RuntimeError(f"pmctl serve exited ({p.returncode}): {(tmp / 'serve.err').read_text()[-2000:]}")
        if time.time() - t0 > 120:
            p.kill()
            raise RuntimeError("pmctl serve did not open its console")
        time.sleep(0.05)
    return p, link


def stop_serve(p, sig=signal.SIGTERM, timeout=60):
    if p.poll() is None:
        p.send_signal(sig)
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    return p.returncode


def serve_session(tmp_path_factory, name: str):
    """A module fixture's body: ``pmctl serve`` on the sim with its console on a fresh pty and a
    reset sender; yields (sender, folder, pty link), then closes the sender and stops the daemon."""
    tmp = tmp_path_factory.mktemp(name)
    p, link = start_serve(tmp)
    s = Sender(link)
    s.reset()
    yield s, tmp, link
    s.close()
    stop_serve(p)


class Sender:
    def __init__(self, link, greeting_s=30.0):
        """Open the console's pty; the console greets a sender that opens it (the banner): wait for
        it (up to ``greeting_s``) so that it is not taken for the answer to a later reset."""
        self.fd = os.open(str(link), os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.buf = b""
        self.pending = []             # lengths of lines sent and not yet answered
        self.answers = []             # ok / error:N in order
        self.pushed = []              # everything else
        self.reports = []
        if greeting_s:
            self.wait_for(lambda: any(x.startswith("Grbl ") for x in self.pushed), greeting_s)

    def close(self):
        os.close(self.fd)

    def _pump(self, timeout=0.05):
        r, _, _ = select.select([self.fd], [], [], timeout)
        if not r:
            return
        try:
            self.buf += os.read(self.fd, 65536)
        except OSError:
            return
        while b"\n" in self.buf:
            line, self.buf = self.buf.split(b"\n", 1)
            s = line.decode("ascii", "replace").strip()
            if not s:
                continue
            if s == "ok" or s.startswith("error:"):
                self.answers.append(s)
                if self.pending:
                    self.pending.pop(0)
            elif s.startswith("<"):
                self.reports.append(s)
            else:
                self.pushed.append(s)

    def wait_for(self, pred, timeout=60.0):
        t0 = time.time()
        while time.time() - t0 < timeout:
            if pred():
                return True
            self._pump()
        return pred()

    def realtime(self, b: bytes):
        os.write(self.fd, b)

    def send(self, line: str, wait=True, timeout=60.0):
        """Send one line (character counting); with wait, return its answer."""
        data = (line.strip() + "\n").encode()
        n0 = len(self.answers)
        # a line longer than the whole buffer (a test of over-long lines) goes once nothing is pending
        room = min(RX_BUFFER, len(data))
        self.wait_for(lambda: sum(self.pending) + room <= RX_BUFFER, timeout)
        self.pending.append(len(data))
        os.write(self.fd, data)
        if wait:
            self.wait_for(lambda: len(self.answers) > n0, timeout)
            return self.answers[n0] if len(self.answers) > n0 else None
        return None

    def stream(self, lines, timeout=600.0, during=None):
        """Character-counting stream of ``lines``; ``during(i)`` runs after each line is sent."""
        n0 = len(self.answers)
        for i, line in enumerate(lines):
            self.send(line, wait=False, timeout=timeout)
            if during:
                during(i)
        self.wait_for(lambda: len(self.answers) - n0 >= len(lines), timeout)
        return self.answers[n0:]

    def status(self, timeout=10.0):
        n0 = len(self.reports)
        self.realtime(b"?")
        self.wait_for(lambda: len(self.reports) > n0, timeout)
        return parse_status(self.reports[-1]) if len(self.reports) > n0 else None

    def wait_state(self, states, timeout=120.0, poll=0.1):
        t0 = time.time()
        st = None
        while time.time() - t0 < timeout:
            st = self.status()
            if st and st["state"] in states:
                return st
            time.sleep(poll)
        return st

    def reset(self, timeout=30.0):
        n0 = len(self.pushed)
        self.pending.clear()
        self.realtime(b"\x18")
        self.wait_for(lambda: any(s.startswith("Grbl ") for s in self.pushed[n0:]), timeout)
        return [s for s in self.pushed[n0:]]


def counters_clean_log(tmp: Path) -> str:
    """The stopped ``pmctl serve``'s log (tmp/serve.err), once asserted to say that its rt side ended
    with every pulse sent counted and the device's counters equal to its own."""
    err = (tmp / "serve.err").read_text()
    assert "pulses sent = counter change: yes; device counters = counters: yes" in err, err[-2000:]
    return err


def hold_still_resume(s, settle=0.3, atol=1e-3, timeout=60):
    """Feed hold (``!``): the machine comes to Hold:0 and stays where it held for ``settle`` s; then
    cycle start (``~``). Returns the held status."""
    import numpy as np
    s.realtime(b"!")
    held = s.wait_state(("Hold:0",), timeout)
    assert held["state"] == "Hold:0", held
    time.sleep(settle)
    assert np.allclose(s.status()["pos"], held["pos"], atol=atol)
    s.realtime(b"~")
    return held


def parse_status(s):
    m = STATUS.match(s)
    if not m:
        return None
    out = {"state": m.group(1), "kind": m.group(2), "pos": [float(x) for x in m.group(3).split(",")]}
    for f in m.group(4).split("|"):
        if ":" in f:
            k, v = f.split(":", 1)
            out[k] = v
    return out


def rt_pid_of(pid):
    """The pid of the rt motion process that supervisor ``pid`` started (None when there is none)."""
    for t in os.listdir(f"/proc/{pid}/task"):
        for k in Path(f"/proc/{pid}/task/{t}/children").read_text().split():
            try:
                if b"pmctl.motion.rtproc" in Path(f"/proc/{k}/cmdline").read_bytes():
                    return int(k)
            except FileNotFoundError:          # (a child that just exited)
                continue
    return None


def power_cut_mid_move(tmp: Path, state: Path):
    """Start ``pmctl serve`` with ``state``, move X by −12 mm at F300 and, once the journal records the
    running job, the tool has moved 0.5 mm and a periodic snapshot (every 100 ticks) is past, SIGKILL
    the rt process and the supervisor at once: a power cut, nobody saves anything. Returns the
    position before the move."""
    import json
    import numpy as np
    p, link = start_serve(tmp, state=state)
    s = Sender(link)
    try:
        s.reset()
        p0 = np.array(s.status()["pos"])
        assert s.send("G21 G91 G1 F300 X-12") == "ok"
        s.wait_state(("Run",), 60)
        journal = Path(str(state) + ".journal")
        t0 = time.time()                 # the journal has recorded the running job ...
        while not json.loads(journal.read_text()).get("running") and time.time() - t0 < 60:
            time.sleep(0.05)
        t0 = time.time()                 # ... the tool moves (the first plan can take a second) ...
        while s.status()["pos"][0] - p0[0] > -0.5 and time.time() - t0 < 60:
            time.sleep(0.05)
        time.sleep(0.3)                  # ... and a periodic snapshot is past
        os.kill(rt_pid_of(p.pid), signal.SIGKILL)
        p.send_signal(signal.SIGKILL)
        p.wait(10)
    finally:
        s.close()
    return p0


def kill_supervisor_wait_rt(p, rt_pid, timeout=60.0):
    """SIGKILL the supervisor ``p`` and wait for its rt process ``rt_pid`` to notice, hold on the path,
    save its counters and exit by itself; if it is still there after ``timeout``, kill it too and
    fail the test."""
    import pytest
    p.send_signal(signal.SIGKILL)
    p.wait(10)
    t0 = time.time()
    while time.time() - t0 < timeout:
        try:
            os.kill(rt_pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
    os.kill(rt_pid, signal.SIGKILL)
    pytest.fail(f"the rt process kept running {timeout:g} s after the supervisor died")


def assert_locked_then_unlocked(s):
    """In Alarm, G-code is refused (error:9) until ``$X``, after which the machine is Idle."""
    assert s.status()["state"] == "Alarm"
    assert s.send("G1 X1") == "error:9"
    assert s.send("$X") == "ok"
    assert s.wait_state(("Idle",), 30)["state"] == "Idle"
