"""The helpers of the learning chapters (adaptfilt.course.training, .policy_reading, .seed_results,
.beyond_studies: chapters 6-8 and 12-15), against direct computations."""
import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest

from adaptfilt.course import beyond_studies, policy_reading, seed_results, training
from adaptfilt.evaluation import evaluate
from adaptfilt.experiment_registry import get_experiment
from adaptfilt import seed_stats as sd
from adaptfilt import verdicts
from adaptfilt.features import FeatureSet, fit_scaler, observe, visited_states
from adaptfilt.policies import FixedPolicy, GreedyPolicy, default_policy


@pytest.fixture(scope="module")
def ungm_results():
    """A tiny UNGM evaluation with two seed groups of fixed policies standing in for learned ones."""
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=20)
    g = exp.grid
    pols = [default_policy(2.0, grid=g), FixedPolicy(200, "kappa", grid=g), GreedyPolicy(grid=g)]
    pols += [FixedPolicy(v, "kappa", grid=g, name=f"a-s{i}") for i, v in enumerate((1.0, 5.0, 20.0, 1000.0))]
    pols += [FixedPolicy(v, "kappa", grid=g, name=f"b-s{i}") for i, v in enumerate((2.0, 10.0, 500.0))]
    return evaluate(env, pols, n_runs=60, seed=1, progress=False, n_boot=200)


class SigmoidPolicy:
    """pi(large kappa | s) = sigmoid(|innovation| - c): a policy with a known switch."""

    def __init__(self, c: float, name: str, grid=(1.0, 1000.0)):
        self.c, self.name, self.grid = c, name, np.asarray(grid)

    def probs(self, s):
        p = 1.0 / (1.0 + np.exp(-(np.abs(s[:, 4]) - self.c)))
        return np.stack([1.0 - p, p], axis=1)


def test_ungm_state_is_the_environments_information_state():
    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=30)
    d = env.reset(n_runs=4, rng=np.random.default_rng(3))
    for _ in range(17):
        d, *_ = env.step(np.full(4, d.default_index))
    f = observe(d, exp.features)
    for i in range(4):
        mine = policy_reading.ungm_state(P_pred=f[i, 1], innov=f[i, 4], x_pred=f[i, 0], k=d.t + 1)
        assert np.allclose(mine, f[i], rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match="P_pred"):
        policy_reading.ungm_state(0.0, 1.0)


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


def test_usage_lines_and_share_over_time(ungm_results):
    lines = policy_reading.usage_lines(ungm_results, ["fixed-kappa=200", "a-s0"], split=50).splitlines()
    assert "50 or less:   0%" in lines[0] and "200: 100%" in lines[0]
    assert "50 or less: 100%" in lines[1] and "1: 100%" in lines[1]
    fig = policy_reading.plot_share_over_time(ungm_results, ["a", "fixed-kappa=200"], 100)
    y_group, y_fixed = (line.get_ydata() for line in fig.axes[0].get_lines()[:2])
    assert np.allclose(y_group, 0.25) and np.allclose(y_fixed, 1.0)   # one of four seeds at 1000


def test_switch_off_curves_follow_the_policy():
    rng = np.random.default_rng(0)
    states = rng.normal(size=(4000, 7)) * np.array([1, 1, 1, 1, 3, 1, 1])
    pols = [SigmoidPolicy(1.0, "early"), SigmoidPolicy(3.0, "late")]
    fig = policy_reading.plot_switch_off(pols, states, {"innovation": 4}, at_least=100, n_bins=8)
    early, late = (line.get_ydata() for line in fig.axes[0].get_lines())
    assert np.all(np.diff(early) > 0) and np.all(early > late)
    x = np.abs(states[:, 4])
    top = x >= np.quantile(x, 7 / 8)
    assert np.isclose(early[-1], pols[0].probs(states)[top, 1].mean(), atol=1e-3)


def test_policy_probs_heat_map():
    pols = [SigmoidPolicy(1.0, "a"), SigmoidPolicy(8.0, "b")]
    s = policy_reading.ungm_state(1.0, 4.0)
    fig = policy_reading.plot_policy_probs(pols, s)
    ax = fig.axes[0]
    img = ax.get_images()[0].get_array()
    assert np.allclose(img, np.concatenate([p.probs(s) for p in pols]))
    assert list(ax.get_lines()[0].get_xdata()) == [1, 0]      # argmax: large kappa for "a", small for "b"


def test_seed_lines_and_verdicts(ungm_results):
    text = seed_results.seed_lines(ungm_results, ["a", "b"], ["default"], metrics=("rmse",))
    agg = sd.aggregate(ungm_results, sd.seed_groups(ungm_results.names)["a"], "rmse")
    assert f"rmse {agg.iqm:.3g} [{agg.iqm_ci[0]:.3g}, {agg.iqm_ci[1]:.3g}]" in text.splitlines()[1]
    assert text.splitlines()[1].startswith("a (4 seeds)")
    v = seed_results.seed_verdicts(ungm_results, "a", "fixed-kappa=200", "rmse")
    assert sum(v["counts"].values()) == 4
    for n, (d, lo, hi, verdict) in v["per_seed"].items():
        assert (d, lo, hi) == ungm_results.paired_difference(n, "fixed-kappa=200", "rmse")
        assert verdict == verdicts.verdict("lower", (lo, hi))
    m = verdicts.margin("adaptive vs best fixed", "rmse", ungm_results["fixed-kappa=200"].rmse)
    eq = seed_results.seed_verdicts(ungm_results, "a", "fixed-kappa=200", "rmse", "equal", m)["per_seed"]
    assert all(v[3] == verdicts.verdict("equal", v[1:3], m) for v in eq.values())
    with pytest.raises(ValueError, match="'equal' claim needs a declared margin"):
        seed_results.seed_verdicts(ungm_results, "a", "fixed-kappa=200", "rmse", "equal")


def test_claims_table_keeps_rows_with_per_seed_counts():
    claims = {"C2": [
        {"experiment": "e", "claim": "adaptive lower than ml", "metric": "rmse", "diff": 0.5, "ci": [0.1, 0.9],
         "verdict": "contradicted", "seeds_holding": 0, "n_seeds": 8},
        {"experiment": "e", "claim": "adaptive lower than myopic", "metric": "rmse", "diff": 0.1, "ci": [-0.1, 0.3],
         "verdict": "not confirmed", "seeds_holding": None, "n_seeds": 8},
        {"experiment": "other", "claim": "adaptive lower than ml", "metric": "rmse", "diff": 0.5, "ci": [0.1, 0.9],
         "verdict": "contradicted", "seeds_holding": 3, "n_seeds": 8}]}
    rows = seed_results.claims_table(claims, "e").strip().splitlines()[2:]
    assert len(rows) == 1 and "0/8" in rows[0] and "contradicted" in rows[0]
    assert len(seed_results.claims_table(claims, "e", only_held=False).strip().splitlines()) == 4


def test_claims_table_shows_the_margin_of_an_equal_claim():
    claims = {"C2": [{"experiment": "e", "claim": "adaptive equal than fixed", "metric": "rmse", "diff": -0.2,
                      "ci": [-0.24, -0.15], "verdict": "not confirmed", "seeds_holding": 2, "n_seeds": 8,
                      "margin": 0.154, "declared": "adaptive vs best fixed"}]}
    row = seed_results.claims_table(claims, "e").strip().splitlines()[2]
    assert "adaptive equal to fixed" in row and "not confirmed (margin 0.154)" in row and "2/8" in row


def test_seed_spread_and_differences_figures(ungm_results):
    fig = seed_results.plot_seed_spread(ungm_results, ["a", "b"], "rmse")
    labels = [t.get_text() for t in fig.axes[0].get_yticklabels()]
    assert labels[:4] == ["a-s0", "a-s1", "a-s2", "a-s3"] and "a: IQM of 4" in labels and "b: mean of 3" in labels
    fig = seed_results.plot_differences({"c1": {"x": (1.0, 0.5, 1.5)}, "c2": {"x": (-1.0, -2.0, 0.0), "y": (0.0, -1, 1)}})
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["c1", "c2"]


def test_timed_returns_the_result():
    out, cpu = seed_results.timed(sum, [1, 2, 3])
    assert out == 6 and cpu >= 0.0


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


def test_chapter_11_helpers(ungm_results):
    res = ungm_results
    text = beyond_studies.verdict_counts(res, "a", "greedy", ("cost", "rmse"))
    lines = text.splitlines()
    assert len(lines) == 2 and lines[0].startswith("a - greedy  cost")
    d = sd.difference(res, sd.seed_groups(res.names)["a"], ["greedy"], "rmse")["iqm"]
    assert f"{d[0]:+.4g} [{d[1]:+.4g}, {d[2]:+.4g}]" in lines[1]
    counts = seed_results.seed_verdicts(res, "a", "greedy", "rmse")["counts"]
    assert sum(counts.values()) == 4 and all(f"{n} {v}" in lines[1] for v, n in counts.items())
    fig = beyond_studies.plot_cost_divergence(res, ["a", "b"], title="x")
    ax = fig.axes[0]
    fixed = [n for n in res.names if n.startswith("fixed-")]
    line = next(ln for ln in ax.lines if ln.get_label() == "fixed $n_{it}$")
    rel = 100 * (res[fixed[0]].cost_charged / res["default"].cost_charged - 1)
    assert len(line.get_xdata()) == len(fixed) and ax.get_yscale() == "symlog"
    assert line.get_xdata()[0] == pytest.approx(np.clip(rel, *ax.get_xlim()))
    texts = {t.get_text() for t in ax.get_legend().get_texts()}
    assert texts >= {"greedy", "a (4 seeds)", "b (3 seeds)"} and any(t.startswith("default") for t in texts)
    # the legend sits off the axes, and every panel of several has the same x range
    assert ax.get_legend().get_bbox_to_anchor().x0 > ax.get_window_extent().x1 - 1
    fig = beyond_studies.plot_cost_divergence(res, ["a"], xlim=(-5.0, 5.0), legend=None)
    assert fig.axes[0].get_xlim() == (-5.0, 5.0) and fig.axes[0].get_legend() is None
    # crowded n_it labels are all drawn (none dropped) and no two of them overlap
    fig = beyond_studies.plot_cost_divergence(res, ["a"], xlim=(-1e4, 1e4), legend=None)
    ax = fig.axes[0]
    fig.canvas.draw()
    labels = [t for t in ax.texts if t.get_text() in {n.split("=")[1] for n in fixed}]
    shown = [n for n in fixed if -1e4 <= 100 * (res[n].cost_charged / res["default"].cost_charged - 1) <= 1e4]
    assert len(labels) == len(shown)
    boxes = [t.get_window_extent() for t in labels]
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
    table = {"q1-r1": {"greedy": {"gain": 0.2}, "learned": {"gain": -0.1}}, "q4-r0.25": {"greedy": {"gain": 0.4}}}
    fig = beyond_studies.plot_ood_gains(table, "objective", columns=("greedy", "learned"))
    im = fig.axes[0].images[0]
    assert im.norm.vmax == pytest.approx(0.4) and fig.axes[1].images[0].norm.vmin == pytest.approx(-0.4)
    G = np.asarray(im.get_array())
    assert G[1, 1] == pytest.approx(0.2) and G[2, 0] == pytest.approx(0.4) and np.isnan(G[0, 0])


def test_divergence_onsets_use_the_librarys_one_definition():
    from adaptfilt.metrics import DIVERGED_NEES, divergence_step, divergent

    env = get_experiment("ctm-sif-logmaxnis").make_env(seed=0, n_steps=40)
    out = beyond_studies.divergence_onsets(env, 1.0, n_runs=400, seed=3)
    N, onset, div = out["nees"], out["onset"], out["divergent"]
    assert N.shape == (40, 400) and onset.shape == div.shape == (400,)
    np.testing.assert_array_equal(div, divergent(N.T, env.model.nx))
    np.testing.assert_array_equal(onset, divergence_step(N.T, env.model.nx))
    # the onset is the first step at which the running time average crosses DIVERGED_NEES * nx
    running = np.cumsum(np.where(np.isfinite(N), N, np.inf), axis=0) / np.arange(1, 41)[:, None]
    for m in np.flatnonzero(onset >= 0)[:20]:
        assert not running[onset[m], m] <= DIVERGED_NEES * env.model.nx
        assert (running[: onset[m], m] <= DIVERGED_NEES * env.model.nx).all()
    assert (onset[div] >= 0).all()
    # the same runs with ten iterations: no more divergent runs (the SIF with one iteration is the fragile one)
    ten = beyond_studies.divergence_onsets(env, 10.0, n_runs=400, seed=3)
    assert ten["divergent"].sum() <= div.sum()
    with pytest.raises(ValueError, match="not on the grid"):
        beyond_studies.divergence_onsets(env, 4.0, n_runs=2)


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


def test_seed_differences_show_every_seed_and_cut_at_the_edge(ungm_results):
    res = ungm_results
    fig = beyond_studies.plot_seed_differences(res, ["a", "b"], "greedy", ("rmse", "cost"), xlim={"cost": (-0.1, 0.1)})
    ax_rmse, ax_cost = fig.axes
    labels = [t.get_text() for t in ax_rmse.get_yticklabels()]
    assert labels[:4] == ["a-s0", "a-s1", "a-s2", "a-s3"] and "a: IQM of 4" in labels and "b: mean of 3" in labels
    # without xlim the range holds every interval and 0; with one, what lies beyond is written at the edge
    lo, hi = ax_rmse.get_xlim()
    d = res.paired_difference("a-s3", "greedy", "rmse")
    assert lo <= min(d[1], 0.0) and hi >= max(d[2], 0.0)
    assert ax_cost.get_xlim() == (-0.1, 0.1)
    big = res.paired_difference("a-s3", "greedy", "cost")[0]
    assert abs(big) > 0.1 and any(f"{big:+.3g}" in t.get_text() for t in ax_cost.texts)


# ------------------------------------------------- chapter 6: the policy gradient derived on toys
def test_exact_policy_gradient_is_the_finite_difference_of_the_expected_cost():
    from adaptfilt.course import policy_gradient as pg

    rng = np.random.default_rng(0)
    for K in (2, 3, 5):
        theta, c = rng.standard_normal(K), rng.standard_normal(K) * 3
        J = lambda th: pg.softmax(th) @ c
        fd = np.array([(J(theta + 1e-6 * e) - J(theta - 1e-6 * e)) / 2e-6 for e in np.eye(K)])
        assert np.allclose(pg.exact_gradient(theta, c), fd, atol=1e-8)


def test_reinforce_is_unbiased_for_every_baseline_and_the_value_baseline_shrinks_it():
    """The mean of many estimates lies within 4 standard errors of the exact gradient, whatever the
    baseline; the baseline at the expected cost has a smaller spread than none, a far one a larger."""
    from adaptfilt.course import policy_gradient as pg

    theta, c = np.array([0.3, -0.2, 0.5]), np.array([1.0, 0.0, 2.0])
    J = pg.softmax(theta) @ c
    sd = {}
    for b in (0.0, J, 5.0):
        s = pg.estimator_spread(theta, c, n=8, repeats=3000, seed=1, baseline=b)
        assert np.all(np.abs(s["mean"] - s["exact"]) < 4 * s["sd"] / np.sqrt(3000) + 1e-12), b
        sd[b] = s["sd"].sum()
    assert sd[J] < sd[0.0] < sd[5.0]
    with pytest.raises(ValueError, match="one length"):
        pg.score_function_estimate(theta, np.array([0, 1]), np.array([1.0]))


def test_trap_values_solve_the_bellman_equations_and_the_td_error_is_the_advantage():
    """trap_values against policy evaluation by iteration; one step of TrapEnv with that exact critic
    gives TD errors equal to the advantages, for several discounts and policies."""
    from adaptfilt.course import policy_gradient as pg
    from adaptfilt.toy import TrapEnv

    for gamma, p in ((0.5, 0.5), (0.9, 0.2), (0.0, 0.7), (0.3, 1.0)):
        v_good, v_bad = 0.0, 0.0
        for _ in range(2000):  # iterative policy evaluation, an independent computation
            v_good, v_bad = (p * (0.25 + gamma * v_good) + (1 - p) * (0.0 + gamma * v_bad), 1.0 + gamma * v_bad)
        v = pg.trap_values(gamma, p)
        assert np.isclose(v["V_good"], v_good) and np.isclose(v["V_bad"], v_bad)
        assert np.isclose(p * v["Q_safe"] + (1 - p) * v["Q_trap"], v["V_good"])
        td = pg.trap_td_errors(TrapEnv(), gamma, p, n_runs=200, seed=3)
        for a, name in ((0, "trap"), (1, "safe")):
            assert np.allclose(td["delta"][td["actions"] == a], v[f"A_{name}"])
    with pytest.raises(ValueError, match="gamma"):
        pg.trap_values(1.0, 0.5)


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
