"""adaptfilt.course.figure_text: a figure's alt text is its titles, read from the code, never matplotlib's repr."""
import json
import re
import time
from pathlib import Path

from adaptfilt.course.book import notebook_chapters
from adaptfilt.course.figure_text import figure_titles, plain_text
from adaptfilt.course.notebook_markdown import notebook_to_markdown

ROOT = Path(__file__).resolve().parent.parent


# ---------------------------------------------------------------- figure alt text

_PNG = "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNkYPhfDwAChwGA60e6kgAAAABJRU5ErkJggg=="


def _figure_nb(source: str, before: str = "Some text.", n_figures: int = 1, plain: str = "<Figure size 700x360 with 1 Axes>") -> dict:
    out = {"output_type": "display_data", "metadata": {}, "data": {"image/png": _PNG, "text/plain": plain}}
    return {"cells": [{"cell_type": "markdown", "metadata": {}, "source": before},
                      {"cell_type": "code", "metadata": {}, "source": source, "outputs": [out] * n_figures}]}


def _alts(md: str) -> list[str]:
    # the alt text as CommonMark renders it: every backslash escape undone
    return [re.sub(r"\\(.)", r"\1", a) for a in re.findall(r"!\[((?:\\.|[^\]\\])*)\]\(", md)]


def test_figure_alt_text_is_the_figures_titles_not_matplotlibs_repr():
    source = ("%matplotlib inline\nfig, axes = style.figure(1, 2, title=\"UNGM, M = 1000\")\n"
              "axes[0].set_title(r\"RMSE$_k$ for $\\kappa = 2$\")\naxes[1].set(xlabel=\"k\", title=f\"{n} runs [x]\")\n"
              "fig.suptitle('Fig. 1: *time* <averaged>')")
    md, _ = notebook_to_markdown(_figure_nb(source), "f")
    assert "Figure size" not in md
    assert _alts(md) == ["Figure: UNGM, M = 1000; RMSE_k for \u03ba = 2; \u2026 runs [x]; Fig. 1: *time* <averaged>"]


def test_figure_titles_are_read_from_the_code_in_source_order():
    src = "plt.title('a')\nax.set(title='b', ylabel='y')\nhelper(x, title=r'$\\gamma$ c')\nfig.suptitle(label)\nbroken("
    assert figure_titles(src) == []  # does not parse: no titles
    assert figure_titles(src[: src.rindex("\n")]) == ["a", "b", "\u03b3 c"]  # a variable's value is not known
    assert plain_text(r"$\bar L_\mathrm{NIS}$ and $x\sim\mathcal{N}(0, 1)$, `code`") == "L_NIS and x~N(0, 1), code"


def test_figure_without_a_title_is_described_by_the_text_before_it():
    before = "## A section\n\nFirst paragraph.\n\nThe sweep shows RMSE against $\\kappa$, e.g. at 2. More follows."
    md, _ = notebook_to_markdown(_figure_nb("plot(x)", before), "f")
    assert _alts(md) == ["Figure after the text: The sweep shows RMSE against \u03ba, e.g. at 2."]
    md, _ = notebook_to_markdown(_figure_nb("plot(x)", "## Only a heading"), "f")
    assert _alts(md) == ["figure"]  # nothing to describe it with, and the repr is no description
    md, _ = notebook_to_markdown(_figure_nb("plot(x)", "## Only a heading", plain="A map of the course"), "f")
    assert _alts(md) == ["A map of the course"]  # a real text/plain is kept


def test_several_figures_of_one_cell_get_one_title_each():
    md, _ = notebook_to_markdown(_figure_nb("f1.suptitle('one')\nf2.suptitle('two')", n_figures=2), "f")
    assert _alts(md) == ["Figure: one", "Figure: two"]
    md, _ = notebook_to_markdown(_figure_nb("f1.suptitle('only')", n_figures=2), "f")
    assert _alts(md) == ["Figure: only", "Figure: only"]


def test_no_figure_of_the_course_has_matplotlibs_repr_as_alt_text():
    for path in notebook_chapters(ROOT):
        md, files = notebook_to_markdown(json.loads(path.read_text(encoding="utf-8")), "f")
        alts = _alts(md)
        assert len(alts) >= len([n for n in files if n.endswith((".png", ".svg", ".jpg"))]), path.name
        assert not [a for a in alts if "Figure size" in a or a == "figure"], (path.name, alts)
