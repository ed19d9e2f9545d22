r"""Study 6, ``look``: how much can looking ahead buy? The science is :mod:`adaptfilt.experiments.look`
(the references, their summary, table and figure); this file is what ``adaptfilt beyond`` runs of it.

Per experiment of :data:`~adaptfilt.experiments.look.LOOK`, one evaluation in parts (the baselines and
learned policies, each rollout (H, S), the two-step cross-check on UNGM), one job each on the same runs,
merged into ``results/look-<experiment>``. It trains nothing; it shows the learned policies there are
(the reproduction's, the candidate-aware and anchored ones): run it after those studies.
"""
from __future__ import annotations

import numpy as np

from adaptfilt.experiments.jobs import EvalSpec, TrainSpec, job_key
from adaptfilt.experiments.study import COMPACT, Run

NAME = "look"


def prepare(run: Run) -> dict:
    return {}


def policies(run: Run, summary: dict) -> list[TrainSpec]:
    return []


def evaluations(run: Run, summary: dict, trained: list[TrainSpec]) -> list[EvalSpec]:
    from adaptfilt.experiments.look import LOOK, LOOK_QUICK, look_files, look_job, look_specs

    specs = []
    for e, (runs, grid_hs) in (LOOK_QUICK if run.quick else LOOK).items():
        files = look_files(run.data, run.out, e, run.scale.seeds)
        for part in look_specs(e, grid_hs, run.quick):
            args = (e, part, files if part == ("base",) else [], runs, run.scale.n_steps)
            # the longest parts first (a rollout's time grows with H x S)
            specs.append(EvalSpec(NAME, e, look_job, args, job_key("look", *args), order=float(np.prod(part[1:] or (0,)))))
    return specs


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    """Each experiment's parts merged (in job order) into one evaluation, saved and summarised."""
    from adaptfilt.experiments.look import look_summary
    from adaptfilt.results import Results

    by_exp: dict[str, list] = {}
    for spec, res in zip(specs, values):
        by_exp.setdefault(spec.experiment, []).append(res)
    out = {}
    for e, parts in by_exp.items():
        res = Results.merge(parts)
        run.save(f"look-{e}", res, drop=COMPACT)
        out[e] = look_summary(res)
    return {NAME: out}


def figures(run: Run, summary: dict) -> list[str]:
    from adaptfilt.experiments.look import plot_look_gain

    return [run.figure(plot_look_gain(summary[NAME]), "look-gain.png")]


def markdown(summary: dict) -> str:
    from adaptfilt.experiments.look import look_md

    return look_md(summary[NAME]) if NAME in summary else ""
