r"""The notebook -> Markdown converter of the course book, pure functions on strings and notebook dicts:
maths for MathJax 2.7 inside CommonMark (:func:`escape_math`, :func:`rewrite_math`), links between
chapters and local images (:func:`rewrite_links`), and a notebook with its committed outputs to mdBook Markdown
(:func:`notebook_to_markdown`, :func:`notebook_title`), each figure with its alt text
(:mod:`adaptfilt.course.figure_text`). The bibliography is :mod:`adaptfilt.course.bibliography`.
Unit-tested in ``tests/test_notebook_markdown.py``; :mod:`adaptfilt.course.book` builds the book with them.
"""
from __future__ import annotations

import base64
import re
import string
from pathlib import Path
from typing import Any, Mapping, Sequence

from adaptfilt.course.figure_text import figure_titles, first_sentence, plain_text

__all__ = ["escape_math", "rewrite_math", "rewrite_links", "notebook_to_markdown", "notebook_title"]

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


def localise_images(markdown: str, base: Path, prefix: str) -> tuple[str, dict[str, bytes]]:
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


def text_of(value: str | Sequence[str]) -> str:
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
        raw = text_of(data[mime])
        files[name] = raw.encode() if mime == "image/svg+xml" else base64.b64decode(raw)
        text = " ".join(text_of(data.get("text/plain", "")).split())
        # matplotlib's text/plain is its repr, "<Figure size 700x360 with 1 Axes>": no description
        alt = alt or ("" if _REPR.match(text) else plain_text(text, markdown=False)) or "figure"
        return f"![{escape_math(alt)}]({name})\n"
    if mime == "text/html":
        return _html_block(text_of(data[mime]))
    if mime in ("text/markdown", "text/latex"):
        return rewrite_math(text_of(data[mime])) + "\n"
    return _fenced(text_of(data[mime]), "text")


def _render_output(output: Mapping[str, Any], stem: str, files: dict[str, bytes], alt: str = "") -> str:
    """Markdown for one cell output."""
    kind = output.get("output_type")
    if kind == "stream":
        text = _collapse_carriage_returns(text_of(output.get("text", "")))
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
                raw = text_of(bundle[mime])
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
        source = text_of(cell.get("source", ""))
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
                alts = _figure_alts(source, outputs, before, (cell.get("metadata") or {}).get("alt"))
                for j, output in enumerate(outputs):
                    parts.append(_render_output(output, f"{figure_prefix}-cell{i}-{j}", files, alts.get(j, "")))
        # raw cells are for other converters (LaTeX, reST): not shown
    return "\n".join(p for p in parts if p), files


def notebook_title(nb: Mapping[str, Any], fallback: str) -> str:
    """The first Markdown heading of a notebook, or ``fallback``."""
    for cell in nb.get("cells", []):
        if cell.get("cell_type") != "markdown":
            continue
        m = re.search(r"^#{1,6}[ \t]+(.+?)[ \t#]*$", text_of(cell.get("source", "")), flags=re.M)
        if m:
            # The sidebar shows titles as plain text: `the $\kappa$ knob` -> `the kappa knob`.
            return re.sub(r"\\([A-Za-z]+)", r"\1", m.group(1).replace("$", "")).strip()
    return fallback


# ---------------------------------------------------------------- figure alt text


def _figure_alts(source: str, outputs: Sequence[Mapping[str, Any]], before: str,
                 given: str | Sequence[str] | None = None) -> dict[int, str]:
    """Alt text for each figure output of a code cell (output index -> text).

    ``given``: the cell's own alt text (metadata ``alt``: one text, or one per figure), which says what
    the figure shows; it wins over everything below.
    The figure's titles from the cell's code (:func:`figure_titles`): one figure gets them all (the axes'
    titles and the suptitle), several figures get one title each when the counts agree. Otherwise a
    caption from the Markdown cell before (its last paragraph's first sentence). Empty: the image
    bundle's own text/plain, unless that is an object's repr.
    """
    figures = [j for j, o in enumerate(outputs) if any(m in _IMAGE_EXT for m in (o.get("data") or {}))]
    if not figures:
        return {}
    if given:
        texts = [given] * len(figures) if isinstance(given, str) else list(given)
        return {j: plain_text(t) for j, t in zip(figures, texts)}
    titles = figure_titles(source)
    if titles and len(figures) > 1 and len(titles) == len(figures):
        return {j: f"Figure: {t}" for j, t in zip(figures, titles)}
    if titles:
        return {j: "Figure: " + "; ".join(titles) for j in figures}
    caption = first_sentence(before)
    return {j: f"Figure after the text: {caption}" for j in figures} if caption else {}
