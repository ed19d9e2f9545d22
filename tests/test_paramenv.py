"""The parameter MDP's declared interface (adaptfilt.paramenv): every environment of the suite passes
the conformance check, and the check names what a broken environment gets wrong."""
import numpy as np
import pytest

from adaptfilt.costs import Cost, FunctionCost, ParticleCost, StepCost, logmaxnis_cost, nis_cost
from adaptfilt.experiment_registry import EXPERIMENTS, PARTICLE_EXPERIMENTS, VARIANTS, Experiment, resolve
from adaptfilt.gaf import UKF
from adaptfilt.mdp import FilterEnv
from adaptfilt.models import ungm
from adaptfilt.paramenv import EnvCheckError, ParamEnv, check_env
from adaptfilt.toy import BanditEnv, TrapEnv

ALL = {**EXPERIMENTS, **VARIANTS, **PARTICLE_EXPERIMENTS}


@pytest.mark.parametrize("name", sorted(ALL))
def test_every_registered_experiment_builds_a_conforming_env(name):
    env = ALL[name].make_env(seed=1, n_steps=4)
    assert isinstance(env, ParamEnv)
    check_env(env)
    assert env.describe()["param_name"] == ALL[name].param_name


@pytest.mark.parametrize("make", [lambda: TrapEnv(n_steps=4), lambda: BanditEnv(n_steps=3),
                                  lambda: FilterEnv(UKF(ungm()), [0.0, 2.0, 10.0], cost=None, n_steps=3),
                                  lambda: FilterEnv(UKF(ungm()), [2.0, 5.0], n_steps=3,
                                                    cost=FunctionCost("abs-nis", lambda u, nz: np.abs(u.nis - nz)))],
                         ids=["trap", "bandit", "filter-no-cost", "filter-function-cost"])
def test_toys_and_hand_built_envs_conform(make):
    check_env(make())


class _Wrap:
    """A conforming environment with one thing broken (the tests below override it)."""

    def __init__(self, env):
        self._env = env

    def __getattr__(self, name):
        return getattr(self._env, name)


class _NoDescribe:
    def __init__(self, env):
        self._env = env

    def __getattr__(self, name):
        if name == "describe":
            raise AttributeError(name)
        return getattr(self._env, name)


class _DefaultOffGrid(_Wrap):
    default_index = 99


class _ShortCost(_Wrap):
    def step(self, actions, predict_param=None):
        d, c, done, info = self._env.step(actions, predict_param)
        return d, c[:-1], done, info


class _NeverDone(_Wrap):
    def step(self, actions, predict_param=None):
        d, c, done, info = self._env.step(actions, predict_param)
        return d, c, False, info


class _AcceptsAnything(_Wrap):
    def check_actions(self, actions):
        return np.clip(np.asarray(actions).astype(np.int64), 0, self._env.grid.size - 1)

    def step(self, actions, predict_param=None):
        return self._env.step(self.check_actions(actions), predict_param)


class _Unseeded(_Wrap):
    def reset(self, n_runs=None, rng=None, traj=None, stream=None):
        return self._env.reset(n_runs=n_runs, rng=None, traj=traj, stream=stream)


class _WrongTheta(_Wrap):
    def step(self, actions, predict_param=None):
        d, c, done, info = self._env.step(actions, predict_param)
        return d, c, done, {**info, "theta": info["theta"] + 1}


class _NoFilterInfo(_Wrap):
    def step(self, actions, predict_param=None):
        d, c, done, info = self._env.step(actions, predict_param)
        return d, c, done, {k: v for k, v in info.items() if k != "x_filt"}


class _DescribesAnotherGrid(_Wrap):
    def describe(self, features=None):
        return {**self._env.describe(features), "grid": [0.0]}


@pytest.mark.parametrize("broken, why", [
    (_NoDescribe, "missing member(s) of the ParamEnv interface: describe"),
    (_DefaultOffGrid, "default_index must be an integer index into the grid"),
    (_ShortCost, "step's cost must be a float array of shape (3,)"),
    (_NeverDone, "returned done = False"),
    (_AcceptsAnything, "accepted a wrong shape"),
    (_Unseeded, "an episode must be a function of its seed"),
    (_WrongTheta, "info['theta'] must be grid[actions]"),
    (_DescribesAnotherGrid, "describe()['grid'] = [0.0]"),
    (_NoFilterInfo, "step's info lacks x_filt"),
], ids=lambda v: v.__name__ if isinstance(v, type) else "")
@pytest.mark.parametrize("base", ["trap", "ungm-ukf"])
def test_the_check_names_what_a_broken_env_gets_wrong(broken, why, base):
    env = TrapEnv(n_steps=3) if base == "trap" else EXPERIMENTS[base].make_env(n_steps=3)
    if broken is _Unseeded and base == "trap":
        pytest.skip("the trap is deterministic: an unseeded reset replays it")
    if broken is _NoFilterInfo and base == "trap":
        pytest.skip("a toy does not filter: its info has no update")
    with pytest.raises(EnvCheckError) as e:
        check_env(broken(env))
    assert why in str(e.value)
    assert type(broken(env)).__name__ in str(e.value)  # the message names the environment's class


def test_a_step_after_the_last_is_an_error_for_every_env_kind():
    for env in (TrapEnv(n_steps=1), EXPERIMENTS["ungm-ukf"].make_env(n_steps=1),
                PARTICLE_EXPERIMENTS["ungm-pf-1e-3"].make_env(n_steps=1)):
        env.reset(n_runs=2, rng=0)
        env.step(np.zeros(2, dtype=int))
        with pytest.raises(RuntimeError, match="reset"):
            env.step(np.zeros(2, dtype=int))


def test_resolve_reads_names_experiments_targets_and_envs_one_way():
    t = resolve("ctm-ukf", seed=2, n_steps=5)
    assert t.experiment is EXPERIMENTS["ctm-ukf"] and t.name == "ctm-ukf" and t.env.n_steps == 5
    assert t.features == "paper+circ" and t.label == "ctm-ukf"
    assert resolve(t) is t and resolve(t, n_steps=5) is t  # resolved once, not built again
    env = TrapEnv(n_steps=4)
    own = resolve(env)
    assert own.env is env and own.experiment is None and own.features is None and own.label == "env"
    with pytest.raises(ValueError, match="n_steps=9 for an environment with horizon 4"):
        resolve(env, n_steps=9)
    with pytest.raises(KeyError, match="unknown experiment 'nope'"):
        resolve("nope")
    with pytest.raises(TypeError, match="FilterEnv\), got dict, which lacks check_actions"):
        resolve({"grid": [1.0]})


def test_an_experiment_holds_an_env_factory_not_a_filter_kind():
    e = EXPERIMENTS["ctm-sif-nis"]
    assert not hasattr(e, "filter_kind")
    assert e.envs.param_name == e.param_name == "n_iter" and e.default_value == 10
    pf = PARTICLE_EXPERIMENTS["ctm-pf-1"]
    assert pf.default_value == 1000 and pf.param_name == "n_particles"
    with pytest.raises(TypeError, match="its environment owns its filter"):
        pf.make_filter()
    assert [p.name for p in pf.baselines(fixed=False)] == [
        "default", "kld-x1", "kld-x4", "kld-x16", "kld-x64", "ess-50", "ess-200", "ess-1000", "greedy"]

    class Doubled:  # a new kind of parameter plugs in through a factory of its own
        param_name = "kappa"

        def make_env(self, exp, seed, n_steps, model):
            return FilterEnv(UKF(exp.make_model()), exp.grid, cost=exp.cost, n_steps=n_steps)

        def default_value(self, exp):
            return 2.0

        def baselines(self, exp, grid, fixed):
            return []

    mine = Experiment("mine", "", ungm, Doubled(), (2.0, 4.0), Cost("nis"))
    check_env(mine.make_env(n_steps=3))
    assert resolve(mine).name == "mine"


def test_variants_are_built_by_the_factory_not_patched_onto_an_env():
    """``make_env(truth=...)`` simulates from another model while the filter keeps the experiment's;
    ``make_env(grid=...)`` cuts the grid (the same environment a hand-built FilterEnv on the cut grid is, step
    for step); both carry the experiment's name; the plain environment does not; a value off the grid is named."""
    from adaptfilt.experiment_registry import get_experiment, scaled_truth
    from adaptfilt.mdp import rollout

    exp = get_experiment("ungm-ukf")
    plain = exp.make_env(n_steps=6)
    assert plain.experiment is None and plain.truth is plain.model
    truth = scaled_truth(exp.make_model(), q=4.0)
    env = exp.make_env(n_steps=6, truth=truth)
    check_env(env)
    assert env.truth is truth and env.model.Q.tolist() == [[1.0]] and env.experiment == "ungm-ukf"
    assert resolve(env).name == "ungm-ukf" and resolve(env).experiment is None
    traj = env.truth.simulate(5, 6, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(traj.x, truth.simulate(5, 6, rng=np.random.default_rng(1)).x)

    sif = get_experiment("ctm-sif-nis")
    cut = sif.make_env(seed=3, n_steps=5, grid=[10, 5, 10])
    check_env(cut)
    by_hand = FilterEnv(sif.make_filter(3), [5.0, 10.0], cost=sif.cost, n_steps=5)
    assert cut.grid.tolist() == [5.0, 10.0] and cut.experiment == "ctm-sif-nis"
    assert cut.describe() == by_hand.describe()
    base = [p for p in sif.baselines() if p.name == "default"]
    (a, ca), (b, cb) = (rollout(e, base[0], n_runs=4, rng=np.random.default_rng(2)) for e in (cut, by_hand))
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(ca, cb)
    with pytest.raises(ValueError, match=r"actions must be values of the ctm-sif-nis grid .*not on it: \[4.0\]"):
        sif.make_env(grid=[4, 10])
    pf = PARTICLE_EXPERIMENTS["ungm-pf-1e-4"]
    penv = pf.make_env(n_steps=4, truth=scaled_truth(pf.make_model(), r=2.0), grid=[100, 1000])
    assert penv.grid.tolist() == [100.0, 1000.0] and penv.truth.R.tolist() == [[0.2]] and penv.experiment == pf.name


def test_baselines_are_selected_by_kind():
    from adaptfilt.experiment_registry import get_experiment

    ungm_ = get_experiment("ungm-ukf")
    kinds = {p.name: p.kind for p in ungm_.baselines()}
    assert kinds["default"] == "default" and kinds["ml"] == "ml" and kinds["greedy"] == "greedy"
    assert kinds["fixed-kappa=2"] == "fixed" and kinds["fixed-both-kappa=2"] == "fixed-both"
    fixed = ungm_.baselines(kinds=("fixed",))
    assert [p.name for p in fixed] == [f"fixed-kappa={v:g}" for v in ungm_.grid]
    assert [p.kind for p in PARTICLE_EXPERIMENTS["ctm-pf-1"].baselines(fixed=False, kinds=("kld", "ess"))] == \
        ["kld"] * 4 + ["ess"] * 3


def test_what_a_cost_reads_is_declared():
    """``needs_truth`` is part of :class:`StepCost`: the squared-error costs declare it, and a FunctionCost that
    declares it is handed the truth by a FilterEnv, charging what Cost("sqerr") charges; one that does not
    is called as always."""
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.mdp import rollout

    assert Cost("sqerr").needs_truth and ParticleCost("sqerr").needs_truth
    assert not (Cost("nis").needs_truth or ParticleCost("nis").needs_truth or FunctionCost("f", len).needs_truth)
    sq = FunctionCost("my-sqerr", lambda u, nz, x: ((u.x_filt - x) ** 2).sum(axis=0), needs_truth=True)
    assert isinstance(sq, StepCost)
    exp = get_experiment("ungm-ukf-sqerr")
    mine = FilterEnv(exp.make_filter(), exp.grid, cost=sq, n_steps=8)
    greedy = [p for p in exp.baselines() if p.name == "greedy"][0]
    (r1, c1), (r2, c2) = (rollout(e, greedy, n_runs=5, rng=np.random.default_rng(4)) for e in (mine, exp.make_env(n_steps=8)))
    np.testing.assert_array_equal(c1, c2)
    np.testing.assert_array_equal(r1.params, r2.params)
    with pytest.raises(ValueError, match="'my-sqerr' needs the true state"):
        sq(None, np.zeros(2), 1)


def test_the_costs_share_the_nis_estimates_and_meet_the_protocol():
    nis = np.array([0.0, 1.0, 3.0])
    assert nis_cost(nis, 1).tolist() == [1.0, 0.0, 4.0]
    assert logmaxnis_cost(nis, 1).tolist() == [0.0, 0.0, float(np.log1p(2.0))]

    class U:
        pass

    u = U()
    u.nis = nis
    for kind in ("nis", "logmaxnis"):  # the two families charge one estimate
        assert np.array_equal(Cost(kind)(u, np.zeros(3), 1), ParticleCost(kind)(u, np.zeros(3), 1))
    for c in (Cost("nis"), ParticleCost("sqerr", 1e-3), FunctionCost("x", lambda u, nz: u.nis)):
        assert isinstance(c, StepCost)
    assert FunctionCost("x", lambda u, nz: u.nis, 0.5)(u, np.full(3, 2.0), 1).tolist() == [1.0, 2.0, 4.0]
    with pytest.raises(ValueError, match="unknown cost 'nees'"):
        Cost("nees")
    with pytest.raises(ValueError, match="non-empty name"):
        FunctionCost("", abs)
    with pytest.raises(TypeError, match="cost must be a ParticleCost"):
        PARTICLE_EXPERIMENTS["ctm-pf-1"].envs.make_env(
            Experiment("x", "", ungm, PARTICLE_EXPERIMENTS["ctm-pf-1"].envs, (1000.0,), Cost("nis")), 0, 3, None)
