"""adaptfilt.course.notebook_markdown: the notebook -> mdBook Markdown converter (maths, cells, outputs, links),
on the fixture notebooks of tests/fixtures/book-notebooks (``*.ipynb.json``: nbval never collects them)."""
import html
import json
import re
from pathlib import Path

import pytest

from adaptfilt.course.notebook_markdown import escape_math, notebook_to_markdown, rewrite_links, rewrite_math

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "tests" / "fixtures" / "book-notebooks"


def fixture_nb(name: str = "01-fixture") -> dict:
    return json.loads((FIXTURES / f"{name}.ipynb.json").read_text(encoding="utf-8"))


# ---------------------------------------------------------------- maths


def test_inline_math_is_delimited_and_escaped():
    assert rewrite_math("mean $x_{k|k-1}$ here") == r"mean \\(x\_\{k\|k\-1\}\\) here"


def test_display_math_doubles_tex_newlines():
    # `\\` (TeX line break) must reach MathJax as `\\`: in Markdown it is `\\\\`.
    assert rewrite_math("$$a \\\\ b$$") == r"\\[a \\\\ b\\]"


def test_thin_space_star_and_underscore_survive_commonmark():
    assert rewrite_math(r"$a\,b*c_1$") == r"\\(a\\\,b\*c\_1\\)"


def test_escape_math_escapes_all_punctuation_only():
    assert escape_math(r"\alpha + 2") == r"\\alpha \+ 2"


def test_escaped_dollar_stays_text():
    assert rewrite_math(r"costs \$5 or \$6") == r"costs \$5 or \$6"


def test_amounts_are_not_maths():
    assert rewrite_math("between $5 and $10") == "between $5 and $10"


def test_unclosed_dollar_stays_text():
    assert rewrite_math("a $x and more") == "a $x and more"


def test_code_spans_are_untouched():
    text = "run `echo $HOME` or ``a `$x$` b`` then $y$"
    assert rewrite_math(text) == "run `echo $HOME` or ``a `$x$` b`` then \\\\(y\\\\)"


def test_fenced_code_is_untouched():
    text = "```bash\necho $x$ $$y$$\n```\n~~~~\n$z$\n~~~~\nafter $w$\n"
    assert rewrite_math(text) == "```bash\necho $x$ $$y$$\n```\n~~~~\n$z$\n~~~~\nafter \\\\(w\\\\)\n"


def test_equation_environment_is_emitted_bare():
    # \[ \begin{align} \] is an error in MathJax 2: the environment must stand alone.
    assert rewrite_math(r"$$\begin{align}a&=b\end{align}$$") == r"\\begin\{align\}a\&\=b\\end\{align\}"


def test_aligned_stays_inside_display_maths():
    assert rewrite_math(r"$$\begin{aligned}a\end{aligned}$$").startswith(r"\\[\\begin\{aligned\}")


def test_bare_environment_is_escaped():
    assert rewrite_math("\\begin{equation}x_1\\end{equation}") == r"\\begin\{equation\}x\_1\\end\{equation\}"


def test_inline_maths_does_not_cross_paragraphs():
    assert rewrite_math("a $x\n\ny$ b") == "a $x\n\ny$ b"


# ---------------------------------------------------------------- notebooks


@pytest.fixture(scope="module")
def converted() -> tuple[str, dict[str, bytes]]:
    return notebook_to_markdown(fixture_nb(), "figures/fx", {"02-second.ipynb": "02-second.md"})


def test_cell_tags_are_honoured(converted):
    md, _ = converted
    assert "VISIBLE-OUTPUT-MARKER" in md  # remove-input keeps the output
    assert "HIDDEN-INPUT-MARKER" not in md
    assert "VISIBLE-INPUT-MARKER" in md  # remove-output keeps the input
    assert "HIDDEN-OUTPUT-MARKER" not in md
    assert "HIDDEN-CELL-MARKER" not in md  # remove-cell drops both


def test_nbval_markers_are_dropped(converted):
    md, _ = converted
    assert "NBVAL" not in md
    assert "import matplotlib.pyplot as plt" in md


def test_figures_are_extracted_and_referenced(converted):
    md, files = converted
    pngs = [n for n in files if n.endswith(".png")]
    svgs = [n for n in files if n.endswith(".svg")]
    assert len(pngs) == 1 and len(svgs) == 1
    assert files[pngs[0]].startswith(b"\x89PNG\r\n\x1a\n")
    assert files[svgs[0]].lstrip().startswith(b"<svg")
    for name in files:
        assert f"]({name})" in md
    assert "base64" not in md and "iVBOR" not in md


def test_widget_dropped_text_fallback_kept(converted):
    md, _ = converted
    assert "widget-view" not in md and "model_id" not in md
    assert "3/3" in md


def test_html_output_is_one_html_block(converted):
    md, _ = converted
    block = re.search(r'<div class="nb-output nb-html">\n(.*?)\n</div>', md, flags=re.S)
    assert block and "<table" in block.group(1)
    assert "\n\n" not in block.group(0)  # a blank line would end the HTML block


def test_text_outputs_are_fenced_and_ansi_free(converted):
    md, _ = converted
    assert "```text\nhello from stdout\n```" in md
    assert "ZeroDivisionError: division by zero" in md and "\x1b" not in md


def test_links_to_notebooks_point_at_chapters(converted):
    md, _ = converted
    assert "](02-second.md)" in md
    assert rewrite_links("[x](../notebooks/03-a.ipynb#s) [y](https://e.org/03-a.ipynb)",
                         {"notebooks/03-a.ipynb": "03-a.md"}) == "[x](03-a.md#s) [y](https://e.org/03-a.ipynb)"


def test_stream_progress_keeps_last_state():
    nb = {"cells": [{"cell_type": "code", "source": "x", "metadata": {}, "outputs": [
        {"output_type": "stream", "name": "stderr", "text": "\r 10%|#\r100%|##########|\n"}]}]}
    md, _ = notebook_to_markdown(nb, "f")
    assert "100%|##########|" in md and "10%|#\n" not in md


def test_fence_is_longer_than_backticks_inside():
    nb = {"cells": [{"cell_type": "code", "source": "s = '```'", "metadata": {}, "outputs": []}]}
    md, _ = notebook_to_markdown(nb, "f")
    assert md.startswith("````python\n")
