"""The step/dir bridge's own guards, reached past the host's: the host backend never sends a tick
with more pulses than fit in it (test_stepdir checks that refusal), so the bridge's check of the
same rule is only exercised by a host that is wrong. A filter on the backend's output rewrites one
tick (valid CRC, the next index) to carry more pulses than the tick holds: the bridge must refuse
it on receipt (E_SPEED: PROTOCOL.md, "More is refused"), stop with the over-speed fault, and step
none of it. (Were it queued, the check as each tick starts would fault it too, a second guard, but
the ticks before it would still run and the host would hear of it only then.)"""

import numpy as np
import pytest

from pmctl.core.config import load_machine
from pmctl.hal import bridge_protocol as bp
from pmctl.hal.stepdir import BridgeFault, StepDirBackend
from test_stepdir import bridge  # noqa: F401  (the fixture: the host bridge on a pty)

M = load_machine()
DT = 1e-3


def _stream(be, pulses_list):
    for p in pulses_list:
        be.read()
        be.write_pulses(p)


@pytest.mark.parametrize("over", [1, 50])
def test_a_tick_with_more_pulses_than_it_holds_is_refused_by_the_bridge_itself(bridge, over):
    be = StepDirBackend(M, DT, bridge.options())
    be.open(np.zeros(5, int))
    _stream(be, [[20, 0, 0, 0, 0]] * 30)
    most = be.max_step                        # what fits in a tick without a direction change

    def too_many(d):                          # a host bug: one tick with `over` pulses too many on X
        if d[3] == bp.T_TICK:
            f = bp.Parser().feed(d)[0]
            k, *p = bp._TICK.unpack(f.payload)
            p[3] = most + over
            return bp.frame(f.seq, f.type, bp.tick_payload(k, p))
        return d
    be.tx_filter = too_many
    # refused on receipt: never queued (none of its X pulses among those not executed), said so
    with pytest.raises(BridgeFault, match=r"more pulses than fit in a tick .*X 0, Y 0\) .*\(refused\)") as ei:
        _stream(be, [[20, 0, 0, 0, 0]] * 10)
    be.close()
    s = bridge.status()
    assert s.state == bp.S_FAULT and s.faults & bp.F_OVERSPEED
    executed = bp.executed_steps(bridge.edges())
    assert executed[3] == 0                                   # not one X step of the bad tick
    assert np.array_equal(ei.value.counts, executed)
