r"""Keep the wall and CPU times the documents quote equal to the files that recorded them.

``README.md``, ``REPRODUCTION.md`` and ``docs/RUNNING.md`` say how long things take ("the full
retrain took 78 minutes"). Such a figure is a copy of a measurement, and it goes stale silently when the
pipeline is re-run. This module finds every *time figure* in a Markdown document and checks each one
against the record it declares (or against a declaration that it is not a measurement of the current
records); ``tests/test_quoted_times.py`` runs it over the three documents.

What counts as a time figure
----------------------------
* a number or a range (with a dash) followed by a time unit: ``4692 s``, ``10.4 min``, ``24 CPU-s``, ``11-20
  CPU-minutes``, ``2 h``, ``34 ms``, ``a 15-minute check`` (units: ms, µs, s, sec, seconds, min,
  minutes, h, hours, each also as ``CPU-...``). ``8 seeds``, ``5e8 particle-steps``, ``s0``, ``10^4 s``
  and a rate such as ``18.4e6 per CPU-second`` (no number before the unit) are not figures, nor is the
  first number of "from 2727 to 1675 s";
* a number in words before a unit: ``a minute``, ``half an hour``, ``three to four minutes`` (``a
  second`` is left out: it is usually the ordinal);
* a number in a table column whose header names a time unit (``wall (s)``, ``CPU (s)``, ``train wall /
  CPU s``, ``where the time goes (job time, s)``); numbers inside parentheses in such a cell are not;
* in fenced code blocks only the comments (after ``#``) are read: code is an example, its comment a claim.

Inline code spans, links, HTML comments and the generated part of ``REPRODUCTION.md`` (between the
``BEGIN report-tables`` / ``END report-tables`` markers, written by ``adaptfilt reproduce`` from the
records themselves) are not read.

Declarations
------------
Each figure carries one HTML comment (invisible in the rendered page):

``<!-- time: [AGG] FIELD of PATH[:KEY] -->``
    the figure is a record. It binds to the nearest time figure before it in the same block (a block is
    a run of non-blank lines; a fenced code block with the lines just above its fence is one block);
    ``<!-- time N: ... -->`` binds to the figure(s) written ``N`` in the block instead (for a figure in
    a code block, where a comment cannot follow it). ``FIELD`` is ``wall`` or ``cpu`` (``wall_time_s``,
    ``cpu_time_s``). ``PATH`` is relative to the repository root:

    * a ``timings.json`` of ``adaptfilt reproduce`` (``data/timings.json``, ``data/medium/timings.json``):
      ``KEY`` is a stage (``train``, ``evaluate``, ``floor+reconcile``, ``report``, ``total``) or a
      glob over its per-job records (``policies/ungm-ukf-adaptive-s*.npz``);
    * a ``manifest.json`` (``data/manifest.json``, ``data/beyond/manifest.json``): ``KEY`` is a glob over
      the files' paths;
    * ``KEY`` may list several, separated by commas (``sum cpu of data/timings.json:evaluate,floor+reconcile``);
    * executed notebooks (``notebooks/04-*.ipynb``, a glob, no ``KEY``): a notebook's wall time is the
      sum over its code cells of ``shell.execute_reply - iopub.execute_input`` (``metadata.execution``).

    ``AGG`` (``mean``, ``min``, ``max``, ``sum``, ``range``) combines the records a glob selects; without it
    the glob must select one. Records without a time (``null``) or with 0 (a job the run reused or
    shared) are left out. ``range`` gives (min, max), for a figure written as a range.

``<!-- times from COMMIT: N N ... (what measured them) -->``
    the figures of the block written ``N`` are historical: measured at git commit ``COMMIT`` (a benchmark
    run, an earlier pipeline run) and not in any current record. The test checks that the commit exists.

``<!-- times not measured: N N ... (why) -->``
    the figures written ``N`` are not measurements of this project: the paper's, a target, a setting.

These two are the allow-list. They sit beside the figures they exempt (a comment line just above a table
or a code fence belongs to it), name each figure and give a reason, so a reader of the source sees why a
number is not checked, and a new figure in the same block is not exempted by accident.

Units are converted by the figure: a record is in seconds, and a figure written in minutes is compared in
minutes (``78 minutes`` against 4692 s). The rounding rule: the figure must equal the record rounded at
the figure's last significant digit, which is its last written digit, or for an integer that ends in
zeros its last non-zero digit (``4692 s`` and ``78 minutes`` match 4691.7 s; ``80 minutes`` too; ``79
minutes`` does not); a word is its digit (``half an hour`` is 0.5 h). A range's ends are compared with
the records' min and max. A figure after ``under``, ``below``, ``less than``, ``at most``, ``within`` or
``up to`` is a bound: the record must not exceed it (``over``, ``above``, ``more than``, ``at least``:
not fall below it). :func:`fixed` rewrites the digit figures whose records changed (at the same
precision, and the names of the declarations that name them), so a re-measurement updates the documents in
one call::

    python -c "from pathlib import Path; from adaptfilt.course.quoted_times import fixed
    for p in map(Path, ('README.md', 'REPRODUCTION.md', 'docs/RUNNING.md')): p.write_text(fixed(p.read_text(), '.'))"

Words and bounds it leaves to a person, as it does a figure whose rounding no longer suits the new value.

Example
-------
>>> import json, pathlib, tempfile
>>> root = pathlib.Path(tempfile.mkdtemp())
>>> _ = (root / "t.json").write_text(json.dumps({"timings": {"total": {"wall_time_s": 4691.7}}, "jobs": {
...     "p/a-s0.npz": {"wall_time_s": 50.0, "cpu_time_s": 23.0}, "p/a-s1.npz": {"wall_time_s": 52.0, "cpu_time_s": 25.0}}}))
>>> doc = ("The retrain took 78 minutes <!-- time: wall of t.json:total -->, about 24 CPU-s per policy "
...        "<!-- time: mean cpu of t.json:p/a-s*.npz --> and 3 h <!-- time: wall of t.json:total -->; "
...        "the paper's 2 s <!-- times not measured: 2 (the paper's) --> and 9 min are not records.")
>>> [str(p) for p in problems(doc, root)]
["line 1: '3 h' is wall of t.json:total = 4691.7 s, which at this precision is '1 h'", "line 1: '9 min' declares no record"]
>>> fixed(doc, root).count("1 h")
1
"""
from __future__ import annotations

import fnmatch
import json
import re
from dataclasses import dataclass, field
from datetime import datetime
from decimal import ROUND_HALF_UP, Decimal
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable

__all__ = ["Figure", "Declaration", "Problem", "figures", "declarations", "record", "matches", "at_precision",
           "bound_figures", "problems", "fixed", "check_phrase", "commits", "GENERATED"]

#: The generated part of REPRODUCTION.md: written from the records by ``adaptfilt reproduce``, not read here.
GENERATED = ("<!-- BEGIN report-tables -->", "<!-- END report-tables -->")

_SECONDS = {"ms": 1e-3, "µs": 1e-6, "s": 1.0, "min": 60.0, "h": 3600.0}
_UNIT_WORDS = {"ms": "ms", "µs": "µs", "s": "s", "sec": "s", "secs": "s", "second": "s", "seconds": "s",
               "min": "min", "mins": "min", "minute": "min", "minutes": "min",
               "h": "h", "hr": "h", "hrs": "h", "hour": "h", "hours": "h"}
_UNIT = r"(?:CPU[- ])?(ms|µs|secs?|seconds?|s|mins?|minutes?|hrs?|hours?|h)(?![\w-])"
_NUM = r"\d+(?:\.\d+)?"
# a number (or a range) not glued to a word, a power (10^4) or a decimal point before it
_DIGIT_FIGURE = re.compile(rf"(?<![\w.^/,-])({_NUM})(?:\s*[-–]\s*({_NUM}))?(?:\s|-(?=minute|hour|second))?{_UNIT}")
_WORDS = {"a": 1, "an": 1, "one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7,
          "eight": 8, "nine": 9, "ten": 10, "eleven": 11, "twelve": 12, "fifteen": 15, "twenty": 20,
          "thirty": 30, "forty": 40, "fifty": 50, "sixty": 60, "half a": "0.5", "half an": "0.5"}
_WORD = r"half an?|an?|one|two|three|four|five|six|seven|eight|nine|ten|eleven|twelve|fifteen|twenty|thirty|forty|fifty|sixty"
_WORD_FIGURE = re.compile(rf"(?<![\w-])({_WORD})(?:\s+(?:to|or)\s+({_WORD}))?[\s-](?:CPU-)?(seconds?|minutes?|hours?)\b",
                          re.I)
_UPPER = re.compile(r"(?:under|below|less than|at most|within|up to)\s+(?:about\s+)?$", re.I)
_LOWER = re.compile(r"(?:over|above|more than|at least)\s+(?:about\s+)?$", re.I)
_COMMENT = re.compile(r"<!--.*?-->", re.S)
_DECL = re.compile(r"<!--\s*(time|times\s+from|times\s+not\s+measured)\b\s*([^:>]*?)\s*:\s*(.*?)\s*-->", re.S)
_SPEC = re.compile(r"^(?:(mean|min|max|sum|range)\s+)?(wall|cpu)\s+of\s+(\S+?)(?::(\S+))?$")
_CODE_SPAN = re.compile(r"`[^`\n]*`")
_URL = re.compile(r"\]\([^)]*\)|https?://\S+")
_FENCE = re.compile(r"^(```|~~~)")
_TIME_HEADER = re.compile(r"\((?:[^()]*,\s*)?(?:CPU-)?(s|min|h|ms)\)|(?:^|\s)(s|min|h|ms)\s*$")
_CELL_NUMBER = re.compile(rf"(?<![\w.^/,-])({_NUM})(?:\s*(?:-|–)\s*({_NUM}))?(?![\w.%^]|\s*x\b)")


@dataclass
class Figure:
    """A time figure of a document: ``text`` as written (``"78"``, ``"11-20"``, ``"half an"``), its
    ``low`` and ``high`` ends as written (the same for one number), its ``unit`` (``s``, ``min``, ``h``,
    ``ms``, ``µs``), ``bound`` (``""``, ``"upper"`` or ``"lower"``), the ``block`` it is in and where
    (``start``, ``end``: offsets of its number in the document; ``line``)."""

    text: str
    low: str
    high: str
    unit: str
    bound: str
    block: int
    start: int
    end: int
    line: int
    written: str = ""
    words: bool = False
    declared: list["Declaration"] = field(default_factory=list)


@dataclass
class Declaration:
    """A ``<!-- time...: ... -->`` comment: ``kind`` (``record``, ``historical``, ``not measured``), the
    figures it names (empty: the nearest one before it), its ``body`` (a record spec, or the reason)."""

    kind: str
    names: list[str]
    body: str
    block: int
    start: int
    line: int
    commit: str = ""
    names_at: tuple[int, int] = (0, 0)  # where a record declaration's names are written (``fixed`` edits them)


@dataclass(frozen=True)
class Problem:
    """A figure that disagrees with its record or declares none, or a declaration that is wrong."""

    line: int
    message: str

    def __str__(self) -> str:
        return f"line {self.line}: {self.message}"


def _blank(text: str, pattern: re.Pattern) -> str:
    return pattern.sub(lambda m: re.sub(r"[^\n]", " ", m.group()), text)


def _blocks(text: str) -> list[tuple[int, int]]:
    """(start, end) offsets of each block: a run of non-blank lines; a fenced code block (blank lines
    included) is in one run with the lines just above it."""
    out: list[tuple[int, int]] = []
    pos, start, fence = 0, None, None
    for line in text.splitlines(keepends=True):
        stripped = line.strip()
        if fence is not None:
            if stripped.startswith(fence):
                fence = None
        elif _FENCE.match(stripped):
            fence = stripped[:3]
            start = pos if start is None else start
        elif not stripped:
            if start is not None:
                out.append((start, pos))
            start = None
        elif start is None:
            start = pos
        pos += len(line)
    if start is not None:
        out.append((start, pos))
    return out


def _code_mask(text: str) -> str:
    """``text`` with everything a reader does not read as prose blanked: fenced code but its comments,
    inline code, links, HTML comments and the generated part."""
    out = list(text)
    i = text.find(GENERATED[0])
    if i >= 0:
        j = text.find(GENERATED[1], i)
        j = len(text) if j < 0 else j
        out[i:j] = [c if c == "\n" else " " for c in text[i:j]]
    pos, fence = 0, None
    for line in text.splitlines(keepends=True):
        stripped = line.strip()
        if fence is not None or _FENCE.match(stripped):
            if fence is not None and stripped.startswith(fence):
                fence = None
            elif fence is None:
                fence = stripped[:3]
            hash_ = line.find("#") if not _FENCE.match(stripped) else -1
            keep_from = hash_ if hash_ >= 0 else len(line)
            for k in range(pos, pos + keep_from):
                if out[k] != "\n":
                    out[k] = " "
        pos += len(line)
    masked = "".join(out)
    for pattern in (_COMMENT, _CODE_SPAN, _URL):
        masked = _blank(masked, pattern)
    return masked


def _line(text: str, offset: int) -> int:
    return text.count("\n", 0, offset) + 1


def _block_of(blocks: list[tuple[int, int]], offset: int) -> int:
    for i, (a, b) in enumerate(blocks):
        if a <= offset < b:
            return i
    return -1


def _bound(prose: str, start: int) -> str:
    before = prose[max(0, start - 30):start]
    return "upper" if _UPPER.search(before) else "lower" if _LOWER.search(before) else ""


def figures(text: str) -> list[Figure]:
    """Every time figure of the Markdown ``text``, in order (module docstring: what counts)."""
    prose = _code_mask(text)
    blocks = _blocks(text)
    found: dict[int, Figure] = {}

    def add(start: int, end: int, low: str, high: str | None, unit: str, written: str, words: bool = False) -> None:
        if any(f.start <= start < f.end for f in found.values()):
            return
        found[start] = Figure(text[start:end], low, high or low, unit, _bound(prose, start),
                              _block_of(blocks, start), start, end, _line(text, start), written, words)

    for m in _DIGIT_FIGURE.finditer(prose):
        end = m.end(2) if m.group(2) else m.end(1)
        add(m.start(1), end, m.group(1), m.group(2), _UNIT_WORDS[m.group(3)], text[m.start(1):m.end()])
    for m in _WORD_FIGURE.finditer(prose):
        if m.group(1).lower() == "a" and m.group(3).lower() == "second" and not m.group(2):
            continue  # "a second" is the ordinal more often than the time
        low, high = (str(_WORDS[w.lower()]) for w in (m.group(1), m.group(2) or m.group(1)))
        end = m.end(2) if m.group(2) else m.end(1)
        add(m.start(1), end, low, high if m.group(2) else None, _UNIT_WORDS[m.group(3).lower()],
            text[m.start(1):m.end()], words=True)
    for start, end, low, high, unit in _table_figures(text, prose):
        add(start, end, low, high, unit, f"{text[start:end]} (a {unit} column)")
    return sorted(found.values(), key=lambda f: f.start)


def _table_figures(text: str, prose: str) -> Iterable[tuple[int, int, str, str | None, str]]:
    """Numbers in the cells of table columns whose header names a time unit (not inside parentheses)."""
    lines = text.splitlines(keepends=True)
    offsets = [0]
    for line in lines:
        offsets.append(offsets[-1] + len(line))
    i = 0
    while i < len(lines) - 1:
        if lines[i].lstrip().startswith("|") and re.match(r"^\s*\|[\s:|-]+\|\s*$", lines[i + 1]):
            header = [c.strip() for c in prose[offsets[i]:offsets[i + 1]].strip().strip("|").split("|")]
            units: dict[int, str] = {}
            for k, cell in enumerate(header):
                m = _TIME_HEADER.search(cell.replace("*", ""))
                if m:
                    units[k] = m.group(1) or m.group(2)
            j = i + 2
            while j < len(lines) and lines[j].lstrip().startswith("|"):
                row = prose[offsets[j]:offsets[j + 1]]
                bars = [k for k, c in enumerate(row) if c == "|"]
                for k in range(len(bars) - 1):
                    if k not in units:
                        continue
                    a, b = bars[k] + 1, bars[k + 1]
                    cell = _blank(row[a:b], re.compile(r"\([^()]*\)"))
                    for m in _CELL_NUMBER.finditer(cell):
                        yield offsets[j] + a + m.start(1), offsets[j] + a + m.end(), m.group(1), m.group(2), units[k]
                j += 1
            i = j
        else:
            i += 1


def declarations(text: str) -> list[Declaration]:
    """Every ``<!-- time... -->`` declaration of ``text`` (module docstring) outside the generated part."""
    blocks = _blocks(text)
    gen = text.find(GENERATED[0])
    gen_end = text.find(GENERATED[1], gen) if gen >= 0 else -1
    out = []
    for m in _DECL.finditer(text):
        if gen >= 0 and gen < m.start() < (gen_end if gen_end >= 0 else len(text)):
            continue
        head, names, body = re.sub(r"\s+", " ", m.group(1)), m.group(2).strip(), m.group(3).strip()
        kind = {"time": "record", "times from": "historical", "times not measured": "not measured"}[head]
        commit = ""
        if kind == "historical":
            commit, names = names, ""
        if kind != "record":
            listed = body.split("(")[0]
            names, body = listed, body[len(listed):].strip()
        out.append(Declaration(kind, names.replace(",", " ").split(), body, _block_of(blocks, m.start()),
                               m.start(), _line(text, m.start()), commit, m.span(2)))
    return out


@lru_cache(maxsize=64)
def _load(path: str, mtime_ns: int) -> Any:
    """A record file's JSON, read once per version of the file (the checks read each many times)."""
    return json.loads(Path(path).read_text(encoding="utf-8"))


def _json(path: Path) -> Any:
    return _load(str(path), path.stat().st_mtime_ns)


def _notebook_wall(path: Path) -> float:
    nb = _json(path)
    total = 0.0
    for cell in nb["cells"]:
        ex = cell.get("metadata", {}).get("execution", {})
        if cell.get("cell_type") == "code" and "iopub.execute_input" in ex and "shell.execute_reply" in ex:
            a, b = (datetime.fromisoformat(ex[k].replace("Z", "+00:00"))
                    for k in ("iopub.execute_input", "shell.execute_reply"))
            total += (b - a).total_seconds()
    if total <= 0:
        raise ValueError(f"{path.name} records no execution times (metadata.execution)")
    return total


def record(spec: str, root: str | Path) -> tuple[float, float]:
    """The recorded time that ``spec`` (``[AGG] FIELD of PATH[:KEY]``) names, in seconds: (low, high),
    the same number twice but for ``range``. Raises ``ValueError`` with the reason when it names none."""
    m = _SPEC.match(spec.strip())
    if not m:
        raise ValueError(f"not a record: {spec!r} (want '[mean|min|max|sum|range] wall|cpu of PATH[:KEY]')")
    agg, fld, path, key = m.groups()
    root = Path(root)
    name = {"wall": "wall_time_s", "cpu": "cpu_time_s"}[fld]
    if path.endswith(".ipynb"):
        if fld != "wall" or key:
            raise ValueError(f"{spec!r}: a notebook records its wall time only, and has no KEY")
        values = [_notebook_wall(p) for p in sorted(root.glob(path))]
        label = path
    else:
        file = root / path
        if not file.is_file():
            raise ValueError(f"{spec!r}: no file {path}")
        data = _json(file)
        if key is None:
            raise ValueError(f"{spec!r}: name a stage or a glob after '{path}:'")
        entries = []
        for part in key.split(","):
            if part in data.get("timings", {}):
                entries.append(data["timings"][part])
            elif "jobs" in data:
                entries += [v for k, v in data["jobs"].items() if fnmatch.fnmatchcase(k, part)]
            else:
                entries += [f for f in data.get("files", []) if fnmatch.fnmatchcase(f["path"], part)]
        values = [e[name] for e in entries if e.get(name)]
        label = f"{path}:{key}"
    if not values:
        raise ValueError(f"{spec!r}: no {fld} time recorded for {label}")
    if agg is None:
        if len(values) > 1:
            raise ValueError(f"{spec!r}: {len(values)} records; say mean, min, max, sum or range")
        return values[0], values[0]
    if agg == "range":
        return min(values), max(values)
    v = {"mean": sum(values) / len(values), "min": min(values), "max": max(values), "sum": sum(values)}[agg]
    return v, v


def _step(written: str) -> Decimal:
    """The place of the last significant digit of a number as written (``4692`` -> 1, ``80`` -> 10)."""
    if "." in written:
        return Decimal(1).scaleb(-len(written.split(".")[1]))
    zeros = len(written) - len(written.rstrip("0"))
    return Decimal(1).scaleb(min(zeros, len(written) - 1))


def at_precision(value: float, written: str) -> str:
    """``value`` rounded at the last significant digit of ``written`` and written the same way."""
    step = _step(written)
    rounded = (Decimal(repr(value)) / step).quantize(Decimal(1), rounding=ROUND_HALF_UP) * step
    return f"{rounded:f}" if "." in written else str(int(rounded))


def matches(written: str, value: float, bound: str = "") -> bool:
    """Whether a figure ``written`` (in some unit) says ``value`` (in the same unit) at its precision;
    ``bound``: ``upper`` (the value may not exceed it) or ``lower``."""
    if bound == "upper":
        return value <= float(written)
    if bound == "lower":
        return value >= float(written)
    return Decimal(at_precision(value, written)) == Decimal(written)


def _check(fig: Figure, spec: str, root: Path) -> str | None:
    """Why ``fig`` does not say the record ``spec`` (None when it does)."""
    try:
        low, high = record(spec, root)
    except (ValueError, KeyError, OSError) as e:
        return f"'{fig.written}': {e}"
    scale = _SECONDS[fig.unit]
    if fig.low != fig.high and low == high:
        return f"'{fig.written}' is a range; declare 'range ...' (the record is one number, {low:.1f} s)"
    ok = matches(fig.low, low / scale, fig.bound) and matches(fig.high, high / scale, fig.bound)
    if ok:
        return None
    said = f"{low:.1f} s" if low == high else f"{low:.1f}-{high:.1f} s"
    want = (f"'{at_precision(low / scale, fig.low)}" + ("" if fig.low == fig.high else
                                                         f"-{at_precision(high / scale, fig.high)}") + f" {fig.unit}'")
    if fig.bound:
        want = f"a bound {'above' if fig.bound == 'upper' else 'below'} {said}"
    return f"'{fig.written}' is {spec} = {said}, which at this precision is {want}"


def bound_figures(text: str) -> tuple[list[Figure], list[Problem]]:
    """The time figures of ``text`` with their declarations attached (``Figure.declared``), and what is
    wrong with the declarations themselves (one that names no figure of its block, or a second record
    for one figure)."""
    figs = figures(text)
    out: list[Problem] = []
    for d in declarations(text):
        if d.names:
            bound = [f for f in figs if f.block == d.block and (f.text in d.names or f.low in d.names)]
            for n in d.names:
                if not any(n in (f.text, f.low) for f in bound):
                    out.append(Problem(d.line, f"the declaration names {n!r}, which is no time figure of its block"))
        else:
            before = [f for f in figs if f.block == d.block and f.end <= d.start]
            if d.kind != "record" or not before:
                out.append(Problem(d.line, f"a '{d.kind}' declaration with no figure to bind to (name the figures)"))
                continue
            bound = [before[-1]]
        for f in bound:
            if d.kind == "record" and any(x.kind == "record" for x in f.declared):
                out.append(Problem(d.line, f"a second record for '{f.written}'"))
            f.declared.append(d)
    return figs, out


def problems(text: str, root: str | Path) -> list[Problem]:
    """What is wrong with the time figures of the Markdown ``text`` (records under ``root``): a figure
    that differs from its record at its precision, a figure with no declaration, a declaration that names
    no figure or no record."""
    root = Path(root)
    figs, out = bound_figures(text)
    for f in figs:
        if not f.declared:
            out.append(Problem(f.line, f"'{f.written}' declares no record"))
        for d in f.declared:
            why = _check(f, d.body, root) if d.kind == "record" else None
            if why:
                out.append(Problem(f.line, why))
    return sorted(out, key=lambda p: p.line)


def fixed(text: str, root: str | Path) -> str:
    """``text`` with every digit figure that disagrees with its record rewritten at its precision (words,
    bounds and figures whose record cannot be read are left for a person)."""
    root = Path(root)
    edits = set()
    for f in bound_figures(text)[0]:
        records = [d for d in f.declared if d.kind == "record"]
        if f.words or f.bound or len(records) != 1 or _check(f, records[0].body, root) is None:
            continue
        try:
            low, high = record(records[0].body, root)
        except (ValueError, KeyError, OSError):
            continue
        scale = _SECONDS[f.unit]
        new = at_precision(low / scale, f.low)
        if f.low != f.high:  # "11-20": both ends, the separator as written
            new += f.text[len(f.low):len(f.text) - len(f.high)] + at_precision(high / scale, f.high)
        edits.add((f.start, f.end, new))
        if records[0].names == [f.text]:  # a declaration that names the figure names the new one
            edits.add((*records[0].names_at, new))
    for start, end, new in sorted(edits, reverse=True):
        text = text[:start] + new + text[end:]
    return text


def check_phrase(phrase: str, spec: str, root: str | Path) -> str | None:
    """For a time quoted outside Markdown (an error message): why the one time figure in ``phrase`` does
    not say the record ``spec`` (None when it does)."""
    figs = figures(phrase)
    if len(figs) != 1:
        return f"{phrase!r} has {len(figs)} time figures, not one"
    return _check(figs[0], spec, Path(root))


def commits(text: str) -> list[tuple[int, str]]:
    """(line, commit) of every ``times from COMMIT`` declaration, for the test that the commits exist."""
    return [(d.line, d.commit) for d in declarations(text) if d.kind == "historical"]
