r"""Beyond the paper: ``adaptfilt beyond --out DIR [--quick] [--studies cand,sif,ood,raw,anchor,look,particles,gain,mlanchor]``.

Studies the paper leaves open, each at the seed level (8 training seeds, paired runs), written
into ``DIR/beyond/`` with their own manifest entries (``DIR/beyond/manifest.json``).

Each study is one file of :mod:`adaptfilt.experiments.studies` (its docstring says what it asks):
``cand`` (a candidate-aware information state), ``sif`` (SIF policies and divergence: a repair penalty, a safe
action set), ``ood`` (out of distribution and retuning), ``raw`` (training on the untransformed cost),
``anchor`` (policies anchored on greedy), ``look`` (the look-ahead references), ``particles`` (the particle
count), ``gain`` (the learned kappa against KalmanNet's learned gain), ``mlanchor`` (the CTM's open question:
learners anchored on maximum likelihood, imitation of it, the learning curve). Each declares what it trains, what it evaluates, its rows, tables and figures
(:class:`adaptfilt.experiments.study.Study`); :func:`run` is the loop over the chosen ones.

Every training and evaluation is a job of :func:`adaptfilt.experiments.sweep.run_jobs` (local pool or
Dask), recorded as it finishes in ``DIR/beyond/journal.jsonl`` (:mod:`adaptfilt.experiments.journal`):
the same command run again after an interrupt reuses every finished job and gives the same files. A
policy that ``DIR/beyond/manifest.json`` lists with the same training command and sha256 is reused too
(studies run separately with ``--studies`` share the folder). The reproduction's policies are looked
for in ``--data DIR``, ``$ADAPTFILT_DATA``, then the checkout's ``data/`` (:func:`adaptfilt.experiments.artefacts.find_data`).
"""
from __future__ import annotations

import json
from pathlib import Path

from adaptfilt.experiment_registry import SIF_EXPERIMENTS  # re-exported: chapter 13 reads beyond.SIF_EXPERIMENTS
from adaptfilt.experiments.jobs import TrainSpec, train
from adaptfilt.experiments.journal import Journal
from adaptfilt.experiments.studies import ALL
from adaptfilt.experiments.studies.sif import SELECTION_SEED, select_safe_actions, selection_md
# study_rows: REPRODUCTION.md cites it as beyond.study_rows
from adaptfilt.experiments.study import (FULL, QUICK, BeyondScale, Run, listed_policies, run_evaluations,  # noqa: F401
                                         same_training, study_rows)
from adaptfilt.files import atomic_write, sha256

__all__ = ["BeyondScale", "FULL", "QUICK", "run", "command", "summary_md", "STUDIES", "JOURNAL", "SELECTION_SEED",
           "select_safe_actions", "SIF_EXPERIMENTS", "study_rows"]

#: The journal of a run's finished jobs, in ``DIR/beyond`` (removed when the run completes).
JOURNAL = "journal.jsonl"
#: The ``--studies`` words, in the order the command line lists them.
STUDIES = ("cand", "sif", "ood", "raw", "anchor", "look", "particles", "gain", "mlanchor")


def command(out_dir: str | Path, quick: bool, studies: tuple[str, ...]) -> str:
    """The run's command, recorded for every file it writes but the policies (they record their own)."""
    return (f"adaptfilt beyond --out {out_dir}" + (" --quick" if quick else "")
            + ("" if set(studies) == set(STUDIES) else f" --studies {','.join(studies)}"))


def run(out_dir: str | Path, quick: bool = False, workers: int | None = None, cluster=None,
        studies: tuple[str, ...] = STUDIES, progress: bool = True, data: str | Path | None = None) -> dict:
    """Run the studies (module docstring) into ``out_dir/beyond``; returns their summaries. ``data``:
    where the reproduction's policies are (default: ``$ADAPTFILT_DATA``, then the checkout's ``data/``)."""
    from adaptfilt._version import __version__
    from adaptfilt.experiments.artefacts import find_data
    from adaptfilt.experiments.reproduce import RETRAIN_COST

    root = Path(out_dir).resolve()
    need = None if quick or not set(studies) & {"sif", "ood", "raw"} else (
        "the sif, ood and raw studies compare with the reproduction's policies: make them with `adaptfilt reproduce "
        f"--out DIR --retrain` ({RETRAIN_COST}) and give --data DIR")
    data = root if quick else find_data(data, required=need)  # before anything is written: it may refuse
    out = root / "beyond"
    (out / "policies").mkdir(parents=True, exist_ok=True)
    r = Run(out, data, QUICK if quick else FULL, quick, command(out_dir, quick, studies), Journal(out / JOURNAL),
            workers, cluster, progress)
    chosen = [s for s in ALL if s.NAME in studies]
    summary: dict = {"scale": r.scale.name, "version": __version__}
    for s in chosen:
        summary.update(s.prepare(r))
    trained = {s.NAME: s.policies(r, summary) for s in chosen}
    _train(r, [t for s in chosen for t in trained[s.NAME]])
    specs = {s.NAME: s.evaluations(r, summary, trained[s.NAME]) for s in chosen}
    values = iter(run_evaluations(r, [e for s in chosen for e in specs[s.NAME]]))
    for s in chosen:
        summary.update(s.rows(r, summary, specs[s.NAME], [next(values) for _ in specs[s.NAME]]))
    for s in chosen:
        s.figures(r, summary)
    summary = _write(r, summary, __version__)
    r.journal.finish()
    return summary


def _train(r: Run, policies: list[tuple[str, TrainSpec]]) -> None:
    """Train what neither the manifest (an earlier run's, same command) nor the journal holds."""
    listed = listed_policies(r.out)
    todo = [(rel, t) for rel, t in policies if not same_training(listed.get(rel), t.command, r.out / rel)]
    keys = [t.key for _, t in todo]
    resumed = r.journal.count(keys)
    r.say(f"[beyond] {len(todo) - resumed} policies to train, {resumed} finished by an earlier run ({JOURNAL}), "
          f"{len(policies) - len(todo)} listed in the manifest")
    times = r.jobs(train, [(t,) for _, t in todo], keys, files=[[r.out / rel] for rel, _ in todo],
                   progress=r.progress, desc="beyond: train")
    r.entries.update({rel: t for (rel, _), t in zip(todo, times)})


def _write(r: Run, summary: dict, version: str) -> dict:
    """summary.json and the manifest; studies run separately (--studies) add to what an earlier run of the
    same scale wrote."""
    out = r.out
    old_summary, old_files = {}, {}
    if (out / "summary.json").exists() and (out / "manifest.json").exists():
        prev = json.loads((out / "summary.json").read_text())
        if prev.get("scale") == r.scale.name:
            old_summary = prev
            old_files = {f["path"]: f for f in json.loads((out / "manifest.json").read_text())["files"]}
    summary = {**{k: v for k, v in old_summary.items() if k not in summary}, **summary}
    atomic_write(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    r.entries["summary.json"] = {"command": r.command}
    files = {rel: f for rel, f in old_files.items() if rel not in r.entries and (out / rel).exists()}
    for rel, e in r.entries.items():
        files[rel] = {"path": rel, "sha256": sha256(out / rel), "command": e.get("command"), "seed": 0,
                      "version": version, "wall_time_s": e.get("wall_time_s"), "cpu_time_s": e.get("cpu_time_s")}
    atomic_write(out / "manifest.json", json.dumps({"scale": r.scale.name, "files": [files[k] for k in sorted(files)]},
                                                   indent=1) + "\n")
    return summary


def summary_md(summary: dict, studies: tuple[str, ...] = STUDIES) -> str:
    """The studies' tables for REPRODUCTION.md (IQM over seeds [seed-level CI], differences to greedy): the
    SIF study's safe set first (chosen before anything is trained), then each study's tables."""
    summary = {k: v for k, v in summary.items() if k not in STUDIES or k in studies}
    parts = [selection_md(summary)] + [s.markdown(summary) for s in ALL]
    return "\n".join(p for p in parts if p)
