"""Long work a user can stop and resume: Ctrl-C, SIGTERM and SIGKILL on the real command line.

Each test starts ``adaptfilt`` in a process group of its own (as a terminal would), waits until its
workers run (or until some jobs have finished, by the journal), sends the signal and checks: the
exit within seconds, the status, the one line on stderr, and that no worker process is left (by
pid, from /proc). A resumed run must reuse the finished jobs and write byte-identical files.
"""
from __future__ import annotations

import signal
import sys
import time

import pytest

from adaptfilt.learned import read_npz
from processes import adaptfilt, descendants, digests, lines, one_line, run, start, stop, wait_for  # tests/processes.py

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

#: A training of a few seconds per seed: long enough to be stopped in the middle.
TRAIN = ["train", "ungm-ukf", "--algo", "fast", "--episodes", "1500", "--horizon", "20", "--seeds", "0-3"]


def test_ctrl_c_stops_train_seeds_and_the_same_command_resumes_to_identical_files(tmp_path):
    out = tmp_path / "p.npz"
    cmd = adaptfilt(*TRAIN, "--workers", "2", "--out", str(out))
    files = [tmp_path / f"p-s{s}.npz" for s in range(4)]
    run(cmd, tmp_path)
    reference = digests(files)  # uninterrupted (the files record their --out: same path for both runs)
    for f in files:
        f.unlink()

    journal = tmp_path / "p.journal.jsonl"
    proc = start(cmd, tmp_path)
    wait_for(lambda: lines(journal) >= 1, proc=proc)
    seen = stop(proc, signal.SIGINT, group=True)
    line = one_line(seen["err"])
    assert seen["rc"] == 130 and seen["seconds"] < 10
    assert len(seen["workers"]) >= 2 and seen["left"] == []
    kept = lines(journal)
    assert 1 <= kept < 4 and f"{kept} finished jobs are kept in {journal}" in line and "resume" in line
    for f in tmp_path.glob("p-s*.npz"):  # whatever a stopped job left is whole (atomic writes)
        read_npz(f)

    again = run(cmd, tmp_path)
    assert f"{kept} of 4 seeds finished by an earlier run" in again.stdout
    assert digests(files) == reference and not journal.exists()


@pytest.mark.parametrize("engine", ["pool", "dask"])
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_workers_die_with_their_parent(tmp_path, sig, engine):
    if engine == "dask":
        pytest.importorskip("distributed")
    where = ["--workers", "2"] if engine == "pool" else ["--cluster", "local"]
    proc = start(adaptfilt(*TRAIN, *where, "--out", str(tmp_path / "p.npz")), tmp_path)
    wait_for(lambda: len(descendants(proc.pid)) >= 3, proc=proc)  # two workers and the resource tracker
    time.sleep(2 if engine == "pool" else 6)  # into the training (a local cluster starts its workers first)
    seen = stop(proc, sig, group=False)
    assert seen["left"] == [] and len(seen["workers"]) >= 3
    if sig == signal.SIGTERM:  # a scheduler ending the job: stopped as Ctrl-C stops it
        assert seen["rc"] == 143 and seen["seconds"] < (10 if engine == "pool" else 15)
        one_line(seen["err"])
    else:
        assert seen["rc"] == -signal.SIGKILL


def test_ctrl_c_stops_a_local_dask_cluster(tmp_path):
    pytest.importorskip("distributed")
    journal = tmp_path / "p.journal.jsonl"
    proc = start(adaptfilt(*TRAIN, "--cluster", "local", "--out", str(tmp_path / "p.npz")), tmp_path)
    wait_for(lambda: lines(journal) >= 1, proc=proc)
    seen = stop(proc, signal.SIGINT, group=True)
    assert seen["rc"] == 130 and seen["seconds"] < 15 and seen["left"] == []
    assert len(seen["workers"]) >= 2
    assert "finished jobs are kept" in one_line(seen["err"])


def test_ctrl_c_stops_evaluate(tmp_path):
    proc = start(adaptfilt("evaluate", "ungm-ukf", "--runs", "20000", "--out", str(tmp_path / "o")), tmp_path)
    time.sleep(8)  # imported and evaluating (the whole evaluation takes a minute)
    assert proc.poll() is None
    seen = stop(proc, signal.SIGINT, group=True)
    assert seen["rc"] == 130 and seen["seconds"] < 5
    assert one_line(seen["err"]) == "adaptfilt: interrupted: nothing was written"
    assert not (tmp_path / "o" / "results.json").exists()


def test_ctrl_c_on_one_training_names_its_checkpoint(tmp_path):
    out = tmp_path / "p.npz"
    proc = start(adaptfilt("train", "ungm-ukf", "--algo", "faithful", "--episodes", "5000", "--horizon", "10",
                           "--no-progress", "--out", str(out)), tmp_path)
    ckpt = tmp_path / "p.ckpt.npz"
    wait_for(ckpt.exists, proc=proc)
    seen = stop(proc, signal.SIGINT, group=True)
    assert seen["rc"] == 130 and seen["seconds"] < 5 and not out.exists()
    assert one_line(seen["err"]) == (f"adaptfilt: interrupted: the checkpoint {ckpt} is kept; add --resume to the "
                                     "same command to continue from it")
    read_npz(ckpt)  # whole
