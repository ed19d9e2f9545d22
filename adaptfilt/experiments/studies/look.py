r"""Study 6, ``look``: how much can looking ahead buy? The science is :mod:`adaptfilt.experiments.look`
(the references, their summary, table and figure); this file is what ``adaptfilt beyond`` runs of it.

Per experiment of :data:`~adaptfilt.experiments.look.LOOK`, one evaluation in parts (the baselines and
learned policies, each rollout (H, S), the two-step cross-check on UNGM; then the rollouts over ML and over
the better of both, :data:`~adaptfilt.experiments.look.LOOK_BASES`, and the ``mlanchor`` study's policies),
one job each on the same runs, merged into ``results/look-<experiment>``. It trains nothing; it shows the
learned policies there are (the reproduction's, the candidate-aware, anchored and ``mlanchor`` ones): run it
after those studies. A part that the stored evaluation (listed in the manifest) records under the same job
key is taken from it (:func:`~adaptfilt.experiments.look.stored_part`), not computed again.
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
    from adaptfilt.experiments.look import (LOOK, LOOK_BASES, LOOK_BASES_QUICK, LOOK_QUICK, look_files, look_job,
                                            look_new_files, look_specs, part_names, stored_part)

    specs = []
    for e, (runs, grid_hs) in (LOOK_QUICK if run.quick else LOOK).items():
        files = look_files(run.data, run.out, e, run.scale.seeds)
        new = look_new_files(run.out, e, run.scale.seeds)
        bases = (LOOK_BASES_QUICK if run.quick else LOOK_BASES).get(e)
        stored = _stored(run, e)
        for part in look_specs(e, grid_hs, run.quick, bases, learned=bool(new)):
            own = files if part == ("base",) else new if part == ("learned",) else []
            args = (e, part, own, runs, run.scale.n_steps)
            key = job_key("look", *args)
            if key in stored.get("parts", {}):  # computed by an earlier run: taken from its stored evaluation
                names = part_names(e, part, own)
                specs.append(EvalSpec(NAME, e, stored_part, (stored["path"], stored["sha"], names), key, tag=part))
                continue
            # the longest parts first (a rollout's time grows with H x S)
            work = float(np.prod([x for x in part[1:] if isinstance(x, int)] or (0,)))
            specs.append(EvalSpec(NAME, e, look_job, args, key, order=work, tag=part))
    return specs


def _stored(run: Run, experiment: str) -> dict:
    """The stored evaluation of ``experiment`` that the manifest lists unchanged: its path, sha256 and the
    parts it records ({job key: policy names}); empty if there is none."""
    import json

    from adaptfilt.files import sha256

    rel = f"results/look-{experiment}/results.json"
    path = run.out / rel
    man = run.out / "manifest.json"
    if not (path.is_file() and man.is_file()):
        return {}
    listed = {f["path"]: f for f in json.loads(man.read_text())["files"]}.get(rel)
    sha = sha256(path)
    if listed is None or listed["sha256"] != sha:
        return {}
    config = json.loads(path.read_text())["config"]
    return {"path": str(path.parent), "sha": sha, "parts": config.get("parts", {})}


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    """Each experiment's parts merged (in job order) into one evaluation, saved and summarised."""
    from adaptfilt.experiments.look import look_summary
    from adaptfilt.results import Results

    by_exp: dict[str, list] = {}
    for spec, res in zip(specs, values):
        by_exp.setdefault(spec.experiment, []).append((spec.key, res))
    out = {}
    for e, parts in by_exp.items():
        keys = {k: list(r.policies) for k, r in parts}  # before the merge extends the first part
        res = Results.merge([r for _, r in parts])
        res.config["parts"] = keys  # what a later run of the study can take from this file
        run.save(f"look-{e}", res, drop=COMPACT)
        out[e] = look_summary(res)
    return {NAME: out}


def figures(run: Run, summary: dict) -> list[str]:
    from adaptfilt.experiments.look import FIGURE_GROUPS, plot_look_gain

    look = summary[NAME]
    return [run.figure(plot_look_gain(look, learned={e: FIGURE_GROUPS for e in look}), "look-gain.png")]


def markdown(summary: dict) -> str:
    from adaptfilt.experiments.look import look_md

    return look_md(summary[NAME]) if NAME in summary else ""
