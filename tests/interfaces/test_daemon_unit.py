"""The shipped systemd unit: Type=notify with a watchdog, a dedicated user, a state directory,
real-time limits, and nothing that re-runs a job by itself."""

import configparser
from pathlib import Path

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "pmctl.service"


def test_unit_is_a_notify_service_with_watchdog_user_state_and_rt_limits():
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.optionxform = str
    cp.read(UNIT)
    s = cp["Service"]
    assert s["Type"] == "notify" and float(s["WatchdogSec"]) > 0
    assert s["User"] == "pmctl" and s["StateDirectory"] == "pmctl"
    assert int(s["LimitRTPRIO"]) > 0
    assert "pmctl serve" in s["ExecStart"] and "--state /var/lib/pmctl/" in s["ExecStart"]
    assert "--job" not in s["ExecStart"] and " run " not in s["ExecStart"]      # no job re-run after a restart
    assert s["KillMode"] == "mixed"
