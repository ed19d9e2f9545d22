"""Long work a user can stop and resume: Ctrl-C, SIGTERM and SIGKILL on the real command line.

Each test starts ``adaptfilt`` in a process group of its own (as a terminal would), waits until its
workers start or run (or until some jobs have finished, by the journal), sends the signal and checks:
the exit within the stated bound (:data:`~adaptfilt.experiments.sweep.STOP_SECONDS` on the local pool,
``STOP_SECONDS_DASK`` on a Dask cluster, from the signal to the exit), the status, the one line on
stderr, and that no worker process is left (by pid, from /proc). A resumed run must reuse the finished
jobs and write byte-identical files. The watchdog that holds the bound when something hangs, and the
second signal that ends a stop at once, are checked on a small script that hangs on purpose.
"""
from __future__ import annotations

import os
import signal
import sys
import textwrap
import time

import pytest

from adaptfilt.experiments.sweep import STOP_SECONDS, STOP_SECONDS_DASK
from adaptfilt.files import read_npz
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
    assert seen["rc"] == 130 and seen["seconds"] < STOP_SECONDS, seen["err"][-3000:]
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
    # into the training; a local cluster's workers may still be in their initializer then (it imports torch,
    # seconds on a loaded machine), another phase that must stop in time
    time.sleep(2 if engine == "pool" else 6)
    seen = stop(proc, sig, group=False)
    assert seen["left"] == [] and len(seen["workers"]) >= 3
    if sig == signal.SIGTERM:  # a scheduler ending the job: stopped as Ctrl-C stops it
        assert seen["rc"] == 143 and seen["seconds"] < (STOP_SECONDS if engine == "pool" else STOP_SECONDS_DASK), \
            seen["err"][-3000:]
        one_line(seen["err"])
    else:
        assert seen["rc"] == -signal.SIGKILL


@pytest.mark.parametrize("engine", ["pool", "dask"])
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "Ctrl-C"])
def test_a_signal_while_the_workers_start(tmp_path, sig, engine):
    """SIGTERM (to the command) as the first worker process appears, or Ctrl-C (to its whole process group,
    workers included) half a second later: the pool spawning its workers, or a local Dask cluster starting (its nannies
    spawning workers, before any job runs). A cluster whose start-up is interrupted must still be closed,
    quietly (distributed's exit hook would print a traceback after the line), a spawn must not be torn
    apart (the child would print one), a worker that gets Ctrl-C before its initializer runs must not
    print a KeyboardInterrupt; all within the bound, no process left."""
    if engine == "dask":
        pytest.importorskip("distributed")
    where = ["--workers", "2"] if engine == "pool" else ["--cluster", "local"]
    proc = start(adaptfilt(*TRAIN, *where, "--out", str(tmp_path / "p.npz")), tmp_path)
    wait_for(lambda: len(descendants(proc.pid)) >= 1, proc=proc, poll=0.005)
    if sig == signal.SIGINT:  # into the workers' own start-up (imports), when Python turns it into a traceback
        time.sleep(0.5)
    seen = stop(proc, sig, group=sig == signal.SIGINT)
    assert seen["rc"] == 128 + sig and seen["seconds"] < (STOP_SECONDS if engine == "pool" else STOP_SECONDS_DASK), \
        seen["err"][-3000:]
    assert seen["left"] == []
    assert one_line(seen["err"]) == "adaptfilt: interrupted: no job had finished: nothing to resume"
    assert lines(tmp_path / "p.journal.jsonl") == 0


def test_ctrl_c_stops_a_local_dask_cluster(tmp_path):
    pytest.importorskip("distributed")
    journal = tmp_path / "p.journal.jsonl"
    proc = start(adaptfilt(*TRAIN, "--cluster", "local", "--out", str(tmp_path / "p.npz")), tmp_path)
    wait_for(lambda: lines(journal) >= 1, proc=proc)
    seen = stop(proc, signal.SIGINT, group=True)
    assert seen["rc"] == 130 and seen["seconds"] < STOP_SECONDS_DASK and seen["left"] == [], seen["err"][-3000:]
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


#: A command stopped by SIGTERM whose stop then hangs (as a Dask close or an exit hook can): before the line
#: ``adaptfilt: interrupted`` (``stop``), after it (``exit``, in an exit hook), or with the signal held by the
#: main thread (``held``: its Python handler never runs; the watchdog counts from the signal's arrival).
HANGS = """
    import atexit, os, sys, time
    from adaptfilt import cli
    from adaptfilt.experiments.sweep import _deferred_interrupts

    def hang():
        print("hanging", flush=True)
        time.sleep(120)

    try:
        with cli._stop_on_signals(BOUND, own_process=True):
            if WHERE == "held":
                with _deferred_interrupts(deaf=False):
                    print("ready", flush=True)
                    time.sleep(120)
            print("ready", flush=True)
            time.sleep(120)
    except KeyboardInterrupt as e:
        if WHERE == "stop":
            hang()
        atexit.register(hang)
        cli._interrupted(e)
"""


def _hanging(tmp_path, where: str, bound: float):
    code = textwrap.dedent(HANGS).replace("BOUND", repr(bound)).replace("WHERE", repr(where))
    proc = start([sys.executable, "-c", code], tmp_path)
    wait_for(lambda: proc.stdout.readline() == "ready\n", proc=proc)
    return proc


@pytest.mark.parametrize("where", ["stop", "exit", "held"])
def test_a_stop_that_hangs_ends_within_the_bound(tmp_path, where):
    """The watchdog: whatever hangs after the signal, the process ends 2 s before the bound, with the
    signal's status and one line (its own, saying the stop was cut short, if the command's is not out)."""
    bound = 4.0
    proc = _hanging(tmp_path, where, bound)
    seen = stop(proc, signal.SIGTERM, group=False)
    assert seen["rc"] == 143 and bound - 2.5 < seen["seconds"] < bound
    line = one_line(seen["err"])
    if where in ("stop", "held"):
        assert line.startswith("adaptfilt: interrupted: stopping took over 2 s, so it was cut short; ")
    else:
        assert line == "adaptfilt: interrupted: nothing was written"


def test_a_second_signal_ends_the_stop_at_once(tmp_path):
    proc = _hanging(tmp_path, "stop", 60.0)
    os.kill(proc.pid, signal.SIGTERM)
    wait_for(lambda: proc.stdout.readline() == "hanging\n", proc=proc)
    seen = stop(proc, signal.SIGINT, group=True)
    assert seen["rc"] == 130 and seen["seconds"] < 2
    assert one_line(seen["err"]).startswith("adaptfilt: interrupted: a second signal cut the stop short; ")


#: A command whose main thread waits on a lock with no timeout (as ``as_completed`` waits for a job) while the
#: kernel gives SIGTERM to another thread (here it must: the main thread blocks SIGTERM).
ASLEEP = """
    import signal, threading, time
    from adaptfilt import cli

    threading.Thread(target=time.sleep, args=(120,), daemon=True).start()  # a thread that takes SIGTERM
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
    lock = threading.Lock()
    lock.acquire()
    try:
        with cli._stop_on_signals(60.0, own_process=True):
            print("ready", flush=True)
            lock.acquire()
    except KeyboardInterrupt as e:
        cli._interrupted(e)
"""


def test_a_signal_another_thread_takes_still_stops_the_main_thread(tmp_path):
    """The handler of a signal the kernel delivered to another thread runs only when the main thread runs
    Python code, and a lock's acquire is not woken: the watchdog pokes the main thread (SIGURG) until it
    has run. Without that the stop would wait for the watchdog's bound (58 s here)."""
    proc = start([sys.executable, "-c", textwrap.dedent(ASLEEP)], tmp_path)
    wait_for(lambda: proc.stdout.readline() == "ready\n", proc=proc)
    seen = stop(proc, signal.SIGTERM, group=False)
    assert seen["rc"] == 143 and seen["seconds"] < 2, seen["err"][-3000:]
    assert one_line(seen["err"]) == "adaptfilt: interrupted: nothing was written"
