"""The package's layers (docs/ARCHITECTURE.md), checked on its import graph.

Every ``import`` of an ``adaptfilt`` module counts, the lazy ones inside functions included:

* the library (``adaptfilt/*.py``) imports neither the reproduction pipeline
  (``adaptfilt/experiments/``) nor the course (``adaptfilt/course/``);
* the pipeline never imports the course;
* nothing inside the package imports its faces (``adaptfilt/__init__``: the library's public names;
  ``adaptfilt/cli.py``, ``adaptfilt/__main__.py``: the command line, which may import every layer);
  the package face itself imports the library only, eagerly or through its lazy list (``_LAZY``), and
  no other module imports by a computed name (``importlib.import_module``);
* the graph has no circle;
* inside the library, four sub-layers (:data:`SUBLAYERS`): **core** (models, filters, rules, metrics, costs)
  imports none of the others; **decision** (the parameter MDP, its environments, features, policies, the
  registry) imports the core only; **evaluation** (the Monte-Carlo engine, results, seed statistics,
  figures) and **learning** (policy files, the trainers, the Gymnasium wrapper: torch) import the core and
  the decision layer, never each other (evaluation does not load torch);
* ``import adaptfilt`` loads no heavy dependency (torch, matplotlib, numba, the particle filter).
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

#: The library's sub-layers by module (``adaptfilt.<name>``; a package stands for its modules).
SUBLAYERS = {
    "core": ("_version", "linalg", "linalg_kernels", "models", "filters", "rules", "gaf", "metrics", "exact", "particles",
             "particle_kernels", "files", "style", "costs"),
    "decision": ("paramenv", "features", "policies", "mdp", "particle_env", "toy", "lookahead", "experiment_registry"),
    "evaluation": ("runs", "evaluation", "results", "seed_stats", "verdicts", "plots"),
    "learning": ("nets", "anchor", "learned", "actor_critic", "gym", "trainers", "distill", "imitation", "kalmannet", "gainnets"),
}
#: What each sub-layer never imports.
NEVER = {"core": {"decision", "evaluation", "learning"}, "decision": {"evaluation", "learning"},
         "evaluation": {"learning"}, "learning": {"evaluation"}}


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


def sublayer(module: str) -> str | None:
    name = module.split(".")[1] if module.count(".") else None
    return next((k for k, names in SUBLAYERS.items() if name in names), None)


def sublayer_breaches() -> list[str]:
    """Every import inside the library that breaks a sub-layer's "never", as ``file:line: a (x) -> b (y)``."""
    bad, mods = [], modules()
    for m, targets in graph().items():
        if layer(m) != LIBRARY or m == "adaptfilt" or m in CLI:
            continue
        for t, line in sorted(targets.items()):
            if t in mods and layer(t) == LIBRARY and sublayer(t) in NEVER.get(sublayer(m), ()):
                bad.append(f"{mods[m].relative_to(PKG.parent)}:{line}: {m} ({sublayer(m)}) -> {t} ({sublayer(t)})")
    return bad


def test_every_library_module_has_a_sublayer():
    mods = modules()
    lost = sorted(m for m in mods if layer(m) == LIBRARY and m != "adaptfilt" and m not in CLI and sublayer(m) is None)
    assert not lost, f"add {lost} to SUBLAYERS (and to the library's map in docs/ARCHITECTURE.md)"


def test_the_library_sublayers_hold():
    bad = sublayer_breaches()
    assert not bad, f"{len(bad)} imports against the library's sub-layers:\n" + "\n".join(bad)


@pytest.mark.parametrize("probe, source, expected", [
    ("gaf", "def f():\n    from adaptfilt.mdp import FilterEnv\n", "(core) -> adaptfilt.mdp (decision)"),
    ("evaluation", "from adaptfilt.learned import load_policy\n", "(evaluation) -> adaptfilt.learned (learning)"),
    ("learned", "from adaptfilt.results import Results\n", "(learning) -> adaptfilt.results (evaluation)"),
])
def test_the_check_sees_a_sublayer_breach(tmp_path, monkeypatch, probe, source, expected):
    fake = tmp_path / "adaptfilt"
    for p in PKG.rglob("*.py"):
        q = fake / p.relative_to(PKG)
        q.parent.mkdir(parents=True, exist_ok=True)
        q.write_text(p.read_text())
    (fake / f"{probe}.py").write_text((fake / f"{probe}.py").read_text() + "\n" + source)
    monkeypatch.setattr(sys.modules[__name__], "PKG", fake)
    bad = [b for b in sublayer_breaches() if b.startswith(f"adaptfilt/{probe}.py")]
    assert len(bad) == 1 and expected in bad[0], bad


def _imports_of(path: Path) -> set[str]:
    return {t for t, _ in imports(path, modules())}


def test_filter_does_not_import_the_mdp():
    """The filter registers nothing from the MDP built on it (the MDP registers its episode loop with the filter)."""
    assert not any(i.startswith("adaptfilt.mdp") for i in _imports_of(PKG / "gaf.py"))
    for rules in sorted((PKG / "rules").glob("*.py")):
        assert not any(i.startswith(("adaptfilt.mdp", "adaptfilt.gaf")) for i in _imports_of(rules))


def test_import_adaptfilt_loads_no_heavy_dependency():
    """``import adaptfilt`` (every command-line run, every worker) loads numpy, scipy's linear algebra, the
    Gaussian-assumed filters and the parameter MDP; torch, matplotlib, scipy.stats (about a second of import
    time on a 2-core machine) and the particle filter with its compiled kernels (numba) load when first used."""
    import subprocess

    heavy = ("torch", "matplotlib", "numba", "scipy.stats", "adaptfilt.particles", "adaptfilt.particle_kernels")
    code = f"import sys, adaptfilt; print(' '.join(m for m in {heavy!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
    # and the particle filter does load where it is used
    code = ("import sys, adaptfilt; adaptfilt.experiment_registry.get_experiment('ungm-pf-1e-3').make_env(); "
            "print('adaptfilt.particles' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "True"


def private_imports(root: Path = PKG) -> list[str]:
    """``from adaptfilt.X import _name`` where ``_name`` is private to another module: a name with a leading
    underscore is that module's own. The moment rules' package (``adaptfilt.rules``) shares its base
    helpers among siblings, one package, as the review allows; a public name imported under a private
    alias (``import colors as _colors``) is no breach."""
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("adaptfilt")):
                continue
            inside_rules = path.parent.name == "rules" and node.module.startswith("adaptfilt.rules")
            for a in node.names:
                if a.name.startswith("_") and not a.name.startswith("__") and not inside_rules:
                    found.append(f"{path.relative_to(root.parent)}: from {node.module} import {a.name}")
    return found


def test_no_private_name_crosses_a_module():
    assert not private_imports()


def test_the_check_sees_a_private_import(tmp_path):
    pkg = tmp_path / "adaptfilt"
    (pkg / "course").mkdir(parents=True)
    (pkg / "course" / "a.py").write_text("from adaptfilt.course.common import _ax\n")
    (pkg / "b.py").write_text("from adaptfilt.style import colors as _colors\n")
    assert private_imports(pkg) == ["adaptfilt/course/a.py: from adaptfilt.course.common import _ax"]


#: What a user reads: the library, its tests and benchmarks, the documents and what the commands wrote into data/.
READ_BY_USERS = ("adaptfilt", "tests", "benchmarks", "docs", "README.md", "REPRODUCTION.md", "data")


def internal_issue_numbers(root: Path = PKG.parent) -> list[str]:
    """Lines that cite the project's internal issue tracker by number (the word "issue" and a number), which a
    user cannot look up: a text names the study or the decision instead."""
    import re

    pattern = re.compile(r"issues? [0-9]+", re.IGNORECASE)
    found = []
    for top in READ_BY_USERS:
        base = root / top
        files = [base] if base.is_file() else sorted(p for p in base.rglob("*") if p.suffix in (".py", ".md", ".json"))
        for p in files:
            for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1):
                if pattern.search(line):
                    found.append(f"{p.relative_to(root)}:{i}: {line.strip()[:100]}")
    return found


def test_no_internal_issue_numbers_in_what_a_user_reads():
    assert not internal_issue_numbers()


def test_the_issue_check_sees_one(tmp_path):
    (tmp_path / "docs").mkdir()
    cited = "as decided in Issue " + "12, item 3"  # written apart: this file is checked too
    (tmp_path / "docs" / "a.md").write_text(f"fine\n{cited}\n")
    assert internal_issue_numbers(tmp_path) == [f"docs/a.md:2: {cited}"]


def long_functions(root: Path, limit: int = 80) -> list[str]:
    """Functions (methods and nested ones too, docstrings included) longer than ``limit`` lines under ``root``."""
    found = []
    for p in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno + 1 > limit:
                found.append(f"{p.relative_to(root.parent)}:{node.lineno} {node.name} "
                             f"({node.end_lineno - node.lineno + 1} lines)")
    return found


def test_no_function_of_the_pipeline_is_over_80_lines():
    """The pipeline reads top to bottom: a step that grows past 80 lines is split into named parts."""
    assert not long_functions(PKG / "experiments")


# ------------------------------------------------------------------ one place each
_RNG_CALLS = {"default_rng", "SeedSequence", "Generator", "PCG64", "Philox"}


def _call_name(node: ast.Call) -> str:
    f = node.func
    return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""


def one_place_breaches(root: Path = PKG) -> list[str]:
    """Code outside its one place: the evaluation's runs' seed (``TRAJ_SEED_KEY`` in a generator) outside
    ``adaptfilt/runs.py``, a point-mass filter built (for a Bayes floor) outside ``exact.bayes_floor``."""
    bad = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent).as_posix()
        tree = ast.parse(path.read_text())
        floor = {id(n) for f in ast.walk(tree) if isinstance(f, ast.FunctionDef) and f.name == "bayes_floor"
                 and rel == "adaptfilt/exact.py" for n in ast.walk(f)}
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            name = _call_name(node)
            if name in _RNG_CALLS and rel != "adaptfilt/runs.py" and any(
                    isinstance(n, (ast.Name, ast.Attribute)) and "TRAJ_SEED_KEY" in (getattr(n, "id", None), getattr(n, "attr", None))
                    for a in [*node.args, *(k.value for k in node.keywords)] for n in ast.walk(a)):
                bad.append(f"{rel}:{node.lineno}: the evaluation's runs re-derived ({name} with TRAJ_SEED_KEY): "
                           "use adaptfilt.runs (EvalRuns, trajectory_rng, bootstrap_counts)")
            if name == "PointMassFilter" and id(node) not in floor:
                bad.append(f"{rel}:{node.lineno}: a point-mass filter built outside exact.bayes_floor: use the one floor")
    return bad


def test_the_runs_seed_and_the_bayes_floor_each_have_one_place():
    bad = one_place_breaches()
    assert not bad, "\n".join(bad)


def test_the_one_place_check_sees_a_copy(tmp_path):
    pkg = tmp_path / "adaptfilt"
    (pkg / "experiments").mkdir(parents=True)
    (pkg / "exact.py").write_text("def bayes_floor(model):\n    return PointMassFilter(model)\n")
    (pkg / "runs.py").write_text("import numpy as np\nTRAJ_SEED_KEY = 1\nrng = np.random.default_rng([TRAJ_SEED_KEY, 0])\n")
    (pkg / "experiments" / "floor.py").write_text(
        "import numpy as np\nfrom adaptfilt import runs\n\ndef f(model, seed):\n"
        "    traj = model.simulate(9, rng=np.random.default_rng([runs.TRAJ_SEED_KEY, seed]))\n"
        "    return PointMassFilter(model).run(traj.z)\n")
    assert one_place_breaches(pkg) == [
        "adaptfilt/experiments/floor.py:5: the evaluation's runs re-derived (default_rng with TRAJ_SEED_KEY): use "
        "adaptfilt.runs (EvalRuns, trajectory_rng, bootstrap_counts)",
        "adaptfilt/experiments/floor.py:6: a point-mass filter built outside exact.bayes_floor: use the one floor"]
