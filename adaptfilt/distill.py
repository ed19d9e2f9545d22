r"""Distilling the rollout reference into a policy anchored on greedy (:mod:`adaptfilt.anchor`).

:func:`rollout_data` records states and the rollout policy's Q-value estimates
(:mod:`adaptfilt.lookahead`) along its own trajectories; :func:`distill_rollout` fits the anchored
residual form of :mod:`adaptfilt.anchor` to them (a supervised trainer, no look-ahead at run time)
and returns a :class:`~adaptfilt.learned.LearnedPolicy`. Moved out of :mod:`adaptfilt.anchor`, which
:mod:`adaptfilt.learned` imports, so that the policy form and this trainer do not import each other.
"""
from __future__ import annotations

import numpy as np

from adaptfilt.anchor import DEFAULT_STRENGTH, Anchor, greedy_index

__all__ = ["rollout_data", "distill_rollout"]

#: keys the distillation's trajectories apart from training and evaluation runs
_DISTILL_KEY = 0xD157


def rollout_data(experiment, seed: int = 0, *, runs: int = 500, features: str | None = None,
                 n_steps: int | None = None, horizon: int = 1, samples: int = 4, gamma: float = 0.5,
                 progress: bool = False) -> dict:
    """States and rollout Q-values along the rollout policy's own trajectories: the data of
    :func:`distill_rollout`.

    ``runs`` trajectories from ``default_rng([seed, _DISTILL_KEY])`` (stream ``seed``) of the experiment's
    environment (filter seeded with ``seed``), driven by :class:`~adaptfilt.lookahead.RolloutPolicy`
    (greedy base policy, ``horizon``, ``samples``, ``gamma``, its continuations keyed by ``seed``).
    Returns ``{"features" (N, d) raw information states of the feature set, "greedy" (N,) greedy's
    choice, "q" (N, G) the rollout estimate of every candidate's discounted cost}``, ``N = runs * T``.
    """
    from adaptfilt.experiment_registry import resolve
    from adaptfilt.features import observe
    from adaptfilt.lookahead import RolloutPolicy

    # an environment of one's own (a FilterEnv, or a toy MDP with a look-ahead model) keeps its horizon
    target = resolve(experiment, seed=seed, n_steps=n_steps)
    fs, env, label = features or target.features or "paper", target.env, target.name
    teacher = RolloutPolicy(env.grid, horizon=horizon, samples=samples, gamma=gamma, seed=seed)
    d = env.reset(n_runs=int(runs), rng=np.random.default_rng([seed, _DISTILL_KEY]), stream=seed)
    X, g, Q = [], [], []
    steps = range(env.n_steps)
    if progress:
        from tqdm.auto import tqdm

        steps = tqdm(steps, desc=f"rollout data {label} seed={seed}", leave=False)
    for _ in steps:
        X.append(observe(d, fs))
        g.append(greedy_index(d))
        q = teacher.q(d)
        Q.append(q.T)
        d, _, _, _ = env.step(np.argmin(np.where(np.isnan(q), np.inf, q), axis=0))
    return {"features": np.concatenate(X), "greedy": np.concatenate(g), "q": np.concatenate(Q),
            "feature_set": fs, "env": env, "experiment": label}


def distill_rollout(experiment, seed: int = 0, *, runs: int = 500, features: str | None = None,
                    n_steps: int | None = None, horizon: int = 1, samples: int = 4, gamma: float = 0.5,
                    strength: float = DEFAULT_STRENGTH, kl: float = 1.0, epochs: int = 20, lr: float = 1e-3,
                    batch_size: int = 1024, clip: float = 100.0, progress: bool = False,
                    command: str | None = None, name: str | None = None, data: dict | None = None):
    r"""An anchored policy trained on rollout's Q-values instead of by PPO: one step of
    KL-regularised, classification-based policy iteration with greedy as the base policy.

    Rollout improves on its base policy (Bertsekas); approximate policy iteration by
    classification (Lagoudakis and Parr 2003; Lazaric, Ghavamzadeh and Munos 2010, "DPI")
    fits a policy to the rollout's choices so that the improvement holds without simulating at
    run time. Here the fit is cost-sensitive and anchored: with ``A(theta) = Q(theta) - Q(greedy)``
    the rollout estimate of what choosing ``theta`` instead of greedy's value saves (negative: a
    saving; :func:`rollout_data`), in units of the mean saving rollout finds per step and clipped at
    ``+-clip``, the actor minimises

    .. math::
        \mathbb E_s\Big[\sum_\theta \pi(\theta|s) A(s, \theta) + \beta\,
        \mathrm{KL}\big(\pi(\cdot|s)\,\|\,\pi_0(\cdot|s)\big)\Big],

    whose minimiser over all policies is ``pi ∝ pi_0 exp(-A / beta)``: the residual form of
    :mod:`adaptfilt.anchor` with the network in the place of ``-A / beta``, so the policy
    leaves greedy (at its argmax) only where the expected saving exceeds ``beta * c`` mean savings,
    and stays at greedy where rollout finds nothing. Weighting by the saving itself (not counting
    choices) is what the mean cost needs: rare steps with large savings are most of it.

    The policy acts from its information state (``features``, default the experiment's) and greedy's
    candidates only: no look-ahead at run time. ``epochs=0`` returns the untrained policy (greedy). Deterministic for a seed (data, network
    initialisation and minibatches; one torch thread). Returns a
    :class:`~adaptfilt.learned.LearnedPolicy` with ``anchor`` metadata (acts identically from its file).
    """
    import torch

    from adaptfilt._version import __version__
    from adaptfilt.features import FeatureSet, fit_scaler
    from adaptfilt.learned import Actor, LearnedPolicy
    from adaptfilt.nets import one_torch_thread

    spec = Anchor("greedy", strength, kl)
    for k, v, lo in (("runs", runs, 1), ("epochs", epochs, 0), ("batch_size", batch_size, 1)):
        if not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{k} must be an integer >= {lo}, got {v!r}")
    if not (np.isfinite(lr) and lr > 0) or not (np.isfinite(clip) and clip > 0):
        raise ValueError(f"lr and clip must be finite and > 0, got {lr!r}, {clip!r}")
    data = data or rollout_data(experiment, seed, runs=runs, features=features, n_steps=n_steps, horizon=horizon,
                                samples=samples, gamma=gamma, progress=progress)
    env, fs = data["env"], data["feature_set"]
    scaler = fit_scaler(env, fs, seed=seed)  # as the Gymnasium adapter fits it for the same seed
    q = np.where(np.isfinite(data["q"]), data["q"], np.finfo(float).max / 1e10)
    N, G = q.shape
    A = q - q[np.arange(N), data["greedy"]][:, None]
    saving = np.maximum(0.0, -A.min(axis=1))
    unit = float(saving.mean()) if saving.mean() > 0 else 1.0
    A = np.clip(A / unit, -clip, clip)
    onehot = np.zeros((N, G), dtype=np.float32)
    onehot[np.arange(N), data["greedy"]] = 1.0
    with one_torch_thread(), torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        actor = Actor(scaler.center.shape[0], G)
        last = [m for m in actor.net if isinstance(m, torch.nn.Linear)][-1]
        with torch.no_grad():  # the untrained policy is pi_0: greedy at its argmax
            last.weight.zero_()
            last.bias.zero_()
        X = torch.from_numpy(scaler.network_input(data["features"]))
        At, Ot = torch.from_numpy(A.astype(np.float32)), torch.from_numpy(onehot)
        logp0 = torch.log_softmax(spec.strength * Ot, dim=-1)
        opt = torch.optim.Adam(actor.parameters(), lr=lr)
        gen = torch.Generator().manual_seed(seed)
        curve = []
        for _ in range(int(epochs)):
            perm, tot = torch.randperm(N, generator=gen), 0.0
            for lo in range(0, N, int(batch_size)):
                i = perm[lo:lo + int(batch_size)]
                logp = torch.log_softmax(actor(X[i]) + spec.strength * Ot[i], dim=-1)
                p = logp.exp()
                loss = (p * At[i]).sum(-1).mean() + spec.kl * (p * (logp - logp0[i])).sum(-1).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
                tot += float(loss.detach()) * i.numel()
            curve.append(tot / N)
    meta = {**env.describe(fs), "experiment": data["experiment"], "feature_set": FeatureSet.parse(fs).name,
            "algo": "rollout-distill", "seed": int(seed), "runs": int(runs), "n_steps": int(env.n_steps),
            "teacher": {"policy": "rollout", "horizon": int(horizon), "samples": int(samples), "gamma": float(gamma)},
            "trainer": {"epochs": int(epochs), "lr": float(lr), "batch_size": int(batch_size), "clip": float(clip),
                        "saving_unit": unit},
            "anchor": spec.to_dict(), "command": command, "version": __version__,
            "torch_version": torch.__version__.split("+")[0]}
    return LearnedPolicy(actor, scaler, env.grid, gamma=gamma, name=name, metadata=meta,
                         curve={"train_loss": np.asarray(curve)})

