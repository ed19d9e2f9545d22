r"""The parameter-adaptation MDP in the RL ecosystem: Gymnasium and Stable-Baselines3.

Needs the optional extra ``rl`` (``pip install -e ".[rl]"``: gymnasium,
stable-baselines3). Three front doors onto the same batched
:class:`~adaptfilt.mdp.FilterEnv`:

* :class:`FilterVectorEnv` -- a ``gymnasium.vector.VectorEnv``: one filter,
  ``num_envs`` Monte-Carlo runs stepping together (each sub-environment is a
  run). All runs end together at the horizon ``T``, which is a time limit
  (``truncated``), never a terminal state; the environment then resets itself
  in the same step (autoreset mode ``SAME_STEP``) and puts the last
  information state in ``infos["final_obs"]`` so that a learner can bootstrap.
* :class:`FilterGymEnv` -- a single-run ``gymnasium.Env`` for tools that
  want one (``gymnasium.make("adaptfilt/ungm-ukf-v0")``).
* :func:`make_vec` -- the vector environment as a Stable-Baselines3
  ``VecEnv`` (:class:`SB3VecEnv`), with SB3's time-limit convention
  (``infos[i]["terminal_observation"]``, ``"TimeLimit.truncated"``).

In all three, an **observation** is the information state of a
:class:`~adaptfilt.features.FeatureSet` (default: the paper's) scaled by a
:class:`~adaptfilt.features.FeatureScaler` exactly as our own trainer scales
it (:func:`~adaptfilt.features.fit_scaler`, fitted on a seeded mix of grid
values, ``asinh``), as float32. An **action** is an index into the parameter
grid. The **reward** is minus the transformed one-step cost,
``-log(1 + L)`` by default (:func:`adaptfilt.costs.transform_cost`;
``cost_transform="none"`` gives ``-L``). A non-finite cost (a diverged
update) is replaced by the largest float before the transform, as in our
trainer. ``reset(seed=s)`` simulates fresh trajectories from a generator
seeded with ``s``; later resets continue that generator.

:func:`as_policy` turns any SB3 model (or any callable ``obs -> actions``)
into an adaptfilt policy, so that :func:`adaptfilt.evaluation.evaluate`
compares it with every baseline on the same paired runs, and
:func:`to_learned_policy` converts an SB3 actor-critic into a
:class:`~adaptfilt.learned.LearnedPolicy` (weights copied exactly) that is
saved as a pickle-free policy file.

Example
-------
>>> from stable_baselines3 import PPO                         # doctest: +SKIP
>>> import adaptfilt.gym as afg                               # doctest: +SKIP
>>> venv = afg.make_vec("ungm-ukf", n_envs=64, seed=0)         # doctest: +SKIP
>>> model = PPO("MlpPolicy", venv, gamma=0.5).learn(200_000)   # doctest: +SKIP
>>> from adaptfilt.evaluation import evaluate                  # doctest: +SKIP
>>> from adaptfilt.experiment_registry import get_experiment           # doctest: +SKIP
>>> exp = get_experiment("ungm-ukf")                           # doctest: +SKIP
>>> res = evaluate(exp, exp.baselines() + [afg.as_policy(model, name="ppo")], n_runs=2000)  # doctest: +SKIP
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from adaptfilt.anchor import ANCHORS, Anchor, allowed_mask, anchor_onehot
from adaptfilt.costs import transform_cost
from adaptfilt.experiment_registry import resolve
from adaptfilt.features import OBS_LIMIT, FeatureScaler, FeatureSet, fit_scaler, observe

__all__ = ["FilterVectorEnv", "FilterGymEnv", "SB3VecEnv", "make_vec", "make_vector_env", "make_env",
           "as_policy", "to_learned_policy", "rewards"]



def rewards(cost: np.ndarray, cost_transform: str = "log1p") -> np.ndarray:
    """Minus the transformed cost; a non-finite cost counts as the largest float."""
    cost = np.where(np.isfinite(cost), cost, np.finfo(float).max)
    return -transform_cost(cost, cost_transform)


class _Observer:
    """Information state -> network input: feature set, scaler, float32, bounded; with an anchor
    (:mod:`adaptfilt.anchor`), the anchor's one-hot appended (the anchored policy drops it before its networks)."""

    def __init__(self, env, features, scaler: FeatureScaler | None, scaler_seed: int, anchor=None):
        if isinstance(anchor, str):
            if anchor not in ANCHORS:
                raise ValueError(f"unknown anchor {anchor!r}; choose one of {', '.join(ANCHORS)} (or None)")
            anchor = Anchor(anchor)
        if anchor is not None and not isinstance(anchor, Anchor):
            raise ValueError(f"anchor must be None, a name or an adaptfilt.anchor.Anchor, got {anchor!r}")
        self.anchor = None if anchor is None else anchor.policy
        self.shield = None if anchor is None else anchor.shield
        self.features = FeatureSet.parse(features)
        self.scaler = scaler if scaler is not None else fit_scaler(env, self.features, seed=scaler_seed)
        names = getattr(env, "feature_names", None)  # an environment with features of its own names them
        if names is None:
            model = getattr(env, "model", None)  # the toy MDPs have none: their names are the scaler's
            names = self.features.names(model, env.grid) if model is not None else list(self.scaler.names)
        names = list(names)
        if self.scaler.names and list(self.scaler.names) != list(names):
            raise ValueError(f"the scaler was fitted on features {list(self.scaler.names)}, "
                             f"the environment's feature set {self.features.name!r} has {names}")
        G = int(np.asarray(env.grid).size)
        self.n_anchor = 0 if anchor is None else G * (2 if self.shield is not None else 1)
        self.dim = int(self.scaler.center.shape[0]) + self.n_anchor

    def __call__(self, decision) -> np.ndarray:
        s = self.scaler.network_input(observe(decision, self.features))
        if self.anchor is None:
            return s
        onehot = anchor_onehot(decision, self.anchor)
        keep = None if self.anchor == "greedy" else onehot.argmax(axis=1)  # the anchor's choice is always allowed
        extra = [onehot] + ([] if self.shield is None else [allowed_mask(decision, self.shield, keep=keep)])
        return np.concatenate([s] + extra, axis=1)

    def space(self) -> spaces.Box:
        return spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(self.dim,), dtype=np.float32)


class FilterVectorEnv(VectorEnv):
    """A batched :class:`~adaptfilt.mdp.FilterEnv` as a ``gymnasium.vector.VectorEnv``.

    Parameters
    ----------
    env_or_experiment : str, Experiment or FilterEnv
        ``"ungm-ukf"`` etc. (see ``adaptfilt experiments``) or an environment of your own.
    num_envs : int
        Monte-Carlo runs that step together (one filter, batched).
    features : str or FeatureSet
        The information state (default: the paper's, ``"paper"``).
    scaler : FeatureScaler, optional
        Default: :func:`~adaptfilt.features.fit_scaler` with ``scaler_seed``.
    cost_transform : "log1p" or "none"
        Reward ``-log(1 + L)`` or ``-L``.
    repair_penalty : float
        Subtracted from the reward of a run whose covariance the filter had to
        repair in that step (a sign of divergence the bounded costs do not
        punish; default 0: the paper's reward).
    seed : int
        Seeds the filter's random numbers (SIF) and the scaler when not given;
        trajectories come from ``reset(seed=...)``.
    n_steps : int, optional
        Horizon (default: the model's).
    anchor : "greedy", "ml", an Anchor or None
        Append the anchor's choice (greedy's or ML's) as a one-hot ``(G,)`` to each observation, for an anchored policy
        (:mod:`adaptfilt.anchor`; default None: the scaled features only), and with the anchor's
        shield its mask ``(G,)`` (:func:`~adaptfilt.anchor.allowed_mask`).

    Example
    -------
    >>> venv = FilterVectorEnv("ungm-ukf", num_envs=4, n_steps=10)
    >>> obs, info = venv.reset(seed=0)
    >>> obs.shape, venv.single_action_space
    ((4, 5), Discrete(13))
    >>> obs, r, terminated, truncated, info = venv.step(np.zeros(4, dtype=int))
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, env_or_experiment="ungm-ukf", num_envs: int = 64, features="paper",
                 scaler: FeatureScaler | None = None, cost_transform: str = "log1p", seed: int = 0,
                 n_steps: int | None = None, repair_penalty: float = 0.0, anchor=None):
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        target = resolve(env_or_experiment, seed, n_steps)
        self.env, self.experiment = target.env, target.name
        if getattr(self.env, "cost", None) is None:
            raise ValueError("the environment needs a cost: the reward is minus the cost")
        self.cost_transform = cost_transform
        rewards(np.zeros(1), cost_transform)  # unknown transform: ValueError now, not at the first step
        if not (np.isfinite(repair_penalty) and repair_penalty >= 0):
            raise ValueError(f"repair_penalty must be finite and >= 0, got {repair_penalty}")
        self.repair_penalty = float(repair_penalty)
        self.observer = _Observer(self.env, features, scaler, seed, anchor)
        self.num_envs = int(num_envs)
        self.grid = np.asarray(self.env.grid, dtype=float)
        self.single_observation_space = self.observer.space()
        self.single_action_space = spaces.Discrete(self.grid.size)
        self.observation_space = gymnasium.vector.utils.batch_space(self.single_observation_space, self.num_envs)
        self.action_space = spaces.MultiDiscrete(np.full(self.num_envs, self.grid.size))
        self._decision = None

    @property
    def scaler(self) -> FeatureScaler:
        return self.observer.scaler

    @property
    def features(self) -> FeatureSet:
        return self.observer.features

    def _start(self):
        stream = int(self.np_random.integers(2**31))  # keys a stochastic rule's draws for this episode
        self._decision = self.env.reset(n_runs=self.num_envs, rng=self.np_random, stream=stream)
        return self.observer(self._decision)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        return self._start(), {}

    def step(self, actions):
        if self._decision is None:
            raise RuntimeError("call reset() before step()")
        a = np.asarray(actions).reshape(self.num_envs)
        d, cost, done, info = self.env.step(a)
        r = rewards(cost, self.cost_transform)
        if self.repair_penalty:
            r = r - self.repair_penalty * info["repaired"]
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.full(self.num_envs, done)
        infos: dict[str, Any] = {}
        if done:
            final = info.get("final_decision")
            infos["final_obs"] = None if final is None else self.observer(final)
            infos["_final_obs"] = np.ones(self.num_envs, dtype=bool)
            obs = self._start()
        else:
            self._decision = d
            obs = self.observer(d)
        return obs, r, terminated, truncated, infos

    def close_extras(self, **kwargs):
        self._decision = None


class FilterGymEnv(gymnasium.Env):
    """One Monte-Carlo run of the MDP as a ``gymnasium.Env`` (observation ``(d,)``, ``Discrete(|grid|)``).

    The episode is truncated (never terminated) after the horizon. Same
    parameters as :class:`FilterVectorEnv`. For training, the vector
    environment is much faster: it steps all runs with one batched filter.

    >>> env = FilterGymEnv("ctm-ukf", n_steps=5)
    >>> obs, info = env.reset(seed=1)
    >>> obs.shape
    (8,)
    """

    metadata = {"render_modes": []}

    def __init__(self, env_or_experiment="ungm-ukf", features="paper", scaler: FeatureScaler | None = None,
                 cost_transform: str = "log1p", seed: int = 0, n_steps: int | None = None):
        self._venv = FilterVectorEnv(env_or_experiment, 1, features, scaler, cost_transform, seed, n_steps)
        self.observation_space = self._venv.single_observation_space
        self.action_space = self._venv.single_action_space

    @property
    def scaler(self) -> FeatureScaler:
        return self._venv.scaler

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self._venv._np_random = self.np_random  # one generator: reset(seed) fixes the episode
        return self._venv._start()[0], {}

    def step(self, action):
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is not in {self.action_space}")
        d, cost, done, info = self._venv.env.step(np.array([int(action)]))
        r = float(rewards(cost, self._venv.cost_transform)[0])
        if done:
            final = info.get("final_decision")
            obs = self._venv.observer(final)[0] if final is not None else np.zeros(self._venv.observer.dim, np.float32)
            self._venv._decision = None
            return obs, r, False, True, {}
        self._venv._decision = d
        return self._venv.observer(d)[0], r, False, False, {}


def _sb3_vecenv_base():
    from stable_baselines3.common.vec_env import VecEnv

    return VecEnv


class SB3VecEnv(_sb3_vecenv_base()):
    """A :class:`FilterVectorEnv` as a Stable-Baselines3 ``VecEnv``.

    SB3 expects each sub-environment to reset itself when done and to hand
    the last observation over in ``infos[i]["terminal_observation"]``, with
    ``infos[i]["TimeLimit.truncated"] = True`` when the episode was cut by a
    time limit: then SB3's on-policy algorithms bootstrap from it (SB3 issue #633).
    """

    def __init__(self, venv: FilterVectorEnv):
        self.venv = venv
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions = None

    # the MDP's own objects, for as_policy / to_learned_policy
    @property
    def scaler(self) -> FeatureScaler:
        return self.venv.scaler

    @property
    def features(self) -> FeatureSet:
        return self.venv.features

    def reset(self):
        seed = self._seeds[0] if self._seeds else None
        obs, _ = self.venv.reset(seed=seed)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, r, terminated, truncated, infos = self.venv.step(self._actions)
        dones = terminated | truncated
        out = [{} for _ in range(self.num_envs)]
        if dones.any():
            final = infos.get("final_obs")
            for i in np.flatnonzero(dones):
                out[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                out[i]["terminal_observation"] = None if final is None else final[i]
        return obs, r.astype(np.float32), dones, out

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices=None) -> list:
        return [getattr(self.venv, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list:
        return [getattr(self.venv, method_name)(*args, **kwargs)] * len(self._get_indices(indices))

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._get_indices(indices))


def make_vector_env(experiment="ungm-ukf", n_envs: int = 64, **kwargs) -> FilterVectorEnv:
    """``FilterVectorEnv(experiment, n_envs, ...)``: the Gymnasium vector environment."""
    return FilterVectorEnv(experiment, n_envs, **kwargs)


def make_vec(experiment="ungm-ukf", n_envs: int = 64, **kwargs) -> SB3VecEnv:
    """The experiment's MDP as an SB3 ``VecEnv`` of ``n_envs`` runs:
    ``PPO("MlpPolicy", make_vec("ungm-ukf", n_envs=64))`` trains as written.
    Keyword arguments go to :class:`FilterVectorEnv` (``features``, ``seed``, ``n_steps`` ...)."""
    return SB3VecEnv(FilterVectorEnv(experiment, n_envs, **kwargs))


def make_env(experiment="ungm-ukf", **kwargs) -> FilterGymEnv:
    """One run of the experiment's MDP as a ``gymnasium.Env``."""
    return FilterGymEnv(experiment, **kwargs)


# ------------------------------------------------------------------ policies
class CallablePolicy:
    """An adaptfilt policy from ``fn(obs (M, d) float32) -> grid indices (M,)``."""

    def __init__(self, fn: Callable[[np.ndarray], np.ndarray], features, scaler: FeatureScaler,
                 grid: Sequence[float] | None = None, name: str = "rl"):
        self.fn, self.name = fn, name
        self.features = FeatureSet.parse(features)
        self.scaler = scaler
        self.grid = None if grid is None else np.asarray(grid, dtype=float)

    def act(self, decision) -> np.ndarray:
        if self.grid is not None and (decision.grid.shape != self.grid.shape or not np.allclose(decision.grid, self.grid)):
            raise ValueError(f"policy {self.name!r} was made for the grid {self.grid.tolist()}, "
                             f"the environment uses {decision.grid.tolist()}")
        a = np.asarray(self.fn(self.scaler.network_input(observe(decision, self.features)))).reshape(-1)
        if a.shape != (decision.n_runs,):
            raise ValueError(f"policy {self.name!r} returned {a.shape} actions for {decision.n_runs} runs")
        return a.astype(np.int64)


def _mdp_of(model, venv):
    venv = venv if venv is not None else (model.get_env() if hasattr(model, "get_env") else None)
    if venv is None or not hasattr(venv, "scaler"):
        raise ValueError("give the environment the model was trained on (venv=make_vec(...)), "
                         "or scaler= and features= explicitly")
    return venv


def as_policy(model, venv=None, *, scaler: FeatureScaler | None = None, features=None,
              grid: Sequence[float] | None = None, name: str | None = None, deterministic: bool = True) -> CallablePolicy:
    """Any SB3 model (``model.predict``) or callable ``obs -> actions`` as an adaptfilt policy.

    The observation scaling and feature set are taken from ``venv`` (default:
    the model's own training environment, ``model.get_env()``) unless given.
    ``deterministic`` (SB3): the most probable action, as Algorithm 3.
    """
    if scaler is None or features is None:
        v = _mdp_of(model, venv)
        scaler = v.scaler if scaler is None else scaler
        features = v.features if features is None else features
        if grid is None and hasattr(v, "venv"):
            grid = v.venv.grid
        elif grid is None and hasattr(v, "grid"):
            grid = v.grid
    if hasattr(model, "predict"):
        fn = lambda obs: model.predict(obs, deterministic=deterministic)[0]
        name = name or type(model).__name__.lower()
    elif callable(model):
        fn, name = model, name or getattr(model, "__name__", "rl")
    else:
        raise TypeError(f"expected an SB3 model or a callable obs -> actions, got {type(model).__name__}")
    return CallablePolicy(fn, features, scaler, grid, name)


def to_learned_policy(model, venv=None, gamma: float | None = None, name: str | None = None,
                      metadata: dict | None = None):
    """An SB3 actor-critic (``ActorCriticPolicy`` with an MLP actor and a
    ``Discrete`` action space) as a :class:`~adaptfilt.learned.LearnedPolicy`:
    the actor's layers are copied exactly, so ``act`` is SB3's deterministic
    ``predict``; the result saves to a pickle-free policy file."""
    import torch

    from adaptfilt.learned import Actor, LearnedPolicy

    v = _mdp_of(model, venv)
    pol = model.policy
    layers = [m for m in pol.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)] + [pol.action_net]
    acts = {type(m).__name__ for m in pol.mlp_extractor.policy_net if not isinstance(m, torch.nn.Linear)}
    act = {"ReLU": "relu", "Tanh": "tanh"}.get(acts.pop() if len(acts) == 1 else "", None)
    if act is None:
        raise ValueError(f"only MLP actors with one ReLU or Tanh activation convert, got {acts or 'none'}")
    hidden = [m.out_features for m in layers[:-1]]
    actor = Actor(layers[0].in_features, layers[-1].out_features, hidden, act)
    with torch.no_grad():
        for mine, theirs in zip([m for m in actor.net if isinstance(m, torch.nn.Linear)], layers):
            mine.weight.copy_(theirs.weight)
            mine.bias.copy_(theirs.bias)
    venv_ = getattr(v, "venv", v)
    gamma = float(model.gamma if gamma is None else gamma)
    meta = {"experiment": venv_.experiment, "feature_set": venv_.features.name,
            "cost_transform": venv_.cost_transform, "algo": type(model).__name__.lower(), **(metadata or {})}
    anchor = getattr(venv_.observer, "anchor", None)
    if anchor is not None:  # the policy adds c * onehot(anchor's choice) to the actor's logits (adaptfilt.anchor)
        from adaptfilt.anchor import Anchor

        if not hasattr(pol, "n_anchor") or pol.shield != (venv_.observer.shield is not None):
            raise ValueError("the environment appends the anchor's one-hot (and the shield's mask) but the model is not "
                             "an anchored policy with the same shield")
        meta["anchor"] = Anchor(anchor, pol.strength, float(getattr(model, "ent_coef", 0.0)),
                                venv_.observer.shield).to_dict()

    meta = {**venv_.env.describe(venv_.features), **meta}
    return LearnedPolicy(actor, venv_.scaler, venv_.grid, gamma=gamma, name=name, metadata=meta)


# ------------------------------------------------------------------ registry
def _register() -> None:
    from adaptfilt.experiment_registry import EXPERIMENTS

    for name in EXPERIMENTS:
        env_id = f"adaptfilt/{name}-v0"
        if env_id not in gymnasium.registry:
            gymnasium.register(env_id, entry_point=FilterGymEnv, kwargs={"env_or_experiment": name},
                               vector_entry_point=FilterVectorEnv)


_register()
