"""Fuzzing the command line, in process: `pmctl kin` with hostile numbers and mutated configs, `pmctl run`
with mutated jobs that are refused before anything moves, and junk argument lists.
Strategies and targets in tests/fuzz_common.py; benchmarks/fuzz_counts.py runs them with large budgets
and prints the counts (inputs tried, clean refusals, valid results, crashes)."""

from hypothesis import given, settings

from fuzz_common import FUZZ, TARGETS, check as _check


@settings(FUZZ, max_examples=50)
@given(TARGETS["cli"][0])
def test_cli_ends_in_one_line_and_a_documented_exit_code(x):
    """Exit 0, 1 (one line 'pmctl: error: ...') or 2 (usage): never a traceback or an internal error."""
    _check("cli", x)


# ---------------------------------------------------------------- the last line of defence

import pytest  # noqa: E402

from pmctl.interfaces import cli  # noqa: E402
from pmctl.interfaces.commands import kin  # noqa: E402


def _boom(args):
    raise ZeroDivisionError("a bug\non two lines")


def test_any_other_exception_is_one_line_and_exit_70(monkeypatch, capsys):
    monkeypatch.setattr(kin, "run", _boom)
    monkeypatch.delenv("PMCTL_DEBUG", raising=False)
    assert cli.main(["kin", "fk", "--joints", "1,2,3,4,5"]) == cli.EXIT_INTERNAL == 70
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("pmctl: internal error: ZeroDivisionError: a bug; on two lines")
    monkeypatch.setenv("PMCTL_DEBUG", "1")
    assert cli.main(["kin", "fk", "--joints", "1,2,3,4,5"]) == 70
    err = capsys.readouterr().err
    assert "Traceback" in err and "ZeroDivisionError" in err


def test_pmctl_errors_usage_and_memory(monkeypatch, capsys, tmp_path):
    p = tmp_path / "bad.ngc"
    p.write_text("G0 X0 Y0 Z90\nG1 F0.42 X1e400\n")
    assert cli.main(["run", "--no-realtime", "--quiet", "--state", "", "--job", str(p)]) == 1
    err = capsys.readouterr().err
    assert err == f"pmctl: error: {p}:2: column 12: E400 has nothing to use it: E is an analog channel of " \
                  "M66-M68 (numbers have no exponent in G-code)\n"
    with pytest.raises(SystemExit) as e:
        cli.main(["kin", "ik", "--tip"])
    assert e.value.code == 2
    capsys.readouterr()

    def oom(args):
        raise MemoryError()
    monkeypatch.setattr(kin, "run", oom)
    monkeypatch.delenv("PMCTL_DEBUG", raising=False)
    assert cli.main(["kin", "fk", "--joints", "1,2,3,4,5"]) == 70
    assert capsys.readouterr().err.startswith("pmctl: internal error: out of memory")
