r"""Training a parameter policy by name of algorithm: ``adaptfilt train NAME --algo ALGO``.

=============  ==========================================================================
``algo``       what trains the policy
=============  ==========================================================================
``faithful``   Algorithm 2's update loop with the library's recipe
               (:func:`adaptfilt.actor_critic.train`, ``parallel=1``): one episode at a
               time, one Adam step per time step; the corrected sign, log(1 + L), the
               feature set, the asinh scaler and the time-limit bootstrap of the
               defaults (``docs/DEVIATIONS.md``). The reference; about 11 CPU-minutes
               per UNGM policy.
``batched``    the same code with ``parallel`` episodes per Adam step
               (:func:`adaptfilt.actor_critic.train`): faster, measurably worse.
``fast``       the fast mode: Stable-Baselines3's PPO through :mod:`adaptfilt.gym`
               with large batches (:data:`FAST`; about 30 s per UNGM policy on one
               core, as good as ``faithful`` over 8 seeds: ``REPRODUCTION.md``).
``a2c``        Stable-Baselines3's A2C (:data:`A2C_FAST`): the first fast mode,
               kept so that its recorded commands still reproduce.
``ppo``        Stable-Baselines3's PPO with its defaults (:data:`PPO_DEFAULTS`;
               the peer comparison; about 700 CPU-s per UNGM policy).
=============  ==========================================================================

Every algorithm sees the same MDP: the experiment's feature set (UNGM
``paper+time``, CTM ``paper+circ``), the feature scaler fitted on a seeded mix of
grid values with ``asinh`` squashing, the reward ``-log(1 + L)`` and the horizon as
a time limit with a bootstrap there. The budget is counted in episodes as in the
paper (``N_MC = 1000`` episodes of ``T`` steps, i.e. ``1000 T`` transitions).

**The fast mode deviates from Algorithm 2** (the deviations are SB3's PPO):
256 runs step together (one batched filter) for 64 steps; the 16384
transitions of such a rollout get GAE(0.95) advantages from the critic
(instead of one-step TD errors), and then 5 epochs of Adam steps (learning rate
2e-3, one optimiser for actor and critic, the critic's loss weighted 0.5,
gradients clipped at norm 0.5) on shuffled minibatches of 2048 minimise PPO's
clipped surrogate (clip 0.2) with advantages normalised per minibatch; there
is no target critic (no Polyak averaging) and no entropy bonus (PPO's default
0; the paper's is 1e-3). The networks are the paper's (two hidden layers of 64
ReLU units, separate actor and critic), as are the discount and the budget in
transitions (rounded up to whole rollouts). Why these values:
``benchmarks/bench_fast_tuning.py`` (PPO's defaults learn best but take about
700 s; the batch and epochs here are the largest change that keeps UNGM under
30 s on one core, the learning rate the one that recovers the defaults' quality).

``a2c`` (:data:`A2C_FAST`, the first fast mode) deviates differently: 64 runs,
5-step returns, RMSprop at 7e-4, the paper's entropy bonus 1e-3.

**Anchored on greedy** (``anchor="greedy"``, ``adaptfilt train ... --anchor greedy``; SB3 trainers):
the policy is a residual over greedy's choice that acts exactly as greedy before training, kept near
it by ``beta KL(pi || pi_0)`` in the place of PPO's entropy term (:mod:`adaptfilt.anchor`);
``anchor="ml"`` (``--anchor ml``) the same over maximum likelihood's choice.

All trainers return a :class:`~adaptfilt.learned.LearnedPolicy` whose file is
byte-identical for the same command (one torch thread, seeded everything) on the
same kind of CPU; on another instruction set the floating-point kernels round
differently and training amplifies that into a different policy (README, Conventions).
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from adaptfilt.experiment_registry import resolve

__all__ = ["ALGOS", "SB3Config", "FAST", "A2C_FAST", "PPO_DEFAULTS", "train_policy", "train_sb3", "seed_path",
           "sb3_optimiser_steps"]

ALGOS = ("faithful", "batched", "fast", "a2c", "ppo")


@dataclass(frozen=True)
class SB3Config:
    """A Stable-Baselines3 learner: class name, environments per batch, keyword arguments."""

    algo: str = "a2c"
    n_envs: int = 64
    kwargs: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"algo": self.algo, "n_envs": self.n_envs, "kwargs": dict(self.kwargs)}


#: The fast mode: PPO over 256 runs, rollouts of 64 steps, 5 epochs of minibatches of 2048 at 2e-3.
FAST = SB3Config("ppo", 256, {"n_steps": 64, "batch_size": 2048, "n_epochs": 5, "learning_rate": 2e-3})
#: The first fast mode (``--algo a2c``): A2C with 5-step returns over 64 runs and the paper's entropy bonus.
A2C_FAST = SB3Config("a2c", 64, {"n_steps": 5, "ent_coef": 1e-3})
#: PPO with Stable-Baselines3's defaults (gamma and the networks set as for every learner).
PPO_DEFAULTS = SB3Config("ppo", 16, {})


def seed_path(out: str | Path, seed: int) -> Path:
    """``policy.npz`` -> ``policy-s3.npz``; an ``{seed}`` in ``out`` is filled in instead."""
    out = str(out)
    if "{seed}" in out:
        return Path(out.format(seed=seed))
    p = Path(out)
    stem = p.name[:-4] if p.name.endswith(".npz") else p.name
    return p.with_name(f"{stem}-s{seed}.npz")


class _Progress:
    """A tqdm bar over transitions for SB3's ``learn`` (a ``BaseCallback``)."""

    def __new__(cls, total: int, desc: str):
        from stable_baselines3.common.callbacks import BaseCallback
        from tqdm.auto import tqdm

        class Bar(BaseCallback):
            def _on_training_start(self):
                self.bar = tqdm(total=total, desc=desc, unit="step", unit_scale=True)

            def _on_step(self) -> bool:
                self.bar.update(self.training_env.num_envs)
                return True

            def _on_training_end(self):
                self.bar.close()

        return Bar()


def sb3_optimiser_steps(metadata: dict) -> int:
    """The optimiser steps a :func:`train_sb3` training took, from its policy's metadata (``transitions`` and
    ``trainer``): per rollout of ``n_steps x n_envs`` transitions, PPO makes ``n_epochs`` passes in minibatches
    of ``batch_size`` (the last one partial), A2C one step. SB3 trains whole rollouts only.

    >>> sb3_optimiser_steps({"transitions": 3 * 16384, "trainer": FAST.to_dict()})  # 3 x 5 x 8
    120
    """
    tr = metadata["trainer"]
    kw = tr["kwargs"]
    rollout = int(kw["n_steps"]) * int(tr["n_envs"])
    rollouts = int(metadata["transitions"]) // rollout
    if tr["algo"] == "a2c":
        return rollouts
    return rollouts * int(kw["n_epochs"]) * -(-rollout // int(kw["batch_size"]))


def train_sb3(experiment, gamma: float = 0.5, episodes: int = 1000, seed: int = 0,
              config: SB3Config = FAST, *, features: str | None = None, n_steps: int | None = None,
              progress: bool = True, command: str | None = None, name: str | None = None,
              max_seconds: float | None = None, repair_penalty: float = 0.0,
              actions: Sequence[float] | None = None, cost_transform: str = "log1p",
              normalize_reward: bool = False, anchor=None, max_cpu_s: float | None = None,
              snapshots: Sequence[int] = (), truth: str | None = None):
    """Train a policy with a Stable-Baselines3 algorithm on a named experiment or an environment.

    ``experiment``: a name (``"ungm-ukf"``), an :class:`~adaptfilt.experiment_registry.Experiment`
    or a :class:`~adaptfilt.mdp.FilterEnv` of your own (features default to the
    experiment's recommended set, ``"paper"`` for an environment; ``n_steps`` is
    the environment's own horizon and cannot be changed here).
    ``episodes * T`` transitions (``T`` the horizon), ``config.n_envs`` runs per
    batch; returns the :class:`~adaptfilt.learned.LearnedPolicy` (actor copied
    from the SB3 model) with its learning curve (mean transformed cost per
    batch of episodes) and metadata (algorithm, hyperparameters, seed, command).
    ``max_seconds`` stops training after that much wall time (for comparisons
    at equal wall time; such a policy depends on the machine, not only its seed);
    ``max_cpu_s`` after that many process CPU seconds since the call (set-up included; for tuning at
    equal CPU budgets, likewise not reproducible).
    ``snapshots``: episode counts ``E`` (at most ``episodes``) at which the policy is kept as a training of
    ``E`` episodes would have returned it, bit for bit: SB3 trains on whole rollouts, so a training of
    ``E`` episodes ends after the first rollout that reaches ``E T`` transitions, and with the fast mode's
    constant learning rate and clip range nothing else depends on the total. ``pol.snapshots[E]`` is that
    policy (its weights, metadata and curve those of the shorter training, ``command`` this training's: the
    command that made it; its ``cpu_s``: the process CPU seconds spent up to it). One training then serves a
    budget curve.
    ``actions``: the grid values the policy may choose, a subset of the experiment's
    grid holding its default (a *safe action set*: e.g. no SIF iteration count that
    can diverge); the policy still acts in the full experiment (named experiments only).
    ``truth``: the training episodes are simulated from this truth (:func:`adaptfilt.experiment_registry.truth_model`
    words, e.g. ``"q=4,r=1"`` or ``"forcing=10"``) while the filter keeps the experiment's model: a learner
    trained on data of the true system (named experiments only; recorded in the metadata as ``truth``).
    ``cost_transform``: the reward is ``-log(1 + L)`` (``"log1p"``, the default; the paper trains on ``L`` itself) or ``-L`` (``"none"``:
    the mean cost itself, whose rare large steps the log flattens). ``normalize_reward``: the learner
    sees the reward divided by a running estimate of the return's spread (SB3's ``VecNormalize``,
    observations untouched); the learning curve keeps the transformed cost itself.
    ``anchor``: ``None``, ``"greedy"``, ``"ml"`` or an :class:`~adaptfilt.anchor.Anchor`: the policy is a residual
    over the anchor's choice, ``pi ∝ exp(actor(s) + c onehot(anchor))`` with the actor's output layer at
    zero (the untrained policy acts as its anchor), and the loss carries ``kl * KL(pi || pi_0)`` in the
    slot of PPO's entropy term (:mod:`adaptfilt.anchor`; ``config.kwargs`` must not set ``ent_coef`` then).
    """
    import torch
    from stable_baselines3 import A2C, PPO
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import VecNormalize

    from adaptfilt._version import __version__
    from adaptfilt.gym import make_vec, to_learned_policy
    from adaptfilt.nets import one_torch_thread

    cpu0 = time.process_time()
    classes = {"a2c": A2C, "ppo": PPO}
    if config.algo not in classes:
        raise ValueError(f"unknown SB3 algorithm {config.algo!r}; choose one of {sorted(classes)}")
    _check(gamma, episodes)
    snaps = sorted({int(e) for e in snapshots})
    if snaps and (snaps[0] < 1 or snaps[-1] > int(episodes) or any(int(e) != e for e in snapshots)):
        raise ValueError(f"snapshots must be episode counts in 1..episodes={episodes}, got {list(snapshots)}")
    if snaps and any(callable(config.kwargs.get(k)) for k in ("learning_rate", "clip_range")):
        raise ValueError("snapshots need a constant learning rate and clip range (a schedule depends on the total)")
    if actions is not None or truth is not None:  # the experiment's environment with its grid cut or its truth
        experiment, features, n_steps = _variant(experiment, seed, n_steps, features, actions, truth)
    target = resolve(experiment, seed, n_steps)  # an environment's horizon is its own
    label, features = target.label, features or target.features or "paper"
    anchor = _anchor(anchor)
    if anchor is not None and config.kwargs.get("ent_coef", 0.0):
        raise ValueError("an anchored policy's KL term takes the place of PPO's entropy term: set the "
                         "anchor's kl instead of ent_coef")
    venv = make_vec(target, n_envs=config.n_envs, seed=seed, features=features, n_steps=n_steps,
                    repair_penalty=repair_penalty, cost_transform=cost_transform,
                    anchor=anchor)
    T = venv.venv.env.n_steps
    total = int(episodes) * T
    kwargs = {"policy_kwargs": {"activation_fn": torch.nn.ReLU, "net_arch": {"pi": [64, 64], "vf": [64, 64]}},
              **config.kwargs}
    policy_class = "MlpPolicy"
    if anchor is not None:
        from adaptfilt.anchor import anchored_policy_class

        policy_class = anchored_policy_class()
        kwargs["policy_kwargs"].update(strength=anchor.strength, shield=anchor.shield is not None)
        kwargs["ent_coef"] = anchor.kl
    curve: list[float] = []
    kept: dict = {}

    def learned(m, n_episodes: int, c: list, cmd: str | None):
        c = np.asarray(c, dtype=float)
        meta = {"seed": int(seed), "episodes": int(n_episodes), "n_steps": int(T), "parallel": int(config.n_envs),
                "trainer": config.to_dict(), "transitions": int(m.num_timesteps), "version": __version__,
                "command": cmd, "torch_version": torch.__version__.split("+")[0],
                "curve_summary": {"episodes": int(n_episodes), "train_cost_first10pct": _frac(c, 0),
                                  "train_cost_last10pct": _frac(c, 1)}}
        if repair_penalty:  # recorded only when set: files made before the option existed stay reproducible
            meta["repair_penalty"] = float(repair_penalty)
        if normalize_reward:
            meta["normalize_reward"] = True
        if truth is not None:
            meta["truth"] = str(truth)
        pol = to_learned_policy(m, venv, gamma=gamma, name=name, metadata=meta)
        pol.curve = {"train_cost": c}  # wall time lives in the manifest, not in the (byte-identical) file
        return pol

    def snapshot(m, e: int):
        """The policy a training of ``e`` episodes returns, from the model now (its CPU-s so far in ``cpu_s``)."""
        with torch.random.fork_rng(devices=[]):  # building the policy's actor draws initial weights: not the training's
            p = learned(m, e, list(curve), command)
        p.cpu_s = time.process_time() - cpu0
        return p

    with one_torch_thread(), torch.random.fork_rng(devices=[]):
        venv.seed(seed)
        env = VecNormalize(venv, norm_obs=False, norm_reward=True, gamma=float(gamma)) if normalize_reward else venv
        model = classes[config.algo](policy_class, env, gamma=float(gamma), seed=int(seed), device="cpu",
                                     verbose=0, **kwargs)
        # SB3's default logger makes an empty folder in the temporary directory per learn() (SB3-<time>),
        # one per policy trained; a logger with no outputs makes none
        model.set_logger(Logger(folder=None, output_formats=[]))
        callbacks = [_curve_callback(curve, config.n_envs)]
        if max_seconds is not None:
            callbacks.append(_deadline(float(max_seconds)))
        if max_cpu_s is not None:
            callbacks.append(_deadline(float(max_cpu_s), clock=time.process_time, start=cpu0))
        if snaps:
            callbacks.append(_snapshot_callback(snaps, T, kept, snapshot))
        if progress:  # SB3 collects whole rollouts: the bar's end is the total rounded up to one
            rollout = model.n_steps * model.n_envs
            callbacks.append(_Progress(-(-total // rollout) * rollout, f"{config.algo} {label} gamma={gamma:g} seed={seed}"))
        model.learn(total_timesteps=total, callback=callbacks)
    for e in snaps:  # the snapshots the end of training reaches (the last rollout's)
        if e not in kept and int(e) * T <= model.num_timesteps:
            kept[e] = snapshot(model, e)
    pol = learned(model, episodes, curve, command)
    pol.cpu_s = time.process_time() - cpu0
    pol.snapshots = dict(sorted(kept.items()))
    return pol


def _snapshot_callback(snaps: list[int], T: int, kept: dict, snapshot):
    """Keep ``snapshot(model, e)`` at the start of the rollout after the one a training of ``e`` episodes ends with."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Snapshots(BaseCallback):
        def _on_rollout_start(self) -> None:
            done = self.model.num_timesteps
            for e in snaps:
                if e not in kept and 0 < e * T <= done:
                    kept[e] = snapshot(self.model, e)

        def _on_step(self) -> bool:
            return True

    return Snapshots()


def _anchor(anchor):
    """``None``, an anchor name or an :class:`~adaptfilt.anchor.Anchor` -> an Anchor or None (ValueError if bad)."""
    from adaptfilt.anchor import Anchor

    if anchor is None or isinstance(anchor, Anchor):
        return anchor
    if isinstance(anchor, str):
        return Anchor(anchor)
    raise ValueError(f"anchor must be None, a name ('greedy', 'ml') or an Anchor, got {anchor!r}")


def _variant(experiment, seed: int, n_steps: int | None, features: str | None, actions: Sequence[float] | None,
             truth: str | None):
    """``(env, features, None)``: the experiment's environment with its grid cut to ``actions`` and its
    trajectories simulated from ``truth`` (:func:`~adaptfilt.experiment_registry.truth_model`'s words; ValueError
    naming what is wrong), the features the experiment recommends unless given; the horizon is the env's."""
    from adaptfilt.experiment_registry import Experiment, Target, get_experiment, truth_model

    exp = get_experiment(experiment) if isinstance(experiment, str) else experiment
    exp = exp.experiment if isinstance(exp, Target) else exp
    if not isinstance(exp, Experiment):
        raise ValueError("actions= and truth= make a variant of a named experiment; for an environment of your own, "
                         "build it with the grid and truth you want")
    t = None if truth is None else truth_model(exp.make_model(), truth)
    return exp.make_env(seed=seed, n_steps=n_steps, grid=actions, truth=t), features or exp.features, None


def _frac(c: np.ndarray, last: int) -> float:
    if c.size == 0:
        return float("nan")
    w = max(1, c.size // 10)
    return float(c[-w:].mean() if last else c[:w].mean())


def _curve_callback(curve: list, n_envs: int):
    """Mean transformed cost of each finished batch of episodes (SB3 rewards are minus it)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Curve(BaseCallback):
        def _on_training_start(self):
            self.acc, self.n = 0.0, 0

        def _on_step(self) -> bool:
            env = self.training_env  # under VecNormalize the learner's rewards are rescaled: log the MDP's own
            r = env.get_original_reward() if hasattr(env, "get_original_reward") else self.locals["rewards"]
            self.acc += float(-np.mean(r))
            self.n += 1
            if np.any(self.locals["dones"]):
                curve.append(self.acc / self.n)
                self.acc, self.n = 0.0, 0
            return True

    return Curve()


def _deadline(seconds: float, clock=time.perf_counter, start: float | None = None):
    """Stop SB3's ``learn`` once ``seconds`` have passed on ``clock`` (wall time by default) since ``start``
    (default: the training's start)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Deadline(BaseCallback):
        def _on_training_start(self):
            self.t0 = clock() if start is None else start

        def _on_step(self) -> bool:
            return clock() - self.t0 < seconds

    return Deadline()


def _check(gamma: float, episodes: int) -> None:
    if not (0.0 <= float(gamma) < 1.0):
        raise ValueError(f"gamma must be in [0, 1), got {gamma}")
    if int(episodes) < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")


def train_policy(experiment, algo: str = "faithful", gamma: float = 0.5, episodes: int = 1000, seed: int = 0,
                 *, parallel: int | None = None, features: str | None = None, n_steps: int | None = None,
                 progress: bool = True, command: str | None = None, out: str | Path | None = None,
                 resume: bool = False, sb3: dict[str, Any] | None = None, name: str | None = None,
                 repair_penalty: float = 0.0, actions: Sequence[float] | None = None,
                 cost_transform: str = "log1p", anchor: str | None = None, anchor_strength: float | None = None,
                 anchor_kl: float | None = None, anchor_shield: float | None = None, truth: str | None = None,
                 snapshots: Sequence[int] = ()):
    """Train one policy with ``algo`` (see :data:`ALGOS`); write it to ``out`` when given.

    ``experiment``: a name, an :class:`~adaptfilt.experiment_registry.Experiment` or an
    environment of your own (a :class:`~adaptfilt.mdp.FilterEnv`).
    ``parallel``: episodes per update of the ``batched`` mode (default 50) or runs per
    batch of an SB3 algorithm (default: its config's). ``sb3``: extra keyword
    arguments for the SB3 algorithm. ``resume`` (faithful and batched) continues
    from the checkpoint next to ``out``. ``name``: the policy's name (default:
    ``adaptive`` for gamma > 0, ``myopic`` for gamma = 0). ``cost_transform``: the learner
    minimises the mean of ``log(1 + L)`` (``"log1p"``, the default; the paper trains on ``L`` itself) or of ``L`` (``"none"``).
    ``anchor="greedy"`` or ``"ml"`` (SB3 trainers): a residual policy over the anchor's choice with strength
    ``anchor_strength`` (``c``, default :data:`adaptfilt.anchor.DEFAULT_STRENGTH`) and the penalty
    ``anchor_kl * KL(pi || pi_0)`` (default :data:`adaptfilt.anchor.DEFAULT_KL`): it acts exactly as its anchor
    before training (:mod:`adaptfilt.anchor`); recorded in the file's ``anchor`` metadata.
    ``anchor_shield``: mask out candidates whose one-step ``log(1 + L)`` exceeds greedy's by more than it
    (:func:`adaptfilt.anchor.allowed_mask`; default :data:`adaptfilt.anchor.DEFAULT_SHIELD`, 0: no shield).
    ``truth`` and ``snapshots`` (SB3 trainers): :func:`train_sb3`'s (episodes simulated from a truth the filter
    does not know; the policy kept at several episode counts of one training, ``pol.snapshots``).

    >>> import adaptfilt as af                                        # doctest: +SKIP
    >>> env = af.mdp.FilterEnv(af.UKF(my_model), grid, af.mdp.Cost("nis"))   # doctest: +SKIP
    >>> pols = [train_policy(env, "fast", seed=s, name=f"fast-s{s}") for s in range(4)]  # doctest: +SKIP
    """
    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r}; choose one of {', '.join(ALGOS)}")
    spec = None
    if anchor is None:
        if anchor_strength is not None or anchor_kl is not None or anchor_shield is not None:
            raise ValueError("anchor_strength, anchor_kl and anchor_shield set the anchor: give anchor='greedy' or 'ml' too")
    else:
        from adaptfilt.anchor import DEFAULT_KL, DEFAULT_SHIELD, DEFAULT_STRENGTH, Anchor

        shield = DEFAULT_SHIELD if anchor_shield is None else anchor_shield
        spec = Anchor(anchor, DEFAULT_STRENGTH if anchor_strength is None else anchor_strength,
                      DEFAULT_KL if anchor_kl is None else anchor_kl,
                      None if shield == 0 else shield)  # 0: no shield (Anchor's None)
    if algo in ("faithful", "batched"):
        from adaptfilt.actor_critic import train_experiment

        if actions is not None:
            raise ValueError("actions= (a restricted grid) needs an SB3 trainer (fast, a2c or ppo)")
        if spec is not None:
            raise ValueError("anchor= (a residual policy over greedy or ML) needs an SB3 trainer (fast, a2c or ppo)")
        if truth is not None or len(snapshots):
            raise ValueError("truth= and snapshots= need an SB3 trainer (fast, a2c or ppo)")

        B = 1 if algo == "faithful" else (parallel or 50)
        if algo == "faithful" and parallel not in (None, 1):
            raise ValueError("the faithful algorithm learns from one episode at a time (parallel = 1)")
        kw = {} if features is None else {"features": features}
        if cost_transform != "log1p":
            kw["cost_transform"] = cost_transform
        if repair_penalty:
            kw["repair_penalty"] = repair_penalty
        if n_steps is not None:
            kw["n_steps"] = n_steps
        if out is None:
            from adaptfilt.actor_critic import train

            return train(experiment, gamma=gamma, episodes=episodes, parallel=B, seed=seed, progress=progress,
                         command=command, name=name, **kw)[0]
        return train_experiment(experiment, out=out, gamma=gamma, episodes=episodes, parallel=B, seed=seed,
                                resume=resume, progress=progress, command=command, policy_name=name, **kw)
    base = {"fast": FAST, "a2c": A2C_FAST, "ppo": PPO_DEFAULTS}[algo]
    kwargs = {**base.kwargs, **(sb3 or {})}
    if algo == "fast" and parallel and "batch_size" not in (sb3 or {}):
        # keep FAST's 8 minibatches per rollout when the user picks fewer (or more) runs per batch
        kwargs["batch_size"] = max(2, parallel * kwargs["n_steps"] // 8)
    cfg = SB3Config(base.algo, parallel or base.n_envs, kwargs)
    pol = train_sb3(experiment, gamma, episodes, seed, cfg, features=features, n_steps=n_steps, progress=progress,
                    command=command, name=name, repair_penalty=repair_penalty, actions=actions,
                    cost_transform=cost_transform, anchor=spec, truth=truth, snapshots=snapshots)
    if out is not None:
        pol.save(out)
    return pol
