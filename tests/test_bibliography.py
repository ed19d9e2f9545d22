"""adaptfilt.course.bibliography: each chapter's references, merged into the book's bibliography."""
import json
from pathlib import Path

from adaptfilt.course.book import collect_chapters, notebook_chapters
from adaptfilt.course.bibliography import bibliography_markdown, notebook_references, split_reference

ROOT = Path(__file__).resolve().parent.parent


# ---------------------------------------------------------------- bibliography


def test_references_are_read_from_the_references_section_only():
    nb = {"cells": [
        {"cell_type": "markdown", "source": "# T\n\n* not a reference\n\n## References\n\n* A. Author, \"One\",\n  *J.* 1, 2001.\n"},
        {"cell_type": "code", "source": "* code", "outputs": []},
        {"cell_type": "markdown", "source": "- B. Writer, *Two*, 1999 (why).\n\n## Appendix\n\n* not one either"}]}
    assert notebook_references(nb) == ['A. Author, "One", *J.* 1, 2001.', "B. Writer, *Two*, 1999 (why)."]
    assert split_reference("B. Writer, *Two*, 1999 (why).") == ("B. Writer, *Two*, 1999", "why")
    assert split_reference("C. D, *Three*, MIT Press, 1998 (2nd ed. 2018).") == ("C. D, *Three*, MIT Press, 1998 (2nd ed. 2018)", "")
    assert split_reference('E. F, "Four", 2018: what for.') == ('E. F, "Four", 2018', "what for")


def test_bibliography_merges_a_work_cited_twice_and_links_the_chapters():
    chapters = [
        ("01-a.md", "chapter 1", ['Z. Zed and Y. Why, "Last", *J.* 1, 2001 (the $\\kappa$ rule).', "A. Ay et al., *First*, 1990."]),
        ("02-b.md", "chapter 2", ['Z. Zed and Y. Why, "Last", *J.* 1, 2001.', "A. Ay, B. Bee and C. Cee, *First*, 1990 (again)."]),
        ("03-c.md", "chapter 3", []),
    ]
    md = bibliography_markdown(chapters)
    items = [ln for ln in md.splitlines() if ln.startswith("* ")]
    assert items == [
        "* A. Ay, B. Bee and C. Cee, *First*, 1990. Cited in [chapter 1](01-a.md); [chapter 2](02-b.md) (again).",
        '* Z. Zed and Y. Why, "Last", *J.* 1, 2001. Cited in [chapter 1](01-a.md) (the $\\kappa$ rule); [chapter 2](02-b.md).',
    ]
    assert md.startswith("# Bibliography") and "2 in all" in md


def test_the_books_bibliography_holds_every_chapters_references_once():
    chapters = collect_chapters(ROOT)
    bib = next(c for c in chapters if c.filename == "bibliography.md")
    items = [ln for ln in bib.markdown.splitlines() if ln.startswith("* ")]
    cited = {p.stem: notebook_references(json.loads(p.read_text(encoding="utf-8"))) for p in notebook_chapters(ROOT)}
    assert all(cited.values()), [s for s, r in cited.items() if not r]  # every chapter has references
    assert 0 < len(items) < sum(len(r) for r in cited.values())  # duplicates merged
    for stem in cited:  # every chapter is linked from the page
        assert f"]({stem}.md)" in bib.markdown, stem
    assert sum("Straka" in i and "Learning Adaptive Parameter Policies" in i for i in items) == 1  # the paper, once
