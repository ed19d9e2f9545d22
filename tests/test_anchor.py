"""adaptfilt.anchor: learned policies anchored on greedy (the anchored learner of study 5)."""
import numpy as np
import pytest

from adaptfilt.anchor import Anchor, anchor_index, anchor_onehot, anchored_policy_class, greedy_index, greedy_onehot
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.learned import load_policy
from adaptfilt.mdp import rollout
from adaptfilt.policies import GreedyPolicy
from adaptfilt.toy import TrapEnv
from adaptfilt.trainers import train_policy

CAND = {"ungm-ukf": "paper+time+cand", "ctm-ukf": "paper+circ+cand"}


def _choices(env, pol, runs: int, seed: int) -> np.ndarray:
    run, _ = rollout(env, pol, n_runs=runs, rng=np.random.default_rng(seed), stream=seed)
    return run.params


@pytest.mark.parametrize("experiment", ["ungm-ukf", "ctm-ukf"])
def test_before_any_improvement_step_the_anchored_policy_is_greedy_exactly(experiment):
    # learning_rate 0: SB3 collects a rollout and takes its Adam steps, which change nothing
    kw = dict(episodes=2, seed=3, parallel=8, n_steps=12, progress=False, features=CAND[experiment], anchor="greedy",
              anchor_shield=0)
    pol = train_policy(experiment, "fast", 0.5, sb3={"learning_rate": 0.0}, **kw)
    env = get_experiment(experiment).make_env(n_steps=12)
    assert np.array_equal(_choices(env, pol, 64, 5), _choices(env, GreedyPolicy(env.grid), 64, 5))
    # the actor's output layer starts at zero: the network adds nothing to greedy's logit c
    d = env.reset(n_runs=16, rng=np.random.default_rng(1))
    assert np.array_equal(pol.logits(d.observe(CAND[experiment]), greedy_onehot(d)), 3.0 * greedy_onehot(d))
    # ... on the paper's state too (the anchor needs greedy's candidates, not the candidate features)
    paper = train_policy(experiment, "fast", 0.5, sb3={"learning_rate": 0.0}, **{**kw, "features": None})
    assert np.array_equal(_choices(env, paper, 32, 6), _choices(env, GreedyPolicy(env.grid), 32, 6))


@pytest.mark.parametrize("experiment", ["ungm-ukf", "ctm-ukf"])
def test_anchored_on_ml_the_untrained_policy_is_ml_exactly(experiment):
    """The anchor is a declared choice: on ML, the untrained policy (any features, shield on) acts as
    MaxLikelihoodPolicy, bit for bit, in training's observation and in acting."""
    from adaptfilt.anchor import allowed_mask
    from adaptfilt.policies import MaxLikelihoodPolicy

    kw = dict(episodes=2, seed=3, parallel=8, n_steps=12, progress=False, features=CAND[experiment], anchor="ml")
    pol = train_policy(experiment, "fast", 0.5, sb3={"learning_rate": 0.0}, **kw)
    assert pol.anchor == Anchor("ml", 3.0, 0.01, 1.0)
    env = get_experiment(experiment).make_env(n_steps=12)
    assert np.array_equal(_choices(env, pol, 64, 5), _choices(env, MaxLikelihoodPolicy(env.grid), 64, 5))
    assert not np.array_equal(_choices(env, pol, 64, 5), _choices(env, GreedyPolicy(env.grid), 64, 5))
    d = env.reset(n_runs=200, rng=np.random.default_rng(1))
    for _ in range(6):
        d, *_ = env.step(MaxLikelihoodPolicy().act(d))
    ml = anchor_index(d, "ml")
    assert np.array_equal(ml, MaxLikelihoodPolicy().act(d)) and np.array_equal(anchor_index(d, "greedy"), greedy_index(d))
    assert np.array_equal(anchor_onehot(d, "ml").argmax(axis=1), ml)
    # the shield keeps the anchor's choice whatever its cost (ML's is outside greedy's shield at 3 of 10^5 CTM
    # steps): any index given to keep is allowed on top of the shield's own mask
    k = np.random.default_rng(0).integers(0, env.grid.size, 200)
    plain = allowed_mask(d, 0.01)
    assert (plain == 0).any() and np.array_equal(allowed_mask(d, 0.01, keep=k), np.maximum(plain, anchor_onehot_of(k, plain.shape)))
    # the Gymnasium adapter's observation carries ML's one-hot and the mask that keeps it
    from adaptfilt.gym import make_vec

    venv = make_vec(experiment, n_envs=4, n_steps=5, features=CAND[experiment], anchor=Anchor("ml", shield=1.0))
    obs = venv.reset()
    G = env.grid.size
    assert obs.shape[1] == venv.venv.scaler.center.shape[0] + 2 * G and (obs[:, -2 * G:-G].sum(axis=1) == 1).all()
    assert (obs[np.arange(4), -G + obs[:, -2 * G:-G].argmax(axis=1)] == 1).all()


def anchor_onehot_of(idx, shape):
    out = np.zeros(shape, dtype=np.float32)
    out[np.arange(shape[0]), idx] = 1.0
    return out


def test_the_saved_file_loads_and_acts_as_the_trained_model(tmp_path):
    out = tmp_path / "anchored.npz"
    pol = train_policy("ungm-ukf", "fast", 0.5, episodes=40, seed=0, parallel=8, n_steps=10, progress=False,
                       features="paper+time+cand", anchor="greedy", anchor_strength=0.5, anchor_kl=0.02, out=out,
                       command="adaptfilt train ungm-ukf --anchor greedy ...")
    back = load_policy(out, "ungm-ukf")
    assert back.anchor == Anchor("greedy", 0.5, 0.02, 1.0) == pol.anchor  # the default shield
    assert back.metadata["anchor"] == {"policy": "greedy", "strength": 0.5, "kl": 0.02, "shield": 1.0}
    env = get_experiment("ungm-ukf").make_env(n_steps=10)
    a, b = _choices(env, pol, 64, 2), _choices(env, back, 64, 2)
    assert np.array_equal(a, b)
    # trained (c = 0.5 is weak): it no longer always agrees with greedy, so the test above tests something
    assert not np.array_equal(a, _choices(env, GreedyPolicy(env.grid), 64, 2))


def test_the_policy_file_acts_as_sb3s_anchored_model():
    from stable_baselines3 import PPO

    from adaptfilt.gym import make_vec, to_learned_policy

    venv = make_vec("ctm-ukf", n_envs=8, seed=0, features="paper+circ+cand", n_steps=8, anchor="greedy")
    model = PPO(anchored_policy_class(), venv, n_steps=16, batch_size=32, n_epochs=2, learning_rate=3e-2, seed=0,
                policy_kwargs={"strength": 1.0}, ent_coef=0.05, device="cpu").learn(256)
    pol = to_learned_policy(model, venv, name="anchored")
    assert pol.anchor == Anchor("greedy", 1.0, 0.05)
    env = get_experiment("ctm-ukf").make_env(n_steps=8)
    d = env.reset(n_runs=50, rng=np.random.default_rng(4))
    while d is not None:
        obs = np.concatenate([venv.venv.scaler.network_input(d.observe("paper+circ+cand")), greedy_onehot(d)], axis=1)
        sb3, _ = model.predict(obs, deterministic=True)
        assert np.array_equal(pol.act(d), sb3)
        d, _, _, _ = env.step(sb3)


def test_the_kl_term_is_what_ppo_minimises_in_the_entropy_slot():
    import torch

    from adaptfilt.gym import make_vec

    venv = make_vec("ungm-ukf", n_envs=4, seed=0, features="paper+time+cand", n_steps=5, anchor="greedy")
    cls = anchored_policy_class()
    pol = cls(venv.observation_space, venv.action_space, lambda _: 1e-3, strength=2.0,
              net_arch={"pi": [8], "vf": [8]})
    obs = torch.as_tensor(venv.reset())
    _, _, minus_kl = pol.evaluate_actions(obs, torch.zeros(4, dtype=torch.long))
    assert torch.allclose(minus_kl, torch.zeros(4), atol=1e-6)  # pi = pi_0 at initialisation
    with torch.no_grad():
        pol.action_net.bias.copy_(torch.arange(13, dtype=torch.float32) / 4)
    _, _, minus_kl = pol.evaluate_actions(obs, torch.zeros(4, dtype=torch.long))
    p = torch.softmax(pol.action_net.bias + 2.0 * obs[:, -13:], -1)
    p0 = torch.softmax(2.0 * obs[:, -13:], -1)
    assert torch.allclose(-minus_kl, (p * (p.log() - p0.log())).sum(-1), atol=1e-5) and (minus_kl < 0).all()


def test_greedy_index_is_greedys_argmin_also_on_a_subset_of_the_grid():
    env = get_experiment("ungm-ukf").make_env(n_steps=5)
    d = env.reset(n_runs=30, rng=np.random.default_rng(0))
    assert np.array_equal(greedy_index(d), GreedyPolicy().act(d))
    sub = env.grid[::3]
    want = np.argmin(d.candidates()["cost"][::3], axis=0)
    assert np.array_equal(greedy_index(d, sub), want)
    assert greedy_onehot(d, sub).shape == (30, sub.size) and (greedy_onehot(d, sub).sum(axis=1) == 1).all()


def test_bad_options_are_named():
    for bad, match in [(dict(anchor="median"), "unknown anchor 'median'"),
                       (dict(anchor="greedy", anchor_strength=0.0), "strength must be finite and > 0"),
                       (dict(anchor="greedy", anchor_strength=float("nan")), "strength must be finite"),
                       (dict(anchor="greedy", anchor_kl=-1.0), "kl must be finite and >= 0"),
                       (dict(anchor_strength=2.0), "give anchor='greedy' or 'ml' too"),
                       (dict(anchor="greedy", sb3={"ent_coef": 0.01}), "instead of ent_coef")]:
        with pytest.raises(ValueError, match=match):
            train_policy("ungm-ukf", "fast", episodes=1, n_steps=3, parallel=2, progress=False, **bad)
    with pytest.raises(ValueError, match="needs an SB3 trainer"):
        train_policy("ungm-ukf", "batched", episodes=1, n_steps=3, progress=False, anchor="greedy")
    with pytest.raises(ValueError, match="malformed anchor"):
        Anchor.from_dict({"strength": 3})
    from adaptfilt.gym import make_vec

    with pytest.raises(ValueError, match="unknown anchor 'median'"):
        make_vec("ungm-ukf", n_envs=2, n_steps=3, anchor="median")


def test_a_damaged_anchor_in_a_policy_file_is_named(tmp_path):
    from adaptfilt.files import read_npz, write_npz

    out = tmp_path / "p.npz"
    train_policy("ungm-ukf", "fast", episodes=1, n_steps=3, parallel=2, progress=False, anchor="greedy", out=out)
    arrays, meta = read_npz(out)
    meta["anchor"]["strength"] = -1
    write_npz(out, arrays, meta)
    with pytest.raises(ValueError, match="not an adaptfilt policy file .*strength must be finite and > 0"):
        load_policy(out)


def test_on_the_trap_the_anchored_learner_leaves_greedy_where_that_pays():
    """TrapEnv: greedy takes the free action 0 and falls into the state where every step costs 1; with
    gamma 0.5 action 1 (0.25 a step, stays good) is optimal. The anchored policy starts as greedy and
    learns action 1 in the good state; in the bad state (a tie, greedy's first index) nothing pays."""
    env = TrapEnv(n_steps=10)
    pol = train_policy(env, "fast", 0.5, episodes=3000, seed=0, parallel=16, progress=False, anchor="greedy")
    d = env.reset(n_runs=8, rng=np.random.default_rng(0))
    assert (GreedyPolicy().act(d) == 0).all()
    assert (pol.act(d) == 1).all()
    costs = []
    while d is not None:
        d, c, _, _ = env.step(pol.act(d))
        costs.append(c)
    assert np.allclose(costs, 0.25)  # the non-myopic optimum, every step


def test_the_command_line_records_the_anchor(tmp_path, capsys):
    from adaptfilt.cli import main

    out = tmp_path / "a.npz"
    assert main(["train", "ungm-ukf", "--algo", "fast", "--episodes", "1", "--horizon", "3", "--parallel", "2",
                 "--anchor", "greedy", "--anchor-kl", "0.05", "--out", str(out), "--no-progress"]) == 0
    pol = load_policy(out, "ungm-ukf")
    assert pol.anchor == Anchor("greedy", 3.0, 0.05, 1.0)
    assert "--anchor greedy --anchor-kl 0.05 --out" in pol.metadata["command"]
    assert main(["train", "ungm-ukf", "--algo", "fast", "--episodes", "1", "--horizon", "3", "--parallel", "2",
                 "--anchor", "greedy", "--anchor-shield", "0", "--out", str(out), "--no-progress"]) == 0
    assert load_policy(out).anchor == Anchor("greedy", 3.0, 0.01, None)
    for argv, match in [(["--anchor-kl", "0.1"], "give --anchor greedy (or ml) too"),
                        (["--anchor", "greedy", "--algo", "batched"], "needs an SB3 trainer")]:
        with pytest.raises(SystemExit):
            main(["train", "ungm-ukf", "--episodes", "1", "--horizon", "3", "--out", str(out)] + argv)
        assert match in capsys.readouterr().err


def test_distilled_before_training_is_greedy_and_its_file_acts_identically(tmp_path):
    from adaptfilt.distill import distill_rollout, rollout_data

    data = rollout_data("ctm-ukf", 1, runs=6, n_steps=6, features="paper+circ+cand")
    assert data["features"].shape[0] == data["q"].shape[0] == 36 and data["q"].shape[1] == 12
    env = get_experiment("ctm-ukf").make_env(n_steps=6)
    untrained = distill_rollout("ctm-ukf", 1, epochs=0, data=data)
    assert np.array_equal(_choices(env, untrained, 40, 3), _choices(env, GreedyPolicy(env.grid), 40, 3))
    pol = distill_rollout("ctm-ukf", 1, epochs=3, lr=0.05, kl=0.01, data=data, command="distill_rollout(...)")
    assert pol.metadata["algo"] == "rollout-distill" and pol.anchor == Anchor("greedy", 3.0, 0.01)
    pol.save(tmp_path / "d.npz")
    back = load_policy(tmp_path / "d.npz", "ctm-ukf")
    assert np.array_equal(_choices(env, back, 40, 3), _choices(env, pol, 40, 3))
    again = distill_rollout("ctm-ukf", 1, epochs=3, lr=0.05, kl=0.01, data=data, command="distill_rollout(...)")
    assert again.to_arrays()[0]["actor/net.4.weight"].tobytes() == pol.to_arrays()[0]["actor/net.4.weight"].tobytes()
    with pytest.raises(ValueError, match="epochs must be an integer >= 0"):
        distill_rollout("ctm-ukf", 1, epochs=-1, data=data)
    with pytest.raises(ValueError, match="kl must be finite"):
        distill_rollout("ctm-ukf", 1, kl=-1.0, data=data)


def test_on_the_trap_the_distilled_policy_takes_the_non_myopic_optimum():
    from adaptfilt.distill import distill_rollout

    env = TrapEnv(n_steps=10)
    # every good step saves the same (the mean saving): the margin beta * c must be below one mean saving
    pol = distill_rollout(env, 0, runs=64, horizon=1, samples=1, epochs=30, lr=1e-2, kl=0.1)
    d = env.reset(n_runs=8, rng=np.random.default_rng(0))
    costs = []
    while d is not None:
        d, c, _, _ = env.step(pol.act(d))
        costs.append(c)
    assert np.allclose(costs, 0.25)


def test_the_shield_masks_candidates_far_above_greedys_cost_in_training_and_acting(tmp_path):
    from adaptfilt.anchor import allowed_mask

    env = get_experiment("ungm-ukf").make_env(n_steps=10)
    d = env.reset(n_runs=40, rng=np.random.default_rng(0))
    m = allowed_mask(d, 1.0)
    lc = np.log1p(d.candidates()["cost"]).T
    g = greedy_index(d)
    assert np.array_equal(m > 0, lc - lc[np.arange(40), g][:, None] <= 1.0) and (m[np.arange(40), g] == 1).all()
    kw = dict(episodes=2, seed=0, parallel=8, n_steps=10, progress=False, features="paper+time+cand", anchor="greedy")
    untrained = train_policy("ungm-ukf", "fast", 0.5, sb3={"learning_rate": 0.0}, anchor_shield=1.0, **kw)
    assert untrained.anchor.shield == 1.0
    assert np.array_equal(_choices(env, untrained, 32, 1), _choices(env, GreedyPolicy(env.grid), 32, 1))
    # weakly anchored and trained: it leaves greedy, but only for candidates inside the shield
    out = tmp_path / "s.npz"
    pol = train_policy("ungm-ukf", "fast", 0.5, anchor_strength=0.3, anchor_shield=0.5, out=out,
                       **{**kw, "episodes": 40})
    back = load_policy(out, "ungm-ukf")
    assert back.metadata["anchor"]["shield"] == 0.5
    d, left = env.reset(n_runs=64, rng=np.random.default_rng(2)), 0
    while d is not None:
        a = pol.act(d)
        assert np.array_equal(a, back.act(d))
        assert (allowed_mask(d, 0.5)[np.arange(64), a] == 1).all()
        left += int((a != greedy_index(d)).sum())
        d, _, _, _ = env.step(a)
    assert left > 0
    with pytest.raises(ValueError, match="shield must be finite and > 0"):
        train_policy("ungm-ukf", "fast", anchor_shield=-1.0, **kw)


def test_same_seed_same_bytes():
    kw = dict(episodes=4, parallel=4, n_steps=6, progress=False, features="paper+time+cand", anchor="greedy")
    a, b = (train_policy("ungm-ukf", "fast", 0.5, seed=5, **kw).to_arrays() for _ in range(2))
    c = train_policy("ungm-ukf", "fast", 0.5, seed=6, **kw).to_arrays()
    w = "actor/net.4.weight"
    assert a[0][w].tobytes() == b[0][w].tobytes() and a[1] == b[1]
    assert a[0][w].tobytes() != c[0][w].tobytes()
