"""Every verdict word the course states is the one the rule gives for its interval (adaptfilt.course.verdict_words):
the chapters, REPRODUCTION.md and the README; and the check fails on the sentences the third course read found
judged two ways (fixtures from commit 4432022 in tests/fixtures/verdicts)."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from adaptfilt.course.verdict_words import declarations, document_problems, output_problems, problems, sentences
from adaptfilt.verdicts import DECLARED_MARGINS

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("[0-9][0-9]-*.ipynb"))
FIXTURES = ROOT / "tests" / "fixtures" / "verdicts"
#: Chapters not yet brought to the rule: held by the course restructure when the rest was (strict: the mark goes
#: when they pass).
PENDING: set[str] = set()


def _fixture(name: str) -> dict:
    return json.loads((FIXTURES / name).read_text(encoding="utf-8"))


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.xfail(
    strict=True, reason="its verdict sentences are declared when the course restructure releases it"))
    if p.stem in PENDING else p for p in NOTEBOOKS], ids=lambda p: p.stem)
def test_every_verdict_in_a_chapter_is_the_rules(path):
    bad = problems(json.loads(path.read_text(encoding="utf-8")))
    assert not bad, f"{path.name}: verdict words the rule does not give, or not tied to an interval (declare " \
                    "the verdict, fix the word, or re-execute):\n" + "\n".join(map(str, bad))


@pytest.mark.parametrize("doc", ["REPRODUCTION.md", "README.md"])
def test_every_verdict_in_the_documents_is_the_rules(doc):
    bad = document_problems((ROOT / doc).read_text(encoding="utf-8"), doc)
    assert not bad, f"{doc}:\n" + "\n".join(map(str, bad))


def test_the_old_equal_sentence_of_reading_the_stored_policies_fails():
    """Reading the stored policies (chapter 7 then, 8 now) called adaptive and myopic "equal with that margin" in
    RMSE, -0.0006 [-0.049, +0.056], where the next chapter says no margin was declared: the check fails on it as it stood, with a margin invented for it,
    and with the true declaration, which then contradicts its "equal"."""
    nb = _fixture("old-07-equal-with-that-margin.ipynb")
    bad = problems(nb)
    assert any("equivalence word beside a margin" in p.why and "equal with that margin" in p.text for p in bad)
    assert any("verdict word near an interval" in p.why and "+0.0023" in p.text for p in bad)  # "equal" to greedy
    cell = "".join(nb["cells"][2]["source"])
    sentence = "so in accuracy the two\n  groups are equal with that margin:"
    assert sentence in cell
    for decl, why in [
            ('equal [-0.049, +0.056] margin "adaptive vs myopic" rmse 2.87 -> confirmed',
             "no margin is declared for the comparison 'adaptive vs myopic'"),
            ("lower [-0.049, +0.056] -> not confirmed", "equivalence word ('equal', 'tied') without a declared")]:
        text = cell.replace(sentence, sentence[:-1] + f" <!-- verdict: {decl} -->:")
        found = [p.why for p in document_problems(text) if "equal with that margin" in p.text]
        assert any(why in w for w in found), (decl, found)


def test_the_old_margin_0_line_of_how_results_are_reported_fails():
    """How results are reported (chapter 5) printed "margin 0.000: not worse -> confirmed; equal -> confirmed" for
    [-0.048, +0.056]: the rule gives "not confirmed" for "not worse" with margin 0, and no "equal" verdict without
    a margin."""
    bad = problems(_fixture("old-05-not-worse-margin-0.ipynb"))
    printed = [p for p in bad if "output" in p.where]
    assert any("the rule gives 'not confirmed' for 'not worse' on [-0.048, +0.056] with margin 0, printed 'confirmed'"
               in p.why for p in printed)
    assert any("'equal' verdict with margin 0" in p.why for p in printed)
    assert any("both claims are confirmed with the margin" in p.text for p in bad)  # its prose too


def test_the_old_claims_table_of_ukf_on_ungm_fails():
    """C2's "equal to kappa = 200", -0.202 [-0.241, -0.152] against a margin of 0.154, was printed "contradicted
    (lower)": an equivalence claim is contradicted only when its interval lies wholly outside the margin."""
    bad = problems(_fixture("old-08-claims-table.ipynb"))
    assert [p.why for p in bad] == ["the rule gives 'not confirmed' for 'equal' on [-0.241, -0.152] with margin "
                                    "0.154, printed 'contradicted'"]


def test_declarations_are_checked_against_the_rule_the_prose_and_the_interval():
    ok = "Adaptive minus greedy in cost is lower, $-0.046$ $[-0.051, -0.040]$ (confirmed) " \
         "<!-- verdict: lower [-0.051, -0.040] -> confirmed -->."
    assert document_problems(ok) == []
    cases = {
        ok.replace("-> confirmed", "-> not confirmed"): "the rule gives 'confirmed'",
        ok.replace("[-0.051, -0.040] ->", "[-0.052, -0.040] ->"): "is not one the prose or the outputs state",
        ok.replace("is lower,", "is").replace("(confirmed)", "(see the table)"): "does not say 'confirmed'",
        ok.replace("lower [", "lowest ["): "cannot read the declaration",
        "Fast minus faithful, $+0.55$ $[-0.51, +2.89]$, not worse <!-- verdict: not worse [-0.51, +2.89] "
        "-> confirmed -->.": "needs a declared comparison",
    }
    for text, why in cases.items():
        assert any(why in p.why for p in document_problems(text)), (why, document_problems(text))
    # a declared margin, named with its metric and reference: 10 % of 9.437 is 0.944 < 2.89
    nw = "ANEES $+0.55$ $[-0.51, +2.89]$ against the faithful 9.437: not confirmed <!-- verdict: not worse " \
         "[-0.51, +2.89] margin " \
         "\"fast vs faithful\" anees 9.437 -> not confirmed -->."
    assert document_problems(nw) == []
    assert any("the rule gives 'not confirmed'" in p.why for p in document_problems(
        nw.replace("not confirmed <!--", "not worse <!--").replace("-> not confirmed", "-> confirmed")))
    assert any("reference value 9.4 " in p.why for p in document_problems(nw.replace("anees 9.437", "anees 9.4")))
    # a difference stated as a magnitude: "lower by 0.030 [0.017, 0.045]" is a - b in [-0.045, -0.017]
    assert document_problems("It lowers the cost by $0.030$ $[0.017, 0.045]$ (confirmed) "
                             "<!-- verdict: lower [-0.045, -0.017] -> confirmed -->.") == []
    # a sentence that names verdict words but judges nothing is marked as such
    assert document_problems("Confirmed means the interval $[lo, hi]$ lies inside; e.g. $[-1, -0.5]$ is confirmed "
                             "for lower. <!-- verdict: none -->") == []
    # an interval the sentence does not state may be the cell's (a Summary that repeats a verdict)
    cell = "The cost is lower, $-0.046$ $[-0.051, -0.040]$.\n\nIn short: confirmed " \
           "<!-- verdict: lower [-0.051, -0.040] -> confirmed -->."
    assert document_problems(cell) == []


def test_the_scan_needs_a_declaration_only_where_a_verdict_word_meets_an_interval_or_a_margin():
    assert document_problems("At equal price the learned count costs $+0.83$ $[+0.05, +1.77]$ more.") == []
    assert document_problems('A claim of *equal* RMSE needs a **margin**, a difference too small to matter.') == []
    assert document_problems("Both filters agree: the RMSE is 2.87 in each, equal.") == []  # no interval, no margin
    flagged = document_problems("The RMSE is tied (+0.003 [-0.034, +0.038]).")
    assert [p.why for p in flagged] == ["a verdict word near an interval, without a <!-- verdict: ... --> declaration"]
    assert document_problems("The groups are equal within the margin.")  # an equivalence verdict beside a margin


def test_printed_verdicts_are_checked_line_by_line():
    assert output_problems("adaptive-s0 alone +0.029 [+0.006, +0.052]  contradicted\n"
                           "adaptive - greedy  cost  -0.05446 [-0.05666, +8.07]  not confirmed   (seeds alone: 7 "
                           "confirmed, 1 contradicted)\n") == []
    bad = output_problems("adaptive-s2 alone -0.013 [-0.036, +0.008]  confirmed\n")
    assert [p.why for p in bad] == ["the rule gives 'not confirmed' for 'lower' on [-0.036, +0.008], printed "
                                    "'confirmed'"]
    # rounding: an end printed to its digits may sit on either side of a margin printed beside it
    assert output_problems("| C2 | adaptive equal to fixed | rmse | -0.2 [-0.25, -0.154] | not confirmed "
                           "(margin 0.154) | 2/8 |") == []
    assert output_problems("x - y, rmse: -0.001 [-0.048, +0.056]; margin 0.144\n"
                           "   margin 0.144: not worse -> confirmed; equal -> confirmed\n") == []


def test_sentences_keep_a_declaration_with_the_sentence_it_ends_and_table_rows_whole():
    s = sentences("First $[1, 2]$ is lower. <!-- verdict: lower [1, 2] -> contradicted --> Second one.\n\n"
                  "| a | b; c. D | e |\n| f | g |")
    assert s[0].startswith("First") and "verdict: lower" in s[0] and s[1].strip().startswith("Second")
    assert "| a | b; c. D | e |" in s and "| f | g |" in s
    assert [d.word for d in declarations(s[0])] == ["contradicted"]


def test_the_generated_learned_gain_verdicts_in_reproduction_are_the_studys():
    """REPRODUCTION.md's learned-gain verdict table (a generated passage the prose check skips) is the one
    adaptfilt.experiments.studies.gain.markdown writes into data/beyond/summary.md from the one rule."""
    rep = (ROOT / "REPRODUCTION.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- BEGIN generated: data/beyond/summary.md, the learned-gain verdicts -->\n(.*?)\n"
                      r"<!-- END generated -->", rep, re.S).group(1)
    summary = (ROOT / "data" / "beyond" / "summary.md").read_text(encoding="utf-8")
    assert block.startswith("**Learn the parameter or learn the gain: seed-level verdicts**")
    assert block in summary and block.count("\n| ") > 100


def test_reproduction_lists_every_declared_margin():
    rep = (ROOT / "REPRODUCTION.md").read_text(encoding="utf-8")
    for name, d in DECLARED_MARGINS.items():
        assert re.search(rf"^\| {re.escape(name)} \| \"{d.claim}\" \|", rep, re.M), name


def test_the_generated_stop_table_in_reproduction_is_the_studys():
    """REPRODUCTION.md's table of where each learned-gain arm stops improving (generated, skipped by the prose
    check) is the one data/beyond/summary.md holds."""
    rep = (ROOT / "REPRODUCTION.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- BEGIN generated: data/beyond/summary.md, where each learned-gain arm stops improving -->"
                      r"\n(.*?)\n<!-- END generated -->", rep, re.S).group(1)
    summary = (ROOT / "data" / "beyond" / "summary.md").read_text(encoding="utf-8")
    assert block.startswith("**Where each arm stops improving**") and block in summary
    assert block.count("\n| ") >= 10
