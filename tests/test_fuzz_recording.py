"""Fuzzing the recording reader: byte mutations of the bundled recordings' recording.json and
(shortened) data.csv.
Strategies and targets in tests/fuzz_common.py; benchmarks/fuzz_counts.py runs them with large budgets
and prints the counts (inputs tried, clean refusals, valid results, crashes)."""

from hypothesis import HealthCheck, event, given, settings

from fuzz_common import TARGETS

FUZZ = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                      HealthCheck.filter_too_much])


def _check(name, x):
    outcome = TARGETS[name][1](x)            # raises on anything but a clean refusal or a valid result
    assert outcome in ("valid", "refused")
    event(outcome)


@settings(FUZZ, max_examples=100)
@given(TARGETS["recording"][0])
def test_recording_is_refused_cleanly_or_finite(x):
    """InputError/ConfigError naming the folder, or columns without infinities and a strictly increasing t."""
    _check("recording", x)
