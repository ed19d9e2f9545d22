"""The TD(0) actor-critic (Algorithm 2) and learned-policy files.

Toy MDPs with known optima (``adaptfilt.toy``) keep these fast; each test can fail.
"""
from __future__ import annotations

import copy
import hashlib
import zipfile

import numpy as np
import pytest
import torch

from adaptfilt.actor_critic import checkpoint_path, soft_update, train, train_experiment
from adaptfilt.files import read_npz
from adaptfilt.learned import Critic, load_policy
from adaptfilt.toy import BanditEnv, TrapEnv

# larger learning rates than the paper's so that toys converge in a second
FAST = dict(cost_transform="none", lr_actor=3e-3, lr_critic=3e-3, progress=False)


def weights(policy) -> dict[str, np.ndarray]:
    return {k: v.detach().numpy().copy() for k, v in policy.actor.state_dict().items()}


def same_weights(a, b) -> bool:
    wa, wb = weights(a), weights(b)
    return wa.keys() == wb.keys() and all(np.array_equal(wa[k], wb[k]) for k in wa)


def bandit_probe():
    s = np.array([-2.0, -1.0, -0.5, 0.5, 1.0, 2.0])
    return s, np.stack([s, np.zeros_like(s)], axis=1)


def test_actor_converges_to_known_optimum():
    env = BanditEnv(n_steps=10)
    pol, curve = train(env, gamma=0.0, episodes=800, parallel=16, seed=0, **FAST)
    s, f = bandit_probe()
    np.testing.assert_array_equal(pol.probs(f).argmax(axis=1), env.best_action(s))
    assert curve["cost"][-50:].mean() < 0.1 < 0.5 < curve["cost"][:50].mean()


def test_paper_printed_sign_learns_the_worst_action():
    """-delta log pi with a *cost* TD error reinforces expensive actions."""
    env = BanditEnv(n_steps=10)
    pol, curve = train(env, gamma=0.0, episodes=800, parallel=16, seed=0, actor_sign=-1, **FAST)
    _, f = bandit_probe()
    assert (pol.probs(f).argmax(axis=1) == 2).all()  # action 2 is the most expensive everywhere
    assert curve["cost"][-50:].mean() > 1.5


def test_paper_faithful_mode_learns_too():
    env = BanditEnv(n_steps=20)
    pol, _ = train(env, gamma=0.0, episodes=150, parallel=1, seed=1, **FAST)
    s, f = bandit_probe()
    assert (pol.probs(f).argmax(axis=1) == env.best_action(s)).mean() >= 5 / 6


def test_discount_makes_the_policy_non_myopic():
    """TrapEnv: action 0 is free now but every later step costs 1; action 1 costs 0.25 and keeps costs low.
    For gamma = 0 the trap is optimal, for gamma = 0.5 the safe action. A trained policy is a random draw of
    its seed, so the claim is made over seeds, with chapter 6's rule (decisive: pi(safe | good) above 0.9 or
    below 0.1) and its seeds: every gamma = 0 seed (0-2) takes the trap; at this budget (800 episodes) about
    half the gamma = 0.5 seeds miss the non-myopic optimum (seeds 0-5: 3 safe, 2 trap, 1 undecided), but at
    least half learn it decisively, which no myopic seed does."""
    good = np.array([[0.0, 0.0], [0.0, 1.0], [0.0, -1.0]])  # the good state, three noise values

    def p_safe(gamma: float, seed: int) -> float:
        pol, _ = train(TrapEnv(n_steps=10), gamma=gamma, episodes=800, parallel=16, seed=seed, **FAST)
        assert pol.name == ("myopic" if gamma == 0 else "adaptive")
        return float(pol.probs(good).mean(axis=0)[1])

    myopic = [p_safe(0.0, seed) for seed in range(3)]
    assert max(myopic) < 0.1, myopic
    discounted = [p_safe(0.5, seed) for seed in range(6)]
    assert sum(p > 0.9 for p in discounted) >= 3, discounted


def test_soft_update_is_polyak_average():
    torch.manual_seed(0)
    source, target = Critic(3), Critic(3)
    before = [p.detach().clone() for p in target.parameters()]
    soft_update(target, source, 0.01)
    for new, old, psi in zip(target.parameters(), before, source.parameters()):
        torch.testing.assert_close(new, 0.01 * psi + 0.99 * old, rtol=1e-6, atol=1e-7)
        assert not torch.equal(new, old)


def test_save_load_roundtrip_and_no_pickle(tmp_path):
    pol, curve = train(BanditEnv(n_steps=5), gamma=0.5, episodes=32, parallel=8, seed=0, **FAST)
    path = pol.save(tmp_path / "p.npz")
    with np.load(path, allow_pickle=False) as z:  # loads without pickles
        assert "__metadata__" in z.files
    back = load_policy(path)
    feats = np.random.default_rng(1).standard_normal((50, 2))
    np.testing.assert_array_equal(pol.probs(feats), back.probs(feats))
    assert back.name == "adaptive" and back.gamma == 0.5
    np.testing.assert_array_equal(back.grid, pol.grid)
    np.testing.assert_array_equal(back.curve["cost"], curve["cost"])
    _, meta = read_npz(path)
    for key in ("model", "param_name", "grid", "feature_names", "gamma", "cost", "seed", "episodes", "parallel",
                "version", "command", "curve_summary", "cost_transform"):
        assert key in meta, key


def test_mismatched_metadata_raises(tmp_path):
    pol, _ = train(BanditEnv(n_steps=5), gamma=0.0, episodes=8, parallel=8, seed=0, **FAST)
    path = pol.save(tmp_path / "p.npz")
    load_policy(path, BanditEnv())  # the same env is fine
    with pytest.raises(ValueError, match="model"):
        load_policy(path, TrapEnv())
    with pytest.raises(ValueError, match="grid"):
        load_policy(path, {"grid": [0.0, 1.0, 5.0]})
    with pytest.raises(ValueError, match="feature_names"):
        load_policy(path, {"feature_names": ["x_pred[0]", "tr P_pred"]})
    with pytest.raises(ValueError, match="experiment"):
        load_policy(path, {"experiment": "ungm-ukf"})


def test_mismatched_experiment_raises(tmp_path):
    pol, _ = train("ungm-ukf", gamma=0.0, episodes=2, parallel=2, seed=0, n_steps=5, progress=False)
    path = pol.save(tmp_path / "u.npz")
    assert load_policy(path, "ungm-ukf").metadata["experiment"] == "ungm-ukf"
    with pytest.raises(ValueError, match="experiment|model"):
        load_policy(path, "ctm-ukf")


@pytest.mark.parametrize("parallel", [1, 4])
def test_resume_equals_uninterrupted(tmp_path, parallel):
    kw = dict(gamma=0.5, episodes=16, parallel=parallel, seed=3, checkpoint_every=4, **FAST)
    full, full_curve = train(TrapEnv(n_steps=6), **kw)
    ck = tmp_path / "run.ckpt.npz"
    part, _ = train(TrapEnv(n_steps=6), checkpoint=ck, stop_after=8, **kw)
    assert part.metadata["episodes_done"] == 8 and ck.exists()
    assert not same_weights(part, full)
    resumed, curve = train(TrapEnv(n_steps=6), checkpoint=ck, resume=True, **kw)
    assert same_weights(resumed, full)
    for k in full_curve:
        np.testing.assert_array_equal(curve[k], full_curve[k])


def test_same_seed_same_weights_and_bytes(tmp_path):
    kw = dict(gamma=0.5, episodes=24, parallel=4, **FAST)
    a, _ = train(BanditEnv(n_steps=5), seed=7, **kw)
    b, _ = train(BanditEnv(n_steps=5), seed=7, **kw)
    c, _ = train(BanditEnv(n_steps=5), seed=8, **kw)
    assert same_weights(a, b) and not same_weights(a, c)
    pa, pb = a.save(tmp_path / "a.npz"), b.save(tmp_path / "b.npz")
    assert hashlib.sha256(pa.read_bytes()).digest() == hashlib.sha256(pb.read_bytes()).digest()
    with zipfile.ZipFile(pa) as zf:
        assert {i.date_time for i in zf.infolist()} == {(1980, 1, 1, 0, 0, 0)}


def test_train_experiment_cli_file_is_reproducible_and_resumable(tmp_path):
    """The CLI entry: a file, checkpoint deleted at the end; interrupted + resumed = same bytes."""
    kw = dict(gamma=0.5, episodes=4, parallel=1, seed=0, progress=False, command="test", n_steps=20)
    out1, out2 = tmp_path / "a.npz", tmp_path / "b.npz"
    train_experiment("ungm-ukf", out1, **kw)
    assert out1.exists() and not checkpoint_path(out1).exists()
    train_experiment("ungm-ukf", out2, stop_after=2, checkpoint_every=1, **kw)
    assert not out2.exists() and checkpoint_path(out2).exists()
    train_experiment("ungm-ukf", out2, resume=True, **{**kw})
    assert out1.read_bytes() == out2.read_bytes()
    pol = load_policy(out1, "ungm-ukf")
    assert pol.metadata["command"] == "test" and pol.metadata["cost_transform"] == "log1p"
