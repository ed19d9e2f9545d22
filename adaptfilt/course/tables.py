"""Tables a page can show whole: :func:`fit` splits a Markdown table wider than ``max_columns`` into
several tables of at most that many columns, each repeating the columns that name a row (the course's rule: a
chapter's tables have at most 7 columns, so that a student finds the comparison the text discusses).

Nothing is dropped: every cell of the wide table is in one of the narrower ones, in its row and under its
header, so the numbers the prose quotes are still printed.

>>> print(fit("| a | b | c | d |\\n|---|---|---|---|\\n| x | 1 | 2 | 3 |", max_columns=3, key=1))
| a | b | c |
|---|---|---|
| x | 1 | 2 |
<BLANKLINE>
| a | d |
|---|---|
| x | 3 |
"""
from __future__ import annotations

__all__ = ["fit", "key_columns", "MAX_COLUMNS", "ROW_NAMES"]

MAX_COLUMNS = 7
#: Headers of columns that name a row rather than hold a value: a table's leading columns with these
#: headers (after its first, which always names the row) are its key, repeated in every part of a split.
ROW_NAMES = ("experiment", "claim", "comparison", "metric", "policy", "group", "variant", "filter")


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _is_rule(line: str) -> bool:
    return set(line.replace("|", "").replace(":", "").strip()) <= {"-"} and "-" in line


def key_columns(header: list[str], max_columns: int = MAX_COLUMNS) -> int:
    """How many leading columns of a table with ``header`` name its rows: the first, and every column
    after it whose header is one of :data:`ROW_NAMES` ("claim | experiment | comparison | metric | ..."
    has four), at most ``max_columns - 1`` so that every part keeps a column of values.

    >>> key_columns(["claim", "experiment", "comparison", "metric", "a - b", "verdict"])
    4
    >>> key_columns(["experiment", "policy", "cost", "RMSE"])
    2
    """
    k = 1
    while k < len(header) and header[k].strip().lower() in ROW_NAMES:
        k += 1
    return min(k, max_columns - 1)


def fit(markdown: str, max_columns: int = MAX_COLUMNS, key: int | None = None) -> str:
    """``markdown`` with every table wider than ``max_columns`` split into narrower tables that repeat
    its first ``key`` columns in every part (default: :func:`key_columns`, the columns that name a
    row), so that each part can be read on its own."""
    lines = markdown.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        if lines[i].lstrip().startswith("|") and i + 1 < len(lines) and _is_rule(lines[i + 1]):
            j = i + 2
            while j < len(lines) and lines[j].lstrip().startswith("|"):
                j += 1
            header, rows = _cells(lines[i]), [_cells(line) for line in lines[i + 2:j]]
            if len(header) <= max_columns:
                out.extend(lines[i:j])
            else:
                k = key if key is not None else key_columns(header, max_columns)
                rest = list(range(k, len(header)))
                width = max_columns - k
                parts = [rest[s:s + width] for s in range(0, len(rest), width)]
                for n, part in enumerate(parts):
                    cols = list(range(k)) + part
                    if n:
                        out.append("")
                    out.append(_row([header[c] for c in cols]))
                    out.append("|" + "---|" * len(cols))
                    out.extend(_row([r[c] if c < len(r) else "" for c in cols]) for r in rows)
            i = j
        else:
            out.append(lines[i])
            i += 1
    return "\n".join(out)
