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
