"""Beyond the paper: the studies' pipeline at toy scale, out-of-distribution truths and retuning."""
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from same_numbers import assert_same_numbers  # tests/same_numbers.py
from adaptfilt.experiments.ood import CONDITIONS, Condition, evaluate_condition, gain_table, retune, truth_model


def test_truth_model_scales_the_noise_only():
    c = Condition(4.0, 0.25)
    nominal = truth_model("ctm-ukf", Condition(1.0, 1.0))
    m = truth_model("ctm-ukf", c)
    np.testing.assert_allclose(m.Q, 4.0 * nominal.Q)
    np.testing.assert_allclose(m.R, 0.25 * nominal.R)
    np.testing.assert_array_equal(m.P0, nominal.P0)
    assert m.circular_z == (0,) and len(CONDITIONS) == 9
    # simulated noise has the scaled variance
    t1 = truth_model("ungm-ukf", Condition(1.0, 4.0)).simulate(4000, 3, rng=np.random.default_rng(0))
    x, z = t1.x[:, 0, 0], t1.z[:, 0, 0]
    assert abs(np.var(z - x**2 / 20) / 0.4 - 1) < 0.1


def test_retune_moves_the_policy_and_is_reproducible():
    from adaptfilt.trainers import train_policy

    pol = train_policy("ungm-ukf", "a2c", 0.5, episodes=20, seed=0, progress=False, n_steps=20)
    pol.name = "adaptive-s0"
    c = Condition(4.0, 0.25)
    a = retune(pol, "ungm-ukf", c, episodes=3, seed=1, n_steps=20)
    b = retune(pol, "ungm-ukf", c, episodes=3, seed=1, n_steps=20)
    wa, wb, w0 = (p.actor.net[0].weight.detach().numpy() for p in (a, b, pol))
    np.testing.assert_array_equal(wa, wb)
    assert not np.array_equal(wa, w0)
    np.testing.assert_array_equal(a.scaler.center, pol.scaler.center)  # keeps the features' scaling
    res = evaluate_condition("ungm-ukf", c, [pol, a], n_runs=40, n_steps=20)
    assert {"default", "greedy", "adaptive-s0", "adaptive-s0-retuned"} <= set(res.names)
    table = gain_table({c.key: res}, {"learned": ["adaptive-s0"]}, "objective")
    row = table[c.key]
    assert row["learned"]["gain"] == pytest.approx(res["default"].objective - res["adaptive-s0"].objective)


def test_quick_candidate_study_writes_its_manifest(tmp_path):
    from adaptfilt.experiments.beyond import run, summary_md
    from adaptfilt.experiments.reproduce import sha256

    summary = run(tmp_path, quick=True, workers=1, studies=("cand",), progress=False)
    man = json.loads((tmp_path / "beyond" / "manifest.json").read_text())
    for e in man["files"]:
        assert sha256(tmp_path / "beyond" / e["path"]) == e["sha256"] and e["command"]
    assert set(summary["cand"]) == {"ungm-ukf", "ctm-ukf"}
    rows = summary["cand"]["ungm-ukf"]
    assert rows["adaptive-cand"]["cost"]["n_seeds"] == 2 and "greedy" in rows
    assert "| ungm-ukf | adaptive-cand |" in summary_md(summary)


def test_beyond_resumes_from_its_journal_to_identical_files(tmp_path, monkeypatch, capsys):
    """Stopped after its third job, the same run again takes those three from the journal and writes the
    files an uninterrupted run writes (into the same folder: a policy records its --out); run once
    more, it trains nothing, the manifest listing every policy with its command and sha256."""
    from adaptfilt.experiments.beyond import run
    from adaptfilt.experiments.journal import Journal
    from adaptfilt.experiments.sweep import Interrupted
    from adaptfilt.experiments.reproduce import sha256

    def digests(d):
        return {str(p.relative_to(d)): sha256(p) for p in sorted(d.rglob("*")) if p.is_file()}

    run(tmp_path, quick=True, workers=1, studies=("cand",), progress=False)
    reference = digests(tmp_path / "beyond")
    (tmp_path / "beyond").rename(tmp_path / "reference")
    add = Journal.add

    def add_then_stop(self, *a, **kw):
        rec = add(self, *a, **kw)
        if len(self.records) == 3:
            raise KeyboardInterrupt
        return rec

    monkeypatch.setattr(Journal, "add", add_then_stop)
    with pytest.raises(Interrupted, match="3 finished jobs are kept in .*journal.jsonl; run the same command again"):
        run(tmp_path, quick=True, workers=1, studies=("cand",), progress=False)
    monkeypatch.setattr(Journal, "add", add)
    capsys.readouterr()
    run(tmp_path, quick=True, workers=1, studies=("cand",))
    assert "[beyond] 5 policies to train, 3 finished by an earlier run" in capsys.readouterr().out
    again = digests(tmp_path / "beyond")
    assert again.keys() == reference.keys() and "journal.jsonl" not in again
    # equal but for the manifest, which records this run's training times
    assert {k: v for k, v in again.items() if k != "manifest.json"} == \
        {k: v for k, v in reference.items() if k != "manifest.json"}
    run(tmp_path, quick=True, workers=1, studies=("cand",))
    assert "[beyond] 0 policies to train, 0 finished by an earlier run (journal.jsonl), 8 listed in the manifest" \
        in capsys.readouterr().out


def test_committed_beyond_studies_match_their_manifest_and_summary():
    """data/beyond (``adaptfilt beyond --out data``): every file matches its manifest and loads; the
    summary's seed-level numbers are what the stored evaluations give; the policies are what their
    recorded commands say (8 seeds, the fast mode, the safe SIF policies on the set chosen on the
    selection runs, which are not the evaluation's)."""
    import shlex

    from adaptfilt.experiments import artefacts
    from adaptfilt.experiments.studies.cand import CAND_EXPERIMENTS
    from adaptfilt.experiments.studies.sif import PENALTY, SELECTION_SEED, SIF_EXPERIMENTS
    from adaptfilt.experiments.study import study_rows
    from adaptfilt.seed_stats import aggregate, difference, iqm, seed_groups
    from adaptfilt.learned import load_policy

    root = artefacts.data_dir() / "beyond"
    checked = artefacts.verify_beyond()
    man = json.loads((root / "manifest.json").read_text())
    assert len(checked) == len(man["files"]) and man["scale"] == "full"
    summary = artefacts.load_beyond()
    assert set(summary) >= {"cand", "sif", "ood"} and set(summary["cand"]) == set(CAND_EXPERIMENTS)
    sel = summary["sif-selection"]
    assert sel["seed"] == SELECTION_SEED != 0 and sel["n_runs"] == 10_000
    assert list(sel["safe"]) == [float(v) for v, k in sel["divergent_runs"].items() if k == 0]
    for study, exps, groups in (("cand", CAND_EXPERIMENTS, ("adaptive-cand", "myopic-cand")),
                                ("sif", SIF_EXPERIMENTS, ("adaptive-penalised", "adaptive-safe"))):
        for e in exps:
            res = artefacts.load_beyond_results(f"{study}-{e}")
            assert res.config["n_runs"] == 10_000
            sg = seed_groups(res.names)
            for g in groups:
                assert sg[g] == [f"{g}-s{s}" for s in range(8)], (e, g)
                row = summary[study][e][g]
                assert row["cost"]["iqm"] == aggregate(res, sg[g], "cost").iqm
                assert row["cost_charged"]["iqm"] == aggregate(res, sg[g], "cost_charged").iqm
                assert row["minus_greedy"]["rmse"] == list(difference(res, sg[g], ["greedy"], "rmse")["iqm"])
                assert row["divergent_frac_max"] == max(res[n].divergent_frac for n in sg[g])
            if study == "sif":  # every row as the study computes it, from the stored evaluation
                assert sg["adaptive"] == [f"adaptive-s{s}" for s in range(8)]
                want = json.loads(json.dumps(study_rows("sif", res, sel)))
                assert summary["sif"][e] == want and len(want["adaptive"]["divergent_runs"]) == 8
            for s in (0, 7):
                for g in groups:
                    entry = next(f for f in man["files"] if f["path"] == f"policies/{e}-{g}-s{s}.npz")
                    argv = shlex.split(entry["command"])
                    assert argv[:3] == ["adaptfilt", "train", e] and argv[argv.index("--seed") + 1] == str(s)
                    assert argv[argv.index("--algo") + 1] == "fast"
                    pol = load_policy(root / entry["path"], experiment=e)
                    if g == "adaptive-safe":
                        assert pol.grid.tolist() == list(sel["safe"]) and "--actions" in argv
                    elif g == "adaptive-penalised":
                        assert float(argv[argv.index("--repair-penalty") + 1]) == PENALTY
                    else:
                        assert "+cand" in argv[argv.index("--features") + 1]
    for e in ("ungm-ukf", "ctm-ukf"):  # training on -L itself, beside the reproduction's log(1 + L) policies
        res = artefacts.load_beyond_results(f"raw-{e}")
        sg = seed_groups(res.names)
        assert sg["adaptive-raw"] == [f"adaptive-raw-s{s}" for s in range(8)] == [
            n.replace("adaptive-", "adaptive-raw-") for n in sg["adaptive"]]
        row = summary["raw"][e]["adaptive-raw"]
        assert row["minus_adaptive"]["cost"] == list(difference(res, sg["adaptive-raw"], sg["adaptive"], "cost")["iqm"])
        entry = next(f for f in man["files"] if f["path"] == f"policies/{e}-adaptive-raw-s3.npz")
        assert "--cost-transform none" in entry["command"] and "--algo fast" in entry["command"]
        assert load_policy(root / entry["path"], experiment=e).metadata["cost_transform"] == "none"
    assert len(summary["ood"]["objective"]) == 9
    for key, row in summary["ood"]["objective"].items():
        res = artefacts.load_beyond_results(f"ood-{key}")
        assert res.config["arrays"] is False and res.config["condition"] == key
        learned = [n for n in res.names if n.startswith("adaptive-s")]
        assert len(learned) == 8 and row["learned"]["n_seeds"] == 8
        want = res["default"].objective - iqm([res[n].objective for n in learned])
        assert row["learned"]["gain"] == pytest.approx(want, rel=1e-12, abs=1e-15)


def test_committed_particle_study_is_what_its_stored_evaluations_give():
    """data/beyond's particle study (``adaptfilt beyond --out data --studies particles``): per experiment,
    8 learned seeds evaluated on 250 runs (PARTICLE_FULL) beside every fixed count in both forms (the study's filter and
    the reference ``bpf-N``), the KLD bins, the ESS targets and greedy; the summary's rows are what
    particle_rows computes from the stored evaluation; the policies' recorded commands train them with the
    fast mode; the point-mass floor is computed where it can be (UNGM, on the first 200 runs)."""
    import shlex

    from adaptfilt.experiment_registry import PARTICLE_EXPERIMENTS
    from adaptfilt.experiments import artefacts
    from adaptfilt.experiments.particles_study import PARTICLE_FULL, particle_rows
    from adaptfilt.seed_stats import seed_groups

    root = artefacts.data_dir() / "beyond"
    man = {f["path"]: f for f in json.loads((root / "manifest.json").read_text())["files"]}
    summary = artefacts.load_beyond()["particles"]
    assert set(summary) == set(PARTICLE_EXPERIMENTS)
    assert "figures/particles-tradeoff.png" in man
    for e, rows in summary.items():
        res = artefacts.load_beyond_results(f"particles-{e}")
        assert res.config["n_runs"] == PARTICLE_FULL.eval_runs == 250
        assert seed_groups(res.names)["adaptive"] == [f"adaptive-s{s}" for s in range(8)]
        grid = [int(n) for n in res.config["grid"]]
        for n in grid:
            assert f"fixed-n_particles={n}" in res.names and f"bpf-{n}" in res.names
        assert {"kld-x1", "kld-x64", "ess-50", "greedy"} <= set(res.names)
        assert json.loads(json.dumps(particle_rows(res, rows["floor"]))) == rows
        assert rows["floor"]["runs"] == (200 if e.startswith("ungm") else 0)  # the point-mass floor: 1-D models only
        argv = shlex.split(man[f"policies/{e}-adaptive-s3.npz"]["command"])
        assert argv[:3] == ["adaptfilt", "train", e] and argv[argv.index("--algo") + 1] == "fast"


def test_committed_mlanchor_study_is_what_its_stored_evaluations_give():
    """data/beyond's mlanchor study (``adaptfilt beyond --out data --studies mlanchor``): the final evaluations
    (10^4 runs of the anchor study's seed, UNGM and CTM) and the CTM learning curve (2000 selection runs) are
    stored; the summary's rows, verdicts and the imitation policies' held-out agreement are what the study
    computes from them and from the policy files; 8 seeds in every group; the imitation fits record their call."""
    from adaptfilt.experiments import artefacts
    from adaptfilt.experiments.studies import mlanchor
    from adaptfilt.experiments.studies.sif import SELECTION_SEED
    from adaptfilt.learned import load_policy
    from adaptfilt.seed_stats import seed_groups

    root = artefacts.data_dir() / "beyond"
    man = {f["path"]: f for f in json.loads((root / "manifest.json").read_text())["files"]}
    s = artefacts.load_beyond()["mlanchor"]
    assert s["eval-seed"] == mlanchor.EVAL_SEED == 2 and s["selection-seed"] == SELECTION_SEED
    for e, rows in s["final"].items():
        res = artefacts.load_beyond_results(f"mlanchor-{e}")
        assert res.config["n_runs"] == 10_000 and res.config["seed"] == mlanchor.EVAL_SEED
        groups = seed_groups(res.names)
        files = [str(root / f"policies/{e}-{n}.npz") for g in mlanchor.GROUPS for n in groups.get(g, [])]
        assert json.loads(json.dumps(mlanchor._final_rows(res, files))) == rows
        assert all(len(groups[g]) == 8 for g in mlanchor.GROUPS if g in groups)
        assert set(mlanchor.CONTROLS) & set(rows) and all(c in rows for g, c in mlanchor.CONTROLS.items() if g in rows)
    ctm = s["final"]["ctm-ukf"]
    for g in mlanchor.IMITATION:  # the held-out agreement is the one each file records
        pol = load_policy(root / f"policies/ctm-ukf-{g}-s3.npz", experiment="ctm-ukf")
        assert ctm[g]["imitation"]["heldout_accuracy"][3] == pol.metadata["imitation"]["heldout_accuracy"]
        assert man[f"policies/ctm-ukf-{g}-s3.npz"]["command"].startswith("adaptfilt imitate ctm-ukf ")
    curve = artefacts.load_beyond_results("mlanchor-ctm-ukf-curve")
    assert curve.config["n_runs"] == 2000 and curve.config["seed"] == SELECTION_SEED
    tags = {r["group"]: (learner, int(ep)) for learner, by in s["curve"]["learners"].items() for ep, r in by.items()}
    assert json.loads(json.dumps(mlanchor._curve_rows(curve, tags))) == s["curve"]
    assert {ep: r["n_seeds"] for ep, r in s["curve"]["learners"]["adaptive-lik"].items()} == {
        str(ep): 8 for ep in mlanchor.CURVE_EPISODES["full"]}


@pytest.mark.crosscpu
def test_the_stored_particle_evaluations_rerun():
    """The particle study was evaluated with the numpy form of the filter on a CPU whose numpy ``exp`` is the
    C library's; whichever backend this machine has (the compiled one where numba is installed) re-evaluates
    a fixed count and a learned policy on the same 250 runs to the stored per-step RMSE, ANEES, cost and
    usage, to the stated relative tolerance (tests/same_numbers.py; bit for bit on a CPU like the one that
    made them), an ANEES above the divergence line as such: at a few steps of the CTM with 100 particles the
    cloud collapses and the stored ANEES is 1e15-1e17 or infinite by the rounding of a Cholesky factor, which
    OpenBLAS's kernels for another CPU round otherwise. The study is reproducible."""
    import warnings

    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments import artefacts
    from adaptfilt.learned import learned_name, load_policy
    from adaptfilt.metrics import DIVERGED_NEES

    for e, learned in (("ungm-pf-1e-4", True), ("ctm-pf-1", False)):
        stored = artefacts.load_beyond_results(f"particles-{e}")
        exp = get_experiment(e)
        nx = exp.make_model().nx
        pols = [p for p in exp.baselines() if p.name == "fixed-n_particles=100"]
        if learned:
            f = artefacts.data_dir() / "beyond" / "policies" / f"{e}-adaptive-s0.npz"
            pols.append(load_policy(f, experiment=exp, name=learned_name(f, e)))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a diverged run's infinite NEES, as in the study
            res = evaluate(exp, pols, n_runs=stored.config["n_runs"], seed=stored.config["seed"], progress=False)
        assert res.names == [p.name for p in pols]
        for name in res.names:
            for key in ("rmse_t", "anees_t", "cost_t", "usage"):
                line = DIVERGED_NEES * nx if key == "anees_t" else None
                assert_same_numbers(getattr(res[name], key), getattr(stored[name], key), err_msg=f"{e} {name} {key}",
                                    exact=False, diverged_above=line)


@pytest.mark.crosscpu
def test_the_stored_reference_filter_rows_rerun():
    """The particle study's reference rows (``bpf-N``, the bootstrap particle filter evaluated beside the
    policies as a filter) rerun to the stored per-step RMSE, ANEES and cost, the usage of the count and the
    bootstrap replicates, for two counts on UNGM and the CTM (the study's 250 runs), to the stated relative
    tolerance (tests/same_numbers.py; they were made on another CPU)."""
    import warnings

    from adaptfilt.evaluation import evaluate
    from adaptfilt.exact import BootstrapParticleFilter
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments import artefacts
    from adaptfilt.metrics import DIVERGED_NEES

    for e in ("ungm-pf-1e-4", "ctm-pf-1"):
        stored = artefacts.load_beyond_results(f"particles-{e}")
        exp = get_experiment(e)
        model = exp.make_model()
        filters = {f"bpf-{N}": BootstrapParticleFilter(model, n_particles=N, seed=[24, 0, N]) for N in (50, 100)}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a collapsed cloud's infinite NEES, as in the study
            res = evaluate(exp, [], filters=filters, n_runs=stored.config["n_runs"], seed=stored.config["seed"],
                           progress=False)
        for name in filters:
            for key in ("rmse_t", "anees_t", "cost_t", "usage", "boot_rmse", "boot_cost"):
                line = DIVERGED_NEES * model.nx if key == "anees_t" else None
                assert_same_numbers(getattr(res[name], key), getattr(stored[name], key), err_msg=f"{e} {name} {key}",
                                    exact=False, diverged_above=line)


def test_quick_sif_study_trains_penalised_and_safe_policies(tmp_path):
    """The SIF study at toy scale: both families per seed, the safe ones never choose an iteration count
    outside the set chosen on the selection runs (usage in the evaluation), the cheapest fixed value of
    that set is reported with its charged cost, divergence is a rate with an interval, and a later study
    run adds to the same summary and manifest instead of replacing them."""
    from adaptfilt.experiments.beyond import run, summary_md
    from adaptfilt.experiments.studies.sif import SELECTION_SEED, select_safe_actions
    from adaptfilt.seed_stats import seed_groups
    from adaptfilt.results import Results

    summary = run(tmp_path, quick=True, workers=1, studies=("sif",), progress=False)
    e = "ctm-sif-nis"
    res = Results.load(tmp_path / "beyond" / "results" / f"sif-{e}")
    groups = seed_groups(res.names)
    assert groups["adaptive-penalised"] == ["adaptive-penalised-s0", "adaptive-penalised-s1"]
    grid = np.asarray(res.grid)
    sel = summary["sif-selection"]
    assert sel["seed"] == SELECTION_SEED and res.config["seed"] == 0  # chosen on other runs than judged
    assert sel == select_safe_actions("ctm-sif-stateinnov", 100, 20)  # what the selection runs give, again
    unsafe = ~np.isin(grid, sel["safe"])
    for n in groups["adaptive-safe"]:
        assert res[n].usage[unsafe].sum() == 0 and res[n].usage.sum() > 0
    row = summary["sif"][e]["best safe fixed"]
    assert float(row["policy"].split("=")[1]) in sel["safe"] and row["cost_charged"] == res[row["policy"]].cost_charged
    assert row["divergent_rate_ci"][0] <= row["divergent_rate"] <= row["divergent_rate_ci"][1] and row["divergent_rate_ci"][1] > 0
    assert "best safe fixed (" in summary_md(summary) and "Safe action set, chosen on selection runs" in summary_md(summary)
    with pytest.raises(ValueError, match="selection seed"):
        select_safe_actions(e, 10, 5, seed=0)
    before = {f["path"] for f in json.loads((tmp_path / "beyond" / "manifest.json").read_text())["files"]}
    summary2 = run(tmp_path, quick=True, workers=1, studies=("cand",), progress=False)
    after = {f["path"] for f in json.loads((tmp_path / "beyond" / "manifest.json").read_text())["files"]}
    assert before <= after and any(p.startswith("results/cand-") for p in after - before)
    assert set(summary2) >= {"sif", "cand"}


def test_quick_raw_study_pairs_the_untransformed_policies_with_the_log_ones(tmp_path):
    """The raw study at toy scale: policies trained on -L record it (command and metadata) and are compared,
    paired and at the seed level, with the adaptive policies of the reproduction found beside them."""
    from adaptfilt.results import Results
    from adaptfilt.experiments.beyond import QUICK, run, summary_md
    from adaptfilt.seed_stats import difference
    from adaptfilt.learned import load_policy
    from adaptfilt.trainers import train_policy

    for e in ("ungm-ukf", "ctm-ukf"):  # stand-ins for the reproduction's policies (toy scale)
        for s in QUICK.seeds:
            train_policy(e, "fast", 0.5, QUICK.episodes, s, n_steps=QUICK.n_steps, progress=False,
                         out=tmp_path / "policies" / f"{e}-adaptive-s{s}.npz")
    summary = run(tmp_path, quick=True, workers=1, studies=("raw",), progress=False)
    for e in ("ungm-ukf", "ctm-ukf"):
        res = Results.load(tmp_path / "beyond" / "results" / f"raw-{e}")
        raw, log = ["adaptive-raw-s0", "adaptive-raw-s1"], ["adaptive-s0", "adaptive-s1"]
        assert set(raw + log + ["greedy", "default", "ml"]) <= set(res.names)
        row = summary["raw"][e]["adaptive-raw"]
        assert row["minus_adaptive"]["rmse"] == list(difference(res, raw, log, "rmse")["iqm"])
        pol = load_policy(tmp_path / "beyond" / "policies" / f"{e}-adaptive-raw-s1.npz", experiment=e)
        assert pol.metadata["cost_transform"] == "none" and "--cost-transform none" in pol.metadata["command"]
        # a different reward: not the policy the same seed learns on log(1 + L)
        other = load_policy(tmp_path / "policies" / f"{e}-adaptive-s1.npz", experiment=e)
        assert other.metadata["cost_transform"] == "log1p"
        assert not np.array_equal(pol.curve["train_cost"], other.curve["train_cost"])
    md = summary_md(summary)
    assert "| ungm-ukf | adaptive-raw |" in md and "adaptive-raw - adaptive, IQM" in md


def test_quick_anchor_and_look_studies(tmp_path):
    """The anchored learner and the look-ahead references at toy scale: the anchored policies record their
    recipe and are evaluated on runs of their own seed (2); the references sit beside greedy on the same
    paired runs, and the two-step look-ahead equals rollout with H = 1 (the same computation, the same
    samples), while looking further costs more compute."""
    from adaptfilt.results import Results
    from adaptfilt.experiments.beyond import run, summary_md
    from adaptfilt.experiments.studies.anchor import ANCHOR_EVAL_SEED
    from adaptfilt.learned import load_policy

    summary = run(tmp_path, quick=True, workers=1, studies=("anchor", "look"), progress=False)
    res = Results.load(tmp_path / "beyond" / "results" / "anchor-ungm-ukf")
    assert res.config["seed"] == ANCHOR_EVAL_SEED == summary["anchor-eval-seed"] != 0
    row = summary["anchor"]["ungm-ukf"]["adaptive-anchored"]
    assert row["cost"]["n_seeds"] == 2 and 0 <= row["seeds_below_greedy"] <= 2
    pol = load_policy(tmp_path / "beyond" / "policies" / "ungm-ukf-adaptive-anchored-s1.npz", experiment="ungm-ukf")
    assert "--anchor greedy --anchor-strength 3 --anchor-kl 0.01 --anchor-shield 1" in pol.metadata["command"]
    look = summary["look"]["ungm-ukf"]
    refs = look["references"]
    assert set(refs) == {"rollout-H1-S2", "rollout-H2-S2", "twostep-S2", "rollout-ml-H1-S2", "rollout-best-H1-S2"}
    assert refs["twostep-S2"]["cost"] == refs["rollout-H1-S2"]["cost"]
    assert refs["rollout-H2-S2"]["spent"] > refs["rollout-H1-S2"]["spent"] > look["baselines"]["greedy"]["spent"] == 13
    assert "adaptive-anchored" in look["learned"] and look["n_runs"] == 40
    sif = summary["look"]["ctm-sif-stateinnov"]
    assert sif["verdict_cost"] == "cost_charged"  # the SIF references pay for their continuations
    r = sif["references"]["rollout-H1-S2"]
    assert r["cost_charged"] > r["cost"]
    md = summary_md(summary)
    assert "How much can looking ahead buy?" in md and "adaptive-anchored" in md
    assert (tmp_path / "beyond" / "figures" / "look-gain.png").stat().st_size > 1000


def test_quick_mlanchor_study_and_the_look_parts_it_adds(tmp_path, monkeypatch):
    """The mlanchor study at toy scale: ML-anchored policies record their anchor and are judged on the anchor
    study's runs against greedy, ML and their gamma = 0 control; the imitation policies record their held-out
    agreement with ML; the learning curve is on selection runs. The look study adds the rollouts over ML and
    over the better of both, and the mlanchor groups against every reference; run again with one more part,
    it computes that part only and takes the others, bit for bit, from its stored evaluation."""
    import dataclasses

    from adaptfilt.experiments import look as look_mod
    from adaptfilt.experiments.beyond import run, summary_md
    from adaptfilt.experiments.studies import mlanchor
    from adaptfilt.learned import load_policy
    from adaptfilt.results import Results
    from adaptfilt.verdicts import margin, verdict

    summary = run(tmp_path, quick=True, workers=1, studies=("mlanchor", "look"), progress=False)
    root = tmp_path / "beyond"
    s = summary["mlanchor"]
    assert s["eval-seed"] == 2 and s["selection-seed"] == 1 and set(s["final"]) == {"ungm-ukf", "ctm-ukf"}
    res = Results.load(root / "results" / "mlanchor-ctm-ukf")
    assert res.config["seed"] == 2 and res.config["n_runs"] == 100
    assert {"myopic-lik-e10-s0", "myopic-lik-e10-s1"} <= set(res.names)  # the lik learner's control, merged
    rows = s["final"]["ctm-ukf"]
    assert set(mlanchor.GROUPS) - {"adaptive-lik-e1000", "myopic-lik-e1000"} <= set(rows)  # the main budget: 1000
    for g in ("adaptive-mlanchored", "adaptive-mlanchored-raw"):
        assert rows[g]["verdict"]["below ml"] == verdict("lower", rows[g]["minus_ml"]["cost"])
        assert "minus_myopic" in rows[g] and "below its gamma = 0 control" in rows[g]["verdict"]
        for m in ("rmse", "anees"):  # not worse than ML's, with the declared margin around ML's value
            assert rows[g]["margin_vs_ml"][m] == margin("learned vs ML", m, rows["ml"][m])
            assert rows[g]["verdict"][f"{m} not worse than ml"] == verdict("not worse", rows[g]["minus_ml"][m],
                                                                           rows[g]["margin_vs_ml"][m])
    pol = load_policy(root / "policies" / "ctm-ukf-adaptive-mlanchored-raw-s1.npz", experiment="ctm-ukf")
    assert "--anchor ml --anchor-strength 3 --anchor-kl 0.01 --anchor-shield 1" in pol.metadata["command"]
    assert "--cost-transform none" in pol.metadata["command"] and pol.anchor.policy == "ml"
    im = load_policy(root / "policies" / "ctm-ukf-imitation-lik-s0.npz", experiment="ctm-ukf")
    assert im.feature_set.name == "paper+circ+cand+lik" and im.anchor is None
    acc = rows["imitation-lik"]["imitation"]["heldout_accuracy"]
    assert acc[0] == im.metadata["imitation"]["heldout_accuracy"] and len(acc) == 2
    man = {f["path"]: f for f in json.loads((root / "manifest.json").read_text())["files"]}
    assert man["policies/ctm-ukf-imitation-lik-s0.npz"]["command"].startswith("adaptfilt imitate ctm-ukf ")
    assert man["policies/ctm-ukf-imitation-lik-s0.npz"]["cpu_time_s"] > 0
    curve = s["curve"]
    assert curve["seed"] == 1 and set(curve["learners"]) == {"adaptive-lik", "adaptive-mlanchored", "adaptive"}
    assert list(curve["learners"]["adaptive-lik"]) == ["4", "10"]
    # the reproduction's learner at the first learned-gain study's budgets: trained by this study now
    assert "4" in curve["learners"]["adaptive"]
    assert man["policies/ctm-ukf-kappa-nis-b2-s1.npz"]["command"].startswith("adaptfilt train ctm-ukf --algo fast ")
    md = summary_md(summary, studies=("mlanchor",))
    assert "Imitation of ML's choice" in md and "Learning curve" in md and "| ctm-ukf | adaptive-mlanchored |" in md
    for f in ("mlanchor-curve.png", "mlanchor-imitation.png"):
        assert (root / "figures" / f).stat().st_size > 1000
    # the look study: the other bases and the mlanchor groups on its runs, against every reference
    look = summary["look"]["ctm-ukf"]
    assert {"rollout-ml-H1-S2", "rollout-best-H1-S2"} <= set(look["references"])
    against = look["learned"]["adaptive-mlanchored"]["against"]
    assert set(against) == {"ml", "rollout-H1-S2", "rollout-ml-H1-S2", "rollout-best-H1-S2"}
    assert "ctm-ukf: learned groups against ML and the best rollout of each base" in summary_md(summary)
    before = Results.load(root / "results" / "look-ctm-ukf")
    from adaptfilt.verdicts import verdict

    # every reference against ML on the same runs, judged by the one rule (the rollout over ML is bounded
    # by ML only with exact expectations over the full horizon: measured, not assumed)
    for n, row in look["references"].items():
        assert row["minus_ml"]["cost"] == list(before.paired_difference(n, "ml", "cost")), n
        assert row["improves_on_ml"] == verdict("lower", row["minus_ml"]["cost"])
    md = summary_md(summary)
    assert "ctm-ukf: every look-ahead reference against ML" in md and "| rollout-ml-H1-S2 |" in md
    from adaptfilt.experiments.look import look_md
    short = look_md(summary["look"], bases=("greedy",), learned=("adaptive-mlanchored",))
    assert "rollout-ml-" not in short and "against ML" not in short and "adaptive-mlanchored" in short
    assert len(before.config["parts"]) == 5  # base, rollout, over ML, over the better of both, learned
    # one more part: only it is computed, the rest comes from the stored evaluation as it was
    monkeypatch.setattr(look_mod, "LOOK_BASES_QUICK", {**look_mod.LOOK_BASES_QUICK,
                                                       "ctm-ukf": {"ml": ((1, 2), (2, 2)), "best": ((1, 2),)}})
    computed = []
    job = look_mod.look_job

    def counting(experiment, spec, *a):
        computed.append((experiment, spec))
        return job(experiment, spec, *a)

    monkeypatch.setattr(look_mod, "look_job", counting)
    summary2 = run(tmp_path, quick=True, workers=1, studies=("look",), progress=False)
    assert computed == [("ctm-ukf", ("rollout", 2, 2, "ml"))]
    after = Results.load(root / "results" / "look-ctm-ukf")
    assert after.names == before.names[:before.names.index("rollout-ml-H1-S2") + 1] + ["rollout-ml-H2-S2"] + \
        before.names[before.names.index("rollout-ml-H1-S2") + 1:]
    for n in before.names:
        a, b = dataclasses.asdict(before[n]), dataclasses.asdict(after[n])
        for k, v in a.items():
            if k != "wall_time_s":
                np.testing.assert_array_equal(np.asarray(b[k]), np.asarray(v), err_msg=f"{n} {k}")
    assert summary2["look"]["ctm-ukf"]["references"]["rollout-ml-H1-S2"] == look["references"]["rollout-ml-H1-S2"]


def test_look_gain_figure_cuts_far_values_at_the_edge():
    """Each panel's range is its own; a reference or a learned interval beyond it ends at the edge in a
    triangle with its value written there, and the learned groups sit right of the largest horizon."""
    from adaptfilt.experiments.look import plot_look_gain

    look = {"e": {"verdict_cost": "cost", "n_runs": 10,
                  "references": {"rollout-H1-S4": {"minus_greedy": {"cost": [21.3, 21.2, 21.4]}},
                                 "rollout-H2-S4": {"minus_greedy": {"cost": [0.05, 0.02, 0.08]}}},
                  "learned": {"g": {"n_seeds": 4, "minus_greedy": {"cost": [-0.3, -0.4, 8.0]}}}}}
    fig = plot_look_gain(look, ylim={"e": (-1.0, 0.5)})
    ax = fig.axes[0]
    assert ax.get_ylim() == (-1.0, 0.5)
    texts = [t.get_text() for t in ax.texts]
    assert "-21.3\n[-21.4, -21.2]" in texts and "to -8" in texts
    assert ax.get_xlim()[1] > 2.2 and list(ax.get_xticks()) == [0, 1, 2]
    fig = plot_look_gain(look)  # by default the range fits everything
    assert ax is not fig.axes[0] and fig.axes[0].get_ylim()[0] < -21.4


#: Studies whose full run is not in data/beyond yet (the manifest guard leaves them out, and a test checks that the
#: manifest indeed lists none of their files: once one is stored it must leave this list).
NOT_STORED: dict[str, str] = {}


def _beyond_policy_commands(root: str, selection: dict) -> dict[str, str]:
    """What every stored study builds for its policy files in a full-scale ``adaptfilt beyond --out ROOT``: path ->
    command."""
    from pathlib import Path

    from adaptfilt.experiments.studies import ALL
    from adaptfilt.experiments.study import FULL, Run

    from adaptfilt.experiments.studies import mlanchor

    run = Run(Path(root) / "beyond", Path(root), FULL, False, "", journal=None)
    made = {str(Path(o).relative_to(run.out)): t.command for s in ALL if s.NAME not in NOT_STORED
            for t in s.policies(run, {"sif-selection": selection}) for o in t.outputs}
    # the mlanchor study's imitation fits (adaptfilt imitate, made before its trainings)
    return made if "mlanchor" in NOT_STORED else {**made, **mlanchor.imitation_files(run)}


def test_a_study_not_stored_yet_has_no_file_in_data_beyond():
    """NOT_STORED is true: data/beyond's manifest and summary hold nothing of those studies (when one is stored,
    the guard above must cover it: remove it from NOT_STORED)."""
    import re

    from adaptfilt.experiments import artefacts

    beyond_dir = artefacts.data_dir() / "beyond"
    man = json.loads((beyond_dir / "manifest.json").read_text())
    summary = json.loads((beyond_dir / "summary.json").read_text())
    for name in NOT_STORED:
        assert name not in summary, name
        # a study's files: its evaluations (results/<name>-...), figures (figures/<name>-...) and policies
        # (policies/<experiment>-<arm>-...: the gain study's arms are kappa-nis, kappa-sqerr, gain-sup, gain-unsup)
        ours = [f["path"] for f in man["files"] if f["path"].split("/")[-1].startswith(f"{name}-")
                or (name == "gain" and re.search(r"-(kappa-nis|kappa-sqerr|gain-sup|gain-unsup)-", f["path"]))]
        assert not ours, (name, ours)


def test_recorded_commands_name_the_output_folder_as_typed():
    """The manifest records a job's ``--out`` under the folder the user typed (``data``), not the resolved path
    of the checkout that ran it; a path that only begins like the folder, and an absolute folder, stay as they are."""
    from pathlib import Path

    from adaptfilt.experiments.beyond import as_typed

    cmd = "adaptfilt train-gain ungm-ukf --seed 0 --out /w/c/data/beyond/policies/a.npz --out /w/c/data/beyond/b.npz"
    assert as_typed(cmd, Path("/w/c/data"), "data") == (
        "adaptfilt train-gain ungm-ukf --seed 0 --out data/beyond/policies/a.npz --out data/beyond/b.npz")
    assert as_typed(cmd, Path("/w/c/data"), "out/") == (
        "adaptfilt train-gain ungm-ukf --seed 0 --out out/beyond/policies/a.npz --out out/beyond/b.npz")
    assert as_typed(cmd, Path("/w/c/dat"), "data") == cmd  # not the folder, a prefix of its name
    assert as_typed(cmd, Path("/w/c/data"), "/w/c/data") == cmd


def _beyond_run_command(root: str, studies: tuple[str, ...]) -> str:
    from adaptfilt.experiments.beyond import command

    return command(root, False, studies)


@pytest.mark.crosscpu
def test_every_command_the_beyond_manifest_records_is_the_one_the_pipeline_builds():
    """The guard of the move of the studies into one file each: each command in data/beyond/manifest.json, byte for byte, is
    what the pipeline builds for that file at full scale, run as the README says (``--out data`` from the
    checkout: no recorded path is absolute, so a command reruns on any machine); the run's files carry the
    ``adaptfilt beyond`` command of the run that wrote them, which must have chosen their study."""
    import re

    from adaptfilt.experiments import artefacts

    beyond_dir = artefacts.data_dir() / "beyond"
    man = json.loads((beyond_dir / "manifest.json").read_text())
    selection = json.loads((beyond_dir / "summary.json").read_text())["sif-selection"]
    assert man["scale"] == "full" and selection["seed"] == 1
    built = {}  # by the root the record names
    for entry in man["files"]:
        rel, cmd = entry["path"], entry["command"]
        if rel.startswith("policies/"):  # adaptfilt train, imitate, or train-gain (one line for its snapshots)
            m = re.search(r"^adaptfilt (?:train(?:-gain)?|imitate) .* --out (\S+)/beyond/" + re.escape(rel) + "(?: |$)",
                          cmd)
            assert m, (rel, cmd)
            root = m.group(1)
            assert root == "data", (rel, cmd)
            built.setdefault(root, _beyond_policy_commands(root, selection))
            assert cmd == built[root][rel], rel
            continue
        if rel == "summary.json" and cmd == "adaptfilt beyond --out data --report-only":
            continue  # its verdicts judged again by the one rule, nothing trained or evaluated
        m = re.fullmatch(r"adaptfilt beyond --out (\S+)(?: --studies (\S+))?", cmd)
        assert m and m.group(1) == "data", (rel, cmd)
        studies = tuple(m.group(2).split(",")) if m.group(2) else ()
        assert cmd == _beyond_run_command(m.group(1), studies), rel
        study = {"look-gain.png": "look", "particles-tradeoff.png": "particles"}.get(
            rel.split("/")[-1], rel.split("/")[1].split("-")[0] if "/" in rel else None)
        assert study is None or study in studies, rel
    assert len(man["files"]) == 758 and len([f for f in man["files"] if f["path"].startswith("policies/")]) == 688
    # and the studies train nothing the manifest lacks
    assert set(next(iter(built.values()))) == {f["path"] for f in man["files"] if f["path"].startswith("policies/")}


def test_every_study_is_one_file_with_a_word_on_the_command_line():
    """``--studies`` takes exactly the studies that have a file in adaptfilt/experiments/studies, and each
    file implements the whole interface (what it trains, evaluates, its rows, figures and tables)."""
    import inspect
    from pathlib import Path

    from adaptfilt.experiments import studies
    from adaptfilt.experiments.beyond import STUDIES
    from adaptfilt.experiments.study import Study

    files = {p.stem for p in Path(studies.__file__).parent.glob("*.py")} - {"__init__"}
    assert set(STUDIES) == set(studies.BY_NAME) == files
    wanted = {n for n, _ in inspect.getmembers(Study, inspect.isfunction) if not n.startswith("_")}
    assert wanted == {"prepare", "policies", "evaluations", "rows", "figures", "markdown"}
    for s in studies.ALL:
        assert all(callable(getattr(s, n, None)) for n in wanted), s.NAME
        assert s.markdown({}) == "" and s.NAME == Path(s.__file__).stem


def test_merged_evaluation_parts_keep_their_order_and_must_agree():
    from adaptfilt.results import Results

    a, b = Results({"n_runs": 5, "experiment": "x"}, {"p": 1, "q": 2}), Results({"n_runs": 5, "experiment": "x"}, {"r": 3})
    merged = Results.merge([a, b])
    assert merged.names == ["p", "q", "r"] == merged.config["policies"]
    with pytest.raises(RuntimeError, match="parts of the x evaluation disagree on n_runs"):
        Results.merge([Results({"n_runs": 5, "experiment": "x"}, {}), Results({"n_runs": 6, "experiment": "x"}, {})])
    assert Results.merge([Results({"command": "a"}, {"p": 1}), Results({"command": "b"}, {"q": 1})],
                         ignore=("command",)).names == ["p", "q"]


@dataclass(frozen=True)
class _StubTraining:
    """A :class:`~adaptfilt.experiments.jobs.Training` that writes its files at once (``stop``: interrupts)."""

    kind: str
    seed: int
    outs: tuple[str, ...]
    experiment: str = "ungm-ukf"
    stop: bool = False

    @property
    def command(self) -> str:
        return f"adaptfilt {self.kind} ungm-ukf --seed {self.seed}" + "".join(f" --out {o}" for o in self.outs)

    @property
    def key(self) -> tuple[str, int]:
        return self.command, self.seed

    @property
    def outputs(self) -> tuple[str, ...]:
        return self.outs

    def run(self, progress: bool = False) -> dict:
        if self.stop:
            raise KeyboardInterrupt
        for o in self.outs:
            Path(o).write_text(self.command)
        return {o: {"command": self.command, "wall_time_s": None, "cpu_time_s": 1.0} for o in self.outs}


def test_a_rerun_after_an_interrupt_says_what_it_reused_of_each_kind_of_training(tmp_path, capsys):
    """The one training loop (``beyond._train``) runs both kinds of training (``adaptfilt train``,
    ``adaptfilt train-gain`` with several files) and says, per kind, how many the journal held after a stop."""
    from adaptfilt.experiments.beyond import JOURNAL, _train
    from adaptfilt.experiments.journal import Journal
    from adaptfilt.experiments.study import QUICK, Run

    out = tmp_path / "beyond"
    (out / "policies").mkdir(parents=True)

    def gain(s, **kw):
        return _StubTraining("train-gain", s, tuple(str(out / f"policies/g-b{b}-s{s}.npz") for b in (1, 2)), **kw)

    kappa = _StubTraining("train", 0, (str(out / "policies/k-s0.npz"),))
    run = Run(out, tmp_path, QUICK, True, "adaptfilt beyond", Journal(out / JOURNAL), workers=1, progress=True)
    with pytest.raises(KeyboardInterrupt):
        _train(run, [kappa, gain(0), gain(1), gain(2, stop=True)])
    capsys.readouterr()
    run = Run(out, tmp_path, QUICK, True, "adaptfilt beyond", Journal(out / JOURNAL), workers=1, progress=True)
    _train(run, [kappa, gain(0), gain(1), gain(2)])
    said = capsys.readouterr().out
    assert "[beyond] 0 policies to train, 1 finished by an earlier run (journal.jsonl), 0 listed in the manifest" in said
    assert ("[beyond] 1 learned-gain trainings (KalmanNet), 2 finished by an earlier run (journal.jsonl), 0 listed "
            "in the manifest") in said
    assert set(run.entries) == {"policies/k-s0.npz"} | {f"policies/g-b{b}-s{s}.npz" for b in (1, 2) for s in range(3)}
    assert run.entries["policies/g-b2-s1.npz"]["command"] == gain(1).command
