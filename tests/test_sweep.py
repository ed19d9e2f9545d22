"""The sweep runner: the same results bit for bit on one process, a process pool and a Dask cluster."""
import hashlib
import os
import signal
import time

import numpy as np
import pytest

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)


def train_job(algo: str, seed: int) -> str:
    """A tiny training: a digest of the policy's arrays."""
    from adaptfilt.trainers import train_policy

    pol = train_policy("ungm-ukf", algo, 0.5, episodes=12, seed=seed, progress=False, n_steps=20,
                       **({"parallel": 4} if algo == "batched" else {}))
    arrays, _ = pol.to_arrays()
    return hashlib.sha256(b"".join(arrays[k].tobytes() for k in sorted(arrays))).hexdigest()


def failing_job(x: int, *rest) -> int:
    if x == 2:
        raise ValueError("two is not allowed")
    return x


JOBS = [("batched", 0), ("a2c", 0), ("batched", 1), ("a2c", 1)]


def test_process_pool_equals_serial():
    from adaptfilt.experiments.sweep import run_jobs

    serial = run_jobs(train_job, JOBS, workers=1, progress=False)
    assert len(set(serial)) == len(JOBS)  # different seeds and algorithms: different policies
    assert run_jobs(train_job, JOBS, workers=2, progress=False) == serial


def test_dask_in_process_cluster_equals_serial():
    distributed = pytest.importorskip("distributed")
    from adaptfilt.experiments.sweep import run_jobs

    serial = run_jobs(train_job, JOBS, workers=1, progress=False)
    # two threads in one worker process: jobs must not draw from each other's global generators
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=2, dashboard_address=None) as client:
        assert run_jobs(train_job, JOBS, cluster=client, progress=False) == serial


def test_errors_name_the_job():
    from adaptfilt.experiments.sweep import run_jobs

    for workers in (1, 2):
        with pytest.raises(RuntimeError, match=r"job 2 failing_job\(2,\) failed: two is not allowed"):
            run_jobs(failing_job, [(1,), (3,), (2,)], workers=workers, progress=False)
    with pytest.raises(ValueError, match="workers"):
        run_jobs(failing_job, [(1,), (3,)], workers=0, progress=False)
    assert run_jobs(failing_job, [], progress=False) == []
    assert np.array_equal(run_jobs(failing_job, [(1,), (3,)], workers=1, progress=False), [1, 3])


def dying_job(x: int) -> int:
    if x == 1:
        os.kill(os.getpid(), signal.SIGKILL)  # as the OOM killer would
    time.sleep(0.2)
    return x


def test_a_worker_that_dies_is_a_failed_job_naming_it():
    from adaptfilt.experiments.sweep import JobFailed, run_jobs

    with pytest.raises(JobFailed, match=r"a worker process died .*try fewer --workers"):
        run_jobs(dying_job, [(0,), (1,), (2,), (3,)], workers=2, progress=False)


def test_long_arguments_are_cut_short_in_the_error():
    from adaptfilt.experiments.sweep import JobFailed, run_jobs

    with pytest.raises(JobFailed) as e:
        run_jobs(failing_job, [(2, "x" * 500)], workers=1, progress=False)
    assert len(str(e.value)) < 200 and str(e.value).endswith("failed: two is not allowed")


def sleeping_job(x: int) -> int:
    time.sleep(0.3)
    return x


def test_ctrl_c_cancels_the_jobs_on_a_shared_dask_cluster():
    """A cluster the caller owns is left open, and no job of the interrupted run stays on it."""
    distributed = pytest.importorskip("distributed")
    from adaptfilt.experiments.sweep import Interrupted, run_jobs

    def stop(i, value):
        raise KeyboardInterrupt

    with distributed.Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=None) as client:
        with pytest.raises(Interrupted) as e:
            run_jobs(sleeping_job, [(i,) for i in range(20)], cluster=client, progress=False, on_done=stop)
        assert (e.value.done, e.value.total) == (1, 20)  # stopped as the first job finished
        end = time.monotonic() + 10
        while client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) and time.monotonic() < end:
            time.sleep(0.05)
        assert client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) == 0
        assert client.status == "running" and run_jobs(sleeping_job, [(7,)], cluster=client, progress=False) == [7]


def test_a_workers_warning_reaches_the_console_in_one_line(capfd):
    """A job's warning is printed by the worker as ``adaptfilt: warning: ...``, not in Python's two-line
    format with our source line under it."""
    import warnings

    from adaptfilt.experiments.sweep import run_jobs

    msg = ("attempt 0 has not beaten\n its initial network", RuntimeWarning)
    run_jobs(warnings.warn, [msg, msg], workers=2, progress=False)  # two jobs: a pool, not this process
    err = capfd.readouterr().err
    assert "adaptfilt: warning: attempt 0 has not beaten its initial network\n" in err
    assert "RuntimeWarning" not in err and "sweep.py" not in err


def test_the_command_line_formats_warnings_in_one_line_and_gives_the_format_back():
    import warnings

    from adaptfilt import cli

    before = warnings.formatwarning
    with cli._console_warnings():
        assert warnings.formatwarning("x", RuntimeWarning, "f.py", 1) == "adaptfilt: warning: x\n"
    assert warnings.formatwarning is before
