"""The how-to pages' examples run, and print what the pages show.

Each page of `docs/how-to/` runs its ```python blocks in a fresh process and compares what
they print with the ```text block shown after them, within the tolerance of
`tests.docs._shown_output` (the mechanism of the README's check). Blocks marked
`<!-- docs-test: skip, <reason> -->` in the page are not run.
"""

import importlib.util

import pytest

from tests.docs._shown_output import ROOT, SKIP, examples, page_problems

PAGES = sorted((ROOT / "docs" / "how-to").glob("*.md"))
#: Pages with a block that cannot run as it stands and is not yet marked in the page.
UNMARKED: dict[str, str] = {}
#: Pages whose examples need an optional extra.
EXTRAS = {"render.md": ("mitsuba", "drjit"), "local-kernels.md": ("blackjax",), "diagnostics.md": ("numpyro", "arviz")}


def test_a_marked_block_is_left_out_and_a_shown_output_is_paired():
    page = "```python\nprint(1)\n```\n\n```text\n1\n```\n\n<!-- docs-test: skip, takes hours -->\n```python\nrun()\n```\n"
    assert examples(page) == [("print(1)\n", "1\n")]
    assert not SKIP.search("<!-- docs-test: skip -->\n"), "a skipped block states why"


@pytest.mark.slow
@pytest.mark.parametrize("page", PAGES, ids=[page.name for page in PAGES])
def test_howto_examples_print_what_the_page_shows(page):
    if page.name in UNMARKED:
        pytest.skip(UNMARKED[page.name])
    missing = [name for name in EXTRAS.get(page.name, ()) if importlib.util.find_spec(name) is None]
    if missing:
        pytest.skip(f"{page.name} needs {', '.join(missing)}, which is not installed")
    shown, problems = page_problems(page)
    assert not problems, "\n".join(problems)
