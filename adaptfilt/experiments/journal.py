r"""Long runs that can be stopped and resumed: the journal of a run's finished jobs.

A long command (``adaptfilt reproduce``, ``beyond``, ``train --seeds``) is a list of jobs
(:func:`adaptfilt.experiments.sweep.run_jobs`). As each job finishes, this process appends one JSON
line to the run's journal, a file beside its output::

    {"command": ..., "seed": ..., "version": ..., "files": {path: sha256}, "value": ...}

the command that identifies the job, its seed, the package version, the sha256 of every file the job
wrote (paths relative to the journal's folder) and its value (timings, a small result). Run the same
command again into the same place and every job whose record matches -- same command, seed and
version, every file there with its recorded sha256 -- is taken from the journal, not run again.
A job is a deterministic function of its command and seed, and a value takes the same path whether it
was computed now or read back (:meth:`Journal.run` always hands on what it loads from what it saved),
so the resumed run's files are byte-identical to an uninterrupted run's. A completed run removes its
journal (:meth:`Journal.finish`): its manifest then records every file.

Values that are not JSON (an evaluation's :class:`~adaptfilt.evaluation.Results`) are files too: a
``save(folder, value) -> (files, json_value)`` writes them under ``<journal>.parts/`` and
``load(folder, json_value)`` reads them back. Every file is written atomically (:mod:`adaptfilt.files`)
and a record only after its files, so a record never names a file that is not whole; a line cut short
by a kill is ignored.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
from pathlib import Path
from typing import Any, Callable, Sequence

from adaptfilt.experiments.sweep import Interrupted, run_jobs
from adaptfilt.files import sha256

__all__ = ["Journal", "save_results", "load_results"]


class Journal:
    """The finished jobs of one run, in the JSON-lines file ``path`` (module docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.root = self.path.parent
        self.parts = self.path.with_name(self.path.name.removesuffix(".jsonl") + ".parts")
        self.records = self._read()

    def _read(self) -> dict[tuple[str, int], dict]:
        records: dict[tuple[str, int], dict] = {}
        if self.path.exists():
            for line in self.path.read_text(encoding="utf-8").splitlines():
                try:
                    r = json.loads(line)
                    records[r["command"], r["seed"]] = r
                except (ValueError, KeyError, TypeError):  # a line cut short when the run was killed
                    continue
        return records

    @staticmethod
    def _version() -> str:
        from adaptfilt._version import __version__

        return __version__

    def get(self, command: str, seed: int) -> dict | None:
        """The record of a finished job that can be reused as it is, else None."""
        r = self.records.get((command, seed))
        if r is None or r.get("version") != self._version():
            return None
        for rel, digest in r.get("files", {}).items():
            p = self.root / rel
            if not p.is_file() or sha256(p) != digest:
                return None
        return r

    def count(self, keys: Sequence[tuple[str, int]]) -> int:
        """How many of the jobs ``keys`` (command, seed) the journal holds, reusable."""
        return sum(self.get(*k) is not None for k in keys)

    def add(self, command: str, seed: int, files: Sequence[str | Path] = (), value: Any = None) -> dict:
        """Record a finished job (after its files are written: they are hashed now)."""
        rec = {"command": command, "seed": seed, "version": self._version(),
               "files": {self._rel(f): sha256(f) for f in files}, "value": value}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(json.dumps(rec, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self.records[command, seed] = rec
        return rec

    def _rel(self, f: str | Path) -> str:
        p = Path(f)
        return str(p.relative_to(self.root) if p.is_absolute() else p)

    def folder(self, command: str, seed: int) -> Path:
        """Where a job's value files go (one folder per job)."""
        return self.parts / hashlib.sha256(f"{command}\0{seed}".encode()).hexdigest()[:16]

    def run(self, fn: Callable, jobs: Sequence[tuple], keys: Sequence[tuple[str, int]],
            files: Sequence[Sequence[str | Path]] | None = None,
            save: Callable[[Path, Any], tuple[list[Path], Any]] | None = None,
            load: Callable[[Path, Any], Any] | None = None,
            checkpoints: Sequence[str | Path | None] | None = None, **run_kw) -> list:
        """:func:`~adaptfilt.experiments.sweep.run_jobs` over the jobs the journal does not hold.

        ``keys[i]``: job i's (command, seed); ``files[i]``: the files job i writes itself (recorded
        with their sha256); ``save``/``load``: a value kept as files (module docstring); ``checkpoints[i]``: where
        job i keeps its own checkpoint while it runs, if it does (an interrupt then says how many are kept).
        Returns every job's value in job order, taken from the journal or computed now."""
        values: list = [None] * len(jobs)
        todo = []
        for i, (command, seed) in enumerate(keys):
            rec = self.get(command, seed)
            if rec is None:
                todo.append(i)
            else:
                values[i] = self._value(rec, load)

        def done(j: int, value: Any) -> None:
            i = todo[j]
            command, seed = keys[i]
            written, stored = save(self.folder(command, seed), value) if save else (list(files[i]) if files else [], value)
            values[i] = self._value(self.add(command, seed, written, stored), load)

        try:
            run_jobs(fn, [jobs[i] for i in todo], on_done=done, **run_kw)
        except KeyboardInterrupt as e:
            kept = [Path(checkpoints[i]) for i in todo if checkpoints and checkpoints[i] is not None]
            raise self.interrupted(e, [p for p in kept if p.exists()]) from None
        return values

    def _value(self, rec: dict, load) -> Any:
        return load(self.folder(rec["command"], rec["seed"]), rec["value"]) if load else rec["value"]

    def interrupted(self, e: BaseException, checkpoints: Sequence[Path] = ()) -> Interrupted:
        """The interrupt ``e`` (Ctrl-C, or SIGTERM turned into it) with one line on what is kept: the finished
        jobs, and the ``checkpoints`` unfinished jobs left to go on from."""
        n = len(checkpoints)
        partial = (f"{n} unfinished job{'s' * (n != 1)} keep{'s' * (n == 1)} {'its' if n == 1 else 'their'} "
                   f"checkpoint{'s' * (n != 1)} ({', '.join(p.name for p in checkpoints[:2])}"
                   f"{', ...' if n > 2 else ''})") if n else ""
        if self.records:
            kept = (f"{len(self.records)} finished jobs are kept in {self.path}" + (f"; {partial}" if n else "")
                    + "; run the same command again to resume")
        elif n:
            kept = f"no job had finished; {partial}; run the same command again to resume"
        else:
            kept = "no job had finished: nothing to resume"
        return Interrupted(getattr(e, "done", 0), getattr(e, "total", 0), kept, getattr(e, "signum", signal.SIGINT))

    def finish(self) -> None:
        """The run completed: its journal and the value files go (the manifest records the outputs)."""
        self.path.unlink(missing_ok=True)
        shutil.rmtree(self.parts, ignore_errors=True)


def save_results(folder: Path, results: Sequence) -> list[Path]:
    """Evaluations (:class:`~adaptfilt.evaluation.Results`) as a job's value files: ``folder/part{j}``."""
    files = []
    for j, res in enumerate(results):
        res.save(folder / f"part{j}")
        files += [folder / f"part{j}" / "results.npz", folder / f"part{j}" / "results.json"]
    return files


def load_results(folder: Path, n: int) -> list:
    """What :func:`save_results` saved, bit for bit."""
    from adaptfilt.results import Results

    return [Results.load(folder / f"part{j}") for j in range(n)]
