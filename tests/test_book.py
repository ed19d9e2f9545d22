"""The static book (adaptfilt.course.book): its pages and order, the build, and a real browser (the
converter, figure text and bibliography it uses: tests/test_notebook_markdown.py, test_figure_text.py,
test_bibliography.py).

The fixture notebooks live in tests/fixtures/book-notebooks as ``*.ipynb.json`` so that a
notebook test run (nbval) never collects them; the tests copy them to
``NN-*.ipynb`` in a temporary directory.

The browser tests drive one headless Chromium over the DevTools protocol
(tests/browser_cdp.py) through *every* page of the repository's book, at a phone's
width: no console error, MathJax finished without errors, every image loaded, no
text cut off. Chromium is required under CI=true and skipped without it elsewhere;
screenshots and Chromium's log go to build/book-test (a CI artefact).
"""
from __future__ import annotations

import ast
import functools
import html
import http.server
import json
import os
import re
import shutil
import threading
import time
import urllib.parse
import urllib.request
from html.parser import HTMLParser
from pathlib import Path

import pytest

from adaptfilt.course.book import (FRONT_PAGES, NOTEBOOK_DIR, BookBuildError, build_book, collect_chapters,
                                   notebook_chapters, notebook_link)
from adaptfilt.course.notebook_markdown import escape_math, notebook_title
from adaptfilt.cli import main as cli_main
from browser_cdp import Browser  # tests/browser_cdp.py

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "tests" / "fixtures" / "book-notebooks"
ARTEFACTS = ROOT / "build" / "book-test"  # git-ignored; CI keeps it as an artefact
IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")


# ---------------------------------------------------------------- the front pages and the order


def test_book_order_front_pages_after_the_introduction_bibliography_before_the_reference():
    chapters = collect_chapters(ROOT, reference_modules=["adaptfilt.gaf"])
    files = [c.filename for c in chapters]
    notebooks = [f"{p.stem}.md" for p in notebook_chapters(ROOT)]
    assert files == (["course-map.md", "introduction.md", "running.md", "notation.md", "deviations.md"] + notebooks
                     + ["reproduction.md", "architecture.md", "bibliography.md", "reference.md"])
    assert [c.numbered for c in chapters[:5]] == [False] * 5 and all(c.numbered for c in chapters[5:])
    assert [c.title for c in chapters[2:5]] == [t for _, t, _ in FRONT_PAGES]
    landing = chapters[0].markdown
    assert all(f"]({f})" in landing for _, _, f in FRONT_PAGES)


def test_front_pages_link_chapters_that_exist():
    """The front pages link chapters by their notebooks (which work on GitHub too); every link names a
    notebook of the repository and becomes a link to its chapter in the book."""
    chapters = {c.filename: c for c in collect_chapters(ROOT)}
    for source, _, filename in FRONT_PAGES:
        text = (ROOT / source).read_text(encoding="utf-8")
        links = re.findall(r"\]\(([^)#\s]+)", text)
        assert links, source
        for link in links:
            assert (ROOT / source).parent.joinpath(link).resolve().exists(), (source, link)
        assert ".ipynb" not in "".join(re.findall(r"\]\(([^)\s]+)", chapters[filename].markdown)), filename


def test_deviations_page_states_what_the_code_does():
    """The numbers of the deviations page that come from the code and the stored policies."""
    from adaptfilt.experiment_registry import CTM_KAPPA_GRID, SIF_ITER_GRID, UNGM_KAPPA_GRID, get_experiment
    from adaptfilt.experiments import artefacts
    from adaptfilt.features import FeatureSet
    from adaptfilt.trainers import FAST

    page = " ".join((ROOT / "docs" / "DEVIATIONS.md").read_text(encoding="utf-8").split())
    sizes = {}
    for name, features in (("ungm-ukf", "paper+time"), ("ctm-ukf", "paper+circ"), ("ctm-sif-nis", "paper+circ+innov@1")):
        exp = get_experiment(name)
        assert exp.features == features and f"`{features}`" in page
        sizes[name] = (FeatureSet.parse("paper").size(exp.make_model()), FeatureSet.parse(features).size(exp.make_model()))
    assert sizes == {"ungm-ukf": (5, 7), "ctm-ukf": (8, 9), "ctm-sif-nis": (8, 9)}
    assert "5 numbers on UNGM" in page and "7 inputs" in page and "9 inputs instead of the paper's 8" in page
    for grid in (UNGM_KAPPA_GRID, CTM_KAPPA_GRID, SIF_ITER_GRID):
        assert f"({len(grid)} values)" in page
    assert "10^4\\}" in page and "-3, -2, -1, -0.5, 0, 0.5, 1, 2, 5, 10, 20, 50\\}" in page
    rollout = FAST.n_envs * FAST.kwargs["n_steps"]
    assert f"{rollout} transitions" in page and rollout == 16384
    for name, steps in (("ungm-ukf", 500), ("ctm-ukf", 150)):
        stored = artefacts.stored_policy(name, "adaptive", 0).metadata["transitions"]
        assert stored == -(-1000 * steps // rollout) * rollout and f"{stored:,}" in page
    faithful = sorted(p.name for p in (artefacts.data_dir() / "policies").glob("*faithful*"))
    assert len(faithful) == 16 and not [n for n in faithful if "sif" in n]
    assert "16 in all" in page and "There are no faithful-trainer SIF policies" in page
    # the faithful trainer's departures from the printed Algorithm 2, as its policy files record them
    for name, features in (("ungm-ukf", "paper+time"), ("ctm-ukf", "paper+circ")):
        hyper = artefacts.stored_policy(name, "adaptive-faithful", 0).metadata["hyper"]
        assert hyper["features"] == features
        for key in ("actor_sign", "cost_transform", "scaler_visit", "scaler_squash", "bootstrap_at_limit"):
            assert f"`{key}: {hyper[key]}`" in page, key


# ---------------------------------------------------------------- the build


class _Pages(HTMLParser):
    """Collects <img src>, <script src> and <a href> of an HTML page."""

    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.scripts: list[str] = []
        self.links: list[str] = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "a" and attrs.get("href"):
            self.links.append(attrs["href"])
        if tag == "img" and attrs.get("src"):
            self.images.append(attrs["src"])
        if tag == "script" and attrs.get("src"):
            self.scripts.append(attrs["src"])


def _parse(page: Path) -> _Pages:
    parser = _Pages()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser


def _expected_pages(out: Path, notebooks: list[Path]) -> list[Path]:
    pages = [out / "index.html", out / "course-map.html", out / "introduction.html"]
    pages += [out / f"{nb.stem}.html" for nb in notebooks]
    if (ROOT / "REPRODUCTION.md").is_file():
        pages.append(out / "reproduction.html")
    if (ROOT / "docs" / "ARCHITECTURE.md").is_file():
        pages.append(out / "architecture.html")
    pages += [out / f"{Path(f).stem}.html" for src, _, f in FRONT_PAGES if (ROOT / src).is_file()]
    if any("## References" in nb.read_text(encoding="utf-8") for nb in notebooks):
        pages.append(out / "bibliography.html")
    return pages


def _check_built_book(out: Path, notebooks: list[Path]) -> None:
    """Every chapter page exists; every image is a file on disk; no remote script."""
    for page in _expected_pages(out, notebooks):
        assert page.is_file(), f"missing chapter page {page.name}"
    assert (out / "mathjax" / "MathJax.js").is_file()
    for page in out.glob("*.html"):
        parsed = _parse(page)
        for src in parsed.images:
            assert not re.match(r"^[a-z]+:", src), f"{page.name}: remote image {src}"
            assert (page.parent / html.unescape(src).split("#")[0]).is_file(), f"{page.name}: missing {src}"
        for src in parsed.scripts:
            assert not re.match(r"^(https?:)?//", src), f"{page.name}: loads {src} from the network"


@pytest.fixture(scope="module")
def fixture_notebooks(tmp_path_factory) -> list[Path]:
    folder = tmp_path_factory.mktemp("fixture-notebooks")
    for path in sorted(FIXTURES.glob("*.ipynb.json")):
        shutil.copy(path, folder / path.name.removesuffix(".json"))
    return sorted(folder.glob("*.ipynb"))


@pytest.fixture(scope="module")
def fixture_book(tmp_path_factory, fixture_notebooks) -> Path:
    out = tmp_path_factory.mktemp("fixture-book") / "book"
    build_book(out, root=ROOT, notebooks=fixture_notebooks)
    return out


@pytest.fixture(scope="module")
def repo_book(tmp_path_factory) -> tuple[Path, list[Path]]:
    """The book of the repository through the CLI, as users build it."""
    out = tmp_path_factory.mktemp("repo-book") / "book"
    assert cli_main(["book", "--out", str(out)]) == 0
    return out, notebook_chapters(ROOT)


def test_fixture_book_pages_and_images(fixture_book, fixture_notebooks):
    _check_built_book(fixture_book, fixture_notebooks)
    figures = sorted(p.name for p in (fixture_book / "figures").iterdir())
    assert len(figures) == 3 and "course-map.svg" in figures  # the fixture's PNG and SVG, and the map


def test_repo_book_pages_and_images(repo_book):
    out, notebooks = repo_book
    _check_built_book(out, notebooks)


def _broken_links(out: Path) -> list[str]:
    """Links of the book's pages to a file of the book (another chapter, the library reference's
    pages) that reach no file. 404.html is left out: its links start at a web server's root."""
    broken = []
    for page in sorted(out.glob("*.html")):
        if page.name == "404.html":
            continue
        for href in _parse(page).links:
            target = html.unescape(href).split("#")[0].split("?")[0]
            if target and not re.match(r"^[a-z]+:", target) and not (page.parent / target).is_file():
                broken.append(f"{page.name}: {href}")
    return broken


def test_links_between_pages_reach_files(repo_book, tmp_path):
    """No chapter (nor the navigation, the print page, the front pages) links to a page of the book,
    the library reference's included, that is not there. The check itself sees a broken link."""
    out, _ = repo_book
    assert _broken_links(out) == []
    (tmp_path / "reference" / "adaptfilt").mkdir(parents=True)
    (tmp_path / "reference" / "adaptfilt" / "gaf.html").write_text("<p>gaf</p>")
    (tmp_path / "ch.html").write_text('<a href="reference/adaptfilt/gaf.html#UKF">ok</a> <a href="https://x.org/a">web</a>'
                                      ' <a href="#top">here</a>'
                                      ' <a href="reference/adaptfilt/gaff.html">typo</a>')
    assert _broken_links(tmp_path) == ["ch.html: reference/adaptfilt/gaff.html"]


def test_every_chapter_page_links_its_notebook_which_the_book_ships(repo_book, served_book):
    """A reader who wants to run a chapter downloads its notebook from the page: the book holds each
    notebook as committed (outputs included), each chapter's page links it right under the title, and a
    web server hands it out byte for byte."""
    out, notebooks = repo_book
    for nb in notebooks:
        shipped = out / NOTEBOOK_DIR / nb.name
        assert shipped.read_bytes() == nb.read_bytes(), nb.name
        page = (out / f"{nb.stem}.html").read_text(encoding="utf-8")
        assert page.count(f'href="{NOTEBOOK_DIR}/{nb.name}"') == 1, nb.name
        md = (out.with_name(out.name + "-src") / f"{nb.stem}.md").read_text(encoding="utf-8").split("\n")
        title = next(i for i, line in enumerate(md) if line.startswith("# "))
        assert md[title + 2] == notebook_link(nb.name), nb.name  # right under the title
    with urllib.request.urlopen(f"{served_book}/{NOTEBOOK_DIR}/{notebooks[0].name}") as got:
        assert got.read() == notebooks[0].read_bytes()


def test_readme_links_to_the_architecture_page(repo_book):
    out, _ = repo_book
    intro = (out / "introduction.html").read_text(encoding="utf-8")
    assert 'href="architecture.html"' in intro and "docs/ARCHITECTURE.md\"" not in intro
    assert "Architecture and decisions" in (out / "architecture.html").read_text(encoding="utf-8")


def test_landing_page_is_the_first_page_with_the_course_map(repo_book):
    out, notebooks = repo_book
    src = out.with_name(out.name + "-src")
    summary = (src / "SUMMARY.md").read_text(encoding="utf-8")
    # The landing page, the introduction and the front pages come before the numbered chapters.
    front = [f"[{escape_math(t)}]({f})" for _, t, f in FRONT_PAGES]
    assert summary.split("\n")[2:8] == ["[Course map](course-map.md)", "[Introduction](introduction.md)", *front, ""]
    landing = (src / "course-map.md").read_text(encoding="utf-8")
    assert "](figures/course-map.svg)" in landing
    assert (out / "figures" / "course-map.svg").read_bytes().lstrip().startswith(b"<?xml")
    rows = [ln for ln in landing.splitlines() if ln.startswith("| [")]
    assert [re.search(r"\]\(([^)]+)\.md\)", r).group(1) for r in rows] == [nb.stem for nb in notebooks]
    for row in rows:  # every chapter builds or uses some part of the library
        assert "`" in row, row
    index = (out / "index.html").read_text(encoding="utf-8")
    assert "figures/course-map.svg" in index and "The course has" in index


def test_library_reference_is_built_and_linked(repo_book):
    """The navigation's "Library reference" page links one pdoc page per library module (none for the
    pipeline or the course); every link of those pages that stays in the book reaches a file; the
    pages load the book's MathJax, nothing from the network."""
    from adaptfilt.course.reference import library_modules

    out, _ = repo_book
    summary = (out.with_name(out.name + "-src") / "SUMMARY.md").read_text(encoding="utf-8")
    assert "- [Library reference](reference.md)" in summary.splitlines()
    links = [h for h in _parse(out / "reference.html").links if h.startswith("reference/")]
    modules = library_modules()
    assert {"adaptfilt.gaf", "adaptfilt.rules", "adaptfilt.rules.stochastic", "adaptfilt.mdp"} <= set(modules)
    assert not [m for m in modules if m.startswith(("adaptfilt.experiments", "adaptfilt.course", "adaptfilt.cli"))]
    assert sorted(links) == sorted("reference/" + m.replace(".", "/") + ".html" for m in modules)
    pages = sorted((out / "reference").rglob("*.html"))
    assert not [p for p in pages if p.stem in ("experiments", "course", "cli")]
    for page in [out / "reference.html", *pages]:
        parsed = _parse(page)
        for src in parsed.scripts:
            assert not re.match(r"^(https?:)?//", src), f"{page}: loads {src} from the network"
            assert (page.parent / src.split("?")[0]).is_file(), f"{page}: missing script {src}"
        for href in parsed.links:
            target = html.unescape(href).split("#")[0]
            if not target or re.match(r"^[a-z]+:", target):
                continue
            assert (page.parent / target).is_file(), f"{page.relative_to(out)}: broken link {href}"


def test_simple_tables_become_markdown_tables():
    """pdoc leaves reST simple tables as a paragraph of ``=`` signs; the reference converts them."""
    from adaptfilt.course.reference import simple_tables_to_markdown

    text = ("Intro.\n\n====  =========\nname  what\n====  =========\n``a``   one\n      two | three\n"
            "``b`` four\n====  =========\n\nAfter ====  ==== stays.")
    assert simple_tables_to_markdown(text).split("\n") == [
        "Intro.", "", "| name | what |", "| --- | --- |", "| ``a`` | one two \\| three |", "| ``b`` | four |", "",
        "After ====  ==== stays."]
    headless = simple_tables_to_markdown("  ===  ===\n  x    y\n  ===  ===")
    assert headless.split("\n") == ["  |  |  |", "  | --- | --- |", "  | x | y |"]
    unclosed = "===  ===\nx    y\n\nz"
    assert simple_tables_to_markdown(unclosed) == unclosed


def _library_docstrings():
    from adaptfilt.course.reference import library_modules

    for module in library_modules():
        path = ROOT.joinpath(*module.split("."))
        path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                doc = ast.get_docstring(node)
                if doc:
                    yield f"{path.relative_to(ROOT)}:{getattr(node, 'name', 'module')}", doc


def test_library_docstrings_render_in_the_reference():
    """What pdoc would show wrongly: a ``.. math::`` block with a blank line inside (pdoc puts its parts
    in separate paragraphs between one pair of ``$$``, which MathJax leaves raw; write one directive per
    formula), and a reST table the converter does not handle (it would stay a paragraph of ``=``)."""
    from adaptfilt.course.reference import _BORDER, simple_tables_to_markdown

    split_maths, tables = [], []
    for where, doc in _library_docstrings():
        for block in re.finditer(r"^([ \t]*)\.\. math::[ \t]*\n((?:\1[ \t]+\S.*\n|[ \t]*\n)*)", doc + "\n", flags=re.M):
            if re.search(r"\S.*\n[ \t]*\n[ \t]*\S", block.group(2)):
                split_maths.append(where)
        if any(_BORDER.match(line) for line in simple_tables_to_markdown(doc).split("\n")):
            tables.append(where)
    assert split_maths == [] and tables == []


def test_landing_page_without_notebooks(tmp_path):
    (tmp_path / "repo").mkdir()
    (tmp_path / "repo" / "book.toml").write_text((ROOT / "book.toml").read_text(encoding="utf-8"))
    build_book(tmp_path / "out", root=tmp_path / "repo", notebooks=[])
    page = (tmp_path / "out" / "index.html").read_text(encoding="utf-8")
    assert "No course notebooks" in page and "course-map.svg" not in page
    assert (tmp_path / "out" / "introduction.html").is_file()


def test_maths_reaches_the_html_exactly(fixture_book):
    # What MathJax reads is the page text: it must be the notebook's TeX, delimited.
    text = html.unescape(re.sub(r"<[^>]+>", "", (fixture_book / "01-fixture.html").read_text()))
    for tex in (r"\hat x_{k|k-1} = f(x_{k-1})", r"W_0 = \kappa/(n+\kappa)", "a*b*c", r"a\,b"):
        assert f"\\({tex}\\)" in text
    assert r"(\mathcal{Z}_i - z)^\top \\" + "\nS &= P_{zz} + R" in text
    assert "A price of $5" in text and "echo $HOME" in text


def test_unknown_output_html_key_fails_the_build(tmp_path):
    root = tmp_path / "repo"
    root.mkdir()
    config = (ROOT / "book.toml").read_text(encoding="utf-8")
    (root / "book.toml").write_text(config.replace("[output.html]\n", "[output.html]\nbogus-key = 1\n", 1))
    with pytest.raises(BookBuildError, match="bogus-key"):
        build_book(tmp_path / "out", root=root, notebooks=[])


def test_top_level_config_disables_the_cdn_mathjax():
    config = (ROOT / "book.toml").read_text(encoding="utf-8")
    assert re.search(r"^mathjax-support\s*=\s*false", config, flags=re.M)


# ---------------------------------------------------------------- a real browser

# One headless Chromium (tests/browser_cdp.py) visits every page of the built book
# in one tab. The probe waits until MathJax has typeset the page, every image has
# loaded or failed and (print.html) the print call has happened, then reports
# what a reader would see. Console errors are collected by the DevTools protocol.
_PROBE = r"""
(function () {
  var root = document.documentElement, started = Date.now();
  var mathjax = !!document.querySelector('script[src*="MathJax.js"]');
  var printPage = /\/print\.html$/.test(location.pathname);
  function ready() {
    return (!mathjax || root.getAttribute("data-mathjax") === "done")
      && Array.prototype.every.call(document.images, function (i) { return i.complete; })
      && (!printPage || root.hasAttribute("data-printed"));
  }
  function describe(e) {
    var text = (e.textContent || "").trim().replace(/\s+/g, " ").slice(0, 50).replace(/[\ud800-\udfff]/g, "?");
    var cls = typeof e.className === "string" && e.className ? "." + e.className.trim().split(/\s+/).join(".") : "";
    return "<" + e.tagName.toLowerCase() + cls + "> \"" + text + "\"";
  }
  // Text a reader cannot see or scroll to: content larger than a box that hides its
  // overflow, or anything reaching past the right edge of <main> outside a box that
  // scrolls sideways (mdBook's page clips it).
  var scrollers = [];
  function clipped(main) {
    var found = [], edge = main.getBoundingClientRect().right + 1;
    function check(e, inScroller) {
      // MathJax's screen-reader copy is hidden by design; a formula is checked as one box.
      if (e.matches(".MJX_Assistive_MathML, script, style")) return;
      var s = getComputedStyle(e);
      if (s.display === "none" || s.visibility === "hidden" || e.getClientRects().length === 0) return;
      var hidesX = s.overflowX === "hidden" || s.overflowX === "clip";
      var hidesY = s.overflowY === "hidden" || s.overflowY === "clip";
      var scrolls = s.overflowX === "auto" || s.overflowX === "scroll";
      if (hidesX && e.scrollWidth > e.clientWidth + 1)
        found.push(describe(e) + " cuts off content " + e.scrollWidth + " px wide at " + e.clientWidth + " px");
      if (hidesY && e.scrollHeight > e.clientHeight + 1)
        found.push(describe(e) + " cuts off content " + e.scrollHeight + " px high at " + e.clientHeight + " px");
      if (scrolls && e.scrollWidth > e.clientWidth + 1) scrollers.push(e);
      if (!inScroller) {
        // Text is no element: a box whose overflow shows reaches as far as its scrollWidth.
        var box = e.getBoundingClientRect();
        var right = scrolls || hidesX ? box.right : Math.max(box.right, box.left + e.scrollWidth);
        if (right > edge) {
          found.push(describe(e) + " runs past the column (" + Math.round(right) + " > " + Math.round(edge) + " px)");
          return;  // the outermost box that runs past is enough
        }
      }
      if (e.matches(".MathJax, .MathJax_Display")) return;
      for (var c = e.firstElementChild; c; c = c.nextElementSibling) check(c, inScroller || scrolls);
    }
    for (var c = main.firstElementChild; c; c = c.nextElementSibling) check(c, false);
    return found;
  }
  // What MathJax's TeX input made of a formula it could not read: an undefined macro becomes red text
  // (the noUndefined extension: an <mtext mathcolor="red">), a TeX error an <merror> (noErrors). Both
  // are found in the typeset formulas' MathML trees, whatever the output looks like.
  function mathErrors() {
    if (!window.MathJax || !MathJax.Hub || !MathJax.Hub.getAllJax) return [];
    var found = [];
    MathJax.Hub.getAllJax().forEach(function (jax) {
      (function walk(node) {
        if (!node || typeof node !== "object") return;
        if (node.type === "merror")
          found.push("TeX error in " + JSON.stringify(jax.originalText.trim().slice(0, 80)));
        else if (node.type === "mtext" && node.mathcolor === "red")
          found.push("undefined macro " + JSON.stringify(node.data.join("")) + " in "
                     + JSON.stringify(jax.originalText.trim().slice(0, 80)));
        (node.data || []).forEach(walk);
      })(jax.root);
    });
    return found;
  }
  function report() {
    var main = document.querySelector("main") || document.body;
    var visible = main.cloneNode(true);
    visible.querySelectorAll("pre, code, script, style, .MathJax, .MathJax_Display, .MathJax_Preview, .MJX_Assistive_MathML")
      .forEach(function (e) { e.remove(); });
    return {
      waited: Date.now() - started,
      mathjax: mathjax,
      typeset: root.getAttribute("data-mathjax"),
      printed: root.getAttribute("data-printed"),
      rendered: main.querySelectorAll(".MathJax, .MathJax_Display").length,
      errors: main.querySelectorAll(".MathJax_Error, .noError, merror").length,
      mathErrors: mathErrors(),
      text: visible.innerText,
      images: Array.prototype.map.call(document.images, function (i) {
        return {src: i.getAttribute("src"), width: i.naturalWidth};
      }),
      clipped: clipped(main),
      scrolls: scrollers.map(describe),  // boxes wider than the column that scroll sideways
      notebooks: Array.prototype.map.call(main.querySelectorAll('a[href$=".ipynb"]'), function (a) {
        return {href: a.getAttribute("href"), url: a.href};  // as written, and as the browser resolved it
      })
    };
  }
  return new Promise(function (resolve) {
    (function poll() {
      if (ready() || Date.now() - started > 240000) { resolve(report()); } else { setTimeout(poll, 50); }
    })();
  });
})()
"""
# print.html calls window.print(): record when instead of opening a dialog. The
# book's MathJax configuration wraps this stand-in, as it wraps the real one.
_PRINT_SPY = """
window.print = function () {
  var root = document.documentElement;
  root.setAttribute("data-printed", root.getAttribute("data-mathjax") || "before MathJax had typeset the page");
};
"""
PHONE = (412, 915)  # CSS pixels: where text is cut off first, so every page is checked at this width
DESKTOP = (1280, 1600)  # the screenshots


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    if IN_CI:
        pytest.fail("chromium is required in CI (apt-get install chromium)")
    pytest.skip("chromium not installed (apt-get install chromium); required under CI=true")


def _chromium_args(user_dir: Path) -> list[str]:
    return [
        _chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
        "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", f"--user-data-dir={user_dir}",
        # No name resolves: the page can only use what the book ships (404.html is served from 127.0.0.1).
        "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
    ]


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    """One headless Chromium for the module's browser tests (its log goes to the test artefacts)."""
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    # generous bounds: this checks that MathJax finishes, not how fast (print.html typesets the whole book:
    # over 90 s on two cores shared with other work)
    with Browser(_chromium_args(tmp_path_factory.mktemp("chromium")), log=ARTEFACTS / "chromium.log",
                 timeout=300) as b:
        b.add_init_script(_PRINT_SPY)
        b.set_viewport(*PHONE)
        yield b


@pytest.fixture(scope="module")
def served_book(repo_book):
    """The repository's book over HTTP at the server root, as a web host serves it."""
    out, _ = repo_book

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(out)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def _problems(page: str, visit: dict) -> list[str]:
    """What is wrong with a page as the browser showed it (empty: nothing)."""
    seen, problems = visit["value"], [f"{page}: console: {e}" for e in visit["errors"]]
    if not seen["mathjax"]:
        problems.append(f"{page}: does not load the book's MathJax")
    elif seen["typeset"] != "done":
        problems.append(f"{page}: MathJax did not finish in {seen['waited']} ms")
    if seen["errors"]:
        problems.append(f"{page}: {seen['errors']} MathJax errors")
    problems += [f"{page}: MathJax: {m}" for m in seen.get("mathErrors", [])]
    text = seen["text"]
    for raw in ("\\(", "\\)", "\\[", "\\]", "\\begin{", "$$", "Math Processing Error"):
        if raw in text:
            problems.append(f"{page}: raw {raw!r} left in the visible text")
    if re.search(r"\$[^$\s][^$\n]*[^$\s]\$", text):
        problems.append(f"{page}: raw $..$ maths left in the visible text")
    problems += [f"{page}: image {i['src']} did not load" for i in seen["images"] if not i["width"]]
    problems += [f"{page}: {c}" for c in seen["clipped"]]
    if page == "print.html" and seen["printed"] != "done":
        problems.append(f"print.html: printed when MathJax was {seen['printed']!r}, not done")
    return problems


def _visit(browser: Browser, url: str, screenshot: str | None = None) -> dict:
    shot = None
    if screenshot:
        ARTEFACTS.mkdir(parents=True, exist_ok=True)
        shot = ARTEFACTS / screenshot
    return browser.visit(url, _PROBE, screenshot=shot)


def test_browser_renders_fixture_maths_and_figures(browser, fixture_book):
    page = fixture_book / "01-fixture.html"
    browser.set_viewport(*DESKTOP)
    try:
        visit = _visit(browser, page.as_uri(), screenshot="fixture-chapter.png")
    finally:
        browser.set_viewport(*PHONE)
    assert _problems(page.name, visit) == []
    seen = visit["value"]
    assert seen["rendered"] >= 7  # title, five inline formulas, the aligned display
    assert len(seen["images"]) >= 2
    assert "A price of $5" in seen["text"]
    assert (ARTEFACTS / "fixture-chapter.png").stat().st_size > 10_000


def test_browser_wide_content_scrolls_or_wraps(browser, fixture_book):
    # The second fixture chapter holds a long code line, a wide text output, a wide
    # table, a wide display formula and a long inline one: all must stay readable.
    visit = _visit(browser, (fixture_book / "02-second.html").as_uri())
    assert _problems("02-second.html", visit) == []
    scrolls = visit["value"]["scrolls"]
    # Each wide thing is wider than the phone's column and scrolls (else this test proves nothing).
    for box in ("<div.MathJax_Display>", "<code.language-python", "<code.language-text", "<div.nb-output"):
        assert any(s.startswith(box) for s in scrolls), (box, scrolls)


def test_browser_probe_sees_clipped_text(browser, tmp_path):
    # The check itself: a box that hides its overflow and a line that runs past the page are found.
    page = tmp_path / "clipped.html"
    page.write_text(
        "<html><body><main style='width:300px'>"
        "<pre style='overflow:hidden;width:100px'>" + "x" * 200 + "</pre>"
        "<p style='white-space:nowrap'>" + "word " * 200 + "</p>"
        "<div style='overflow-x:auto'><p style='white-space:nowrap'>" + "fine " * 200 + "</p></div>"
        "<img src='missing.png' alt='gone'>"
        "<script>console.error('deliberate error'); undefinedFunction();</script>"
        "</main></body></html>", encoding="utf-8")
    visit = _visit(browser, page.as_uri())
    problems = _problems(page.name, visit)
    clipped = visit["value"]["clipped"]
    assert len(clipped) == 2, clipped
    assert "cuts off content" in clipped[0] and "<pre>" in clipped[0]
    assert "runs past the column" in clipped[1] and "<p>" in clipped[1]
    assert any("deliberate error" in p for p in problems)
    assert any("undefinedFunction" in p for p in problems)
    assert any("missing.png" in p and "console" in p for p in problems)  # the failed request
    assert any("image missing.png did not load" in p for p in problems)


def test_browser_probe_sees_math_errors(browser, fixture_book):
    # The check itself: an undefined macro (MathJax shows it in red) and a TeX error are found, a good
    # formula is not; on a page of the fixture book, with the book's MathJax and its configuration.
    page = fixture_book / "bad-maths.html"
    chapter = (fixture_book / "01-fixture.html").read_text(encoding="utf-8")
    start, end = chapter.index("<main>") + len("<main>"), chapter.index("</main>")
    page.write_text(chapter[:start] + r"<p>\(x \undefinedmacro 1\)</p><p>\(\frac{1}{\)</p><p>\(a \le b\)</p>"
                    + chapter[end:], encoding="utf-8")
    try:
        problems = _problems(page.name, _visit(browser, page.as_uri()))
    finally:
        page.unlink()
    maths = [p for p in problems if "MathJax: " in p]
    assert len(maths) == 2, problems
    assert 'undefined macro "\\\\undefinedmacro"' in maths[0] + maths[1], maths
    assert any("TeX error in" in p and "frac" in p for p in maths), maths


def test_browser_every_page_of_the_book(browser, repo_book, served_book):
    """Every page: no console error, MathJax done without an error or an undefined macro, every image
    loaded, no text cut off; and every chapter's page links its own notebook, which the browser
    resolves (from ``file://``, offline) to a file the book ships."""
    out, notebooks = repo_book
    pages = sorted(p.name for p in out.glob("*.html"))
    assert set(p.name for p in _expected_pages(out, notebooks)) <= set(pages)
    problems, timings = [], []
    chapter_pages = {f"{nb.stem}.html": nb.name for nb in notebooks}
    for name in pages:
        # 404.html is written for a web server (its links start at the site root).
        url = f"{served_book}/{name}" if name == "404.html" else (out / name).as_uri()
        started = time.monotonic()
        visit = _visit(browser, url)
        problems += _problems(name, visit)
        if name in chapter_pages:
            links = visit["value"]["notebooks"]
            want = f"{NOTEBOOK_DIR}/{chapter_pages[name]}"
            if [a["href"] for a in links] != [want]:
                problems.append(f"{name}: links the notebooks {[a['href'] for a in links]}, not {want}")
            elif not Path(urllib.request.url2pathname(urllib.parse.urlparse(links[0]["url"]).path)).is_file():
                problems.append(f"{name}: its notebook link {links[0]['url']} reaches no file")
        timings.append(f"{time.monotonic() - started:6.1f} s  {name}")
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    (ARTEFACTS / "browser-pages.txt").write_text("\n".join(timings) + "\n", encoding="utf-8")
    assert problems == []


def test_browser_landing_page_shows_the_course_map(browser, repo_book):
    out, notebooks = repo_book
    browser.set_viewport(*DESKTOP)
    try:
        visit = _visit(browser, (out / "index.html").as_uri(), screenshot="repo-landing.png")
    finally:
        browser.set_viewport(*PHONE)
    seen = visit["value"]
    assert _problems("index.html", visit) == []
    # mdBook shows each image twice (the page and its click-to-zoom copy)
    assert {i["src"] for i in seen["images"]} == {"figures/course-map.svg"}
    assert seen["images"][0]["width"] > 300
    for nb in notebooks:  # every chapter, under its title, in the map's table
        title = notebook_title(json.loads(nb.read_text(encoding="utf-8")), nb.stem)
        assert title in seen["text"], title


def test_out_dir_that_is_not_a_book_is_refused(tmp_path):
    # mdBook empties its destination: a typo in --out must not delete someone's files.
    (tmp_path / "precious.txt").write_text("keep me")
    with pytest.raises(BookBuildError, match="not a built book"):
        build_book(tmp_path, root=ROOT, notebooks=[])
    with pytest.raises(BookBuildError, match="contains the repository"):
        build_book(ROOT, root=ROOT, notebooks=[])
    assert (tmp_path / "precious.txt").read_text() == "keep me"


def test_browser_reference_typesets_formulas(browser, repo_book):
    """A page of the library reference with formulas (the moment rules): MathJax (the book's copy)
    typesets them without an error or an undefined macro, and the page logs no console error."""
    out, _ = repo_book
    browser.set_viewport(*DESKTOP)
    try:
        visit = _visit(browser, (out / "reference" / "adaptfilt" / "rules.html").as_uri())
    finally:
        browser.set_viewport(*PHONE)
    seen = visit["value"]
    assert visit["errors"] == [] and seen["mathjax"] and seen["typeset"] == "done", (visit["errors"], seen["typeset"])
    assert seen["rendered"] >= 3 and seen["errors"] == 0 and seen["mathErrors"] == []


def test_browser_every_page_of_the_library_reference(browser, repo_book):
    """Every pdoc page of the library reference, checked as the book's own pages are (at a phone's
    width): no console error, MathJax done without an error or an undefined macro, no raw TeX left in
    the text (a ``.. math::`` block split into paragraphs), no text cut off (a docstring's table)."""
    from adaptfilt.course.reference import library_modules

    out, _ = repo_book
    # pdoc's index.html is a bare redirect to adaptfilt.html
    pages = sorted(p for p in (out / "reference").rglob("*.html") if p.name != "index.html")
    assert pages and len(pages) == len(library_modules())
    problems, timings, formulas = [], [], 0
    for page in pages:
        name = str(page.relative_to(out))
        started = time.monotonic()
        visit = _visit(browser, page.as_uri())
        timings.append(f"{time.monotonic() - started:6.1f} s  {name}")
        formulas += visit["value"]["rendered"]
        problems += _problems(name, visit)
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    (ARTEFACTS / "browser-reference-pages.txt").write_text("\n".join(timings) + "\n", encoding="utf-8")
    assert problems == []
    assert formulas >= 50  # 74 formulas in the library's docstrings when this was written
