r"""The plumbing of the course's learning chapters (6 The actor-critic, 7 Reading the stored policies,
11 Your own model, 12 RL in practice, 13 Beyond the paper).

As :mod:`adaptfilt.course.common` and the modules of chapters 1-4 do: what a chapter computes in
passing (bookkeeping over seeds, binned policy probabilities, a timed
training) and its figures live here, documented and tested
(``tests/test_course_rl.py``), so that a chapter reads as prose with short
calls. Figures use :mod:`adaptfilt.style`.

========================================  =========================================================
chapter                                   helpers
========================================  =========================================================
6 The actor-critic                        :func:`plot_sign_demo`, :func:`plot_training` (with
                                          :func:`kappa_bands`), :func:`candidate_cost_range`,
                                          :func:`scaler_saturation`, :func:`actor_update_batch`,
                                          :func:`library_actor_loss`, :func:`check_actor_update`,
                                          :func:`plot_state_probs` (widget :func:`show_policy_probs`)
7 Reading the stored policies             :func:`plot_share_over_time`, :func:`usage_lines`,
                                          :func:`plot_switch_off`, :func:`ungm_state`,
                                          :func:`plot_policy_probs` (widget :func:`show_policy_probs`)
11 Your own model                         :func:`seed_lines`, :func:`plot_differences`
12 RL in practice                         :func:`plot_seed_spread`, :func:`seed_verdicts`,
                                          :func:`claims_table`, :func:`timed`
13 Beyond the paper                       :func:`verdict_counts`, :func:`plot_seed_differences`,
                                          :func:`divergence_onsets`, :func:`plot_cost_divergence`,
                                          :func:`plot_ood_gains`
========================================  =========================================================

A *seed group* is a set of policies named ``<group>-s<seed>``
(:func:`adaptfilt.seed_stats.seed_groups`); its aggregate is the IQM
over seeds with the two-level (seeds x runs) bootstrap interval of
:func:`adaptfilt.seed_stats.aggregate`.
"""
from __future__ import annotations

import time
from typing import Callable, Mapping, Sequence

import numpy as np

from adaptfilt.seed_stats import aggregate, seed_groups, seed_verdict

__all__ = [
    # chapter 6
    "plot_sign_demo", "kappa_bands", "plot_training", "candidate_cost_range", "scaler_saturation",
    "actor_update_batch", "library_actor_loss", "check_actor_update", "plot_state_probs",
    # chapter 7 (and the widget of both)
    "plot_share_over_time", "usage_lines", "plot_switch_off", "ungm_state", "plot_policy_probs", "show_policy_probs",
    # chapter 11
    "seed_lines", "plot_differences",
    # chapter 12
    "plot_seed_spread", "seed_verdicts", "claims_table", "timed",
    # chapter 13
    "verdict_counts", "plot_seed_differences", "divergence_onsets", "plot_cost_divergence", "plot_ood_gains",
]


def _ax(ax, **figure_kw):
    if ax is not None:
        return ax.figure, ax
    from adaptfilt import style

    return style.figure(**figure_kw)


def _smooth(y: np.ndarray, w: int) -> np.ndarray:
    w = max(1, min(int(w), len(y)))
    return np.convolve(y, np.ones(w) / w, mode="valid")


# ============================================================== chapter 6
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
    from adaptfilt.actor_critic import transform_cost

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
    (``sign=+1`` for a cost; ``tests/test_course_rl.py`` checks that one Adam step on it
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


def plot_state_probs(policy, cases: Mapping[str, np.ndarray], ax=None, title: str | None = None):
    r"""``pi(theta | s)`` of one policy at several raw information states as a heat map: one row
    per entry of ``cases`` (label -> state ``(1, d)``), one column per grid value, the most
    probable value of each row marked."""
    fig, ax = _ax(ax, size=(7.0, 0.5 * len(cases) + 1.6))
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


# ============================================================== chapter 7
def plot_share_over_time(results, policies: Sequence[str], at_least: float, ax=None,
                         overlay: Callable[[np.ndarray], np.ndarray] | None = None, overlay_label: str = ""):
    r"""Share of runs whose parameter is ``>= at_least`` at each step ``k``, per policy
    (from ``Results[...].choices``; a seed group's choices are averaged over seeds),
    with an optional ``overlay(k)`` on a second axis (e.g. the forcing of the dynamics)."""
    fig, ax = _ax(ax)
    grid = results.grid
    for name in policies:
        members = seed_groups(results.names).get(name, [name])
        ch = np.mean([results[m].choices for m in members], axis=0)
        k = np.arange(1, ch.shape[0] + 1)
        ax.plot(k, ch[:, grid >= at_least].sum(axis=1), label=name)
    ax.set(xlabel="time step k", ylabel=f"share of runs with $\\kappa \\geq$ {at_least:g}", ylim=(0, None))
    if overlay is not None:
        ax2 = ax.twinx()
        ax2.plot(k, overlay(k), color="0.55", lw=1, ls="--")
        ax2.set_ylabel(overlay_label, color="0.4")
        ax2.grid(False)
        ax2.spines["right"].set_visible(True)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=len(policies))  # below the axes, off the data
    return fig


def usage_lines(results, names: Sequence[str], split: float = 50.0, min_share: float = 0.01) -> str:
    r"""One line per policy: its RMSE, the share of steps with a parameter ``<= split``
    and every grid value used in at least ``min_share`` of the steps."""
    grid = results.grid
    out = []
    for n in names:
        u = np.asarray(results[n].usage, dtype=float)
        u = u / u.sum()
        used = ", ".join(f"{g:g}: {x:.0%}" for g, x in zip(grid, u) if x >= min_share)
        out.append(f"{n:12s} RMSE {results[n].rmse:5.3g} | {split:g} or less: {u[grid <= split].sum():4.0%} | {used}")
    return "\n".join(out)


def _binned(x: np.ndarray, y: np.ndarray, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Medians of ``x`` and means of ``y`` in ``n_bins`` bins of equal count of ``x``."""
    order = np.argsort(x)
    parts = np.array_split(order, n_bins)
    return np.array([np.median(x[p]) for p in parts]), np.array([y[p].mean() for p in parts])


def plot_switch_off(policies: Sequence, states: np.ndarray, columns: Mapping[str, int], at_least: float,
                    n_bins: int = 12):
    r"""The probability ``pi(theta >= at_least | s)`` that each policy puts on the large
    parameter values, averaged in bins of equal count of one feature (``|feature|``),
    one panel per entry of ``columns`` (label -> column of ``states``), one line per
    policy. All policies are probed on the same raw ``states`` (their own scalers
    apply), so the lines compare functions, not the states each policy visits."""
    from adaptfilt import style

    states = states[np.isfinite(states).all(axis=1)]
    fig, axes = style.figure(1, len(columns), size=(4.2 * len(columns), 3.3), sharey=True)
    axes = np.atleast_1d(axes)
    cols = style.colors(len(policies))
    for ax, (label, j) in zip(axes, columns.items()):
        x = np.abs(states[:, j])
        for pol, c in zip(policies, cols):
            p = pol.probs(states)[:, np.asarray(pol.grid) >= at_least].sum(axis=1)
            mid, mean = _binned(x, p, n_bins)
            ax.plot(mid, mean, "o-", ms=3, color=c, label=pol.name)
        ax.set(xscale="log", xlabel=f"{label} (bins of equal count)", ylim=(-0.02, 1.02))
    axes[0].set_ylabel(f"$\\pi(\\kappa \\geq$ {at_least:g}$\\,|\\,s)$")
    axes[-1].legend(loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=8)
    return fig


def ungm_state(P_pred: float, innov: float, x_pred: float = 5.0, k: int = 100) -> np.ndarray:
    r"""A raw UNGM information state ``(1, 7)`` at step ``k`` (the paper's index) in the layout
    ``paper+time``: ``[x_pred, tr P, log det P, z, innov, cos 0.05k, sin 0.05k]``, consistent with
    the default-parameter update: the unscented mean of ``x^2/20`` is exact for every
    kappa, ``(x_pred^2 + P_pred)/20``, so ``z = (x_pred^2 + P_pred)/20 + innov``."""
    from adaptfilt.models import ungm

    if not P_pred > 0:
        raise ValueError(f"P_pred must be > 0, got {P_pred}")
    z = (x_pred ** 2 + P_pred) / 20.0 + innov
    phase = np.asarray(ungm().time_features(k), dtype=float)
    return np.array([[x_pred, P_pred, np.log(P_pred), z, innov, *phase]])


def plot_policy_probs(policies: Sequence, state: np.ndarray, ax=None, title: str | None = None,
                      colorbar: bool = False):
    r"""``pi(theta | s)`` of each policy at one raw information state ``(1, d)`` as a heat map:
    one row per policy, one column per grid value, the most probable value of each row marked."""
    fig, ax = _ax(ax)
    P = np.concatenate([p.probs(state) for p in policies])          # (n_policies, G)
    grid = np.asarray(policies[0].grid)
    im = ax.imshow(P, vmin=0.0, vmax=1.0, cmap="Blues", aspect="auto", interpolation="nearest")
    ax.plot(P.argmax(axis=1), np.arange(len(policies)), "o", ms=3, color="#D55E00")
    ax.set_xticks(np.arange(grid.size), [f"{g:g}" for g in grid], rotation=90)
    ax.set_yticks(np.arange(len(policies)), [p.name for p in policies])
    ax.set_xlabel(r"$\kappa$")
    ax.grid(False)
    if title:
        ax.set_title(title)
    if colorbar:
        fig.colorbar(im, ax=ax, label=r"$\pi(\kappa\,|\,s)$")
    return fig


def show_policy_probs(policies: Sequence, P_pred: float = 1.0, innov: float = 0.0, x_pred: float = 5.0,
                      k: int = 100) -> None:
    """The widget body of chapter 6: :func:`plot_policy_probs` at :func:`ungm_state`."""
    import matplotlib.pyplot as plt

    plot_policy_probs(policies, ungm_state(P_pred, innov, x_pred, k), colorbar=True,
                      title=f"tr P = {P_pred:.3g}, innovation = {innov:+.2f}, x_pred = {x_pred:g}, k = {k}")
    plt.show()


# ============================================================== chapter 11
def seed_lines(results, groups: Sequence[str], baselines: Sequence[str] = (),
               metrics: Sequence[str] = ("rmse", "anees", "objective")) -> str:
    r"""Baselines one line each (value [run-level CI]), then each seed group: IQM over its
    seeds [two-level 95 % CI] (range of the per-seed values)."""
    rows = []
    for n in baselines:
        p = results[n]
        cells = []
        for m in metrics:
            ci = getattr(p, m + "_ci", None)
            cells.append(f"{m} {getattr(p, m):.3g}" + (f" [{ci[0]:.3g}, {ci[1]:.3g}]" if ci is not None else ""))
        rows.append((n, cells))
    groups_all = seed_groups(results.names)
    for g in groups:
        names = groups_all[g]
        cells = []
        for m in metrics:
            a = aggregate(results, names, m)
            cells.append(f"{m} {a.iqm:.3g} [{a.iqm_ci[0]:.3g}, {a.iqm_ci[1]:.3g}] ({a.values.min():.3g}..{a.values.max():.3g})")
        rows.append((f"{g} ({len(names)} seeds)", cells))
    width = max((len(label) for label, _ in rows), default=0)
    return "\n".join(f"{label:{width}s}  " + "   ".join(cells) for label, cells in rows)


def plot_differences(diffs: Mapping[str, Mapping[str, tuple[float, float, float]]], ax=None, ylabel: str = "",
                     title: str | None = None):
    r"""Paired differences with intervals: ``diffs[condition][label] = (diff, lo, hi)``,
    one x position per condition, one marker per label, a line at 0."""
    from adaptfilt import style

    fig, ax = _ax(ax)
    conds = list(diffs)
    labels = list(dict.fromkeys(lab for c in conds for lab in diffs[c]))
    x = np.arange(len(conds))
    off = np.linspace(-0.2, 0.2, len(labels)) if len(labels) > 1 else np.zeros(1)
    for j, (lab, col) in enumerate(zip(labels, style.colors(len(labels)))):
        d = np.array([diffs[c].get(lab, (np.nan,) * 3) for c in conds])
        ax.errorbar(x + off[j], d[:, 0], yerr=[d[:, 0] - d[:, 1], d[:, 2] - d[:, 0]], fmt="o", color=col, capsize=3,
                    label=style.policy_label(lab))
    ax.axhline(0, color="black", lw=0.8)
    ax.set_xticks(x, conds)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.legend()
    return fig


# ============================================================== chapter 12
def plot_seed_spread(results, groups: Sequence[str], metric: str = "rmse", ax=None):
    r"""Each seed of each group with its own run-level 95 % interval (the noise of one
    evaluation), and beside them the group's IQM and mean with the two-level
    (seeds x runs) intervals: what a single seed hides."""
    from adaptfilt import style

    fig, ax = _ax(ax)
    all_groups = seed_groups(results.names)
    y0 = 0
    ticks, labels = [], []
    for g, col in zip(groups, style.colors(len(groups))):
        names = all_groups[g]
        for i, n in enumerate(names):
            p = results[n]
            v, (lo, hi) = getattr(p, metric), getattr(p, metric + "_ci")
            ax.errorbar(v, y0 + i, xerr=[[v - lo], [hi - v]], fmt="o", ms=4, color=col, capsize=2)
            ticks.append(y0 + i)
            labels.append(n)
        a = aggregate(results, names, metric)
        for j, (lab, v, (lo, hi), mk) in enumerate([("IQM", a.iqm, a.iqm_ci, "D"), ("mean", a.mean, a.mean_ci, "s")]):
            yy = y0 + len(names) + j
            ax.errorbar(v, yy, xerr=[[v - lo], [hi - v]], fmt=mk, ms=6, color=col, mec="black", capsize=4, lw=2)
            ticks.append(yy)
            labels.append(f"{g}: {lab} of {len(names)}")
        y0 += len(names) + 3
    ax.set_yticks(ticks, labels)
    ax.invert_yaxis()
    ax.set_xlabel(f"time-averaged {metric.upper() if metric in ('rmse', 'anees') else metric} (95 % intervals)")
    return fig


def seed_verdicts(results, group: str, other: str, metric: str = "rmse", better: str = "lower") -> dict:
    r"""What each seed of ``group`` alone says about "``group`` is ``better`` than ``other``"
    (its own paired run-level interval): ``{"per_seed": {name: (diff, lo, hi, verdict)},
    "counts": {verdict: n}}``."""
    names = seed_groups(results.names)[group]
    per = {}
    for n in names:
        d = results.paired_difference(n, other, metric)
        per[n] = (*d, seed_verdict(d, better))
    counts: dict[str, int] = {}
    for v in per.values():
        counts[v[3]] = counts.get(v[3], 0) + 1
    return {"per_seed": per, "counts": counts}


def claims_table(claims: Mapping, experiment: str, keys: Sequence[str] = ("C1", "C2", "C4", "C6"),
                 only_held: bool = True) -> str:
    r"""A Markdown table of the stored claims (:func:`adaptfilt.experiments.artefacts.load_claims`) of one
    experiment: the seed-level verdict beside the number of seeds that hold it *alone*
    (each seed's own paired interval; defined where ``b`` is a single policy). A verdict judged
    with a margin ("equal", "not worse") shows it, and the verdict without it where that differs
    (:func:`adaptfilt.experiments.report.verdict_text`). ``only_held``: only the rows where that
    count exists."""
    from adaptfilt.experiments.report import verdict_text
    rows = ["| claim | comparison | metric | a - b, IQM [seed-level 95 % CI] | seed-level verdict | seeds holding alone |",
            "|---|---|---|---|---|---|"]
    seen = set()
    for k in keys:
        for r in claims.get(k, []):
            if r["experiment"] != experiment or (only_held and r.get("seeds_holding") is None):
                continue
            key = (r["claim"], r["metric"])
            if key in seen:
                continue
            seen.add(key)
            held = "" if r.get("seeds_holding") is None else f"{r['seeds_holding']}/{r['n_seeds']}"
            claim = r["claim"].replace(" equal than ", " equal to ")
            rows.append(f"| {k} | {claim} | {r['metric']} | {r['diff']:+.3g} [{r['ci'][0]:+.3g}, {r['ci'][1]:+.3g}] "
                        f"| {verdict_text(r)} | {held} |")
    return "\n".join(rows) + "\n"


def timed(fn: Callable, *args, **kwargs) -> tuple[object, float]:
    """``(fn(*args, **kwargs), CPU seconds it took)`` (process time: less sensitive to a
    loaded machine than wall time; compare two such numbers from one run only)."""
    c0 = time.process_time()
    out = fn(*args, **kwargs)
    return out, time.process_time() - c0


# ============================================================== chapter 13
def verdict_counts(results, group: str, other: str, metrics: Sequence[str] = ("cost", "rmse")) -> str:
    r"""One line per metric: ``group - other`` as IQM over seeds [two-level 95 % CI], the seed-level
    verdict, and how many seeds alone (their own paired run-level interval) find ``group`` lower,
    tied or higher."""
    from adaptfilt.seed_stats import difference

    names = seed_groups(results.names)[group]
    lines = []
    for m in metrics:
        d = difference(results, names, [other], m)["iqm"]
        c = seed_verdicts(results, group, other, m)["counts"]
        alone = ", ".join(f"{n} {v}" for v, n in sorted(c.items(), key=lambda kv: -kv[1]))
        lines.append(f"{group} - {other}  {m:9s} {d[0]:+.4g} [{d[1]:+.4g}, {d[2]:+.4g}]  {seed_verdict(d)}"
                     f"   (seeds alone: {alone})")
    return "\n".join(lines)


def divergence_onsets(env, value: float, n_runs: int = 1000, seed: int = 0) -> dict:
    r"""Run the environment's filter with the grid value ``value`` at every step on ``n_runs``
    simulated runs and find, per run, whether it diverged and when, by the library's one definition
    (:data:`adaptfilt.metrics.DIVERGED_NEES`): a run is divergent when its time-averaged NEES exceeds
    ``10^4 n_x`` (:func:`adaptfilt.metrics.divergent`), and its onset is the first step at which the
    running time average crosses that line (:func:`adaptfilt.metrics.divergence_step`); and whether the
    covariance was repaired at some step. Returns ``{"divergent": (M,) bool, "onset": (M,) first step
    or -1, "repaired": (M,) bool, "nees": (T, M)}``; a run with an onset that recovers below the line
    by the last step has ``onset >= 0`` and ``divergent`` False."""
    from adaptfilt.metrics import divergence_step, divergent

    grid = np.asarray(env.grid, dtype=float)
    hit = np.flatnonzero(np.isclose(grid, value))
    if hit.size == 0:
        raise ValueError(f"{value} is not on the grid {grid.tolist()}")
    d = env.reset(n_runs=n_runs, rng=np.random.default_rng(seed), stream=seed)
    a = np.full(n_runs, hit[0])
    nees, repaired = [], np.zeros(n_runs, dtype=bool)
    done = False
    while not done:
        d, _, done, info = env.step(a)
        e = info["x_filt"] - env.traj.x[:, info["t"], :]
        nees.append(np.einsum("mi,mi->m", e, np.linalg.solve(info["P_filt"], e[..., None])[..., 0]))
        repaired |= np.asarray(info["repaired"], dtype=bool)
    N = np.array(nees)
    return {"divergent": divergent(N.T, env.model.nx), "onset": divergence_step(N.T, env.model.nx),
            "repaired": repaired, "nees": N}


def _clipped_errorbar(ax, v, lo, hi, y, lim, text_fmt, **kw):
    """An error bar at height ``y`` whose parts outside ``lim`` are cut at the axis edge, with the
    value written there (a point far off the scale stays visible and readable)."""
    a, b = lim
    ax.errorbar(min(max(v, a), b), y, xerr=[[max(min(v, b) - max(lo, a), 0)], [max(min(hi, b) - max(v, a), 0)]],
                **kw)
    outside = [(x, side) for x, side in ((v, "point"), (hi, "upper"), (lo, "lower")) if not a <= x <= b]
    if not outside:
        return
    x, _ = outside[0]
    edge, ha, mk = (b, "right", ">") if x > b else (a, "left", "<")
    ax.plot(edge, y, mk, ms=7, color=kw.get("color", "black"), clip_on=False, zorder=5)
    f = text_fmt.format
    what = f"{f(v)} [{f(lo)}, {f(hi)}]" if not a <= v <= b else f"to {f(x)}"
    ax.annotate(what, (edge, y), textcoords="offset points", xytext=(-8 if ha == "right" else 8, 5), ha=ha,
                va="bottom", fontsize=8, color=kw.get("color", "black"))


def plot_seed_differences(results, groups: Sequence[str], other: str, metrics: Sequence[str] = ("cost", "rmse"),
                          xlim: Mapping[str, tuple[float, float]] | None = None, axes=None):
    r"""Each seed of each group minus ``other`` (its paired run-level 95 % interval) and the group's
    IQM and mean of the differences with their two-level (seeds x runs) intervals, on a linear axis
    with a line at 0, one panel per metric: an effect far smaller than the values themselves stays
    visible. ``xlim[metric]`` fixes a panel's range; a point or interval end outside it is cut at the
    edge, marked with a triangle and its value written beside it."""
    from adaptfilt import style
    from adaptfilt.seed_stats import difference

    if axes is None:
        fig, axes = style.figure(1, len(metrics), size=(5.2 * len(metrics) + 1.6, 3.2 * len(groups) + 1.2),
                                 sharey=True)
    axes = np.atleast_1d(axes)
    fig = axes[0].figure
    all_groups = seed_groups(results.names)
    for ax, m in zip(axes, metrics):
        y0, ticks, labels, ends = 0, [], [], []
        rows = []
        for g, col in zip(groups, style.colors(len(groups))):
            names = all_groups[g]
            for i, n in enumerate(names):
                rows.append((y0 + i, *results.paired_difference(n, other, m), "o", 4, col, 1.2))
                labels.append(n)
            d = difference(results, names, [other], m)
            for j, (lab, mk) in enumerate((("IQM", "D"), ("mean", "s"))):
                rows.append((y0 + len(names) + j, *d[lab.lower()], mk, 7, col, 2.2))
                labels.append(f"{g}: {lab} of {len(names)}")
            y0 += len(names) + 3
        ticks = [r[0] for r in rows]
        lim = (xlim or {}).get(m)
        if lim is None:
            ends = np.array([r[1:4] for r in rows], dtype=float)
            lim = (min(ends.min(), 0.0), max(ends.max(), 0.0))
            pad = 0.05 * (lim[1] - lim[0])
            lim = (lim[0] - pad, lim[1] + pad)
        for y, v, lo, hi, mk, ms, col, lw in rows:
            _clipped_errorbar(ax, v, lo, hi, y, lim, "{:+.3g}", fmt=mk, ms=ms, color=col, capsize=3, lw=lw,
                              mec="black" if mk != "o" else col)
        ax.axvline(0.0, color="black", lw=1, ls="--")
        ax.set_xlim(*lim)
        ax.set_yticks(ticks, labels)
        name = m.upper() if m in ("rmse", "anees") else m
        ax.set_xlabel(f"{name} minus {other}'s (95 % intervals; dashed: no difference)")
    axes[0].invert_yaxis()
    return fig


def _label_points(ax, xs, ys, texts, min_px: float = 14.0):
    """Label points on one line without overlap and without dropping any: each label goes to the
    nearest free row (above, below, two rows above, two below, ...), a row being free when its last
    label is at least ``min_px`` display pixels to the left; a label off its point's own row gets a
    thin leader line to the point."""
    ax.figure.canvas.draw()
    to_px = ax.transData.transform
    last: dict[int, float] = {}
    rows = [1, -1, 2, -2, 3, -3, 4, -4]
    for x, y, t in sorted(zip(xs, ys, texts), key=lambda r: r[0]):
        if not (np.isfinite(x) and ax.get_xlim()[0] <= x <= ax.get_xlim()[1]):
            continue
        px = to_px((x, y))[0]
        row = next((r for r in rows if px - last.get(r, -np.inf) >= min_px), rows[-1])
        last[row] = px
        dy = 6 + 10 * (row - 1) if row > 0 else -11 - 10 * (-row - 1)
        ax.annotate(t, (x, y), textcoords="offset points", xytext=(0, dy), ha="center", fontsize=8, color="0.3",
                    zorder=6, arrowprops=dict(arrowstyle="-", color="0.6", lw=0.6, shrinkA=0, shrinkB=3)
                    if abs(row) > 1 else None)


def plot_cost_divergence(results, groups: Sequence[str] = (), ax=None, title: str | None = None,
                         metric: str = "cost_charged", xlim: tuple[float, float] = (-40.0, 105.0),
                         legend: str | None = "right"):
    r"""Every policy of a SIF evaluation as a point (mean cost relative to the default's, fraction of
    divergent runs), the cost ``metric`` by default charged for the iterations each policy computes
    (greedy's candidates included): the fixed iteration counts (a grey line, labelled with n_it),
    greedy, and each seed of ``groups``; the default is the dotted vertical line at 0.

    The x axis is ``100 (cost / default's cost - 1)`` in %, on the linear range ``xlim``; give each
    panel of a figure a range that fits its own policies (the costs differ by orders of magnitude in
    how far the policies spread) and say so in the caption. A point beyond it is drawn at the edge as
    a triangle with its value written beside it. The n_it labels never overlap: a crowded one moves
    to a further row with a leader line. The divergent fraction is on a symlog axis so that
    0 (never diverged) stays on the plot. The learned seeds are drawn last, above the fixed line.
    ``legend``: ``"right"`` of the axes, ``"figure"`` (below all panels of a constrained-layout
    figure), or ``None``."""
    from adaptfilt import style

    fig, ax = _ax(ax, size=(7.5, 4.6))
    ref = getattr(results["default"], metric)

    def rel(n):
        return 100.0 * (getattr(results[n], metric) / ref - 1.0)

    lo, hi = xlim
    ax.set_xlim(lo, hi)
    ax.axvline(0.0, color="0.35", lw=1.2, ls=":", label="default ($n_{it}$ = 10): 0 %", zorder=1)
    fixed = [n for n in results.names if n.startswith("fixed-") and not n.startswith("fixed-both-")]
    x = np.array([rel(n) for n in fixed])
    y = np.array([100 * results[n].divergent_frac for n in fixed])
    ax.plot(np.clip(x, lo, hi), y, "o-", color="0.6", ms=4, label="fixed $n_{it}$", zorder=2)
    cols = style.colors(len(groups) + 1)
    markers = ["^", "v", "o", "P", "X"]

    def point(n, mk, col, ms, label=None, z=3):
        xv, yv = rel(n), 100 * results[n].divergent_frac
        inside = lo <= xv <= hi
        ax.plot(min(max(xv, lo), hi), yv, mk if inside else (">" if xv > hi else "<"), ms=ms, color=col,
                mec="black", mew=0.6, alpha=0.85, label=label, zorder=z, clip_on=False)
        return None if inside else (xv, yv)

    far = []
    if "greedy" in results:
        if (f := point("greedy", "D", cols[0], 8, "greedy")) is not None:
            far.append(("greedy", *f))
    all_groups = seed_groups(results.names)
    for k, (g, col) in enumerate(zip(groups, cols[1:])):
        names = all_groups.get(g, [])
        for i, n in enumerate(names):
            f = point(n, markers[k % len(markers)], col, 7, f"{g} ({len(names)} seeds)" if i == 0 else None, z=4 + k)
            if f is not None:
                far.append((n, *f))
    ax.set_yscale("symlog", linthresh=0.01)
    ax.set_ylim(-0.003, None)
    _label_points(ax, x, y, [n.split("=")[1] for n in fixed])
    for n, xv, yv in [(n, xv, yv) for n, xv, yv in zip(fixed, x, y) if not lo <= xv <= hi] + far:
        label = f"fixed $n_{{it}}$ = {n.split('=')[1]}" if n.startswith("fixed-") else n
        ax.annotate(f"{label}: {xv:+.2g} %", (hi if xv > hi else lo, yv),
                    textcoords="offset points", xytext=(-8 if xv > hi else 8, 6), ha="right" if xv > hi else "left",
                    fontsize=8, color="0.3")
    what = "mean cost, compute charged" if metric == "cost_charged" else f"mean {metric}"
    ax.set_xlabel(f"{what}, relative to the default (%)")
    ax.set_ylabel("divergent runs (%)")
    if title:
        ax.set_title(title)
    if legend == "right":
        ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8)
    elif legend == "figure":  # one legend for all panels, below them
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=6, fontsize=9)
    return fig


def plot_ood_gains(table: Mapping, metric: str = "objective",
                   columns: Sequence[str] = ("greedy", "best fixed", "learned", "retuned")):
    r"""One heat map per column of :func:`adaptfilt.experiments.ood.gain_table` (gain over the
    default on the 3 x 3 grid of truth noise scalings; positive is better), on one colour scale."""
    import matplotlib.pyplot as plt

    from adaptfilt.experiments.ood import plot_gain

    fig, axes = plt.subplots(1, len(columns), figsize=(4.1 * len(columns), 3.7), layout="constrained")
    v = max(abs(c["gain"]) for row in table.values() for k, c in row.items() if k in columns)
    for ax, col in zip(np.atleast_1d(axes), columns):
        plot_gain(table, col, metric, ax=ax, title=f"{col}", vmax=v)
    fig.suptitle(f"gain in {metric} over the default (positive: better)")
    return fig
