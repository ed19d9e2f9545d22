r"""Study 1, ``cand``: the candidate-aware information state.

The paper's information state cannot see what the exhaustive greedy policy sees (on UNGM the innovation
feature is the same for every kappa). Policies that also see every grid value's one-step cost
(``features=...+cand``, :mod:`adaptfilt.features`) are trained with gamma 0.5 (``adaptive-cand``) and
gamma 0 (``myopic-cand``, the control: it should land on greedy) on UNGM-UKF and CTM-UKF, and compared with
greedy and ML on the cost, the objective, RMSE and ANEES.
"""
from __future__ import annotations

from adaptfilt.experiments.jobs import EvalSpec, TrainSpec
from adaptfilt.experiments.study import Run, evaluation, groups_md, save_each, study_rows

NAME = "cand"
#: The learner of the candidate study (chosen by the measurement reported in REPRODUCTION.md).
CAND_ALGO = "fast"
#: experiment -> the candidate-aware features (the ``anchor`` study trains on them too).
CAND_EXPERIMENTS = {"ungm-ukf": "paper+time+cand", "ctm-ukf": "paper+circ+cand"}
KINDS = (("adaptive-cand", 0.5), ("myopic-cand", 0.0))
TITLE = "Candidate-aware information state"


def prepare(run: Run) -> dict:
    return {}


def policies(run: Run, summary: dict) -> list[TrainSpec]:
    sc = run.scale
    return [TrainSpec(e, g, sc.episodes, s, str(run.out / rel), algo=CAND_ALGO, features=feats, horizon=sc.n_steps)
            for e, feats in CAND_EXPERIMENTS.items() for kind, g in KINDS for s in sc.seeds
            for rel in [f"policies/{e}-{kind}-s{s}.npz"]]


def evaluations(run: Run, summary: dict, trained: list[TrainSpec]) -> list[EvalSpec]:
    return [evaluation(NAME, e, [t.out for t in trained if t.experiment == e], run.scale,
                       ("default", "ml", "greedy")) for e in CAND_EXPERIMENTS]


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    return {NAME: save_each(run, NAME, specs, values, lambda res: study_rows(NAME, res))}


def figures(run: Run, summary: dict) -> list[str]:
    return []


def markdown(summary: dict) -> str:
    return "\n".join(groups_md(TITLE, summary[NAME])) + "\n" if NAME in summary else ""
