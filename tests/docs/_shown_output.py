"""Run the ```python blocks of a Markdown page and compare what they print with what it shows.

The blocks run in order and in one namespace (later blocks use earlier names), in a fresh
process with JAX's defaults (float32), as a reader would run them. A ```text block right
after a ```python block is that block's output: the words must be the same and the numbers
within 2% + 0.05 (wall times, `<number> s`, within a factor of five; progress bars left
out). A block preceded by `<!-- docs-test: skip, <reason> -->` is not run (a fragment, or
a run of minutes); the page states why.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FENCE = re.compile(r"```(\w+)\n(.*?)```", re.S)
SKIP = re.compile(r"<!--\s*docs-test:\s*skip,\s*[^>]*\S\s*-->\s*$")
NUMBER = r"[-+]?(?:\b(?:nan|inf)\b|(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:e[-+]?\d+)?)"
PROGRESS_BAR = "\u2501"
TOKEN = re.compile(rf"(?P<time>{NUMBER})(?= ?s\b)|(?P<number>{NUMBER})")

RUNNER = """
import contextlib, io, json, sys
namespace, outputs = {}, []
name, codes = json.loads(sys.stdin.read())
for code in codes:
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(code, name, "exec"), namespace)
    outputs.append(printed.getvalue())
print(json.dumps(outputs))
"""


def examples(text: str) -> list[tuple[str, str | None]]:
    """Each python block that is not marked skipped, with the text block that follows it (its shown output), if any."""
    fences = list(FENCE.finditer(text))
    found = []
    for i, fence in enumerate(fences):
        if fence.group(1) != "python" or SKIP.search(text[fences[i - 1].end() if i else 0 : fence.start()]):
            continue
        after = fences[i + 1] if i + 1 < len(fences) else None
        shown = None
        if after is not None and after.group(1) == "text" and not text[fence.end() : after.start()].strip():
            shown = after.group(2)
        found.append((textwrap.dedent(fence.group(2)), shown and textwrap.dedent(shown)))
    return found


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
        if math.isnan(x) or math.isnan(y) or math.isinf(x) or math.isinf(y):
            ok = (math.isnan(x) and math.isnan(y)) or x == y
        elif kind == "time":
            ok = y > 0 and x / 5 <= y <= 5 * x
        else:
            ok = abs(x - y) <= 0.02 * max(abs(x), abs(y)) + 0.05
        if not ok:
            found.append(f"shown {a}, printed {b}")
    return found


def page_problems(page: Path, timeout: float = 600) -> tuple[int, list[str]]:
    """Run the page's blocks; the number of shown outputs, and every disagreement with them."""
    blocks = examples(page.read_text())
    run = subprocess.run(
        [sys.executable, "-c", RUNNER], input=json.dumps([page.name, [code for code, _ in blocks]]),
        capture_output=True, text=True, cwd=ROOT, timeout=timeout,
    )  # fmt: skip
    if run.returncode != 0:
        return 0, [f"{page.name} raised:\n{run.stderr[-3000:]}"]
    outputs = json.loads(run.stdout.strip().splitlines()[-1])
    problems = [
        f"{page.name}, block {i + 1}: {problem}"
        for i, ((_, shown), printed) in enumerate(zip(blocks, outputs, strict=True))
        if shown is not None
        for problem in disagreements(shown, printed)
    ]
    return sum(shown is not None for _, shown in blocks), problems
