r"""Study 4, ``raw``: training on the untransformed cost.

The learners minimise the mean of ``log(1 + L)``, while the costs reported are means of ``L``, set by rare
large steps. Policies trained on ``-L`` itself (``adaptive-raw``, gamma 0.5, the fast mode,
``--cost-transform none``) on UNGM-UKF and CTM-UKF, against the reproduction's adaptive policies (trained on
``log(1 + L)``), greedy, ML and the default, on the same runs.
"""
from __future__ import annotations

from adaptfilt.experiments.jobs import EvalSpec, TrainSpec
from adaptfilt.experiments.report import md_table
from adaptfilt.experiments.study import Run, diff_ci, evaluation, groups_md, save_each, study_rows

NAME = "raw"
RAW_EXPERIMENTS = ("ungm-ukf", "ctm-ukf")
TITLE = "Training on the untransformed cost (adaptive-raw) against log(1 + L) (adaptive)"


def prepare(run: Run) -> dict:
    return {}


def policies(run: Run, summary: dict) -> list[TrainSpec]:
    sc = run.scale
    return [TrainSpec(e, 0.5, sc.episodes, s, str(run.out / rel), horizon=sc.n_steps, cost_transform="none")
            for e in RAW_EXPERIMENTS for s in sc.seeds for rel in [f"policies/{e}-adaptive-raw-s{s}.npz"]]


def evaluations(run: Run, summary: dict, trained: list[TrainSpec]) -> list[EvalSpec]:
    """Beside the reproduction's policies, trained on log(1 + L) with the same recipe."""
    return [evaluation(NAME, e, [t.out for t in trained if t.experiment == e] + run.reproduction(e),
                       run.scale, ("default", "ml", "greedy")) for e in RAW_EXPERIMENTS]


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    return {NAME: save_each(run, NAME, specs, values, lambda res: study_rows(NAME, res))}


def figures(run: Run, summary: dict) -> list[str]:
    return []


def markdown(summary: dict) -> str:
    if NAME not in summary:
        return ""
    lines = groups_md(TITLE, summary[NAME])
    metrics = ("cost", "objective", "rmse", "anees")
    paired = [(e, rows["adaptive-raw"]["minus_adaptive"]) for e, rows in summary[NAME].items()
              if "minus_adaptive" in rows.get("adaptive-raw", {})]
    if paired:
        lines += ["", *md_table(["experiment", "adaptive-raw - adaptive, IQM [seed-level 95 % CI]", "cost", "log(1+L)",
                                 "RMSE", "ANEES"])]
        lines += [f"| {e} | | " + " | ".join(diff_ci(x[m]) for m in metrics) + " |"
                  for e, x in paired]
    return "\n".join(lines) + "\n"
