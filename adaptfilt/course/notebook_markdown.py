r"""The notebook -> Markdown converter of the course book, pure functions on strings and notebook dicts:
maths for MathJax 2.7 inside CommonMark (:func:`escape_math`, :func:`rewrite_math`), links between
chapters and local images (:func:`rewrite_links`), a notebook with its committed outputs to mdBook
Markdown (:func:`notebook_to_markdown`, :func:`notebook_title`), a figure's alt text from its titles
(:func:`figure_titles`, :func:`plain_text`) and the book's bibliography from the chapters' ``## References``
sections (:func:`notebook_references`, :func:`split_reference`, :func:`bibliography_markdown`).
Unit-tested in ``tests/test_book.py``; :mod:`adaptfilt.course.book` builds the book with them.
"""
from __future__ import annotations

import ast
import base64
import re
import string
import unicodedata
from collections import Counter
from pathlib import Path
from typing import Any, Mapping, Sequence

__all__ = ["escape_math", "rewrite_math", "rewrite_links", "notebook_to_markdown", "notebook_title", "figure_titles",
           "plain_text", "notebook_references", "split_reference", "bibliography_markdown"]

_REPR = re.compile(r"^<.*>$", flags=re.S)  # an object's default repr, e.g. matplotlib's "<Figure size ...>"
NBVAL_MARKER = re.compile(r"^[ \t]*#[ \t]*NBVAL_[A-Z_]+[ \t]*$")
ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")
# Every ASCII punctuation character may be backslash-escaped in CommonMark,
# and escaping is the only way to stop the parser from acting on it.
_PUNCTUATION = frozenset(string.punctuation)
_FENCE_OPEN = re.compile(r"^[ \t]*(`{3,}|~{3,})(.*)$")
_WIDGET_MIME = "application/vnd.jupyter.widget-view+json"
# Output MIME types in order of preference (what Jupyter would show).
_MIME_ORDER = (
    "image/svg+xml",
    "image/png",
    "image/jpeg",
    "text/html",
    "text/markdown",
    "text/latex",
    "text/plain",
)
# Environments that are a display on their own (not allowed inside \[ \]).
_EQUATION_ENVS = frozenset({"equation", "align", "alignat", "flalign", "gather", "multline", "eqnarray"})
_IMAGE_EXT = {"image/svg+xml": "svg", "image/png": "png", "image/jpeg": "jpg"}


# ---------------------------------------------------------------- maths


def escape_math(tex: str) -> str:
    """Escape TeX so that CommonMark hands it to MathJax unchanged.

    CommonMark turns ``\\`` + ASCII punctuation into the bare punctuation and
    gives ``_ * [ < & ` ~ -`` (and smart punctuation ``' " -- ...``) meaning.
    Backslash-escaping *every* ASCII punctuation character is exact: each
    ``\\p`` renders as ``p``, while letters, digits and spaces (which can't be
    escaped) are left alone. So ``\\\\`` becomes ``\\\\\\\\``, ``_`` ``\\_``,
    ``\\,`` ``\\\\\\,`` and ``\\alpha`` ``\\\\alpha``.
    """
    return "".join("\\" + c if c in _PUNCTUATION else c for c in tex)


def _emit_math(tex: str, display: bool) -> str:
    """Markdown for one formula, delimited the way the book's MathJax reads it."""
    stripped = tex.strip()
    env = re.fullmatch(r"\\begin\{([A-Za-z*]+)\}.*\\end\{\1\}", stripped, flags=re.S)
    if display and env and env.group(1).rstrip("*") in _EQUATION_ENVS:
        # `$$\begin{align}..\end{align}$$`: MathJax 2 rejects an equation
        # environment nested in \[..\], so emit the bare environment.
        return escape_math(stripped)
    if display:
        return "\\\\[" + escape_math(tex) + "\\\\]"
    return "\\\\(" + escape_math(tex) + "\\\\)"


def _find_unescaped(text: str, target: str, start: int, stop_at_blank_line: bool) -> int:
    """Index of the next ``target`` not preceded by a backslash escape, or -1."""
    i = start
    while i < len(text):
        if text[i] == "\\":
            i += 2
            continue
        if stop_at_blank_line and text.startswith("\n\n", i):
            return -1
        if text.startswith(target, i):
            return i
        i += 1
    return -1


def _closing_inline_dollar(text: str, start: int) -> int:
    """Closing ``$`` of inline maths opened just before ``start``, or -1.

    Pandoc's rule: the content neither starts nor ends with whitespace, and
    the closing ``$`` is not followed by a digit (so ``$5 and $10`` is text).
    """
    if start >= len(text) or text[start].isspace() or text[start] == "$":
        return -1
    i = start
    while True:
        j = _find_unescaped(text, "$", i, stop_at_blank_line=True)
        if j < 0:
            return -1
        after_ok = j + 1 >= len(text) or not text[j + 1].isdigit()
        if not text[j - 1].isspace() and after_ok:
            return j
        i = j + 1


def _rewrite_math_prose(text: str) -> str:
    """Rewrite maths in Markdown that contains no fenced code block."""
    out: list[str] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("\\begin{", i):
            m = re.match(r"\\begin\{([A-Za-z*]+)\}", text[i:])
            end = text.find("\\end{" + m.group(1) + "}", i) if m else -1
            if end >= 0:
                end += len("\\end{" + m.group(1) + "}")  # type: ignore[union-attr]
                out.append(escape_math(text[i:end]))
                i = end
                continue
        if c == "\\":  # an escape (\$ stays a literal dollar): copy it as is
            out.append(text[i : i + 2])
            i += 2
            continue
        if c == "`":  # a code span: copy verbatim up to the same-length run
            run = re.match(r"`+", text[i:]).group(0)  # type: ignore[union-attr]
            close = re.compile(r"(?<!`)" + run + r"(?!`)").search(text, i + len(run))
            end = close.end() if close else i + len(run)
            out.append(text[i:end])
            i = end
            continue
        if text.startswith("$$", i):
            j = _find_unescaped(text, "$$", i + 2, stop_at_blank_line=True)
            if j > i + 2:
                out.append(_emit_math(text[i + 2 : j], display=True))
                i = j + 2
                continue
            out.append("$$")
            i += 2
            continue
        if c == "$":
            j = _closing_inline_dollar(text, i + 1)
            if j > 0:
                out.append(_emit_math(text[i + 1 : j], display=False))
                i = j + 1
                continue
        out.append(c)
        i += 1
    return "".join(out)


def _split_fenced(markdown: str) -> list[tuple[bool, str]]:
    """Split Markdown into (is_fenced_code, text) pieces, keeping every character."""
    pieces: list[tuple[bool, str]] = []
    prose: list[str] = []
    lines = markdown.splitlines(keepends=True)
    i = 0
    while i < len(lines):
        m = _FENCE_OPEN.match(lines[i].rstrip("\r\n"))
        if not m or (m.group(1)[0] == "`" and "`" in m.group(2)):
            prose.append(lines[i])
            i += 1
            continue
        fence = m.group(1)
        closing = re.compile(r"^[ \t]*" + re.escape(fence[0]) + "{" + str(len(fence)) + r",}[ \t]*$")
        j = i + 1
        while j < len(lines) and not closing.match(lines[j].rstrip("\r\n")):
            j += 1
        if prose:
            pieces.append((False, "".join(prose)))
            prose = []
        pieces.append((True, "".join(lines[i : j + 1])))  # unclosed: runs to the end
        i = j + 1
    if prose:
        pieces.append((False, "".join(prose)))
    return pieces


def rewrite_math(markdown: str) -> str:
    """Rewrite Jupyter's ``$..$`` / ``$$..$$`` maths for mdBook's CommonMark + MathJax.

    Inline maths becomes ``\\\\( .. \\\\)``, display maths ``\\\\[ .. \\\\]`` and
    bare ``\\begin{env}..\\end{env}`` stays bare; the TeX inside is escaped by
    :func:`escape_math`. Code spans and fenced code are left untouched, and an
    escaped ``\\$`` stays a literal dollar.
    """
    return "".join(text if code else _rewrite_math_prose(text) for code, text in _split_fenced(markdown))


# ---------------------------------------------------------------- links and images


def rewrite_links(markdown: str, targets: Mapping[str, str]) -> str:
    """Point Markdown links at chapter files: ``](notebooks/01-x.ipynb#a)`` -> ``](01-x.md#a)``.

    ``targets`` maps a source path (as written in the repository, e.g.
    ``notebooks/01-x.ipynb`` or ``README.md``) to its chapter file; a link
    matches on its path with leading ``./`` and ``../`` removed, or on its
    file name.
    """
    by_name = {Path(k).name: v for k, v in targets.items()}

    def repl(m: re.Match[str]) -> str:
        path = re.sub(r"^(\.\.?/)+", "", m.group(2))
        new = None if "://" in path else targets.get(path) or by_name.get(Path(path).name)
        return m.group(1) + new + (m.group(3) or "") if new else m.group(0)

    return re.sub(r"(\]\(\s*<?)([^)\s#>]+)(#[^)\s>]*)?", repl, markdown)


def _localise_images(markdown: str, base: Path, prefix: str) -> tuple[str, dict[str, bytes]]:
    """Copy images a Markdown file references by relative path into the book.

    Returns the rewritten Markdown and the files to write (relative to src).
    References that are URLs or do not exist are left alone (the built book's
    test then reports them).
    """
    files: dict[str, bytes] = {}

    def localise(ref: str) -> str:
        if re.match(r"^[a-z][a-z0-9+.-]*:", ref, flags=re.I) or ref.startswith("/"):
            return ref
        source = (base / ref).resolve()
        if not source.is_file():
            return ref
        target = f"{prefix}/{_safe_name(ref)}"
        files[target] = source.read_bytes()
        return target

    markdown = re.sub(
        r"(!\[[^\]]*\]\(\s*<?)([^)\s>]+)", lambda m: m.group(1) + localise(m.group(2)), markdown
    )
    markdown = re.sub(
        r"(<img\b[^>]*\bsrc=[\"'])([^\"']+)", lambda m: m.group(1) + localise(m.group(2)), markdown
    )
    return markdown, files


def _safe_name(path: str) -> str:
    """A flat, URL-safe file name for a relative path."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", re.sub(r"^(\.\.?/)+", "", path))


# ---------------------------------------------------------------- notebooks


def _text(value: str | Sequence[str]) -> str:
    """Notebook strings may be stored as a list of lines."""
    return value if isinstance(value, str) else "".join(value)


def _fenced(body: str, info: str = "") -> str:
    """A fenced code block whose fence is longer than any backtick run inside."""
    longest = max((len(r) for r in re.findall(r"`+", body)), default=0)
    fence = "`" * max(3, longest + 1)
    return f"{fence}{info}\n{body.rstrip()}\n{fence}\n"


def _collapse_carriage_returns(text: str) -> str:
    """Keep what a terminal would show: the last ``\\r``-separated state of each line."""
    lines = []
    for line in text.split("\n"):
        parts = [p for p in line.split("\r") if p]
        lines.append(parts[-1] if parts else "")
    return "\n".join(lines)


def _clean_source(source: str) -> str:
    """Drop nbval markers: they steer the notebook tests, readers don't need them."""
    lines = [ln for ln in source.splitlines() if not NBVAL_MARKER.match(ln)]
    return "\n".join(lines).strip("\n")


def _html_block(html: str) -> str:
    """Raw HTML as one CommonMark HTML block (a blank line would end it early)."""
    body = "\n".join(ln for ln in html.strip().splitlines() if ln.strip())
    return f'<div class="nb-output nb-html">\n{body}\n</div>\n'


def _render_data(data: Mapping[str, Any], stem: str, files: dict[str, bytes], alt: str = "") -> str:
    """Markdown for an execute_result / display_data bundle (``alt``: a figure's alt text, see
    :func:`_figure_alt`)."""
    # Widgets (tqdm bars, ipywidgets) need a live kernel: _WIDGET_MIME is not in
    # _MIME_ORDER, so a widget view is dropped and its text fallback kept.
    mimes = [m for m in _MIME_ORDER if m in data]
    if not mimes:
        return ""
    mime = mimes[0]
    if mime in _IMAGE_EXT:
        name = f"{stem}.{_IMAGE_EXT[mime]}"
        raw = _text(data[mime])
        files[name] = raw.encode() if mime == "image/svg+xml" else base64.b64decode(raw)
        text = " ".join(_text(data.get("text/plain", "")).split())
        # matplotlib's text/plain is its repr, "<Figure size 700x360 with 1 Axes>": no description
        alt = alt or ("" if _REPR.match(text) else plain_text(text, markdown=False)) or "figure"
        return f"![{escape_math(alt)}]({name})\n"
    if mime == "text/html":
        return _html_block(_text(data[mime]))
    if mime in ("text/markdown", "text/latex"):
        return rewrite_math(_text(data[mime])) + "\n"
    return _fenced(_text(data[mime]), "text")


def _render_output(output: Mapping[str, Any], stem: str, files: dict[str, bytes], alt: str = "") -> str:
    """Markdown for one cell output."""
    kind = output.get("output_type")
    if kind == "stream":
        text = _collapse_carriage_returns(_text(output.get("text", "")))
        return _fenced(ANSI_ESCAPE.sub("", text), "text") if text.strip() else ""
    if kind == "error":
        trace = "\n".join(output.get("traceback") or []) or f"{output.get('ename')}: {output.get('evalue')}"
        return _fenced(ANSI_ESCAPE.sub("", trace), "text")
    if kind in ("execute_result", "display_data"):
        return _render_data(output.get("data", {}), stem, files, alt)
    return ""


def _attachments(cell: Mapping[str, Any], source: str, prefix: str, files: dict[str, bytes]) -> str:
    """Extract ``attachment:NAME`` images of a Markdown cell to files."""
    for name, bundle in (cell.get("attachments") or {}).items():
        for mime, ext in _IMAGE_EXT.items():
            if mime in bundle:
                raw = _text(bundle[mime])
                target = f"{prefix}-{_safe_name(name)}"
                if not target.endswith("." + ext):
                    target += "." + ext
                files[target] = raw.encode() if mime == "image/svg+xml" else base64.b64decode(raw)
                source = source.replace(f"attachment:{name}", target)
                break
    return source


def notebook_to_markdown(
    nb: Mapping[str, Any], figure_prefix: str, links: Mapping[str, str] | None = None
) -> tuple[str, dict[str, bytes]]:
    """Convert an executed notebook (as a dict) to mdBook Markdown.

    Figures become files named ``{figure_prefix}-cell{i}-{j}.{ext}`` (relative
    to the book's src); they are returned in the second element, mapping file
    name to bytes. Cell tags ``remove-cell``, ``remove-input`` and
    ``remove-output`` are honoured; nbval markers are dropped from the code.
    """
    files: dict[str, bytes] = {}
    meta = nb.get("metadata", {})
    lang = (meta.get("language_info") or {}).get("name") or (meta.get("kernelspec") or {}).get("language") or "python"
    parts: list[str] = []
    before = ""  # the last Markdown cell so far: a figure without a title is described from it
    for i, cell in enumerate(nb.get("cells", [])):
        tags = set((cell.get("metadata") or {}).get("tags") or [])
        source = _text(cell.get("source", ""))
        kind = cell.get("cell_type")
        if kind == "markdown":
            before = source
        if "remove-cell" in tags:
            continue
        if kind == "markdown":
            source = _attachments(cell, source, f"{figure_prefix}-cell{i}", files)
            parts.append(rewrite_links(rewrite_math(source), links or {}).rstrip() + "\n")
        elif kind == "code":
            code = _clean_source(source)
            if code.strip() and "remove-input" not in tags:
                parts.append(_fenced(code, lang))
            if "remove-output" not in tags:
                outputs = cell.get("outputs") or []
                alts = _figure_alts(source, outputs, before)
                for j, output in enumerate(outputs):
                    parts.append(_render_output(output, f"{figure_prefix}-cell{i}-{j}", files, alts.get(j, "")))
        # raw cells are for other converters (LaTeX, reST): not shown
    return "\n".join(p for p in parts if p), files


def notebook_title(nb: Mapping[str, Any], fallback: str) -> str:
    """The first Markdown heading of a notebook, or ``fallback``."""
    for cell in nb.get("cells", []):
        if cell.get("cell_type") != "markdown":
            continue
        m = re.search(r"^#{1,6}[ \t]+(.+?)[ \t#]*$", _text(cell.get("source", "")), flags=re.M)
        if m:
            # The sidebar shows titles as plain text: `the $\kappa$ knob` -> `the kappa knob`.
            return re.sub(r"\\([A-Za-z]+)", r"\1", m.group(1).replace("$", "")).strip()
    return fallback


# ---------------------------------------------------------------- figure alt text

# TeX a figure title may hold, as the plain text an alt attribute can carry.
_GREEK = {name: chr(code) for name, code in (
    ("alpha", 0x3B1), ("beta", 0x3B2), ("gamma", 0x3B3), ("delta", 0x3B4), ("epsilon", 0x3B5), ("zeta", 0x3B6),
    ("eta", 0x3B7), ("theta", 0x3B8), ("kappa", 0x3BA), ("lambda", 0x3BB), ("mu", 0x3BC), ("nu", 0x3BD),
    ("xi", 0x3BE), ("pi", 0x3C0), ("rho", 0x3C1), ("sigma", 0x3C3), ("tau", 0x3C4), ("phi", 0x3C6),
    ("chi", 0x3C7), ("psi", 0x3C8), ("omega", 0x3C9), ("Gamma", 0x393), ("Delta", 0x394), ("Theta", 0x398),
    ("Lambda", 0x39B), ("Pi", 0x3A0), ("Sigma", 0x3A3), ("Phi", 0x3A6), ("Psi", 0x3A8), ("Omega", 0x3A9))}
_SYMBOLS = {"times": "\u00d7", "cdot": "\u00b7", "le": "\u2264", "leq": "\u2264", "ge": "\u2265", "geq": "\u2265",
            "approx": "\u2248", "pm": "\u00b1", "infty": "\u221e", "to": "\u2192", "ne": "\u2260", "neq": "\u2260",
            "sim": "~", "in": "\u2208", ",": " ", ";": " ", "!": "", " ": " ", "%": "%", "$": "$", "_": "_",
            "{": "{", "}": "}", "&": "&", "#": "#"}
_TITLE_CALLS = frozenset({"set_title", "suptitle", "title"})


def plain_text(text: str, markdown: bool = True) -> str:
    r"""Markdown (or, with ``markdown=False``, a matplotlib title) with ``$..$`` maths as plain text for
    an alt attribute: maths loses its markup, Greek letters become Unicode; Markdown also loses its
    links, HTML tags, emphasis and code marks (in a title they are literal text).

    >>> plain_text(r"RMSE$_k$ for $\kappa = 2$ and $\bar L_\mathrm{NIS}$, `code` and **bold**")
    'RMSE_k for κ = 2 and L_NIS, code and bold'
    """
    if markdown:
        text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)  # a link: its text
        text = re.sub(r"<[^>]+>", "", text)  # HTML tags

    def maths(m: re.Match[str]) -> str:
        tex = m.group(1) or m.group(2) or ""
        tex = re.sub(r"\\(?:mathrm|text|mathbf|boldsymbol|operatorname|mathcal|mathsf|textrm|mathit)\s*\{([^{}]*)\}",
                     r"{\1}", tex)  # braces keep "\sim\mathcal{N}" two words; they go below
        tex = re.sub(r"\\(?:bar|hat|tilde|overline|widetilde|widehat|left|right|big|Big|bigg|Bigg)\b\s*", "", tex)
        tex = re.sub(r"\\([A-Za-z]+)", lambda c: _GREEK.get(c.group(1), _SYMBOLS.get(c.group(1), c.group(1))), tex)
        tex = re.sub(r"\\(.)", lambda c: _SYMBOLS.get(c.group(1), c.group(1)), tex)
        return tex.replace("{", "").replace("}", "")

    text = re.sub(r"\$\$(.+?)\$\$|\$([^$]+)\$", maths, text, flags=re.S)
    if markdown:
        text = re.sub(r"(\*\*|__|\*|`)", "", text)  # emphasis and code spans: their text
    return " ".join(text.split())


def _string_value(node: ast.AST) -> str | None:
    """A string literal's text; an f-string's with each ``{..}`` replaced by ``…`` (its value is not known)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value if isinstance(v, ast.Constant) else "\u2026" for v in node.values)
    return None


def figure_titles(source: str) -> list[str]:
    """The titles a code cell gives its figures, in source order, as plain text.

    A title is the string given to ``set_title``, ``suptitle`` or ``title`` (``plt.title``, or a helper
    of the course) or as the keyword ``title=`` of any call (``ax.set(title=...)``,
    ``style.figure(..., title=...)``). What a helper sets inside itself is not seen. IPython magics and
    shell lines are skipped; a cell that does not parse has no titles.
    """
    code = "\n".join("" if ln.lstrip().startswith(("%", "!")) else ln for ln in source.splitlines())
    try:
        tree = ast.parse(code)
    except SyntaxError:
        return []
    found: list[tuple[int, int, str]] = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
        values = [node.args[0]] if name in _TITLE_CALLS and node.args else []
        values += [k.value for k in node.keywords if k.arg == "title"]
        for value in values:
            text = _string_value(value)
            if text and text.strip():
                found.append((value.lineno, value.col_offset, plain_text(text, markdown=False)))
    return [t for _, _, t in sorted(found)]


def _first_sentence(markdown: str, limit: int = 250) -> str:
    """The first sentence of the last paragraph of prose in ``markdown`` (no heading, code, list marker)."""
    prose = [p for p in re.split(r"\n\s*\n", markdown)
             if p.strip() and not re.match(r"\s*(#|```|~~~|<|\$\$|\|)", p)]
    if not prose:
        return ""
    text = plain_text(re.sub(r"^\s*(?:[*+-]|\d+\.)\s+", "", prose[-1], flags=re.M))
    m = re.match(r"(.+?[.!?])(?=\s+[A-Z(\"]|$)", text)  # not at "e.g. the" or "i.e. one"
    sentence = m.group(1) if m else text
    return sentence if len(sentence) <= limit else sentence[: limit - 1].rsplit(" ", 1)[0] + "\u2026"


def _figure_alts(source: str, outputs: Sequence[Mapping[str, Any]], before: str) -> dict[int, str]:
    """Alt text for each figure output of a code cell (output index -> text).

    The figure's titles from the cell's code (:func:`figure_titles`): one figure gets them all (the axes'
    titles and the suptitle), several figures get one title each when the counts agree. Otherwise a
    caption from the Markdown cell before (its last paragraph's first sentence). Empty: the image
    bundle's own text/plain, unless that is an object's repr.
    """
    figures = [j for j, o in enumerate(outputs) if any(m in _IMAGE_EXT for m in (o.get("data") or {}))]
    if not figures:
        return {}
    titles = figure_titles(source)
    if titles and len(figures) > 1 and len(titles) == len(figures):
        return {j: f"Figure: {t}" for j, t in zip(figures, titles)}
    if titles:
        return {j: "Figure: " + "; ".join(titles) for j in figures}
    caption = _first_sentence(before)
    return {j: f"Figure after the text: {caption}" for j in figures} if caption else {}


# ---------------------------------------------------------------- bibliography


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
        for line in _text(cell.get("source", "")).splitlines():
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
