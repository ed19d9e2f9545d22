"""The prefix-average path of the stochastic integration rule and the filter's candidate updates.

With a fixed count, ``n_iter = k`` averages the first ``k`` draws of the rule's Generator, so every
grid value's moments are snapshots of one recursion of ``max(grid)`` draws. These tests hold that
path to the tiled evaluation (``tile = G``, G copies of every run) and to separate untiled calls,
one per grid value, which is what the candidates mean.
"""
import itertools

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.mdp import rollout
from adaptfilt.policies import GreedyPolicy, MaxLikelihoodPolicy
from adaptfilt.rules import StochasticIntegrationRule, UnscentedRule

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)

ORDERS, PASSES, ERRORS = (1, 3, 5), (1, 2), (False, "diag", "full")
SIF_GRID = np.array([1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0])
FIELDS = ("z_pred", "Pzz", "Pxz", "K", "innovation", "nis", "loglik", "x_filt", "P_filt", "n_iter_spent")


def assert_close(a, b, what, rtol=1e-12):
    """Equal to ``rtol`` relative to the largest entry of each array (entries that cancel to ~0 included)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, (what, a.shape, b.shape)
    assert np.isfinite(a).all() and np.isfinite(b).all(), what
    scale = max(np.abs(b).max(), 1e-300)
    assert np.abs(a - b).max() <= rtol * scale, (what, np.abs(a - b).max() / scale)


def g_two(X):
    """A nonlinear map R^3 -> R^2 (run axis last), not integrated exactly by any order."""
    return np.stack([np.sin(X[0]) * X[1], np.exp(0.3 * X[2]) + X[0] ** 2])


def spd_batch(rng, n, M):
    A = rng.standard_normal((n, n, M))
    return np.einsum("ikM,jkM->ijM", A, A) + 0.5 * np.eye(n)[:, :, None]


# ---------------------------------------------------------------- the rule
@pytest.mark.parametrize("order,passes,ie", list(itertools.product(ORDERS, PASSES, ERRORS)))
def test_prefixes_equal_tiled_and_untiled_moments(order, passes, ie):
    rng = np.random.default_rng(3)
    n, M = 3, 6
    m, P = rng.standard_normal((n, M)), spd_batch(rng, n, M)
    grid = [5, 1, 3, 5, 8]  # unsorted, with a repeat
    G = len(grid)
    tile = lambda a: np.concatenate([a] * G, axis=-1)  # noqa: E731
    rule = StochasticIntegrationRule(order=order, passes=passes, integration_error=ie)
    pre = rule.moments_prefixes(g_two, m, P, grid, rng=np.random.default_rng(11))
    tiled = rule.moments(g_two, tile(m), tile(P), np.repeat(np.array(grid, float), M), rng=np.random.default_rng(11), tile=G)
    assert len(pre) == G
    for gi, k in enumerate(grid):
        one = rule.moments(g_two, m, P, k, rng=np.random.default_rng(11))
        sl = slice(gi * M, (gi + 1) * M)
        for name in ("mean", "cov", "cross", "mean_var"):
            a, b, c = getattr(pre[gi], name), getattr(tiled, name), getattr(one, name)
            if c is None:
                assert a is None and b is None, name
                continue
            assert_close(a, b[..., sl], f"{name} vs tiled, k={k}")
            assert_close(a, c, f"{name} vs untiled, k={k}")
        assert pre[gi].n_iter.tolist() == [passes * k] * M
    if ie:  # the error term is there and is not the same for every count
        assert np.abs(pre[1].mean_var).max() == 0.0  # k = 1: V_1 = 0 (the documented convention)
        assert not np.allclose(pre[2].mean_var, pre[4].mean_var)


def test_prefixes_without_cross_and_refusals():
    rng = np.random.default_rng(4)
    m, P = rng.standard_normal((3, 4)), spd_batch(rng, 3, 4)
    rule = StochasticIntegrationRule(order=5, passes=2)
    mo = rule.moments_prefixes(g_two, m, P, [2, 4], rng=np.random.default_rng(1), cross=False)
    assert all(x.cross is None for x in mo)
    assert_close(mo[1].cov, rule.moments(g_two, m, P, 4, rng=np.random.default_rng(1), cross=False).cov, "cov")
    assert StochasticIntegrationRule().supports_prefixes and not UnscentedRule().supports_prefixes
    tol_rule = StochasticIntegrationRule(tol=1e-3)
    assert not tol_rule.supports_prefixes
    with pytest.raises(ValueError, match="fixed count"):
        tol_rule.moments_prefixes(g_two, m, P, [1, 2], rng=np.random.default_rng(1))
    for bad, msg in (([], "non-empty"), ([[1, 2]], "non-empty"), ([0, 2], "positive integer"), ([1.5], "positive integer")):
        with pytest.raises(ValueError, match=msg):
            rule.moments_prefixes(g_two, m, P, bad, rng=np.random.default_rng(1))
    with pytest.raises(ValueError, match="Generator"):
        rule.moments_prefixes(g_two, m, P, [1, 2])


# -------------------------------------------------------------- the filter
def predicted_state(sif, traj, t):
    """``(m, P, z)`` run-last at step ``t`` of a filter run on ``traj``."""
    run = sif.run(traj.z[:, :t + 1], keep_pred=True)
    return run.x_pred[:, t].T.copy(), np.moveaxis(run.P_pred[:, t], 0, -1).copy(), traj.z[:, t].T.copy()


def ctm_across_the_cut(M, rng):
    """CTM predictions straddling the bearing's +-pi cut (target behind the sensor, on the -x axis)."""
    m = np.stack([-40.0 + rng.standard_normal(M), rng.standard_normal(M), 0.3 * rng.standard_normal(M),
                  rng.standard_normal(M)])
    P = np.repeat(np.diag([4.0, 1.0, 25.0, 1.0])[:, :, None], M, axis=2)
    z = np.where(rng.random(M) < 0.5, np.pi - 0.01, -np.pi + 0.01)[None]
    return m, P, z


CASES = [(model, order, passes, ie) for model in ("ctm", "ungm") for order in (3, 5) for passes in PASSES for ie in ERRORS]


@pytest.mark.parametrize("model_name,order,passes,ie", CASES)
def test_candidates_prefix_path_equals_tiled_path(model_name, order, passes, ie):
    """update_candidates_rl: the prefix path against the tiled path and against one untiled update per
    grid value, with the per-step, per-episode Generator the MDP uses."""
    model = af.models.coordinated_turn() if model_name == "ctm" else af.models.ungm()
    sif = af.SIF(model, n_iter=10, seed=5, order=order, passes=passes, integration_error=ie, on_indefinite="clip")
    traj = model.simulate(8, 4, rng=21)
    states = [(predicted_state(sif, traj, 3), 3)]
    if model_name == "ctm":
        states.append((ctm_across_the_cut(8, np.random.default_rng(2)), 1))
    grid = SIF_GRID if order == 3 else SIF_GRID[:6]  # degree 5 costs 4x per draw; the prefix logic is the same
    G = grid.size
    for (m, P, z), t in states:
        M = m.shape[1]
        tile = lambda a: np.concatenate([a] * G, axis=-1)  # noqa: E731
        assert sif.candidate_prefixes
        fast = sif.update_candidates_rl(m, P, z, t, grid, rng=sif.rng(1, t, 7))
        ref = sif.update_rl(tile(m), tile(P), tile(z), t, np.repeat(grid, M), rng=sif.rng(1, t, 7), tile=G)
        sif.candidate_prefixes = False
        slow = sif.update_candidates_rl(m, P, z, t, grid, rng=sif.rng(1, t, 7))
        sif.candidate_prefixes = True
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(slow, name), getattr(ref, name), err_msg=name)  # the fallback is the tiled call
            assert_close(getattr(fast, name), getattr(ref, name), name)
        for g in (0, 3, G - 1):
            one = sif.update_rl(m, P, z, t, grid[g], rng=sif.rng(1, t, 7))
            for name in FIELDS:
                assert_close(getattr(fast, name)[..., g * M:(g + 1) * M], getattr(one, name), f"{name}, g={g}")
        if model_name == "ctm" and t == 1:  # the wrap matters here: without it the bearing's mean is ~0, not ~pi
            assert (np.abs(fast.z_pred) > 2.5).all()


def test_candidates_fall_back_to_the_tiled_call():
    """Tolerance stopping, deterministic rules and linear measurements take the tiled call, bit for bit."""
    ctm, lin = af.models.coordinated_turn(), af.models.ungm()
    traj = ctm.simulate(5, 3, rng=1)
    grid = np.array([1.0, 4.0, 9.0])
    for filt, g in ((af.SIF.reference(ctm, seed=2), grid), (af.UKF(ctm), np.array([-1.0, 0.0, 2.0]))):
        m, P, z = predicted_state(filt, traj, 2)
        M, G = m.shape[1], g.size
        tile = lambda a: np.concatenate([a] * G, axis=-1)  # noqa: E731
        rng = filt.rng(1, 2, 3)
        fast = filt.update_candidates_rl(m, P, z, 2, g, rng=rng)
        ref = filt.update_rl(tile(m), tile(P), tile(z), 2, np.repeat(g, M), rng=filt.rng(1, 2, 3), tile=G)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(fast, name), getattr(ref, name), err_msg=name)
    with pytest.raises(ValueError, match="grid must be"):
        af.SIF(ctm).update_candidates_rl(m, P, z, 2, [])


@pytest.mark.parametrize("policy", [GreedyPolicy, MaxLikelihoodPolicy])
def test_sif_episode_choices_identical_with_and_without_prefixes(policy):
    """A short SIF episode of the ctm-sif-nis experiment: the greedy (and ML) choices, costs and
    filter outputs are those of the tiled candidates."""
    exp = get_experiment("ctm-sif-nis")
    traj = exp.make_env(n_steps=5).model.simulate(60, 6, rng=9)
    out = {}
    for prefixes in (True, False):
        env = exp.make_env(n_steps=5)
        env.filt.candidate_prefixes = prefixes
        out[prefixes] = rollout(env, policy(), traj=traj, stream=4)
    (fast, cf), (slow, cs) = out[True], out[False]
    np.testing.assert_array_equal(fast.params, slow.params)
    assert len(np.unique(fast.params)) > 2  # the choices are not all one value
    assert_close(cf, cs, "cost")
    assert_close(fast.mean, slow.mean, "mean")
    assert_close(fast.cov, slow.cov, "cov")
