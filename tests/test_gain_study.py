"""The learned-gain study (``adaptfilt beyond --studies gain``): the squared-error cost of the UKF's MDP, its experiments, and the
study ``gain`` of ``adaptfilt beyond`` at quick scale (every arm x budget x model x regime, KalmanNet paired with
the filters on the same runs, a journaled resume)."""
import json

import numpy as np
import pytest

from adaptfilt.costs import Cost


# ------------------------------------------------------------------ the cost
def test_sqerr_cost_is_the_squared_error_against_the_rollouts_truth():
    """Charged by a FilterEnv, the cost of every step is ||x_filt - x||^2 computed here from the rollout's own
    truth and means; greedy's candidates are charged the same truth (tiled over the grid)."""
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.mdp import rollout
    from adaptfilt.models import Trajectory

    for name in ("ungm-ukf-sqerr", "ctm-ukf-sqerr"):
        exp = get_experiment(name)
        env = exp.make_env(n_steps=12)
        traj = env.truth.simulate(7, 12, rng=np.random.default_rng(3))
        pols = {p.name: p for p in exp.baselines()}
        for pol in (pols["default"], pols["greedy"]):
            run, cost = rollout(env, pol, traj=traj)
            want = ((run.mean - traj.x) ** 2).sum(axis=-1)
            np.testing.assert_allclose(cost, want, rtol=1e-12, atol=1e-12)
        # greedy on the squared error is the one-step oracle: never above the default's one-step cost
        # at the first step (same prior, same measurement)
        _, c_def = rollout(env, pols["default"], traj=traj)
        _, c_gr = rollout(env, pols["greedy"], traj=traj)
        assert (c_gr[:, 0] <= c_def[:, 0] + 1e-9).all()
        # without the truth the cost refuses, naming what is missing
        blind = Trajectory(x=np.full_like(traj.x, np.nan), z=traj.z)
        with pytest.raises(ValueError, match="sqerr.*true state"):
            rollout(env, pols["default"], traj=blind)


def test_sqerr_cost_direct_and_errors():
    from types import SimpleNamespace

    u = SimpleNamespace(x_filt=np.array([[1.0, 2.0, -1.0], [0.0, 1.0, 3.0]]), nis=np.zeros(3))
    truth = np.array([[0.0, 2.0, 1.0], [1.0, 1.0, 0.0]])
    np.testing.assert_array_equal(Cost("sqerr")(u, np.zeros(3), 1, truth=truth), [2.0, 0.0, 13.0])
    assert Cost("sqerr").needs_truth and not Cost("nis").needs_truth and Cost("sqerr").name == "sqerr"
    with pytest.raises(ValueError, match="needs the true state"):
        Cost("sqerr")(u, np.zeros(3), 1)
    with pytest.raises(ValueError, match="run-last"):
        Cost("sqerr")(u, np.zeros(3), 1, truth=truth.T)
    with pytest.raises(ValueError, match="unknown cost"):
        Cost("mse")


def test_existing_costs_are_charged_as_before():
    """The NIS cost through the env equals (NIS - nz)^2 of the rollout's NIS (no truth passed to it)."""
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.mdp import rollout

    exp = get_experiment("ungm-ukf")
    env = exp.make_env(n_steps=10)
    run, cost = rollout(env, exp.baselines()[0], n_runs=5, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(cost, (run.nis - 1) ** 2)


def test_sqerr_experiments_pass_check_env_and_refuse_cand_features():
    from adaptfilt.experiment_registry import VARIANTS, get_experiment
    from adaptfilt.features import FeatureSet
    from adaptfilt.paramenv import check_env

    for name, twin in (("ungm-ukf-sqerr", "ungm-ukf"), ("ctm-ukf-sqerr", "ctm-ukf")):
        e, n = get_experiment(name), get_experiment(twin)
        assert name in VARIANTS and e.grid == n.grid and e.features == n.features and e.cost == Cost("sqerr")
        check_env(e.make_env(n_steps=4))
    env = get_experiment("ungm-ukf-sqerr").make_env(n_steps=4)
    d = env.reset(n_runs=3, rng=0)
    with pytest.raises(ValueError, match="true state"):
        d.observe(FeatureSet.parse("paper+cand"))


# ------------------------------------------------------------------ KalmanNet snapshots
def test_kalmannet_snapshot_is_the_shorter_training():
    import adaptfilt as af
    from adaptfilt.kalmannet import train_kalmannet

    model = af.models.linear_gaussian(F=[[0.9]], H=[[1.0]], Q=[[1.0]], R=[[1.0]], m0=[0.0], P0=[[1.0]])
    kw = dict(n_train=8, n_val=4, n_steps=10, batch_size=4, seed=3, progress=False)
    long = train_kalmannet(model, epochs=3, snapshots=(1, 2), **kw)
    short = train_kalmannet(model, epochs=2, **kw)
    snap = long.snapshot(2)
    for a, b in zip(snap.net.parameters(), short.net.parameters()):
        np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy())
    assert snap.history["val_loss"] == short.history["val_loss"] and snap.history["epochs"] == 2
    assert snap.history["cpu_s"] <= long.history["cpu_s"]
    with pytest.raises(ValueError, match="no snapshot at epoch 3"):
        long.snapshot(3)
    with pytest.raises(ValueError, match="snapshots must be epochs"):
        train_kalmannet(model, epochs=2, snapshots=(3,), **kw)


# ------------------------------------------------------------------ the quick study
@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    from adaptfilt.experiments.beyond import run

    root = tmp_path_factory.mktemp("gain")
    summary = run(root, quick=True, workers=1, studies=("gain",), progress=False)
    return root, summary


def test_quick_gain_study_has_every_arm_budget_model_and_regime(quick):
    """Every arm of :func:`arms_of` at each of its budgets under the nominal model, the mismatched truths with the
    arms trained on them, the references, the verdicts of every pair at every budget, where each arm stops
    improving; each file listed in the manifest with the one ``adaptfilt train``/``train-gain`` line of its
    training (one training per arm and seed, kept at its budgets)."""
    from adaptfilt.experiments.beyond import summary_md
    from adaptfilt.experiments.reproduce import sha256
    from adaptfilt.experiments.studies.gain import (ARM_NAMES, CARRIED, MODEL_REGIMES, MODELS, PAIRS, QUICK,
                                                    arms_of, evaluated, policy_rel)
    from adaptfilt.files import read_npz

    root, summary = quick
    g = summary["gain"]
    assert set(g["models"]) == set(MODELS)
    for e in MODELS:
        assert set(g["models"][e]) == set(MODEL_REGIMES[e])
        for r in MODEL_REGIMES[e]:
            m = g["models"][e][r]
            want = evaluated(e, r)
            assert set(m["curve"]) == set(want)
            for a, (kind, bs) in want.items():
                assert set(m["curve"][a]) == {str(b) for b in bs}
                for b, row in m["curve"][a].items():
                    assert row["rmse"]["n_seeds"] == len(QUICK.seeds)
                    assert all(c is not None and c > 0 for c in row["train_cpu_s"])
                    if kind == "gain":  # plain KalmanNet: no covariance, no NIS cost, said so; restarts counted
                        assert row["anees"] is None and row["cost"] is None and row["covariance"] is False
                        assert len(row["restarts"]) == len(QUICK.seeds) and row["failed"] == sum(
                            bool(read_npz(root / "beyond" / policy_rel(e, a, int(b), s))[1]["history"]["failed"])
                            for s in QUICK.seeds)  # a failed training (an untrained network kept) is counted
                        assert row["unit"] == "optimiser steps"
                    else:
                        assert row["anees"]["n_seeds"] == len(QUICK.seeds) and row["unit"] == "episodes"
            assert {"default", "best fixed", "ml", "greedy", f"bpf-{QUICK.pf_particles[e]}"} <= set(m["references"])
            assert (m["floor"]["rmse"] is not None) == (e == "ungm-ukf")
            if r == "nominal":
                assert set(m["final"]) == set(evaluated(e, r, final=True))
                assert set(m["stops_improving"]) == {a for a, s in arms_of(e).items() if s["truth"] is None}
                pairs = {(v["a"], v["b"].split(" (")[0], v["budget"]) for v in m["verdicts"]}
                for a, b, _ in PAIRS:
                    both = set(arms_of(e)[a]["budgets"]) & (set(arms_of(e)[b]["budgets"]) if b in ARM_NAMES
                                                            else set(arms_of(e)[a]["budgets"]))
                    assert all((a, b, x) in pairs for x in both), (a, b)
                for a, b in CARRIED:  # past the kappa's top budget the gain is judged against that top, named
                    ta, tb = arms_of(e)[a]["top"], arms_of(e)[b]["top"]
                    assert ta > tb
                    past = [v for v in m["verdicts"] if (v["a"], v["b"]) == (a, b) and v["budget"] > tb]
                    assert {v["budget"] for v in past} == set(range(tb + 1, ta + 1))
                    assert all(v["budget_b"] == tb and v["lower"] is not None for v in past)
                    assert [v["budget_b"] for v in m["final_verdicts"] if (v["a"], v["b"]) == (a, b)] == [tb]
            else:  # the arms trained on this truth, judged against the same learner trained on the model
                on = [a for a in m["curve"] if "-on-" in a]
                assert bool(on) == (e == "ungm-ukf")
                assert all(any(v["a"] == a and v["b"] == a.split("-on-")[0] for v in m["verdicts"]) for a in on)
    man = json.loads((root / "beyond" / "manifest.json").read_text())
    cmds = {}
    for f in man["files"]:
        assert sha256(root / "beyond" / f["path"]) == f["sha256"] and f["command"]
        cmds[f["path"]] = f["command"]
    k = cmds["policies/gain-ungm-ukf-gain-sup-b3-s1.npz"]
    assert k.startswith("adaptfilt train-gain ungm-ukf --arch kalmannet-arch1 ") and "--snapshot-steps 2,4,6,8,10,12" in k
    assert k == cmds["policies/gain-ungm-ukf-gain-sup-b5-s1.npz"]  # one training, a file per budget
    p = cmds["policies/gain-ungm-ukf-kappa-sqerr-b2-s0.npz"]
    assert p.startswith("adaptfilt train ungm-ukf-sqerr --algo fast ") and "--snapshots 20,45,70,95,120" in p
    assert "--truth q=1,r=1,forcing=10" in cmds["policies/gain-ungm-ukf-gain-sup-on-forcing10-b3-s0.npz"]
    for fig in ("gain-budget.png", "gain-mismatch.png"):
        assert (root / "beyond" / "figures" / fig).stat().st_size > 1000
    md = summary_md(summary, ("gain",))
    assert "| ungm-ukf | q4 | gain-sup-on-q4 b3" in md and "what is learned" in md and "stops improving" in md
    from adaptfilt.experiments.studies.gain import top

    for e, where in (("ungm-ukf", "nominal"), ("ctm-ukf", "nominal, final")):  # the carried pair at the tops
        assert f"| {e} | {where} | gain-sup b{top(e, 'gain-sup')} | kappa-sqerr b{top(e, 'kappa-sqerr')} |" in md


def test_kalmannet_entries_are_paired_with_the_filters_on_the_same_runs(quick):
    """The stored evaluation's default is a direct UKF run on the trajectories the study's KalmanNet entries
    were computed on, run for run (under the nominal model and a truth whose forcing differs); and the KalmanNet
    entry is the file's filter on those runs."""
    import adaptfilt as af
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.studies.gain import QUICK, _env, evaluate_part, policy_rel
    from adaptfilt.kalmannet import load_kalmannet
    from adaptfilt.results import Results
    from adaptfilt.runs import TRAJ_SEED_KEY

    root, _ = quick
    e = "ungm-ukf"
    for regime in ("nominal", "forcing10"):
        env = _env(e, regime, QUICK)
        traj = env.truth.simulate(QUICK.curve_runs, env.n_steps, rng=np.random.default_rng([TRAJ_SEED_KEY, 0]))
        f = str(root / "beyond" / policy_rel(e, "gain-sup", 3, 0))
        ukf_part = evaluate_part(e, regime, "ukf", {}, QUICK)
        gain_part = evaluate_part(e, regime, "gain", {"gain-sup-b3-s0": f}, QUICK)
        run = af.UKF(get_experiment(e).make_model()).run(traj.z)
        direct = np.sqrt(((run.mean - traj.x) ** 2).sum(-1).mean(axis=1))
        np.testing.assert_allclose(ukf_part["default"].run_rmse, direct, rtol=1e-12)
        knet = load_kalmannet(f, env.model).run(traj.z)
        want = np.sqrt(((knet.mean - traj.x) ** 2).sum(-1).mean(axis=1))
        np.testing.assert_array_equal(gain_part["gain-sup-b3-s0"].run_rmse, want)
        both = Results.merge([ukf_part, gain_part])
        d, lo, hi = both.paired_difference("gain-sup-b3-s0", "default", "rmse")
        assert lo <= d <= hi and np.isnan(both["gain-sup-b3-s0"].anees)


def test_quick_gain_study_resumes_from_its_journal(quick, tmp_path, monkeypatch):
    """In a copy of the quick run's folder (its policies listed in the manifest: nothing is trained again),
    stopped after its fourth evaluation, the run again takes those four from the journal and ends with the
    same numbers."""
    import shutil

    from adaptfilt.experiments.beyond import run
    from adaptfilt.experiments.journal import Journal

    root, reference = quick
    shutil.copytree(root / "beyond", tmp_path / "beyond")
    add = Journal.add
    done = []

    def add_then_stop(self, *a, **kw):
        rec = add(self, *a, **kw)
        done.append(a[0])
        if len(done) == 4:
            raise KeyboardInterrupt
        return rec

    monkeypatch.setattr(Journal, "add", add_then_stop)
    with pytest.raises(BaseException):
        run(tmp_path, quick=True, workers=1, studies=("gain",), progress=False)
    assert len(done) == 4 and (tmp_path / "beyond" / "journal.jsonl").exists()
    assert not [k for k in done if "adaptfilt train" in k]  # every training listed in the manifest: reused
    ran = []

    def record(self, *a, **kw):
        ran.append(a[0])
        return add(self, *a, **kw)

    monkeypatch.setattr(Journal, "add", record)
    summary = run(tmp_path, quick=True, workers=1, studies=("gain",), progress=False)
    assert ran and not set(done) & set(ran)  # the four finished jobs were taken from the journal
    assert not (tmp_path / "beyond" / "journal.jsonl").exists()
    g, h = summary["gain"]["models"], reference["gain"]["models"]
    for e in g:  # same runs, same policies: the same numbers
        for r in g[e]:
            assert g[e][r]["verdicts"] == h[e][r]["verdicts"]
            for a in g[e][r]["curve"]:
                for b, row in g[e][r]["curve"][a].items():  # all but the measured microseconds per step
                    assert {k: v for k, v in row.items() if k != "us_per_step"} == \
                        {k: v for k, v in h[e][r]["curve"][a][b].items() if k != "us_per_step"}


def test_the_full_scale_waits_for_its_tuning_and_calibration(tmp_path, capsys, monkeypatch):
    """While a tuning or calibration is pending, ``adaptfilt beyond --studies gain`` at full scale stops before
    any work with one line naming what is pending; the quick scale runs (the test suite's)."""
    from adaptfilt.cli import main
    from adaptfilt.experiments.studies import gain

    monkeypatch.setattr(gain, "PENDING", ("the CTM's tuning (a stand-in)",))
    with pytest.raises(SystemExit) as e:
        main(["beyond", "--out", str(tmp_path), "--studies", "gain", "--no-progress"])
    err = capsys.readouterr().err.splitlines()
    assert e.value.code == 2 and len(err) == 1 and "waits for its tuning and calibration" in err[0], err
    assert not list((tmp_path / "beyond" / "policies").glob("*.npz")) if (tmp_path / "beyond").exists() else True


def test_kappa_and_kalmannet_trainings_are_the_commands_the_study_records(tmp_path):
    """Each training of the study (quick scale) read back from its command line is the same spec: the recipe,
    the snapshots at every budget, the truth, written out in full."""
    import shlex
    from pathlib import Path

    from adaptfilt.cli import _train_spec, build_parser, gain_spec
    from adaptfilt.experiments.jobs import GainSpec
    from adaptfilt.experiments.study import QUICK as BEYOND_QUICK
    from adaptfilt.experiments.study import Run
    from adaptfilt.experiments.studies.gain import policies

    run = Run(Path(tmp_path) / "beyond", Path(tmp_path), BEYOND_QUICK, True, "", journal=None)
    specs = policies(run, {})
    assert {type(s).__name__ for s in specs} == {"TrainSpec", "GainSpec"}
    for spec in specs:
        args = build_parser().parse_args(shlex.split(spec.command)[1:])
        back = gain_spec(args) if isinstance(spec, GainSpec) else _train_spec(args, args.seed, tuple(args.out)
                                                                               if spec.snapshots else args.out[0])
        assert back.command == spec.command


def test_nll_cost_adds_the_gaussian_log_score_and_is_smallest_at_the_true_covariance():
    """||e||^2 + w (e' P^-1 e + log det P) per run, checked against a direct computation on a 2-D case; its
    expectation over errors of covariance C, with P = c C, is smallest at c = 1 (a proper score), where a
    penalty (NEES - nx)^2 would prefer a larger covariance."""
    from types import SimpleNamespace

    from adaptfilt.costs import gaussian_nll

    rng = np.random.default_rng(0)
    A = rng.standard_normal((2, 2))
    C = A @ A.T + np.eye(2)
    e = rng.multivariate_normal(np.zeros(2), C, size=20000).T  # (nx, M)
    P = np.repeat(C[:, :, None], e.shape[1], axis=2)
    u = SimpleNamespace(x_filt=e, P_filt=P, nis=np.zeros(e.shape[1]))
    got = Cost("sqerr", nll_weight=0.5)(u, np.zeros(e.shape[1]), 1, truth=np.zeros_like(e))
    want = (e * e).sum(0) + 0.5 * (np.einsum("im,ij,jm->m", e, np.linalg.inv(C), e) + np.log(np.linalg.det(C)))
    np.testing.assert_allclose(got, want, rtol=1e-10)
    score = {c: gaussian_nll(e, c * P).mean() for c in (0.5, 0.8, 1.0, 1.25, 2.0)}
    assert min(score, key=score.get) == 1.0
    nees_sq = {c: ((np.einsum("im,ij,jm->m", e, np.linalg.inv(c * C), e) - 2) ** 2).mean() for c in score}
    assert min(nees_sq, key=nees_sq.get) == 2.0
    assert Cost("sqerr", nll_weight=0.1).name == "sqerr+0.1*nll"
    with pytest.raises(ValueError, match="needs kind='sqerr'"):
        Cost("nis", nll_weight=1.0)
    bad = np.repeat(np.array([[1.0, 0.0], [0.0, -1.0]])[:, :, None], 3, axis=2)
    with pytest.raises(ValueError, match="positive definite covariance: run 0"):
        gaussian_nll(np.zeros((2, 3)), bad)


def test_nll_experiments_are_the_sqerr_experiment_with_the_term():
    from adaptfilt.experiment_registry import NLL_WEIGHTS, get_experiment

    base = get_experiment("ungm-ukf-sqerr")
    for w in NLL_WEIGHTS:
        e = get_experiment(f"ungm-ukf-sqerr-nll{w:g}")
        assert e.cost == Cost("sqerr", nll_weight=w) and e.grid == base.grid and e.features == base.features


def test_ungm_forcing_changes_only_the_forcing_term():
    import adaptfilt as af

    m, t = af.models.ungm(), af.models.ungm(forcing=10.0)
    x = np.linspace(-20, 20, 9)[:, None]
    for k in (1, 17, 300):
        np.testing.assert_allclose(t.f(x, k) - m.f(x, k), np.full_like(x, 2.0 * np.cos(0.05 * k)), rtol=1e-12)
    assert m.name == t.name and "forcing 10" in t.description and "forcing" not in m.description
    np.testing.assert_array_equal(af.models.ungm(forcing=8.0).f(x, 5), m.f(x, 5))


def test_kalmannet_trains_on_a_truths_trajectories_and_keeps_the_model():
    """``truth=``: training and validation trajectories come from the truth (here the process noise x 100: the
    validation loss of the untrained filter differs from the model's), the filter keeps the model's f and h."""
    import dataclasses

    import adaptfilt as af
    from adaptfilt.kalmannet import train_kalmannet

    model = af.models.linear_gaussian(F=[[0.9]], H=[[1.0]], Q=[[1.0]], R=[[1.0]], m0=[0.0], P0=[[1.0]])
    truth = dataclasses.replace(model, Q=model.Q * 100, description="lin, Q x 100")
    kw = dict(n_train=8, n_val=4, n_steps=10, batch_size=4, seed=3, progress=False, epochs=1)
    a = train_kalmannet(model, **kw)
    b = train_kalmannet(model, truth=truth, **kw)
    assert b.history["truth"] == "lin, Q x 100" and "truth" not in a.history
    assert b.history["val_loss"][0] > 10 * a.history["val_loss"][0]
    assert b.model is model
    with pytest.raises(ValueError, match="truth must be a StateSpaceModel with the model's dimensions"):
        train_kalmannet(model, truth=af.models.coordinated_turn(), **kw)


def test_the_full_scale_is_sized_to_twenty_two_hours_of_one_worker_and_its_units_meet_the_targets():
    """The full scale's work units give each budget its target CPU-s by the calibration (within 10 %, or one
    rollout / 25 optimiser steps at the smallest budgets), and the whole run, trainings and evaluations, is
    estimated at no more than 22 hours of one worker (the first run's 5 and the supervised gain's extensions)."""
    from adaptfilt.experiments.studies.gain import CALIBRATION, FULL, TARGET_CPU_S, estimate

    for e, eps in FULL.kappa_episodes.items():
        c = CALIBRATION["kappa"][e]
        for t, n in zip(TARGET_CPU_S[e], eps):
            assert abs(c["setup_cpu_s"] + n * c["cpu_s_per_episode"] - t) <= max(0.1 * t, 10 * c["cpu_s_per_episode"])
    for (e, arch), steps in FULL.knet_steps.items():
        rate = CALIBRATION["knet"][(e, arch)]["cpu_s_per_step"]
        for t, n in zip(TARGET_CPU_S[e], steps):
            assert n % 25 == 0 and abs(n * rate - t) <= max(0.1 * t, 12.5 * rate)
    size = estimate()
    assert size["hours_one_worker"] <= 22.0 and size["total_cpu_s"] == sum(
        v["train_cpu_s"] + v["eval_cpu_s"] for k, v in size.items() if isinstance(v, dict))


def test_report_only_judges_the_quick_studys_verdicts_again_from_its_evaluations(quick, tmp_path):
    """``adaptfilt beyond --report-only`` on a copy of the quick run: a stale verdict word and a stale "stops
    improving" are judged again from the stored evaluations, giving back the run's own summary."""
    import shutil

    from adaptfilt.experiments.beyond import report_only

    root, reference = quick
    shutil.copytree(root / "beyond", tmp_path / "beyond")
    stale = json.loads((tmp_path / "beyond" / "summary.json").read_text())
    m = stale["gain"]["models"]["ungm-ukf"]["nominal"]
    m["verdicts"][0]["lower"] = "stale"
    m["stops_improving"]["gain-sup"]["stops_at"] = 99
    (tmp_path / "beyond" / "summary.json").write_text(json.dumps(stale, indent=1) + "\n")
    out = report_only(tmp_path, progress=False)
    assert out["gain"] == json.loads(json.dumps(reference["gain"]))
