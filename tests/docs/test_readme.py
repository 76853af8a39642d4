"""The README's examples run as shown, and print what the README says they print.

Every ```python block of the README runs, in order and in one namespace (later blocks use
earlier names), in a fresh process with JAX's defaults (float32), as a reader would run
them. A ```text block right after a ```python block is that block's output: the words
must be the same and the numbers within 2% + 0.05 (wall times, `<number> s`, within a
factor of five; progress bars left out), so the shown output cannot drift from what the
code does.
"""

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FENCE = re.compile(r"```(\w+)\n(.*?)```", re.S)
NUMBER = r"[-+]?(?:nan|inf|(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:e[-+]?\d+)?)"
PROGRESS_BAR = "\u2501"
TOKEN = re.compile(rf"(?P<time>{NUMBER})(?= ?s\b)|(?P<number>{NUMBER})")

RUNNER = """
import contextlib, io, json, sys
namespace, outputs = {}, []
for code in json.loads(sys.stdin.read()):
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(code, "README.md", "exec"), namespace)
    outputs.append(printed.getvalue())
print(json.dumps(outputs))
"""


def readme_examples(text: str) -> list[tuple[str, str | None]]:
    """Each python block with the text block that follows it (its shown output), if any."""
    fences = list(FENCE.finditer(text))
    examples = []
    for i, fence in enumerate(fences):
        if fence.group(1) != "python":
            continue
        after = fences[i + 1] if i + 1 < len(fences) else None
        shown = None
        if after is not None and after.group(1) == "text" and not text[fence.end() : after.start()].strip():
            shown = after.group(2)
        examples.append((fence.group(2), shown))
    return examples


def _value(token: str) -> float:
    return float(token.replace(",", ""))


def disagreements(shown: str, printed: str) -> list[str]:
    """Where `printed` differs from `shown`: other words, or numbers outside the tolerance
    (2% + 0.05; a factor of five for wall times)."""
    def split(text):
        words, numbers = [], []
        for line in text.strip().splitlines():
            if PROGRESS_BAR in line:  # the bars' last frame, where no terminal takes them
                continue
            words.append(" ".join(TOKEN.sub("#", line).split()))
            numbers += [(m.lastgroup, m.group()) for m in TOKEN.finditer(line)]
        return words, numbers

    (shown_words, shown_numbers), (printed_words, printed_numbers) = split(shown), split(printed)
    if shown_words != printed_words:
        return [f"the words differ:\nshown:\n{shown.strip()}\nprinted:\n{printed.strip()}"]
    found = []
    for (kind, a), (_, b) in zip(shown_numbers, printed_numbers, strict=True):
        x, y = _value(a), _value(b)
        if math.isnan(x) or math.isnan(y):
            ok = math.isnan(x) and math.isnan(y)
        elif kind == "time":
            ok = y > 0 and x / 5 <= y <= 5 * x
        else:
            ok = abs(x - y) <= 0.02 * max(abs(x), abs(y)) + 0.05
        if not ok:
            found.append(f"shown {a}, printed {b}")
    return found


def test_the_readme_check_can_fail():
    assert disagreements("x4 in 16.4 s: 0.1665 +- 0.0010", "x4 in 21.0 s: 0.1653 +- 0.0011") == []
    assert disagreements("full x4", "diagonal x4")
    assert disagreements("x4", "x8")
    assert disagreements("in 87 s", "in 16 s")
    assert disagreements("log Z = -31.31", "log Z = -30.2")


@pytest.mark.slow
def test_readme_examples_print_what_the_readme_shows():
    examples = readme_examples((ROOT / "README.md").read_text())
    assert sum(shown is not None for _, shown in examples) >= 3, "the README shows the output of its examples"
    run = subprocess.run(
        [sys.executable, "-c", RUNNER], input=json.dumps([code for code, _ in examples]), capture_output=True,
        text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    outputs = json.loads(run.stdout.strip().splitlines()[-1])
    problems = [
        f"example {i + 1}: {problem}"
        for i, ((_, shown), printed) in enumerate(zip(examples, outputs, strict=True))
        if shown is not None
        for problem in disagreements(shown, printed)
    ]
    assert not problems, "\n".join(problems)
