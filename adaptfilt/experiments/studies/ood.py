r"""Study 3, ``ood``: out of distribution and retuning. The science is :mod:`adaptfilt.experiments.ood`
(the mismatched truths, the retuning, the gain tables and heat maps); this file is what ``adaptfilt beyond``
runs of it.

The reproduction's adaptive UNGM-UKF policies (8 seeds) on a 3 x 3 grid of mismatched process and
measurement noise, against default, best fixed in hindsight and greedy; then retuned with 50 episodes on
each condition; heat maps of the gain over the default. Without the reproduction's policies it is skipped.
"""
from __future__ import annotations

from adaptfilt.experiments.jobs import EvalSpec, TrainSpec, job_key
from adaptfilt.experiments.report import md_table
from adaptfilt.experiments.study import Run

NAME = "ood"
EXPERIMENT = "ungm-ukf"


def condition_job(condition, files: list[str], scale, retune_seed: int = 0):
    """One condition: the stored policies, and each retuned there, on the same runs."""
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.jobs import load_learned
    from adaptfilt.experiments.ood import evaluate_condition, retune

    pols = load_learned(get_experiment(EXPERIMENT), files)
    tuned = [retune(p, EXPERIMENT, condition, episodes=scale.retune_episodes, seed=retune_seed, n_steps=scale.n_steps)
             for p in pols]
    for p, t in zip(pols, tuned):
        t.name = p.name.replace("adaptive-", "retuned-")
    return evaluate_condition(EXPERIMENT, condition, pols + tuned, n_runs=scale.eval_runs, n_steps=scale.n_steps)


def prepare(run: Run) -> dict:
    return {}


def policies(run: Run, summary: dict) -> list[TrainSpec]:
    return []


def evaluations(run: Run, summary: dict, trained: list[TrainSpec]) -> list[EvalSpec]:
    from adaptfilt.experiments.ood import CONDITIONS

    files = run.reproduction(EXPERIMENT)
    conds = CONDITIONS[:2] if run.quick else CONDITIONS
    return [EvalSpec(NAME, EXPERIMENT, condition_job, (c, files, run.scale),
                     job_key("ood", c.key, EXPERIMENT, files, run.scale.words())) for c in conds] if files else []


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    """Summaries only: nine conditions x 32 policies of per-run arrays would triple data/; the paired gains
    are computed here, before saving, and kept in summary.json."""
    from adaptfilt.experiments.ood import gain_table

    if not values:
        return {}
    tables = {}
    for spec, res in zip(specs, values):
        run.save(f"ood-{spec.args[0].key}", res, arrays=False)
        tables[spec.args[0].key] = res
    groups = {"learned": [n for n in values[0].names if n.startswith("adaptive-s")],
              "retuned": [n for n in values[0].names if n.startswith("retuned-s")]}
    return {NAME: {m: gain_table(tables, groups, m) for m in ("objective", "rmse")}}


def figures(run: Run, summary: dict) -> list[str]:
    import matplotlib.pyplot as plt

    from adaptfilt.experiments.ood import plot_gain

    if NAME not in summary:
        return []
    for metric, table in summary[NAME].items():
        fig, axes = plt.subplots(1, 4, figsize=(17, 3.8), layout="constrained")
        for ax, col in zip(axes, ("greedy", "best fixed", "learned", "retuned")):
            plot_gain(table, col, metric, ax=ax, title=f"{col}: {metric} gain over default")
        run.figure(fig, f"ood-gain-{metric}.png")
    # every figure in the folder is recorded with this run's command, as it always was
    for f in (run.out / "figures").glob("*.png"):
        run.entries[str(f.relative_to(run.out))] = {"command": run.command}
    return [f"figures/ood-gain-{m}.png" for m in summary[NAME]]


def markdown(summary: dict) -> str:
    if NAME not in summary:
        return ""
    lines = ["**Out of distribution** (UNGM-UKF; gain over the default in mean log(1+L), positive is better; "
             "learned and retuned: IQM over seeds [CI])", "",
             *md_table(["truth", "greedy", "best fixed (in hindsight)", "learned", "retuned (50 episodes)"])]
    for key, row in summary[NAME]["objective"].items():
        cells = []
        for col in ("greedy", "best fixed", "learned", "retuned"):
            c = row.get(col)
            cells.append("" if c is None else f"{c['gain']:+.3g} [{c['ci'][0]:+.3g}, {c['ci'][1]:+.3g}]"
                         + (f" ({c['policy']})" if col == "best fixed" else ""))
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
