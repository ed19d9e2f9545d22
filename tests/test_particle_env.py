"""The particle count as an MDP (adaptfilt.particle_env): the environment against the particle filter it
wraps, the costs against their definitions, the baselines against their rules, and the evaluation."""
from __future__ import annotations

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt.evaluation import evaluate
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.mdp import rollout
from adaptfilt.costs import ParticleCost
from adaptfilt.particle_env import (ESSTargetPolicy, KLDSamplingPolicy, ParticleCountEnv,
                                    particle_feature_names)
from adaptfilt.particles import ParticleCountFilter, kld_count
from adaptfilt.policies import FixedPolicy, GreedyPolicy


@pytest.fixture(scope="module")
def ungm():
    model = af.models.ungm()
    return model, model.simulate(n_runs=6, n_steps=25, rng=3)


class _Switch:
    """A policy that changes the count per run and step (a fixed pseudo-random pattern)."""
    name = "switch"

    def act(self, d):
        return (np.arange(d.n_runs) * 5 + d.t * 3) % d.grid.size


def test_a_rollout_is_the_particle_filter_with_those_counts(ungm):
    model, traj = ungm
    env = ParticleCountEnv(model, ParticleCost("logmaxnis", 1e-4), n_steps=25, seed=2)
    run, cost = rollout(env, _Switch(), traj=traj)
    ref = ParticleCountFilter(model, seed=2).run(traj.z, run.params.astype(int))
    np.testing.assert_array_equal(run.mean, ref.mean)
    np.testing.assert_array_equal(run.cov, ref.cov)
    np.testing.assert_array_equal(run.loglik, ref.loglik)
    assert len(np.unique(run.params)) > 5
    # reading the features (which draw the first grid[0] particles) changes nothing
    class Looking(_Switch):
        def act(self, d):
            d.features
            return super().act(d)
    run2, cost2 = rollout(env, Looking(), traj=traj)
    np.testing.assert_array_equal(run2.mean, run.mean)
    np.testing.assert_array_equal(cost2, cost)
    assert np.all(run.info["extra_spent"] == 0) and np.allclose(run.info["spent"], run.params.mean(axis=1))


def test_costs_follow_their_definitions(ungm):
    model, traj = ungm
    env = ParticleCountEnv(model, None, n_steps=25)
    d = env.reset(traj=traj)
    _, _, _, info = env.step(np.full(6, 4))  # 200 particles
    x = d.predicted(200)
    r = traj.z[:, 0, 0][:, None] - model.h(x, 1)[..., 0]  # (M, 200)
    S = r.var(axis=1, ddof=1) + model.R[0, 0]
    nis = (r.mean(axis=1)) ** 2 / S
    np.testing.assert_allclose(info["nis"], nis, rtol=1e-10)
    u = info["update"]
    np.testing.assert_allclose(ParticleCost("logmaxnis", 0.01)(u, info["theta"], 1), np.log1p(np.maximum(nis - 1, 0)) + 2.0)
    np.testing.assert_allclose(ParticleCost("nis")(u, info["theta"], 1), (nis - 1) ** 2)
    np.testing.assert_allclose(ParticleCost("stateinnov")(u, info["theta"], 1),
                               np.abs(info["x_filt"][:, 0] - x[..., 0].mean(axis=1)), rtol=1e-10)
    np.testing.assert_allclose(ParticleCost("sqerr")(u, info["theta"], 1), (info["x_filt"][:, 0] - traj.x[:, 0, 0]) ** 2)


def test_greedy_weighs_every_count_and_pays_for_it(ungm):
    model, traj = ungm
    env = ParticleCountEnv(model, ParticleCost("sqerr", 1e-4), n_steps=25)
    d = env.reset(traj=traj)
    cand = d.candidates()["cost"]
    assert cand.shape == (env.grid.size, 6) and d.extra_spent == env.grid.max()
    for g in (0, 6, 12):  # the candidate cost of a count is the cost of stepping with it
        d2 = env.reset(traj=traj)
        _, c, _, _ = env.step(np.full(6, g))
        np.testing.assert_allclose(cand[g], c, rtol=1e-9)
    run, _ = rollout(env, GreedyPolicy(), traj=traj)
    np.testing.assert_allclose(run.info["spent"], env.grid.max())  # every step weighs 5000 particles


def test_kld_policy_rounds_fox_count_up_to_the_grid(ungm):
    model, traj = ungm
    env = ParticleCountEnv(model, None, n_steps=25)
    d = env.reset(traj=traj)
    pol = KLDSamplingPolicy(bin_size=0.5, n_min=50)
    n = pol.counts(d)
    x = d.predicted(5000)
    assert n.tolist() == [kld_count(x[i], 0.5, n_min=50) for i in range(6)]
    chosen = env.grid[pol.act(d)]
    below = np.concatenate([[0], env.grid])[pol.act(d)]
    assert np.all(chosen >= np.minimum(n, env.grid.max())) and np.all(below < n)
    # finer bins occupy more bins: Fox's bound asks for more particles
    assert np.all(KLDSamplingPolicy(bin_size=0.05).counts(d) >= n) and np.any(KLDSamplingPolicy(bin_size=0.05).counts(d) > n)


def test_ess_policy_keeps_the_effective_sample_size_near_its_target(ungm):
    model, traj = ungm
    env = ParticleCountEnv(model, None, n_steps=25)
    pol = ESSTargetPolicy(target=100)
    d = env.reset(traj=traj)
    assert np.all(pol.act(d) == env.default_index)
    d, _, _, info = env.step(pol.act(d))
    want = 100 * d.n_prev / info["ess"]
    chosen = env.grid[pol.act(d)]
    assert np.all((chosen >= np.minimum(want, 5000)) | (chosen == 5000))


def test_evaluate_takes_the_particle_environment_and_charges_greedy(ungm):
    model, _ = ungm
    env = ParticleCountEnv(model, ParticleCost("logmaxnis", 1e-4), n_steps=10)
    res = evaluate(env, [FixedPolicy(100, "n_particles"), GreedyPolicy(), KLDSamplingPolicy(1.0)], n_runs=8,
                   progress=False, n_boot=50)
    assert res.config["param_name"] == "n_particles" and res.config["compute_unit"] == "particles"
    g = res["greedy"]
    assert g.spent == 5000 and g.cost_charged == pytest.approx(g.cost + 1e-4 * g.extra_spent)
    assert res["fixed-n_particles=100"].extra_spent == 0


def test_features_are_named_and_finite(ungm):
    model, traj = ungm
    env = ParticleCountEnv(model, None, n_steps=25)
    d = env.reset(traj=traj)
    assert d.features.shape == (6, len(particle_feature_names(model))) == (6, 10)
    for _ in range(5):
        d, _, _, _ = env.step(np.full(6, 2))
    assert np.isfinite(d.features).all() and np.all(d.features[:, 2] <= 1)  # ESS/N
    ctm = af.models.coordinated_turn()
    names = particle_feature_names(ctm)
    assert "sin z[0]" in names and len(names) == 4 + 4 + 2 + 1 + 1


def test_bad_input_is_named(ungm):
    model, traj = ungm
    with pytest.raises(ValueError, match="default count 7"):
        ParticleCountEnv(model, None, grid=(5, 10), default=7)
    with pytest.raises(ValueError, match="integers >= 1"):
        ParticleCountEnv(model, None, grid=(0.5, 10), default=10)
    with pytest.raises(ValueError, match="unknown cost"):
        ParticleCost("mse")
    with pytest.raises(ValueError, match="price"):
        ParticleCost("nis", price=-1)
    env = ParticleCountEnv(model, None, n_steps=25)
    env.reset(traj=traj)
    with pytest.raises(ValueError, match="out of range"):
        env.step(np.full(6, 13))
    with pytest.raises(ValueError, match="predict parameter"):
        env.step(np.zeros(6, dtype=int), predict_param=3)
    with pytest.raises(ValueError, match="bin_size"):
        KLDSamplingPolicy(bin_size=0)


def test_a_collapsed_cloud_has_infinite_nees_and_counts_as_diverged():
    from adaptfilt import metrics

    e = np.array([[[1.0], [0.5]]])  # one run, two steps, nx = 1
    cov = np.array([[[[2.0]], [[0.0]]]])  # the second step's cloud sits on one point
    ne = metrics.nees(e, np.zeros_like(e), cov, on_indefinite="inf")
    assert ne[0, 0] == 0.5 and np.isinf(ne[0, 1])
    assert metrics.divergent(ne, 1, np.zeros_like(e)).tolist() == [True]
    e2 = np.ones((1, 2, 2))
    cov2 = np.stack([np.eye(2), np.zeros((2, 2))])[None]
    ne2 = metrics.nees(e2, np.zeros_like(e2), cov2, on_indefinite="inf")
    assert ne2[0, 0] == 2.0 and np.isinf(ne2[0, 1])
    with pytest.raises(ValueError, match="not positive definite"):
        metrics.nees(e, np.zeros_like(e), cov)  # the Gaussian filters' default stays strict


def test_the_particle_experiments_are_named_with_their_baselines():
    from adaptfilt.experiment_registry import (ESS_TARGETS, KLD_BIN_SCALES, PARTICLE_EXPERIMENTS, PARTICLE_PRICES,
                                               get_experiment)

    assert sorted(PARTICLE_EXPERIMENTS) == sorted(f"{m}-pf-{p}" for m, ps in PARTICLE_PRICES.items() for p in ps)
    exp = get_experiment("ctm-pf-0.1")
    env = exp.make_env(seed=3, n_steps=5)
    assert isinstance(env, ParticleCountEnv) and env.cost == ParticleCost("sqerr", 0.1) and env.n_steps == 5
    assert exp.param_name == "n_particles" and exp.default_value == 1000
    names = [p.name for p in exp.baselines()]
    assert names[0] == "default" and names[-1] == "greedy"
    assert [n for n in names if n.startswith("ess-")] == [f"ess-{t}" for t in ESS_TARGETS]
    klds = [p for p in exp.baselines() if p.name.startswith("kld")]
    assert [p.name for p in klds] == [f"kld-x{k}" for k in KLD_BIN_SCALES]
    noise_std = np.sqrt(np.diag(exp.make_model().Q))
    for k, p in zip(KLD_BIN_SCALES, klds):  # the rule: multiples of the process noise's std per dimension
        np.testing.assert_allclose(p.bin_size, k * noise_std)
    assert get_experiment("ungm-pf-1e-4").make_model().n_steps == 100
