"""Every decimal number the course's prose states is one its code printed (adaptfilt.course.prose_numbers),
and so is every integer that states a result: a percentage, a time, a count of runs, seeds or episodes
(a count must be one the code sets or prints *as a count of the same thing*).

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


#: Chapters whose integers the check does not yet pass: notebooks 01-06 belong to the helper rewriting
#: them, who adds the declarations; strict, so the mark goes when they pass.
INTEGERS_PENDING: set[str] = set()


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.xfail(
    strict=True, reason="the helper who owns notebooks 01-06 declares or prints their counts"))
    if p.name[:2] in INTEGERS_PENDING else p for p in NOTEBOOKS], ids=lambda p: p.stem)
def test_every_integer_result_in_the_prose_is_one_the_chapter_set_or_printed(path):
    bad = unmatched(CHAPTERS[path.name[:2]], chapters=CHAPTERS, integers=True)
    assert not bad, f"{path.name}: counts, percentages or times in the prose that no output or setting shows " \
                    "(fix the prose, print the value, or declare it):\n" + "\n".join(map(str, bad))


def test_the_integer_check_catches_a_count_of_runs_no_output_states():
    """A review's finding: chapter 16 said "500 runs" where its study stored 250, while 500 was printed as a
    grid value and a particle count: a count is matched only by a count of the same thing."""
    out = {"cell_type": "code", "source": "print(protocol)", "outputs": [{"output_type": "stream", "text":
           "ungm-pf-1e-4: evaluated on 250 runs; 8 learned seeds\n| bpf-500 | 0.647 | 500 | 3.60% |\n"
           "(7 of 8 seeds below alone)\n"}]}
    nb = {"cells": [out, {"cell_type": "markdown", "source":
                          "The study measures both forms at every count on 500 runs, seven seeds of eight."}]}
    assert [m.number for m in unmatched(nb, integers=True)] == ["500"]
    nb["cells"][1]["source"] = "Evaluated on the same 250 runs, 8 seeds, 4 % <!-- quoted: 4 -->, in 12 s."
    assert [m.number for m in unmatched(nb, integers=True)] == ["12"]
    nb["cells"][1]["source"] = "In 95 % of resamples (a two-level 95 % CI), $M = 250$ runs."
    assert [m.number for m in unmatched(nb, integers=True)] == ["95"]


def test_the_readme_states_only_numbers_the_chapters_printed():
    readme = {"cells": [{"cell_type": "markdown", "source": (ROOT / "README.md").read_text(encoding="utf-8")}]}
    # the README prints nothing: every number it states must be declared as taken from a chapter (or quoted)
    bad = unmatched(readme, printed=[], chapters=CHAPTERS) + unmatched(readme, printed=[], chapters=CHAPTERS,
                                                                       integers=True)
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
    nb["cells"][0]["source"] = "*Figure 13.2: the gain*, as Figures 8.1 and 8.2 show, and 0.0462."
    assert unmatched(nb, printed=printed) == []
