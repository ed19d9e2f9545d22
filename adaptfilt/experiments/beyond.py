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
import re
import sys
from pathlib import Path

from adaptfilt.experiments.jobs import Training, run_training
from adaptfilt.experiments.journal import Journal
from adaptfilt.experiments.studies import ALL
from adaptfilt.experiments.studies.sif import SELECTION_SEED, select_safe_actions, selection_md
from adaptfilt.experiments.study import FULL, QUICK, BeyondScale, Run, listed_policies, run_evaluations, same_training
from adaptfilt.files import atomic_write, sha256

__all__ = ["BeyondScale", "FULL", "QUICK", "run", "report_only", "command", "summary_md", "STUDIES",
           "STUDY_TITLES", "JOURNAL", "SELECTION_SEED", "select_safe_actions"]

#: The journal of a run's finished jobs, in ``DIR/beyond`` (removed when the run completes).
JOURNAL = "journal.jsonl"
#: The ``--studies`` words, in the order the command line lists them, with what each asks.
STUDY_TITLES = {"cand": "a candidate-aware information state", "sif": "SIF policies and divergence",
                "ood": "out of distribution and retuning", "raw": "training on the untransformed cost",
                "anchor": "policies anchored on greedy", "look": "the look-ahead references",
                "particles": "the particle count", "gain": "the learned kappa against KalmanNet's learned gain",
                "mlanchor": "learners anchored on ML, imitation of ML, the CTM's learning curve"}
STUDIES = tuple(STUDY_TITLES)


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
            workers, cluster, progress, typed_out=str(out_dir))
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


def _train(r: Run, trainings: list[Training]) -> None:
    """Run every training that neither the manifest (an earlier run's, same command, every file unchanged)
    nor the journal holds; say how many of each kind (``adaptfilt train``, ``adaptfilt train-gain``) were
    reused from where."""
    listed = listed_policies(r.out)

    def rel(path: str) -> str:
        return str(Path(path).relative_to(r.out))

    todo = [t for t in trainings
            if not all(same_training(listed.get(rel(o)), t.command, Path(o)) for o in t.outputs)]
    keys = [t.key for t in todo]
    for kind, noun in (("train", "policies to train"), ("train-gain", "learned-gain trainings (KalmanNet)")):
        mine = [t for t in trainings if t.command.split()[1] == kind]
        if not mine and kind != "train":
            continue
        left = [t.key for t in todo if t.command.split()[1] == kind]
        resumed = r.journal.count(left)
        r.say(f"[beyond] {len(left) - resumed} {noun}, {resumed} finished by an earlier run ({JOURNAL}), "
              f"{len(mine) - len(left)} listed in the manifest")
    records = r.jobs(run_training, [(t,) for t in todo], keys, files=[list(t.outputs) for t in todo],
                     checkpoints=[getattr(t, "checkpoint", None) for t in todo], progress=r.progress,
                     desc="beyond: train")
    r.entries.update({rel(o): rec for made in records for o, rec in made.items()})


def as_typed(cmd: str, root: Path, typed: str) -> str:
    """``cmd`` with the resolved output folder ``root`` written as the user typed it (``--out data``): a recorded
    command reruns from where the run was started, on any machine, not only in the folder that made it."""
    if Path(typed).is_absolute():
        return cmd
    return re.sub(rf"(--out ){re.escape(str(root))}(?=/|\s|$)", lambda m: m.group(1) + typed.rstrip("/"), cmd)


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
    typed = r.typed_out
    for rel, e in r.entries.items():
        cmd = e.get("command")
        if cmd and typed is not None:
            cmd = as_typed(cmd, out.parent, typed)
        files[rel] = {"path": rel, "sha256": sha256(out / rel), "command": cmd, "seed": 0,
                      "version": version, "wall_time_s": e.get("wall_time_s"), "cpu_time_s": e.get("cpu_time_s")}
    atomic_write(out / "manifest.json", json.dumps({"scale": r.scale.name, "files": [files[k] for k in sorted(files)]},
                                                   indent=1) + "\n")
    return summary


def report_only(out_dir: str | Path, progress: bool = True) -> dict:
    """``adaptfilt beyond --out DIR --report-only``: the studies' verdict words judged again by the one rule
    (:mod:`adaptfilt.verdicts`) from what ``DIR/beyond`` holds, nothing trained or evaluated: the look-ahead
    references' "lower cost than greedy" from their stored intervals, the learned-gain study's verdicts from
    its stored evaluations (``results/gain-<model>-<regime>`` and ``-final``). ``summary.json`` (its manifest
    entry: the new sha256 and this command) and ``summary.md`` are rewritten when they change. Returns the
    summary."""
    from adaptfilt.experiments.look import rejudge as rejudge_look
    from adaptfilt.experiments.studies import gain

    out = Path(out_dir).resolve() / "beyond"
    summary = json.loads((out / "summary.json").read_text())
    if "look" in summary:
        summary["look"] = rejudge_look(summary["look"])
    if "gain" in summary:
        summary["gain"] = gain.rejudge(summary["gain"], out)
    text = json.dumps(summary, indent=1) + "\n"
    if text != (out / "summary.json").read_text():
        atomic_write(out / "summary.json", text)
        man = json.loads((out / "manifest.json").read_text())
        for f in man["files"]:
            if f["path"] == "summary.json":
                f.update(sha256=sha256(out / "summary.json"), command=f"adaptfilt beyond --out {out_dir} --report-only")
        atomic_write(out / "manifest.json", json.dumps(man, indent=1) + "\n")
    md = summary_md(summary)
    if not (out / "summary.md").exists() or md != (out / "summary.md").read_text():
        atomic_write(out / "summary.md", md)
    if progress:
        print(f"[beyond report-only] {out}: summary.json and summary.md judged again", file=sys.stderr)
    return summary


def summary_md(summary: dict, studies: tuple[str, ...] = STUDIES) -> str:
    """The studies' tables for REPRODUCTION.md (IQM over seeds [seed-level CI], differences to greedy): the
    SIF study's safe set first (chosen before anything is trained), then each study's tables."""
    summary = {k: v for k, v in summary.items() if k not in STUDIES or k in studies}
    parts = [selection_md(summary)] + [s.markdown(summary) for s in ALL]
    return "\n".join(p for p in parts if p)
