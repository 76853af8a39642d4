"""The README's examples run as shown, and print what the README says they print.

Every ```python block of the README runs, in order and in one namespace, in a fresh process
with JAX's defaults (float32); a ```text block right after one is its output, compared
within a tolerance (`tests.docs._shown_output`), so the shown output cannot drift from what
the code does.
"""

import pytest

from tests.docs._shown_output import ROOT, disagreements, page_problems


def test_the_readme_check_can_fail():
    assert disagreements("x4 in 16.4 s: 0.1665 +- 0.0010", "x4 in 21.0 s: 0.1653 +- 0.0011") == []
    assert disagreements("full x4", "diagonal x4")
    assert disagreements("x4", "x8")
    assert disagreements("in 87 s", "in 16 s")
    assert disagreements("log Z = -31.31", "log Z = -30.2")


@pytest.mark.slow
def test_readme_examples_print_what_the_readme_shows():
    shown, problems = page_problems(ROOT / "README.md")
    assert not problems, "\n".join(problems)
    assert shown >= 3, "the README shows the output of its examples"
