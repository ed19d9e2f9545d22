"""The stochastic integration rule's compiled Gram-Schmidt and random draws (:mod:`adaptfilt.rules._sif_kernels`)
give numpy's numbers bit for bit, and the rule gives the same moments with either backend."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt import linalg_kernels
from adaptfilt.rules import StochasticIntegrationRule, _sif_kernels

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)

needs_numba = pytest.mark.skipif(not _sif_kernels.available(), reason="the optional extra 'fast' (numba) is not installed")


def _gaussians(n: int, M: int, seed: int) -> np.ndarray:
    """Gaussian matrices with magnitudes over 12 decades (rounding shows in every bit) and one run of zeros
    in a column's entries but one (signed zeros in the sums)."""
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((n, n, M)) * 10.0 ** rng.uniform(-6, 6, (n, n, M))
    if n > 1:
        G[1:, 0, 0] = -0.0
    return G


@needs_numba
@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 8, 9, 12])
@pytest.mark.parametrize("M", [2, 3, 17, 256, 1001])
def test_compiled_gram_schmidt_is_numpys_bit_for_bit(monkeypatch, n, M):
    """Whole batches, subsets in any order, repeated runs and tiled copies (``runs`` beyond ``M``)."""
    G = _gaussians(n, M, seed=n * 1000 + M)
    rng = np.random.default_rng(M)
    subsets = [None, rng.permutation(M)[: max(2, M // 3)], np.array([M - 1, M - 1]), np.sort(rng.integers(0, M, 2 * M)),
               np.tile(np.arange(M), 3)]
    monkeypatch.setattr(linalg_kernels, "BACKEND", "numba")
    for runs in subsets:
        Q = _sif_kernels.gram_schmidt(G, runs)
        ref = _sif_kernels.gram_schmidt_numpy(G if runs is None else np.ascontiguousarray(G[..., runs]))
        assert Q.flags.c_contiguous and Q.shape == ref.shape
        assert np.array_equal(Q.view(np.int64), ref.view(np.int64))  # the bits, signed zeros and NaN payloads too


def test_one_run_and_the_numpy_backend_take_numpys_form(monkeypatch):
    """One run: numpy sums a contiguous axis pairwise, so the numpy form is used; likewise when the
    backend is set to numpy (the form without numba)."""
    G = _gaussians(9, 1, seed=3)
    assert np.array_equal(_sif_kernels.gram_schmidt(G), _sif_kernels.gram_schmidt_numpy(G))
    monkeypatch.setattr(linalg_kernels, "BACKEND", "numpy")
    G = _gaussians(5, 40, seed=4)
    assert np.array_equal(_sif_kernels.gram_schmidt(G, np.arange(3, 9)), _sif_kernels.gram_schmidt_numpy(G[..., 3:9].copy()))
    monkeypatch.setattr(linalg_kernels, "BACKEND", "cuda")
    with pytest.raises(ValueError, match="ADAPTFILT_SIF_BACKEND"):
        _sif_kernels.gram_schmidt(G)


def _sif_outputs(monkeypatch, backend: str) -> dict:
    monkeypatch.setattr(linalg_kernels, "BACKEND", backend)
    model = af.models.coordinated_turn()
    traj = model.simulate(24, 8, rng=5)
    counts = np.random.default_rng(1).integers(1, 7, size=(24, 8)).astype(float)
    out = {}
    for name, kw, params in (("deg3", dict(passes=2, integration_error="diag"), counts),
                             ("deg5", dict(order=5, passes=2, integration_error="full"), counts),
                             ("deg1", dict(order=1), 3),
                             ("tol", dict(tol=1e-3, n_min=2, passes=2, integration_error="diag"), 9)):
        run = af.SIF(model, seed=3, on_indefinite="clip", **kw).run(traj.z, params=params)
        out.update({f"{name}/{k}": v for k, v in (("mean", run.mean), ("cov", run.cov), ("nis", run.nis),
                                                  ("spent", run.info["n_iter_spent"]))})
    rule = StochasticIntegrationRule(passes=2, integration_error="diag")
    sif = af.SIF(model, seed=3)
    m, P = sif.initial(6)
    for i, mo in enumerate(rule.moments_prefixes(sif._wrap(model.h, 1), m, P, [1, 4, 2], residual=sif._residual_rl(),
                                                 rng=np.random.default_rng(2), tile=3)):
        out.update({f"prefix{i}/mean": mo.mean, f"prefix{i}/cov": mo.cov, f"prefix{i}/cross": mo.cross})
    return out


@needs_numba
def test_sif_runs_are_the_same_with_either_backend(monkeypatch):
    """Whole SIF runs (per-run counts, degrees 1, 3, 5, both passes, both error terms, tolerance
    stopping) and prefix moments of tiled runs: the same bits with the compiled and the numpy Gram-Schmidt."""
    a, b = _sif_outputs(monkeypatch, "numba"), _sif_outputs(monkeypatch, "numpy")
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k], b[k], equal_nan=True), k


@needs_numba
@pytest.mark.parametrize("bitgen", [np.random.PCG64, np.random.SFC64, np.random.Philox])
def test_compiled_draws_are_numpys_variates_and_leave_the_same_state(monkeypatch, bitgen):
    """``rule3_draws`` (numba's port of numpy's ziggurat and gamma sampler) against numpy's own calls, draw by
    draw: 1.2 million normals (thousands through the ziggurat's slow paths and its tail), the chi-square
    radii, and the generator's state afterwards; below the size where the compiled call pays, at one run,
    into the scratch buffers (views valid until the next call), and with the numpy backend."""
    a, b = np.random.Generator(bitgen(11)), np.random.Generator(bitgen(11))
    calls = [(5, 10_000, 4), (5, 256, 30), (2, 1, 1), (3, 7, 2), (5, 10_000, 2)]
    for i, (n, M, count) in enumerate(calls):
        G, chi2 = _sif_kernels.rule3_draws(a, n, M, count, scratch=i % 2 == 1)
        assert G.shape == (count, n, n, M) and chi2.shape == (count, M)
        for k in range(count):
            assert np.array_equal(G[k], b.standard_normal((n, n, M))), (n, M, k)
            assert np.array_equal(chi2[k], b.chisquare(n + 2, size=M)), (n, M, k)
        assert repr(a.bit_generator.state) == repr(b.bit_generator.state)  # SFC64, Philox: arrays in the state
    assert _sif_kernels._build_draws()  # the compiled form was used above the threshold
    monkeypatch.setattr(linalg_kernels, "BACKEND", "numpy")
    assert not _sif_kernels._build_draws()
    G, chi2 = _sif_kernels.rule3_draws(a, 5, 10_000)
    assert np.array_equal(G[0], b.standard_normal((5, 5, 10_000))) and np.array_equal(chi2[0], b.chisquare(7, 10_000))


def test_importing_adaptfilt_rules_does_not_compile_the_kernel():
    """The kernel is built on first use: importing the rules does not import numba for it."""
    code = ("import sys; import adaptfilt.rules._sif_kernels as k; import adaptfilt.rules.stochastic; "
            "print(k._kernel is None)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "True"


def test_without_numba_the_numpy_form_is_used(monkeypatch):
    """numba missing (the extra 'fast' not installed): ``auto`` falls back to numpy, ``numba`` says why it cannot."""
    monkeypatch.setitem(sys.modules, "numba", None)  # import numba raises ImportError
    monkeypatch.setattr(_sif_kernels, "_kernel", None)
    G = _gaussians(5, 30, seed=6)
    assert not _sif_kernels.available()
    assert np.array_equal(_sif_kernels.gram_schmidt(G, np.arange(4, 20)), _sif_kernels.gram_schmidt_numpy(G[..., 4:20].copy()))
    monkeypatch.setattr(linalg_kernels, "BACKEND", "numba")
    with pytest.raises(ImportError, match="numba"):
        _sif_kernels.gram_schmidt(G)
