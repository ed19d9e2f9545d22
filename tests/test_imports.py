"""The package's import graph: eager (module-level) imports are acyclic, and the filter does not
import the MDP built on it (the MDP registers its episode loop with the filter instead), and `import adaptfilt`
loads no heavy dependency."""
import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "adaptfilt"


def _imports(path: Path, top_level_only: bool) -> set[str]:
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    out = set()
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("adaptfilt"):
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("adaptfilt"))
    return out


def _modules() -> dict[str, Path]:
    mods = {}
    for p in PKG.rglob("*.py"):
        rel = p.relative_to(PKG.parent).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        mods[name] = p
    return mods


def test_eager_imports_are_acyclic():
    mods = _modules()
    graph = {m: {i for i in _imports(p, True) if i in mods and i != m} for m, p in mods.items()}
    graph["adaptfilt"] = set()  # the package namespace re-exports; its submodules never need it eagerly
    state: dict[str, int] = {}

    def visit(m, stack):
        state[m] = 1
        for n in graph.get(m, ()):
            if state.get(n) == 1:
                raise AssertionError("import cycle: " + " -> ".join(stack + [m, n]))
            if not state.get(n):
                visit(n, stack + [m])
        state[m] = 2

    for m in graph:
        if not state.get(m):
            visit(m, [])


def test_filter_does_not_import_the_mdp():
    assert not any(i.startswith("adaptfilt.mdp") for i in _imports(PKG / "gaf.py", top_level_only=False))
    for rules in sorted((PKG / "rules").glob("*.py")):  # the rules package
        assert not any(i.startswith(("adaptfilt.mdp", "adaptfilt.gaf")) for i in _imports(rules, False))


def test_import_adaptfilt_loads_no_heavy_dependency():
    """``import adaptfilt`` (every command-line run, every worker) loads numpy, scipy's linear algebra and the
    filters; torch, matplotlib, numba (the compiled kernels) and scipy.stats (about a second of import time on a
    2-core machine) load when first used."""
    import subprocess
    import sys

    code = ("import sys, adaptfilt; print(' '.join(m for m in ('torch', 'matplotlib', 'numba', 'scipy.stats', "
            "'adaptfilt.particle_kernels') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
