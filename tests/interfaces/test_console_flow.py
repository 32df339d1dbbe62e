"""grbl's flow control on the console of `pmctl serve`, over a real pty: ``ok`` means the block entered
the planner queue, whose depth is the one ``[OPT:]`` and ``Bf:`` advertise. A character-counting
sender streaming three times that many moves is paced by the motion: when it holds the k-th ``ok``,
the machine executes block k - depth or later (``Ln:``, the N word of the block being executed); the
free blocks of ``Bf:`` are the depth less what is queued; M30 is answered once the end is queued."""

import re

import pytest

from grbl_sender import serve_session


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    yield from serve_session(tmp_path_factory, "console_flow")


def depth_of(s):
    n = len(s.pushed)
    assert s.send("$I") == "ok"
    opt = [x for x in s.pushed[n:] if x.startswith("[OPT:")]
    assert opt, s.pushed[n:]
    m = re.match(r"\[OPT:[A-Z]*,(\d+),(\d+)\]", opt[0])
    return int(m.group(1)), int(m.group(2))


def test_oks_are_paced_by_the_motion_and_bf_counts_the_queue(daemon):
    s, *_ = daemon
    depth, rx = depth_of(s)
    assert (depth, rx) == (128, 128)
    assert s.send("$10=3") == "ok"                        # MPos and Bf:
    st = s.status()
    assert st["Bf"] == f"{depth},{rx}", st                # idle: all free
    assert s.send("G21 G91 F1200") == "ok"
    # 3 x depth moves of 0.5 mm at 20 mm/s (25 ms each at speed) along the sides of a 16 mm square, each
    # with its N word
    steps = ["X0.5", "Y0.5", "X-0.5", "Y-0.5"]
    lines = [f"N{k + 1} G1 {steps[(k // 32) % 4]}" for k in range(3 * depth)]
    seen = []                                             # (oks received, block executing) after each ok
    n0 = len(s.answers)

    def during(i):
        k = len(s.answers) - n0
        if k > depth + 2 and (not seen or seen[-1][0] != k):
            st = s.status()
            seen.append((k, int(st.get("Ln", 0)) if st["state"] == "Run" else len(lines) + 1, st.get("Bf")))
    answers = s.stream(lines, during=during)
    assert answers == ["ok"] * len(lines)
    assert len(seen) >= depth // 2, seen
    for k, ln, bf in seen:
        # k - 1 motion lines answered (the first ok was G21 G91 F600's): block k - 1 - depth or a later one runs
        assert ln >= k - 1 - depth, (k, ln, seen)
        free = int(bf.split(",")[0])
        assert 0 <= free <= depth
    st = s.wait_state(("Idle",), 300)
    assert st["Bf"] == f"{depth},{rx}"
    assert s.send("G90") == "ok" and s.send("$10=1") == "ok"


def test_the_queue_fills_to_its_depth_while_held(daemon):
    s, *_ = daemon
    depth, _ = depth_of(s)
    assert s.send("$10=3") == "ok"
    s.realtime(b"!")                                      # a hold while idle: motion sent now waits
    assert s.wait_state(("Hold:0",), 30)["state"] == "Hold:0"
    n0 = len(s.answers)
    lines = ["G21 G91 F3000"] + ["G1 X0.1"] * (depth + 5)            # 13.3 mm in a straight line
    for ln in lines:
        s.send(ln, wait=False)
    s.wait_for(lambda: len(s.answers) - n0 >= depth + 1, 30)
    s.wait_for(lambda: False, 0.5)                        # more would have come by now: the machine holds
    assert len(s.answers) - n0 == depth + 1, s.answers[n0:]          # G21 G91 F600 and depth blocks
    st = s.status()
    assert st["Bf"].split(",")[0] == "0", st
    s.realtime(b"~")
    assert s.wait_for(lambda: len(s.answers) - n0 == len(lines), 60)
    assert s.wait_state(("Idle",), 60)["state"] == "Idle"
    assert s.send("G90") == "ok" and s.send("$10=1") == "ok"
