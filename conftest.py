"""Settings for the whole suite, the tests and the notebooks alike.

pytest-xdist runs one test file (or notebook) per core (``-n auto`` in pyproject.toml). OpenBLAS starts
threads of its own as well, and they spin for a while before they sleep: with every core busy, the
spinning takes the cores the other workers need (a point-mass filter run: 11-12.5 CPU-s with the
default wait, 7.7-8.7 with the shortest, on 2 busy cores). Under xdist each process, and each process
it starts (notebook kernels, command-line runs, pool workers), waits the shortest time
(``OPENBLAS_THREAD_TIMEOUT=4``, which changes no number); a value set in the environment is kept. One
BLAS thread per process would be as fast, but it changes numbers: OpenBLAS on one thread computes a
matrix product (even a matrix-vector one) in another order than on two or more.
"""
import os

if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")
