"""The course map: modules read from the notebooks' code, checked against Python's own imports."""
from __future__ import annotations

import importlib
import inspect
import json
from pathlib import Path

import numpy as np
import pytest

from adaptfilt.course.book import notebook_chapters
from adaptfilt.course.notebook_markdown import notebook_title
from adaptfilt.course.coursemap import course_map, course_map_svg, module_order, notebook_usage, plot_course_map

ROOT = Path(__file__).resolve().parent.parent


def nb(*cells: str, markdown: str = "# A chapter") -> dict:
    return {"cells": [{"cell_type": "markdown", "source": markdown}]
            + [{"cell_type": "code", "source": c, "outputs": []} for c in cells]}


def repo_chapters() -> list[tuple[str, str, dict]]:
    out = []
    for path in notebook_chapters(ROOT):
        notebook = json.loads(path.read_text(encoding="utf-8"))
        out.append((path.stem, notebook_title(notebook, path.stem), notebook))
    return out


# ---------------------------------------------------------------- one notebook


def test_alias_and_reexports_resolve_to_the_defining_module():
    usage = notebook_usage(nb("import adaptfilt as af\nf = af.UKF(af.models.ungm())\nk = af.KalmanFilter"))
    assert usage == {"gaf": ["UKF"], "models": ["ungm"], "exact": ["KalmanFilter"]}


def test_from_imports_follow_package_reexports():
    usage = notebook_usage(nb("from adaptfilt.experiment_registry import get_experiment, UNGM_KAPPA_GRID",
                              "from adaptfilt.mdp import FilterEnv, feature_names"))
    # mdp re-exports features' feature_names
    assert usage == {"experiment_registry": ["get_experiment", "UNGM_KAPPA_GRID"], "mdp": ["FilterEnv"],
                     "features": ["feature_names"]}


def test_module_imports_and_calls_on_them():
    usage = notebook_usage(nb("from adaptfilt.course import common\nfrom adaptfilt import style\nimport adaptfilt.plots",
                              "common.show_source(common.score)\nadaptfilt.plots.plot_rmse_bars\nstyle._private"))
    assert usage == {"course.common": ["show_source", "score"], "style": [], "plots": ["plot_rmse_bars"]}


def test_submodule_of_a_subpackage_through_attributes():
    usage = notebook_usage(nb("import adaptfilt as af\naf.experiments.report.fmt"))
    assert list(usage) == ["experiments", "experiments.report"]
    assert usage["experiments.report"] == ["fmt"]


def test_other_packages_magics_and_unbound_names_are_ignored():
    usage = notebook_usage(nb("%matplotlib inline\n!pip list\nimport numpy as np\nnp.linalg.norm\nmodels.ungm()",
                              "from adaptfilt.gaf import UKF\nUKF.run  # an attribute of a class, not a module"))
    assert usage == {"gaf": ["UKF"]}


def test_a_cell_that_does_not_parse_still_names_its_modules():
    usage = notebook_usage(nb("x = (\nadaptfilt.rules.UnscentedRule", "import adaptfilt as af\naf.UKF"))
    assert usage == {"rules": [], "gaf": ["UKF"]}


def test_markdown_is_not_code():
    assert notebook_usage(nb(markdown="# A chapter on `adaptfilt.rules`\n\nimport adaptfilt.rules")) == {}


def test_every_name_of_the_repo_notebooks_is_defined_where_the_map_says():
    # The reference is Python's import system: each (module, name) of the map must be an
    # attribute of that module, and a function or class must have been defined there (for a
    # sub-package such as rules: in one of its own modules, which its face exports).
    checked = 0
    for _, _, notebook in repo_chapters():
        for module, names in notebook_usage(notebook).items():
            mod = importlib.import_module(f"adaptfilt.{module}")
            for name in names:
                obj = getattr(mod, name)
                if inspect.isfunction(obj) or inspect.isclass(obj):
                    package = hasattr(mod, "__path__") and obj.__module__.startswith(mod.__name__ + ".")
                    assert obj.__module__ == mod.__name__ or package, (module, name, obj.__module__)
                checked += 1
    assert checked > 20


# ---------------------------------------------------------------- the course


def test_repo_map_has_every_notebook_in_order_and_uses_the_library():
    chapters = repo_chapters()
    cmap = course_map(chapters)
    assert [c.stem for c in cmap] == [p.stem for p in notebook_chapters(ROOT)]
    assert len(cmap) >= 9
    for chapter, (_, title, _) in zip(cmap, chapters):
        assert chapter.title == title
        assert chapter.modules, f"{chapter.stem}: no adaptfilt module found in its code"
    built = module_order(cmap)
    assert len(built) == len(set(built))  # each module is built once
    assert {"exact", "gaf", "rules", "mdp", "actor_critic"} <= set(built)
    assert "exact" in cmap[0].builds  # chapter 1 builds the exact references


def test_builds_is_first_use_and_uses_the_rest():
    cmap = course_map([("01-a", "A", nb("import adaptfilt as af\naf.UKF")),
                       ("02-b", "B", nb("import adaptfilt as af\naf.SIF\naf.rules.UnscentedRule")),
                       ("03-c", "C", nb("x = 1"))])
    assert [(c.builds, c.uses) for c in cmap] == [(("gaf",), ()), (("rules",), ("gaf",)), ((), ())]
    assert cmap[1].modules == {"gaf": ["SIF"], "rules": ["UnscentedRule"]}
    assert module_order(cmap) == ["gaf", "rules"]


def test_figure_marks_what_each_chapter_builds_and_uses():
    cmap = course_map([("01-a", "First chapter", nb("import adaptfilt as af\naf.UKF\naf.models.ungm")),
                       ("02-b", "Second chapter", nb("import adaptfilt as af\naf.UKF\naf.rules.UnscentedRule"))])
    fig = plot_course_map(cmap)
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_yticklabels()] == ["First chapter", "Second chapter"]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["gaf", "models", "rules"]
    filled, rings = set(), set()
    for line in ax.get_lines():
        x, y = line.get_xdata(), line.get_ydata()
        if len(x) != 1 or line.get_marker() != "o":
            continue
        (rings if line.get_markerfacecolor() == "white" else filled).add((int(x[0]), int(y[0])))
    assert filled == {(0, 0), (1, 0), (2, 1)}  # gaf and models built in chapter 1, rules in 2
    assert rings == {(0, 1)}  # gaf used again in chapter 2


def test_svg_is_reproducible_and_empty_map_is_refused():
    cmap = course_map([("01-a", "A", nb("import adaptfilt as af\naf.UKF"))])
    svg = course_map_svg(cmap)
    assert svg.lstrip().startswith(b"<?xml") and b"<svg" in svg
    assert svg == course_map_svg(cmap)
    assert b"<dc:date>" not in svg
    with pytest.raises(ValueError, match="at least one chapter"):
        plot_course_map([])


def test_long_titles_are_wrapped():
    title = "Parameter adaptation as a Markov decision problem, with a long subtitle"
    fig = plot_course_map(course_map([("01-a", title, nb("import adaptfilt as af\naf.UKF"))]))
    label = fig.axes[0].get_yticklabels()[0].get_text()
    assert label.replace("\n", " ") == title and max(map(len, label.split("\n"))) <= 34
    assert np.all(np.asarray(fig.get_size_inches()) > 0)


def test_relative_reexports_in_another_package_tree(tmp_path):
    package = tmp_path / "adaptfilt"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("from .core import Thing as Alias\nfrom . import sub\n")
    (package / "core.py").write_text("class Thing:\n    pass\n")
    (package / "sub" / "__init__.py").write_text("from ..core import Thing\n")
    usage = notebook_usage(nb("import adaptfilt as af\naf.Alias\naf.sub.Thing"), package_dir=package)
    assert usage == {"core": ["Thing"], "sub": []}
