"""The course book's bibliography: every chapter's ``## References`` section (:func:`notebook_references`),
each entry split into its citation and the chapter's remark on it (:func:`split_reference`), and one page of
the works, deduplicated by first author and title, with the chapters that cite each
(:func:`bibliography_markdown`). Built by :mod:`adaptfilt.course.book`; unit-tested in ``tests/test_bibliography.py``.
"""
from __future__ import annotations

import re
import unicodedata
from collections import Counter
from typing import Any, Mapping, Sequence

from adaptfilt.course.notebook_markdown import text_of

__all__ = ["notebook_references", "split_reference", "bibliography_markdown"]

def notebook_references(nb: Mapping[str, Any]) -> list[str]:
    """The entries of a notebook's ``## References`` section(s), each as one line of Markdown.

    The section runs from its heading to the next heading of level 1 or 2 (or the notebook's end), over
    Markdown cells; an entry is a list item (``*``, ``-`` or ``+``) with its continuation lines.
    """
    entries: list[str] = []
    inside = False
    for cell in nb.get("cells", []):
        if cell.get("cell_type") != "markdown":
            continue
        for line in text_of(cell.get("source", "")).splitlines():
            heading = re.match(r"^(#{1,6})\s+(.*?)\s*#*\s*$", line)
            if heading and len(heading.group(1)) <= 2:
                inside = heading.group(2).strip().lower() in ("references", "reference", "bibliography")
                continue
            if not inside:
                continue
            item = re.match(r"^[*+-]\s+(.*)$", line)
            if item:
                entries.append(item.group(1).strip())
            elif line.strip() and entries and line[:1].isspace():
                entries[-1] += " " + line.strip()
    return [" ".join(e.split()) for e in entries]


def split_reference(entry: str) -> tuple[str, str]:
    """``(citation, note)``: a reference entry without and with its trailing remark.

    The remark is a final parenthesis that holds no year (``(the ML choice of $\\kappa$)``) or the text
    after a colon that follows the citation's year. ``(2nd ed. 2018)`` is part of the citation.

    >>> split_reference('R. Bellman, *Dynamic Programming*, Princeton University Press, 1957 (the recursion).')
    ('R. Bellman, *Dynamic Programming*, Princeton University Press, 1957', 'the recursion')
    >>> split_reference('A. B, "T", MIT Press, 1998 (2nd ed. 2018): value functions.')
    ('A. B, "T", MIT Press, 1998 (2nd ed. 2018)', 'value functions')
    """
    text = entry.strip().rstrip(".").strip()
    if text.endswith(")"):
        depth, i = 0, len(text) - 1
        while i >= 0:
            depth += {")": 1, "(": -1}.get(text[i], 0)
            if depth == 0:
                break
            i -= 1
        inner = text[i + 1 : -1]
        if i > 0 and not re.search(r"\b(1[89]|20)\d\d\b", inner):
            return text[:i].rstrip(" ,"), inner.strip()
    m = re.search(r"\b(1[89]|20)\d\d\b(\s*\([^()]*\))?:\s+(.+)$", text)
    if m:
        return text[: m.start(3)].rstrip(": "), m.group(3).strip()
    return text, ""


def _fold(text: str) -> str:
    """Lower case ASCII letters and digits only (Å -> a), for keys and sorting."""
    ascii_ = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode()
    return re.sub(r"[^a-z0-9]+", " ", ascii_.lower()).strip()


def _reference_key(citation: str) -> tuple[str, str]:
    """(first author's surname, title): the same work cited with other details, ``et al.`` or a
    different year format is one entry."""
    m = re.search(r'"([^"]+)"|\*([^*]+)\*', citation)
    if not m:
        return ("", _fold(citation))
    authors = citation[: m.start()]
    first = re.split(r",| and ", authors.replace(" et al.", ""))[0].strip()
    surname = first.split()[-1] if first.split() else ""
    return (_fold(surname), _fold(m.group(1) or m.group(2)))


def bibliography_markdown(chapters: Sequence[tuple[str, str, Sequence[str]]], title: str = "Bibliography") -> str:
    """The book's bibliography: every chapter's references, deduplicated, sorted by first author.

    ``chapters`` holds ``(chapter file, chapter label, entries)`` (entries as :func:`notebook_references`
    returns them). A work cited in several chapters appears once, in its most frequent form (the longest
    of equally frequent ones), followed by the chapters that cite it, each linked, with that chapter's
    remark (:func:`split_reference`). The result is Markdown in the notebooks' syntax (``$..$`` maths).
    """
    works: dict[tuple[str, str], dict[str, Any]] = {}
    for filename, label, entries in chapters:
        for entry in entries:
            citation, note = split_reference(entry)
            work = works.setdefault(_reference_key(citation), {"forms": Counter(), "cited": []})
            work["forms"][citation] += 1
            cited = f"[{label}]({filename})" + (f" ({note})" if note else "")
            if cited not in work["cited"]:
                work["cited"].append(cited)
    lines = [f"# {title}", "",
             f"Every work the chapters cite in their References sections, {len(works)} in all, once each and sorted",
             "by first author, with the chapters that cite it and what for. This page is generated from the",
             "notebooks when the book is built.", ""]
    for key in sorted(works, key=lambda k: (k[0] or k[1], k[1])):
        forms = works[key]["forms"]
        citation = max(forms, key=lambda c: (forms[c], len(c)))
        lines.append(f"* {citation}. Cited in " + "; ".join(works[key]["cited"]) + ".")
    return "\n".join(lines) + "\n"
