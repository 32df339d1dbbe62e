"""Fuzzing the CL-data reader: random text, lines of hostile numbers and flags, valid passes with a
hostile number now and then, and mutations of the bundled hemisphere.
Strategies and targets in tests/fuzz_common.py; benchmarks/fuzz_counts.py runs them with large budgets
and prints the counts (inputs tried, clean refusals, valid results, crashes)."""

from hypothesis import given, settings

from fuzz_common import FUZZ, TARGETS, check as _check


@settings(FUZZ, max_examples=150)
@given(TARGETS["cldata"][0])
def test_cl_text_is_refused_cleanly_or_gives_finite_unit_axes(x):
    """InputError with the line, or points within range with unit tool axes pointing up."""
    _check("cldata", x)
