"""adaptfilt.trainers on an environment of one's own: the same policy as through the experiment's name."""
import numpy as np
import pytest

import adaptfilt as af
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.mdp import Cost, FilterEnv
from adaptfilt.trainers import train_policy


def digest(pol) -> bytes:
    arrays, _ = pol.to_arrays()
    return b"".join(arrays[k].tobytes() for k in sorted(arrays) if not k.startswith("curve"))


@pytest.mark.parametrize("algo", ["fast", "a2c", "batched"])
def test_an_environment_trains_the_same_policy_as_the_experiment_name(algo):
    kw = dict(episodes=8, progress=False, parallel=4, features="paper+time")
    by_name = train_policy("ungm-ukf", algo, 0.5, seed=1, n_steps=10, **kw)
    env = get_experiment("ungm-ukf").make_env(n_steps=10)
    by_env = train_policy(env, algo, 0.5, seed=1, name="mine", **kw)
    assert by_env.name == "mine"
    assert digest(by_env) == digest(by_name)
    other = train_policy(env, algo, 0.5, seed=2, **kw)
    assert digest(other) != digest(by_env)


def test_own_model_defaults_to_the_papers_features_and_acts_on_its_grid():
    model = af.StateSpaceModel(f=lambda x, k: 0.9 * x, h=lambda x, k: np.sin(x), Q=[[0.5]], R=[[0.1]],
                               m0=[0.0], P0=[[1.0]], name="sine", n_steps=12)
    grid = [0.0, 2.0, 10.0]
    env = FilterEnv(af.UKF(model, on_indefinite="clip"), grid, cost=Cost("nis"))
    pol = train_policy(env, "a2c", 0.0, episodes=8, seed=0, parallel=4, progress=False)
    assert pol.metadata["feature_set"] == "paper" and pol.metadata["experiment"] is None
    assert pol.gamma == 0.0 and np.array_equal(pol.grid, grid)
    d = env.reset(n_runs=5, rng=np.random.default_rng(0))
    a = pol.act(d)
    assert a.shape == (5,) and set(a.tolist()) <= {0, 1, 2}


def test_a_named_policy_file(tmp_path):
    for algo in ("batched", "fast", "a2c"):
        out = tmp_path / f"{algo}.npz"
        train_policy("ungm-ukf", algo, 0.5, episodes=4, seed=0, parallel=2, n_steps=5, progress=False, out=out,
                     name=f"{algo}-mine")
        assert af.learned.load_policy(out, "ungm-ukf").name == f"{algo}-mine"


def test_bad_targets_are_named():
    env = get_experiment("ungm-ukf").make_env(n_steps=10)
    with pytest.raises(ValueError, match="horizon 10"):
        train_policy(env, "a2c", episodes=2, n_steps=20, progress=False)
    with pytest.raises(ValueError, match="horizon 10"):
        train_policy(env, "batched", episodes=2, n_steps=20, progress=False)
    with pytest.raises(TypeError, match="FilterEnv"):
        train_policy(3.5, "a2c", episodes=2, progress=False)
    with pytest.raises(KeyError, match="unknown experiment"):
        train_policy("no-such", "a2c", episodes=2, progress=False)


def test_the_fast_mode_is_ppo_with_large_batches_and_scales_its_minibatch_with_the_runs():
    pol = train_policy("ungm-ukf", "fast", 0.5, episodes=8, seed=0, parallel=4, n_steps=10, progress=False)
    tr = pol.metadata["trainer"]
    assert tr["algo"] == "ppo" and tr["n_envs"] == 4
    assert tr["kwargs"]["batch_size"] == 4 * 64 // 8 and tr["kwargs"]["n_epochs"] == 5
    default = train_policy("ungm-ukf", "fast", 0.5, episodes=8, seed=0, n_steps=10, progress=False)
    assert default.metadata["trainer"]["n_envs"] == 256 and default.metadata["trainer"]["kwargs"]["batch_size"] == 2048


def test_a_policy_trained_on_a_safe_subset_of_the_grid_acts_in_the_full_experiment(tmp_path):
    """actions=: the policy only ever picks the allowed values, in the experiment's own grid indices,
    through evaluate and through a saved file; a value off the grid, the faithful trainer and a policy
    whose grid is not a subset are errors that name the problem."""
    from adaptfilt.evaluation import evaluate
    from adaptfilt.learned import load_policy

    exp = get_experiment("ctm-sif-logmaxnis")
    allowed = [5.0, 10.0, 20.0]
    out = tmp_path / "safe.npz"
    pol = train_policy(exp.name, "fast", 0.5, episodes=4, seed=0, parallel=4, n_steps=6, progress=False,
                       actions=allowed, out=out)
    assert pol.grid.tolist() == allowed and pol.metadata["experiment"] == exp.name
    back = load_policy(out, experiment=exp)
    env = exp.make_env(n_steps=6)
    d = env.reset(n_runs=50, rng=np.random.default_rng(0), stream=0)
    chosen = env.grid[back.act(d)]
    assert set(chosen.tolist()) <= set(allowed)
    # the mapping is by value: the argmax over the policy's own grid, placed in the experiment's grid
    own = np.asarray(allowed)[np.argmax(back.logits(af.features.observe(d, back.feature_set)), axis=1)]
    np.testing.assert_array_equal(chosen, own)
    res = evaluate(env, [back], n_runs=20, seed=0, progress=False)
    assert np.isfinite(res[back.name].cost)
    with pytest.raises(ValueError, match="not on it: \\[4.0\\]"):
        train_policy(exp.name, "fast", 0.5, episodes=2, n_steps=4, progress=False, actions=[4.0, 10.0])
    with pytest.raises(ValueError, match="SB3 trainer"):
        train_policy(exp.name, "faithful", 0.5, episodes=2, n_steps=4, progress=False, actions=[5.0, 10.0])
    coarse = FilterEnv(exp.make_filter(0), [1.0, 2.0, 10.0], cost=exp.cost, n_steps=6)
    with pytest.raises(ValueError, match="not a subset"):
        back.act(coarse.reset(n_runs=3, rng=np.random.default_rng(0), stream=0))


def test_reward_normalisation_rescales_what_the_learner_sees_not_the_learning_curve():
    """normalize_reward=True wraps the runs in SB3's VecNormalize. The first batch of episodes is played by the
    same initial policy on the same runs, so its curve value (the MDP's own cost) must equal the unnormalised
    run's; later ones differ because the learner saw other rewards."""
    from adaptfilt.trainers import FAST, SB3Config, train_sb3

    cfg = SB3Config("ppo", 16, {**FAST.kwargs, "n_steps": 32, "batch_size": 128})
    kw = dict(gamma=0.5, episodes=64, seed=3, config=cfg, n_steps=20, progress=False, cost_transform="none")
    plain = train_sb3("ungm-ukf", **kw)
    norm = train_sb3("ungm-ukf", **kw, normalize_reward=True)
    a, b = plain.curve["train_cost"], norm.curve["train_cost"]
    assert a.shape == b.shape and a[0] == b[0] and not np.array_equal(a, b)
    assert norm.metadata["normalize_reward"] is True and "normalize_reward" not in plain.metadata


def test_sb3_training_leaves_nothing_in_the_temporary_directory(tmp_path, monkeypatch):
    """SB3's default logger makes an empty ``SB3-<time>`` folder in the temporary directory per learn():
    thousands over a test run or a sweep. The SB3 trainers give it a logger that writes nowhere."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    for algo in ("fast", "a2c"):
        train_policy("ungm-ukf", algo, 0.5, episodes=2, seed=0, parallel=2, n_steps=5, progress=False)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith("SB3-")] == []


def test_snapshots_of_one_training_are_the_shorter_trainings_byte_for_byte(tmp_path):
    """A snapshot at E episodes is bit for bit the policy of a training of E episodes (SB3 trains on whole
    rollouts; the fast mode's learning rate and clip range are constants), whether E ends a rollout or lies
    inside one; building a snapshot's actor does not move the training's random numbers."""
    from adaptfilt.trainers import SB3Config, train_sb3

    cfg = SB3Config("ppo", 8, {"n_steps": 16, "batch_size": 32, "n_epochs": 2, "learning_rate": 2e-3})
    cmd = "adaptfilt train ungm-ukf --episodes 12 --seed 0"
    long = train_sb3("ungm-ukf", 0.5, 12, 0, cfg, n_steps=20, progress=False, command=cmd, snapshots=(3, 7, 12))
    assert sorted(long.snapshots) == [3, 7, 12]
    cpu = [long.snapshots[e].cpu_s for e in (3, 7, 12)]
    assert 0 < cpu[0] <= cpu[1] <= cpu[2] <= long.cpu_s
    for e in (3, 7):
        short = train_sb3("ungm-ukf", 0.5, e, 0, cfg, n_steps=20, progress=False, command=cmd)
        long.snapshots[e].save(tmp_path / f"a{e}.npz")
        short.save(tmp_path / f"b{e}.npz")
        assert (tmp_path / f"a{e}.npz").read_bytes() == (tmp_path / f"b{e}.npz").read_bytes()
        assert long.snapshots[e].metadata["episodes"] == e
    long.snapshots[12].save(tmp_path / "a12.npz")
    long.save(tmp_path / "b12.npz")
    assert (tmp_path / "a12.npz").read_bytes() == (tmp_path / "b12.npz").read_bytes()
    with pytest.raises(ValueError, match="snapshots must be episode counts"):
        train_sb3("ungm-ukf", 0.5, 4, 0, cfg, n_steps=20, progress=False, snapshots=(5,))


def test_a_cpu_budget_stops_training_after_that_many_cpu_seconds():
    import time

    from adaptfilt.trainers import SB3Config, train_sb3

    cfg = SB3Config("ppo", 8, {"n_steps": 16, "batch_size": 32, "n_epochs": 2, "learning_rate": 2e-3})
    c0 = time.process_time()
    pol = train_sb3("ungm-ukf", 0.5, 10 ** 6, 0, cfg, n_steps=20, progress=False, max_cpu_s=1.0)
    assert 1.0 <= pol.cpu_s <= time.process_time() - c0 and pol.metadata["transitions"] < 10 ** 6 * 20


def test_sb3_optimiser_steps_counts_the_steps_the_optimiser_took(monkeypatch):
    """The count from a policy's metadata is the number of optimiser steps SB3 took: PPO with a partial last
    minibatch (rollouts of 8 x 16 = 128 transitions in minibatches of 48: 3 per epoch), and A2C (one a
    rollout), counted by wrapping the optimisers' step."""
    import torch

    from adaptfilt.trainers import SB3Config, sb3_optimiser_steps, train_sb3

    calls = []
    for cls in (torch.optim.Adam, torch.optim.RMSprop):
        monkeypatch.setattr(cls, "step", lambda self, *a, _f=cls.step, **k: (calls.append(1), _f(self, *a, **k))[1])
    for algo, kw in (("ppo", {"n_steps": 16, "batch_size": 48, "n_epochs": 2}), ("a2c", {"n_steps": 5})):
        calls.clear()
        pol = train_sb3("ungm-ukf", 0.5, 20, 0, SB3Config(algo, 8, kw), n_steps=20, progress=False)
        assert sb3_optimiser_steps(pol.metadata) == len(calls) > 0, algo
