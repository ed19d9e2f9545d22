r"""The policy gradient derived on two toys with known answers, as chapter 6 (Policy gradient and the
actor-critic) does it: the score-function identity and REINFORCE on one decision of a bandit, and the
TD error as the advantage on the trap.

**One decision.** A softmax policy over :math:`K` actions with logits :math:`\theta` (no state: one
decision of the bandit toy at a fixed state), an expected cost :math:`c_a` per action:

.. math::

    \pi = \operatorname{softmax}(\theta), \qquad J(\theta) = \mathrm{E}_{a\sim\pi}[c_a] = \sum_a \pi_a c_a,
    \qquad \nabla_\theta \log\pi_a = e_a - \pi,

    \nabla_\theta J = \sum_a c_a \nabla_\theta\pi_a = \sum_a \pi_a c_a \nabla_\theta\log\pi_a
    = \mathrm{E}_{a\sim\pi}\big[c_a\nabla_\theta\log\pi_a\big] = \pi\odot(c - J)

(the score-function identity :math:`\nabla\pi_a = \pi_a\nabla\log\pi_a`). REINFORCE estimates it from
sampled actions and observed costs :math:`(a_n, L_n)`, with any baseline :math:`b` that does not
depend on the action, since :math:`\mathrm{E}[b\,\nabla\log\pi_a] = b\,\nabla\sum_a\pi_a = 0`:

.. math::

    \hat g = \frac1N\sum_{n=1}^N (L_n - b)\,(e_{a_n} - \pi).

**The trap.** ``adaptfilt.toy.TrapEnv`` has two states: in *good* the trap (action 0) costs 0 and
leads to *bad*, where every step costs 1; the safe action (1) costs :math:`c_1` and stays in *good*.
For a policy that takes the safe action with probability :math:`p` in *good*, the values solve
:math:`V(\text{bad}) = 1/(1-\gamma)`, :math:`Q(\text{good}, 0) = \gamma V(\text{bad})`,
:math:`Q(\text{good}, 1) = c_1 + \gamma V(\text{good})` and
:math:`V(\text{good}) = p\,Q(\text{good}, 1) + (1-p)\,Q(\text{good}, 0)`. With that exact critic the
TD error of a step is the advantage of its action: :math:`\mathrm{E}[\delta_k\,|\,s_k, a_k] =
Q(s_k, a_k) - V(s_k) = A(s_k, a_k)`.

Example
-------
>>> import numpy as np
>>> theta, c = np.zeros(3), np.array([0.0, 1.0, 2.0])
>>> exact_gradient(theta, c).round(3).tolist()
[-0.333, 0.0, 0.333]
>>> g = score_function_estimate(theta, np.array([0, 1, 2]), c)  # one draw of each action
>>> g.round(3).tolist()
[-0.333, 0.0, 0.333]
"""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["softmax", "exact_gradient", "score_function_estimate", "sample_costs", "estimator_spread",
           "trap_values", "trap_td_errors"]


def softmax(theta: np.ndarray) -> np.ndarray:
    """``exp(theta) / sum(exp(theta))`` along the last axis, computed without overflow."""
    z = np.asarray(theta, dtype=float)
    e = np.exp(z - z.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


def exact_gradient(theta: np.ndarray, costs: np.ndarray) -> np.ndarray:
    r""":math:`\nabla_\theta J = \pi\odot(c - \pi^\top c)`, the exact gradient of the expected cost of
    one decision under ``softmax(theta)`` (``costs``: the expected cost of each action)."""
    pi = softmax(theta)
    c = np.asarray(costs, dtype=float)
    return pi * (c - pi @ c)


def score_function_estimate(theta: np.ndarray, actions: np.ndarray, costs: np.ndarray,
                            baseline: float = 0.0) -> np.ndarray:
    r"""REINFORCE's estimate of :math:`\nabla_\theta J` from ``N`` sampled ``actions`` (indices) and
    the ``costs`` observed after them, both ``(N,)``: the mean of :math:`(L_n - b)(e_{a_n} - \pi)`.
    Unbiased for every ``baseline`` that does not depend on the action."""
    pi = softmax(theta)
    a = np.asarray(actions, dtype=int)
    L = np.asarray(costs, dtype=float)
    if a.shape != L.shape or a.ndim != 1:
        raise ValueError(f"actions {a.shape} and costs {L.shape} must be two arrays (N,) of one length")
    score = np.eye(len(pi))[a] - pi  # grad_theta log pi(a_n), one row per sample
    return ((L - baseline)[:, None] * score).mean(axis=0)


def sample_costs(theta: np.ndarray, mean_costs: np.ndarray, n: int, rng: np.random.Generator,
                 noise: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """``n`` decisions under ``softmax(theta)``: the actions drawn and the costs observed (the action's
    expected cost plus Gaussian noise of standard deviation ``noise``, as in the bandit toy)."""
    pi = softmax(theta)
    a = rng.choice(len(pi), size=n, p=pi)
    return a, np.asarray(mean_costs, dtype=float)[a] + noise * rng.standard_normal(n)


def estimator_spread(theta: np.ndarray, mean_costs: np.ndarray, n: int, repeats: int, seed: int,
                     baseline: float = 0.0, noise: float = 0.1) -> dict[str, np.ndarray]:
    """The REINFORCE estimate from ``n`` decisions, ``repeats`` times: its ``mean`` and standard
    deviation ``sd`` per logit, beside the ``exact`` gradient (seeded: the same numbers every run)."""
    rng = np.random.default_rng(seed)
    est = np.stack([score_function_estimate(theta, *sample_costs(theta, mean_costs, n, rng, noise), baseline)
                    for _ in range(repeats)])
    return {"exact": exact_gradient(theta, mean_costs), "mean": est.mean(axis=0), "sd": est.std(axis=0, ddof=1)}


def trap_values(gamma: float, p_safe: float, c1: float = 0.25) -> dict[str, float]:
    """Exact values of the trap toy under the policy that takes the safe action with probability
    ``p_safe`` in *good* (module docstring): ``V_good``, ``V_bad``, ``Q_trap``, ``Q_safe`` (in *good*)
    and the advantages ``A_trap``, ``A_safe``."""
    if not 0.0 <= gamma < 1.0 or not 0.0 <= p_safe <= 1.0:
        raise ValueError(f"need 0 <= gamma < 1 and 0 <= p_safe <= 1, got gamma={gamma}, p_safe={p_safe}")
    v_bad = 1.0 / (1.0 - gamma)
    q_trap = gamma * v_bad
    v_good = (p_safe * c1 + (1.0 - p_safe) * q_trap) / (1.0 - p_safe * gamma)
    q_safe = c1 + gamma * v_good
    return {"V_good": v_good, "V_bad": v_bad, "Q_trap": q_trap, "Q_safe": q_safe,
            "A_trap": q_trap - v_good, "A_safe": q_safe - v_good}


def trap_td_errors(env: Any, gamma: float, p_safe: float, n_runs: int, seed: int) -> dict[str, np.ndarray]:
    r"""One step of the trap toy from *good* in ``n_runs`` runs, the action drawn from the policy:
    :math:`\delta = L + \gamma V(s') - V(\text{good})` with the exact critic of :func:`trap_values`,
    read from the environment's own costs and next states. Returns ``actions`` and ``delta``."""
    values = trap_values(gamma, p_safe, env.c1)
    rng = np.random.default_rng(seed)
    env.reset(n_runs=n_runs, rng=np.random.default_rng([seed, 1]))
    a = (rng.random(n_runs) < p_safe).astype(int)  # 1: safe, 0: trap
    d, cost, _, _ = env.step(a)
    bad = d.features[:, 0] > 0.5
    v_next = np.where(bad, values["V_bad"], values["V_good"])
    return {"actions": a, "delta": cost + gamma * v_next - values["V_good"]}
