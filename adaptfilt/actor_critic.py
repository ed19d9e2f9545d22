r"""Offline Monte-Carlo TD(0) actor-critic (Algorithm 2 of the paper), in one file.

Read :func:`train` top to bottom: every statement of the inner loop carries the
name of the line of Algorithm 2 it implements. Hyperparameters (Section VI-C):
actor and critic MLPs with two hidden layers of 64 ReLU units; Adam with
learning rates 1e-4 (actor) and 5e-4 (critic), betas (0.9, 0.999); target
critic with Polyak averaging tau = 0.01; entropy coefficient 1e-3; gamma = 0.5
(``adaptive``) or 0 (``myopic``); N_MC = 1000 episodes.

The TD error and the losses, for a *cost* ``L`` (smaller is better)::

    delta_k  = L'_k + gamma * (1 - done_k) * V_target(s_{k+1}) - V(s_k)
    L_critic = delta_k^2
    L_actor  = + delta_k.detach() * log pi(theta_k | s_k) - beta * H(pi(. | s_k))

**The sign of the actor loss.** The paper prints ``L_actor = -delta log pi``.
That is the textbook actor loss for a *reward* TD error. With a cost, a
positive ``delta`` means the action was *worse* than expected; gradient
descent on ``-delta log pi`` then *raises* its probability, so the printed
sign learns the worst action (``tests/test_actor_critic.py`` shows it on a toy
with a known optimum). Minimising the expected cost needs
``+delta log pi`` (equivalently: reward = -cost, delta_reward = -delta). We
implement the correct sign; ``actor_sign=-1`` reproduces the printed one for
the demonstration only.

Choices the paper is silent about (all documented where they are made):

* **Cost transform for training** (``cost_transform``). The one-step NIS cost
  on UNGM is extremely heavy-tailed (median about 0.75, mean in the
  thousands, single steps up to 1e7): a TD target of 1e7 destroys a critic
  trained with a squared loss and Adam. By default the networks learn from
  ``L' = log(1 + L)`` (sign-symmetric for negative toy costs). It is strictly
  monotone, so the ranking of the parameter values at a step is unchanged.
  The myopic optimum (gamma = 0) is unchanged *only where ``L`` is a
  deterministic function of what the policy sees*: on UNGM the information
  state determines the update and its cost for every kappa. On the CTM the
  policy sees ``tr P`` and ``log det P``, not the whole ``P_pred``, and the
  SIF's cost is random (its draws), so there the gamma = 0 policy minimises
  ``E[log(1 + L) | s]``, which need not pick the argmin of ``E[L | s]``
  (Jensen: the log favours a parameter with a small typical cost over one
  with a smaller mean but a heavy tail). For gamma > 0 the discounted
  objective becomes the sum of log-costs, a robust version of the paper's.
  ``cost_transform="none"`` trains on the raw cost (the paper taken
  literally). Learning curves report both the raw and the transformed cost.
* **The last step.** The horizon T is a time limit: the filter and the
  process go on. With ``bootstrap_at_limit=True`` the last update's target
  is ``L' + gamma V_target(s_{T+1})`` from the next information state that
  the environment predicts past the horizon (``info["final_decision"]``).
  Treating it as terminal (target ``L'`` alone, ``bootstrap_at_limit=False``)
  teaches the critic that the last steps are cheaper than they are. All T
  updates of an episode are learned from (the paper's loop is written for
  k = 1..T-1 with predict first; we include the first update, whose
  information state is the prior).
* **Features and their scaling.** Networks see the information state
  (``features``: the experiment's recommended set, e.g. ``paper+time`` on
  UNGM and ``paper+circ`` on the bearing-only CTM; the paper's for an
  environment of your own; see :mod:`adaptfilt.features`)
  through a :class:`~adaptfilt.features.FeatureScaler` (median / IQR), fitted
  before training on ``scaler_runs`` runs of a seeded rollout and stored with
  the policy. Scaling on default-policy states and clipping at 10
  (``scaler_visit="default"``, ``scaler_squash="clip"``) saturates on the
  states other parameter values visit; ``"mix"`` and
  ``"asinh"`` fix that (:func:`~adaptfilt.features.fit_scaler`).
* **Two modes, one code path.** ``parallel=1`` is paper-faithful: one episode
  at a time, one Adam step per time step, actions sampled. ``parallel=B`` runs
  B episodes as one batched environment and makes one Adam step per time step
  with the losses *averaged* over the B runs (same learning rates); the total
  number of episodes is still ``episodes``, so there are B times fewer
  updates, each with a B times less noisy gradient.
* **Randomness.** Episode ``m`` (or the batch starting at ``m``) simulates
  with ``np.random.default_rng([seed, 1, m])`` and uses ``stream=m`` for a
  stochastic rule; actions are drawn from ``default_rng([seed, 2])``; the
  networks are initialised under ``torch.manual_seed(seed)`` (PyTorch default
  initialisation) inside a forked RNG, so the caller's torch RNG is untouched.
  Training uses one torch thread (faster for these tiny networks, see
  ``benchmarks/bench_train.py``, and deterministic).
* **Checkpoints.** Every ``checkpoint_every`` episodes the complete training
  state (actor, critic, target critic, both Adam states, action RNG, torch
  RNG, episode counter, learning curve so far) is written atomically to
  ``checkpoint``; ``resume=True`` continues from it and ends with exactly the
  same weights as an uninterrupted run. :func:`train_experiment` deletes the
  checkpoint once the policy file is written.

>>> from adaptfilt.toy import BanditEnv
>>> pol, curve = train(BanditEnv(n_steps=5), gamma=0.0, episodes=4, parallel=2, seed=0,
...                    cost_transform="none", progress=False)
>>> pol.name, curve["cost"].shape
('myopic', (4,))
"""
from __future__ import annotations

import copy
import dataclasses
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from adaptfilt._version import __version__
from adaptfilt.costs import transform_cost
from adaptfilt.experiment_registry import resolve
from adaptfilt.features import FeatureScaler, FeatureSet, fit_scaler, observe
from adaptfilt.files import read_npz, write_npz
from adaptfilt.learned import Actor, Critic, LearnedPolicy
from adaptfilt.nets import adam_to_arrays, arrays_to_adam, arrays_to_state, state_to_arrays

__all__ = ["Hyper", "train", "train_experiment", "soft_update", "checkpoint_path"]


@dataclass(frozen=True)
class Hyper:
    """Hyperparameters of Algorithm 2 (defaults: Section VI-C of the paper)."""

    lr_actor: float = 1e-4
    lr_critic: float = 5e-4
    betas: tuple[float, float] = (0.9, 0.999)
    tau: float = 0.01              # target critic Polyak coefficient
    entropy_coef: float = 1e-3     # beta
    hidden: tuple[int, ...] = (64, 64)
    cost_transform: str = "log1p"  # "log1p" (default, see module docstring) or "none"
    actor_sign: int = 1            # +1: correct for a cost; -1: the paper's printed sign (demonstration only)
    scaler_runs: int = 64          # runs of the rollout the feature scaler is fitted on
    torch_threads: int = 1
    features: str | None = None    # the information state (adaptfilt.features); None: the experiment's, else "paper"
    scaler_visit: str = "mix"      # states the scaler is fitted on: a "mix" of grid values, or the "default" policy's
    scaler_squash: str = "asinh"   # "asinh" (never saturates) or "clip" at +-10
    bootstrap_at_limit: bool = True  # the last step is a time limit: bootstrap from the next state
    repair_penalty: float = 0.0    # added to the transformed cost of a run whose covariance was repaired


#: Fields added after policies were stored: recorded only when not at their default, so that the
#: stored files' commands still reproduce them byte for byte.
_LATER_FIELDS = {"repair_penalty": 0.0}


def _hyper_record(H: Hyper) -> dict:
    return {k: v for k, v in asdict(H).items() if not (k in _LATER_FIELDS and v == _LATER_FIELDS[k])}


@torch.no_grad()
def soft_update(target: torch.nn.Module, source: torch.nn.Module, tau: float) -> None:
    """Polyak averaging ``psi_bar <- tau * psi + (1 - tau) * psi_bar`` (Algorithm 2, last line)."""
    tp, sp = list(target.parameters()), list(source.parameters())
    torch._foreach_mul_(tp, 1.0 - tau)
    torch._foreach_add_(tp, sp, alpha=tau)


def checkpoint_path(out: str | Path) -> Path:
    """``OUT.ckpt.npz`` next to the policy file ``OUT.npz``."""
    out = Path(out)
    return out.with_name((out.name[:-4] if out.name.endswith(".npz") else out.name) + ".ckpt.npz")


def _summary(curve: dict[str, np.ndarray], grid) -> dict[str, Any]:
    """A compact learning-curve summary (first and last 10% of the episodes)."""
    n = len(curve["cost"])
    if n == 0:
        return {}
    w = max(1, n // 10)
    f = lambda k, s: float(np.mean(curve[k][s]))
    return {
        "episodes": n,
        "cost_first10pct": f("cost", slice(0, w)), "cost_last10pct": f("cost", slice(n - w, n)),
        "train_cost_first10pct": f("train_cost", slice(0, w)), "train_cost_last10pct": f("train_cost", slice(n - w, n)),
        "entropy_first10pct": f("entropy", slice(0, w)), "entropy_last10pct": f("entropy", slice(n - w, n)),
        "critic_loss_last10pct": f("critic_loss", slice(n - w, n)),
        "action_frac_last10pct": {f"{g:g}": float(x) for g, x in zip(grid, curve["action_frac"][n - w:].mean(axis=0))},
        "nonfinite_costs": int(curve["nonfinite"].sum()),
    }


def train(env_or_experiment, gamma: float = 0.5, episodes: int = 1000, parallel: int = 1, seed: int = 0, *,
          n_steps: int | None = None, progress: bool = True, checkpoint: str | Path | None = None,
          checkpoint_every: int = 50, resume: bool = False, stop_after: int | None = None,
          command: str | None = None, name: str | None = None, **hyper) -> tuple[LearnedPolicy, dict]:
    """Train an actor-critic policy with Algorithm 2.

    Parameters
    ----------
    env_or_experiment
        An experiment name (``"ungm-ukf"``), an :class:`~adaptfilt.experiment_registry.Experiment`,
        a :class:`~adaptfilt.mdp.FilterEnv` or any env with the same interface (``adaptfilt.toy``).
    gamma : discount in [0, 1) (0 = myopic); anything else is a ValueError.
    episodes : N_MC, the total number of simulated episodes.
    parallel : episodes simulated and learned from together (1 = paper-faithful).
    seed : seeds everything (networks, trajectories, actions, stochastic rules).
    n_steps : horizon (default: the model's).
    checkpoint, checkpoint_every, resume : see the module docstring.
    stop_after : stop once this many episodes are done (writing a checkpoint), as
        an interruption would; used to test ``resume``.
    **hyper : fields of :class:`Hyper` (learning rates, tau, ``cost_transform``, ``actor_sign`` ...).

    Returns
    -------
    (LearnedPolicy, curve) where ``curve`` holds one entry per episode:
    ``cost`` (mean raw cost), ``train_cost`` (mean transformed cost), ``entropy``
    (mean policy entropy), ``critic_loss`` (mean delta^2), ``action_frac`` ((episodes, |grid|))
    and ``nonfinite`` (non-finite costs replaced by the largest float).
    """
    H = Hyper(**hyper)
    # A discount: gamma < 0 means nothing, and with gamma >= 1 V would be the (growing) sum of the
    # remaining costs, which the time-free information state cannot represent.
    if not (isinstance(gamma, (int, float, np.number)) and 0.0 <= float(gamma) < 1.0):
        raise ValueError(f"gamma must be a discount in [0, 1), got {gamma!r}")
    if H.actor_sign not in (1, -1):
        raise ValueError("actor_sign must be +1 (correct) or -1 (the paper's printed sign)")
    if episodes < 1 or parallel < 1:
        raise ValueError("episodes and parallel must be >= 1")
    target = resolve(env_or_experiment, seed, n_steps)
    env, experiment, recommended = target.env, target.name, target.features
    if H.features is None:
        H = dataclasses.replace(H, features=recommended or "paper")
    desc = env.describe()
    grid = np.asarray(env.grid, dtype=float)
    G = grid.size
    config = {"experiment": experiment, "gamma": float(gamma), "episodes": int(episodes), "parallel": int(parallel),
              "seed": int(seed), "n_steps": int(env.n_steps), "hyper": _hyper_record(H)}
    config = json.loads(json.dumps(config))  # tuples -> lists: comparable with a checkpoint's copy
    threads = torch.get_num_threads()
    torch.set_num_threads(H.torch_threads)
    try:
        # ---- Input: Theta, gamma, N_MC, T, tau, actor pi(theta | s; phi), critic V(s; psi)
        fs = FeatureSet.parse(H.features)
        scaler = fit_scaler(env, fs, runs=H.scaler_runs, seed=seed, visit=H.scaler_visit, squash=H.scaler_squash)
        d_in = scaler.center.shape[0]
        # ---- "Initialize actor phi, critic psi and target critic psi_bar <- psi"
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            actor, critic = Actor(d_in, G, H.hidden), Critic(d_in, H.hidden)
            torch_rng = torch.get_rng_state()
        target = copy.deepcopy(critic).requires_grad_(False)
        opt_actor = torch.optim.Adam(actor.parameters(), lr=H.lr_actor, betas=H.betas)
        opt_critic = torch.optim.Adam(critic.parameters(), lr=H.lr_critic, betas=H.betas)
        rng_act = np.random.default_rng([seed, 2])
        curve: dict[str, list] = {k: [] for k in ("cost", "train_cost", "entropy", "critic_loss", "action_frac", "nonfinite")}
        episode = 0

        if resume and checkpoint is not None and Path(checkpoint).exists():
            arrays, meta = read_npz(checkpoint)
            if meta.get("config") != config:
                raise ValueError(f"checkpoint {checkpoint} was written by a different training "
                                 f"({meta.get('config')}), not {config}")
            actor.load_state_dict(arrays_to_state("actor", arrays))
            critic.load_state_dict(arrays_to_state("critic", arrays))
            target.load_state_dict(arrays_to_state("target", arrays))
            arrays_to_adam("adam_actor", opt_actor, arrays)
            arrays_to_adam("adam_critic", opt_critic, arrays)
            rng_act.bit_generator.state = meta["rng_act"]
            torch_rng = torch.from_numpy(arrays["torch_rng"].copy())
            scaler = FeatureScaler(arrays["scaler/center"], arrays["scaler/scale"], float(meta["scaler"]["clip"]),
                                   tuple(meta["scaler"]["names"]), meta["scaler"].get("squash", "clip"))
            episode = int(meta["episode"])
            for k in curve:
                curve[k] = list(arrays[f"curve/{k}"])

        def save_checkpoint() -> None:
            arrays = {**state_to_arrays("actor", actor), **state_to_arrays("critic", critic),
                      **state_to_arrays("target", target), **adam_to_arrays("adam_actor", opt_actor),
                      **adam_to_arrays("adam_critic", opt_critic), "torch_rng": torch_rng.numpy().copy(),
                      "scaler/center": scaler.center, "scaler/scale": scaler.scale,
                      **{f"curve/{k}": np.asarray(v, dtype=float).reshape((len(v), G) if k == "action_frac" else (len(v),))
                         for k, v in curve.items()}}
            meta = {"config": config, "episode": episode, "rng_act": rng_act.bit_generator.state,
                    "scaler": {"clip": scaler.clip, "names": list(scaler.names), "squash": scaler.squash}}
            write_npz(checkpoint, arrays, meta)

        def features(dec) -> torch.Tensor:
            return torch.from_numpy(scaler.network_input(observe(dec, fs)))

        gamma_t = float(gamma)
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=episodes, initial=episode, desc=f"train {experiment or desc['model'] or 'env'} gamma={gamma:g}",
                       unit="ep")
        stop = episodes if stop_after is None else min(episodes, int(stop_after))
        while episode < stop:  # ---- "for m = 1 to N_MC" (B episodes at a time)
            B = min(parallel, episodes - episode)
            # ---- "Reset simulator and filter state"; the first Predict is the prior
            d = env.reset(n_runs=B, rng=np.random.default_rng([seed, 1, episode]), stream=episode)
            s = features(d)  # ---- "Construct s_k from x_{k|k-1}, P_{k|k-1}" (and z_k, innovation)
            ep_cost, ep_tcost, ep_H, ep_closs = np.zeros(B), np.zeros(B), 0.0, 0.0
            counts, nonfinite, n = np.zeros((B, G)), 0, 0
            done = False
            while not done:  # ---- "for k = 1 to T"
                # ---- "Sample theta_k ~ pi(. | s_k, z_k; phi)"
                logits = actor(s)
                logp = torch.log_softmax(logits, dim=-1)
                p = logp.detach().exp().double().numpy()
                cdf = np.cumsum(p, axis=1)
                a = np.minimum((cdf < rng_act.random(B)[:, None] * cdf[:, -1:]).sum(axis=1), G - 1)
                # ---- "Update(theta_k)", "Compute cost L_k", "Predict", "Construct s_{k+1}"
                d, cost, done, info = env.step(a)
                bad = ~np.isfinite(cost)
                if bad.any():
                    nonfinite += int(bad.sum())
                    cost = np.where(bad, np.finfo(float).max, cost)
                tc = transform_cost(cost, H.cost_transform)
                if H.repair_penalty:
                    tc = tc + H.repair_penalty * info.get("repaired", 0.0)
                c = torch.from_numpy(tc.astype(np.float32))
                # ---- "delta_k <- L_k + gamma V_target(s_{k+1}) - V(s_k)"; at the horizon: a time limit
                #      (bootstrap from the final state) or, with bootstrap_at_limit=False, a terminal state
                final = info.get("final_decision") if H.bootstrap_at_limit else None
                if done and final is None:
                    td_target = c
                else:
                    s_next = features(d if not done else final)
                    with torch.no_grad():
                        td_target = c + gamma_t * target(s_next)
                delta = td_target - critic(s)
                # ---- "L_critic <- delta_k^2"  (averaged over the B runs)
                critic_loss = (delta ** 2).mean()
                # ---- "L_actor <- -delta_k log pi(theta_k | s_k)": sign corrected for a cost (+), see docstring;
                #      minus the entropy bonus beta * H(pi(. | s_k))
                logp_a = logp[torch.arange(B), torch.from_numpy(a)]
                entropy = -(logp.exp() * logp).sum(dim=-1)
                actor_loss = (H.actor_sign * delta.detach() * logp_a - H.entropy_coef * entropy).mean()
                # ---- "Update psi and phi using Adam"
                opt_actor.zero_grad(set_to_none=True)
                opt_critic.zero_grad(set_to_none=True)
                (critic_loss + actor_loss).backward()  # disjoint parameters: one backward, two gradients
                opt_critic.step()
                opt_actor.step()
                # ---- "Update target critic: psi_bar <- tau psi + (1 - tau) psi_bar"
                soft_update(target, critic, H.tau)
                # logging
                ep_cost += cost
                ep_tcost += c.numpy()
                ep_H += float(entropy.detach().mean())
                ep_closs += float(critic_loss.detach())
                counts[np.arange(B), a] += 1
                n += 1
                if not done:
                    s = s_next
            curve["cost"] += list(ep_cost / n)
            curve["train_cost"] += list(ep_tcost / n)
            curve["entropy"] += [ep_H / n] * B
            curve["critic_loss"] += [ep_closs / n] * B
            curve["action_frac"] += list(counts / n)
            curve["nonfinite"] += [nonfinite / B] * B
            prev, episode = episode, episode + B
            if bar is not None:
                bar.update(B)
                bar.set_postfix(cost=f"{np.median(curve['cost'][-50:]):.3g}", H=f"{ep_H / n:.3f}")
            if checkpoint is not None and (episode // checkpoint_every > prev // checkpoint_every
                                           or episode == stop < episodes):
                save_checkpoint()
        if bar is not None:
            bar.close()
    finally:
        torch.set_num_threads(threads)

    curve_arr = {k: np.asarray(v, dtype=float) for k, v in curve.items()}
    curve_arr["action_frac"] = curve_arr["action_frac"].reshape(-1, G)
    metadata = {
        **desc, "experiment": experiment, "feature_names": list(scaler.names), "feature_set": fs.name,
        "cost_transform": H.cost_transform, "seed": int(seed), "episodes": int(episodes), "parallel": int(parallel),
        "episodes_done": int(episode), "n_steps": int(env.n_steps),
        "hyper": _hyper_record(H), "default_index": int(getattr(env, "default_index", 0)),
        "updates": int(-(-episode // parallel) * env.n_steps),
        "version": __version__, "command": command, "torch_version": torch.__version__.split("+")[0],
        "curve_summary": _summary(curve_arr, grid),
    }
    policy = LearnedPolicy(actor, scaler, grid, gamma=gamma, name=name, metadata=metadata, curve=curve_arr)
    return policy, curve_arr


def train_experiment(name: str, out: str | Path, gamma: float = 0.5, episodes: int = 1000, parallel: int = 1,
                     seed: int = 0, resume: bool = False, progress: bool = True, command: str | None = None,
                     policy_name: str | None = None, **kwargs) -> LearnedPolicy:
    """``adaptfilt train NAME ...``: train on a named experiment, write the policy
    file ``out`` (checkpoints in ``OUT.ckpt.npz``, deleted at the end); ``policy_name``
    names the policy (default: by its gamma)."""
    out = Path(out)
    ckpt = checkpoint_path(out)
    if resume and not ckpt.exists():
        print(f"no checkpoint {ckpt}: starting from scratch")
    t0 = time.perf_counter()
    policy, curve = train(name, gamma=gamma, episodes=episodes, parallel=parallel, seed=seed, progress=progress,
                          checkpoint=ckpt, resume=resume, command=command, name=policy_name, **kwargs)
    if policy.metadata["episodes_done"] < episodes:  # stopped early (stop_after): keep the checkpoint
        return policy
    policy.save(out)
    ckpt.unlink(missing_ok=True)
    s = policy.metadata["curve_summary"]
    print(f"wrote {out} ({policy.name}, {episodes} episodes, parallel={parallel}, "
          f"{time.perf_counter() - t0:.0f} s); train cost first/last 10%: "
          f"{s['train_cost_first10pct']:.3g} -> {s['train_cost_last10pct']:.3g}")
    return policy
