"""The package's layers (docs/ARCHITECTURE.md), checked on its import graph.

Every ``import`` of an ``adaptfilt`` module counts, the lazy ones inside functions included:

* the library (``adaptfilt/*.py``) imports neither the reproduction pipeline
  (``adaptfilt/experiments/``) nor the course (``adaptfilt/course/``);
* the pipeline never imports the course;
* nothing inside the package imports its faces (``adaptfilt/__init__``: the library's public names;
  ``adaptfilt/cli.py``, ``adaptfilt/__main__.py``: the command line, which may import every layer);
  the package face itself imports the library only, eagerly or through its lazy list (``_LAZY``), and
  no other module imports by a computed name (``importlib.import_module``);
* the graph has no circle.
"""
import ast
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "adaptfilt"

LIBRARY, PIPELINE, COURSE, FACE = 0, 1, 2, 3
LAYER_NAMES = {LIBRARY: "library", PIPELINE: "pipeline (adaptfilt.experiments)", COURSE: "course (adaptfilt.course)",
               FACE: "command line"}
CLI = {"adaptfilt.cli", "adaptfilt.__main__"}


def modules() -> dict[str, Path]:
    """Every module of the package by dotted name (a package by its own name)."""
    mods = {}
    for p in PKG.rglob("*.py"):
        rel = p.relative_to(PKG.parent).with_suffix("")
        mods[".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)] = p
    return mods


def layer(module: str) -> int:
    if module in CLI:
        return FACE
    if module == "adaptfilt":
        return LIBRARY  # the face exports the library (checked apart: nothing imports it)
    if module.startswith("adaptfilt.experiments"):
        return PIPELINE
    if module.startswith("adaptfilt.course"):
        return COURSE
    return LIBRARY


def imports(path: Path, mods: dict[str, Path]) -> list[tuple[str, int]]:
    """The package modules ``path`` imports, anywhere in it, with the line: ``from adaptfilt.x import y``
    names ``adaptfilt.x.y`` where that is a module, else ``adaptfilt.x``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").split(".")[0] == "adaptfilt":
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                out.append((sub if sub in mods else node.module, node.lineno))
        elif isinstance(node, ast.Import):
            out.extend((a.name, node.lineno) for a in node.names if a.name.split(".")[0] == "adaptfilt")
        elif isinstance(node, ast.ImportFrom) and node.level:
            raise AssertionError(f"{path}:{node.lineno}: relative import (write the module's full name)")
    return out


def graph() -> dict[str, dict[str, int]]:
    mods = modules()
    return {m: {t: line for t, line in imports(p, mods) if t != m} for m, p in mods.items()}


def upward_imports() -> list[str]:
    """Every import that breaks the layer rule, as ``file:line: importer -> imported``."""
    bad = []
    mods = modules()
    for m, targets in graph().items():
        where = mods[m].relative_to(PKG.parent)
        for t, line in sorted(targets.items()):
            if t == "adaptfilt" or t in CLI:
                if not (m == "adaptfilt.__main__" and t == "adaptfilt.cli"):
                    bad.append(f"{where}:{line}: {m} -> {t} (a face: import the module that defines the name)")
            elif m == "adaptfilt" and layer(t) != LIBRARY:
                bad.append(f"{where}:{line}: the package face exports the library only, not {t}")
            elif layer(t) > layer(m):
                bad.append(f"{where}:{line}: {m} ({LAYER_NAMES[layer(m)]}) -> {t} ({LAYER_NAMES[layer(t)]})")
    return bad


def cycles() -> list[list[str]]:
    """The strongly connected sets of more than one module (Tarjan), the face left out."""
    g = {m: set(t) - {"adaptfilt"} for m, t in graph().items() if m != "adaptfilt"}
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(g.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            c = []
            while True:
                w = stack.pop()
                on.discard(w)
                c.append(w)
                if w == v:
                    break
            if len(c) > 1:
                out.append(sorted(c))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def dynamic_imports() -> list[str]:
    """What the ``import`` statements do not show: ``importlib.import_module`` / ``__import__`` anywhere
    but the face, and a name of the face's lazy list (``_LAZY``, loaded by its ``__getattr__``) that is
    not a library module."""
    bad, mods = [], modules()
    for m, path in mods.items():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and m != "adaptfilt" and (
                    (isinstance(node.func, ast.Attribute) and node.func.attr == "import_module")
                    or (isinstance(node.func, ast.Name) and node.func.id in ("import_module", "__import__"))):
                where = f"{path.relative_to(PKG.parent)}:{node.lineno}"
                bad.append(f"{where}: a dynamic import (write an import statement)")
            if m == "adaptfilt" and isinstance(node, ast.Assign) and any(
                    isinstance(t, ast.Name) and t.id == "_LAZY" for t in node.targets):
                for name in ast.literal_eval(node.value):
                    target = f"adaptfilt.{name}"
                    if target not in mods or target in CLI or layer(target) != LIBRARY:
                        bad.append(f"{path.relative_to(PKG.parent)}:{node.lineno}: the face loads {target} lazily"
                                   " (it exports the library only)")
    return bad


def test_dynamic_imports_load_the_library_only():
    assert dynamic_imports() == []


@pytest.mark.parametrize("edit", ["lazy-course", "import_module"])
def test_the_check_sees_a_dynamic_import(tmp_path, monkeypatch, edit):
    fake = tmp_path / "adaptfilt"
    for p in PKG.rglob("*.py"):
        q = fake / p.relative_to(PKG)
        q.parent.mkdir(parents=True, exist_ok=True)
        q.write_text(p.read_text())
    if edit == "lazy-course":
        face = (fake / "__init__.py").read_text()
        assert face.count("_LAZY = (") == 1
        (fake / "__init__.py").write_text(face.replace("_LAZY = (", '_LAZY = ("course", '))
    else:
        (fake / "zz_probe.py").write_text(
            'import importlib\n\ndef f():\n    return importlib.import_module("adaptfilt.course")\n')
    monkeypatch.setattr(sys.modules[__name__], "PKG", fake)
    bad = dynamic_imports()
    assert len(bad) == 1 and ("adaptfilt.course" in bad[0] if edit == "lazy-course" else "zz_probe" in bad[0])


def test_every_import_runs_downwards():
    bad = upward_imports()
    assert not bad, f"{len(bad)} imports against the layers (docs/ARCHITECTURE.md):\n" + "\n".join(bad)


def test_no_import_circle():
    assert not cycles()


def test_the_three_layers_are_folders():
    mods = modules()
    assert any(m.startswith("adaptfilt.experiments.") for m in mods)
    assert any(m.startswith("adaptfilt.course.") for m in mods)
    top = {m for m in mods if m.count(".") == 1 and not (PKG / m.split(".")[1]).is_dir()}
    assert "adaptfilt.gaf" in top and not top & {"adaptfilt.reproduce", "adaptfilt.artefacts", "adaptfilt.book"}


@pytest.mark.parametrize("source, expected", [
    ("from adaptfilt.experiments import report\n", "pipeline"),
    ("def f():\n    from adaptfilt.course import coursemap\n", "course"),
    ("import adaptfilt\n", "face"),
])
def test_the_check_sees_an_upward_import(tmp_path, monkeypatch, source, expected):
    """A library module that reaches up, even lazily inside a function, is reported."""
    fake = tmp_path / "adaptfilt"
    for p in PKG.rglob("*.py"):
        q = fake / p.relative_to(PKG)
        q.parent.mkdir(parents=True, exist_ok=True)
        q.write_text(p.read_text())
    (fake / "zz_probe.py").write_text(source)
    monkeypatch.setattr(sys.modules[__name__], "PKG", fake)
    bad = [b for b in upward_imports() if "zz_probe" in b]
    assert len(bad) == 1 and expected in bad[0]
