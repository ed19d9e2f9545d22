"""Monte-Carlo evaluation (adaptfilt.evaluation), its files, figures and the CLI."""
import json

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt import metrics
from adaptfilt.cli import main
from adaptfilt.evaluation import evaluate
from adaptfilt.experiments.evaluate import evaluate_experiment
from adaptfilt.experiment_registry import get_experiment
from adaptfilt.results import Results
from adaptfilt.mdp import Cost, FilterEnv
from adaptfilt.policies import FixedPolicy, GreedyPolicy

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)


@pytest.fixture(scope="module")
def ctm_results():
    """ctm-ukf on 60 runs x 40 steps: default, two fixed values, a twin of the default, greedy."""
    exp = get_experiment("ctm-ukf")
    env = exp.make_env(n_steps=40)
    grid = exp.grid
    pols = [FixedPolicy(0.0, name="default", grid=grid), FixedPolicy(0.0, name="twin", grid=grid),
            FixedPolicy(-1.0, "kappa", grid=grid), FixedPolicy(20.0, "kappa", grid=grid), GreedyPolicy(grid=grid)]
    traj = exp.make_model().simulate(60, 40, rng=np.random.default_rng(2))
    return evaluate(env, pols, seed=3, progress=False, n_boot=200, traj=traj), traj


def test_anees_bars_name_the_ideal_line_off_the_data(ctm_results):
    """The ideal-nx line is named in the x label, not in a legend that could cover a policy's marker
    or narrow the caller's panels."""
    from adaptfilt.plots import plot_anees_bars, plt
    res, _ = ctm_results
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4), layout="constrained")
    plot_anees_bars(res, ax=ax[1])
    assert ax[1].get_legend() is None and not fig.legends
    assert ax[1].get_xlabel() == f"time-averaged ANEES (dashed: ideal, $n_x$ = {res.config['nx']})"
    assert any(ln.get_linestyle() == "--" and ln.get_xdata()[0] == res.config["nx"] for ln in ax[1].get_lines())
    plt.close(fig)


def test_metrics_match_a_direct_filter_run(ctm_results):
    res, traj = ctm_results
    run = af.UKF(af.models.coordinated_turn(), kappa=20.0).run(traj.z)
    p = res["fixed-kappa=20"]
    np.testing.assert_allclose(p.rmse_t, metrics.rmse(traj.x, run.mean), rtol=1e-12)
    np.testing.assert_allclose(p.anees_t, metrics.anees(traj.x, run.mean, run.cov), rtol=1e-9)
    np.testing.assert_allclose(p.nis_t, run.nis.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(p.cost, ((run.nis - 1) ** 2).mean(), rtol=1e-12)
    assert p.rmse == pytest.approx(metrics.rmse(traj.x, run.mean).mean(), rel=1e-12)
    assert p.rmse_ci[0] < p.rmse < p.rmse_ci[1] and p.anees_ci[0] < p.anees < p.anees_ci[1]
    assert p.cost_median <= p.cost_q99 <= p.cost_q999 <= p.cost_max
    # choices and usage: the fixed policy always used kappa = 20, the greedy one a mix
    g = res.grid.tolist().index(20.0)
    np.testing.assert_array_equal(p.choices[:, g], 1.0)
    assert p.usage[g] == 60 * 40 and p.usage.sum() == 60 * 40
    gr = res["greedy"]
    np.testing.assert_allclose(gr.choices.sum(axis=1), 1.0)
    assert gr.usage.sum() == 60 * 40 and (gr.usage > 0).sum() > 1


def test_identical_policies_have_zero_paired_difference(ctm_results):
    res, _ = ctm_results
    for m in ("rmse", "anees", "cost"):
        assert res.paired_difference("twin", "default", m) == (0.0, 0.0, 0.0)
    # and different ones do differ, with an interval that is narrower than the separate ones
    d, lo, hi = res.paired_difference("fixed-kappa=20", "default", "rmse")
    assert d == pytest.approx(res["fixed-kappa=20"].rmse - res["default"].rmse)
    assert lo < d < hi and hi - lo > 0
    with pytest.raises(KeyError, match="no policy 'nope'"):
        res.paired_difference("nope", "default")
    with pytest.raises(ValueError, match="metric must be"):
        res.paired_difference("twin", "default", "nis")


def test_results_round_trip_bit_identically(ctm_results, tmp_path):
    res, _ = ctm_results
    res.save(tmp_path)
    back = Results.load(tmp_path)
    assert back.config == res.config and back.names == res.names
    for n, p in res.policies.items():
        q = back[n]
        assert q.scalars() == p.scalars()
        for k in ("rmse_t", "anees_t_band", "choices", "usage", "boot_rmse", "run_cost"):
            a, b = getattr(p, k), getattr(q, k)
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), (n, k)
    back.save(tmp_path / "again")
    assert (tmp_path / "again" / "results.json").read_bytes() == (tmp_path / "results.json").read_bytes()
    # summaries only: the same scalars, no arrays (and no npz file), marked in the config
    res.save(tmp_path / "light", arrays=False)
    assert not (tmp_path / "light" / "results.npz").exists()
    light = Results.load(tmp_path / "light")
    assert light.config["arrays"] is False and light.names == res.names
    for n, p in res.policies.items():
        assert light[n].scalars() == p.scalars() and light[n].run_cost.size == 0
    # compact: some arrays dropped, the rest bit-identical, and paired differences still work
    res.save(tmp_path / "compact", drop=("run_cost", "choices"))
    compact = Results.load(tmp_path / "compact")
    assert compact.config["dropped"] == ["choices", "run_cost"] and compact[res.names[0]].run_cost.size == 0
    assert compact[res.names[0]].boot_rmse.tobytes() == res[res.names[0]].boot_rmse.tobytes()
    assert compact.paired_difference(res.names[0], res.names[1]) == res.paired_difference(res.names[0], res.names[1])
    with pytest.raises(ValueError, match="drop names no array"):
        res.save(tmp_path / "x", drop=("nope",))


def test_evaluate_refuses_bad_input():
    exp = get_experiment("ungm-ukf")
    with pytest.raises(ValueError, match="policy names must be unique; repeated: default"):
        evaluate(exp, [FixedPolicy(2.0, name="default"), FixedPolicy(0.0, name="default")], n_runs=3, progress=False)
    with pytest.raises(ValueError, match=r"made for the grid \[0.0, 2.0\]"):
        evaluate(exp, [FixedPolicy(2.0, grid=[0.0, 2.0])], n_runs=3, progress=False)
    with pytest.raises(KeyError, match="unknown experiment 'nope'"):
        evaluate("nope", n_runs=3, progress=False)
    env = FilterEnv(af.UKF(af.models.ungm()), [0.0, 2.0], cost=Cost("nis"), n_steps=3)
    with pytest.raises(ValueError, match="give the policies"):
        evaluate(env, n_runs=3, progress=False)


def test_cli_evaluate_writes_summary_and_figures_reproducibly(tmp_path, capsys):
    args = ["evaluate", "ungm-ukf", "--runs", "50", "--seed", "1", "--no-progress"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    printed = capsys.readouterr().out
    assert "| greedy |" in printed
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    names = [p.name for p in get_experiment("ungm-ukf").baselines()]
    assert list(summary) == names and "ml" in names and "fixed-kappa=10000" in names
    for n in names:
        s = summary[n]
        assert {"rmse", "anees", "cost", "rmse_ci", "anees_ci"} <= set(s)
        assert s["rmse_ci"][0] <= s["rmse"] <= s["rmse_ci"][1]
    for png in ("rmse_time", "anees_time", "rmse_bars", "anees_bars", "tradeoff", "usage", "choices_ml", "choices_greedy"):
        f = tmp_path / "a" / f"{png}.png"
        assert f.stat().st_size > 10_000 and f.read_bytes()[:4] == b"\x89PNG", png
    assert (tmp_path / "a" / "summary.md").read_text().count("\n| ") == len(names) + 1
    cfg = Results.load(tmp_path / "a").config
    assert cfg["command"].startswith("adaptfilt evaluate ungm-ukf --runs 50 --seed 1") and cfg["version"] == af.__version__
    # same seed again (figures skipped to save time): the same summary, byte for byte; another seed: a different one
    evaluate_experiment("ungm-ukf", n_runs=50, seed=1, out_dir=tmp_path / "b", progress=False, figures=False, quiet=True)
    assert (tmp_path / "b" / "summary.json").read_bytes() == (tmp_path / "a" / "summary.json").read_bytes()
    res_c = evaluate("ungm-ukf", [FixedPolicy(2.0, name="default")], n_runs=50, seed=2, progress=False)
    assert res_c["default"].rmse != summary["default"]["rmse"]


def test_evaluate_costs_equals_one_evaluation_per_experiment_bit_for_bit():
    """The SIF experiments differ in their cost only: one rollout per policy, every cost charged on
    it, gives each experiment exactly what its own evaluation gives; ``default`` (the constant 10)
    is ``fixed-n_iter=10`` again and is not rolled out twice."""
    from adaptfilt.evaluation import evaluate_costs
    from adaptfilt.experiment_registry import SIF_EXPERIMENTS

    names = ("default", "fixed-n_iter=1", "fixed-n_iter=10")
    pols = lambda e: [p for p in get_experiment(e).baselines() if p.name in names]  # noqa: E731
    shared = evaluate_costs(list(SIF_EXPERIMENTS), pols(SIF_EXPERIMENTS[0]), n_runs=40, seed=2, progress=False, n_steps=25)
    assert list(shared) == list(SIF_EXPERIMENTS)
    costs = set()
    for e in SIF_EXPERIMENTS:
        alone = evaluate(e, pols(e), n_runs=40, seed=2, progress=False, n_steps=25)
        assert shared[e].config == alone.config
        for n in names:
            a, b = alone[n].__dict__, shared[e][n].__dict__
            for k, v in a.items():
                if isinstance(v, str):
                    assert v == b[k]
                elif k != "wall_time_s":
                    assert np.array_equal(np.asarray(v), np.asarray(b[k]), equal_nan=True), (e, n, k)
        costs.add(round(shared[e]["fixed-n_iter=1"].cost, 12))
    assert len(costs) == 3  # three costs really were charged
    walls = [shared[SIF_EXPERIMENTS[0]][n].wall_time_s for n in ("default", "fixed-n_iter=10")]
    assert walls[0] > 0 and walls[1] == 0.0  # fixed-n_iter=10 is default's episode again: copied, not rolled out


def test_evaluate_costs_refuses_what_it_cannot_share():
    from adaptfilt.evaluation import evaluate_costs

    greedy = [p for p in get_experiment("ctm-sif-nis").baselines() if p.name == "greedy"]
    with pytest.raises(ValueError, match="greedy.*may choose by the cost"):
        evaluate_costs(["ctm-sif-nis", "ctm-sif-stateinnov"], greedy, n_runs=4, progress=False, n_steps=3)
    fixed = [p for p in get_experiment("ctm-sif-nis").baselines() if p.name == "default"]
    with pytest.raises(ValueError, match="differ in filter"):  # a constant both grids hold
        evaluate_costs(["ctm-sif-nis", "ctm-ukf"], [FixedPolicy(10.0)], n_runs=4, progress=False, n_steps=3)
    with pytest.raises(ValueError, match="distinct"):
        evaluate_costs(["ctm-sif-nis", "ctm-sif-nis"], fixed, n_runs=4, progress=False, n_steps=3)


def test_the_charged_cost_makes_greedy_pay_for_its_candidates():
    """On a SIF cost (N_it / 50) greedy computes every candidate (max(grid) = 30 iterations from one set
    of draws) each step: its charged cost is its estimation cost plus 30/50 per step exactly, per run, and
    its paired difference to a constant is taken on the same resampled runs; a constant pays nothing extra."""
    exp = get_experiment("ctm-sif-logmaxnis")
    pols = [p for p in exp.baselines() if p.name in ("default", "fixed-n_iter=2", "greedy")]
    res = evaluate(exp, pols, n_runs=40, seed=1, progress=False, n_steps=20, n_boot=300)
    g, d = res["greedy"], res["default"]
    assert d.cost_charged == d.cost and np.array_equal(d.boot_cost_charged, d.boot_cost) and d.extra_spent == 0
    assert d.spent == 10 and res["fixed-n_iter=2"].spent == 2 and res.config["compute_unit"] == "iteration"
    # greedy: chosen N_it / 50 is in ``cost``; the rest of the 30 iterations is charged on top
    assert g.spent == pytest.approx(30.0) and g.extra_spent == pytest.approx(30.0 - (g.usage * res.grid).sum() / g.usage.sum())
    assert g.cost_charged == pytest.approx(g.cost + g.extra_spent / 50, rel=1e-12)
    assert g.cost_charged_ci[0] < g.cost_charged < g.cost_charged_ci[1]
    diff, lo, hi = res.paired_difference("greedy", "default", "cost_charged")
    assert diff == pytest.approx(g.cost_charged - d.cost_charged)
    np.testing.assert_allclose(np.quantile(g.boot_cost_charged - d.boot_cost_charged, [0.025, 0.975]), [lo, hi])
    ukf = evaluate("ungm-ukf", [p for p in get_experiment("ungm-ukf").baselines() if p.name == "greedy"],
                   n_runs=10, progress=False, n_steps=5, n_boot=50)
    assert ukf["greedy"].spent == 13 and ukf.config["compute_unit"] == "update"  # 13 candidate updates per step


def test_a_learned_policy_sees_the_features_sb3_trained_on():
    """One transform from information state to network input, in training (the Gymnasium observer) and in
    acting (LearnedPolicy): a diverged run's 1e300, inf or nan reaches the network finite and bounded."""
    import adaptfilt.gym as afg
    from adaptfilt.features import OBS_LIMIT, FeatureScaler
    from adaptfilt.learned import Actor, LearnedPolicy

    scaler = FeatureScaler(np.zeros(3), np.ones(3), squash="asinh")
    x = np.array([[np.nan, np.inf, 1e300], [1.0, -np.inf, -2.0]])
    s = scaler.network_input(x)
    np.testing.assert_array_equal(s, np.float32([[0.0, OBS_LIMIT, OBS_LIMIT], [np.arcsinh(1.0), -OBS_LIMIT, np.arcsinh(-2.0)]]))
    pol = LearnedPolicy(Actor(3, 4, hidden=(8,)), scaler, grid=[0.0, 1.0, 2.0, 5.0])
    import torch

    with torch.no_grad():
        want = pol.actor(torch.from_numpy(s)).double().numpy()
    np.testing.assert_array_equal(pol.logits(x), want)
    assert afg._Observer.__call__.__code__.co_names.count("network_input") == 1  # the observer uses the same function


def test_a_policy_records_its_filter_and_is_refused_by_another_form():
    """The SIF form is part of what a policy was trained for: a file made on the one-pass SIF is refused by
    the experiment that runs the reference (two-pass) form, naming the filter."""
    from adaptfilt.learned import check_compatible, describe_target

    ref, one = describe_target("ctm-sif-nis"), describe_target("ctm-sif-nis-onepass")
    assert "passes=2" in ref["filter"] and "passes" not in one["filter"]
    with pytest.raises(ValueError, match="mismatch in filter"):
        check_compatible({**ref, "filter": one["filter"]}, ref)
    check_compatible({k: v for k, v in ref.items() if k != "filter"}, ref)  # files written before the record: accepted


def test_streamed_runs_are_the_one_pass_runs(tmp_path):
    """The trajectories a streamed evaluation writes and reads back chunk by chunk are the rows of
    ``simulate(M, T, default_rng([TRAJ_SEED_KEY, seed]))``, and its bootstrap counts are those of
    ``metrics.bootstrap_counts``, bit for bit."""
    from adaptfilt.runs import TRAJ_SEED_KEY, RunStore

    for name in ("ungm-ukf", "ctm-ukf"):
        env = get_experiment(name).make_env(n_steps=12)
        store = RunStore(env.truth, 50, 12, 4, 30, None, 16, tmp_path)
        want = env.truth.simulate(50, 12, rng=np.random.default_rng([TRAJ_SEED_KEY, 4]))
        counts = metrics.bootstrap_counts(50, 30, rng=np.random.default_rng([TRAJ_SEED_KEY, 4, 1]))
        assert store.chunks() == [(0, 16), (16, 32), (32, 48), (48, 50)]
        for a, b in store.chunks():
            tr = store.trajectory(a, b)
            assert tr.x.tobytes() == want.x[a:b].tobytes() and tr.z.tobytes() == want.z[a:b].tobytes()
            assert store.counts(a, b).tobytes() == np.ascontiguousarray(counts[:, a:b]).tobytes()


def test_exact_quantiles_from_a_file_are_numpys(tmp_path):
    from adaptfilt.evaluation import COST_QUANTILES, _file_quantiles

    rng = np.random.default_rng(0)
    for trial in range(40):
        n = int(rng.integers(1, 2000))
        v = rng.standard_normal(n) ** 2 * 10 ** rng.uniform(-3, 6, n)
        if trial % 3 == 1:
            v[rng.random(n) < 0.6] = 0.0  # ties at the median
        if trial % 3 == 2:
            v = np.round(v)
        (tmp_path / "c").write_bytes(v.tobytes())
        got = _file_quantiles(tmp_path / "c", n, COST_QUANTILES, block=int(rng.integers(1, 300)))
        assert np.asarray(got).tobytes() == np.quantile(v, COST_QUANTILES).tobytes(), trial
    (tmp_path / "c").write_bytes(np.array([1.0, np.nan, 2.0]).tobytes())
    assert np.isnan(_file_quantiles(tmp_path / "c", 3, COST_QUANTILES)).all()


#: what a streamed evaluation keeps exactly (per run, counts, order statistics); the rest is a sum over chunks
_EXACT = ("run_rmse", "run_anees", "run_cost", "rmse_run_median", "anees_run_median", "usage", "choices", "n_repairs",
          "divergent_frac", "cost_max", "cost_median", "cost_q99", "cost_q999", "spent", "extra_spent")


def test_a_streamed_evaluation_is_the_one_pass_evaluation(tmp_path):
    """A deterministic rule on runs streamed in chunks of 16: every per-run value, count and quantile is the
    one-pass evaluation's byte for byte in the saved files, every mean and bootstrap replicate equal to 1e-12
    (sums in another order); at chunk_size >= M the files are the one-pass files byte for byte."""
    exp = get_experiment("ctm-ukf")
    pols = lambda: [p for p in exp.baselines() if p.name in ("default", "fixed-kappa=20", "greedy")]  # noqa: E731
    kw = dict(n_runs=70, seed=5, progress=False, n_steps=15, n_boot=100)
    one = evaluate(exp, pols(), **kw)
    same = evaluate(exp, pols(), chunk_size=70, **kw)
    streamed = evaluate(exp, pols(), chunk_size=16, **kw)
    for r in (one, same, streamed):
        for p in r.policies.values():
            p.wall_time_s = 0.0
    one.save(tmp_path / "one"), same.save(tmp_path / "same"), streamed.save(tmp_path / "streamed")
    for f in ("results.json", "results.npz"):
        assert (tmp_path / "one" / f).read_bytes() == (tmp_path / "same" / f).read_bytes()
    back = Results.load(tmp_path / "streamed")
    assert back.config == {**one.config, "chunk_size": 16}
    for n in one.names:
        for k, v in one[n].__dict__.items():
            w = getattr(back[n], k)
            if k in _EXACT:
                assert np.asarray(v).tobytes() == np.asarray(w).tobytes(), (n, k)
            elif k != "name":
                np.testing.assert_allclose(np.asarray(w, dtype=float), np.asarray(v, dtype=float), rtol=1e-12,
                                           atol=0, err_msg=f"{n} {k}")
    assert back.paired_difference("greedy", "default", "cost")[0] == pytest.approx(
        one.paired_difference("greedy", "default", "cost")[0], rel=1e-12)


def test_a_streamed_stochastic_rule_stays_paired():
    """SIF draws per step for all runs of a batch: streamed, each chunk has its own stream (other draws than
    one pass), the same for every policy, so that a twin of the default differs from it by exactly 0."""
    exp = get_experiment("ctm-sif-nis")
    pols = [p for p in exp.baselines() if p.name in ("default", "fixed-n_iter=10", "fixed-n_iter=3")]
    res = evaluate(exp, pols, n_runs=24, seed=1, progress=False, n_steps=6, n_boot=50, chunk_size=10)
    assert res.config["chunk_size"] == 10 and res["fixed-n_iter=10"].run_cost.shape == (24,)
    assert res.paired_difference("fixed-n_iter=10", "default", "cost") == (0.0, 0.0, 0.0)
    assert np.isfinite(res["fixed-n_iter=3"].cost) and res["fixed-n_iter=3"].usage.sum() == 24 * 6


@pytest.mark.parametrize("bad", [0, -3, 2.5, True])
def test_a_chunk_size_that_is_not_a_positive_integer_is_refused(bad):
    with pytest.raises(ValueError, match=r"chunk_size must be a positive integer .* got " + repr(bad).replace(".", r"\.")):
        evaluate("ungm-ukf", [FixedPolicy(2.0, name="default")], n_runs=4, progress=False, chunk_size=bad)


def test_cli_chunk_size_is_recorded_and_changes_no_per_run_value_of_a_deterministic_filter(tmp_path):
    """``adaptfilt evaluate --chunk-size C`` streams the runs C at a time: the command it records says so
    (the default is left out, so older commands stay as they were), and a UKF's per-run values are the
    one-pass ones byte for byte."""
    base = ["evaluate", "ctm-ukf", "--runs", "30", "--horizon", "12", "--no-progress"]
    assert main(base + ["--out", str(tmp_path / "one")]) == 0
    assert main(base + ["--chunk-size", "7", "--out", str(tmp_path / "seven")]) == 0
    one, seven = Results.load(tmp_path / "one"), Results.load(tmp_path / "seven")
    assert "--chunk-size" not in one.config["command"] and "--chunk-size 7 " in seven.config["command"]
    for name in one.names:
        for k in ("run_rmse", "run_anees", "run_cost"):
            assert getattr(one[name], k).tobytes() == getattr(seven[name], k).tobytes(), (name, k)


def test_the_bootstrap_counts_are_drawn_once_per_runs_and_seed():
    """A worker that evaluates policy after policy on the same runs draws the counts once: the kept counts
    are the draw of their own runs and seed (another seed, another draw), and nobody can change them."""
    from adaptfilt import runs

    runs._bootstrap_counts.cache_clear()
    a = runs.bootstrap_counts(50, 20, 3)
    assert runs.bootstrap_counts(50, 20, 3) is a and not a.flags.writeable
    np.testing.assert_array_equal(a, metrics.bootstrap_counts(50, 20, rng=np.random.default_rng([runs.TRAJ_SEED_KEY, 3, 1])))
    assert not np.array_equal(runs.bootstrap_counts(50, 20, 4), a)
    one = evaluate("ungm-ukf", [FixedPolicy(2.0, name="default")], n_runs=30, n_steps=5, progress=False, n_boot=40)
    two = evaluate("ungm-ukf", [FixedPolicy(2.0, name="default")], n_runs=30, n_steps=5, progress=False, n_boot=40)
    assert one["default"].boot_rmse.tobytes() == two["default"].boot_rmse.tobytes()


# ------------------------------------------------------------------ filters beside policies (evaluate(filters=))
class _Blind:
    """A filter without a covariance (the declared "none": cov and nis all NaN) that estimates zero, and
    loses run 0 from step 3 on (a NaN estimate) when ``lose``."""

    def __init__(self, model, lose=False):
        self.model, self.lose = model, lose

    def __repr__(self):
        return f"Blind(lose={self.lose})"

    def run(self, z):
        M, T = z.shape[:2]
        mean = np.zeros((M, T, self.model.nx))
        if self.lose:
            mean[0, 3] = np.nan
        nan = np.full((M, T), np.nan)
        return af.FilterRun(mean=mean, cov=np.full((M, T, self.model.nx, self.model.nx), np.nan), nis=nan,
                            loglik=nan, params=nan)


def test_the_environments_own_filter_as_a_filter_is_its_fixed_policy():
    """The default UKF given as a filter and the default policy rolled out in the environment: the same runs,
    the same numbers (error, NEES, NIS cost, choices, compute), and their paired difference is zero; a
    filter whose parameter is not the environment's counts no choices and no compute."""
    exp = get_experiment("ungm-ukf")
    model = exp.make_model()
    pf = af.BootstrapParticleFilter(model, n_particles=200, seed=[7, 0])
    res = evaluate(exp, [FixedPolicy(2.0, name="default")], filters={"ukf": af.UKF(model, kappa=2.0), "pf": pf},
                   n_runs=30, n_steps=12, progress=False, n_boot=100)
    a, b = res["default"], res["ukf"]
    for k in ("rmse_t", "run_rmse", "anees_t", "run_anees", "nis_t", "cost_t", "run_cost", "boot_rmse", "boot_cost"):
        np.testing.assert_allclose(getattr(b, k), getattr(a, k), rtol=1e-10, err_msg=k)
    assert b.usage.tolist() == a.usage.tolist() and b.spent == a.spent == 1.0
    assert res.paired_difference("ukf", "default", "rmse")[0] == pytest.approx(0.0, abs=1e-12)
    assert res.names == ["default", "ukf", "pf"] and res.config["policies"] == res.names
    assert res.config["filters"] == {"ukf": "UKF(model='ungm', kappa=2)", "pf": repr(pf)}
    assert res["pf"].usage.sum() == 0 and np.isnan(res["pf"].spent) and np.isnan(res["pf"].cost)  # no NIS: cost n/a
    assert np.isfinite(res["pf"].anees)


def test_a_filter_without_a_covariance_and_a_lost_run():
    """No covariance: ANEES, its interval, replicates and per-run values and the NEES divergence are NaN (n/a),
    not averaged; a NaN estimate is an infinite error from that step on: the run is kept, diverged."""
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=8)
    runs = af.runs.EvalRuns(env.truth, 20, 0, 8, n_boot=50)
    res = evaluate(env, [], filters={"zero": _Blind(env.model), "lost": _Blind(env.model, lose=True)}, runs=runs,
                   progress=False)
    x = runs.traj.x
    zero, lost = res["zero"], res["lost"]
    np.testing.assert_allclose(zero.run_rmse, np.sqrt((x ** 2).sum(-1).mean(axis=1)), rtol=1e-14)
    for p in (zero, lost):
        assert np.isnan([p.anees, *p.anees_ci, p.anees_run_median, p.divergent_frac, p.nis, p.cost]).all()
        assert np.isnan(p.anees_t).all() and np.isnan(p.boot_anees).all() and np.isnan(p.run_anees).all()
    assert np.isposinf(lost.run_rmse[0]) and (lost.run_rmse[1:] == zero.run_rmse[1:]).all()
    assert np.isposinf(lost.rmse_t[3:]).all() and (lost.rmse_t[:3] == zero.rmse_t[:3]).all()


def test_the_squared_error_cost_is_charged_to_a_filter():
    """On the squared-error experiments, a filter is charged ||x_filt - x||^2 (plus the price times its count
    where the count is the environment's parameter), as a policy is."""
    for name, filt in (("ungm-ukf-sqerr", lambda m: af.UKF(m, kappa=2.0)),
                       ("ungm-pf-1e-3", lambda m: af.BootstrapParticleFilter(m, n_particles=100, seed=[3]))):
        exp = get_experiment(name)
        env = exp.make_env(n_steps=6)
        runs = af.runs.EvalRuns(env.truth, 12, 1, 6, n_boot=20)
        res = evaluate(env, [], filters={"f": filt(env.model)}, runs=runs, progress=False)
        r = filt(env.model).run(runs.traj.z)
        se = ((r.mean - runs.traj.x) ** 2).sum(-1)
        price = 1e-3 * 100 if name.startswith("ungm-pf") else 0.0
        np.testing.assert_allclose(res["f"].cost_t, se.mean(axis=0) + price, rtol=1e-12)


def test_filters_errors_are_named_and_a_failing_filter_can_be_left_out():
    exp = get_experiment("ungm-ukf")
    model = exp.make_model()

    class Failing(_Blind):
        def run(self, z):
            raise ValueError("no particle explains the measurement at step t=2")

    kw = dict(n_runs=6, n_steps=4, progress=False, n_boot=10)
    with pytest.raises(ValueError, match="no particle explains"):
        evaluate(exp, [], filters={"bad": Failing(model)}, **kw)
    res = evaluate(exp, [FixedPolicy(2.0, name="default")], filters={"bad": Failing(model), "ok": _Blind(model)},
                   on_filter_error="skip", **kw)
    assert res.names == ["default", "ok"] == res.config["policies"] and list(res.config["filters"]) == ["ok"]
    assert res.config["failed_filters"] == {"bad": "no particle explains the measurement at step t=2"}
    with pytest.raises(TypeError, match="filter 'x': a filter needs .model and .run"):
        evaluate(exp, [], filters={"x": object()}, **kw)
    with pytest.raises(ValueError, match="filter 'ctm' filters a model with nx = 4, the evaluation's has 1"):
        evaluate(exp, [], filters={"ctm": af.UKF(af.models.coordinated_turn())}, **kw)
    with pytest.raises(ValueError, match="nothing to evaluate"):
        evaluate(exp, [], **kw)
    with pytest.raises(ValueError, match="policy names must be unique; repeated: default"):
        evaluate(exp, [FixedPolicy(2.0, name="default")], filters={"default": _Blind(model)}, **kw)
    with pytest.raises(ValueError, match="filters are evaluated in one pass"):
        evaluate(exp, [], filters={"ok": _Blind(model)}, chunk_size=4, **kw)
    with pytest.raises(ValueError, match="on_filter_error must be"):
        evaluate(exp, [], filters={"ok": _Blind(model)}, on_filter_error="ignore", **kw)


def test_given_runs_are_the_evaluations_runs():
    """``runs=``: the evaluation's own runs made by the caller give the same numbers bit for bit; runs of another
    model or horizon, or runs with trajectories, are refused."""
    exp = get_experiment("ctm-ukf")
    pols = [p for p in exp.baselines() if p.name in ("default", "fixed-kappa=1")]
    env = exp.make_env(seed=2, n_steps=7)
    one = evaluate(exp, pols, n_runs=15, seed=2, n_steps=7, progress=False, n_boot=30)
    runs = af.runs.EvalRuns(env.truth, 15, 2, 7, n_boot=30)
    two = evaluate(exp, pols, n_steps=7, progress=False, runs=runs)
    for n in one.names:
        assert one[n].boot_rmse.tobytes() == two[n].boot_rmse.tobytes() and one[n].run_anees.tobytes() == two[n].run_anees.tobytes()
    assert {k: v for k, v in one.config.items() if k != "command"} == {k: v for k, v in two.config.items() if k != "command"}
    with pytest.raises(ValueError, match="not the evaluation's"):
        evaluate(exp, pols, n_steps=9, progress=False, runs=runs)
    with pytest.raises(ValueError, match="not the evaluation's"):
        evaluate("ungm-ukf", n_steps=7, progress=False, runs=runs)
    with pytest.raises(ValueError, match="runs or the trajectories"):
        evaluate(exp, pols, n_steps=7, progress=False, runs=runs, traj=runs.traj)
