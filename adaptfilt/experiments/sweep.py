r"""Independent jobs on every core, or on a Dask cluster.

A sweep (training seeds x experiments x gamma, one evaluation per experiment)
is a list of independent jobs, each a call ``fn(*args)`` of a module-level
function that seeds itself: its result does not depend on where, when or next
to what it runs. :func:`run_jobs` runs them

* in this process (``workers=1``),
* on a local process pool using every core (the default; nothing to start),
* or on a Dask ``distributed`` cluster (``cluster="tcp://scheduler:8786"``,
  ``"local"`` for a throw-away cluster of local processes, or a
  ``distributed.Client``), so that a user with a cluster runs a 100-seed study
  unchanged. A worker process runs one job at a time whatever its number of
  threads: the trainers seed process-global generators.

Why Dask rather than Ray: ``distributed`` is a pure-Python wheel with no
daemon to install, its ``LocalCluster(processes=False)`` runs in-process for a
test, and a scheduler address is all a user needs; Ray brings a native
runtime and an object store this workload (seconds-long CPU jobs exchanging
kilobytes) does not use.

Results come back in job order, identical bit for bit whatever the number of
workers and the engine (a test checks it). Every worker runs torch on one
thread: the networks are tiny, and several processes each with several
threads only wait on each other.

Stopping. Ctrl-C (``KeyboardInterrupt`` here) cancels the jobs not yet started, terminates the
workers of the running ones (every job writes its files atomically, :mod:`adaptfilt.files`, so a
stopped job leaves nothing half-written) and raises :class:`Interrupted`, which counts the jobs that
finished; ``on_done`` has been called for each of them as it finished, so a caller can record them
(:mod:`adaptfilt.experiments.journal`) and a later run skip them. Workers ignore SIGINT, which a
terminal sends to the whole process group: this process alone decides what stops. Workers die with
this process however it dies (SIGTERM, SIGKILL, the OOM killer): on Linux the kernel kills them
(``prctl(PR_SET_PDEATHSIG)``), elsewhere a thread in each worker watches its parent. On a Dask cluster
the futures are cancelled, and a cluster started here is closed.

Stopping is bounded, whatever the phase (start-up, jobs, closing): :func:`run_jobs` returns or raises
within :data:`STOP_SECONDS` (10 s) of the interrupt in this process or on the local pool, and within
:data:`STOP_SECONDS_DASK` (20 s) on a Dask cluster; the command line (:mod:`adaptfilt.cli`) exits within
the same bounds, a watchdog ending the process if anything hangs. The interrupt is an exception raised
at whatever bytecode the main thread is running, so nothing that must not be torn apart runs there:
a Dask client (and its local cluster) is started and closed in a thread of its own, the main thread
only waiting for it, and a cluster whose start-up was interrupted is still closed once it is up; the
pool starts its workers with the interrupt held for those milliseconds (a spawn torn apart leaves a
child that prints a traceback), and stops every child process started since it was created (a worker
left alive would hold up the interpreter's exit, which joins every child process), waiting for them and
for its own shutdown a few seconds at most. Workers of the pool
and of a local cluster are started with SIGINT blocked, so a terminal's Ctrl-C, sent to them too, finds
them deaf even before their initializer ignores it.
"""
from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Sequence

__all__ = ["run_jobs", "default_workers", "Interrupted", "JobFailed", "STOP_SECONDS", "STOP_SECONDS_DASK"]

#: Seconds from an interrupt (Ctrl-C, SIGTERM) to the end of a run in this process or on the local pool,
#: and on a Dask cluster (module docstring); :mod:`adaptfilt.cli` exits within them whatever hangs.
STOP_SECONDS = 10.0
STOP_SECONDS_DASK = 20.0
#: Within them: the pool's workers get _POOL_GRACE s to exit after SIGTERM, then SIGKILL; a Dask client
#: gets _DASK_CLOSE s to close (its local cluster and workers with it) and a cancel _DASK_CANCEL s.
_POOL_GRACE = 3.0
_DASK_CLOSE = 10.0
_DASK_CANCEL = 3.0


class JobFailed(RuntimeError):
    """A job raised (the message names the job and its error) or its worker process died."""


class Interrupted(KeyboardInterrupt):
    """A run stopped by a signal before its end: Ctrl-C (SIGINT), or SIGTERM where the command line
    turns it into this. ``done`` jobs of ``total`` had finished; ``kept`` says in words what they left
    and how to resume (the driver that knows fills it in); ``signum`` sets the exit status, 128 + signum."""

    def __init__(self, done: int = 0, total: int = 0, kept: str = "", signum: int = signal.SIGINT) -> None:
        super().__init__(kept or f"{done} of {total} jobs finished")
        self.done, self.total, self.kept, self.signum = done, total, kept, int(signum)


def default_workers() -> int:
    """``$ADAPTFILT_JOBS`` if set, else the number of cores this process may use."""
    env = os.environ.get("ADAPTFILT_JOBS")
    if env:
        return max(1, int(env))
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _one_thread() -> None:
    import torch

    torch.set_num_threads(1)


_PR_SET_PDEATHSIG = 1


def die_with_parent(parent: int) -> None:
    """Make this (worker) process die when ``parent`` does, whatever kills the parent."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            if ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL) == 0:
                if os.getppid() != parent:  # the parent died before prctl took effect
                    os._exit(1)
                return
        except (OSError, AttributeError):  # pragma: no cover - a libc without prctl
            pass

    def watch() -> None:  # pragma: no cover - not Linux
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="adaptfilt-parent-watch").start()


def one_line_warning(message, category, filename, lineno, line=None) -> str:
    """A warning as the command line prints it: ``adaptfilt: warning: MESSAGE``, one line, for a
    :data:`warnings.formatwarning`. Python's default adds the source line that raised it, which tells a
    user of ``adaptfilt beyond`` nothing (it is our code, in a worker)."""
    return f"adaptfilt: warning: {' '.join(str(message).split())}\n"


def _worker_init(parent: int) -> None:
    import warnings

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent)
    _one_thread()
    warnings.formatwarning = one_line_warning  # a worker is ours: its warnings reach a user's console


#: One job at a time per process: trainers seed process-global generators (torch, and SB3 also
#: numpy's and Python's), so two jobs in threads of one Dask worker would draw from each other's.
_LOCK = threading.Lock()


def _call(fn: Callable, args: tuple) -> Any:
    with _LOCK:
        _one_thread()
        return fn(*args)


def run_jobs(fn: Callable, jobs: Sequence[tuple], workers: int | None = None, cluster=None,
             progress: bool = True, desc: str = "jobs", on_done: Callable[[int, Any], None] | None = None) -> list:
    """``[fn(*a) for a in jobs]``, in parallel (see the module docstring); results in job order.

    ``fn`` must be importable by name (a module-level function) for the process
    pool and a cluster. An exception in a job is a :class:`JobFailed` here, naming
    the job, and stops the others; Ctrl-C is :class:`Interrupted`. ``on_done(i, result)``
    is called here, in this process, as job ``i`` finishes (in the order they finish).
    """
    jobs = [tuple(a) for a in jobs]
    if not jobs:
        return []
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(jobs), desc=desc, unit="job")
    done = 0

    def finished(i: int, value: Any) -> None:
        nonlocal done
        # whole or not at all: an interrupt between a journal's line and its count would say "no job had
        # finished" of a run whose journal keeps one (the next run would still reuse it)
        with _deferred_interrupts(deaf=False):
            done += 1
            if on_done is not None:
                on_done(i, value)
        if bar is not None:
            bar.update(1)

    try:
        if cluster is not None:
            return _run_dask(fn, jobs, cluster, finished)
        if workers == 1 or len(jobs) == 1:
            return _run_here(fn, jobs, finished)
        return _run_pool(fn, jobs, min(workers, len(jobs)), finished)
    except Interrupted as e:
        if not e.total:  # raised by the command line's signal handler, which does not know the counts
            e.done, e.total = done, len(jobs)
        raise
    except KeyboardInterrupt:
        raise Interrupted(done, len(jobs)) from None
    finally:
        if bar is not None:
            bar.close()  # ends the bar's line: a message after it starts on a line of its own


def _job(i: int, fn: Callable, args: tuple) -> str:
    """``job 3 fn(args...)``, the arguments cut short: the error after them is what a reader needs."""
    text = repr(args)
    return f"job {i} {fn.__name__}{text if len(text) <= 100 else text[:96] + ' ...)'}"


def _failed(i: int, fn: Callable, args: tuple, e: BaseException, where: str = "") -> JobFailed:
    return JobFailed(f"{_job(i, fn, args)} failed{where}: {e}")


def _run_here(fn: Callable, jobs: list[tuple], finished: Callable) -> list:
    out: list = []
    for i, a in enumerate(jobs):
        try:
            out.append(_call(fn, a))
        except Exception as e:
            raise _failed(i, fn, a, e) from e
        finished(i, out[i])
    return out


def _run_pool(fn: Callable, jobs: list[tuple], workers: int, finished: Callable) -> list:
    import multiprocessing as mp

    ex, before = None, set()
    # Idle OpenBLAS threads spin before they sleep, on cores the other workers need (the UNGM floor:
    # 38-40 CPU-s against 44-49 with the default wait, two workers on two cores); the workers inherit
    # the shortest wait, which changes no number. A value set in the environment is kept.
    os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")
    try:
        with _deferred_interrupts():  # the workers are started here, in submit: not torn apart
            before = set(mp.active_children())  # the pool's workers are the children started from now on
            ex = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                     initializer=_worker_init, initargs=(os.getpid(),))
            futs = {ex.submit(fn, *a): i for i, a in enumerate(jobs)}
        out: list = [None] * len(jobs)
        for f in _as_completed(futs):
            i = futs[f]
            try:
                out[i] = f.result()
            except BrokenProcessPool as e:
                raise JobFailed(f"{_job(i, fn, jobs[i])}: a worker process died ({e}); out of memory? "
                                "try fewer --workers") from e
            except Exception as e:
                raise _failed(i, fn, jobs[i], e) from e
            finished(i, out[i])
        return out
    except BaseException:
        if ex is not None:
            _stop_pool(ex, before)
            # its manager thread ends once it sees the workers gone; not waited for beyond the bound (a worker
            # in uninterruptible sleep dies late; the interpreter's exit joins the thread again)
            _in_thread(lambda: ex.shutdown(wait=True), _POOL_GRACE, "adaptfilt-pool-shutdown")
            ex = None
        raise
    finally:
        if ex is not None:
            ex.shutdown(wait=True)  # every job has finished


def _as_completed(futs: dict):
    """``concurrent.futures.as_completed``, waking every half second: a signal handler runs in the main thread
    only when it runs Python code, and a signal the kernel gives another thread does not wake a main thread
    blocked in a lock's acquire, which ``as_completed`` is until the next job ends (minutes, maybe)."""
    pending = set(futs)
    while pending:
        done, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
        yield from sorted(done, key=futs.__getitem__)


@contextlib.contextmanager
def _deferred_interrupts(deaf: bool = True):
    """Hold Ctrl-C and SIGTERM during a short section that must not be torn apart, then let the signal act
    as it would have, at the section's end (its handler called then; SIG_DFL: the signal raised again).

    Starting worker processes is one: a spawn interrupted half-way leaves a child reading its start-up data
    from a pipe the parent never wrote, which prints a traceback after the command's last line; recording a
    finished job (``on_done``) is another. ``deaf``: the section also blocks SIGINT in this thread
    (:func:`_deaf_to_ctrl_c`), so that the workers it starts ignore a terminal's Ctrl-C from birth. Signal
    handlers are the main thread's: elsewhere only the blocking applies."""
    if threading.current_thread() is not threading.main_thread():
        mask = _deaf_to_ctrl_c() if deaf else None
        try:
            yield
        finally:
            _restore_mask(mask)
        return
    held: list[int] = []

    def hold(signum, frame) -> None:
        held.append(signum)

    previous: dict = {}
    mask = None
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            handler = signal.getsignal(sig)
            if handler is not None and handler is not signal.SIG_IGN:  # None: not set from Python
                previous[sig] = signal.signal(sig, hold)
        if deaf:
            mask = _deaf_to_ctrl_c()  # held too: it may start the resource tracker, a process
        yield
    finally:
        _restore_mask(mask)  # a Ctrl-C held by the mask comes now, to ``hold`` or to the handler restored
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if held:
            handler = previous[held[0]]
            if callable(handler):
                handler(held[0], None)
            else:
                signal.raise_signal(held[0])


def _deaf_to_ctrl_c():
    """Block SIGINT in the calling thread and return the previous mask (None where there are no masks).

    A terminal sends Ctrl-C to the whole process group, workers included, and a worker that gets it while
    it starts, before its initializer ignores it (:func:`_worker_init`), prints a KeyboardInterrupt
    traceback. Threads started by this one and processes they spawn inherit the mask, so the workers are
    deaf to it from birth; the main thread, which does not block it, still gets it and stops the run (as
    the standard library's resource tracker is started)."""
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - not POSIX
        return None
    # started first: starting it unblocks SIGINT and SIGTERM in the thread that does (multiprocessing's
    # own trick to start it deaf), which would be the thread starting the workers, from then on
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    return signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


def _restore_mask(mask) -> None:
    if mask is not None:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def _stop_pool(ex: ProcessPoolExecutor, before: set = frozenset(), grace: float = _POOL_GRACE) -> None:
    """Cancel what has not started and terminate the workers (the with-block's shutdown would wait
    for every queued job). A terminated job leaves no partial file: jobs write atomically.

    The workers are the pool's and every child process started since the pool was (``before``: the
    children then): an interrupt that came while the pool was starting a worker leaves one the pool
    does not know yet, and the interpreter's exit would wait for it (multiprocessing joins every child)."""
    import multiprocessing as mp

    procs = list((getattr(ex, "_processes", None) or {}).values())
    procs += [p for p in mp.active_children() if p not in before and p not in procs]
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + grace
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
    deadline = time.monotonic() + 1.0  # one second for all, however many workers
    for p in procs:
        if p.is_alive():
            p.kill()
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))


def _run_dask(fn: Callable, jobs: list[tuple], cluster, finished: Callable) -> list:
    try:
        from distributed import Client, as_completed as dask_completed
    except ImportError as e:
        raise ImportError(f"a Dask cluster needs the distributed package: pip install 'adaptfilt[cluster]' ({e})") from e

    started = _Started()  # the client started here, if any: filled by its own thread, closed below
    futs: list = []
    stopping = False
    try:
        client = cluster if isinstance(cluster, Client) else _start_client(Client, cluster, started)
        futs = [client.submit(_call, fn, a, pure=False) for a in jobs]
        index = {f.key: i for i, f in enumerate(futs)}
        out: list = [None] * len(jobs)
        for f in dask_completed(futs):
            i = index[f.key]
            try:
                out[i] = f.result()
            except Exception as e:
                raise _failed(i, fn, jobs[i], e, " on the cluster") from e
            finished(i, out[i])
        return out
    except BaseException:
        stopping = True
        # the cancelled tasks and stopped workers are expected now: no screenful of warnings about them
        logging.getLogger("distributed").setLevel(logging.ERROR)
        if futs and cluster != "local":  # a shared cluster must not go on with jobs nobody waits for
            _in_thread(lambda: client.cancel(futs), _DASK_CANCEL, "adaptfilt-dask-cancel")
        raise
    finally:
        started.close(stopping)


def _in_thread(fn: Callable[[], Any], seconds: float | None, name: str, started: "_Started | None" = None) -> dict:
    """Run ``fn()`` in a daemon thread and wait for it at most ``seconds`` (None: until it ends).

    An interrupt raised in the main thread (the signal handlers raise at whatever bytecode runs) then
    stops the waiting, never ``fn`` half-way: a Dask client's start-up or close torn apart can leave a
    cluster half-started or a lock held, which hangs a later close or the interpreter's exit.
    Returns ``{"value": ...}``, ``{"error": exception}``, or ``{}`` if ``fn`` had not ended."""
    box: dict = {}
    done = threading.Event()

    def run() -> None:
        try:
            box["value"] = fn()
        except BaseException as e:  # reported to the waiting thread
            box["error"] = e
        finally:
            done.set()

    thread = threading.Thread(target=run, daemon=True, name=name)
    if started is not None:
        started.thread = thread
    thread.start()
    if seconds is None:
        while not done.wait(0.1):
            pass
    else:
        done.wait(seconds)
    return dict(box)


class _Started:
    """The Dask client :func:`_start_client` starts, handed over by the thread that starts it, so that it
    is closed however the start-up ends: an interrupt while it starts, or before the caller has it.

    One of two closes it: :meth:`close` (the caller's), which waits for a start-up still going on, or,
    if that one has left (it gave up waiting, or found nothing started yet), the start thread itself."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.thread: threading.Thread | None = None  # the start thread, once created
        self.client = None  # handed over, not yet closed
        self.stop = threading.Event()  # set: nobody will use the client; the start thread must not go on
        self.gone = False  # set: the closer has left; a client handed over now is closed by its start thread

    def hand_over(self, client) -> bool:
        """From the start thread: keep ``client``; False if it must be closed there (the closer has left)."""
        with self.lock:
            if self.gone:
                return False
            self.client = client
            return True

    def close(self, stopping: bool) -> None:
        """Close the client started here, waiting for a start-up still going on, all within ``_DASK_CLOSE`` s."""
        self.stop.set()
        end = time.monotonic() + _DASK_CLOSE
        while True:
            with self.lock:
                client, self.client = self.client, None
                if client is not None or self.thread is None or not self.thread.is_alive() \
                        or time.monotonic() >= end:
                    self.gone = True
                    break
            time.sleep(0.05)
        if client is not None:
            _close_client(client, stopping, max(1.0, end - time.monotonic()))


def _start_client(Client, cluster, started: _Started) -> Any:
    """A client of the cluster at address ``cluster``, or of a local cluster (``"local"``) whose workers are
    this process's children: they ignore Ctrl-C and die with it, as the pool's do.

    Started in a thread of its own (:func:`_in_thread`), which hands the client to ``started`` as soon
    as it exists, so that the caller closes it (:meth:`_Started.close`) even if an interrupt stops the
    waiting here, or comes before the caller holds the client."""
    parent = os.getpid()

    def start() -> Any:
        _deaf_to_ctrl_c()  # this thread's, inherited by the client's threads and the workers they spawn
        if cluster == "local":
            # CRITICAL, not ERROR: on Ctrl-C the scheduler closes first and each worker logs its failed
            # heartbeat as an ERROR traceback; a job's own error reaches us as an exception, not a log line
            client = Client(processes=True, n_workers=default_workers(), threads_per_worker=1,
                            dashboard_address=None, silence_logs=logging.CRITICAL)
        else:
            try:
                client = Client(str(cluster))
            except (OSError, ValueError):  # distributed's own word: a timeout, a malformed address
                raise
            except Exception as e:  # its IO loop failed to start (an AssertionError inside distributed)
                raise ConnectionError(f"could not connect to the Dask scheduler at {cluster}: {e!r}") from e
        if not started.hand_over(client):
            _close_client(client, stopping=True)
        elif cluster == "local" and not started.stop.is_set():
            client.run(_worker_init, parent)
        return client

    box = _in_thread(start, None, "adaptfilt-dask-start", started)
    if "error" in box:
        raise box["error"]
    return box["value"]


def _close_client(client, stopping: bool, seconds: float = _DASK_CLOSE) -> None:
    """Close ``client`` (and the local cluster it started, if any) within about ``seconds``, in a thread of
    its own (:func:`_in_thread`). When stopping, a close that fails or does not end in time is left to
    the process's exit: distributed's own exit hook, which would try again for 10 s and print a traceback
    after the command's last line, is told the cluster is not its to close (its workers are this
    process's children and die with it)."""
    box = _in_thread(lambda: client.close(timeout=seconds), seconds + 1.0, "adaptfilt-dask-close")
    if stopping and "value" not in box:
        cluster = getattr(client, "cluster", None)
        if cluster is not None:
            cluster.shutdown_on_close = False
