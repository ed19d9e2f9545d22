"""The compiled Cholesky factor (:mod:`adaptfilt.linalg_kernels`) is numpy's form's bit for bit, over
dimensions 2-12, batches of runs across the kernel's blocks and conditioning over many decades; a
pivot that is not positive is handed back to numpy's form, which names the same runs."""
from __future__ import annotations

import numpy as np
import pytest

from adaptfilt import linalg, linalg_kernels

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)

needs_kernel = pytest.mark.skipif(not linalg_kernels.available(),
                                  reason="numba missing, or numpy's einsum fuses multiply-adds (see linalg_kernels.einsum_is_plain)")


def _spd(rng, n: int, M: int) -> np.ndarray:
    """``(n, n, M)`` positive definite, scales over six decades per run and condition numbers up to ~1e8."""
    A = rng.standard_normal((M, n, n)) * 10.0 ** rng.uniform(-3, 3, (M, 1, 1))
    P = np.einsum("mij,mkj->ikm", A, A) + np.eye(n)[:, :, None] * 10.0 ** rng.uniform(-8, 0, M)
    return np.ascontiguousarray(P)


def _numpy_form(monkeypatch, P):
    with monkeypatch.context() as mp:
        mp.setattr(linalg_kernels, "SUMS", False)
        assert linalg_kernels.chol_positive(P) is False
        return linalg.chol(P)


@needs_kernel
@pytest.mark.parametrize("n", [2, 3, 4, 5, 8, 12])
@pytest.mark.parametrize("M", [2, 3, 37, 257, 1000])
def test_the_factor_is_numpys_bit_for_bit(monkeypatch, n, M):
    P = _spd(np.random.default_rng(100 * n + M), n, M)
    got = linalg_kernels.chol_positive(P)
    assert got is not None and got is not False
    ref = _numpy_form(monkeypatch, P)
    assert got.tobytes() == ref.tobytes()
    assert np.array_equal(linalg.chol(P), ref)  # and chol takes it
    assert not np.triu(np.moveaxis(got, -1, 0), 1).any()


@needs_kernel
@pytest.mark.parametrize("bad", [-1.0, 0.0, np.nan])
def test_a_pivot_that_is_not_positive_names_the_same_runs(monkeypatch, bad):
    P = _spd(np.random.default_rng(7), 4, 50)
    P[2, 2, [3, 17]] = bad  # the third pivot of runs 3 and 17
    P[0, 0, 40] = bad if bad != 0.0 else -0.0  # the first of run 40
    assert linalg_kernels.chol_positive(P) is None
    with pytest.raises(linalg.NotPositiveDefinite) as got:
        linalg.chol(P)
    with monkeypatch.context() as mp:
        mp.setattr(linalg_kernels, "SUMS", False)
        with pytest.raises(linalg.NotPositiveDefinite) as ref:
            linalg.chol(P)
    assert got.value.runs.tolist() == ref.value.runs.tolist() == [3, 17, 40]


def test_what_the_kernel_does_not_factor_is_numpys():
    """One run, a scalar, another dtype, a non-contiguous batch, more than 12 dimensions: False (numpy's form)."""
    rng = np.random.default_rng(1)
    P = _spd(rng, 3, 10)
    for other in (P[..., :1], P[:1, :1], P.astype(np.float32), np.asfortranarray(P), P[:, :, ::2], _spd(rng, 13, 4)):
        assert linalg_kernels.chol_positive(other) is False
