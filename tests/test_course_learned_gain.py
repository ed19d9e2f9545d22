"""Chapter 18's reading of the learned-gain study (adaptfilt.course.learned_gain), on the study run at quick scale:
every table and figure helper against the summary it reads, the verdicts judged again by the one rule, the
kappa learner's optimiser steps against the tuning's own record, and the failed trainings the summary counts
against the KalmanNet files' weights."""
from __future__ import annotations

import re

import pytest

from adaptfilt.course import learned_gain as lg
from adaptfilt.course.tables import MAX_COLUMNS
from adaptfilt.kalmannet import KalmanNet, load_kalmannet, train_kalmannet
from adaptfilt.verdicts import judge, verdict


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    from adaptfilt.experiments.beyond import run

    root = tmp_path_factory.mktemp("gain")
    summary = run(root, quick=True, workers=1, studies=("gain",), progress=False)
    return root, summary["gain"]


def _rows(table: str) -> list[list[str]]:
    lines = [ln for ln in table.splitlines() if ln.startswith("|")]
    assert all(len(ln.strip("|").split("|")) <= MAX_COLUMNS for ln in lines), "a table wider than the page"
    return [[c.strip() for c in ln.strip().strip("|").split("|")] for ln in lines[2:]]


def _interval(text: str) -> list[float]:
    d, lo, hi = re.match(r"([-+]\S+) \[([-+]\S+), ([-+]\S+)\]", text).groups()
    return [float(d), float(lo), float(hi)]


def _iqm(agg: dict) -> str:
    return f"{agg['iqm']:.3g} [{agg['iqm_ci'][0]:.3g}, {agg['iqm_ci'][1]:.3g}]"


def test_a_fresh_network_is_initial_a_trained_one_is_not_and_a_file_keeps_it(tmp_path):
    model = lg.linear_model()
    fresh = KalmanNet(model, seed=3, feature_norm="scale")
    assert lg.is_initial_network(fresh) and lg.initial_attempt(fresh) == 3
    path = fresh.save(tmp_path / "fresh.npz")
    assert lg.is_initial_network(load_kalmannet(path, model))
    trained = train_kalmannet(model, seed=3, feature_norm="scale", **{**lg.TRAIN, "epochs": 1})
    assert trained.history["best_epoch"] == 1 and not lg.is_initial_network(trained)
    other_seed = KalmanNet(model, seed=4, feature_norm="scale")
    other_seed.seed = 3  # another seed's weights under this seed's name are not its initial network
    assert not lg.is_initial_network(other_seed)


def test_design_lines_state_the_studys_settings(quick):
    from adaptfilt.experiments.studies.gain import CONSISTENCY_WEIGHT, KAPPA_RECIPES, QUICK, TARGET_CPU_S

    _, g = quick
    text = lg.design_lines(g)
    assert text.startswith(f"{len(QUICK.seeds)} training seeds per arm")
    for e, t in TARGET_CPU_S.items():
        assert f"{e}: budgets b1-b{len(t)} of {', '.join(f'{x:g}' for x in t)} CPU-s per policy" in text
        assert f"kappa: {', '.join(map(str, QUICK.kappa_episodes[e]))} episodes" in text
        assert f"kappa recipe: lr {KAPPA_RECIPES[e]['lr']:g}, {KAPPA_RECIPES[e]['n_epochs']} PPO epochs" in text
    assert "kappa-sqnll b3" in text and "gain-sup-on-q4 b3 (truth q=4,r=1)" in text
    assert "KalmanNet (both architectures) ungm 16, ctm 20" in text  # RECIPE_TUNING: 8 + 8, 10 + 10
    assert f"consistency weight {CONSISTENCY_WEIGHT:g}" in text


def test_the_verdict_table_is_the_rule_on_the_summarys_intervals_at_every_budget(quick):
    """Each row's words are the rule's on its printed interval (margin 0 for "lower", the printed margin for
    "not worse"), and every budget both arms of each learned pair have is there, with the final runs' rows."""
    _, g = quick
    rows = _rows(lg.verdict_table(g))
    for model, budget, pair, diff, lower, not_worse in rows:
        d = _interval(diff)
        assert lower == judge("lower", d)[0] or abs(d[1]) < 1e-3 or abs(d[2]) < 1e-3
        word, margin = re.fullmatch(r"(.+) \((\S+)\)", not_worse).groups()
        assert word in {"confirmed", "not confirmed", "contradicted"} and float(margin) > 0
    from adaptfilt.experiments.studies.gain import CARRIED

    for e, regimes in g["models"].items():
        for a, b in lg.LEARNED_PAIRS:
            curve = regimes["nominal"]["curve"]
            both = set(curve[a]) if (a, b) in CARRIED else set(curve[a]) & set(curve[b])
            mine = [r for r in rows if r[0] == e and r[2].split(" b")[0] == f"{a} - {b}"]
            assert len(mine) == len(both) + 1 and mine[-1][1].endswith(f"{g['eval_runs']} runs")
            top_b = max(map(int, curve[b]))  # past b's top budget, b stays at it, named in the row
            assert all(r[2] == f"{a} - {b} " + lg._budget(g, e, top_b) for r in mine
                       if int(r[1].split()[0][1:]) > top_b), mine


def test_the_training_table_reads_what_each_learner_saw(quick):
    from adaptfilt.experiments.studies.gain import QUICK

    _, g = quick
    rows = {(r[0], r[1]): r for r in _rows(lg.training_table(g))}
    n = QUICK.knet["batch_size"]
    for (e, arch), steps in QUICK.knet_steps.items():
        arm = "gain-sup" if g["recipes"]["arch"][e] == arch else "gain-sup-arch2"
        for b, s in enumerate(steps, 1):
            r = rows[e, f"{arm}, b{b}"]
            assert r[4] == str(s)
            if r[5].startswith("0,"):  # no restart: one fresh minibatch a step
                assert r[3] == str(s * n)
    for e in g["models"]:
        r = rows[e, "kappa-sqerr, b1"]  # whole rollouts of 8 runs x 64 steps: at least the budget's episodes
        trained = {int(v) for v in r[3].split("-")}
        assert min(trained) >= QUICK.kappa_episodes[e][0] and int(r[4]) > 0
        pts = g["models"][e]["nominal"]["curve"]["kappa-sqerr"]["1"]
        assert set(pts["trajectories_seen"]) == trained and pts["n_seeds"] == len(QUICK.seeds)
        assert r[5] == "n/a"
    assert ("ungm-ukf", "gain-sup-on-forcing10, b3") in rows


def test_the_failed_trainings_are_the_files_whose_weights_are_an_untrained_network(quick):
    """The summary counts a training as failed from its history; the weights, compared with a fresh network of
    each attempt's seed, are a second record: per arm and budget they must agree (the quick run has failures)."""
    root, g = quick
    knets = lg.stored_gain_policies(root)
    initial = {k for k, knet in knets.items() if lg.is_initial_network(knet)}
    assert initial  # the quick CTM's first budget keeps an untrained network
    rows = {(r[0], r[1]): r for r in _rows(lg.restart_table(g))}
    for (e, r, a, b, row) in lg._trained_rows(g):
        if row["restarts"] is None:
            continue
        assert row["failed"] == sum(1 for k in initial if k[:3] == (e, a, int(b)))
        assert f"b{b} {row['failed']}" in rows[e, a][4].split(", ")


def test_truth_and_consistency_tables_are_the_summarys(quick):
    from adaptfilt.experiments.studies.gain import TRUTH_ARMS

    _, g = quick
    truth = lg.truth_table(g)
    rows = {(r[0], r[1]): r for r in _rows(truth)}
    for e, regimes in TRUTH_ARMS.items():
        for r, arms in regimes.items():
            for a in arms:
                row = rows[f"{e}, {r}", a]
                assert row[4] == _iqm(g["models"][e][r]["curve"][f"{a}-on-{r}"]["3"]["rmse"])
                assert _interval(row[5]) and row[5].split("] ")[1] == judge("lower", _interval(row[5]))[0]
            assert f"* {e}, {r}: gain-sup-on-{r} - kappa-sqerr-on-{r}" in truth
    assert rows["ctm-ukf, q4", "gain-sup"][4] == "not trained"
    cons = _rows(lg.consistency_table(g))
    assert [r[1] for r in cons] == ["kappa-sqerr", "kappa-sqnll"] * 3
    m = g["models"]["ungm-ukf"]["nominal"]["curve"]
    assert cons[1][3] == _iqm(m["kappa-sqnll"]["1"]["anees"]) and cons[0][2] == _iqm(m["kappa-sqerr"]["1"]["rmse"])
    assert cons[1][4].endswith(judge("lower", _interval(cons[1][4]))[0])
    margin, word = re.search(r"margin (\S+): not worse -> (.+)$", cons[1][5]).groups()
    assert word == verdict("not worse", _interval(cons[1][5])[1:], float(margin))


def test_curves_figure_marks_where_every_arm_stops_and_the_lines_say_the_same(quick):
    _, g = quick
    fig = lg.plot_curves(g)
    assert len(fig.axes) == len(g["models"])
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "stops improving" in labels and "gain-sup" in labels and "particle filter" in labels
    for ax, e in zip(fig.axes, g["models"]):
        marks = [ln for ln in ax.get_lines() if ln.get_marker() in ("o", ">") and ln.get_markersize() >= 11]
        assert len(marks) == len(g["models"][e]["nominal"]["stops_improving"])
    text = lg.stops_lines(g)
    for e, regimes in g["models"].items():
        for a, s in regimes["nominal"]["stops_improving"].items():
            assert (f"stops at b{s['stops_at']}" if s["stops_at"] else "still improving") in \
                next(ln for ln in text.splitlines() if ln.split()[:2] == [e, a])
    for ln in text.splitlines():
        if ": " in ln and "[" in ln:
            assert ln.endswith(judge("lower", _interval(ln.split(": ")[1]))[0])
    curves = lg.curve_lines(g)
    assert len(curves.splitlines()) == sum(len(r["nominal"]["curve"]) for r in g["models"].values())


def test_final_table_lists_every_top_budget_and_the_references_on_the_final_runs(quick):
    _, g = quick
    rows = _rows(lg.final_table(g))
    for e, regimes in g["models"].items():
        m = regimes["nominal"]
        names = [r[1] for r in rows if r[0] == e]
        for a, spec in g["arms"][e].items():
            if spec["truth"] is None:
                assert any(n.startswith(f"{a} b{spec['top']}") for n in names)
        assert sum(1 for n in names if "floor" in n) == (m["final_floor"]["rmse"] is not None)
        assert len(names) == len(m["final"]) + len(m["final_references"]) + (m["final_floor"]["rmse"] is not None)


def test_the_collapse_table_reads_each_arms_top_budget_history():
    """collapse_table counts, per model and arm, the trainings that collapse_step finds collapsed in the top
    budget's history (a lower budget's history is a prefix and is not read), and where the best network lies."""
    from types import SimpleNamespace

    def knet(vals, best_step, n=150, restores=()):
        steps = list(range(0, 25 * len(vals), 25))
        return SimpleNamespace(history={"val_steps": steps, "val_loss": vals, "max_steps": n, "best_step": best_step,
                                        "attempts": [{"first_step": 0, "init_val": vals[0]}],
                                        "restores": [{"step": s} for s in restores]})

    ok, bad = [10, 5, 4, 3, 3, 2, 2], [10, 5, 4, 30, 40, 50, 60]
    knets = {("m", "gain-sup", 2, 0): knet(ok, 150, restores=(50, 100)), ("m", "gain-sup", 2, 1): knet(bad, 50),
             ("m", "gain-sup", 1, 1): knet(bad[:3], 50, n=50, restores=(25,)),  # a prefix: not read
             ("m", "gain-unsup", 1, 0): knet(ok, 25)}
    rows = {(r[0], r[1]): r for r in _rows(lg.collapse_table(knets))}
    assert rows["m", "gain-sup"] == ["m", "gain-sup", "b2 (150)", "1 of 2 (75)", "100", "1 of 2", "2 (1)"]
    assert rows["m", "gain-unsup"][3:] == ["0 of 1", "25", "0 of 1", "0 (0)"]


def test_the_particle_filter_lines_judge_the_supervised_gains_top_budget_by_the_one_rule(quick):
    """pf_lines: per model, the supervised gain's top budget against the particle filter (final runs), its word
    the one rule's for its interval (margin 0: no margin was declared for the pair)."""
    _, g = quick
    lines = lg.pf_lines(g).splitlines()
    assert len(lines) == len(g["models"])
    for ln, e in zip(lines, g["models"]):
        assert ln.startswith(f"{e}: gain-sup b{g['arms'][e]['gain-sup']['top']} - particle filter (bpf-")
        assert ln.endswith(judge("lower", _interval(ln.split(": ")[-1]))[0])
    assert len(lg.pf_lines(g, "q4").splitlines()) == len(g["models"])
