"""The static book: the notebook -> mdBook converter, the build, and a real browser.

The fixture notebooks live in tests/fixtures/book-notebooks as ``*.ipynb.json`` so that a
notebook test run (nbval) never collects them; the tests copy them to
``NN-*.ipynb`` in a temporary directory.
"""
from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

from adaptfilt.book import (
    BookBuildError,
    build_book,
    escape_math,
    notebook_chapters,
    notebook_to_markdown,
    rewrite_links,
    rewrite_math,
)
from adaptfilt.cli import main as cli_main

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "tests" / "fixtures" / "book-notebooks"
ARTEFACTS = ROOT / "build" / "book-test"  # git-ignored; CI keeps it as an artefact
IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")


def fixture_nb(name: str = "01-fixture") -> dict:
    return json.loads((FIXTURES / f"{name}.ipynb.json").read_text(encoding="utf-8"))


# ---------------------------------------------------------------- maths


def test_inline_math_is_delimited_and_escaped():
    assert rewrite_math("mean $x_{k|k-1}$ here") == r"mean \\(x\_\{k\|k\-1\}\\) here"


def test_display_math_doubles_tex_newlines():
    # `\\` (TeX line break) must reach MathJax as `\\`: in Markdown it is `\\\\`.
    assert rewrite_math("$$a \\\\ b$$") == r"\\[a \\\\ b\\]"


def test_thin_space_star_and_underscore_survive_commonmark():
    assert rewrite_math(r"$a\,b*c_1$") == r"\\(a\\\,b\*c\_1\\)"


def test_escape_math_escapes_all_punctuation_only():
    assert escape_math(r"\alpha + 2") == r"\\alpha \+ 2"


def test_escaped_dollar_stays_text():
    assert rewrite_math(r"costs \$5 or \$6") == r"costs \$5 or \$6"


def test_amounts_are_not_maths():
    assert rewrite_math("between $5 and $10") == "between $5 and $10"


def test_unclosed_dollar_stays_text():
    assert rewrite_math("a $x and more") == "a $x and more"


def test_code_spans_are_untouched():
    text = "run `echo $HOME` or ``a `$x$` b`` then $y$"
    assert rewrite_math(text) == "run `echo $HOME` or ``a `$x$` b`` then \\\\(y\\\\)"


def test_fenced_code_is_untouched():
    text = "```bash\necho $x$ $$y$$\n```\n~~~~\n$z$\n~~~~\nafter $w$\n"
    assert rewrite_math(text) == "```bash\necho $x$ $$y$$\n```\n~~~~\n$z$\n~~~~\nafter \\\\(w\\\\)\n"


def test_equation_environment_is_emitted_bare():
    # \[ \begin{align} \] is an error in MathJax 2: the environment must stand alone.
    assert rewrite_math(r"$$\begin{align}a&=b\end{align}$$") == r"\\begin\{align\}a\&\=b\\end\{align\}"


def test_aligned_stays_inside_display_maths():
    assert rewrite_math(r"$$\begin{aligned}a\end{aligned}$$").startswith(r"\\[\\begin\{aligned\}")


def test_bare_environment_is_escaped():
    assert rewrite_math("\\begin{equation}x_1\\end{equation}") == r"\\begin\{equation\}x\_1\\end\{equation\}"


def test_inline_maths_does_not_cross_paragraphs():
    assert rewrite_math("a $x\n\ny$ b") == "a $x\n\ny$ b"


# ---------------------------------------------------------------- notebooks


@pytest.fixture(scope="module")
def converted() -> tuple[str, dict[str, bytes]]:
    return notebook_to_markdown(fixture_nb(), "figures/fx", {"02-second.ipynb": "02-second.md"})


def test_cell_tags_are_honoured(converted):
    md, _ = converted
    assert "VISIBLE-OUTPUT-MARKER" in md  # remove-input keeps the output
    assert "HIDDEN-INPUT-MARKER" not in md
    assert "VISIBLE-INPUT-MARKER" in md  # remove-output keeps the input
    assert "HIDDEN-OUTPUT-MARKER" not in md
    assert "HIDDEN-CELL-MARKER" not in md  # remove-cell drops both


def test_nbval_markers_are_dropped(converted):
    md, _ = converted
    assert "NBVAL" not in md
    assert "import matplotlib.pyplot as plt" in md


def test_figures_are_extracted_and_referenced(converted):
    md, files = converted
    pngs = [n for n in files if n.endswith(".png")]
    svgs = [n for n in files if n.endswith(".svg")]
    assert len(pngs) == 1 and len(svgs) == 1
    assert files[pngs[0]].startswith(b"\x89PNG\r\n\x1a\n")
    assert files[svgs[0]].lstrip().startswith(b"<svg")
    for name in files:
        assert f"]({name})" in md
    assert "base64" not in md and "iVBOR" not in md


def test_widget_dropped_text_fallback_kept(converted):
    md, _ = converted
    assert "widget-view" not in md and "model_id" not in md
    assert "3/3" in md


def test_html_output_is_one_html_block(converted):
    md, _ = converted
    block = re.search(r'<div class="nb-output nb-html">\n(.*?)\n</div>', md, flags=re.S)
    assert block and "<table" in block.group(1)
    assert "\n\n" not in block.group(0)  # a blank line would end the HTML block


def test_text_outputs_are_fenced_and_ansi_free(converted):
    md, _ = converted
    assert "```text\nhello from stdout\n```" in md
    assert "ZeroDivisionError: division by zero" in md and "\x1b" not in md


def test_links_to_notebooks_point_at_chapters(converted):
    md, _ = converted
    assert "](02-second.md)" in md
    assert rewrite_links("[x](../notebooks/03-a.ipynb#s) [y](https://e.org/03-a.ipynb)",
                         {"notebooks/03-a.ipynb": "03-a.md"}) == "[x](03-a.md#s) [y](https://e.org/03-a.ipynb)"


def test_stream_progress_keeps_last_state():
    nb = {"cells": [{"cell_type": "code", "source": "x", "metadata": {}, "outputs": [
        {"output_type": "stream", "name": "stderr", "text": "\r 10%|#\r100%|##########|\n"}]}]}
    md, _ = notebook_to_markdown(nb, "f")
    assert "100%|##########|" in md and "10%|#\n" not in md


def test_fence_is_longer_than_backticks_inside():
    nb = {"cells": [{"cell_type": "code", "source": "s = '```'", "metadata": {}, "outputs": []}]}
    md, _ = notebook_to_markdown(nb, "f")
    assert md.startswith("````python\n")


# ---------------------------------------------------------------- the build


class _Pages(HTMLParser):
    """Collects <img src> and <script src> of an HTML page."""

    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.scripts: list[str] = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img" and attrs.get("src"):
            self.images.append(attrs["src"])
        if tag == "script" and attrs.get("src"):
            self.scripts.append(attrs["src"])


def _parse(page: Path) -> _Pages:
    parser = _Pages()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser


def _expected_pages(out: Path, notebooks: list[Path]) -> list[Path]:
    pages = [out / "index.html", out / "introduction.html"]
    pages += [out / f"{nb.stem}.html" for nb in notebooks]
    if (ROOT / "REPRODUCTION.md").is_file():
        pages.append(out / "reproduction.html")
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
    assert len(list((fixture_book / "figures").iterdir())) == 2


def test_repo_book_pages_and_images(repo_book):
    out, notebooks = repo_book
    _check_built_book(out, notebooks)


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

# Injected into a copy of a chapter page: after MathJax's queue has run,
# write what the page shows into <pre id="book-probe"> for --dump-dom.
_PROBE = r"""
<script>
window.addEventListener("load", function () {
  function report() {
    var main = document.querySelector("main");
    var visible = main.cloneNode(true);
    visible.querySelectorAll("pre, code, script, .MathJax, .MathJax_Display, .MathJax_Preview, mjx-container")
      .forEach(function (e) { e.remove(); });
    var out = document.createElement("pre");
    out.id = "book-probe";
    out.textContent = JSON.stringify({
      typeset: document.documentElement.getAttribute("data-mathjax"),
      rendered: main.querySelectorAll(".MathJax, .MathJax_Display, mjx-container").length,
      errors: main.querySelectorAll(".MathJax_Error, .noError, merror, [data-mjx-error]").length,
      text: visible.innerText,
      images: Array.prototype.map.call(main.querySelectorAll("img"), function (i) {
        return {src: i.getAttribute("src"), width: i.naturalWidth};
      })
    });
    document.body.appendChild(out);
  }
  if (window.MathJax && MathJax.Hub) { MathJax.Hub.Queue(report); } else { report(); }
});
</script>
"""


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
        # No name resolves: the page can only use what the book ships.
        "--host-resolver-rules=MAP * ~NOTFOUND", "--virtual-time-budget=15000",
    ]


def _probe(page: Path, tmp: Path) -> dict:
    """Open ``page`` in headless Chromium and return what the probe saw."""
    probe = page.with_name(f"probe-{page.name}")
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    proc = subprocess.run(
        [*_chromium_args(tmp / "chromium-dom"), "--dump-dom", probe.as_uri()],
        capture_output=True, text=True, timeout=180, check=False,
    )
    m = re.search(r'<pre id="book-probe">(.*?)</pre>', proc.stdout, flags=re.S)
    assert m, f"probe did not report (exit {proc.returncode}):\n{proc.stderr[-3000:]}"
    return json.loads(html.unescape(m.group(1)))


def _screenshot(page: Path, tmp: Path, name: str) -> Path:
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    target = ARTEFACTS / name
    subprocess.run(
        [*_chromium_args(tmp / "chromium-shot"), "--window-size=1280,1600", f"--screenshot={target}", page.as_uri()],
        capture_output=True, timeout=180, check=False,
    )
    return target


def _assert_rendered(seen: dict, page: str) -> None:
    assert seen["typeset"] == "done", f"{page}: MathJax did not finish"
    assert seen["errors"] == 0, f"{page}: MathJax errors"
    text = seen["text"]
    for raw in ("\\(", "\\)", "\\[", "\\]", "\\begin{", "$$"):
        assert raw not in text, f"{page}: raw {raw!r} left in the visible text"
    assert not re.search(r"\$[^$\s][^$\n]*[^$\s]\$", text), f"{page}: raw $..$ maths left"
    assert "Math Processing Error" not in text
    for image in seen["images"]:
        assert image["width"] > 0, f"{page}: figure {image['src']} did not load"


def test_browser_renders_fixture_maths_and_figures(fixture_book, tmp_path):
    page = fixture_book / "01-fixture.html"
    seen = _probe(page, tmp_path)
    _assert_rendered(seen, page.name)
    assert seen["rendered"] >= 7  # title, five inline formulas, the aligned display
    assert len(seen["images"]) >= 2
    assert "A price of $5" in seen["text"]
    shot = _screenshot(page, tmp_path, "fixture-chapter.png")
    assert shot.is_file() and shot.stat().st_size > 10_000


def test_browser_renders_repo_chapters(repo_book, tmp_path):
    out, notebooks = repo_book
    pages = [out / f"{nb.stem}.html" for nb in notebooks] or [out / "introduction.html"]
    for page in pages:
        seen = _probe(page, tmp_path)
        _assert_rendered(seen, page.name)
    _screenshot(pages[0], tmp_path, "repo-first-chapter.png")


def test_out_dir_that_is_not_a_book_is_refused(tmp_path):
    # mdBook empties its destination: a typo in --out must not delete someone's files.
    (tmp_path / "precious.txt").write_text("keep me")
    with pytest.raises(BookBuildError, match="not a built book"):
        build_book(tmp_path, root=ROOT, notebooks=[])
    with pytest.raises(BookBuildError, match="contains the repository"):
        build_book(ROOT, root=ROOT, notebooks=[])
    assert (tmp_path / "precious.txt").read_text() == "keep me"
