r"""One PPO update by hand, in the notation of Algorithm 2 (chapter 7).

Every stored policy of the course was trained by PPO (Schulman et al. 2017) as
Stable-Baselines3 implements it (the fast mode, :data:`adaptfilt.trainers.FAST`).
This module writes one PPO update out in the course's notation, a *cost*
:math:`\bar L'_k = \log(1 + \bar L_k)` to minimise and a critic
:math:`V_\psi(\bar{\mathbf s}_k, \mathbf z_k)` of the expected discounted cost to
go, small enough to step through, and checks it against SB3's own computation
(:func:`sb3_reference`; ``tests/test_ppo_step.py``). SB3 maximises a reward
:math:`r_k = -\bar L'_k` with a value :math:`-V_\psi`; every quantity below is
SB3's with its sign flipped, and the loss is the same number.

**GAE(lambda)** (:func:`gae`). With the TD error of Algorithm 2,

.. math::

    \delta_k = \bar L'_k + \gamma (1 - e_k) V_\psi(\bar{\mathbf s}_{k+1})
               - V_\psi(\bar{\mathbf s}_k),

(``e_k = 1`` when step ``k`` ended its episode), the advantage is an
exponentially weighted sum of the TD errors that follow,

.. math::

    \hat A_k = \sum_{l \ge 0} (\gamma\lambda)^l \delta_{k+l}
             = \delta_k + \gamma\lambda (1 - e_k) \hat A_{k+1},

computed backwards over a rollout of ``K`` steps from the critic's value of the
state after the last one. :math:`\lambda = 0` gives Algorithm 2's
:math:`\delta_k`, :math:`\lambda = 1` the Monte-Carlo cost to go minus
:math:`V_\psi`. The critic's target is the lambda-return
:math:`G_k = \hat A_k + V_\psi(\bar{\mathbf s}_k)`. A *negative*
:math:`\hat A_k` means the action did better (cheaper) than expected.

**The loss** (:func:`ppo_loss`), over a minibatch, with the advantages normalised
(:math:`\tilde A_k = (\hat A_k - \mathrm{mean}) / (\mathrm{std} + 10^{-8})`) and
the probability ratio of the new to the rollout's (old) policy
:math:`\rho_k = \pi_\phi(\boldsymbol\theta_k | \bar{\mathbf s}_k) /
\pi_{\phi_\text{old}}(\boldsymbol\theta_k | \bar{\mathbf s}_k)`:

.. math::

    \mathcal L = \underbrace{\mathrm{mean}_k \max\big(\rho_k \tilde A_k,\;
    \mathrm{clip}(\rho_k, 1-\epsilon, 1+\epsilon)\,\tilde A_k\big)}_{\text{clipped surrogate}}
    + c_V \underbrace{\mathrm{mean}_k \big(V_\psi(\bar{\mathbf s}_k) - G_k\big)^2}_{\text{value loss}}
    - \beta \underbrace{\mathrm{mean}_k H(\pi_\phi(\cdot | \bar{\mathbf s}_k))}_{\text{entropy}}.

For a cost the surrogate takes the *max* (SB3's ``-min`` of the reward form): the
pessimistic of the two, so that moving :math:`\rho_k` beyond :math:`1 \pm \epsilon`
in the direction the advantage favours earns nothing. At :math:`\rho_k = 1` its
gradient is :math:`\mathrm{mean}_k\,\tilde A_k \nabla\log\pi_\phi`, Algorithm 2's
actor gradient (corrected sign) with :math:`\tilde A_k` for :math:`\delta_k`.
One update is ``epochs`` passes of Adam steps over the rollout (here one minibatch
of the whole rollout), gradients clipped at a global norm.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["gae", "ppo_loss", "TinyPolicy", "collect", "ppo_update", "sb3_reference", "check_gae"]


def gae(costs, values, last_values, gamma: float, lam: float, ends=None, last_ends=None):
    r"""GAE(lambda) advantages and lambda-returns of a rollout, in costs.

    ``costs``, ``values``: ``(K, M)`` (``K`` steps of ``M`` runs; ``values`` is
    :math:`V_\psi(\bar{\mathbf s}_k)`), ``last_values``: ``(M,)``, the critic at the
    state after step ``K - 1``. ``ends``: ``(K, M)`` bools, step ``k`` ended its
    episode (no bootstrap past it; default none). ``last_ends`` is ``ends[-1]``
    (kept separate as SB3's ``dones``; default ``ends[-1]``). Returns
    ``(advantages, returns)``, both ``(K, M)``::

        delta_k = L'_k + gamma (1 - e_k) V_{k+1} - V_k
        A_k     = delta_k + gamma lam (1 - e_k) A_{k+1}
        G_k     = A_k + V_k
    """
    c = np.asarray(costs, dtype=float)
    v = np.asarray(values, dtype=float)
    e = np.zeros_like(c) if ends is None else np.asarray(ends, dtype=float)
    if last_ends is not None:
        e = e.copy()
        e[-1] = np.asarray(last_ends, dtype=float)
    nxt = np.concatenate([v[1:], np.asarray(last_values, dtype=float)[None]], axis=0)
    delta = c + gamma * (1.0 - e) * nxt - v
    adv = np.zeros_like(c)
    running = np.zeros(c.shape[1])
    for k in reversed(range(c.shape[0])):
        running = delta[k] + gamma * lam * (1.0 - e[k]) * running
        adv[k] = running
    return adv, adv + v


def ppo_loss(logits, actions, old_logp, advantages, values, returns, clip: float = 0.2,
             vf_coef: float = 0.5, ent_coef: float = 0.0, normalize: bool = True) -> dict:
    r"""PPO's loss on one minibatch, in costs (the module docstring's :math:`\mathcal L`).

    ``logits``: ``(B, |Theta|)`` of the current actor, ``actions``: ``(B,)`` indices,
    ``old_logp``: ``(B,)`` log-probabilities of the actions under the rollout's policy,
    ``advantages``, ``returns``: ``(B,)`` cost advantages and lambda-returns from
    :func:`gae`, ``values``: ``(B,)`` the current critic. Returns a dict of tensors:
    ``loss`` (what Adam minimises), its three terms ``surrogate``, ``value``,
    ``entropy``, and ``ratio``, ``clipped`` (where the clip took effect: the
    unclipped term was the smaller, i.e. the max chose the clipped one) and
    ``clip_fraction`` (SB3's: the share with :math:`|\rho_k - 1| > \epsilon`)."""
    import torch

    A = torch.as_tensor(advantages, dtype=logits.dtype)
    if normalize and len(A) > 1:
        A = (A - A.mean()) / (A.std() + 1e-8)
    logp_all = torch.log_softmax(logits, dim=-1)
    idx = torch.as_tensor(actions, dtype=torch.long)
    logp = logp_all[torch.arange(len(idx)), idx]
    ratio = torch.exp(logp - torch.as_tensor(old_logp, dtype=logits.dtype))
    unclipped = ratio * A
    clipped_term = torch.clamp(ratio, 1 - clip, 1 + clip) * A
    surrogate = torch.max(unclipped, clipped_term).mean()
    value = ((torch.as_tensor(returns, dtype=values.dtype) - values) ** 2).mean()
    entropy = -(logp_all.exp() * logp_all).sum(dim=-1).mean()
    loss = surrogate + vf_coef * value - ent_coef * entropy
    return {"loss": loss, "surrogate": surrogate, "value": value, "entropy": entropy,
            "ratio": ratio.detach(), "clipped": (clipped_term > unclipped).detach(),
            "clip_fraction": float(((ratio - 1).abs() > clip).float().mean())}


def _torch():
    import torch

    return torch


class TinyPolicy:
    r"""A linear actor (logits ``W_pi s + b_pi``) and a linear critic
    (:math:`V_\psi(s) = w_V^T s + b_V`, a cost to go) on the raw features: the smallest
    policy PPO can update. ``seed`` fixes the initial weights."""

    def __init__(self, n_features: int, n_actions: int, seed: int = 0):
        torch = _torch()
        g = torch.Generator().manual_seed(int(seed))
        self.actor = torch.nn.Linear(n_features, n_actions)
        self.critic = torch.nn.Linear(n_features, 1)
        with torch.no_grad():
            for p in self.parameters():
                p.copy_(0.5 * torch.randn(p.shape, generator=g))

    def parameters(self):
        return list(self.actor.parameters()) + list(self.critic.parameters())

    def logits(self, s):
        return self.actor(_torch().as_tensor(np.asarray(s), dtype=_torch().float32))

    def value(self, s):
        return self.critic(_torch().as_tensor(np.asarray(s), dtype=_torch().float32))[..., 0]


@dataclass
class Rollout:
    """``K`` steps of ``M`` runs: ``obs`` ``(K, M, F)``, ``actions``, ``costs``,
    ``values``, ``old_logp`` ``(K, M)``, ``last_obs`` ``(M, F)``, ``last_values`` ``(M,)``."""

    obs: np.ndarray
    actions: np.ndarray
    costs: np.ndarray
    values: np.ndarray
    old_logp: np.ndarray
    last_obs: np.ndarray
    last_values: np.ndarray


def collect(env, policy: TinyPolicy, n_runs: int, n_steps: int, seed: int = 0) -> Rollout:
    """Run ``policy`` (sampling its actions) for ``n_steps`` steps of ``n_runs`` runs of a
    toy environment (:mod:`adaptfilt.toy`, inside one episode: ``n_steps`` below the
    environment's horizon), recording what a PPO update needs."""
    torch = _torch()
    if n_steps >= env.n_steps:
        raise ValueError("the rollout must end inside the episode (n_steps < env.n_steps)")
    rng = np.random.default_rng(seed)
    d = env.reset(n_runs=n_runs, rng=rng)
    obs, acts, costs, vals, logps = [], [], [], [], []
    with torch.no_grad():
        for _ in range(n_steps):
            s = d.features.astype(np.float32)
            logp = torch.log_softmax(policy.logits(s), dim=-1).numpy()
            a = np.array([rng.choice(logp.shape[1], p=np.exp(lp) / np.exp(lp).sum()) for lp in logp])
            obs.append(s), acts.append(a), vals.append(policy.value(s).numpy())
            logps.append(logp[np.arange(n_runs), a])
            d, c, _, _ = env.step(a)
            costs.append(c)
        last = d.features.astype(np.float32)
        last_v = policy.value(last).numpy()
    return Rollout(np.stack(obs), np.stack(acts), np.stack(costs).astype(float), np.stack(vals),
                   np.stack(logps), last, last_v)


def ppo_update(policy: TinyPolicy, ro: Rollout, gamma: float, lam: float = 0.95, lr: float = 2e-3,
               epochs: int = 2, clip: float = 0.2, vf_coef: float = 0.5, ent_coef: float = 0.0,
               max_grad_norm: float = 0.5) -> list[dict]:
    """One PPO update of ``policy`` in place: GAE by :func:`gae`, then ``epochs`` Adam steps
    (``eps=1e-5`` as SB3's) on :func:`ppo_loss` of the whole rollout (one minibatch), the
    gradient clipped at ``max_grad_norm``. Returns :func:`ppo_loss`'s dict of each epoch,
    evaluated before that epoch's step."""
    torch = _torch()
    adv, ret = gae(ro.costs, ro.values, ro.last_values, gamma, lam)
    K, M = ro.costs.shape
    s = ro.obs.reshape(K * M, -1)
    opt = torch.optim.Adam(policy.parameters(), lr=lr, eps=1e-5)
    out = []
    for _ in range(epochs):
        terms = ppo_loss(policy.logits(s), ro.actions.reshape(-1), ro.old_logp.reshape(-1),
                         adv.reshape(-1), policy.value(s), ret.reshape(-1), clip, vf_coef, ent_coef)
        opt.zero_grad()
        terms["loss"].backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), max_grad_norm)
        opt.step()
        out.append(terms)
    return out


def sb3_reference(policy: TinyPolicy, ro: Rollout, gamma: float, lam: float = 0.95, lr: float = 2e-3,
                  epochs: int = 2, clip: float = 0.2, vf_coef: float = 0.5, ent_coef: float = 0.0,
                  max_grad_norm: float = 0.5, ends=None) -> dict:
    """The same update done by Stable-Baselines3 itself: an SB3 ``PPO`` whose actor and critic
    are linear (``net_arch=[]``) and start from ``policy``'s weights (the critic's negated: SB3's
    value is a return, minus the cost to go), its ``RolloutBuffer`` filled with the rollout
    (rewards ``-costs``), ``compute_returns_and_advantage`` and ``PPO.train()``. Returns the
    cost advantages and returns SB3 computed (``(K, M)``), the loss it logged for the last
    epoch, and the weights after its update in ``policy``'s order and signs. ``ends``: as
    :func:`gae`'s, to test episode boundaries (passed to the buffer as episode starts)."""
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import DummyVecEnv

    K, M = ro.costs.shape
    n_features = ro.obs.shape[-1]
    n_actions = policy.actor.out_features

    class _Spaces(gym.Env):
        observation_space = gym.spaces.Box(-np.inf, np.inf, (n_features,), np.float32)
        action_space = gym.spaces.Discrete(n_actions)

    venv = DummyVecEnv([_Spaces for _ in range(M)])
    model = PPO("MlpPolicy", venv, n_steps=K, batch_size=K * M, n_epochs=epochs, learning_rate=lr,
                gamma=gamma, gae_lambda=lam, clip_range=clip, vf_coef=vf_coef, ent_coef=ent_coef,
                max_grad_norm=max_grad_norm, device="cpu", seed=0,
                policy_kwargs={"net_arch": {"pi": [], "vf": []}})
    model.set_logger(Logger(folder=None, output_formats=[]))
    p = model.policy
    with torch.no_grad():
        p.action_net.weight.copy_(policy.actor.weight), p.action_net.bias.copy_(policy.actor.bias)
        p.value_net.weight.copy_(-policy.critic.weight), p.value_net.bias.copy_(-policy.critic.bias)
    e = np.zeros((K, M), dtype=bool) if ends is None else np.asarray(ends, dtype=bool)
    buf = model.rollout_buffer
    buf.reset()
    for k in range(K):
        start = np.ones(M, dtype=bool) if k == 0 else e[k - 1]
        buf.add(ro.obs[k], ro.actions[k][:, None], -ro.costs[k], start,
                torch.as_tensor(-ro.values[k]), torch.as_tensor(ro.old_logp[k]))
    buf.compute_returns_and_advantage(torch.as_tensor(-ro.last_values), e[-1])
    adv, ret = -buf.advantages.copy(), -buf.returns.copy()
    model.train()
    after = [p.action_net.weight, p.action_net.bias, -p.value_net.weight, -p.value_net.bias]
    return {"advantages": adv, "returns": ret, "loss": float(model.logger.name_to_value["train/loss"]),
            "clip_fraction": float(model.logger.name_to_value["train/clip_fraction"]),
            "params": [x.detach().clone() for x in after]}


def _gae_cases():
    """``(name, costs, values, last_values, gamma, lam)``: three small rollouts."""
    rng = np.random.default_rng(6)
    out = []
    for K, M, gamma, lam in ((6, 4, 0.5, 0.95), (5, 3, 0.9, 0.0), (7, 2, 0.7, 1.0)):
        out.append((f"K = {K} steps, M = {M} runs, gamma = {gamma}, lambda = {lam}",
                    rng.gamma(1.0, 1.0, (K, M)), rng.standard_normal((K, M)), rng.standard_normal(M),
                    gamma, lam))
    return out


def check_gae(my_gae) -> bool:
    r"""Check a reader's ``my_gae(costs, values, last_values, gamma, lam) -> advantages (K, M)``
    (no episode ends inside the rollout) against :func:`gae` on three rollouts, among them
    :math:`\lambda = 0` (Algorithm 2's TD error) and :math:`\lambda = 1`. Names the usual slips:
    the lambda-returns instead of the advantages, :math:`\lambda` without :math:`\gamma` in the
    recursion, no bootstrap from ``last_values``, a sum forwards instead of backwards, a reward's
    sign. Prints the verdict and returns whether the answer is right."""
    problems = []
    for name, c, v, last, gamma, lam in _gae_cases():
        ref, ret = gae(c, v, last, gamma, lam)
        try:
            mine = np.asarray(my_gae(c.copy(), v.copy(), last.copy(), gamma, lam), dtype=float)
        except Exception as e:  # noqa: BLE001 - the reader's code: report, do not raise
            problems.append(f"{name}: your function raised {type(e).__name__}: {e}")
            continue
        if mine.shape != ref.shape:
            problems.append(f"{name}: you returned shape {mine.shape}, not the rollout's {ref.shape}")
            continue
        if np.allclose(mine, ref, atol=1e-10):
            continue
        nxt = np.concatenate([v[1:], last[None]])
        delta = c + gamma * nxt - v
        no_boot = c + gamma * np.concatenate([v[1:], np.zeros((1, v.shape[1]))]) - v
        wrong = {"the lambda-returns G_k = A_k + V_k, not the advantages": ret,
                 "a reward's sign (-A_k)": -ref,
                 "lambda alone in the recursion (it is gamma * lambda)": _recursion(delta, lam),
                 "no bootstrap from the value after the rollout": _recursion(no_boot, gamma * lam),
                 "a sum forwards in time (A_k from the steps before k)": _forward(delta, gamma * lam)}
        what = next((k for k, w in wrong.items() if np.allclose(mine, w, atol=1e-10)
                     and not np.allclose(w, ref, atol=1e-10)), None)
        problems.append(f"{name}: your advantages differ (largest difference {np.abs(mine - ref).max():.3g})"
                        + (f"; yours are {what}" if what else ""))
    if problems:
        print("not yet:\n  " + "\n  ".join(problems))
        print("hint: delta_k = L'_k + gamma V_{k+1} - V_k (V_K = last_values), then backwards "
              "A_k = delta_k + gamma lam A_{k+1} with A_K = 0")
        return False
    print("right: your GAE is ppo_step.gae's (and so SB3's) on all three rollouts")
    return True


def _recursion(delta, factor):
    out, running = np.zeros_like(delta), np.zeros(delta.shape[1])
    for k in reversed(range(delta.shape[0])):
        running = delta[k] + factor * running
        out[k] = running
    return out


def _forward(delta, factor):
    out, running = np.zeros_like(delta), np.zeros(delta.shape[1])
    for k in range(delta.shape[0]):
        running = delta[k] + factor * running
        out[k] = running
    return out
