r"""Keep every verdict word the course states equal to the word the one rule gives for its interval.

:mod:`adaptfilt.course.prose_numbers` keeps a number in the prose equal to a printed one; a verdict word
("equal", "tied", "not worse", "better", "confirmed", "contradicted", "not confirmed") could still drift
from its interval: the same interval was once "equal with the margin" in one chapter and "not a claim of
equality" in another. This check holds the words to :func:`adaptfilt.verdicts.verdict`, explicitly:

* **A verdict sentence declares its verdict** in an HTML comment, as the prose declares a quoted number:
  ``<!-- verdict: lower [-0.051, -0.040] -> confirmed -->``, or with a margin that
  :data:`adaptfilt.verdicts.DECLARED_MARGINS` declares, named with its metric and the reference value it
  is a fraction of: ``<!-- verdict: equal [-0.241, -0.152] margin "adaptive vs best fixed" rmse 3.072 ->
  not confirmed -->``. The check applies the rule to the declared interval and margin and compares the
  word; the interval must be one the sentence (or, where the sentence names none, its cell) states, or its
  mirror (a difference stated as a magnitude: "lower by 0.030 [0.017, 0.045]"); the
  reference value must be one the prose or the outputs state; the sentence must say the word (``confirmed``,
  or the claim itself: "lower", "not worse", "equal"; for
  "contradicted" also "higher", "worse"; for "not confirmed" also "not shown", "no detectable
  difference"); and an equivalence word ("equal", "tied") that the sentence affirms needs a declared
  "equal ... -> confirmed", which needs a declared margin. ``<!-- verdict: none -->`` marks a sentence
  that names verdict words but judges no interval (a definition, a history).
* **The scan**: a sentence with a verdict word and an interval ``[lo, hi]``, or with an unquoted "equal"
  or "tied" and the word "margin", must carry a declaration.
* **Printed verdicts** are checked too: a line ``margin 0.144: not worse -> confirmed; equal -> ...`` (the
  interval on the line or the lines before it), a line that prints an interval followed by a verdict word
  (a "lower" claim unless the line names another), and a table row "a <claim> than/to b | ... [lo, hi] |
  ... | word (margin m) |".

The check cannot tell whether a declaration's comparison is the one its sentence is about (a margin
borrowed from another comparison passes the rule); the declaration puts the name where a reviewer reads
it. A passage the code generates from the rule (the report's tables embedded in ``REPRODUCTION.md`` between
``<!-- BEGIN ... -->`` and ``<!-- END ... -->``) is not prose; tests hold it to its generator.

:func:`problems` returns what disagrees; ``tests/test_verdict_words.py`` runs it over the chapters,
``REPRODUCTION.md`` and the README, and on fixtures with the sentences the third course read found.

>>> nb = {"cells": [{"cell_type": "markdown", "source":
...     "The groups are equal in RMSE ($-0.0006$ $[-0.049, +0.056]$) with chapter 5's margin."}]}
>>> [p.why for p in problems(nb)]
['a verdict word near an interval, without a <!-- verdict: ... --> declaration']
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

from adaptfilt.course.prose_numbers import output_text, cell_text
from adaptfilt.verdicts import CLAIMS, WORDS, judge, verdict

__all__ = ["Problem", "Declaration", "declarations", "sentences", "problems", "document_problems",
           "output_problems"]

_NUM = r"[-−+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?:\s*\\times\s*10\^\{?[-−]?\d+\}?)?|[-−+]?\\?infty|[-−+]?inf"
# An interval as the course writes it: [lo, hi], in maths or not ($[-0.049, +0.056]$, [-0.049, +0.056])
_INTERVAL = re.compile(rf"\[\s*\$?\s*({_NUM})\s*\$?\s*,\s*\$?\s*({_NUM})\s*\$?\s*\]")
_TERM = re.compile(r"\b(?:equal|tied|ties|tie|not worse|better|confirmed|contradicted|not confirmed)\b", re.I)
_EQUIV = re.compile(r"(?<![\"'*“‘])\b(?:equal|tied|ties)\b(?![\"'*”’])", re.I)
# not a verdict: "at equal price", "equal to the library's", "equal weights", "tied to"
_EQUIV_NOT = re.compile(r"\bat\s+equal\b|\bequal(?:ly)?\s+(?:to\s+(?:the\s+)?(?:library|one|that\s+of|its)|weights?|"
                        r"counts?|prices?|budgets?|footing|numbers?|share|spacing|parts?)\b|\btied\s+to\b|"
                        r"\bnot\s+(?:a\s+)?(?:claim\s+of\s+)?equal|\bno\s+(?:claim\s+of\s+)?equal", re.I)
_DECL = re.compile(r"<!--\s*verdict:\s*(.*?)\s*-->", re.S)
_DECL_BODY = re.compile(
    rf"^(lower|not worse|equal)\s*\[\s*({_NUM})\s*,\s*({_NUM})\s*\]"
    rf"(?:\s*margin\s+\"([^\"]+)\"\s+(\w+)\s+({_NUM}))?\s*->\s*(confirmed|contradicted|not confirmed)$")
_COMMENT = re.compile(r"<!--.*?-->", re.S)
_CODE = re.compile(r"```.*?```|`[^`\n]*`", re.S)
_GENERATED = re.compile(r"<!--\s*BEGIN\s[^>]*-->.*?<!--\s*END\s[^>]*-->", re.S)
# where one sentence ends: a full stop or question mark and a capital after it, a blank line,
# a list item, a table row
_SPLIT = re.compile(r"(?<=[.!?])\s+(?=[A-Z*($\[\"“])|\n(?=\s*(?:[*-]|\d+\.)\s)")
#: What a sentence may say for each verdict of each claim (besides the word itself).
SAYS = {
    ("lower", "confirmed"): r"\b(?:lower|better|below|beats?|more accurate|more consistent|cheaper|gain)\b",
    ("not worse", "confirmed"): r"\bnot worse\b",
    ("equal", "confirmed"): r"\b(?:equal|tied|the same)\b",
    ("lower", "contradicted"): r"\b(?:higher|worse|above|dearer|not lower|less accurate|less consistent|fails?)\b",
    ("not worse", "contradicted"): r"\b(?:worse|above|fails?)\b",
    ("equal", "contradicted"): r"\b(?:differ\w*|not equal|above|below|fails?)\b",
}
_NOT_CONFIRMED = r"\b(?:not confirmed|not shown|no detectable difference|not separable|cannot tell|n\.s\.|" \
                 r"does not confirm|not distinguishable)\b"


@dataclass(frozen=True)
class Problem:
    """A verdict word that disagrees with the rule, or that the check cannot tie to an interval."""

    where: str
    why: str
    text: str

    def __str__(self) -> str:
        return f"{self.where}: {self.why}: '{self.text[:220]}'"


@dataclass(frozen=True)
class Declaration:
    """One ``<!-- verdict: ... -->``: the claim, the interval, the declared margin (comparison, metric,
    reference value) if any, and the word the prose states."""

    claim: str
    lo: float
    hi: float
    comparison: str | None
    metric: str | None
    reference: float | None
    word: str

    def rule(self) -> str:
        """The word the rule gives (raises ``ValueError`` where no margin is declared)."""
        return judge(self.claim, (self.lo, self.hi), self.comparison, self.metric, self.reference)[0]


def _number(text: str) -> float:
    t = text.replace("−", "-").replace(" ", "").replace("\\infty", "inf")
    m = re.match(r"^([-+]?[\d.]+(?:[eE][-+]?\d+)?)\\times10\^\{?([-]?\d+)\}?$", t)
    return float(m.group(1)) * 10.0 ** int(m.group(2)) if m else float(t)


def _same(a: str, b: float) -> bool:
    """Whether the written number ``a`` is ``b`` to the digits ``a`` shows."""
    x = _number(a)
    if math.isinf(x) or math.isinf(b):
        return x == b
    digits = len(a.split(".")[1].split("e")[0].split("E")[0].split("\\")[0]) if "." in a else 0
    return abs(x - b) <= 0.5 * 10.0 ** -digits * (1 + 1e-9) or abs(x - b) <= 1e-12 * max(1.0, abs(b))


def _witnessed(value: float, text: str) -> bool:
    """Whether ``text`` (a cell's prose and the outputs, declarations left out) states ``value`` as a decimal."""
    plain = _DECL.sub(" ", text)
    return any(_same(m.group(0), value) for m in re.finditer(r"(?<![\w.])\d+\.\d+(?:[eE][-+]?\d+)?", plain))


def declarations(text: str) -> list[Declaration | str]:
    """The ``<!-- verdict: ... -->`` declarations of ``text``: a :class:`Declaration`, ``"none"``, or the
    body of one the check cannot read (a string)."""
    out: list[Declaration | str] = []
    for m in _DECL.finditer(text):
        body = " ".join(m.group(1).split())
        if body == "none":
            out.append("none")
            continue
        d = _DECL_BODY.match(body)
        if d is None:
            out.append(body)
            continue
        claim, lo, hi, comparison, metric, ref, word = d.groups()
        out.append(Declaration(claim, _number(lo), _number(hi), comparison, metric,
                               None if ref is None else _number(ref), word))
    return out


def sentences(markdown: str) -> list[str]:
    """The sentences of Markdown (list items and table rows count as sentences), code and generated passages
    left out; a declaration stays with the sentence it ends (a comment after the full stop is moved in)."""
    text = _CODE.sub(" ", _GENERATED.sub(" ", markdown))
    text = re.sub(r"([.!?;])(\s*)(<!--\s*verdict:.*?-->)", r" \3\1\2", text, flags=re.S)
    out, prose = [], []
    for line in text.split("\n") + [""]:
        if line.lstrip().startswith("|"):  # a table row is one unit, whatever its cells hold
            out.append(line)
            line = ""
        if line.strip():
            prose.append(line)
            continue
        out += [s for s in _SPLIT.split("\n".join(prose)) if s.strip()]
        prose = []
    return [s for s in out if s.strip()]


def _affirms_equivalence(sentence: str) -> bool:
    prose = _COMMENT.sub(" ", sentence)
    prose = _EQUIV_NOT.sub(" ", prose)
    return bool(_EQUIV.search(prose))


def _says(claim: str, word: str, prose: str) -> bool:
    """Whether ``prose`` states ``word`` for ``claim`` (module docstring)."""
    plain = re.sub(r"not confirmed", " ", prose)
    if word == "not confirmed":
        return bool(re.search(_NOT_CONFIRMED, prose, re.I))
    if re.search(rf"\b{word}\b", plain, re.I):
        return True
    return bool(re.search(SAYS[(claim, word)], plain, re.I))


def _sentence_problems(sentence: str, cell: str, where: str, outputs: str = "") -> list[Problem]:
    decls = declarations(sentence)
    prose = " ".join(_COMMENT.sub(" ", sentence).split())
    intervals = [(a, b) for a, b in _INTERVAL.findall(prose)]
    out = []
    if not decls:
        if _TERM.search(_EQUIV_NOT.sub(" ", prose)) and (intervals or (_affirms_equivalence(sentence) and "margin" in prose)):
            why = ("a verdict word near an interval" if intervals else "an equivalence word beside a margin") + \
                  ", without a <!-- verdict: ... --> declaration"
            out.append(Problem(where, why, prose))
        return out
    if "none" in decls:
        return out
    for d in decls:
        if isinstance(d, str):
            out.append(Problem(where, f"cannot read the declaration {d!r} (want: CLAIM [lo, hi] "
                                      "[margin \"COMPARISON\" METRIC REFERENCE] -> WORD)", prose))
            continue
        try:
            rule = d.rule()
        except ValueError as e:
            out.append(Problem(where, f"no verdict for '{d.claim}' on [{d.lo:g}, {d.hi:g}]: {e}", prose))
            continue
        if rule != d.word:
            out.append(Problem(where, f"the rule gives '{rule}' for '{d.claim}' on [{d.lo:g}, {d.hi:g}]"
                                      + (f" with the margin of {d.comparison!r}" if d.comparison else "")
                                      + f", not '{d.word}'", prose))
        here = intervals or _INTERVAL.findall(" ".join(_COMMENT.sub(" ", cell).split()))
        stated = lambda ivs: any(_same(a, d.lo) and _same(b, d.hi) or _same(a, -d.hi) and _same(b, -d.lo)  # noqa: E731
                                 for a, b in ivs)  # "lower by 0.030 [0.017, 0.045]" states [-0.045, -0.017]
        if not stated(here) and not stated(_INTERVAL.findall(outputs)):
            out.append(Problem(where, f"the declared interval [{d.lo:g}, {d.hi:g}] is not one the prose or the "
                                      "outputs state", prose))
        if d.reference is not None and not _witnessed(d.reference, cell + "\n" + outputs):
            out.append(Problem(where, f"the declared reference value {d.reference:g} (b's value, which sets the "
                                      "margin) is not one the prose or the outputs state", prose))
        if not _says(d.claim, d.word, prose):
            out.append(Problem(where, f"the sentence does not say '{d.word}' for '{d.claim}'", prose))
    if _affirms_equivalence(sentence) and not any(
            isinstance(d, Declaration) and d.claim == "equal" and d.word == "confirmed" for d in decls):
        out.append(Problem(where, "an equivalence word ('equal', 'tied') without a declared 'equal ... -> "
                                  "confirmed' (which needs a declared margin)", prose))
    return out


def document_problems(markdown: str, where: str = "", outputs: str = "") -> list[Problem]:
    """The problems of one Markdown text (a cell, ``REPRODUCTION.md``): every sentence checked (module
    docstring); ``outputs``: printed text whose intervals a declaration may name."""
    return [p for s in sentences(markdown) for p in _sentence_problems(s, markdown, where, outputs)]


# ------------------------------------------------------------------ printed verdicts
_MARGIN_CLAIMS = re.compile(rf"margin\s+({_NUM}):\s*((?:(?:lower|not worse|equal)\s*->\s*(?:{'|'.join(WORDS)})"
                            rf"(?:\s*\([^)]*\))?\s*;?\s*)+)")
_CLAIM_ARROW = re.compile(rf"(lower|not worse|equal)\s*->\s*({'|'.join(sorted(WORDS, key=len, reverse=True))})")
_AFTER_INTERVAL = re.compile(rf"^\]?\s*[:,;]?\s*(?:->\s*)?\**\s*({'|'.join(sorted(WORDS, key=len, reverse=True))})\b")
_ROW_CLAIM = re.compile(r"\b(lower|not worse|equal)\s+(?:than|to)\b")
_ROW_WORD = re.compile(rf"\|\s*\**\s*({'|'.join(sorted(WORDS, key=len, reverse=True))})\s*(?:\((?!margin)[^)]*\)\s*)?"
                       rf"(?:\(margin\s+({_NUM})\))?\s*\**\s*(?=\|)")
_LINE_CLAIM = re.compile(r"'[^']*\b(lower|not worse|equal)'")


def _digits(text: str) -> int:
    t = text.replace("−", "-")
    return len(t.split(".")[1].split("e")[0]) if "." in t else 0


def _agrees(claim: str, lo: str, hi: str, margin: str | float | None, word: str) -> tuple[bool, str]:
    """Whether the printed ``word`` is the rule's for the printed interval and margin; printed numbers are
    rounded, so an end within half a unit of its last digit of a margin may fall either way."""
    m = None if margin is None else (margin if isinstance(margin, float) else _number(margin))
    if m is not None and m == 0 and claim == "equal":
        return False, "an 'equal' verdict with margin 0 (no margin: no equality verdict)"
    if m is None and claim != "lower":
        return False, f"a '{claim}' verdict printed without its margin"
    x, y = _number(lo), _number(hi)
    ex = 0.5 * 10.0 ** -_digits(lo) if math.isfinite(x) else 0.0
    ey = 0.5 * 10.0 ** -_digits(hi) if math.isfinite(y) else 0.0
    seen = {verdict(claim, (x + a, y + b), m) for a in (-ex, 0.0, ex) for b in (-ey, 0.0, ey) if x + a <= y + b}
    rule = verdict(claim, (x, y), m)
    return word in seen, f"the rule gives '{rule}' for '{claim}' on [{lo}, {hi}]" + \
        ("" if m is None else f" with margin {m:g}") + f", printed '{word}'"


def output_problems(text: str, where: str = "") -> list[Problem]:
    """The printed verdicts of one output ``text`` that disagree with the rule (module docstring)."""
    out = []
    last: tuple[str, str] | None = None
    for line in text.splitlines():
        ivs = list(_INTERVAL.finditer(line))
        mm = _MARGIN_CLAIMS.search(line)
        if mm and (ivs or last):
            lo, hi = (ivs[-1].group(1), ivs[-1].group(2)) if ivs else last
            for claim, word in _CLAIM_ARROW.findall(mm.group(2)):
                ok, why = _agrees(claim, lo, hi, mm.group(1), word)
                if not ok:
                    out.append(Problem(where, why, line.strip()))
        elif line.lstrip().startswith("|") and _ROW_CLAIM.search(line) and ivs:
            w = _ROW_WORD.search(line[ivs[0].end():])
            if w:
                ok, why = _agrees(_ROW_CLAIM.search(line).group(1), ivs[0].group(1), ivs[0].group(2), w.group(2),
                                  w.group(1))
                if not ok:
                    out.append(Problem(where, why, line.strip()))
        else:
            for iv in ivs:
                w = _AFTER_INTERVAL.match(line[iv.end() - 1:])
                if w is None:
                    continue
                named = _LINE_CLAIM.search(line[:iv.start()])
                claim = named.group(1) if named else "lower"
                if claim != "lower":
                    continue  # a margin the line does not print: judged where the margin is printed
                ok, why = _agrees(claim, iv.group(1), iv.group(2), None, w.group(1))
                if not ok:
                    out.append(Problem(where, why, line.strip()))
        if ivs:
            last = (ivs[-1].group(1), ivs[-1].group(2))
    return out


def problems(nb: Mapping[str, Any], cells: Iterable[int] | None = None) -> list[Problem]:
    """Every verdict of notebook ``nb`` (Markdown cells ``cells``, default all, and every output) that
    disagrees with the rule or is not tied to an interval (module docstring)."""
    all_cells = nb["cells"]
    outputs = "\n".join(output_text(c) for c in all_cells if c.get("cell_type") == "code")
    wanted = range(len(all_cells)) if cells is None else cells
    out = []
    for i in wanted:
        c = all_cells[i]
        if c.get("cell_type") == "markdown":
            out += document_problems(cell_text(c), f"cell {i}", outputs)
        elif c.get("cell_type") == "code":
            out += output_problems(output_text(c), f"cell {i} (output)")
    return out


assert set(CLAIMS) == {c for c, _ in SAYS}  # every claim has its phrases
