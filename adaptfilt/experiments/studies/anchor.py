r"""Study 5, ``anchor``: learned policies anchored on greedy (:mod:`adaptfilt.anchor`).

On the candidate-aware state (greedy is a function of its inputs), a residual over greedy's choice
(``adaptive-anchored``, gamma = 0.5), beside the same learner with gamma = 0 (``myopic-anchored``: all
else equal, so that the paired difference is what of the anchored gain is looking ahead, the rule of
chapter 8) and the candidate-aware policies of :mod:`~adaptfilt.experiments.studies.cand`, on runs no
choice of its recipe saw (:data:`ANCHOR_EVAL_SEED`).
"""
from __future__ import annotations

from adaptfilt.experiments.jobs import EvalSpec, TrainSpec
from adaptfilt.experiments.report import md_table
from adaptfilt.experiments.studies.cand import CAND_EXPERIMENTS
from adaptfilt.experiments.study import Run, diff_ci, evaluation, groups_md, save_each, study_rows

NAME = "anchor"
#: The anchored learner: a residual over greedy's choice (strength, KL weight and shield: the library's
#: defaults, recorded explicitly in each file's command).
ANCHOR = ("greedy", 3.0, 0.01, 1.0)
#: Evaluation seed: runs that no choice of its recipe saw (the recipe was tuned on selection runs, seed 1,
#: and its shield added after a first check on the evaluation runs of seed 0).
ANCHOR_EVAL_SEED = 2
#: The anchored groups: gamma = 0.5 (the recipe) and gamma = 0 (its myopic control).
KINDS = (("adaptive-anchored", 0.5), ("myopic-anchored", 0.0))


def prepare(run: Run) -> dict:
    return {}


def policies(run: Run, summary: dict) -> list[TrainSpec]:
    sc = run.scale
    return [TrainSpec(e, g, sc.episodes, s, str(run.out / rel), features=feats, horizon=sc.n_steps,
                      anchor=ANCHOR)
            for e, feats in CAND_EXPERIMENTS.items() for kind, g in KINDS for s in sc.seeds
            for rel in [f"policies/{e}-{kind}-s{s}.npz"]]


def evaluations(run: Run, summary: dict, trained: list[TrainSpec]) -> list[EvalSpec]:
    """Beside the candidate-aware policies there are (of this run or an earlier one)."""
    return [evaluation(NAME, e, [t.out for t in trained if t.experiment == e]
                       + [str(p) for p in sorted((run.out / "policies").glob(f"{e}-adaptive-cand-s*.npz"))],
                       run.scale, ("default", "ml", "greedy"), ANCHOR_EVAL_SEED) for e in CAND_EXPERIMENTS]


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    return {NAME: save_each(run, NAME, specs, values, _rows), "anchor-eval-seed": ANCHOR_EVAL_SEED}


def _rows(res) -> dict:
    """:func:`study_rows`, and gamma's effect on the anchored learner, paired over seeds and runs."""
    from adaptfilt.seed_stats import difference, seed_groups

    rows = study_rows(NAME, res)
    seeds = seed_groups(res.names)
    if seeds.get("adaptive-anchored") and seeds.get("myopic-anchored"):
        rows["adaptive-anchored"]["minus_myopic"] = {
            m: list(difference(res, seeds["adaptive-anchored"], seeds["myopic-anchored"], m)["iqm"])
            for m in ("cost", "objective", "rmse", "anees")}
    return rows


def figures(run: Run, summary: dict) -> list[str]:
    return []


def markdown(summary: dict) -> str:
    if NAME not in summary:
        return ""
    title = ("Learned policies anchored on greedy (adaptive-anchored, gamma = 0.5; myopic-anchored, gamma = 0), "
             f"evaluated on runs of seed {summary.get('anchor-eval-seed', ANCHOR_EVAL_SEED)}")
    lines = groups_md(title, summary[NAME])
    metrics = ("cost", "objective", "rmse", "anees")
    paired = [(e, rows["adaptive-anchored"]["minus_myopic"]) for e, rows in summary[NAME].items()
              if "minus_myopic" in rows.get("adaptive-anchored", {})]
    if paired:
        lines += ["", *md_table(["experiment", "adaptive-anchored - myopic-anchored, IQM [seed-level 95 % CI]",
                                 "cost", "log(1+L)", "RMSE", "ANEES"])]
        lines += [f"| {e} | | " + " | ".join(diff_ci(x[m]) for m in metrics) + " |" for e, x in paired]
    return "\n".join(lines) + "\n"
