"""Settings for the whole suite, the tests and the notebooks alike.

pytest-xdist runs one test file (or notebook) per core (``-n auto`` in pyproject.toml). OpenBLAS starts
threads of its own as well, and they spin for a while before they sleep: with every core busy, the
spinning takes the cores the other workers need (a point-mass filter run: 11-12.5 CPU-s with the
default wait, 7.7-8.7 with the shortest, on 2 busy cores). Under xdist each process, and each process
it starts (notebook kernels, command-line runs, pool workers), waits the shortest time
(``OPENBLAS_THREAD_TIMEOUT=4``, which changes no number); a value set in the environment is kept. One
BLAS thread per process would be as fast, but it changes numbers: OpenBLAS on one thread computes a
matrix product (even a matrix-vector one) in another order than on two or more.

Stable-Baselines3 makes an empty folder ``SB3-<time>`` in the temporary directory for every model
that learns without a logger of its own (the tests' and chapter 13's small trainings; the library's
trainers set one). ``SB3_LOGDIR`` names the one folder they all use instead, removed at the end.
"""
import os
import shutil
import tempfile

# the old chapters' notebooks that the verdict-word test reads are data, not notebooks to execute
collect_ignore_glob = ["tests/fixtures/*"]


def pytest_configure(config) -> None:
    if "SB3_LOGDIR" not in os.environ:
        os.environ["SB3_LOGDIR"] = config._adaptfilt_sb3 = tempfile.mkdtemp(prefix="adaptfilt-sb3-")


def pytest_unconfigure(config) -> None:
    made = getattr(config, "_adaptfilt_sb3", None)
    if made:
        shutil.rmtree(made, ignore_errors=True)
        os.environ.pop("SB3_LOGDIR", None)


if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")
