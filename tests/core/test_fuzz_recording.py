"""Fuzzing the recording reader: byte mutations of the bundled recordings' recording.json and
(shortened) data.csv.
Strategies and targets in tests/fuzz_common.py; benchmarks/fuzz_counts.py runs them with large budgets
and prints the counts (inputs tried, clean refusals, valid results, crashes)."""

from hypothesis import given, settings

from fuzz_common import FUZZ, TARGETS, check as _check


@settings(FUZZ, max_examples=100)
@given(TARGETS["recording"][0])
def test_recording_is_refused_cleanly_or_finite(x):
    """InputError/ConfigError naming the folder, or columns without infinities and a strictly increasing t."""
    _check("recording", x)
