"""Fuzzing the machine and service configs: byte mutations of config/*.toml, hostile values
(strings, bools, huge integers, inf/nan, arrays, tables) for one key, and renamed keys and tables.
Strategies and targets in tests/fuzz_common.py; benchmarks/fuzz_counts.py runs them with large budgets
and prints the counts (inputs tried, clean refusals, valid results, crashes)."""

from hypothesis import given, settings

from fuzz_common import FUZZ, TARGETS, check as _check


@settings(FUZZ, max_examples=100)
@given(TARGETS["machine-config"][0])
def test_machine_config_is_refused_cleanly_or_finite_and_in_range(x):
    """ConfigError naming the file, or a Machine whose every number is finite and in range."""
    _check("machine-config", x)


@settings(FUZZ, max_examples=100)
@given(TARGETS["service-config"][0])
def test_service_config_is_refused_cleanly_or_valid_with_backend_options(x):
    """ConfigError naming the file, or a config whose loop, NC and backend options are all valid."""
    _check("service-config", x)
