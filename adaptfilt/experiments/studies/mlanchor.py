r"""Study 9, ``mlanchor``: the CTM's open question. A learned policy below maximum likelihood, or a measured
reason why none gets there.

On the CTM, maximum likelihood (ML), a one-step rule that does not minimise the cost, has a mean cost about
20 % below greedy's, the one-step optimum: its choices pay later, the non-myopic effect the paper is about.
Every learner of studies 1-5 sits at or above greedy. This study asks why, in four parts.

**1. Learners anchored on ML** (:mod:`adaptfilt.anchor` with ``anchor="ml"``; the anchor study's recipe
otherwise: strength 3, KL weight 0.01, shield 1, the candidate-aware state, the fast mode, 1000 episodes,
8 seeds): ``adaptive-mlanchored`` (gamma = 0.5) and its control ``myopic-mlanchored`` (gamma = 0, all else
equal: what of any gain is looking ahead) on UNGM-UKF and CTM-UKF; on the CTM also trained on the
untransformed cost ``L`` (``-raw``, both gammas), the mean of which is what the verdicts judge.
The likelihood-aware learner of part 3 at the main budget (``adaptive-lik-e1000``) gets its gamma = 0 control
too (``myopic-lik-e1000``, :data:`LIK_CONTROL`), evaluated on the same runs.

**Objectives probed and not adopted** (declared here before the evaluation runs were touched):
``benchmarks/bench_mlanchor_objective.py`` trained the ML-anchored learner on the CTM (gamma = 0.5,
1000 episodes, seeds 0-3) with four objectives and measured them on 2000 selection runs (seed 1, not the
evaluation's). IQM over seeds minus ML in mean cost [seed-level 95 % CI]: ``log(1 + L)`` -0.09
[-0.77, +0.45]; ``log(1 + L)`` with the reward scaled by its running spread (SB3's ``VecNormalize``)
+0.16 [-0.59, +0.80]; ``L`` so scaled +0.05 [-0.11, +0.34]; ``log(1 + L)`` with gamma = 0.9 +0.35
[-0.30, +0.98]. None was better than ``log(1 + L)`` at gamma = 0.5, so no third objective is trained.

**2. Can the network represent ML's choice?** (:mod:`adaptfilt.imitation`) On the CTM, the learner's
actor network fitted by supervised imitation of ML (cross-entropy on the states ML visits, 2000 runs of
which the last 20 % held out) from three information states: the reproduction's learner's
(``imitation-paper``: ``paper+circ``), the candidate-aware learners' (``imitation-cand``: ``+cand``, greedy's
inputs) and the same with the candidates' log-likelihoods (``imitation-lik``: ``+lik``, what ML ranks);
8 seeds each (data, initialisation, minibatches). Their held-out accuracy is in each file's metadata; the
fitted policies are evaluated as any policy.

**3. Objective, exploration or budget?** The learning curve on the CTM: each learner's cost on 2000
selection runs (seed :data:`SELECTION_SEED`) at the budgets :data:`CURVE_EPISODES` against ML's and
greedy's: the reproduction's learner (``adaptive``: paper+circ, log(1 + L); its files are the
reproduction's at 1000 episodes and the gain study's ``kappa-nis`` ones at the other budgets, the same
recipe), a learner that sees the candidates' log-likelihoods (``adaptive-lik``: the features from which
imitation reaches ML), trained from scratch by PPO, and the ML-anchored learner (which starts at ML).

**4. Verdicts** at the seed level on 10^4 runs of seed :data:`EVAL_SEED` (the anchor study's: no choice of
the recipe saw them) against greedy and ML (:func:`adaptfilt.verdicts.verdict`, "lower" with margin 0: the
seed-level interval of the paired difference below 0, the issue's criterion), the gamma = 0 control beside every
gamma = 0.5 group; RMSE and ANEES "not worse" than ML's with the margins declared for ``"learned vs ML"``
(:data:`adaptfilt.verdicts.DECLARED_MARGINS`: a lower cost bought with a worse track would not answer the question);
against the rollout references in the ``look`` study, on its runs (seed 0, M = 2000), where these groups are
a part of their own (:data:`LOOK_GROUPS`).
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from adaptfilt.experiments.jobs import EvalSpec, TrainSpec
from adaptfilt.experiments.report import md_table
from adaptfilt.experiments.studies.anchor import ANCHOR_EVAL_SEED
from adaptfilt.experiments.studies.cand import CAND_EXPERIMENTS
from adaptfilt.experiments.studies.sif import SELECTION_SEED
from adaptfilt.experiments.study import (COMPACT, Run, diff_ci, evaluation, groups_md, listed_policies, same_training,
                                         study_rows)

NAME = "mlanchor"
#: The anchored learner of the anchor study with ML's choice as its anchor: (anchor, strength, KL weight, shield).
ANCHOR = ("ml", 3.0, 0.01, 1.0)
#: The evaluation seed (the anchor study's).
EVAL_SEED = ANCHOR_EVAL_SEED
#: The anchored groups: (group, gamma, cost transform, experiments).
KINDS = (("adaptive-mlanchored", 0.5, "log1p", tuple(CAND_EXPERIMENTS)),
         ("myopic-mlanchored", 0.0, "log1p", tuple(CAND_EXPERIMENTS)),
         ("adaptive-mlanchored-raw", 0.5, "none", ("ctm-ukf",)),
         ("myopic-mlanchored-raw", 0.0, "none", ("ctm-ukf",)))
#: The gamma = 0.5 groups and their gamma = 0 controls.
CONTROLS = {"adaptive-mlanchored": "myopic-mlanchored", "adaptive-mlanchored-raw": "myopic-mlanchored-raw",
            "adaptive-lik-e1000": "myopic-lik-e1000"}
#: The imitation fits: group -> the information state (CTM).
IMITATION = {"imitation-paper": "paper+circ", "imitation-cand": "paper+circ+cand", "imitation-lik": "paper+circ+cand+lik"}
#: Runs of ML's trajectories per fit (the last 20 % held out) and epochs, per scale.
IMITATION_SIZE = {"full": (2000, 100), "quick": (40, 2)}
#: The learner that sees the candidates' log-likelihoods (trained by PPO from scratch).
LIK_FEATURES = "paper+circ+cand+lik"
#: Training budgets of the learning curve (episodes), per scale: the gain study's CTM budgets and the
#: reproduction's 1000.
CURVE_EPISODES = {"full": (300, 1000, 2500, 10300), "quick": (4, 10)}
#: The episodes of the first learned-gain study's CTM kappa-nis files (``policies/ctm-ukf-kappa-nis-b<b>-s<s>.npz``,
#: the fast mode's recipe, per scale), points of the learning curve where they exist; the study that replaced it
#: writes its own files under ``policies/gain-...``.
FIRST_GAIN_STUDY_KAPPA_NIS = {"full": (300, 2500, 10300), "quick": (2, 4, 6)}
#: Selection runs of the learning curve, per scale.
CURVE_RUNS = {"full": 2000, "quick": 100}
#: The groups the look study shows on its runs (where the files exist).
LOOK_GROUPS = ("adaptive-mlanchored", "myopic-mlanchored", "adaptive-mlanchored-raw", "myopic-mlanchored-raw",
               "imitation-paper", "imitation-cand", "imitation-lik", "adaptive-lik-e1000")
#: The declared comparison (:data:`adaptfilt.verdicts.DECLARED_MARGINS`) whose margins judge each group's RMSE
#: and ANEES "not worse" than ML's.
NOT_WORSE_THAN_ML = "learned vs ML"
#: The learned groups of the final evaluation, in table order.
GROUPS = tuple(k for k, *_ in KINDS) + tuple(IMITATION) + ("adaptive-lik-e1000", "myopic-lik-e1000")
#: The likelihood-aware learner's gamma = 0 control (at the main budget): evaluated as a part of its own on the
#: final evaluation's runs (the same seed: the same runs and resamples) and merged into it.
LIK_CONTROL = "myopic-lik"


def _size(run: Run) -> str:
    return "quick" if run.quick else "full"


# ------------------------------------------------------------------ imitation (prepare)
def imitation_rel(experiment: str, group: str, seed: int) -> str:
    return f"policies/{experiment}-{group}-s{seed}.npz"


def _imitation_commands(run: Run, seed: int) -> dict[str, str]:
    from adaptfilt.imitation import imitation_command

    runs, epochs = IMITATION_SIZE[_size(run)]
    return {g: imitation_command("ctm-ukf", fs, seed, runs=runs, epochs=epochs, n_steps=run.scale.n_steps,
                                 out=str(run.out / imitation_rel("ctm-ukf", g, seed)))
            for g, fs in IMITATION.items()}


def imitation_files(run: Run) -> dict[str, str]:
    """Every imitation policy of the run (``policies/...``) and the command its manifest entry records."""
    return {imitation_rel("ctm-ukf", g, s): c for s in run.scale.seeds for g, c in _imitation_commands(run, s).items()}


def imitation_job(seed: int, runs: int, epochs: int, n_steps: int | None, paths: dict[str, str],
                  commands: dict[str, str]) -> dict:
    """Fit the three imitation policies of ``seed`` on the same ML trajectories and save them to ``paths``
    (group -> file); returns per file its CPU-s (the fit's and a third of the trajectories') and accuracies."""
    from adaptfilt.imitation import imitate, teacher_data

    c0 = time.process_time()
    data = teacher_data("ctm-ukf", list(IMITATION.values()), seed, runs=runs, n_steps=n_steps)
    share = (time.process_time() - c0) / len(IMITATION)
    out = {}
    for g, fs in IMITATION.items():
        c1 = time.process_time()
        pol = imitate("ctm-ukf", fs, seed, runs=runs, epochs=epochs, n_steps=n_steps, data=data, name=f"{g}-s{seed}",
                      command=commands[g])
        pol.save(paths[g])
        info = pol.metadata["imitation"]
        out[paths[g]] = {"cpu_time_s": share + time.process_time() - c1, "heldout_accuracy": info["heldout_accuracy"],
                         "fit_accuracy": info["fit_accuracy"]}
    return out


def prepare(run: Run) -> dict:
    """The imitation fits (CTM), one journaled job per seed; files the manifest lists with the same command and
    sha256 are reused."""
    runs, epochs = IMITATION_SIZE[_size(run)]
    listed = listed_policies(run.out)
    jobs, keys, files = [], [], []
    for s in run.scale.seeds:
        cmds = _imitation_commands(run, s)
        rels = {g: imitation_rel("ctm-ukf", g, s) for g in IMITATION}
        if all(same_training(listed.get(rels[g]), cmds[g], run.out / rels[g]) for g in IMITATION):
            continue
        paths = {g: str(run.out / r) for g, r in rels.items()}
        jobs.append((s, runs, epochs, run.scale.n_steps, paths, cmds))
        keys.append((" ; ".join(cmds.values()), s))
        files.append(list(paths.values()))
    run.say(f"[beyond] mlanchor: {len(jobs)} imitation jobs ({len(IMITATION)} fits each)")
    values = run.jobs(imitation_job, jobs, keys, files=files, progress=run.progress, desc="beyond: imitation")
    for (s, *_, paths, cmds), v in zip(jobs, values):
        for g, p in paths.items():
            run.entries[str(Path(p).relative_to(run.out))] = {"command": cmds[g], "cpu_time_s": v[p]["cpu_time_s"]}
    return {}


# ------------------------------------------------------------------ trainings
def _curve_rel(learner: str, episodes: int, seed: int) -> str:
    return f"policies/ctm-ukf-{learner}-e{episodes}-s{seed}.npz"


def policies(run: Run, summary: dict) -> list[TrainSpec]:
    """The anchored groups (:data:`KINDS`) and the learning curve's trainings: the likelihood-aware learner at
    every budget, the ML-anchored one at every budget but the main one (its main group is that point), and the
    reproduction's learner at :data:`FIRST_GAIN_STUDY_KAPPA_NIS`."""
    sc = run.scale
    out = []
    for kind, g, transform, exps in KINDS:
        for e in exps:
            for s in sc.seeds:
                out.append(TrainSpec(e, g, sc.episodes, s, str(run.out / f"policies/{e}-{kind}-s{s}.npz"),
                                     features=CAND_EXPERIMENTS[e], horizon=sc.n_steps, cost_transform=transform,
                                     anchor=ANCHOR))
    out += [TrainSpec("ctm-ukf", 0.0, sc.episodes, s, str(run.out / _curve_rel(LIK_CONTROL, sc.episodes, s)),
                      features=LIK_FEATURES, horizon=sc.n_steps) for s in sc.seeds]
    for ep in CURVE_EPISODES[_size(run)]:
        for s in sc.seeds:
            out.append(TrainSpec("ctm-ukf", 0.5, ep, s, str(run.out / _curve_rel("adaptive-lik", ep, s)),
                                 features=LIK_FEATURES, horizon=sc.n_steps))
            if ep != sc.episodes:
                out.append(TrainSpec("ctm-ukf", 0.5, ep, s, str(run.out / _curve_rel("adaptive-mlanchored", ep, s)),
                                     features=CAND_EXPERIMENTS["ctm-ukf"], horizon=sc.n_steps, anchor=ANCHOR))
    # the reproduction's learner (the fast mode) at the first learned-gain study's CTM budgets, under that study's
    # file names: made by it, kept as this curve's points when the study that replaced it wrote its own files
    out += [TrainSpec("ctm-ukf", 0.5, ep, s, str(run.out / f"policies/ctm-ukf-kappa-nis-b{b}-s{s}.npz"),
                      horizon=sc.n_steps)
            for b, ep in enumerate(FIRST_GAIN_STUDY_KAPPA_NIS[_size(run)], start=1) for s in sc.seeds]
    return out


# ------------------------------------------------------------------ evaluations
def curve_files(run: Run) -> dict[str, tuple[str, int, list[str]]]:
    """The learning curve's seed groups: group name in the evaluation -> (learner, episodes, files that exist)."""
    sc, budgets = run.scale, CURVE_EPISODES[_size(run)]
    out = {}
    for ep in budgets:
        out[f"adaptive-lik-e{ep}"] = ("adaptive-lik", ep, [run.out / _curve_rel("adaptive-lik", ep, s) for s in sc.seeds])
        anchored = [run.out / (f"policies/ctm-ukf-adaptive-mlanchored-s{s}.npz" if ep == sc.episodes else
                               _curve_rel("adaptive-mlanchored", ep, s)) for s in sc.seeds]
        out["adaptive-mlanchored" if ep == sc.episodes else f"adaptive-mlanchored-e{ep}"] = ("adaptive-mlanchored", ep, anchored)
    # the reproduction's learner: its own files at its budget, the first learned-gain study's kappa-nis (the same
    # recipe, the fast mode's) at that study's budgets, where they exist
    out["adaptive"] = ("adaptive", sc.episodes, [run.data / f"policies/ctm-ukf-adaptive-s{s}.npz" for s in sc.seeds])
    for b, ep in enumerate(FIRST_GAIN_STUDY_KAPPA_NIS[_size(run)], start=1):
        if ep in budgets and ep != sc.episodes:
            out[f"kappa-nis-b{b}"] = ("adaptive", ep, [run.out / f"policies/ctm-ukf-kappa-nis-b{b}-s{s}.npz"
                                                       for s in sc.seeds])
    return {g: (lr, ep, [str(f) for f in fs if Path(f).exists()]) for g, (lr, ep, fs) in out.items()}


def evaluations(run: Run, summary: dict, trained: list[TrainSpec]) -> list[EvalSpec]:
    """The final evaluation per experiment (10^4 runs of :data:`EVAL_SEED`) and the learning curve (CTM, selection
    runs)."""
    specs, control = [], f"{LIK_CONTROL}-e{run.scale.episodes}"
    for e in CAND_EXPERIMENTS:
        files = [str(run.out / f"policies/{e}-{g}-s{s}.npz") for g in GROUPS if g != control for s in run.scale.seeds]
        files = [f for f in files if Path(f).exists()]  # the study's own: trained (or fitted) before this phase
        specs.append(evaluation(NAME, e, files, run.scale, ("default", "ml", "greedy"), EVAL_SEED))
    # the likelihood-aware learner's gamma = 0 control: its own job on the same runs, merged into the CTM's
    files = [str(run.out / _curve_rel(LIK_CONTROL, run.scale.episodes, s)) for s in run.scale.seeds]
    spec = evaluation(NAME, "ctm-ukf", [f for f in files if Path(f).exists()], run.scale, ("ml",), EVAL_SEED)
    specs.append(dataclasses.replace(spec, tag="control"))
    curve = curve_files(run)
    scale = dataclasses.replace(run.scale, eval_runs=CURVE_RUNS[_size(run)])
    spec = evaluation(NAME, "ctm-ukf", [f for _, _, fs in curve.values() for f in fs], scale,
                      ("default", "ml", "greedy"), SELECTION_SEED)
    specs.append(dataclasses.replace(spec, tag={g: [lr, ep] for g, (lr, ep, fs) in curve.items() if fs}))
    return specs


# ------------------------------------------------------------------ rows
def _final_rows(res, files: list[str]) -> dict:
    """:func:`study_rows` for the study's groups, and each group against ML, its gamma = 0 control, with the
    seed-level verdicts (:func:`adaptfilt.verdicts.verdict`: "lower" at all, margin 0; RMSE and ANEES "not worse"
    than ML's with the margins declared for :data:`NOT_WORSE_THAN_ML`); the imitation groups' held-out accuracy
    (from their files)."""
    from adaptfilt.learned import load_policy
    from adaptfilt.seed_stats import difference, seed_groups
    from adaptfilt.verdicts import judge, verdict

    rows = study_rows(NAME, res, groups=GROUPS)
    seeds = seed_groups(res.names)
    metrics = ("cost", "objective", "rmse", "anees")
    for g in GROUPS:
        if g not in rows:
            continue
        r = rows[g]
        r["minus_ml"] = {m: list(difference(res, seeds[g], ["ml"], m)["iqm"]) for m in metrics}
        r["verdict"] = {"below greedy": verdict("lower", r["minus_greedy"]["cost"]),
                        "below ml": verdict("lower", r["minus_ml"]["cost"])}
        for m in ("rmse", "anees"):  # a margin around ML's value, as declared
            word, margin = judge("not worse", r["minus_ml"][m], NOT_WORSE_THAN_ML, m, getattr(res["ml"], m))
            r["verdict"][f"{m} not worse than ml"] = word
            r.setdefault("margin_vs_ml", {})[m] = margin
        r["seeds_below_ml"] = int(sum(verdict("lower", res.paired_difference(n, "ml", "cost")) == "confirmed"
                                      for n in seeds[g]))
        if g in CONTROLS and CONTROLS[g] in seeds:
            r["minus_myopic"] = {m: list(difference(res, seeds[g], seeds[CONTROLS[g]], m)["iqm"]) for m in metrics}
            r["verdict"]["below its gamma = 0 control"] = verdict("lower", r["minus_myopic"]["cost"])
        if g in IMITATION:
            by_name = {Path(f).stem.split("ctm-ukf-", 1)[-1]: f for f in files}
            acc = [load_policy(by_name[n]).metadata["imitation"] for n in seeds[g]]
            r["imitation"] = {k: [a[k] for a in acc] for k in ("heldout_accuracy", "fit_accuracy", "majority_accuracy",
                                                               "best_epoch")}
    return rows


def _curve_rows(res, groups: dict) -> dict:
    """The learning curve: per learner and budget, IQM cost and log(1 + L) over seeds, and against ML and greedy."""
    from adaptfilt.seed_stats import aggregate, difference, seed_groups

    seeds = seed_groups(res.names)
    out = {"n_runs": res.config["n_runs"], "seed": res.config["seed"],
           "reference": {n: {"cost": res[n].cost, "objective": res[n].objective} for n in ("ml", "greedy", "default")},
           "learners": {}}
    for g, (learner, ep) in groups.items():
        if g not in seeds:
            continue
        row = {"group": g, "n_seeds": len(seeds[g])}
        for m in ("cost", "objective"):
            row[m] = aggregate(res, seeds[g], m).to_dict()
            for ref in ("ml", "greedy"):
                row.setdefault(f"minus_{ref}", {})[m] = list(difference(res, seeds[g], [ref], m)["iqm"])
        out["learners"].setdefault(learner, {})[str(ep)] = row
    for learner in out["learners"]:
        out["learners"][learner] = dict(sorted(out["learners"][learner].items(), key=lambda kv: int(kv[0])))
    return out


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    from adaptfilt.results import Results

    final, curve = {}, None
    control = {s.experiment: (s, v) for s, v in zip(specs, values) if s.tag == "control"}
    for spec, res in zip(specs, values):
        if spec.tag == "control":
            continue
        if spec.tag is None:
            files = spec.args[1]
            if spec.experiment in control:  # the same runs: the merge is exact
                cspec, cres = control[spec.experiment]
                res, files = Results.merge([res, cres]), files + cspec.args[1]
            run.save(f"{NAME}-{spec.experiment}", res, drop=COMPACT)
            final[spec.experiment] = _final_rows(res, files)
        else:
            run.save(f"{NAME}-{spec.experiment}-curve", res, drop=COMPACT)
            curve = _curve_rows(res, spec.tag)
    return {NAME: {"final": final, "curve": curve, "eval-seed": EVAL_SEED, "selection-seed": SELECTION_SEED}}


# ------------------------------------------------------------------ figures and tables
#: The learning curve's labels and colours.
CURVE_STYLE = {"adaptive": ("the reproduction's learner (paper+circ)", "C0"),
               "adaptive-lik": ("sees the candidates' likelihoods (+cand+lik)", "C2"),
               "adaptive-mlanchored": ("anchored on ML (+cand)", "C1")}


def plot_curve(curve: dict, axes=None):
    """The learning curve: each learner's IQM over seeds (seed-level 95 % interval) against its training
    episodes, on the mean cost and on log(1 + L), with ML's and greedy's level on the same runs."""
    import matplotlib.pyplot as plt

    if axes is None:
        fig, axes = plt.subplots(1, 2, figsize=(10.4, 4.0), layout="constrained")
    fig = axes[0].figure
    for ax, m, label in zip(axes, ("cost", "objective"), ("mean cost L", "mean log(1 + L)")):
        for learner, by_ep in curve["learners"].items():
            name, col = CURVE_STYLE.get(learner, (learner, "C4"))
            ep = np.array([int(k) for k in by_ep])
            v = np.array([r[m]["iqm"] for r in by_ep.values()])
            lo, hi = (np.array([r[m]["iqm_ci"][i] for r in by_ep.values()]) for i in (0, 1))
            ax.errorbar(ep, v, yerr=[v - lo, hi - v], fmt="o-", color=col, capsize=3, label=name)
        for ref, ls in (("ml", "-"), ("greedy", "--")):
            ax.axhline(curve["reference"][ref][m], color="black", ls=ls, lw=1, label=f"{ref} (one-step rule)")
        ax.set_xscale("log")
        ax.set(xlabel="training episodes (log scale)", ylabel=label,
               title=f"CTM-UKF, {curve['n_runs']} selection runs (seed {curve['seed']})")
    axes[0].legend(fontsize=8)
    return fig


def plot_imitation(final: dict, axes=None):
    """Each imitation policy (one point per seed) at its held-out agreement with ML against its mean cost on the
    evaluation runs, one colour per information state; ML's and greedy's cost as lines."""
    import matplotlib.pyplot as plt

    rows = final["ctm-ukf"]
    if axes is None:
        fig, axes = plt.subplots(figsize=(6.0, 4.2), layout="constrained")
    ax = axes
    for i, (g, fs) in enumerate(IMITATION.items()):
        if g not in rows:
            continue
        acc = np.array(rows[g]["imitation"]["heldout_accuracy"])
        ax.plot(100 * acc, rows[g]["cost"]["values"], "o", color=f"C{i + 3}", label=f"{g} ({fs})")
    for ref, ls in (("ml", "-"), ("greedy", "--")):
        ax.axhline(rows[ref]["cost"], color="black", ls=ls, lw=1, label=ref)
    ax.set_yscale("log")
    ax.set(xlabel="held-out agreement with ML's choice (%)", ylabel="mean cost L on the evaluation runs (log scale)",
           title="CTM-UKF: the actor network fitted to ML's choices")
    ax.legend(fontsize=8)
    return ax.figure


def figures(run: Run, summary: dict) -> list[str]:
    s = summary[NAME]
    out = []
    if s.get("curve"):
        out.append(run.figure(plot_curve(s["curve"]), f"{NAME}-curve.png"))
    if "ctm-ukf" in s.get("final", {}) and any(g in s["final"]["ctm-ukf"] for g in IMITATION):
        out.append(run.figure(plot_imitation(s["final"]), f"{NAME}-imitation.png"))
    return out


def markdown(summary: dict) -> str:
    if NAME not in summary:
        return ""
    s = summary[NAME]
    title = (f"The CTM's open question: learners anchored on ML, imitation of ML (evaluated on runs of seed "
             f"{s['eval-seed']})")
    lines = groups_md(title, s["final"])
    lines += ["", *md_table(["experiment", "group", "cost - ML, IQM [seed-level 95 % CI]", "log(1+L) - ML",
                             "RMSE - ML", "below greedy?", "below ML?", "seeds below ML alone",
                             "gamma 0.5 - gamma 0 (cost)", "below its control?"])]
    for e, rows in s["final"].items():
        for g in GROUPS:
            if g not in rows:
                continue
            r = rows[g]
            my = r.get("minus_myopic")
            lines.append(f"| {e} | {g} | {diff_ci(r['minus_ml']['cost'])} | {diff_ci(r['minus_ml']['objective'])} "
                         f"| {diff_ci(r['minus_ml']['rmse'])} | {r['verdict']['below greedy']} | {r['verdict']['below ml']} "
                         f"| {r['seeds_below_ml']} of {len(r['cost']['values'])} | {diff_ci(my['cost']) if my else ''} "
                         f"| {r['verdict'].get('below its gamma = 0 control', '')} |")
    im = {g: r["imitation"] for g, r in s["final"].get("ctm-ukf", {}).items() if "imitation" in r}
    if im:
        lines += ["", "**Imitation of ML's choice** (CTM; held-out agreement per seed; a constant at ML's commonest "
                  "choice would agree as often as 'majority')", "",
                  *md_table(["group", "information state", "held-out agreement (IQM, min-max)", "majority"])]
        for g, a in im.items():
            acc = np.array(a["heldout_accuracy"])
            lines.append(f"| {g} | {IMITATION[g]} | {100 * _iqm(acc):.1f} % ({100 * acc.min():.1f}-{100 * acc.max():.1f}) "
                         f"| {100 * np.mean(a['majority_accuracy']):.1f} % |")
    c = s.get("curve")
    if c:
        lines += ["", f"**Learning curve** (CTM, {c['n_runs']} selection runs of seed {c['seed']}; ML {c['reference']['ml']['cost']:.4g}, "
                  f"greedy {c['reference']['greedy']['cost']:.4g}; IQM over seeds [seed-level 95 % CI])", "",
                  *md_table(["learner", "episodes", "cost", "cost - ML", "log(1+L) - ML"])]
        for learner, by_ep in c["learners"].items():
            for ep, r in by_ep.items():
                lines.append(f"| {learner} | {ep} | {r['cost']['iqm']:.4g} [{r['cost']['iqm_ci'][0]:.4g}, "
                             f"{r['cost']['iqm_ci'][1]:.4g}] | {diff_ci(r['minus_ml']['cost'])} "
                             f"| {diff_ci(r['minus_ml']['objective'])} |")
    return "\n".join(lines) + "\n"


def _iqm(x: np.ndarray) -> float:
    from adaptfilt.seed_stats import iqm

    return float(iqm(np.asarray(x, dtype=float)))
