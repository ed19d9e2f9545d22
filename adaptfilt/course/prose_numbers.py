r"""Keep the numbers a chapter's prose states equal to the numbers its code printed.

nbval compares the outputs of a few marked cells with a fresh run; a number
*quoted in the prose* ("adaptive minus greedy, -0.046 [-0.051, -0.040]")
is not an output and would drift silently when a result changes. This module
finds every decimal number in the prose of an executed notebook and looks for
it among the numbers the notebook printed (text, tables, figure-free outputs):

* a prose number written with ``d`` decimals matches a printed number with
  ``d`` to ``d + 2`` decimals that rounds to it (a table's 0.0302 is the
  prose's 0.030; a printed 0.123456 is no witness for a prose 0.1). Signs
  are compared as magnitudes: the prose says "0.030 lower" as often as "-0.030";
* ``5.6 %`` also matches a printed fraction ``0.0563``;
* an integer enters when it states a result or a sample size: a percentage
  (``56 %``), a count of runs, seeds, episodes or trajectories (``250 runs``,
  ``7 of 8 seeds``, ``seven seeds of eight``, ``$M = 2000$ runs``) or a time
  (``78 s``, ``3 minutes``); it matches a printed integer, or a printed
  decimal that rounds to it. Other integers (equation, chapter and section
  numbers, grid values, settings) are not results and do not enter;
* ``9.69\times10^6`` in the prose is the number 9.69e6 (printed as ``9.69e+06``
  or ``9690000.0``);
* a number the prose takes from another chapter is declared in the cell, where
  a reader of the source sees it, and checked against *that* chapter's outputs:
  ``<!-- from 08: 0.046 0.051 0.040 -->``;
* a number from outside the course's outputs (the paper, a parameter of the
  setup, arithmetic in the text) is declared as such:
  ``<!-- quoted: 5.63 6.866 -->``.

:func:`unmatched` returns what the prose states and the outputs do not show;
``tests/test_prose_numbers.py`` runs it over the chapters and the README.

Example
-------
>>> nb = {"cells": [
...     {"cell_type": "code", "source": "", "outputs": [{"output_type": "stream", "text": "gain -0.0302\n"}]},
...     {"cell_type": "markdown", "source": "The gain is $-0.030$, not 0.05."}]}
>>> [(m.number, m.cell) for m in unmatched(nb)]
[('0.05', 1)]
"""
from __future__ import annotations

import html
import re
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

__all__ = ["Mismatch", "output_numbers", "output_text", "prose_numbers", "matches", "unmatched", "borrowed",
           "cell_text", "counted"]

# A decimal number: optional sign (ASCII or Unicode minus), digits, a point, digits; or scientific.
_NUMBER = re.compile(r"(?<![\w.:/])[-−+]?(\d+\.\d+(?:[eE][-+]?\d+)?|\d+[eE][-+]?\d+)(?![\w.]*\d)(?![A-Za-z])")
# LaTeX's scientific notation in the prose: 9.69\times10^6, 5.516 \times 10^{11}
_TIMES_TEN = re.compile(r"^\s*\\times\s*10\^\{?([-−]?\d+)\}?")
_PERCENT_AFTER = re.compile(r"^\s*(\\?%|\\,\\%|\s*per\s*cent)")
_QUOTED = re.compile(r"<!--\s*quoted:\s*([^>]*?)\s*-->")
_FROM = re.compile(r"<!--\s*from\s+(\d\d):\s*([^>]*?)\s*-->")
_CODE_SPAN = re.compile(r"```.*?```|`[^`\n]*`", re.S)
_SLACK = 2  # a printed number may carry this many more decimals than the prose that rounds it
_TAG = re.compile(r"<[^>]+>")
_URL = re.compile(r"\]\([^)]*\)|https?://\S+")
# An integer printed by the code (a count, a size): digits not part of a decimal or a word.
_INTEGER = re.compile(r"(?<![\w.])[-−+]?(\d+)(?![\w.]*\d)(?![A-Za-z])(?!\.\d)")
_WORDS = {w: str(i) for i, w in enumerate(
    "zero one two three four five six seven eight nine ten eleven twelve".split()) if i > 1}
_WORD = "(?:" + "|".join(_WORDS) + ")"
# What makes an integer of the prose a result: the unit after it (one qualifying word may stand between,
# "250 evaluation runs", and a closing ``$`` of maths, "$M = 2000$ runs").
_NOT_QUALIFIER = r"(?!(?:for|of|in|per|at|on|to|and|or|with|from|by|a|an|the|than|more|fewer)\s)"
_UNIT = (rf"(?:\s*\$)?\s*(?:{_NOT_QUALIFIER}[A-Za-z-]+\s+)?(?:runs|seeds|episodes|trajectories|CPU-s|CPU-minutes?|"
         r"CPU-hours?|s|sec|seconds?|min|minutes?|hours?|h)(?![\w-])")
_COUNT = re.compile(rf"(?<![\w.,\\^_{{-])(\d+|{_WORD})(?:\s+(?:of|out of)\s+(?:the\s+|its\s+)?(\d+|{_WORD}))?(?={_UNIT})",
                    re.I)
# "seven seeds of eight", "in 7 runs of 250": the total after the unit
_OF_TOTAL = re.compile(rf"^\s*(?:[A-Za-z-]+\s+)?seeds\s+of\s+(?:the\s+)?(\d+|{_WORD})\b", re.I)
_PERCENT_INT = re.compile(r"(?<![\w.,\\^_{-])(\d+)(?=\s*(?:\\?%|\\,\\%|per\s*cent))"
                          r"(?!\s*(?:\\?%|\\,\\%|per\s*cent)\s*(?:CI|confidence|interval|level))")
_UNIT_WORD = re.compile(rf"(?:\s*\$)?\s*(?:{_NOT_QUALIFIER}[A-Za-z-]+\s+(?=\w+(?![\w-])\s*(?:$|\W)))?([A-Za-z-]+)")
_NAMES = {"n_runs": "run", "m": "run", "runs": "run", "n_seeds": "seed", "seeds": "seed", "episodes": "episode",
          "n_episodes": "episode", "n_mc": "episode"}
_NAMED_COUNT = re.compile(r"(?<![\w])(--episodes|--runs|n_runs|M|runs|n_seeds|n_episodes|episodes|N_MC)\s*[=:]?\s*(\d+)\b")
# "Figure 13.2", "Figures 8.1 and 8.2", "Table 10.1": numbered captions and references are not results
_NUMBERED = re.compile(r"\b(?:Figures?|Fig\.|Tables?)\s+\d+\.\d+(?:\s*(?:,|and|to|-|–)\s*\d+\.\d+)*")
_TIME_DECLARED = re.compile(r"<!--\s*times?\b[^>]*-->")
# A verdict declaration (adaptfilt.course.verdict_words): its numbers are the interval the prose states beside it,
# checked there, and a reference value that sets the margin.
_VERDICT = re.compile(r"<!--\s*verdict:.*?-->", re.S)


@dataclass(frozen=True)
class Mismatch:
    """A number stated in the prose of cell ``cell`` that no output of the notebook shows."""

    number: str
    cell: int
    context: str

    def __str__(self) -> str:
        return f"cell {self.cell}: {self.number!r} in '...{self.context}...'"


def cell_text(cell: Mapping[str, Any]) -> str:
    src = cell.get("source", "")
    return "".join(src) if isinstance(src, list) else src


def output_text(cell: Mapping[str, Any]) -> str:
    """What a code cell printed: its text, plain, Markdown, HTML (tags stripped) and LaTeX outputs."""
    parts = []
    for out in cell.get("outputs", []):
        if "text" in out:
            parts.append(cell_text({"source": out["text"]}))
        data = out.get("data", {})
        for mime in ("text/plain", "text/markdown", "text/html", "text/latex"):
            if mime in data:
                text = cell_text({"source": data[mime]})
                parts.append(html.unescape(_TAG.sub(" ", text)) if mime == "text/html" else text)
    return "\n".join(parts)


def _decimals(token: str) -> int:
    if token.isdigit():
        return 0
    mant = token.lower().split("e")[0]
    exp = int(token.lower().split("e")[1]) if "e" in token.lower() else 0
    d = len(mant.split(".")[1]) if "." in mant else 0
    return d - exp  # negative for 9.69e6 (resolution 10^4)


def _ranges_apart(text: str) -> str:
    """``2.50..4.07`` (a range as some helpers print it) as two numbers."""
    return re.sub(r"(?<=\d)\.\.(?=[-−+]?\d)", " .. ", text)


def output_numbers(cells: Iterable[Mapping[str, Any]]) -> list[tuple[float, int]]:
    """Every decimal number printed by the code cells: (magnitude, decimals printed)."""
    found = set()
    for cell in cells:
        if cell.get("cell_type") == "code":
            text = _ranges_apart(output_text(cell))
            for m in _NUMBER.finditer(text):
                found.add((abs(float(m.group(1))), _decimals(m.group(1))))
            for m in _INTEGER.finditer(text):
                found.add((float(m.group(1)), 0))
    return sorted(found)


def prose_numbers(markdown: str, integers: bool = False) -> list[tuple[str, bool, str]]:
    """The decimal numbers a Markdown cell states: (as written, followed by a percent sign, context).

    Code spans, links and the ``quoted``, ``from``, ``time`` and ``verdict`` declarations are left out; maths is prose
    here. With ``integers``, the integers that state a result (a percentage, a count of runs, seeds or
    episodes, a time) too, number words ("seven seeds") as digits.
    """
    text = _VERDICT.sub(" ", _TIME_DECLARED.sub(" ", _FROM.sub(" ", _QUOTED.sub(" ", markdown))))
    text = _NUMBERED.sub(lambda m: " " * len(m.group()), text)
    text = _CODE_SPAN.sub(lambda m: " " * len(m.group()), text)
    text = _URL.sub(lambda m: " " * len(m.group()), text)
    text = _ranges_apart(text)
    out = []
    for m in _NUMBER.finditer(text):
        after = text[m.end():m.end() + 24]
        pct = bool(_PERCENT_AFTER.match(after))
        ctx = text[max(0, m.start() - 40):m.end() + 20].replace("\n", " ")
        number = m.group(1)
        power = _TIMES_TEN.match(after)
        if power:
            number = f"{number}e{power.group(1).replace('−', '-')}"
        out.append((number, pct, ctx))
    if integers:
        out.extend((n, kind == "pct", ctx) for n, kind, ctx in _prose_integers(text))
    return out


def _unit_kind(unit: str) -> str:
    unit = unit.lower()
    for kind in ("run", "seed", "episode"):
        if unit.startswith(kind):
            return kind
    return "run" if unit.startswith("traject") else "time"


def _prose_integers(text: str) -> list[tuple[str, str, str]]:
    """(integer, kind, context): kind "pct", "time", or the unit counted ("run", "seed", "episode")."""
    out = []
    for m in _COUNT.finditer(text):
        ctx = text[max(0, m.start() - 40):m.end() + 30].replace("\n", " ")
        unit = _UNIT_WORD.match(text[m.end():]).group(1)
        groups = [m.group(1), m.group(2)]
        total = _OF_TOTAL.match(text[m.end():])
        if total:
            groups.append(total.group(1))
        for g in groups:
            if g:
                out.append((_WORDS.get(g.lower(), g), _unit_kind(unit), ctx))
    for m in _PERCENT_INT.finditer(text):
        out.append((m.group(1), "pct", text[max(0, m.start() - 40):m.end() + 20].replace("\n", " ")))
    return out


def counted(cells: Iterable[Mapping[str, Any]]) -> dict[str, set[int]]:
    """The counts a chapter's code sets or prints, by what they count: an integer before "runs", "seeds",
    "episodes" (``250 runs``, ``7 of 8 seeds``) in an output or in the code, or after a name that counts
    (``n_runs=250``, ``M = 250``, ``--episodes 500``, ``seeds alone: 7 confirmed, 1 contradicted``)."""
    found: dict[str, set[int]] = {"run": set(), "seed": set(), "episode": set()}
    for cell in cells:
        if cell.get("cell_type") != "code":
            continue
        for text in (output_text(cell), cell_text(cell)):
            for m in _COUNT.finditer(text):
                kind = _unit_kind(_UNIT_WORD.match(text[m.end():]).group(1))
                if kind in found:
                    for g in (m.group(1), m.group(2)):
                        if g:
                            found[kind].add(int(_WORDS.get(g.lower(), g)))
            for m in _NAMED_COUNT.finditer(text):
                found[_NAMES[m.group(1).lower().lstrip("-")]].add(int(m.group(2)))
            for m in re.finditer(r"(?<![\w.])(\d+)\s*/\s*(\d{3,})(?![\w.])", text):  # "13 / 2000" runs
                found["run"].update((int(m.group(1)), int(m.group(2))))
            for m in re.finditer(r"seeds alone:([^)]*)", text):
                found["seed"].update(int(x) for x in re.findall(r"\d+", m.group(1)))
    return found


def matches(number: str, percent: bool, printed: Sequence[tuple[float, int]]) -> bool:
    """Whether the prose ``number`` (``percent``: it is followed by %) rounds from a printed one."""
    d = _decimals(number)
    want = _rounded(abs(float(number)), d)
    for value, decimals in printed:
        if d <= decimals <= d + _SLACK and _rounded(value, d) == want:
            return True
        if percent and d <= decimals - 2 <= d + _SLACK and _rounded(100 * value, d) == want:
            return True
    return False


def _rounded(value: float, d: int) -> str:
    """``value`` to ``d`` decimals (``d`` < 0: to a multiple of 10^-d), as the prose would write it."""
    return f"{value:.{d}f}" if d >= 0 else f"{round(value / 10.0 ** -d):d}"


def _quoted(markdown: str) -> set[str]:
    return {tok for m in _QUOTED.finditer(markdown) for tok in m.group(1).replace(",", " ").split()}


def borrowed(markdown: str) -> dict[str, list[str]]:
    """The ``<!-- from NN: ... -->`` declarations of a cell: chapter number -> numbers."""
    out: dict[str, list[str]] = {}
    for m in _FROM.finditer(markdown):
        out.setdefault(m.group(1), []).extend(m.group(2).replace(",", " ").split())
    return out


def unmatched(nb: Mapping[str, Any], cells: Iterable[int] | None = None,
              printed: Sequence[tuple[float, int]] | None = None,
              chapters: Mapping[str, Mapping[str, Any]] | None = None,
              integers: bool = False) -> list[Mismatch]:
    """The prose numbers of ``nb`` (Markdown cells ``cells``, default all) that no output shows.

    With ``integers``, the integers that state results instead of the decimals: a percentage or a time
    matches a printed number; a count of runs, seeds or episodes matches a count of the same thing the
    code sets or prints (:func:`counted`), so that "500 runs" is not witnessed by a grid value 500; a
    number just before a ``<!-- time: ... -->`` declaration is checked by ``tests/test_quoted_times.py``.

    ``printed`` overrides the notebook's own outputs (the README is checked against the course's);
    ``chapters`` maps a chapter number (``"08"``) to its executed notebook, for the numbers a cell
    declares it takes from there (a declaration naming a chapter not given is itself a mismatch).
    """
    all_cells = nb["cells"]
    counts = counted(all_cells) if printed is None else {}
    printed = output_numbers(all_cells) if printed is None else printed
    wanted = range(len(all_cells)) if cells is None else cells
    bad = []
    for i in wanted:
        cell = all_cells[i]
        if cell.get("cell_type") != "markdown":
            continue
        src = cell_text(cell)
        allowed = _quoted(src)
        for chapter, numbers in borrowed(src).items():
            other = (chapters or {}).get(chapter)
            theirs = output_numbers(other["cells"]) if other is not None else []
            for number in numbers:
                if other is None or not matches(number.lstrip("-−+"), False, theirs):
                    bad.append(Mismatch(number, i, f"declared as from chapter {chapter}, not among its outputs"))
                allowed.add(number)
        if not integers:
            for number, pct, ctx in prose_numbers(src):
                if number in allowed or number.lstrip("-−+") in allowed:
                    continue
                if not matches(number, pct, printed):
                    bad.append(Mismatch(number, i, ctx.strip()))
            continue
        for m in _TIME_DECLARED.finditer(src):
            allowed.update(re.findall(r"\d+", src[max(0, m.start() - 30):m.start()]))
        text = _NUMBERED.sub(" ", _VERDICT.sub(" ", _TIME_DECLARED.sub(" ", _FROM.sub(" ", _QUOTED.sub(" ", src)))))
        text = _URL.sub(lambda m: " " * len(m.group()), _CODE_SPAN.sub(lambda m: " " * len(m.group()), text))
        for number, kind, ctx in _prose_integers(text):
            if number in allowed:
                continue
            if kind in ("pct", "time"):
                ok = matches(number, kind == "pct", printed)
            else:
                ok = int(number) in counts.get(kind, set())
            if not ok:
                bad.append(Mismatch(number, i, ctx.strip()))
    return bad
