r"""Training a policy, as chapters 6 (Policy gradient and actor-critic) and 7 (PPO and the training
recipe) show it: the sign demonstration on a toy, a learning curve, the scale of the costs and of the
features, the reader's actor update checked against the library's, and one policy's probabilities at
several information states.

========================================  =========================================================
function                                  what
========================================  =========================================================
plot_sign_demo                            ``pi(a | s)`` of toy policies and their learning curves
plain_soft_update                         the target critic's Polyak averaging, one weight tensor at
                                          a time (what :func:`adaptfilt.actor_critic.soft_update`
                                          computes in two batched calls)
plot_training, kappa_bands                a learning curve of :func:`adaptfilt.actor_critic.train`,
                                          the grid values sampled shown by band
candidate_cost_range                      the range of the one-step costs a critic regresses on
scaler_saturation                         how two feature scalers treat the states that other
                                          parameter values visit
actor_update_batch, library_actor_loss,   the reader's actor loss against the library's, on a
check_actor_update                        fixed batch: the gradient it gives, and what is wrong
plot_state_probs                          one policy's ``pi(theta | s)`` at several states
========================================  =========================================================

The chapter's widget is :func:`adaptfilt.course.policy_reading.show_policy_probs` (chapter 8 uses
it too). As :mod:`adaptfilt.course.common` and the modules of chapters 1-4 do: what a chapter
computes in passing and its figures live here, documented and tested (``tests/test_course_training.py``),
so that a chapter reads as prose with short calls. Figures use :mod:`adaptfilt.style`.
"""
from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np

from adaptfilt.course.common import figure_axes

__all__ = ["plot_sign_demo", "plain_soft_update", "kappa_bands", "plot_training", "candidate_cost_range", "scaler_saturation",
           "actor_update_batch", "library_actor_loss", "check_actor_update", "plot_state_probs"]


def _smooth(y: np.ndarray, w: int) -> np.ndarray:
    w = max(1, min(int(w), len(y)))
    return np.convolve(y, np.ones(w) / w, mode="valid")


def plot_sign_demo(states: np.ndarray, policies: Mapping[str, object], curves: Mapping[str, Mapping],
                   window: int = 32):
    r"""The sign demonstration on a toy with a scalar state: ``pi(a | s)`` of each
    policy over ``states`` (one panel per policy) and the smoothed learning
    curves (mean cost per step, last panel). ``policies`` and ``curves`` are
    keyed by the same labels; features are ``(s, 0)`` (the toy's noise feature at 0)."""
    from adaptfilt import style

    n = len(policies)
    fig, axes = style.figure(1, n + 1, size=(3.0 * (n + 1), 3.0))
    feats = np.stack([states, np.zeros_like(states)], axis=1)
    for ax, (label, pol) in zip(axes, policies.items()):
        p = pol.probs(feats)
        for a, col in zip(range(p.shape[1]), style.colors(p.shape[1])):
            ax.plot(states, p[:, a], color=col, label=f"action {a}")
        ax.axvline(0, color="0.5", lw=0.8, ls=":")
        ax.set(xlabel="state s", ylim=(-0.02, 1.02), title=label)
    axes[0].set_ylabel(r"$\pi(a\,|\,s)$")
    axes[0].legend(loc="center left")
    for label, c in curves.items():
        y = _smooth(np.asarray(c["cost"]), window)
        axes[-1].plot(np.arange(len(y)) + window, y, label=label)
    axes[-1].set(xlabel="episode", ylabel="mean cost per step", title="learning curves")
    axes[-1].legend()
    return fig


def kappa_bands(grid: Sequence[float], edges: Sequence[float] = (5.0, 100.0, 1000.0)) -> dict[str, np.ndarray]:
    r"""Group a grid into bands: ``{label: boolean mask over the grid}``, split *below* each of
    ``edges`` (default: small 0-2, moderate 5-50, large 100-500, switched (almost) off >= 1000 on
    the UNGM grid). Empty bands are dropped; a band is labelled by the grid values it holds."""
    grid = np.asarray(grid, dtype=float)
    cuts = [-np.inf, *sorted(float(e) for e in edges), np.inf]
    out = {}
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        m = (grid >= lo) & (grid < hi)
        if m.any():
            v = grid[m]
            out[f"{v[0]:g}" if v.size == 1 else f"{v[0]:g}-{v[-1]:g}"] = m
    return out


def plot_training(curve: Mapping[str, np.ndarray], grid: Sequence[float], batch: int,
                  edges: Sequence[float] = (5.0, 100.0, 1000.0)):
    r"""A learning curve of :func:`adaptfilt.actor_critic.train`: the transformed cost
    per episode, the raw cost (log scale) and the share of the steps in each band of
    grid values (:func:`kappa_bands`) per batch of ``batch`` episodes (a stack plot of
    3-4 bands, not one colour per grid value)."""
    from adaptfilt import style

    grid = np.asarray(grid, dtype=float)
    fig, axes = style.figure(1, 3, size=(10.5, 3.3))
    ep = np.arange(1, len(curve["cost"]) + 1)
    axes[0].plot(ep, curve["train_cost"], ".", ms=2, alpha=0.5)
    axes[0].set(xlabel="episode", ylabel=r"mean $\log(1+\bar L)$ per step", title="transformed cost")
    axes[1].semilogy(ep, curve["cost"], ".", ms=2, color="0.4", alpha=0.5)
    axes[1].set(xlabel="episode", ylabel=r"mean $\bar L_\mathrm{NIS}$ per step", title="raw cost")
    n_b = len(ep) // batch
    frac = np.asarray(curve["action_frac"])[: n_b * batch].reshape(n_b, batch, grid.size).mean(axis=1)
    bands = kappa_bands(grid, edges)
    shares = np.array([frac[:, m].sum(axis=1) for m in bands.values()])
    mid = batch * (np.arange(n_b) + 0.5)
    axes[2].stackplot(mid, shares, colors=style.colors(len(bands)), labels=list(bands))
    axes[2].set(xlabel="episode", ylabel="share of steps", title=r"$\kappa$ sampled, by band", ylim=(0, 1),
                xlim=(mid[0], mid[-1]))
    axes[2].legend(title=r"$\kappa$", loc="center left", bbox_to_anchor=(1.0, 0.5), reverse=True)
    return fig


def candidate_cost_range(env, n_runs: int = 200, seed: int = 0) -> dict:
    r"""Run the default parameter on ``n_runs`` runs and, at every decision, compute the
    one-step cost of *every* grid value (:meth:`~adaptfilt.mdp.Decision.candidates`).

    Returns ``{"decisions", "median", "max", "max_log1p", "share_above_1e3"}`` over all
    candidate costs: the range of the TD targets a critic would regress on, raw and
    as ``log(1 + L)``."""
    from adaptfilt.costs import transform_cost

    d = env.reset(n_runs=n_runs, rng=np.random.default_rng(seed))
    costs, n = [], 0
    while d is not None:
        costs.append(np.asarray(d.candidates()["cost"], dtype=float).ravel())
        n += d.n_runs
        d, _, _, _ = env.step(np.full(d.n_runs, d.default_index))
    c = np.concatenate(costs)
    return {"decisions": n, "median": float(np.median(c)), "max": float(c.max()),
            "max_log1p": float(transform_cost(c, "log1p").max()), "share_above_1e3": float((c > 1e3).mean())}


def scaler_saturation(env, features: str = "paper", seed: int = 0, runs: int = 64) -> dict[str, dict[str, float]]:
    r"""How a scaler fitted on default-parameter states and clipped at ``+-10`` and the
    library's (fitted on a mix of grid values, squashed with ``asinh``) treat the states
    that *other* parameter values visit (:func:`~adaptfilt.features.visited_states`
    with ``visit="mix"`` and another seed).

    Returns ``{feature: {"clipped": share of states at the clip (default-fitted, clipped scaler),
    "asinh_max": largest |scaled value| (the library's scaler)}}``."""
    from adaptfilt.features import fit_scaler, visited_states

    old = fit_scaler(env, features, runs=runs, seed=seed, visit="default", squash="clip")
    new = fit_scaler(env, features, runs=runs, seed=seed, visit="mix", squash="asinh")
    s = visited_states(env, features, runs=runs, seed=seed + 1, visit="mix")
    s = s[np.isfinite(s).all(axis=1)]
    clipped = (np.abs(old(s)) >= old.clip).mean(axis=0)
    big = np.abs(new(s)).max(axis=0)
    return {n: {"clipped": float(c), "asinh_max": float(b)} for n, c, b in zip(old.names, clipped, big)}


def actor_update_batch(seed: int = 0, batch: int = 32, n_features: int = 3, n_actions: int = 4,
                       gamma: float = 0.5) -> dict:
    r"""A fixed batch for the actor update of Algorithm 2, built as :func:`adaptfilt.actor_critic.train`
    builds one: an actor and a critic with the paper's layers initialised under ``seed``, a target
    critic (a copy), scaled states ``s`` and ``s_next``, the sampled actions, the transformed costs and
    the TD error ``delta = c + gamma V_target(s_next) - V(s)``, still attached to the critic's graph.

    Returns ``{"actor", "critic", "s", "actions", "cost", "delta", "logits"}`` (torch objects)."""
    import copy

    import torch

    from adaptfilt.learned import Actor, Critic

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        actor, critic = Actor(n_features, n_actions), Critic(n_features)
        s, s_next = torch.randn(batch, n_features), torch.randn(batch, n_features)
        actions = torch.randint(n_actions, (batch,))
        cost = torch.log1p(torch.rand(batch) * 10.0)
    target = copy.deepcopy(critic).requires_grad_(False)
    with torch.no_grad():
        td_target = cost + gamma * target(s_next)
    delta = td_target - critic(s)
    return {"actor": actor, "critic": critic, "s": s, "actions": actions, "cost": cost, "delta": delta,
            "logits": actor(s)}


def library_actor_loss(logits, actions, delta, beta: float = 1e-3, sign: int = 1):
    r"""The actor loss of :func:`adaptfilt.actor_critic.train`, the same statements on the same
    tensors: ``mean(sign * delta.detach() * log pi(a | s) - beta * H(pi(. | s)))``
    (``sign=+1`` for a cost; ``tests/test_course_training.py`` checks that one Adam step on it
    reproduces ``train``'s actor)."""
    import torch

    logp = torch.log_softmax(logits, dim=-1)
    logp_a = logp[torch.arange(logits.shape[0]), actions]
    entropy = -(logp.exp() * logp).sum(dim=-1)
    return (sign * delta.detach() * logp_a - beta * entropy).mean()


def check_actor_update(actor_loss: Callable, beta: float = 0.1, seed: int = 0) -> bool:
    r"""Check a reader's actor loss ``actor_loss(logits, actions, delta, beta) -> scalar tensor``
    against :func:`library_actor_loss` on the fixed batch of :func:`actor_update_batch`: the
    gradient it gives the actor's weights (the update direction of Adam's input) and the gradient
    it must *not* give the critic. The reader's actor gradient is written as
    ``a * (TD-error term) + b * (entropy term)`` of the library's (least squares) to say what is
    wrong: ``a = -1`` is the printed sign, ``a = batch`` a sum instead of a mean, ``b = 0`` a
    missing entropy bonus. ``beta`` is larger than the paper's 1e-3 so that the entropy term
    is visible in the gradient. Prints the verdict and returns whether the update is right."""
    import torch

    def grads(loss_fn, **kw):
        b = actor_update_batch(seed=seed)
        loss = loss_fn(b["logits"], b["actions"], b["delta"], **kw)
        params = list(b["actor"].parameters()) + list(b["critic"].parameters())
        g = torch.autograd.grad(loss, params, allow_unused=True)
        n_actor = len(list(b["actor"].parameters()))
        flat = lambda gs, ps: torch.cat([(x if x is not None else torch.zeros_like(p)).reshape(-1) for x, p in zip(gs, ps)])
        return flat(g[:n_actor], params[:n_actor]).double(), flat(g[n_actor:], params[n_actor:]).double(), loss

    try:
        g_actor, g_critic, loss = grads(actor_loss, beta=beta)
    except Exception as err:  # the reader's code: say what failed instead of a traceback
        print(f"your actor_loss raised {type(err).__name__}: {err}")
        return False
    if not (torch.is_tensor(loss) and loss.dim() == 0):
        print(f"your actor_loss must return a scalar tensor (one loss for the batch), got {getattr(loss, 'shape', type(loss))}")
        return False
    g_ref = grads(library_actor_loss, beta=beta)[0]
    g_pg = grads(library_actor_loss, beta=0.0)[0]   # the TD-error term alone
    g_ent = g_ref - g_pg                              # the entropy term alone
    A = torch.stack([g_pg, g_ent], dim=1)
    coef = torch.linalg.lstsq(A, g_actor[:, None]).solution[:, 0]
    resid = float(torch.linalg.norm(A @ coef - g_actor) / torch.linalg.norm(g_ref))
    err = float(torch.linalg.norm(g_actor - g_ref) / torch.linalg.norm(g_ref))
    leaks = float(torch.linalg.norm(g_critic)) > 0.0
    right = err < 1e-5 and not leaks
    a, b = (float(x) for x in coef)
    print(f"actor gradient vs the library's: relative difference {err:.2g}; "
          f"yours = {a:.3g} x (TD-error term) + {b:.3g} x (entropy term){'' if resid < 1e-4 else ' + something else'}")
    if abs(a + 1) < 1e-3:
        print("  the TD-error term has the printed sign -delta log pi (a reward's): for a cost it is +delta log pi")
    elif abs(a - len(actor_update_batch(seed=seed)["actions"])) < 1e-3 * abs(a):
        print("  the TD-error term is summed over the batch: the library averages it (.mean())")
    if abs(b) < 1e-3 and beta > 0:
        print("  the entropy bonus -beta H(pi) is missing")
    elif abs(b + 1) < 1e-3:
        print("  the entropy term has the wrong sign: the loss subtracts beta H(pi), so that minimising it raises H")
    if leaks:
        print("  your loss sends a gradient into the critic: detach the TD error (delta.detach())")
    print("right: your update is the library's" if right else "not yet right")
    return right


def plain_soft_update(target, source, tau: float) -> None:
    """The target critic's soft (Polyak) update psi_bar <- tau psi + (1 - tau) psi_bar, one weight
    tensor at a time. ``adaptfilt.actor_critic.soft_update`` computes the same numbers for all the
    tensors in two batched calls (``tests/test_course_training.py`` holds them equal bit for bit)."""
    import torch

    with torch.no_grad():
        for psi_bar, psi in zip(target.parameters(), source.parameters()):
            psi_bar.mul_(1.0 - tau).add_(psi, alpha=tau)    # (1 - tau) psi_bar + tau psi


def plot_state_probs(policy, cases: Mapping[str, np.ndarray], ax=None, title: str | None = None):
    r"""``pi(theta | s)`` of one policy at several raw information states as a heat map: one row
    per entry of ``cases`` (label -> state ``(1, d)``), one column per grid value, the most
    probable value of each row marked."""
    fig, ax = figure_axes(ax, size=(7.0, 0.5 * len(cases) + 1.6))
    P = np.concatenate([policy.probs(st) for st in cases.values()])
    grid = np.asarray(policy.grid)
    im = ax.imshow(P, vmin=0.0, vmax=1.0, cmap="Blues", aspect="auto", interpolation="nearest")
    ax.plot(P.argmax(axis=1), np.arange(len(cases)), "o", ms=4, color="#D55E00")
    ax.set_xticks(np.arange(grid.size), [f"{g:g}" for g in grid], rotation=90)
    ax.set_yticks(np.arange(len(cases)), list(cases))
    ax.set_xlabel(r"$\kappa$")
    ax.grid(False)
    fig.colorbar(im, ax=ax, label=r"$\pi(\kappa\,|\,s)$")
    if title:
        ax.set_title(title)
    return fig
