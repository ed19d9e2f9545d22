"""Chapters 1-7: every figure has a numbered caption ("*Figure 3.2: ...*") in the Markdown cell right
after it and its own alt text (cell metadata ``alt``), which the book uses instead of a placeholder;
no code line is longer than 88 characters (the course's rule)."""
import json
import re
from pathlib import Path

import pytest

from adaptfilt.course.notebook_markdown import notebook_to_markdown

ROOT = Path(__file__).resolve().parents[1]
FIRST = sorted(p for p in (ROOT / "notebooks").glob("0[1-7]-*.ipynb"))
_PNG = "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNkYPhfDwAChwGA60e6kgAAAABJRU5ErkJggg=="


def _figures(nb):
    for i, c in enumerate(nb["cells"]):
        if c["cell_type"] == "code":
            n = sum(1 for o in c.get("outputs", []) if "image/png" in o.get("data", {}))
            if n:
                yield i, c, n


def test_a_cells_alt_metadata_is_the_figures_alt_text():
    cell = {"cell_type": "code", "source": "ax.set_title('t')", "metadata": {"alt": "A curve that falls"},
            "outputs": [{"output_type": "display_data", "data": {"image/png": _PNG, "text/plain": "<Figure>"}}]}
    md, _ = notebook_to_markdown({"cells": [cell]}, "x")
    assert "![A curve that falls]" in md
    del cell["metadata"]["alt"]
    md, _ = notebook_to_markdown({"cells": [cell]}, "x")
    assert "![Figure\\: t]" in md   # the book escapes the colon


@pytest.mark.parametrize("path", FIRST, ids=lambda p: p.stem)
def test_every_figure_has_a_numbered_caption_and_alt_text(path):
    nb = json.loads(path.read_text(encoding="utf-8"))
    chapter = int(path.name[:2])
    seen = []
    for i, c, n in _figures(nb):
        nxt = nb["cells"][i + 1] if i + 1 < len(nb["cells"]) else {"cell_type": "", "source": ""}
        src = "".join(nxt["source"]) if nxt["cell_type"] == "markdown" else ""
        m = re.match(r"\s*\*Figure (\d+)\.(\d+):\s+\S", src)
        assert m, f"{path.name} cell {i}: no '*Figure {chapter}.N: ...*' caption right after the figure"
        assert int(m.group(1)) == chapter
        seen.append(int(m.group(2)))
        alt = c.get("metadata", {}).get("alt")
        assert alt and "Figure after the text" not in str(alt) and "\u2026" not in str(alt), \
            f"{path.name} cell {i}: no alt text of its own"
    assert seen == list(range(1, len(seen) + 1)), f"{path.name}: figures numbered {seen}"


@pytest.mark.parametrize("path", FIRST, ids=lambda p: p.stem)
def test_code_lines_fit_the_book(path):
    nb = json.loads(path.read_text(encoding="utf-8"))
    long = [(i, line) for i, c in enumerate(nb["cells"]) if c["cell_type"] == "code"
            for line in "".join(c["source"]).splitlines() if len(line) > 88]
    assert not long, f"{path.name}: code lines over 88 characters: {long[:3]}"
