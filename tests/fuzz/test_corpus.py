"""The bad-input corpus (corpus.py) as tests: one test per case.

Each case must exit with its documented code and one ``Error:`` line naming what was
wrong, raise nothing (no traceback), write nothing anywhere (in particular nothing outside
the output folder) and leave every input byte for byte and mode for mode as it was.
"""

from __future__ import annotations

import pytest
from corpus import BASES, Case, all_cases, build_template, run_case

CASES = all_cases()


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    return build_template(tmp_path_factory.mktemp("fuzz") / "template")


@pytest.mark.parametrize("command", sorted(BASES))
def test_the_unspoiled_inputs_run_clean(command, template, tmp_path):
    outcome = run_case(Case(f"ok-{command}", BASES[command]), template, tmp_path)
    assert outcome.code == 0, outcome.err + outcome.traceback


def test_the_corpus_is_large():
    assert len(CASES) >= 300


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input_is_one_clean_error(case, template, tmp_path):
    outcome = run_case(case, template, tmp_path)
    assert not outcome.problems, "\n".join(outcome.problems) + "\n" + outcome.traceback
