"""The PPO step-through of chapter 7 (adaptfilt.course.ppo_step) against Stable-Baselines3's own
computation: GAE (RolloutBuffer.compute_returns_and_advantage), the loss PPO.train() logs, and the
weights after its update. If SB3 or the hand-written update drifts, this fails."""
import copy

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("stable_baselines3")

from adaptfilt.course import ppo_step as ps  # noqa: E402
from adaptfilt.toy import BanditEnv, TrapEnv  # noqa: E402


def _rollout(env=None, seed=0, runs=4, steps=6):
    env = env or TrapEnv(n_steps=10)
    pol = ps.TinyPolicy(2, env.n_actions, seed=seed)
    return pol, ps.collect(env, pol, n_runs=runs, n_steps=steps, seed=seed)


def test_gae_matches_sb3_with_episode_ends():
    pol, ro = _rollout(BanditEnv(n_steps=20), seed=3, runs=5, steps=8)
    ends = np.random.default_rng(1).random(ro.costs.shape) < 0.3
    for gamma, lam in ((0.5, 0.95), (0.9, 0.0), (0.0, 0.95), (0.7, 1.0)):
        ref = ps.sb3_reference(pol, ro, gamma=gamma, lam=lam, ends=ends)
        adv, ret = ps.gae(ro.costs, ro.values, ro.last_values, gamma, lam, ends=ends)
        np.testing.assert_allclose(adv, ref["advantages"], atol=1e-5)
        np.testing.assert_allclose(ret, ref["returns"], atol=1e-5)


def test_lambda_zero_is_the_td_error_of_algorithm_2():
    _, ro = _rollout()
    adv, _ = ps.gae(ro.costs, ro.values, ro.last_values, 0.5, 0.0)
    nxt = np.concatenate([ro.values[1:], ro.last_values[None]])
    np.testing.assert_allclose(adv, ro.costs + 0.5 * nxt - ro.values, atol=1e-12)


@pytest.mark.parametrize("lr, ent", [(2e-3, 0.0), (0.1, 0.0), (0.3, 0.01)])
def test_update_matches_sb3_ppo_train(lr, ent):
    pol, ro = _rollout(seed=1)
    mine = copy.deepcopy(pol)
    out = ps.ppo_update(mine, ro, gamma=0.5, lr=lr, epochs=3, ent_coef=ent)
    ref = ps.sb3_reference(pol, ro, gamma=0.5, lr=lr, epochs=3, ent_coef=ent)
    assert float(out[-1]["loss"].detach()) == pytest.approx(ref["loss"], abs=1e-5)
    for a, b in zip(mine.parameters(), ref["params"]):
        torch.testing.assert_close(a.detach(), b, atol=1e-5, rtol=1e-5)
    if lr >= 0.3:  # the clip is exercised, not only the first epoch's ratio of 1
        assert out[-1]["clip_fraction"] > 0


def test_first_epoch_ratio_is_one_and_clip_takes_the_pessimistic_term():
    pol, ro = _rollout()
    out = ps.ppo_update(copy.deepcopy(pol), ro, gamma=0.5, lr=0.3, epochs=2)
    torch.testing.assert_close(out[0]["ratio"], torch.ones_like(out[0]["ratio"]), atol=1e-6, rtol=0)
    r = out[1]["ratio"]
    adv, _ = ps.gae(ro.costs, ro.values, ro.last_values, 0.5, 0.95)
    a = torch.as_tensor(adv.reshape(-1), dtype=torch.float32)
    a = (a - a.mean()) / (a.std() + 1e-8)
    # a cost: the clip binds (no gradient) where the ratio already rose past 1 + eps on a cheap
    # action (A < 0) or fell past 1 - eps on an expensive one (A > 0); a move the wrong way is
    # never clipped
    expected = ((a < 0) & (r > 1.2)) | ((a > 0) & (r < 0.8))
    assert torch.equal(out[1]["clipped"], expected)


def test_rollout_must_stay_inside_the_episode():
    with pytest.raises(ValueError):
        ps.collect(TrapEnv(n_steps=5), ps.TinyPolicy(2, 2), n_runs=2, n_steps=5)


def test_check_gae_accepts_the_recursion_and_names_the_slips(capsys):
    def right(c, v, last, gamma, lam):
        return ps.gae(c, v, last, gamma, lam)[0]

    assert ps.check_gae(right)
    capsys.readouterr()

    def backwards(c, v, last, gamma, lam, factor=None, boot=True, sign=1.0, returns=False):
        nxt = np.concatenate([v[1:], (last if boot else 0 * last)[None]])
        delta = c + gamma * nxt - v
        A, run = np.zeros_like(c), np.zeros(c.shape[1])
        for k in reversed(range(c.shape[0])):
            run = delta[k] + (gamma * lam if factor is None else factor(gamma, lam)) * run
            A[k] = run
        return sign * (A + v if returns else A)

    slips = {"lambda-returns": dict(returns=True), "reward's sign": dict(sign=-1.0),
             "lambda alone": dict(factor=lambda g, lam: lam), "no bootstrap": dict(boot=False)}
    for says, kw in slips.items():
        assert not ps.check_gae(lambda *a, kw=kw: backwards(*a, **kw))
        assert says in capsys.readouterr().out

    def forwards(c, v, last, gamma, lam):
        delta = c + gamma * np.concatenate([v[1:], last[None]]) - v
        A, run = np.zeros_like(c), np.zeros(c.shape[1])
        for k in range(c.shape[0]):
            run = delta[k] + gamma * lam * run
            A[k] = run
        return A

    assert not ps.check_gae(forwards)
    assert "forwards" in capsys.readouterr().out
    assert not ps.check_gae(lambda *a: np.zeros(3))
    assert "shape" in capsys.readouterr().out
