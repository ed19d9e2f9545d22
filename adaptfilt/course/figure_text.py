r"""A figure's alt text for the course book, from what the cell that draws it says: the titles it sets
(:func:`figure_titles`: ``set_title``, ``suptitle``, ``title=``) made plain (:func:`plain_text`: TeX and
Markdown to the text an ``alt`` attribute can carry), or the first sentence of the Markdown before it.
Used by :func:`adaptfilt.course.notebook_markdown.notebook_to_markdown`; unit-tested in ``tests/test_figure_text.py``.
"""
from __future__ import annotations

import ast
import re

__all__ = ["plain_text", "figure_titles", "first_sentence"]

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


def first_sentence(markdown: str, limit: int = 250) -> str:
    """The first sentence of the last paragraph of prose in ``markdown`` (no heading, code, list marker)."""
    prose = [p for p in re.split(r"\n\s*\n", markdown)
             if p.strip() and not re.match(r"\s*(#|```|~~~|<|\$\$|\|)", p)]
    if not prose:
        return ""
    text = plain_text(re.sub(r"^\s*(?:[*+-]|\d+\.)\s+", "", prose[-1], flags=re.M))
    m = re.match(r"(.+?[.!?])(?=\s+[A-Z(\"]|$)", text)  # not at "e.g. the" or "i.e. one"
    sentence = m.group(1) if m else text
    return sentence if len(sentence) <= limit else sentence[: limit - 1].rsplit(" ", 1)[0] + "\u2026"
