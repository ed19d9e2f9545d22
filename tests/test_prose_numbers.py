"""Every decimal number the course's prose states is one its code printed (adaptfilt.course.prose_numbers).

The chapters are checked whole (every Markdown cell, the Summaries and the verdict paragraphs
included); a number taken from another chapter is declared (``<!-- from 08: ... -->``) and checked
against that chapter's outputs; the README's results are checked against the chapters they come from.
"""
from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import pytest

from adaptfilt.course.prose_numbers import cell_text, matches, output_numbers, prose_numbers, unmatched

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("[0-9][0-9]-*.ipynb"))
CHAPTERS = {p.name[:2]: json.loads(p.read_text(encoding="utf-8")) for p in NOTEBOOKS}


def _summary_cells(nb: dict) -> list[int]:
    return [i for i, c in enumerate(nb["cells"])
            if c["cell_type"] == "markdown" and re.search(r"^## Summary", cell_text(c), re.M)]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_every_number_in_the_prose_is_one_the_chapter_printed(path):
    bad = unmatched(CHAPTERS[path.name[:2]], chapters=CHAPTERS)
    assert not bad, f"{path.name}: numbers in the prose that no output shows (fix the prose, print the value, " \
                    "or declare where it comes from):\n" + "\n".join(map(str, bad))


def test_the_readme_states_only_numbers_the_chapters_printed():
    readme = {"cells": [{"cell_type": "markdown", "source": (ROOT / "README.md").read_text(encoding="utf-8")}]}
    # the README prints nothing: every number it states must be declared as taken from a chapter (or quoted)
    bad = unmatched(readme, printed=[], chapters=CHAPTERS)
    assert not bad, "README.md:\n" + "\n".join(map(str, bad))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_a_changed_number_in_the_summary_is_caught(path):
    """Change each result the Summary states by a few units in its last digit: the check reports it.

    A number printed with few digits among many similar ones (``gamma = 0.5``) has every neighbour
    printed somewhere, so no change of it can be seen; at most one in ten (or one) may be so blind."""
    nb = CHAPTERS[path.name[:2]]
    printed = output_numbers(nb["cells"])
    cells = _summary_cells(nb)
    assert cells, f"{path.name}: no Summary"
    numbers = [(n, pct) for n, pct, _ in prose_numbers(cell_text(nb["cells"][cells[0]])) if "e" not in n]
    blind = []
    for number, pct in numbers:
        d = len(number.split(".")[1])
        wrong = next((f"{float(number) + k * 10 ** -d:.{d}f}" for k in range(1, 10)
                      if not matches(f"{float(number) + k * 10 ** -d:.{d}f}", pct, printed)), None)
        if wrong is None:
            blind.append(number)
            continue
        changed = copy.deepcopy(nb)
        src = cell_text(changed["cells"][cells[0]])
        changed["cells"][cells[0]]["source"] = re.sub(rf"(?<![\d.]){re.escape(number)}(?![\d])", wrong, src, count=1)
        assert any(m.number == wrong for m in unmatched(changed, cells, chapters=CHAPTERS)), (path.name, number, wrong)
    assert len(blind) <= max(1, len(numbers) // 10), f"{path.name}: the check cannot see a change of {blind}"


def test_the_check_reads_declarations_against_the_named_chapter():
    out = {"cell_type": "code", "source": "", "outputs": [{"output_type": "stream", "text": "gain -0.0462 [-0.0513]\n"}]}
    other = {"cells": [out]}
    nb = {"cells": [{"cell_type": "markdown", "source": "Chapter 8 found $-0.046$ <!-- from 08: 0.046 -->."}]}
    assert unmatched(nb, chapters={"08": other}) == []
    assert [m.number for m in unmatched(nb, chapters={"09": other})] == ["0.046"]  # declared from a chapter not given
    nb["cells"][0]["source"] = "Chapter 8 found $-0.047$ <!-- from 08: 0.047 -->."
    assert [m.number for m in unmatched(nb, chapters={"08": other})] == ["0.047"]
    nb["cells"][0]["source"] = "The paper reports 5.63 <!-- quoted: 5.63 -->, and we 0.0462 and 4.6 %."
    assert [m.number for m in unmatched(nb, printed=output_numbers([out]))] == []
    nb["cells"][0]["source"] = "RMSE $9.69\\times10^6$ m and `kappa=0.5` (code, not a result) and 0.07."
    printed = [(9.6912e6, -2), (0.0462, 4)]
    ranged = {"cell_type": "code", "source": "", "outputs": [{"output_type": "stream", "text": "RMSE 2.50..4.07\n"}]}
    assert (2.5, 2) in output_numbers([ranged]) and (4.07, 2) in output_numbers([ranged])
    assert [m.number for m in unmatched(nb, printed=printed)] == ["0.07"]
