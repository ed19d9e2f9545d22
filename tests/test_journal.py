"""The journal of finished jobs (adaptfilt.experiments.journal) and atomic files (adaptfilt.files), in
process: what a resumed run may reuse, and what it must run again."""
from __future__ import annotations

import json

import pytest

from adaptfilt.experiments.journal import Journal
from adaptfilt.experiments.sweep import Interrupted
from adaptfilt.files import atomic_path, atomic_savefig, atomic_write

CALLS: list[str] = []


def write_job(path: str, text: str) -> int:
    """A job: writes its file atomically, returns a small value; records that it ran."""
    CALLS.append(text)
    atomic_write(path, text)
    return len(text)


def _jobs(tmp_path, n: int = 3):
    jobs = [(str(tmp_path / f"f{i}.txt"), f"job {i} " * (i + 1)) for i in range(n)]
    keys = [(f"write {i}", i) for i in range(n)]
    return jobs, keys, [[j[0]] for j in jobs]


def test_a_resumed_run_reuses_finished_jobs_and_reruns_a_changed_one(tmp_path):
    jobs, keys, files = _jobs(tmp_path)
    path = tmp_path / "journal.jsonl"
    CALLS.clear()
    first = Journal(path).run(write_job, jobs, keys, files=files, workers=1, progress=False)
    assert CALLS == [j[1] for j in jobs] and first == [len(j[1]) for j in jobs]

    CALLS.clear()
    again = Journal(path)
    assert again.count(keys) == 3
    assert again.run(write_job, jobs, keys, files=files, workers=1, progress=False) == first and CALLS == []

    (tmp_path / "f1.txt").write_text("tampered")  # its sha256 no longer matches the record: run again
    again = Journal(path)
    assert again.count(keys) == 2 and again.get(*keys[1]) is None
    assert again.run(write_job, jobs, keys, files=files, workers=1, progress=False) == first
    assert CALLS == [jobs[1][1]] and (tmp_path / "f1.txt").read_text() == jobs[1][1]

    (tmp_path / "f2.txt").unlink()  # a missing file: run again
    assert Journal(path).count(keys) == 2
    assert Journal(path).count([("write 0", 1), ("another command", 0)]) == 0  # another seed, another command


def test_another_version_reuses_nothing(tmp_path, monkeypatch):
    jobs, keys, files = _jobs(tmp_path)
    path = tmp_path / "journal.jsonl"
    Journal(path).run(write_job, jobs, keys, files=files, workers=1, progress=False)
    monkeypatch.setattr(Journal, "_version", staticmethod(lambda: "0.0.0-other"))
    assert Journal(path).count(keys) == 0


def test_a_line_cut_short_by_a_kill_is_ignored(tmp_path):
    jobs, keys, files = _jobs(tmp_path)
    path = tmp_path / "journal.jsonl"
    Journal(path).run(write_job, jobs, keys, files=files, workers=1, progress=False)
    whole = path.read_text()
    path.write_text(whole + whole.splitlines()[0][:25])  # a record the kill cut in the middle
    assert Journal(path).count(keys) == 3
    lines = whole.splitlines()
    path.write_text(lines[0] + "\n" + lines[1][: len(lines[1]) // 2])
    assert Journal(path).count(keys) == 1


def test_an_interrupt_keeps_the_finished_jobs_and_says_so(tmp_path):
    jobs, keys, files = _jobs(tmp_path)
    path = tmp_path / "journal.jsonl"

    def stop_at_second(p: str, text: str) -> int:
        if p.endswith("f1.txt"):
            raise KeyboardInterrupt
        return write_job(p, text)

    with pytest.raises(Interrupted) as e:
        Journal(path).run(stop_at_second, jobs, keys, files=files, workers=1, progress=False)
    assert e.value.kept == f"1 finished jobs are kept in {path}; run the same command again to resume"
    assert e.value.signum == 2 and [json.loads(x)["command"] for x in path.read_text().splitlines()] == ["write 0"]
    CALLS.clear()
    j = Journal(path)
    j.run(write_job, jobs, keys, files=files, workers=1, progress=False)
    assert CALLS == [jobs[1][1], jobs[2][1]]
    j.finish()
    assert not path.exists()


def test_an_interrupt_names_the_checkpoints_that_unfinished_jobs_keep(tmp_path):
    """A job that keeps its own checkpoint (a learned-gain training) and is stopped leaves something to resume
    even before any job has finished: the line says so, and names it."""
    jobs, keys, files = _jobs(tmp_path)
    ckpts = [tmp_path / f"f{i}.ckpt.npz" for i in range(3)]

    def stop_with_a_checkpoint(p: str, text: str) -> int:
        i = int(p[-5])
        if i >= 1:  # jobs 1 and 2 have written a checkpoint each when the stop comes
            ckpts[1].write_text("state")
            ckpts[2].write_text("state")
            raise KeyboardInterrupt
        return write_job(p, text)

    path = tmp_path / "journal.jsonl"
    with pytest.raises(Interrupted) as e:
        Journal(path).run(stop_with_a_checkpoint, jobs, keys, files=files, checkpoints=ckpts, workers=1,
                          progress=False)
    assert e.value.kept == (f"1 finished jobs are kept in {path}; 2 unfinished jobs keep their checkpoints "
                            "(f1.ckpt.npz, f2.ckpt.npz); run the same command again to resume")
    for c in ckpts[1:]:
        c.unlink()
    other = tmp_path / "other.jsonl"
    with pytest.raises(Interrupted) as e:
        Journal(other).run(stop_with_a_checkpoint, jobs[1:], keys[1:], files=files[1:], checkpoints=ckpts[1:],
                           workers=1, progress=False)
    assert e.value.kept == ("no job had finished; 2 unfinished jobs keep their checkpoints (f1.ckpt.npz, "
                            "f2.ckpt.npz); run the same command again to resume")


def test_an_atomic_write_that_fails_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "out.txt"
    atomic_write(target, "old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half of the new")
            raise RuntimeError("killed while writing")
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_a_figure_saved_atomically_is_the_figure_savefig_writes(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([1.0, 3.0, 2.0])
    fig.savefig(tmp_path / "direct.png", dpi=50)
    atomic_savefig(fig, tmp_path / "atomic.png", dpi=50)  # through a temporary that does not end in .png
    plt.close(fig)
    assert (tmp_path / "atomic.png").read_bytes() == (tmp_path / "direct.png").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["atomic.png", "direct.png"]
