r"""The course map: which chapter builds which part of the library, read from the notebooks.

The map is derived, never written by hand, so that it stays true when a
chapter is rewritten, renamed or added. For every course notebook
(``notebooks/NN-*.ipynb``) :func:`notebook_usage` parses the code cells with
:mod:`ast` and collects the ``adaptfilt`` modules the chapter imports or calls,
with the names it uses from each::

    import adaptfilt as af                 ->  (nothing yet: the package itself)
    af.UKF(model)                          ->  gaf: UKF        (af re-exports it from gaf)
    af.models.ungm()                       ->  models: ungm
    from adaptfilt.mdp import FilterEnv    ->  mdp: FilterEnv
    from adaptfilt.course import bayes     ->  course.bayes
    from adaptfilt.rules import UnscentedRule  ->  rules: UnscentedRule  (a sub-package's face: the package)
    from adaptfilt.seed_stats import iqm   ->  seed_stats: iqm

A name is traced to the module that *defines* it by reading the package's
sources (``from x import y`` re-exports are followed, except a sub-package's face over its
own modules), so ``adaptfilt`` is not
imported and nothing is executed. :func:`course_map` puts the chapters in
reading order and marks, for each module, the chapter that uses it first: the
chapter that *builds* it; later chapters *use* it again.
:func:`plot_course_map` draws the map as one figure (chapters down, modules
across) and :func:`course_map_svg` renders it reproducibly for the book.

Example
-------
>>> nb = {"cells": [{"cell_type": "code", "source": "import adaptfilt as af\nukf = af.UKF(af.models.ungm())"}]}
>>> notebook_usage(nb)
{'gaf': ['UKF'], 'models': ['ungm']}
"""
from __future__ import annotations

import ast
import io
import re
import textwrap
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping, Sequence

__all__ = ["ChapterUsage", "notebook_usage", "course_map", "plot_course_map", "course_map_svg"]

PACKAGE = "adaptfilt"
_PACKAGE_DIR = Path(__file__).resolve().parents[1]  # adaptfilt/ (this module is in adaptfilt/course/)
# IPython-only lines (magics, shell escapes, help) are not Python: blank them before parsing.
_IPYTHON_LINE = re.compile(r"^\s*(%|!|\?)|\?\s*$")
# Used on a cell that still does not parse: the modules named in it, without the names.
_DOTTED = re.compile(r"\b" + PACKAGE + r"((?:\.[A-Za-z_]\w*)+)")


@dataclass(frozen=True)
class ChapterUsage:
    """One chapter of the map.

    ``modules`` maps a module (dotted, without the ``adaptfilt.`` prefix) to
    the names the chapter uses from it, in order of first use; ``builds`` are
    the modules no earlier chapter uses, ``uses`` the others (both in the
    order of ``modules``).
    """

    stem: str
    title: str
    modules: dict[str, list[str]]
    builds: tuple[str, ...]
    uses: tuple[str, ...]


# ---------------------------------------------------------------- the package, statically


class _Package:
    """Where the names of a package are defined, read from its source files."""

    def __init__(self, directory: Path, name: str = PACKAGE) -> None:
        self.directory = directory
        self.name = name

    def _file(self, module: str) -> Path | None:
        parts = module.split(".")
        if parts[0] != self.name:
            return None
        base = self.directory.joinpath(*parts[1:])
        for candidate in (base / "__init__.py", base.with_suffix(".py")):
            if candidate.is_file():
                return candidate
        return None

    def is_module(self, module: str) -> bool:
        return self._file(module) is not None

    @lru_cache(maxsize=None)
    def _tree(self, module: str) -> ast.Module | None:
        path = self._file(module)
        if path is None:
            return None
        try:
            return ast.parse(path.read_text(encoding="utf-8"))
        except SyntaxError:
            return None

    def _absolute(self, module: str, node: ast.ImportFrom) -> str:
        """The absolute module of ``from ... import`` inside ``module``."""
        if not node.level:
            return node.module or ""
        path = self._file(module)
        package = module if path is not None and path.name == "__init__.py" else module.rpartition(".")[0]
        for _ in range(node.level - 1):
            package = package.rpartition(".")[0]
        return f"{package}.{node.module}" if node.module else package

    def resolve(self, module: str, name: str, depth: int = 0) -> tuple[str, str | None]:
        """``(defining module, name)`` of ``module.name``; ``(submodule, None)`` if it is a module."""
        if self.is_module(f"{module}.{name}"):
            return f"{module}.{name}", None
        tree = self._tree(module)
        if tree is None or depth > 10:
            return module, name
        for node in _top_level(tree.body):
            if isinstance(node, ast.ImportFrom):
                source = self._absolute(module, node)
                for alias in node.names:
                    if (alias.asname or alias.name) == name and source.split(".")[0] == self.name:
                        face = module != self.name and self._file(module).name == "__init__.py"
                        if face and source.startswith(module + "."):
                            return module, name  # a sub-package's face over its own modules (rules): the package
                        return self.resolve(source, alias.name, depth + 1)
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.asname == name and alias.name.split(".")[0] == self.name:
                        return alias.name, None
        return module, name


def _top_level(body: list[ast.stmt]):
    """The statements of a module body, looking into top-level ``if`` and ``try`` blocks."""
    for node in body:
        yield node
        if isinstance(node, (ast.If, ast.Try)):
            yield from _top_level(node.body + node.orelse + getattr(node, "finalbody", []))
            for handler in getattr(node, "handlers", []):
                yield from _top_level(handler.body)


# ---------------------------------------------------------------- a notebook


def _cell_source(cell: Mapping[str, Any]) -> str:
    source = cell.get("source", "")
    source = source if isinstance(source, str) else "".join(source)
    return "\n".join("" if _IPYTHON_LINE.search(line) else line for line in source.splitlines())


def _chain(node: ast.AST) -> list[str] | None:
    """``a.b.c`` -> ``["a", "b", "c"]``; None for anything that is not a dotted name."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    return [node.id, *reversed(parts)]


def notebook_usage(nb: Mapping[str, Any], package_dir: Path | None = None) -> dict[str, list[str]]:
    """The ``adaptfilt`` modules a notebook's code imports or calls, with the names it uses.

    Returns ``{module: [name, ...]}`` with modules written without the
    ``adaptfilt.`` prefix (``"gaf"``, ``"course.common"``), in order of
    first use; a module used only as a whole (``from adaptfilt.course import common``)
    maps to the names called on it (``common.score`` -> ``["score"]``), or to
    ``[]``. The package itself is not a module of the map. ``package_dir`` is
    the ``adaptfilt`` source tree to resolve names in (default: this one).

    Cells are read in order, so an alias (``import adaptfilt as af``) holds
    from its cell on; a cell that is not valid Python even with IPython lines
    (``%magic``, ``!shell``) blanked contributes the modules its text names.
    """
    package = _Package(package_dir or _PACKAGE_DIR)
    uses: dict[str, list[str]] = {}
    bound: dict[str, tuple[str, str | None]] = {}  # local name -> (module, name or None for a module)

    def record(module: str, name: str | None) -> None:
        if module == PACKAGE or not module.startswith(PACKAGE + "."):
            return
        names = uses.setdefault(module[len(PACKAGE) + 1:], [])
        if name and not name.startswith("_") and name not in names:
            names.append(name)

    for cell in nb.get("cells", []):
        if cell.get("cell_type") != "code":
            continue
        source = _cell_source(cell)
        try:
            tree = ast.parse(source)
        except SyntaxError:
            for m in _DOTTED.finditer(source):
                module, parts = PACKAGE, m.group(1).split(".")[1:]
                while parts and package.is_module(f"{module}.{parts[0]}"):
                    module = f"{module}.{parts.pop(0)}"
                record(module, None)
            continue
        nodes = sorted((n for n in ast.walk(tree) if hasattr(n, "lineno")),
                       key=lambda n: (n.lineno, n.col_offset, -getattr(n, "end_col_offset", 0)))
        for node in nodes:
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.split(".")[0] != PACKAGE:
                        continue
                    record(alias.name, None)
                    if alias.asname:
                        bound[alias.asname] = (alias.name, None)
                    else:  # `import adaptfilt.plots` binds `adaptfilt`
                        bound[PACKAGE] = (PACKAGE, None)
            elif isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").split(".")[0] == PACKAGE:
                for alias in node.names:
                    if alias.name == "*":
                        record(node.module, None)
                        continue
                    module, name = package.resolve(node.module, alias.name)
                    record(module, name)
                    bound[alias.asname or alias.name] = (module, name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load):
                chain = _chain(node)
                binding = bound.get(chain[0]) if chain else None
                if binding is None or binding[1] is not None:  # not a name bound to an adaptfilt module
                    continue
                module = binding[0]
                for attr in chain[1:]:
                    module, name = package.resolve(module, attr)
                    record(module, name)
                    if name is not None:
                        break
    return uses


# ---------------------------------------------------------------- the course


def course_map(chapters: Sequence[tuple[str, str, Mapping[str, Any]]],
               package_dir: Path | None = None) -> list[ChapterUsage]:
    """The map of a course: ``chapters`` are ``(stem, title, notebook)`` in reading order."""
    seen: set[str] = set()
    out = []
    for stem, title, nb in chapters:
        modules = notebook_usage(nb, package_dir)
        builds = tuple(m for m in modules if m not in seen)
        uses = tuple(m for m in modules if m in seen)
        seen.update(modules)
        out.append(ChapterUsage(stem, title, modules, builds, uses))
    return out


def module_order(cmap: Sequence[ChapterUsage]) -> list[str]:
    """The modules of the map in the order the course first uses them."""
    return [m for chapter in cmap for m in chapter.builds]


def plot_course_map(cmap: Sequence[ChapterUsage], wrap: int = 34):
    """The course map as one figure: chapters down (reading order), modules across.

    A filled dot marks the chapter that builds a module (the first to use it),
    a ring each later chapter that uses it again; the filled dots form the
    staircase of what the course adds, chapter by chapter. Chapter titles are
    wrapped at ``wrap`` characters. Returns the matplotlib ``Figure``.
    """
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI backend

    if not cmap:
        raise ValueError("the course map needs at least one chapter")
    modules = module_order(cmap)
    column = {m: j for j, m in enumerate(modules)}
    labels = [textwrap.fill(c.title, wrap) for c in cmap]
    lines = sum(label.count("\n") + 1 for label in labels)
    width = 2.6 + 0.30 * max(len(modules), 4)
    height = 1.5 + 0.22 * lines + 0.12 * len(cmap)
    fig = Figure(figsize=(width, height), layout="constrained")
    ax = fig.add_subplot()
    color_build, color_use = "#0072B2", "#0072B2"  # Okabe-Ito blue, as adaptfilt.style
    for i, chapter in enumerate(cmap):
        ax.axhline(i, color="0.85", lw=0.6, zorder=0)
        for m in chapter.builds:
            ax.plot(column[m], i, "o", ms=9, color=color_build, zorder=3)
        for m in chapter.uses:
            ax.plot(column[m], i, "o", ms=7, mfc="white", mec=color_use, mew=1.4, zorder=3)
    for j in range(len(modules)):
        ax.axvline(j, color="0.92", lw=0.6, zorder=0)
    ax.set_xlim(-0.6, max(len(modules), 1) - 0.4)
    ax.set_ylim(len(cmap) - 0.5, -0.5)
    ax.set_yticks(range(len(cmap)), labels, fontsize=9)
    ax.set_xticks(range(len(modules)), modules, rotation=55, ha="left", rotation_mode="anchor", fontsize=9)
    ax.xaxis.tick_top()
    ax.tick_params(length=0)
    ax.grid(False)
    for side in ax.spines.values():
        side.set_visible(False)
    handles = [ax.plot([], [], "o", ms=9, color=color_build, label="builds (first use)")[0],
               ax.plot([], [], "o", ms=7, mfc="white", mec=color_use, mew=1.4, label="uses again")[0]]
    fig.legend(handles=handles, loc="outside lower center", ncols=2, frameon=False, fontsize=9)
    return fig


def course_map_svg(cmap: Sequence[ChapterUsage]) -> bytes:
    """:func:`plot_course_map` as SVG bytes, identical for identical maps (no date, fixed ids)."""
    import matplotlib

    fig = plot_course_map(cmap)
    buffer = io.StringIO()
    with matplotlib.rc_context({"svg.hashsalt": "adaptfilt-course-map", "svg.fonttype": "path"}):
        fig.savefig(buffer, format="svg", metadata={"Date": None})
    return buffer.getvalue().encode("utf-8")
