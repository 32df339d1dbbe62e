"""Fuzzing the G-code reader: random text, a grammar of words with hostile numbers, and
mutations of the bundled programs (text and bytes, through the file reader).
Strategies and targets in tests/fuzz_common.py; benchmarks/fuzz_counts.py runs them with large budgets
and prints the counts (inputs tried, clean refusals, valid results, crashes)."""

from hypothesis import given, settings

from fuzz_common import FUZZ, TARGETS, check as _check


@settings(FUZZ, max_examples=150)
@given(TARGETS["gcode"][0])
def test_gcode_text_is_refused_cleanly_or_gives_a_finite_job(x):
    """InputError with a sensible line/column, or a job whose every value is finite and in range."""
    _check("gcode", x)


@settings(FUZZ, max_examples=80)
@given(TARGETS["gcode-file"][0])
def test_mutated_bundled_programs_as_files(x):
    """The file reader too: bad bytes (not UTF-8) are InputErrors naming line and column."""
    _check("gcode-file", x)


# ---------------------------------------------------------------- the planner on absurd but legal programs

@settings(FUZZ, max_examples=40)
@given(TARGETS["planner"][0])
def test_planner_refuses_or_plans_within_its_bounds(lines):
    """Tiny feeds, thousands of arc turns, hour-long dwells: a clean refusal naming the line, or a finite
    trajectory within the (here lowered) bounds; never an allocation beyond them."""
    _check("planner", lines)
