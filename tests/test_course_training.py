"""adaptfilt.course.training: the helpers of chapters 6-7 (the learner, its sign, the implement-it-yourself
actor update), against direct computations."""
import matplotlib

matplotlib.use("Agg")

import numpy as np

from adaptfilt.course import training
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.features import FeatureSet, fit_scaler, observe, visited_states


def test_candidate_cost_range_matches_a_direct_rollout():
    env = get_experiment("ungm-ukf").make_env(n_steps=15)
    out = training.candidate_cost_range(env, n_runs=7, seed=2)
    d, all_costs = env.reset(n_runs=7, rng=np.random.default_rng(2)), []
    while d is not None:
        all_costs.append(d.candidates()["cost"])
        d, *_ = env.step(np.full(7, d.default_index))
    c = np.concatenate([x.ravel() for x in all_costs])
    assert out["decisions"] == 7 * 15
    assert out["max"] == c.max() and out["median"] == np.median(c)
    assert np.isclose(out["max_log1p"], np.log1p(c.max()))
    assert out["share_above_1e3"] == (c > 1e3).mean()


def test_scaler_saturation_counts_the_old_clip():
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=60)
    sat = training.scaler_saturation(env, "paper+time", seed=0, runs=32)
    names = FeatureSet.parse("paper+time").names(env.model, env.grid)
    assert list(sat) == names
    old = fit_scaler(env, "paper+time", runs=32, seed=0, visit="default", squash="clip")
    s = visited_states(env, "paper+time", runs=32, seed=1)
    s = s[np.isfinite(s).all(axis=1)]
    assert np.isclose(sat["tr P_pred"]["clipped"], (np.abs(old(s)[:, 1]) >= 10).mean())
    assert sat["tr P_pred"]["clipped"] > 0.05            # the tail that motivated the new scaler
    assert sat["time[cos 0.05k]"]["clipped"] == 0.0      # a bounded feature never clips
    assert all(v["asinh_max"] < 10 for v in sat.values())


def test_sign_demo_and_training_figures():
    from adaptfilt.actor_critic import train
    from adaptfilt.toy import BanditEnv

    pol, curve = train(BanditEnv(n_steps=3), gamma=0.0, episodes=8, parallel=4, seed=0, cost_transform="none",
                       progress=False)
    fig = training.plot_sign_demo(np.linspace(-1, 1, 5), {"a": pol, "b": pol}, {"a": curve}, window=4)
    assert len(fig.axes) == 3
    env = get_experiment("ungm-ukf").make_env(n_steps=5)
    pol, curve = train(env, gamma=0.5, episodes=4, parallel=2, seed=0, progress=False)
    fig = training.plot_training(curve, env.grid, batch=2)
    assert len(fig.axes) == 3


# ------------------------------------------------- chapter 6: the implement-it-yourself actor update
def test_library_actor_loss_is_the_update_of_train():
    """Three Adam steps on ``library_actor_loss`` (plus the critic loss), replayed on the batches
    that ``train`` drew, end with exactly ``train``'s actor: the checker's reference is the library's update."""
    import copy

    import torch

    from adaptfilt.actor_critic import soft_update, train
    from adaptfilt.learned import Actor, Critic
    from adaptfilt.toy import BanditEnv

    seed, B, T = 3, 8, 3
    pol, _ = train(BanditEnv(n_steps=T), gamma=0.5, episodes=B, parallel=B, seed=seed, cost_transform="none",
                   progress=False)
    env = BanditEnv(n_steps=T)
    feats = lambda d: torch.from_numpy(pol.scaler.network_input(observe(d, "paper")))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        actor, critic = Actor(2, 3), Critic(2)
    target = copy.deepcopy(critic).requires_grad_(False)
    opt_a = torch.optim.Adam(actor.parameters(), lr=1e-4)
    opt_c = torch.optim.Adam(critic.parameters(), lr=5e-4)
    rng_act = np.random.default_rng([seed, 2])
    d = env.reset(n_runs=B, rng=np.random.default_rng([seed, 1, 0]), stream=0)
    s, done = feats(d), False
    while not done:
        logits = actor(s)
        p = torch.log_softmax(logits, dim=-1).detach().exp().double().numpy()
        cdf = np.cumsum(p, axis=1)
        a = np.minimum((cdf < rng_act.random(B)[:, None] * cdf[:, -1:]).sum(axis=1), 2)
        d, cost, done, _ = env.step(a)
        c = torch.from_numpy(cost.astype(np.float32))
        if done:
            td_target = c
        else:
            s_next = feats(d)
            with torch.no_grad():
                td_target = c + 0.5 * target(s_next)
        delta = td_target - critic(s)
        loss = (delta ** 2).mean() + training.library_actor_loss(logits, torch.from_numpy(a), delta, 1e-3)
        opt_a.zero_grad(), opt_c.zero_grad()
        loss.backward()
        opt_c.step(), opt_a.step()
        soft_update(target, critic, 0.01)
        if not done:
            s = s_next
    for mine, lib in zip(actor.parameters(), pol.actor.parameters()):
        assert torch.allclose(mine, lib, rtol=0, atol=1e-7)


def test_check_actor_update_accepts_the_library_and_diagnoses_mistakes(capsys):
    import torch

    assert training.check_actor_update(training.library_actor_loss)
    assert "right: your update is the library's" in capsys.readouterr().out
    assert not training.check_actor_update(lambda l, a, d, beta: training.library_actor_loss(l, a, d, beta, sign=-1))
    assert "printed sign" in capsys.readouterr().out
    assert not training.check_actor_update(lambda l, a, d, beta: training.library_actor_loss(l, a, d, 0.0))
    assert "entropy bonus -beta H(pi) is missing" in capsys.readouterr().out

    def leaks(logits, a, delta, beta):
        logp = torch.log_softmax(logits, -1)
        return (delta * logp[torch.arange(len(a)), a] + beta * (logp.exp() * logp).sum(-1)).mean()

    assert not training.check_actor_update(leaks)
    assert "detach the TD error" in capsys.readouterr().out
    assert not training.check_actor_update(lambda l, a, d, beta: 1 / 0)
    assert "raised ZeroDivisionError" in capsys.readouterr().out


def test_kappa_bands_partition_the_grid():
    grid = [0, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 3000, 10000]
    bands = training.kappa_bands(grid)
    assert list(bands) == ["0-2", "5-50", "100-500", "1000-10000"]
    assert (np.sum(list(bands.values()), axis=0) == 1).all()


def test_plain_soft_update_is_the_librarys_bit_for_bit():
    """Chapter 6 shows the target critic's Polyak averaging one tensor at a time; the library batches it
    (torch._foreach_*). Same numbers, over many updates of networks that keep changing."""
    import torch

    from adaptfilt.actor_critic import soft_update
    from adaptfilt.learned import mlp

    torch.manual_seed(0)
    source = mlp(7, 1, (64, 64))
    target_lib, target_plain = mlp(7, 1, (64, 64)), mlp(7, 1, (64, 64))
    target_plain.load_state_dict(target_lib.state_dict())
    for _ in range(50):
        with torch.no_grad():
            for p in source.parameters():
                p.add_(0.01 * torch.randn_like(p))
        soft_update(target_lib, source, 0.01)
        training.plain_soft_update(target_plain, source, 0.01)
    for a, b, s in zip(target_lib.parameters(), target_plain.parameters(), source.parameters()):
        assert torch.equal(a, b)
        assert not torch.equal(a, s)  # the target lags the source: the averaging did something
