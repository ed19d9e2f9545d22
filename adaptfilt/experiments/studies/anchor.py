r"""Study 5, ``anchor``: learned policies anchored on greedy (:mod:`adaptfilt.anchor`).

On the candidate-aware state (greedy is a function of its inputs), a residual over greedy's choice
(``adaptive-anchored``), beside the candidate-aware policies of :mod:`~adaptfilt.experiments.studies.cand`,
on runs no choice of its recipe saw (:data:`ANCHOR_EVAL_SEED`).
"""
from __future__ import annotations

from adaptfilt.experiments.jobs import EvalSpec, TrainSpec
from adaptfilt.experiments.studies.cand import CAND_EXPERIMENTS
from adaptfilt.experiments.study import Run, evaluation, groups_md, save_each, study_rows

NAME = "anchor"
#: The anchored learner: a residual over greedy's choice (strength, KL weight and shield: the library's
#: defaults, recorded explicitly in each file's command).
ANCHOR = ("greedy", 3.0, 0.01, 1.0)
#: Evaluation seed: runs that no choice of its recipe saw (the recipe was tuned on selection runs, seed 1,
#: and its shield added after a first check on the evaluation runs of seed 0).
ANCHOR_EVAL_SEED = 2


def prepare(run: Run) -> dict:
    return {}


def policies(run: Run, summary: dict) -> list[tuple[str, TrainSpec]]:
    sc = run.scale
    return [(rel, TrainSpec(e, 0.5, sc.episodes, s, str(run.out / rel), features=feats, horizon=sc.n_steps,
                            anchor=ANCHOR))
            for e, feats in CAND_EXPERIMENTS.items() for s in sc.seeds
            for rel in [f"policies/{e}-adaptive-anchored-s{s}.npz"]]


def evaluations(run: Run, summary: dict, trained: list[tuple[str, TrainSpec]]) -> list[EvalSpec]:
    """Beside the candidate-aware policies there are (of this run or an earlier one)."""
    return [evaluation(NAME, e, [str(run.out / rel) for rel, t in trained if t.experiment == e]
                       + [str(p) for p in sorted((run.out / "policies").glob(f"{e}-adaptive-cand-s*.npz"))],
                       run.scale, ("default", "ml", "greedy"), ANCHOR_EVAL_SEED) for e in CAND_EXPERIMENTS]


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    return {NAME: save_each(run, NAME, specs, values, lambda res: study_rows(NAME, res)),
            "anchor-eval-seed": ANCHOR_EVAL_SEED}


def figures(run: Run, summary: dict) -> list[str]:
    return []


def markdown(summary: dict) -> str:
    if NAME not in summary:
        return ""
    title = ("Learned policies anchored on greedy (adaptive-anchored), evaluated on runs of seed "
             f"{summary.get('anchor-eval-seed', ANCHOR_EVAL_SEED)}")
    return "\n".join(groups_md(title, summary[NAME])) + "\n"
