r"""Out of distribution: policies trained on the paper's models, run where the world differs.

The paper leaves robustness and retuning as future work. A policy is trained
on the nominal model; here the *truth* that generates the trajectories has
its process noise ``Q`` and measurement noise ``R`` scaled by factors
``(q, r)`` while every filter keeps the nominal model (the practitioner does
not know the mismatch). On each condition of a grid of factors, on the same
paired runs, we evaluate the default, every fixed value (so that the *best
fixed value in hindsight* for that condition is known), the exhaustive
greedy policy (which uses the nominal model's cost) and the learned
policies (all training seeds); then each learned policy is **retuned** with a
small budget on the mismatched world, starting from its trained actor
(:func:`retune`), and evaluated again on the same runs.

Reported per condition: each policy's mean cost and RMSE, and its *gain over
the default* (the default's minus the policy's: positive is better); the
learned groups as IQM over seeds with the two-level interval. :func:`plot_gain`
draws the heat map of the gain over the conditions.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Condition", "CONDITIONS", "truth_model", "evaluate_condition", "retune", "gain_table", "plot_gain"]

#: Scale factors of Q and R (3 x 3, nominal in the centre).
FACTORS = (0.25, 1.0, 4.0)


@dataclass(frozen=True)
class Condition:
    """Truth noise = nominal noise scaled by ``q`` (process) and ``r`` (measurement)."""

    q: float
    r: float

    @property
    def name(self) -> str:
        return f"Q x{self.q:g}, R x{self.r:g}"

    @property
    def key(self) -> str:
        return f"q{self.q:g}-r{self.r:g}"


CONDITIONS = tuple(Condition(q, r) for q in FACTORS for r in FACTORS)


def truth_model(experiment: str, condition: Condition):
    """The experiment's model with ``Q`` and ``R`` scaled (same functions, prior, horizon):
    :func:`adaptfilt.experiment_registry.scaled_truth`."""
    from adaptfilt.experiment_registry import get_experiment, scaled_truth

    return scaled_truth(get_experiment(experiment).make_model(), condition.q, condition.r)


def mismatched_env(experiment: str, condition: Condition, seed: int = 0, n_steps: int | None = None):
    """The nominal filter and cost, trajectories from the scaled truth (the experiment's variant)."""
    from adaptfilt.experiment_registry import get_experiment

    return get_experiment(experiment).make_env(seed=seed, n_steps=n_steps, truth=truth_model(experiment, condition))


def evaluate_condition(experiment: str, condition: Condition, policies: list, n_runs: int = 2000,
                       seed: int = 0, n_steps: int | None = None):
    """Every baseline of the experiment and ``policies`` on the same runs of the mismatched truth."""
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import get_experiment

    exp = get_experiment(experiment)
    env = mismatched_env(experiment, condition, seed, n_steps)
    base = [p for p in exp.baselines() if p.kind != "fixed-both"]
    res = evaluate(env, base + list(policies), n_runs=n_runs, seed=seed, progress=False)
    res.config.update(experiment=experiment, condition=condition.key)
    return res


def retune(policy, experiment: str, condition: Condition, episodes: int = 50, seed: int = 0,
           n_envs: int = 16, critic_warmup: float = 0.5, n_steps: int | None = None):
    """Continue training ``policy`` (a :class:`~adaptfilt.learned.LearnedPolicy` with a ReLU actor) on the
    mismatched world for ``episodes`` episodes with SB3's A2C (:data:`adaptfilt.trainers.A2C_FAST`:
    an update every 5 steps of 16 runs; the PPO fast mode would make only one or two rollouts of a
    50-episode budget), starting from its actor.

    The critic starts untrained: its first advantages are noise, which would push the trained actor
    around. So for the first ``critic_warmup`` fraction of the budget only the critic learns (the
    actor's parameters are frozen), then both. The policy keeps its feature scaling (the retuned
    policy sees the same features, scaled the same way). Returns a new LearnedPolicy.
    """
    import torch
    from stable_baselines3 import A2C
    from stable_baselines3.common.logger import Logger

    import adaptfilt.gym as afg
    from adaptfilt.trainers import A2C_FAST

    env = mismatched_env(experiment, condition, seed, n_steps)
    venv = afg.SB3VecEnv(afg.FilterVectorEnv(env, n_envs, policy.feature_set, policy.scaler, seed=seed))
    venv.seed(seed)
    hidden = list(policy.actor.hidden)
    act = {"relu": torch.nn.ReLU, "tanh": torch.nn.Tanh}[policy.actor.activation]
    with torch.random.fork_rng(devices=[]):
        model = A2C("MlpPolicy", venv, gamma=policy.gamma, seed=seed, device="cpu", verbose=0,
                    policy_kwargs={"activation_fn": act, "net_arch": {"pi": hidden, "vf": hidden}}, **A2C_FAST.kwargs)
        model.set_logger(Logger(folder=None, output_formats=[]))  # else SB3 makes a folder in the temporary directory
        theirs = [m for m in model.policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
        theirs.append(model.policy.action_net)
        mine = [m for m in policy.actor.net if isinstance(m, torch.nn.Linear)]
        actor_params = []
        with torch.no_grad():
            for a, b in zip(theirs, mine):
                a.weight.copy_(b.weight)
                a.bias.copy_(b.bias)
                actor_params += [a.weight, a.bias]
        total = int(episodes) * env.n_steps
        warm = int(critic_warmup * total)
        if warm:
            for p in actor_params:
                p.requires_grad_(False)
            model.learn(warm)
            for p in actor_params:
                p.requires_grad_(True)
        model.learn(total - warm, reset_num_timesteps=False)
    new = afg.to_learned_policy(model, venv, gamma=policy.gamma, name=f"{policy.name}-retuned",
                                metadata={"retuned_from": policy.metadata.get("command"), "condition": condition.key,
                                          "retune_episodes": int(episodes), "seed": int(seed)})
    return new


def gain_table(results: dict, groups: dict[str, list[str]], metric: str = "cost") -> dict:
    """``{condition key: {policy or group: gain over default}}``; groups as IQM over seeds with CI,
    plus the best fixed value in hindsight and greedy."""
    from adaptfilt.seed_stats import difference

    out = {}
    for key, res in results.items():
        row = {}
        bf = res.best_fixed(metric)
        for name in ("greedy", bf):
            d, lo, hi = res.paired_difference("default", name, metric)
            row["best fixed" if name == bf else name] = {"gain": d, "ci": [lo, hi], "policy": name}
        for g, names in groups.items():
            present = [n for n in names if n in res]
            if present:
                d = difference(res, ["default"], present, metric)["iqm"]
                row[g] = {"gain": d[0], "ci": [d[1], d[2]], "n_seeds": len(present)}
        out[key] = row
    return out


def plot_gain(table: dict, column: str, metric: str = "cost", ax=None, title: str | None = None,
              vmax: float | None = None):
    """Heat map of the gain over the default of ``column`` on the q x r grid (positive: better)."""
    import matplotlib.pyplot as plt

    G = np.full((len(FACTORS), len(FACTORS)), np.nan)
    for i, q in enumerate(FACTORS):
        for j, r in enumerate(FACTORS):
            cell = table.get(Condition(q, r).key, {}).get(column)
            if cell is not None:
                G[i, j] = cell["gain"]
    if ax is None:
        fig, ax = plt.subplots(figsize=(4.2, 3.6), layout="constrained")
    else:
        fig = ax.figure
    v = vmax or np.nanmax(np.abs(G)) or 1.0
    im = ax.imshow(G, cmap="RdBu", vmin=-v, vmax=v, origin="lower")
    ax.grid(False)
    for i in range(G.shape[0]):
        for j in range(G.shape[1]):
            if np.isfinite(G[i, j]):
                ax.text(j, i, f"{G[i, j]:.3g}", ha="center", va="center", fontsize=9,
                        color="white" if abs(G[i, j]) > 0.6 * v else "black")  # readable on dark cells
    ax.set_xticks(range(len(FACTORS)), [f"x{f:g}" for f in FACTORS])
    ax.set_yticks(range(len(FACTORS)), [f"x{f:g}" for f in FACTORS])
    ax.set_xlabel("truth R / nominal R")
    ax.set_ylabel("truth Q / nominal Q")
    ax.set_title(title or f"{column}: {metric} gain over default", fontsize=10)
    fig.colorbar(im, ax=ax, shrink=0.8)
    return fig
