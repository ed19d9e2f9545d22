"""The compiled point construction and weighted sums (:func:`adaptfilt.rules._sif_kernels.points`,
:func:`~adaptfilt.rules._sif_kernels.weighted_sums`) give numpy's numbers bit for bit: numpy's einsum
(``mm``, ``isM,jsM->ijM``) and ``sum(axis=1)`` add ``0 + p_0 + p_1 + ...`` in the order of the summed
axis, element by element along the run axis, each product rounded before it is added (the x86-64
wheels' baseline has no FMA; a build with one is detected and left to numpy)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt import linalg_kernels
from adaptfilt.rules import _sif_kernels
from adaptfilt.rules.base import _pair_sums, _pair_sums_made, _PointSet, _weighted_sums
from adaptfilt.linalg import mm

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)

needs_kernels = pytest.mark.skipif(not _sif_kernels.sums_available(),
                                   reason="numba missing, or numpy's einsum fuses multiply-adds (see linalg_kernels.einsum_is_plain)")


def _wide(rng, shape):
    """Values over 12 decades, both signs, with signed zeros: rounding shows in every bit."""
    a = rng.standard_normal(shape) * 10.0 ** rng.uniform(-6, 6, shape)
    flat = a.reshape(-1)
    flat[rng.integers(0, flat.size, max(1, flat.size // 50))] = -0.0
    flat[rng.integers(0, flat.size, max(1, flat.size // 50))] = 0.0
    return a


def _bits(a):
    return None if a is None else np.ascontiguousarray(a).view(np.int64)


def _same(a, b):
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and np.array_equal(_bits(a), _bits(b))


def _case(n, K, ng, M, seed, rotate, scale_kind, weight_kind, residual_kind, layout):
    rng = np.random.default_rng(seed)
    m = _wide(rng, (n, M))
    L = np.tril(_wide(rng, (n, n, M)).transpose(2, 0, 1)).transpose(1, 2, 0).copy()
    Q = _wide(rng, (n, K, M)) if rotate else None
    K = K if rotate else n
    scale = {"scalar": 1.7, "one": 1.0, "runs": np.abs(_wide(rng, (M,)))}[scale_kind]
    weight = {"scalar": 0.5, "runs": _wide(rng, (M,)), "dirs": _wide(rng, (K, M))}[weight_kind]
    C = _wide(rng, (ng, n))

    def g(X):  # (n, S, M) -> (ng, S, M), nonlinear; run-first layout moved to run-last when asked
        Y = np.einsum("gi,isM->gsM", C, np.tanh(X * 1e-3)) + np.sin(X[:1])
        return np.moveaxis(np.ascontiguousarray(np.moveaxis(Y, 0, -1)), -1, 0) if layout == "strided" else Y

    residual = None if residual_kind == "none" else (lambda a, b: np.arctan2(np.sin(a - b), np.cos(a - b)))
    g0 = g(m[:, None, :])[:, 0, :]
    return g, m, g0, L, Q, scale, weight, residual


SHAPES = [(2, 1, 1, 2), (2, 2, 2, 3), (2, 2, 1, 5), (3, 1, 2, 17), (4, 4, 1, 64), (5, 5, 1, 257), (5, 5, 3, 1001),
          (8, 8, 2, 33), (5, 1, 1, 1000)]


@needs_kernels
@pytest.mark.parametrize("n,K,ng,M", SHAPES)
@pytest.mark.parametrize("rotate", [True, False])
@pytest.mark.parametrize("cross", [True, False])
def test_points_and_sums_are_numpys_bit_for_bit(n, K, ng, M, rotate, cross):
    """Every shape, with and without a rotation, cross sums or not, scalar and per-run scales, scalar,
    per-run and per-direction weights, a residual or a plain difference, contiguous or strided values."""
    seed = 0
    for scale_kind in ("scalar", "one", "runs"):
        for weight_kind in ("scalar", "runs", "dirs"):
            for residual_kind, layout in (("none", "contig"), ("wrap", "strided")):
                seed += 1
                g, m, g0, L, Q, scale, weight, residual = _case(n, K, ng, M, seed, rotate, scale_kind, weight_kind,
                                                                residual_kind, layout)
                A = L if Q is None else mm(L, Q)
                ref = _pair_sums(g, m, g0, A * scale, weight, residual, cross)
                made = _sif_kernels.points(m, L, Q, scale)
                assert made is not None
                X, Ak = made
                assert np.array_equal(_bits(Ak), _bits(A * scale))
                got = _pair_sums_made(g, g0, X, Ak, weight, residual, cross)
                for a, b in zip(got, ref):
                    assert _same(a, b), (scale_kind, weight_kind, residual_kind)


@needs_kernels
def test_rules_use_the_kernels_and_give_numpys_moments(monkeypatch):
    """Through the rules: the unscented rule (scalar and per-run kappa) and the stochastic integration rule
    (degrees 1, 3, 5; subsets of runs), the same bits with the kernels on and off."""
    model = af.models.coordinated_turn()
    sif = af.SIF(model, seed=0)
    m, P = sif.initial(40)
    m = m + np.random.default_rng(0).standard_normal(m.shape)
    h, res = sif._wrap(model.h, 1), sif._residual_rl()

    def outputs():
        out = []
        for kappa in (0.0, np.linspace(-1, 3, 40)):
            mo = af.rules.UnscentedRule().moments(h, m, P, kappa, residual=res)
            out += [mo.mean, mo.cov, mo.cross]
        for order in (1, 3, 5):
            rule = af.rules.StochasticIntegrationRule(order=order, passes=2, integration_error="diag")
            counts = np.random.default_rng(order).integers(1, 6, 40)
            mo = rule.moments(h, m, P, counts, residual=res, rng=np.random.default_rng(order))
            out += [mo.mean, mo.cov, mo.cross, mo.mean_var]
        return out

    calls = []
    real = _sif_kernels.weighted_sums
    monkeypatch.setattr(_sif_kernels, "weighted_sums", lambda *a: calls.append(1) or real(*a))
    on = outputs()
    assert calls  # the kernels ran
    monkeypatch.setattr(linalg_kernels, "SUMS", False)
    off = outputs()
    for a, b in zip(on, off):
        assert _same(a, b)


def test_one_run_and_other_dtypes_take_numpys_form(monkeypatch):
    """One run (numpy reduces a contiguous axis pairwise), float32 values, or the kernels switched off:
    the kernels decline and numpy's form runs."""
    L = np.repeat(np.eye(3)[:, :, None], 4, axis=2)
    assert _sif_kernels.points(np.zeros((3, 1)), L[..., :1], None, 1.0) is None
    assert _sif_kernels.points(np.zeros((3, 4), dtype=np.float32), L, None, 1.0) is None
    assert _sif_kernels.weighted_sums(np.zeros((1, 6, 4), dtype=np.float32), np.zeros((3, 3, 4)), 0.5, True) is None
    monkeypatch.setattr(linalg_kernels, "SUMS", False)
    assert _sif_kernels.points(np.zeros((3, 4)), L, None, 1.0) is None
    monkeypatch.setattr(linalg_kernels, "SUMS", True)
    monkeypatch.setattr(linalg_kernels, "BACKEND", "numpy")
    assert _sif_kernels.points(np.zeros((3, 4)), L, None, 1.0) is None
    ps = _PointSet(scale=2.0, rotation=None, weight=0.25)
    g = lambda X: X[:1] ** 2  # noqa: E731
    m = np.arange(3.0)[:, None]
    got = _weighted_sums(g, m, g(m[:, None, :])[:, 0, :], np.eye(3)[:, :, None], ps, None, True)
    ref = _pair_sums(g, m, g(m[:, None, :])[:, 0, :], np.eye(3)[:, :, None] * 2.0, 0.25, None, True)
    assert all(_same(a, b) for a, b in zip(got, ref))


def test_the_einsum_probe_tells_fused_from_plain_sums():
    """The probe that keeps the kernels off a numpy built with FMA: on this machine's numpy it must say what
    an explicit fused sum says (numpy's einsum here is plain exactly when its products round first)."""
    e = 2.0 ** -30
    plain = -(1.0 + e) + (1.0 + e) * (1.0 - e)
    assert plain == -e  # the product rounds to 1 first
    assert linalg_kernels.einsum_is_plain() == bool(
        np.einsum("isM,jsM->ijM", np.full((1, 2, 37), 1.0 + e), np.stack([np.full(37, -1.0), np.full(37, 1.0 - e)])[None])[0, 0, 0] == -e)


def test_importing_the_rules_does_not_build_the_sum_kernels():
    code = "import adaptfilt.rules._sif_kernels as k; import adaptfilt.rules; print(k._sums is None)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "True"
