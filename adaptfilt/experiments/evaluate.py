"""What ``adaptfilt evaluate`` runs: every baseline of a named experiment (plus learned policy files)
evaluated on paired runs (:func:`adaptfilt.evaluation.evaluate`), written as ``results.json`` +
``results.npz`` (:meth:`~adaptfilt.evaluation.Results.save`), ``summary.json``, ``summary.md`` (with the
seed-level table of :mod:`adaptfilt.experiments.report` when policy files come from several training
seeds) and the figures of :mod:`adaptfilt.plots`.

Moved out of :mod:`adaptfilt.evaluation` (the Monte-Carlo engine, library) because it writes files
and reports: the pipeline's job.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

from adaptfilt.evaluation import evaluate
from adaptfilt.runs import CHUNK_SIZE
from adaptfilt.experiments.jobs import evaluate_command
from adaptfilt.results import Results
from adaptfilt.files import atomic_write

__all__ = ["evaluate_experiment"]


def evaluate_experiment(
    name: str,
    n_runs: int = 10_000,
    seed: int = 0,
    out_dir: str | Path = "results",
    policy_files: Iterable[str | Path] = (),
    progress: bool = True,
    *,
    floor: float | None = None,
    figures: bool = True,
    quiet: bool = False,
    n_steps: int | None = None,
    chunk_size: int | None = None,
) -> Results:
    """What ``adaptfilt evaluate NAME --runs M --seed S --out DIR [--policy FILE ...] [--horizon T]
    [--chunk-size C]`` runs.

    Policy files named ``<kind>-s<seed>.npz`` are one policy trained on several
    seeds: the table then adds the seed-level aggregate (IQM over seeds with a
    two-level bootstrap interval, :mod:`adaptfilt.seed_stats`).

    Evaluates every baseline of experiment ``name`` (default, each fixed grid
    value, ML where it applies, greedy) and the learned policies in
    ``policy_files`` (each named after its file by :func:`learned_names`; a
    name that a baseline uses is a ``ValueError``), then writes into
    ``out_dir``: ``results.json`` + ``results.npz``, ``summary.json``,
    ``summary.md`` and PNG figures; prints the table (unless ``quiet``). ``floor`` draws a reference RMSE (e.g. the
    point-mass Bayes floor on UNGM) in the RMSE figures. ``chunk_size`` (default
    :data:`adaptfilt.evaluation.CHUNK_SIZE`): runs filtered at a time (:func:`adaptfilt.evaluation.evaluate`);
    recorded in the command when it is not the default.
    """
    from adaptfilt.experiment_registry import get_experiment

    exp = get_experiment(name)
    policies = exp.baselines()
    policy_files = [Path(p) for p in policy_files]
    if policy_files:
        from adaptfilt.learned import learned_names, load_policy  # torch is imported only when needed

        baseline_names = {p.name for p in policies}
        names = learned_names(policy_files, exp.name)
        for p, n in zip(policy_files, names):
            if n in baseline_names or n.startswith("fixed-"):
                raise ValueError(f"policy file {p} would be named {n!r}, which is reserved for a baseline "
                                 f"({', '.join(sorted(baseline_names))}); rename the file")
        policies += [load_policy(p, experiment=exp, name=n) for p, n in zip(policy_files, names)]
    out = Path(out_dir)
    chunk_size = CHUNK_SIZE if chunk_size is None else int(chunk_size)
    command = evaluate_command(name, n_runs, seed, out, policy_files, horizon=n_steps,
                              chunk_size=None if chunk_size == CHUNK_SIZE else chunk_size)
    target = exp if n_steps is None else exp.make_env(seed=seed, n_steps=n_steps)
    res = evaluate(target, policies, n_runs=n_runs, seed=seed, progress=progress, command=command,
                   chunk_size=chunk_size)
    res.config.update(experiment=exp.name, description=exp.description)
    res.save(out)
    atomic_write(out / "summary.json", json.dumps(res.summary(), indent=1) + "\n")
    table = res.table()
    from adaptfilt.seed_stats import seed_groups

    if seed_groups(res.names):
        from adaptfilt.experiments.report import summary_md

        table += "\n**Seed level**: " + summary_md(res)
    atomic_write(out / "summary.md", table)
    if figures:
        from adaptfilt.plots import save_figures

        save_figures(res, out, floor=floor)
    if not quiet:
        print(table)
    return res
