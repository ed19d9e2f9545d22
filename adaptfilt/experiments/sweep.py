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
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, Callable, Sequence

__all__ = ["run_jobs", "default_workers"]


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


#: One job at a time per process: trainers seed process-global generators (torch, and SB3 also
#: numpy's and Python's), so two jobs in threads of one Dask worker would draw from each other's.
_LOCK = threading.Lock()


def _call(fn: Callable, args: tuple) -> Any:
    with _LOCK:
        _one_thread()
        return fn(*args)


def run_jobs(fn: Callable, jobs: Sequence[tuple], workers: int | None = None, cluster=None,
             progress: bool = True, desc: str = "jobs") -> list:
    """``[fn(*a) for a in jobs]``, in parallel (see the module docstring); results in job order.

    ``fn`` must be importable by name (a module-level function) for the process
    pool and a cluster. An exception in a job is raised here, naming the job.
    """
    jobs = [tuple(a) for a in jobs]
    if not jobs:
        return []
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(jobs), desc=desc, unit="job")
    try:
        if cluster is not None:
            return _run_dask(fn, jobs, cluster, bar)
        workers = default_workers() if workers is None else int(workers)
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if workers == 1 or len(jobs) == 1:
            out = []
            for i, a in enumerate(jobs):
                try:
                    out.append(_call(fn, a))
                except Exception as e:
                    raise RuntimeError(f"job {i} {fn.__name__}{a!r} failed: {e}") from e
                if bar is not None:
                    bar.update(1)
            return out
        import multiprocessing as mp

        with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=mp.get_context("spawn"),
                                 initializer=_one_thread) as ex:
            futs = [ex.submit(fn, *a) for a in jobs]
            return _gather(as_completed(futs), {f: i for i, f in enumerate(futs)}, fn, jobs, bar, "")
    finally:
        if bar is not None:
            bar.close()


def _gather(completed, index: dict, fn: Callable, jobs: list[tuple], bar, where: str, key=lambda f: f) -> list:
    """Results in job order as the futures complete; a failed job is an error naming it."""
    out: list = [None] * len(jobs)
    for f in completed:
        i = index[key(f)]
        try:
            out[i] = f.result()
        except Exception as e:
            raise RuntimeError(f"job {i} {fn.__name__}{jobs[i]!r} failed{where}: {e}") from e
        if bar is not None:
            bar.update(1)
    return out


def _run_dask(fn: Callable, jobs: list[tuple], cluster, bar) -> list:
    from distributed import Client, as_completed as dask_completed

    own = None
    if isinstance(cluster, Client):
        client = cluster
    elif cluster == "local":  # a throw-away cluster of local worker processes, one job each at a time
        own = client = Client(processes=True, n_workers=default_workers(), threads_per_worker=1,
                              dashboard_address=None)
    else:
        own = client = Client(str(cluster))
    try:
        futs = [client.submit(_call, fn, a, pure=False) for a in jobs]
        return _gather(dask_completed(futs), {f.key: i for i, f in enumerate(futs)}, fn, jobs, bar, " on the cluster",
                       key=lambda f: f.key)
    finally:
        if own is not None:
            own.close()
