r"""The book's library reference: HTML pages generated with `pdoc <https://pdoc.dev>`_ from the
docstrings of the library (``adaptfilt`` without the pipeline ``adaptfilt.experiments``, the course
``adaptfilt.course`` and the command line), maths included.

:func:`write_reference` renders the pages into the book's sources (``reference/``; mdBook copies them
into the book as they are) and :func:`reference_chapter` is the book page that the navigation's
"Library reference" entry opens: one link per library module. The pages typeset their formulas with
the book's own MathJax 2.7 (no network): pdoc's ``--math`` template, which loads MathJax 3 from a
CDN, is replaced by :data:`_MATH_TEMPLATE`; pdoc writes ``.. math::`` blocks as ``$$ ... $$`` and
``:math:`` roles as ``\( ... \)`` (one directive per formula: a blank line inside one would split it
into paragraphs that MathJax leaves raw). pdoc leaves reST simple tables as text;
:func:`simple_tables_to_markdown` turns them into Markdown tables before pdoc renders a docstring.
"""
from __future__ import annotations

import ast
import re
import shutil
import tempfile
import warnings
from pathlib import Path

__all__ = ["NOT_LIBRARY", "library_modules", "simple_tables_to_markdown", "write_reference", "reference_chapter",
           "REFERENCE_DIR"]

#: The folder of the book's sources (and of the built book) that holds the pages.
REFERENCE_DIR = "reference"
#: What the reference leaves out: the pipeline, the course and the command line (docs/ARCHITECTURE.md).
NOT_LIBRARY = ("adaptfilt.experiments", "adaptfilt.course", "adaptfilt.cli", "adaptfilt.__main__", "adaptfilt._version")

# Loads the book's MathJax (``mathjax/`` and ``mathjax-config.js`` at the book's root) instead of a CDN;
# ``up`` is the way from a page back to the book's root.
_MATH_TEMPLATE = r"""{# adaptfilt: the book's local MathJax 2.7 instead of pdoc's MathJax 3 from a CDN #}
{% set depth = (module.modulename.count(".") + 1) if module else 1 %}
{% set up = "../" * depth %}
<script src="{{ up }}mathjax-config.js"></script>
<script>
    /* pdoc writes display maths as $$ ... $$ and inline maths as \( ... \) */
    window.MathJax.tex2jax.displayMath = [["$$", "$$"], ["\\[", "\\]"]];
</script>
<script src="{{ up }}mathjax/MathJax.js?config=TeX-AMS-MML_HTMLorMML-full"></script>
<style>
    /* as the book's pages (adaptfilt.course.book): room above and below, or tall formulas are clipped */
    .MathJax_Display { max-width: 100%; overflow-x: auto; overflow-y: hidden; padding: 0.5em 0; margin: 0.5em 0; }
    /* a table wider than the column scrolls sideways instead of running past it */
    .pdoc .docstring table { display: block; max-width: 100%; overflow-x: auto; }
    .MJX_Assistive_MathML, .MJX_Assistive_MathML * { font-family: inherit !important; }
</style>
"""


_BORDER = re.compile(r"^(?P<indent>[ \t]*)=+(?:[ \t]+=+)+[ \t]*$")


def simple_tables_to_markdown(text: str) -> str:
    """reST *simple tables* (columns under ``=====  =====`` borders, an optional header between the
    first two) as Markdown tables, which pdoc renders: its reST support leaves them as text, a
    paragraph of ``=`` signs. A row whose first column is blank continues the row above."""
    lines = text.split("\n")
    out, i = [], 0
    while i < len(lines):
        top = _BORDER.match(lines[i])
        borders = [i]
        if top:  # the table's other borders: same columns, until a blank line or the text's end
            j = i + 1
            while j < len(lines) and lines[j].strip():
                if lines[j].rstrip() == lines[i].rstrip():
                    borders.append(j)
                j += 1
        if not top or len(borders) not in (2, 3) or borders[-1] != j - 1:  # other forms stay as they are
            out.append(lines[i])
            i += 1
            continue
        border, indent = lines[i].rstrip(), top.group("indent")
        starts = [m.start() for m in re.finditer(r"=+", border)]

        def cells(line: str) -> list[str]:
            line = line.ljust(len(border))
            return [line[a:b].strip() for a, b in zip(starts, starts[1:] + [len(line)])]

        def rows(a: int, b: int) -> list[list[str]]:
            got: list[list[str]] = []
            for line in lines[a:b]:
                c = cells(line)
                if got and not c[0]:
                    got[-1] = [f"{x} {y}".strip() for x, y in zip(got[-1], c)]
                else:
                    got.append(c)
            return got

        head = rows(borders[0] + 1, borders[1]) if len(borders) == 3 else [[""] * len(starts)]
        body = rows(borders[-2] + 1, borders[-1])
        for row in [head[0], ["---"] * len(starts), *body]:
            out.append(indent + "| " + " | ".join(c.replace("|", "\\|") for c in row) + " |")
        i = borders[-1] + 1
    return "\n".join(out)


def library_modules(package_dir: Path | None = None) -> list[str]:
    """The library's modules by dotted name, in file order: every module of ``adaptfilt`` that is
    not in :data:`NOT_LIBRARY` (private ``_name`` modules left out)."""
    package_dir = Path(package_dir) if package_dir is not None else Path(__file__).resolve().parents[1]
    out = []
    for p in sorted(package_dir.rglob("*.py")):
        rel = p.relative_to(package_dir.parent).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        if name.startswith(NOT_LIBRARY) or any(part.startswith("_") and part != "__init__" for part in rel.parts):
            continue
        out.append(name)
    return out


def _summary(path: Path) -> str:
    """The first sentence of a module's docstring, for the reference page."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    first = doc.strip().split("\n\n")[0].replace("\n", " ")
    first = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", first)  # reST roles -> code
    return first.split(". ")[0].rstrip(".:") + "." if first else ""


def write_reference(dest: Path) -> list[str]:
    """Render the pages of :func:`library_modules` into ``dest`` (``dest/adaptfilt.html``,
    ``dest/adaptfilt/<module>.html``, ...); return the module names. Imports the library (torch
    included), not the pipeline or the course."""
    import pdoc
    import pdoc.docstrings
    import pdoc.render

    modules = library_modules()
    rst = pdoc.docstrings.rst  # pdoc's reST conversion, with simple tables first
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "math.html.jinja2").write_text(_MATH_TEMPLATE, encoding="utf-8")
        pdoc.render.configure(docformat="restructuredtext", math=True, search=False, show_source=True,
                              template_directory=Path(tmp), footer_text="adaptfilt library reference")
        if Path(dest).exists():
            shutil.rmtree(dest)
        with warnings.catch_warnings():  # a package's spec adds the submodules of its __all__ again: harmless
            warnings.filterwarnings("ignore", message="The module specification", category=UserWarning)
            pdoc.docstrings.rst = lambda contents, source_file: rst(simple_tables_to_markdown(contents), source_file)
            pdoc.docstrings.convert.cache_clear()
            try:
                pdoc.pdoc(*modules, output_directory=Path(dest))
            finally:
                pdoc.docstrings.rst = rst
                pdoc.docstrings.convert.cache_clear()
    return modules


def reference_chapter(modules: list[str], package_dir: Path | None = None) -> str:
    """The Markdown of the book page "Library reference": what the reference covers and one link
    per module to its pdoc page."""
    package_dir = Path(package_dir) if package_dir is not None else Path(__file__).resolve().parents[1]
    lines = ["# Library reference", "",
             "Generated with [pdoc](https://pdoc.dev) from the docstrings of the library: every module of",
             "`adaptfilt` except the reproduction pipeline (`adaptfilt.experiments`), the course",
             "(`adaptfilt.course`) and the command line (the layers are described in *Architecture and",
             "decisions*). Each page shows the signatures, the docstrings with their formulas, and the source.",
             "", "| module | what it holds |", "|---|---|"]
    for name in modules:
        parts = name.split(".")
        page = f"{REFERENCE_DIR}/{'/'.join(parts)}.html"
        path = package_dir.parent.joinpath(*parts)
        path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
        summary = _summary(path).replace("|", "\\|") if path.is_file() else ""
        lines.append(f"| [`{name}`]({page}) | {summary} |")
    return "\n".join(lines) + "\n"
