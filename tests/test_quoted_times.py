"""Every wall or CPU time that README.md, REPRODUCTION.md and docs/RUNNING.md quote is read from the file that
recorded it (``adaptfilt.course.quoted_times``; its docstring has the syntax and the rounding rule).

A time figure either declares its record (``<!-- time: mean cpu of data/timings.json:policies/ungm-ukf-*.npz -->``)
and says it at the figure's precision, or is declared as not a record of the current code: a historical
measurement with the commit it was made at (``<!-- times from 066ae30: 1994 206 (...) -->``), or not a
measurement at all (``<!-- times not measured: 30 (the issue's target) -->``). Those two declarations are the
allow-list: they sit beside the figures they exempt, name each of them and say why, and
``test_the_allow_list_is_explicit`` prints them all. When the records change (a re-run of the pipeline),
``python -c "from adaptfilt.course.quoted_times import fixed; ..."`` rewrites the digit figures in place
(``test_fixed_rewrites_what_a_new_record_changed``).
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
from datetime import datetime, timedelta
from decimal import Decimal
from pathlib import Path

import pytest

from adaptfilt.course import quoted_times as qt

ROOT = Path(__file__).resolve().parents[1]
DOCS = ["README.md", "REPRODUCTION.md", "docs/RUNNING.md"]
#: The record files the documents may name (and the self-tests perturb).
RECORDS = ["data/timings.json", "data/medium/timings.json", "data/retrain/timings.json", "data/manifest.json", "data/beyond/manifest.json"]
TOTAL = "wall of data/retrain/timings.json:total"  # what `adaptfilt reproduce --retrain` costs at full scale, today
MEDIUM = "wall of data/medium/timings.json:total"


def _text(doc: str) -> str:
    return (ROOT / doc).read_text(encoding="utf-8")


@pytest.mark.parametrize("doc", DOCS)
def test_every_time_a_document_quotes_is_its_record(doc):
    bad = qt.problems(_text(doc), ROOT)
    assert not bad, (f"{doc}: time figures that differ from their record or declare none (fix the figure, "
                     "declare its record, or declare it historical / not measured):\n" + "\n".join(map(str, bad)))


def test_the_allow_list_is_explicit():
    """Every exempt figure is named by a declaration with a reason; a historical one by a commit of this
    repository (checked where git and the history are there)."""
    listed = []
    for doc in DOCS:
        for d in qt.declarations(_text(doc)):
            if d.kind == "record":
                continue
            assert d.names, f"{doc}:{d.line}: an exemption names no figure"
            assert re.fullmatch(r"\(.+\)", d.body, re.S), f"{doc}:{d.line}: an exemption without its reason in ()"
            if d.kind == "historical":
                assert re.fullmatch(r"[0-9a-f]{7,40}", d.commit), f"{doc}:{d.line}: {d.commit!r} is not a commit"
            listed.append(f"{doc}:{d.line}: {d.kind} {d.commit} {' '.join(d.names)} {d.body}")
    print("\n".join(listed))
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("no git history to check the commits against")
    for doc in DOCS:
        for line, commit in qt.commits(_text(doc)):
            p = subprocess.run(["git", "cat-file", "-e", f"{commit}^{{commit}}"], cwd=ROOT, capture_output=True)
            if p.returncode and subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT,
                                               capture_output=True, text=True).stdout.strip() == "true":
                pytest.skip("a shallow clone: the commits of the historical figures are not in it")
            assert p.returncode == 0, f"{doc}:{line}: no commit {commit} in this repository"


def test_the_generated_tables_are_the_recorded_ones():
    """The checker does not read REPRODUCTION.md's generated part because it is written from the records:
    it is ``data/report-tables.md`` verbatim, whose stage table is ``data/timings.json``."""
    text = _text("REPRODUCTION.md")
    begin, end = qt.GENERATED
    block = text[text.index(begin) + len(begin):text.index(end)].strip()
    assert block == (ROOT / "data" / "report-tables.md").read_text(encoding="utf-8").strip()
    stages = json.loads((ROOT / "data" / "timings.json").read_text())["timings"]
    for stage, t in stages.items():
        assert f"| {stage} | {t['wall_time_s']:.0f} | {t['cpu_time_s']:.0f} |" in block, stage


def test_the_retrain_cost_the_commands_quote_is_the_recorded_one():
    """Outside a checkout ``adaptfilt reproduce`` cannot read data/timings.json, so its error message quotes
    the cost (``RETRAIN_COST``); it, the command's help and the scale's comment say the record."""
    from adaptfilt.experiments.reproduce import RETRAIN_COST

    quotes = [(RETRAIN_COST, TOTAL)]
    cli = (ROOT / "adaptfilt" / "cli.py").read_text()
    for scale, spec in (("full", TOTAL), ("medium", MEDIUM)):
        m = re.search(rf'{scale}(?: \(default\))?:[^;]*?(about \d+ min)', cli)
        assert m, f"the --scale help quotes no time for {scale}"
        quotes.append((m.group(1), spec))
    src = (ROOT / "adaptfilt" / "experiments" / "reproduce.py").read_text()
    quotes += [(m.group(), TOTAL) for m in re.finditer(r"about \d+ min(?:utes)? on 2 cores", src)]
    bad = [why for phrase, spec in quotes if (why := qt.check_phrase(phrase, spec, ROOT))]
    assert not bad, bad


# --- the check itself --------------------------------------------------------------------------------------

def _figures(text: str) -> list[str]:
    return [f.written for f in qt.figures(text)]


def test_what_counts_as_a_time_figure():
    text = """8 seeds, 5e8 particle-steps, `p-s0.npz`, 18.4e6 per CPU-second, M = 10^4 runs, 2 x 64 units,
    a second policy, a few minutes, `sleep 30 s` in code, [a link](https://x/5 s) and <!-- 7 s in a comment -->.
    It took 4692 s wall and 24 CPU-s per policy, 11-20 CPU-minutes each, about 78 minutes, a 15-minute check,
    half an hour, three to four minutes, 34 ms.

```bash
adaptfilt reproduce --timeout 30s --out x   # about 19 min on 2 cores
```

| stage | runs | wall (s) | where the time goes (job time, s) |
|---|---|---|---|
| train | 80 | **802** (13.4 min) | 24 per policy (48 of the 80) |
"""
    assert _figures(text) == ["4692 s", "24 CPU-s", "11-20 CPU-minutes", "78 minutes", "15-minute",
                              "half an hour", "three to four minutes", "34 ms", "19 min",
                              "802 (a s column)", "13.4 min", "24 (a s column)"]


@pytest.mark.parametrize("written, value, bound, ok", [
    ("78", 4691.7 / 60, "", True), ("80", 4691.7 / 60, "", True), ("79", 4691.7 / 60, "", False),
    ("4692", 4691.7, "", True), ("4691", 4691.7, "", False), ("19.3", 1155.11 / 60, "", True),
    ("19.2", 1155.11 / 60, "", False), ("1800", 1849.0, "", True), ("1800", 1851.0, "", False),
    ("0.5", 1920 / 3600, "", True), ("0.5", 2000 / 3600, "", False),
    ("30", 24.9, "upper", True), ("30", 30.1, "upper", False), ("30", 31.0, "lower", True)])
def test_the_rounding_rule(written, value, bound, ok):
    """The figure is the record rounded at its last significant digit (an integer's trailing zeros are not
    significant); after 'under' it is a bound."""
    assert qt.matches(written, value, bound) is ok


def _records(tmp_path: Path, scale: float) -> Path:
    """A copy of the records under ``tmp_path`` with every time multiplied by ``scale`` (the notebooks' cells
    end later)."""
    def scaled(obj):
        if isinstance(obj, dict):
            return {k: (v * scale if k in ("wall_time_s", "cpu_time_s") and v else scaled(v)) for k, v in obj.items()}
        return [scaled(v) for v in obj] if isinstance(obj, list) else obj

    for rel in RECORDS:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(json.dumps(scaled(json.loads((ROOT / rel).read_text()))))
    (tmp_path / "notebooks").mkdir(parents=True, exist_ok=True)
    for nb_path in (ROOT / "notebooks").glob("[0-9][0-9]-*.ipynb"):
        nb = json.loads(nb_path.read_text(encoding="utf-8"))
        for cell in nb["cells"]:
            ex = cell.get("metadata", {}).get("execution", {})
            if "iopub.execute_input" in ex and "shell.execute_reply" in ex:
                a = datetime.fromisoformat(ex["iopub.execute_input"].replace("Z", "+00:00"))
                b = datetime.fromisoformat(ex["shell.execute_reply"].replace("Z", "+00:00"))
                ex["shell.execute_reply"] = (a + timedelta(seconds=(b - a).total_seconds() * scale)).isoformat()
        (tmp_path / "notebooks" / nb_path.name).write_text(json.dumps(nb))
    return tmp_path


def _recorded(doc: str) -> list[qt.Figure]:
    figs, _ = qt.bound_figures(_text(doc))
    return [f for f in figs if any(d.kind == "record" for d in f.declared)]


@pytest.mark.parametrize("doc", DOCS)
def test_a_changed_record_is_caught(doc, tmp_path):
    """Every figure read from a record is reported once the record says 60 % more (a bound: three times
    as much; a bound that no plausible record breaks would check nothing)."""
    figs = _recorded(doc)
    assert figs
    for scale, which in ((1.6, [f for f in figs if not f.bound]), (3.0, [f for f in figs if f.bound])):
        reported = {p.line for p in qt.problems(_text(doc), _records(tmp_path / str(scale), scale))}
        missed = [f"{f.line}: {f.written}" for f in which if f.line not in reported]
        assert not missed, f"{doc}: a record {scale} times as large is not seen in {missed}"


@pytest.mark.parametrize("doc", DOCS)
def test_a_changed_figure_is_caught(doc):
    """Every digit figure read from a record is reported once it is changed by one in its last digit."""
    text = _text(doc)
    for f in _recorded(doc):
        if f.words:
            continue
        # one more in the last significant digit (two where one would end in a zero: 2289 -> 2291, as 2290
        # is the record at a coarser precision); a bound is broken from the other side
        step = qt._step(f.high)
        wrong = str(Decimal(f.high) + step)
        if qt._step(wrong) != step:
            wrong = str(Decimal(f.high) + 2 * step)
        wrong = {"upper": "1", "lower": "99999"}.get(f.bound, wrong)
        changed = text[:f.start] + f.text[:len(f.text) - len(f.high)] + wrong + text[f.end:]
        assert any(p.line == f.line for p in qt.problems(changed, ROOT)), (doc, f.line, f.written, wrong)


def test_fixed_rewrites_what_a_new_record_changed(tmp_path):
    root = _records(tmp_path, 1.6)
    for doc in DOCS:
        text = _text(doc)
        new = qt.fixed(text, root)
        left = [p for p in qt.problems(new, root)
                if not any(f.line == p.line and (f.words or f.bound) for f in qt.figures(new))]
        assert not left, f"{doc}: fixed() left {list(map(str, left))}"
        assert qt.fixed(text, ROOT) == text  # nothing to do on the current records


def test_declarations_bind_as_documented():
    root = ROOT
    ok = "took 78 minutes <!-- time: wall of data/timings.json:total --> in all."
    assert qt.problems(ok, root) == []
    cases = {
        "took 78 minutes in all.": "declares no record",
        "took <!-- time: wall of data/timings.json:total --> 78 minutes.": "no figure to bind to",
        "took 78 minutes <!-- time: wall of data/timings.json:everything -->.": "no wall time recorded",
        "took 78 minutes <!-- time: mean wall of data/nothing.json:total -->.": "no file",
        "about 25 s <!-- time: cpu of data/timings.json:policies/ungm-ukf-*.npz -->": "say mean, min, max, sum or range",
        "took 78 minutes\n\n<!-- time: wall of data/timings.json:total -->": "no figure to bind to",
        "took 3 s <!-- times not measured: 4 (a setting) -->": "names '4'",
        "took 3 s <!-- times from abc1234: 3 -->": "",
    }
    for text, why in cases.items():
        got = " | ".join(map(str, qt.problems(text, root)))
        assert (why in got) if why else not got, (text, got)
    # a figure in a code block is declared by name on the line above the fence
    code = "<!-- time 6: wall of data/medium/timings.json:total -->\n```bash\nx   # about 6 min\n```\n"
    assert qt.problems(code, root) == []
    got = " | ".join(map(str, qt.problems(code.replace("6 min", "8 min"), root)))
    assert "names '6'" in got and "'8 min' declares no record" in got, got


def test_the_module_example_runs():
    import doctest

    assert doctest.testmod(qt).failed == 0
