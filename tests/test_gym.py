"""adaptfilt.gym: the MDP as Gymnasium environments and a Stable-Baselines3 VecEnv."""
import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")
sb3 = pytest.importorskip("stable_baselines3")

import adaptfilt.gym as afg  # noqa: E402
from adaptfilt.costs import transform_cost  # noqa: E402
from adaptfilt.evaluation import evaluate  # noqa: E402
from adaptfilt.experiment_registry import get_experiment  # noqa: E402


def test_single_env_passes_both_checkers():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    check_env(afg.make_env("ungm-ukf", n_steps=8), skip_render_check=True)
    sb3_check_env(afg.make_env("ctm-sif-nis", n_steps=4), warn=False)


def test_registered_ids():
    env = gymnasium.make("adaptfilt/ctm-ukf-v0", n_steps=3)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (8,) and env.action_space.n == len(get_experiment("ctm-ukf").grid)
    venv = gymnasium.make_vec("adaptfilt/ungm-ukf-v0", num_envs=3, vectorization_mode="vector_entry_point", n_steps=3)
    assert venv.reset(seed=0)[0].shape == (3, 5)


def test_vector_env_is_the_filter_env():
    """Rewards are minus log(1 + the env's cost); observations the scaled information state; the episode
    is truncated at T with the next information state as the final observation; then it resets itself."""
    exp = get_experiment("ungm-ukf")
    T, N = 6, 5
    venv = afg.make_vector_env("ungm-ukf", N, n_steps=T, seed=0)
    obs, _ = venv.reset(seed=11)
    ref = exp.make_env(n_steps=T)
    # the same episode by hand: reset(seed=11) seeds one generator, which draws the episode's
    # stream key for a stochastic rule and then simulates the trajectories
    rng = np.random.default_rng(11)
    stream = int(rng.integers(2**31))
    d = ref.reset(n_runs=N, rng=rng, stream=stream)
    np.testing.assert_allclose(obs, venv.scaler(d.features).astype(np.float32), rtol=1e-6)
    a = np.arange(N) % len(exp.grid)
    for t in range(T):
        obs, r, term, trunc, info = venv.step(a)
        d, cost, done, rinfo = ref.step(a)
        np.testing.assert_allclose(r, -np.log1p(cost), rtol=1e-12)
        assert not term.any() and trunc.all() == done
    final = info["final_obs"]
    np.testing.assert_allclose(final, venv.scaler(rinfo["final_decision"].features).astype(np.float32), rtol=1e-6)
    assert info["_final_obs"].all()
    assert not np.allclose(obs, final)  # the returned observation is the next episode's first


def test_reset_with_a_seed_is_reproducible_and_seeds_differ():
    venv = afg.make_vector_env("ctm-ukf", 4, n_steps=3)
    a, _ = venv.reset(seed=3)
    b, _ = venv.reset(seed=3)
    c, _ = venv.reset(seed=4)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_sb3_vecenv_time_limit_convention():
    venv = afg.make_vec("ungm-ukf", n_envs=3, n_steps=2, seed=0)
    venv.seed(5)
    venv.reset()
    venv.step(np.zeros(3, dtype=int))
    obs, r, dones, infos = venv.step(np.zeros(3, dtype=int))
    assert dones.all() and r.dtype == np.float32
    for i in range(3):
        assert infos[i]["TimeLimit.truncated"] is True
        assert infos[i]["terminal_observation"].shape == (5,)


def test_ppo_as_written_and_its_policies_evaluate_identically(tmp_path):
    from stable_baselines3 import PPO

    venv = afg.make_vec("ungm-ukf", n_envs=8, n_steps=20, seed=0)
    model = PPO("MlpPolicy", venv, n_steps=20, batch_size=80, n_epochs=1, gamma=0.5, seed=0).learn(320)
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=20)
    as_pol = afg.as_policy(model, name="ppo")
    learned = afg.to_learned_policy(model, name="ppo-file")
    path = learned.save(tmp_path / "ppo.npz")
    from adaptfilt.learned import load_policy

    loaded = load_policy(path, experiment="ungm-ukf", name="ppo-loaded")
    assert loaded.feature_set.name == "paper" and loaded.actor.activation == "tanh"
    res = evaluate(env, [as_pol, learned, loaded], n_runs=60, progress=False)
    for other in ("ppo-file", "ppo-loaded"):
        assert res["ppo"].rmse == res[other].rmse and res["ppo"].cost == res[other].cost
    # and a callable obs -> actions is a policy too
    always0 = afg.as_policy(lambda obs: np.zeros(len(obs), dtype=int), venv, name="zero")
    r0 = evaluate(env, [always0, exp.baselines()[1]], n_runs=60, progress=False)
    assert r0["zero"].rmse == r0[exp.baselines()[1].name].rmse  # fixed-kappa=0 is grid index 0


def test_bad_inputs():
    with pytest.raises(ValueError, match="num_envs"):
        afg.make_vector_env("ungm-ukf", 0)
    with pytest.raises(KeyError, match="unknown experiment"):
        afg.make_vec("nope")
    with pytest.raises(ValueError, match="cost_transform"):
        afg.make_vector_env("ungm-ukf", 2, cost_transform="sqrt")
    env = afg.make_env("ungm-ukf", n_steps=3)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="not in Discrete"):
        env.step(99)
    with pytest.raises(ValueError, match="give the environment"):
        afg.as_policy(lambda o: o)


def test_reward_transform_none_is_minus_the_cost():
    venv = afg.make_vector_env("ctm-ukf", 3, n_steps=2, cost_transform="none")
    venv.reset(seed=0)
    ref = get_experiment("ctm-ukf").make_env(n_steps=2)
    _, r, *_ = venv.step(np.zeros(3, dtype=int))
    assert np.all(r <= 0) and transform_cost(np.array([2.0]), "none")[0] == 2.0
