"""The particle-count study of ``adaptfilt beyond`` (adaptfilt.experiments.particles_study): its rows against
the evaluation they summarise, the shared evaluation of one model's prices, its figure and its reference
filter. The MDP it runs on is tested in tests/test_particle_env.py."""
from __future__ import annotations

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt.costs import ParticleCost
from adaptfilt.evaluation import evaluate
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.particle_env import PARTICLE_GRID, ESSTargetPolicy, KLDSamplingPolicy, ParticleCountEnv
from adaptfilt.policies import FixedPolicy, GreedyPolicy


def test_the_study_summary_compares_the_learned_group_with_the_best_kld_and_fixed_count():
    from adaptfilt.experiments.beyond import summary_md
    from adaptfilt.experiments.particles_study import particle_rows

    env = ParticleCountEnv(af.models.ungm(), ParticleCost("sqerr", 1e-3), n_steps=8)
    # stand-ins for two learned seeds: any policy named like one is grouped as one
    pols = [FixedPolicy(n, "n_particles") for n in (50, 300, 2000)] + [
        KLDSamplingPolicy(1.0, name="kld-x1"), KLDSamplingPolicy(4.0, name="kld-x4"),
        FixedPolicy(200, "n_particles", name="adaptive-s0"), ESSTargetPolicy(50, grid=None)]
    pols.append(ESSTargetPolicy(200))
    pols[-1].name = "adaptive-s1"
    res = evaluate(env, pols, n_runs=30, progress=False, n_boot=100)
    rows = particle_rows(res, {"rmse": 0.6, "runs": 3})
    best = min(("kld-x1", "kld-x4"), key=lambda n: res[n].cost_charged)
    assert rows["best kld"] == best
    assert rows["best fixed"] == min(("fixed-n_particles=50", "fixed-n_particles=300", "fixed-n_particles=2000"),
                                     key=lambda n: res[n].cost_charged)
    a = rows["adaptive"]
    assert a["particles"] == [res["adaptive-s0"].spent, res["adaptive-s1"].spent]
    lo, hi = a["minus_best kld"]["cost_charged"][1:]
    assert lo <= a["minus_best kld"]["cost_charged"][0] <= hi
    md = summary_md({"particles": {"ungm-test": rows}}, ("particles",))
    assert "point-mass floor (3 runs)" in md and f"| ungm-test | {best} |" in md


def test_one_models_prices_share_the_baselines_that_cannot_see_the_price():
    from adaptfilt.experiments.particles_study import ParticleScale, evaluate_model_job

    scale = ParticleScale(episodes=1, n_steps=4, eval_runs=6, floor_runs=2)
    exps = ["ungm-pf-1e-4", "ungm-pf-1e-3"]
    shared = evaluate_model_job(exps, [[], []], scale)
    for e, res in zip(exps, shared):
        alone = evaluate(e, n_runs=6, progress=False, n_steps=4)  # every baseline, one evaluation per price
        assert [n for n in res.names if not n.startswith("bpf-")] == alone.names
        assert res.config["cost"] == alone.config["cost"]
        for n in alone.names:
            for m in ("rmse", "cost", "cost_charged", "spent"):
                assert getattr(res[n], m) == getattr(alone[n], m), (e, n, m)
            np.testing.assert_array_equal(res[n].boot_cost, alone[n].boot_cost)
    assert shared[0]["kld-x1"].rmse == shared[1]["kld-x1"].rmse  # the same rollout, charged two prices
    assert shared[0]["kld-x1"].cost != shared[1]["kld-x1"].cost


def test_the_tradeoff_figure_draws_every_family_the_learned_group_and_the_floor():
    import matplotlib

    matplotlib.use("Agg")
    from adaptfilt.experiments.particles_study import particle_rows, plot_particle_tradeoff

    env = ParticleCountEnv(af.models.ungm(), ParticleCost("sqerr", 1e-4), n_steps=6)
    pols = [FixedPolicy(n, "n_particles") for n in (50, 500)] + [KLDSamplingPolicy(1.0, name="kld-x1"),
                                                                  ESSTargetPolicy(50), GreedyPolicy()]
    pols += [FixedPolicy(100, "n_particles", name="adaptive-s0"), FixedPolicy(200, "n_particles", name="adaptive-s1")]
    res = evaluate(env, pols, n_runs=12, progress=False, n_boot=50)
    fig = plot_particle_tradeoff({"ungm-test": particle_rows(res, {"rmse": 0.6, "runs": 3})})
    ax = fig.axes[0]
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    for want in ("fixed N", "KLD-sampling", "ESS target", "greedy", "learned seeds", "point-mass floor (3 runs)"):
        assert want in labels, labels
    seeds = next(line for line in ax.get_lines() if line.get_label() == "learned seeds")
    np.testing.assert_array_equal(seeds.get_xdata(), [100, 200])
    np.testing.assert_allclose(seeds.get_ydata(), [res["adaptive-s0"].rmse, res["adaptive-s1"].rmse])
    assert ax.get_xscale() == "log"


def test_the_reference_filter_rows_are_the_bootstrap_filter_on_the_same_runs_charged_the_price():
    """``bpf-N``: exact.BootstrapParticleFilter (systematic resampling at ESS < N/2) with N particles on the
    evaluation's own runs, its squared error plus price x N, with the evaluation's bootstrap resamples."""
    from adaptfilt.exact import BootstrapParticleFilter
    from adaptfilt.experiments.particles_study import ParticleScale, evaluate_model_job, particle_rows
    from adaptfilt.runs import TRAJ_SEED_KEY

    scale = ParticleScale(episodes=1, n_steps=5, eval_runs=8, floor_runs=2)
    exps = ["ungm-pf-1e-4", "ungm-pf-1e-3"]
    res = evaluate_model_job(exps, [[], []], scale, seed=3)
    env = get_experiment(exps[0]).make_env(seed=3, n_steps=5)
    traj = env.truth.simulate(8, 5, rng=np.random.default_rng([TRAJ_SEED_KEY, 3]))
    assert sorted(n for n in res[0].names if n.startswith("bpf-")) == sorted(f"bpf-{n}" for n in PARTICLE_GRID)
    for N in (50, 1000):
        run = BootstrapParticleFilter(env.model, n_particles=N, seed=np.random.default_rng([24, 3, N])).run(traj.z)
        se = ((run.mean - traj.x[:, :5]) ** 2).sum(axis=-1)
        for r, price in zip(res, (1e-4, 1e-3)):
            p = r[f"bpf-{N}"]
            assert p.rmse == pytest.approx(np.sqrt(se.mean(axis=0)).mean(), rel=1e-12)
            assert p.cost_charged == pytest.approx(se.mean() + price * N, rel=1e-12)
            assert p.spent == N and p.extra_spent == 0
    # paired against the study filter's fixed count on the same runs and resamples
    d, lo, hi = res[0].paired_difference("bpf-1000", "fixed-n_particles=1000", "rmse")
    assert lo <= d <= hi and d == pytest.approx(res[0]["bpf-1000"].rmse - res[0]["fixed-n_particles=1000"].rmse)
    rows = particle_rows(res[1])
    assert rows["best reference"] == min((n for n in res[1].names if n.startswith("bpf-")),
                                         key=lambda n: res[1][n].cost_charged)
    assert rows["reference_failed"] == []
