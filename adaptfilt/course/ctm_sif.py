r"""The analyses of chapter 11 (SIF on CTM, experiments ``ctm-sif-*``): the SIF's integration noise, and
the iterations a policy chooses against the innovation it sees.

==============================  ================================================================
function                        what
==============================  ================================================================
sif_spread                      the SIF's integration noise: spread of estimates on identical data
innovation_response,            SIF: the iterations a policy chooses early and late in the run and
innovation_responses,           by quartile of the one-iteration innovation it saw, per training
innovation_response_md          seed, and summarised over the seeds of each group
==============================  ================================================================

What chapters 9-11 share (seed tables, grid usage, a plain log axis):
:mod:`adaptfilt.course.paper_common`.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from adaptfilt.course.paper_common import markdown_table

__all__ = ["sif_spread", "innovation_response", "innovation_responses", "innovation_response_md"]


# ------------------------------------------------------------------ SIF integration noise
def sif_spread(filt_factory, n_iters: Sequence[int], traj, n_filters: int = 500, pos=(0, 2)) -> dict[str, np.ndarray]:
    """The integration noise of a stochastic filter: the first run of ``traj`` filtered
    ``n_filters`` times (identical data, so all spread is the rule's randomness) with
    ``filt_factory(n_iter)`` for each ``n_iter``. Returns ``{"n_iter", "spread", "claimed"}``:
    the standard deviation over the filters of the final position estimate, and the
    position standard deviation the filters claim (root mean of the diagonal of ``P``),
    both averaged over the ``pos`` coordinates."""
    pos = list(pos)
    z = np.repeat(np.asarray(traj.z)[:1], n_filters, axis=0)
    spread, claimed = [], []
    for n in n_iters:
        run = filt_factory(int(n)).run(z)
        spread.append(run.mean[:, -1, pos].std(axis=0).mean())
        claimed.append(np.sqrt(np.diagonal(run.cov[:, -1], axis1=-2, axis2=-1)[:, pos].mean()))
    return {"n_iter": np.asarray(n_iters, dtype=float), "spread": np.array(spread), "claimed": np.array(claimed)}


# ------------------------------------------------------------------ what a policy does with the innovation it sees
def innovation_response(env, policy, n_runs: int = 200, seed: int = 5, early: int = 10,
                        features: str = "paper+innov@1") -> dict:
    """Roll ``policy`` through ``env`` on ``n_runs`` runs (``rng = default_rng(seed)``) and record,
    at every step, the parameter it chose and the size of the innovation feature it saw (the norm
    of the ``innov@...`` block of its own feature set, else of ``features``; on the SIF's CTM the
    bearing innovation of a one-iteration update, in radians).

    Returns ``{"early", "late", "quartiles", "edges"}``: the mean parameter over steps
    ``1..early`` and after them, and over the run-steps in each quartile of the innovation
    (pooled over runs and steps; non-finite innovations, a diverged run's, left out), with the
    three quartile edges. A policy whose choice follows the innovation has rising ``quartiles``.
    """
    from adaptfilt.features import FeatureSet
    from adaptfilt.mdp import rollout

    fs = FeatureSet.parse(getattr(policy, "feature_set", None) or features)
    cols = [i for i, n in enumerate(fs.names(env.model, env.grid)) if n.startswith("innov")]
    seen = []

    class _Watch:  # passes the choices through, and records the innovation each one saw
        name, predict_param = getattr(policy, "name", "policy"), getattr(policy, "predict_param", None)

        def act(self, d):
            seen.append(np.linalg.norm(d.observe(fs)[:, cols], axis=-1))
            return policy.act(d)

    run, _ = rollout(env, _Watch(), n_runs=n_runs, rng=np.random.default_rng(seed))
    n, a = np.asarray(run.params, dtype=float).T, np.array(seen)  # (T, M): chosen, innovation seen
    ok = np.isfinite(a)
    edges = np.quantile(a[ok], [0.25, 0.5, 0.75])
    q = np.digitize(a, edges)
    quart = np.array([n[ok & (q == k)].mean() if np.any(ok & (q == k)) else np.nan for k in range(4)])
    return {"early": float(n[:early].mean()), "late": float(n[early:].mean()), "quartiles": quart, "edges": edges,
            "early_steps": early}


def innovation_responses(experiments: Sequence[str], groups: Sequence[str] = ("adaptive", "myopic"),
                         seeds: Sequence[int] = range(8), n_runs: int = 200, seed: int = 5, load=None,
                         n_steps: int | None = None) -> dict:
    """:func:`innovation_response` of every training seed of every group, each on the same runs
    (``seed``) in a fresh environment of its experiment (``make_env(0, n_steps)``):
    ``{(experiment, group): [response of seed 0, seed 1, ...]}``. ``load(experiment, group, seed=s)``
    gives a policy (default :func:`adaptfilt.experiments.artefacts.stored_policy`)."""
    from adaptfilt.experiment_registry import get_experiment

    if load is None:
        from adaptfilt.experiments.artefacts import stored_policy as load
    return {(e, g): [innovation_response(get_experiment(e).make_env(0, n_steps), load(e, g, seed=s), n_runs, seed)
                     for s in seeds] for e in experiments for g in groups}


def innovation_response_md(responses: dict, what: str = "N_it") -> str:
    """:func:`innovation_responses` as a table, one row per (experiment, group): each statistic as
    the IQM over the seeds with the seeds' range, and two differences per seed, with their IQM, range
    and how many seeds have them above zero: steps ``1..early`` less the steps after them, and the
    loudest quarter of the innovation less the quietest."""
    from adaptfilt.seed_stats import iqm

    cell = lambda v: f"{iqm(v):.1f} ({v.min():.1f}-{v.max():.1f})" if v.size > 1 else f"{v[0]:.1f}"
    # a difference: two decimals (a seed that nearly always chooses one value differs by hundredths), and how
    # many seeds have it above zero
    diff = lambda d: (f"{iqm(d):+.2f} ({d.min():+.2f} to {d.max():+.2f}); " if d.size > 1 else f"{d[0]:+.2f}; ") \
        + f"{np.sum(d > 0)} / {d.size} > 0"
    rows = []
    for (e, g), rs in responses.items():
        early, late = np.array([r["early"] for r in rs]), np.array([r["late"] for r in rs])
        qs = np.array([r["quartiles"] for r in rs])
        rows.append([e, g, str(len(rs)), cell(early), cell(late), *(cell(qs[:, k]) for k in range(4)),
                     diff(early - late), diff(qs[:, 3] - qs[:, 0])])
    k = next(iter(responses.values()))[0]["early_steps"]
    head = ["experiment", "group", "seeds", f"{what}, steps 1-{k}", "after", "quartile 1 (quietest)", "quartile 2",
            "quartile 3", "quartile 4 (loudest)", "early - after", "quartile 4 - quartile 1"]
    return markdown_table(head, rows)
