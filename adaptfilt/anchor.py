r"""Learned policies anchored on a rule: a residual over greedy's (or ML's) choice, kept near it by a KL term.

A learned policy that starts *as* greedy (the exact one-step optimum, the bar every learned policy is
measured against) and moves away only where the learner finds that it pays.

**The anchor** (:data:`ANCHORS`, a declared choice of the anchored learner): ``"greedy"`` (below) or
``"ml"``, maximum likelihood's choice ``argmax_theta log N(z; z_pred(theta), Pzz(theta))``
(:class:`~adaptfilt.policies.MaxLikelihoodPolicy`, the same ``np.argmax``): on the CTM, ML's run costs
less than greedy's although greedy is the one-step optimum, so a learner that starts at ML starts from the
better rule. Everything below holds with ``g(s)`` the anchor's choice; ML's needs the candidates'
log-likelihoods, which the same candidate updates give (computed and charged as greedy's). The shield stays
relative to greedy's one-step cost (the one-step optimum), and the anchor's own choice is always allowed.

**The policy.** With ``g(s)`` greedy's choice (the argmin of the one-step cost over the grid,
:class:`~adaptfilt.policies.GreedyPolicy`) and ``f(s)`` the actor network's logits,

.. math::
    \pi(\theta \mid s) \propto \exp\big(f(s)_\theta + c\,[\theta = g(s)]\big),
    \qquad \pi_0(\theta \mid s) \propto \exp\big(c\,[\theta = g(s)]\big).

``c`` is the anchor *strength*. The actor's output layer starts at exactly zero (weights and bias),
so the untrained policy is ``pi_0``: its most probable action (what the policy does at evaluation,
Algorithm 3) **is** greedy's, exactly, whatever the network's hidden layers; during training it
samples greedy's action with probability ``e^c / (e^c + G - 1)`` (``c = 3``, ``G = 13``: 0.63) and
explores the rest. The deterministic policy leaves greedy at a state only once the learned logits
prefer another value by more than ``c``.

This is the form of the optimum of KL-regularised RL, ``pi ∝ pi_0 exp(Q / alpha)`` (Todorov 2007;
Rawlik, Toussaint and Vijayakumar 2012; Levine 2018, "Reinforcement learning and control as
inference"): the network plays the role of ``Q / alpha`` relative to the prior ``pi_0``. It is also
the discrete-action form of residual policy learning (Silver et al. 2018; Johannink et al. 2019), in
which a learned correction is added to a fixed base controller and starts at zero.

**The KL term.** The loss also carries ``beta * KL(pi(.|s) || pi_0(.|s))`` (``kl``) averaged over
the minibatch, which pulls the policy back to greedy where the advantage does not push it away.
PPO's entropy bonus ``- ent_coef * H(pi)`` is the special case ``pi_0`` uniform (``-H(pi) =
KL(pi || U) - log G``), so :func:`anchored_policy_class` puts ``-KL(pi || pi_0)`` where SB3's
``evaluate_actions`` returns the entropy and the trainer sets ``ent_coef = beta``: SB3's own PPO
(and A2C) loss then is ``policy loss + beta KL + vf_coef * value loss`` without a subclass of the
algorithm (SB3 logs the mean KL as ``train/entropy_loss``). No maintained library we know of has an
anchor-KL option for PPO; this keeps SB3's algorithm untouched.

**The shield** (``shield = D``, optional). The residual is trained on ``log(1 + L)``, which weighs a
step that costs ``10^6`` like a few dozen ordinary steps; one of eight anchored UNGM policies had a
mean cost of 331 against greedy's 0.80 on 10^4 runs, and on selection runs its steps that cost more
than 10^3 were all steps where it chose kappa = 50 while greedy's kappa = 10^4 would have cost about
100 *at that very step* (``benchmarks/bench_anchor.py``). A shield (Alshiekh et al. 2018, "Safe reinforcement learning
via shielding") removes such choices before they are made: candidates whose one-step
``log(1 + L)`` exceeds greedy's by more than ``D`` get the logit :data:`MASKED_LOGIT`, in training
(PPO never samples them; invalid-action masking, Huang and Ontañón 2022) and in acting alike
(:func:`allowed_mask`; greedy's own choice is always allowed, so the untrained policy is still greedy).
With ``D = 1`` a deviation costs at most ``e (1 + L_greedy) - 1`` at the step where it is made.

**Distilling rollout** (:func:`adaptfilt.distill.distill_rollout`): the same residual form fitted to the rollout
reference's Q-values (:mod:`adaptfilt.lookahead`) instead of trained by PPO.

**What the network sees.** The anchor is not a feature: the network sees the scaled information
state of its feature set as every learned policy does (``paper+time+cand`` etc.), and greedy's
choice reaches the logits only through ``c``. In training, the Gymnasium adapter appends greedy's
one-hot to each observation (``FilterVectorEnv(anchor="greedy")``) and the policy's features
extractor drops it before the networks (the critic never sees it); in acting,
:class:`~adaptfilt.learned.LearnedPolicy` computes it from the decision's candidates
(:func:`greedy_onehot`, the same ``argmin`` as greedy) and adds it in float32 as SB3 does, so a
policy file acts exactly as the trained model. Greedy's candidates are computed every step and
charged like greedy's (``Decision.extra_spent``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

__all__ = ["ANCHORS", "Anchor", "DEFAULT_SHIELD", "greedy_index", "greedy_onehot", "anchor_index", "anchor_onehot",
           "allowed_mask", "anchored_logits", "anchored_policy_class",
           "DEFAULT_STRENGTH",
           "DEFAULT_KL"]

#: Policies a learned policy can be anchored on (module docstring).
ANCHORS = ("greedy", "ml")
#: Default anchor strength ``c`` (logit added to greedy's choice). Chosen on selection runs: see
#: ``benchmarks/bench_anchor.py``.
DEFAULT_STRENGTH = 3.0
#: Default KL coefficient ``beta`` (in units of PPO's per-minibatch normalised advantage).
DEFAULT_KL = 0.01
#: Default shield of the trainers (``train_policy(..., anchor="greedy")``; 0 there: none): without it one of
#: eight UNGM policies had rare steps that cost 10^6 (see the module docstring).
DEFAULT_SHIELD = 1.0


@dataclass(frozen=True)
class Anchor:
    """What a policy is anchored on (``policy``, one of :data:`ANCHORS`), with the strength ``c`` and the KL
    coefficient ``beta`` it was trained with (``kl``; recorded, not used in acting).

    >>> Anchor("greedy", 3.0, 0.01).to_dict()
    {'policy': 'greedy', 'strength': 3.0, 'kl': 0.01}
    """

    policy: str = "greedy"
    strength: float = DEFAULT_STRENGTH
    kl: float = DEFAULT_KL
    #: a shield (None: none): candidates whose one-step ``log(1 + L)`` exceeds greedy's by more than this are
    #: masked out, in training and in acting (:func:`allowed_mask`)
    shield: float | None = None

    def __post_init__(self):
        if self.policy not in ANCHORS:
            raise ValueError(f"unknown anchor {self.policy!r}; choose one of {', '.join(ANCHORS)}")
        try:
            s, k = float(self.strength), float(self.kl)
        except (TypeError, ValueError):
            raise ValueError(f"anchor strength and kl must be numbers, got {self.strength!r}, {self.kl!r}") from None
        if not (np.isfinite(s) and s > 0):
            raise ValueError(f"anchor strength must be finite and > 0 (0 would not anchor), got {self.strength!r}")
        if not (np.isfinite(k) and k >= 0):
            raise ValueError(f"anchor kl must be finite and >= 0, got {self.kl!r}")
        object.__setattr__(self, "strength", s)
        object.__setattr__(self, "kl", k)
        if self.shield is not None:
            try:
                sh = float(self.shield)
            except (TypeError, ValueError):
                raise ValueError(f"anchor shield must be a number or None, got {self.shield!r}") from None
            if not (np.isfinite(sh) and sh > 0):
                raise ValueError(f"anchor shield must be finite and > 0 (or None: no shield), got {self.shield!r}")
            object.__setattr__(self, "shield", sh)

    def to_dict(self) -> dict:
        d = {"policy": self.policy, "strength": self.strength, "kl": self.kl}
        if self.shield is not None:
            d["shield"] = self.shield
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> "Anchor | None":
        """The anchor recorded in a policy file's metadata (None: not anchored); ValueError if malformed."""
        if d is None:
            return None
        if not isinstance(d, Mapping) or "policy" not in d or "strength" not in d:
            raise ValueError(f"malformed anchor metadata {d!r}: expected {{'policy', 'strength', 'kl'}}")
        return cls(d["policy"], d["strength"], d.get("kl", 0.0), d.get("shield"))


def greedy_index(decision, grid: Sequence[float] | None = None) -> np.ndarray:
    """Greedy's choice ``(M,)`` as an index into ``grid`` (default: the decision's grid): the ``argmin``
    of the candidates' one-step cost, exactly as :class:`~adaptfilt.policies.GreedyPolicy` (first index
    on a tie). ``grid`` may be a subset of the decision's grid (a policy on a restricted action set):
    greedy over that subset."""
    cost = decision.candidates()["cost"]
    if cost is None:
        raise ValueError("an anchor on greedy needs an environment with a cost")
    return np.argmin(_over(np.asarray(cost), decision, grid), axis=0)


def _over(values: np.ndarray, decision, grid: Sequence[float] | None) -> np.ndarray:
    """The candidates' ``values`` (one row per grid value) restricted to ``grid`` (None: all of them)."""
    if grid is None:
        return values
    from adaptfilt.policies import grid_indices

    return values[grid_indices(np.asarray(grid, dtype=float), decision.grid, "anchored policy")]


def _onehot(idx: np.ndarray, G: int) -> np.ndarray:
    out = np.zeros((idx.size, G), dtype=np.float32)
    out[np.arange(idx.size), idx] = 1.0
    return out


def greedy_onehot(decision, grid: Sequence[float] | None = None) -> np.ndarray:
    """Greedy's choice as a float32 one-hot ``(M, G)`` over ``grid`` (see :func:`greedy_index`)."""
    return _onehot(greedy_index(decision, grid), decision.grid.size if grid is None else len(grid))


def anchor_index(decision, policy: str = "greedy", grid: Sequence[float] | None = None) -> np.ndarray:
    """The anchor's choice ``(M,)`` as an index into ``grid`` (default: the decision's grid): greedy's
    (:func:`greedy_index`) or ML's, ``argmax`` of the candidates' log-likelihoods exactly as
    :class:`~adaptfilt.policies.MaxLikelihoodPolicy` (first index on a tie), over ``grid`` when it is a
    subset of the decision's."""
    if policy == "greedy":
        return greedy_index(decision, grid)
    if policy != "ml":
        raise ValueError(f"unknown anchor {policy!r}; choose one of {', '.join(ANCHORS)}")
    ll = decision.candidates().get("loglik")
    if ll is None:
        raise ValueError("an anchor on ML needs the candidates' log-likelihoods")
    return np.argmax(_over(np.asarray(ll), decision, grid), axis=0)


def anchor_onehot(decision, policy: str = "greedy", grid: Sequence[float] | None = None) -> np.ndarray:
    """The anchor's choice as a float32 one-hot ``(M, G)`` over ``grid`` (see :func:`anchor_index`)."""
    return _onehot(anchor_index(decision, policy, grid), decision.grid.size if grid is None else len(grid))


def allowed_mask(decision, shield: float, grid: Sequence[float] | None = None,
                 keep: np.ndarray | None = None) -> np.ndarray:
    """The shield's float32 mask ``(M, G)`` over ``grid`` (default the decision's): 1 where a candidate's
    one-step ``log(1 + L)`` is at most ``shield`` above greedy's (greedy's own choice always), 0 elsewhere
    (also where the candidate's cost is not finite). ``shield = 1``: a deviation may cost at most
    ``e (1 + L_greedy) - 1`` now. ``keep (M,)``: indices (into ``grid``) always allowed too, the anchor's
    choice when it is not greedy (so that the untrained policy is its anchor)."""
    cost = np.asarray(decision.candidates()["cost"], dtype=float)
    if grid is not None:
        from adaptfilt.policies import grid_indices

        cost = cost[grid_indices(np.asarray(grid, dtype=float), decision.grid, "anchored policy")]
    g = np.argmin(cost, axis=0)
    with np.errstate(invalid="ignore"):
        lc = np.log1p(np.maximum(cost, 0.0))
        ok = np.isfinite(lc) & (lc - lc[g, np.arange(g.size)] <= float(shield))
    ok[g, np.arange(g.size)] = True
    if keep is not None:
        ok[np.asarray(keep), np.arange(g.size)] = True
    return ok.T.astype(np.float32)


def anchored_policy_class():
    """The SB3 ``ActorCriticPolicy`` subclass of an anchored policy (built on first use: SB3 is optional).

    Its observations are ``[scaled features (d), the anchor's one-hot (G)]`` and, with ``shield=True``, the
    shield's mask ``(G)`` after them (:class:`~adaptfilt.gym.FilterVectorEnv` with an anchor lays them
    out so); keyword arguments ``strength`` (``c``) and ``shield``. The entropy slot always carries
    ``-KL(pi || pi_0)`` (module docstring): the algorithm's ``ent_coef`` is the KL's weight ``beta``.
    Only shared feature extractors (SB3's default for ``MlpPolicy``) are supported.
    """
    global _ANCHORED
    if _ANCHORED is not None:
        return _ANCHORED
    import torch as th
    from gymnasium import spaces
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    class DropAnchor(BaseFeaturesExtractor):
        """The observation without its last ``n_anchor`` columns (the anchor's one-hot): what the networks see."""

        def __init__(self, observation_space: spaces.Box, n_anchor: int):
            super().__init__(observation_space, int(observation_space.shape[0]) - int(n_anchor))
            self.n_keep = int(observation_space.shape[0]) - int(n_anchor)

        def forward(self, obs: th.Tensor) -> th.Tensor:
            return obs[:, : self.n_keep]

    class AnchoredActorCriticPolicy(ActorCriticPolicy):
        """``pi ∝ exp(actor(s) + c onehot(anchor))`` with the actor's output layer initialised at zero."""

        def __init__(self, observation_space, action_space, lr_schedule, *, strength: float = DEFAULT_STRENGTH,
                     shield: bool = False, **kwargs):
            if not isinstance(action_space, spaces.Discrete):
                raise ValueError("an anchored policy needs a Discrete action space (grid indices)")
            if kwargs.get("share_features_extractor", True) is not True:
                raise ValueError("an anchored policy shares its features extractor (SB3's default)")
            self.n_anchor = int(action_space.n)
            self.strength = float(strength)
            self.shield = bool(shield)  # the observation also carries the shield's mask (G more columns)
            n_extra = self.n_anchor * (2 if self.shield else 1)
            kwargs.update(features_extractor_class=DropAnchor, features_extractor_kwargs={"n_anchor": n_extra})
            super().__init__(observation_space, action_space, lr_schedule, **kwargs)
            with th.no_grad():  # the untrained policy is pi_0: the anchor at its argmax, exactly
                self.action_net.weight.zero_()
                self.action_net.bias.zero_()

        def _extra(self, obs):
            """(the anchor's one-hot, the shield's mask or None) from the observation's last columns."""
            G = self.n_anchor
            if not self.shield:
                return obs[:, -G:].float(), None
            return obs[:, -2 * G:-G].float(), obs[:, -G:].float()

        def _split(self, obs):
            features = self.extract_features(obs)
            latent_pi, latent_vf = self.mlp_extractor(features)
            return latent_pi, latent_vf, self._extra(obs)

        def _dist(self, latent_pi, extra):
            return self.action_dist.proba_distribution(action_logits=anchored_logits(
                self.action_net(latent_pi), extra[0], self.strength, extra[1]))

        def _minus_kl(self, dist, extra) -> th.Tensor:
            """``-KL(pi || pi_0)`` per row: what PPO's entropy slot carries (module docstring)."""
            logp = dist.distribution.logits  # normalised log-probabilities
            logp0 = th.log_softmax(anchored_logits(th.zeros_like(logp), extra[0], self.strength, extra[1]), dim=-1)
            return -(logp.exp() * (logp - logp0)).sum(dim=-1)

        def forward(self, obs, deterministic: bool = False):
            latent_pi, latent_vf, extra = self._split(obs)
            dist = self._dist(latent_pi, extra)
            actions = dist.get_actions(deterministic=deterministic)
            log_prob = dist.log_prob(actions)
            return actions.reshape((-1, *self.action_space.shape)), self.value_net(latent_vf), log_prob

        def evaluate_actions(self, obs, actions):
            latent_pi, latent_vf, extra = self._split(obs)
            dist = self._dist(latent_pi, extra)
            return self.value_net(latent_vf), dist.log_prob(actions), self._minus_kl(dist, extra)

        def get_distribution(self, obs):
            latent_pi = self.mlp_extractor.forward_actor(self.extract_features(obs))
            return self._dist(latent_pi, self._extra(obs))

    _ANCHORED = AnchoredActorCriticPolicy
    return _ANCHORED


_ANCHORED = None

#: the logit of a candidate the shield masks out: finite, so that softmax, log-probabilities and the KL stay finite
MASKED_LOGIT = -1e4


def anchored_logits(net, onehot, strength: float, allowed=None):
    """``net + c * onehot``, and ``MASKED_LOGIT`` where the shield's mask ``allowed`` is 0 (torch tensors,
    float32): the one formula of training (SB3 and :func:`distill_rollout`) and acting (``LearnedPolicy``)."""
    import torch as th

    out = net + strength * onehot
    return out if allowed is None else th.where(allowed > 0, out, th.full_like(out, MASKED_LOGIT))
