r"""Monte-Carlo evaluation of parameter policies (Section VI-E of the paper).

:func:`evaluate` simulates ``M`` trajectories **once** and runs every policy
on the same trajectories, through the same :class:`~adaptfilt.mdp.FilterEnv`
(so a stochastic rule draws the same random numbers for every policy): the
comparison is *paired* (common random numbers). The uncertainty of every
summary is a bootstrap over Monte-Carlo runs with **one** set of multinomial
resampling counts shared by all policies, so a difference between two
policies gets its own confidence interval
(:meth:`Results.paired_difference`), much narrower than the two separate
intervals suggest. :func:`evaluate_costs` does the same for several
experiments that differ only in their cost (the three SIF experiments of
Table I): each policy is rolled out once and charged every cost.

What is reported, per policy (``e = x_k - x_{k|k}``, ``l`` = run, ``k`` = step):

========================  ==================================================================
``rmse_t (T,)``           ``RMSE_k = sqrt(mean_l e^T e)``
``anees_t (T,)``          ``ANEES_k = mean_l e^T P^{-1} e`` (ideal ``nx``)
``nis_t (T,)``            mean NIS over runs at step ``k`` (ideal ``nz``)
``rmse``                  time average of ``RMSE_k`` (the paper's "time-averaged RMSE")
``anees`` / ``nis``       time averages of ``ANEES_k`` / mean NIS
``cost``                  mean one-step cost over runs and steps (Table I's "time avg. cost")
``cost_median`` ...       median, 99 % and 99.9 % quantiles and max of the one-step cost over
                          all ``M T`` (run, step) pairs: the NIS cost is extremely heavy-tailed
``rmse_run_median``       median over runs of the run's own RMS error ``sqrt(mean_k e^T e)``
``objective``             mean of ``log(1 + L)`` over runs and steps: what the trainers minimise
                          (their default ``cost_transform``), far less heavy-tailed than ``cost``
``cost_charged``          ``cost`` plus ``compute_weight`` times what the policy computed *to
                          decide* (the SIF innovation feature, the greedy/ML candidates), per
                          run: the paper's cost term charges only the chosen ``n_iter``, a
                          policy pays here for all it computes. The verdict metric of every
                          SIF comparison (equal to ``cost`` when ``compute_weight`` is 0)
``spent``                 compute per step in the rule's unit (``config["compute_unit"]``: SIF
                          iterations, UKF updates): the update that happened plus
                          ``extra_spent``, what the policy computed to decide
``anees_run_median``      median over runs of the run's time-averaged NEES
``divergent_frac``        fraction of runs that diverged: time-averaged NEES above ``1e4 nx``
                          (no consistent filter gets there) or a non-finite estimate
``cost_t (T,)``           mean one-step cost over runs at each step
``*_ci``                  95 % percentile bootstrap interval (runs resampled)
``usage (G,)``            how many (run, step) pairs used each grid value
``choices (T, G)``        fraction of runs using each grid value at each step
``n_repairs``             run-steps in which the filter that ran repaired a covariance
                          (``on_indefinite="clip"``); repairs made only to decide (features,
                          candidates not chosen) are not counted
``wall_time_s``           seconds spent on the policy (filtering + metrics)
========================  ==================================================================

Memory: a policy's full filtering covariances are reduced to per-run,
per-step squared errors and NEES right after its rollout and dropped; only
``(T,)``, ``(M,)`` and bootstrap ``(n_boot,)`` summaries are kept.

What ``adaptfilt evaluate`` runs (files, tables, figures) is
:func:`adaptfilt.experiments.evaluate.evaluate_experiment`, in the pipeline.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Iterable, Literal, Sequence

import numpy as np
from scipy import stats

from adaptfilt import metrics
from adaptfilt.mdp import FilterEnv, rollout
from adaptfilt.models import Trajectory
from adaptfilt.particle_env import ParticleCountEnv
from adaptfilt.results import RESULTS_FORMAT, PolicyResult, Results  # what evaluate returns (adaptfilt.results)

__all__ = ["PolicyResult", "Results", "evaluate", "learned_name", "learned_names",
           "RESULTS_FORMAT", "TRAJ_SEED_KEY"]

#: Trajectories of an evaluation with seed ``s`` come from ``default_rng([TRAJ_SEED_KEY, s])``, so
#: that they are not the trajectories a training run with the same seed simulates.
TRAJ_SEED_KEY = 0xE7A1
#: Quantiles of the one-step cost that are reported besides its mean.
COST_QUANTILES = (0.5, 0.99, 0.999)

#: A run has diverged when its time-averaged NEES exceeds this many times nx (:func:`metrics.divergent`).
DIVERGED_NEES = metrics.DIVERGED_NEES

def _summarise(name: str, x: np.ndarray, run, cost: np.ndarray | None, grid: np.ndarray,
               counts: np.ndarray, n_repairs: int, level: float, compute_weight: float = 0.0) -> dict:
    """Reduce one rollout to the :class:`PolicyResult` fields (wall time excluded)."""
    M, T = run.nis.shape
    se = metrics.squared_error(x, run.mean)  # (M, T)
    # a clipped filter stores the rare indefinite P_filt before repairing it: see metrics.nees
    # filters return positive definite P_filt (gaf.update_rl); a particle cloud collapsed onto one
    # point has none, and its run says so (info["on_indefinite"] = "inf": it counts as diverged)
    ne = metrics.nees(x, run.mean, run.cov, on_indefinite=(getattr(run, "info", None) or {}).get("on_indefinite", "raise"))
    a = (1.0 - level) / 2.0
    # RMSE: bootstrap the per-step mean squared error, then sqrt and time-average
    # (RMSE is not a mean over runs, so it is resampled through se, not per run).
    boot_mse_t = counts @ se / M  # (B, T)
    boot_rmse_t = np.sqrt(boot_mse_t)
    rmse_t = np.sqrt(se.mean(axis=0))
    run_anees = ne.mean(axis=1)
    anees_t = ne.mean(axis=0)
    # ANEES_k is a mean over runs: its pointwise band is the normal one from the
    # standard error (a second (B, M) x (M, T) bootstrap product would double the cost).
    half = stats.norm.ppf(1 - a) * ne.std(axis=0, ddof=1) / np.sqrt(M)
    out = dict(
        rmse_t=rmse_t, rmse_t_band=np.quantile(boot_rmse_t, [a, 1 - a], axis=0),
        anees_t=anees_t, anees_t_band=np.stack([anees_t - half, anees_t + half]),
        nis_t=run.nis.mean(axis=0),
        boot_rmse=boot_rmse_t.mean(axis=1), boot_anees=metrics.bootstrap_mean(run_anees, counts),
        run_rmse=np.sqrt(se.mean(axis=1)), run_anees=run_anees,
    )
    out["rmse"] = float(rmse_t.mean())
    out["anees"] = float(out["anees_t"].mean())
    out["nis"] = float(out["nis_t"].mean())
    out["rmse_ci"] = metrics.percentile_ci(out["boot_rmse"], level)
    out["anees_ci"] = metrics.percentile_ci(out["boot_anees"], level)
    out["rmse_run_median"] = float(np.median(out["run_rmse"]))
    out["anees_run_median"] = float(np.median(run_anees))
    nx = x.shape[-1]
    bad = metrics.divergent(ne, nx, run.mean)
    out["divergent_frac"] = float(bad.mean())
    info = getattr(run, "info", None) or {}
    extra = np.broadcast_to(np.asarray(info.get("extra_spent", 0.0), dtype=float), (M,))
    out["extra_spent"] = float(extra.mean())
    out["spent"] = float(np.mean(info["spent"])) if "spent" in info else float("nan")
    nan = float("nan")
    if cost is None:
        out.update(cost=nan, cost_ci=(nan, nan), cost_median=nan, cost_q99=nan, cost_q999=nan, cost_max=nan,
                   boot_cost=np.full(counts.shape[0], nan), run_cost=np.full(M, nan), objective=nan,
                   objective_ci=(nan, nan), boot_objective=np.full(counts.shape[0], nan), cost_charged=nan,
                   cost_charged_ci=(nan, nan), boot_cost_charged=np.full(counts.shape[0], nan),
                   cost_t=np.full(T, nan))
    else:
        run_cost = cost.mean(axis=1)
        q = np.quantile(cost, COST_QUANTILES)
        # per run, so that a charged difference between two policies is paired like any other
        run_charged = run_cost + compute_weight * extra
        out.update(cost=float(cost.mean()), run_cost=run_cost, boot_cost=metrics.bootstrap_mean(run_cost, counts),
                   cost_median=float(q[0]), cost_q99=float(q[1]), cost_q999=float(q[2]), cost_max=float(cost.max()),
                   cost_t=cost.mean(axis=0), cost_charged=float(cost.mean() + compute_weight * extra.mean()),
                   boot_cost_charged=metrics.bootstrap_mean(run_charged, counts))
        out["cost_ci"] = metrics.percentile_ci(out["boot_cost"], level)
        out["cost_charged_ci"] = metrics.percentile_ci(out["boot_cost_charged"], level)
        # What the trainers minimise: log(1 + L) (a non-finite cost counts as the largest float, as in training).
        obj = np.log1p(np.where(np.isfinite(cost), np.maximum(cost, 0.0), np.finfo(float).max))
        out["objective"] = float(obj.mean())
        out["boot_objective"] = metrics.bootstrap_mean(obj.mean(axis=1), counts)
        out["objective_ci"] = metrics.percentile_ci(out["boot_objective"], level)
    # Which grid value each (run, step) used: params hold grid values exactly.
    choices = np.stack([(run.params == g).mean(axis=0) for g in grid], axis=1)  # (T, G)
    out["choices"] = choices
    out["usage"] = np.stack([(run.params == g).sum() for g in grid]).astype(np.int64)
    out["n_repairs"] = int(n_repairs)
    return out


def _check_policy(policy, grid: np.ndarray) -> None:
    if not hasattr(policy, "act") or not hasattr(policy, "name"):
        raise TypeError(f"a policy needs .name and .act(decision); got {type(policy).__name__}")
    g = getattr(policy, "grid", None)
    if g is not None and getattr(policy, "acts_on_subset", False):
        from adaptfilt.policies import grid_indices

        grid_indices(np.asarray(g, dtype=float), grid, policy.name)  # ValueError unless g is a subset of grid
    elif g is not None and (np.shape(g) != grid.shape or not np.allclose(g, grid)):
        raise ValueError(f"policy {policy.name!r} was made for the grid {np.asarray(g).tolist()}, "
                         f"the environment's grid is {grid.tolist()}")


def evaluate(
    experiment_or_env,
    policies: Sequence | None = None,
    n_runs: int = 10_000,
    seed: int = 0,
    progress: bool | Literal["steps"] = True,
    n_boot: int = 1000,
    traj: Trajectory | None = None,
    level: float = 0.95,
    command: str | None = None,
    *,
    n_steps: int | None = None,
) -> Results:
    """Evaluate ``policies`` on the same ``n_runs`` simulated trajectories.

    Parameters
    ----------
    experiment_or_env : Experiment, str or FilterEnv
        A registered experiment (or its name), or an environment built by hand
        (its filter, grid, cost and horizon are used as they are).
    policies : sequence of policies, optional
        Objects with ``.name`` and ``.act(decision)``; default: the
        experiment's baselines (``Experiment.baselines()``).
    n_runs, seed : int
        Monte-Carlo runs; the seed fixes the trajectories
        (``default_rng([TRAJ_SEED_KEY, seed])``), a stochastic rule's random
        numbers (the filter's seed) and the bootstrap resamples.
    progress : bool or "steps"
        A tqdm bar over policies; ``"steps"`` adds a nested bar over time steps.
    n_boot : int
        Bootstrap resamples (shared by all policies: paired intervals).
    traj : Trajectory, optional
        Replay these trajectories instead of simulating.
    n_steps : int, optional
        A horizon other than the experiment's (``Experiment.make_env``); not
        with an environment, whose horizon is its own.

    Returns
    -------
    Results
    """
    env, policies, traj, counts, config = _setup(experiment_or_env, policies, n_runs, seed, n_boot, traj, level, command,
                                                 n_steps)
    return _evaluate([(env.cost, config)], env, policies, traj, counts, level, progress)[0]


def evaluate_costs(
    experiments: Sequence,
    policies: Sequence | None = None,
    n_runs: int = 10_000,
    seed: int = 0,
    progress: bool | Literal["steps"] = True,
    n_boot: int = 1000,
    level: float = 0.95,
    command: str | None = None,
    *,
    n_steps: int | None = None,
) -> dict[str, Results]:
    """:func:`evaluate` on several experiments that differ in their cost only, each policy rolled out once.

    The SIF experiments of Table I run the same filter on the same runs and
    charge different costs: a fixed ``n_iter`` filters identically in all
    three. Here each policy is rolled out in the first experiment's
    environment and every experiment's cost is charged on the same steps
    (:func:`adaptfilt.mdp.rollout`, ``extra_costs``); a policy that is the
    same constant as one before it (``default`` and ``fixed-n_iter=10``) is
    not rolled out again. The result for each experiment equals
    ``evaluate(experiment, policies, n_runs, seed)`` bit for bit (but for
    ``wall_time_s``) at a fraction of the filter work. ValueError when the
    experiments differ in anything but their cost (model, filter, grid,
    horizon), naming it, or when a policy may choose by the cost (greedy,
    or a learned policy with candidate-cost features): those differ
    between the experiments and are evaluated per experiment.

    Example
    -------
    >>> from adaptfilt.evaluation import evaluate_costs
    >>> from adaptfilt.experiments import get_experiment
    >>> exps = ["ctm-sif-stateinnov", "ctm-sif-nis"]
    >>> pols = [p for p in get_experiment(exps[0]).baselines() if p.name in ("default", "fixed-n_iter=3")]
    >>> res = evaluate_costs(exps, pols, n_runs=20, progress=False)  # doctest: +SKIP
    >>> sorted(res), res["ctm-sif-nis"]["default"].rmse == res["ctm-sif-stateinnov"]["default"].rmse  # doctest: +SKIP
    (['ctm-sif-nis', 'ctm-sif-stateinnov'], True)
    """
    if isinstance(experiments, str) or len(experiments) == 0:
        raise ValueError(f"give a non-empty sequence of experiments, got {experiments!r}")
    setups = [_setup(e, policies, n_runs, seed, n_boot, None, level, command, n_steps) for e in experiments]
    env, pols, traj, counts, first = setups[0]
    names = [c["experiment"] for *_, c in setups]
    if len(set(names)) < len(names):
        raise ValueError(f"experiments must be distinct, got {names}")
    shared = ("model", "nx", "nz", "n_steps", "filter", "param_name", "default", "grid", "n_runs", "seed", "policies")
    for e2, _, _, _, c in setups[1:]:
        for k in shared:
            if c[k] != first[k]:
                raise ValueError(f"experiments {first['experiment']!r} and {c['experiment']!r} differ in {k} "
                                 f"({first[k]!r} vs {c[k]!r}): only experiments that differ in their cost share rollouts")
        if e2.truth.name != env.truth.name:
            raise ValueError(f"experiments {first['experiment']!r} and {c['experiment']!r} simulate different truths")
    for p in pols:
        if not _cost_blind(p):
            raise ValueError(f"policy {p.name!r} may choose by the cost (greedy, candidate features, or a policy type "
                             "evaluate_costs does not know): evaluate it per experiment")
    out = _evaluate([(e.cost, c) for e, _, _, _, c in setups], env, pols, traj, counts, level, progress)
    return dict(zip(names, out))


def _cost_blind(pol) -> bool:
    """Whether ``pol``'s choices cannot depend on the environment's cost: constants, maximum likelihood,
    random choice, KLD-sampling and ESS targets, and learned policies whose information state has no
    candidate costs."""
    from adaptfilt.particle_env import ESSTargetPolicy, KLDSamplingPolicy
    from adaptfilt.policies import FixedPolicy, MaxLikelihoodPolicy, RandomPolicy

    if isinstance(pol, (FixedPolicy, MaxLikelihoodPolicy, RandomPolicy, KLDSamplingPolicy, ESSTargetPolicy)):
        return True
    fs = getattr(pol, "feature_set", None)
    return fs is not None and not fs.candidates


def _setup(experiment_or_env, policies, n_runs, seed, n_boot, traj, level, command, n_steps=None):
    """The environment, checked policies, trajectories, bootstrap counts and config of one evaluation."""
    from adaptfilt._version import __version__
    from adaptfilt.experiment_registry import Experiment, get_experiment

    exp = get_experiment(experiment_or_env) if isinstance(experiment_or_env, str) else experiment_or_env
    if isinstance(exp, Experiment):
        env = exp.make_env(seed=seed, n_steps=n_steps)
        if policies is None:
            policies = exp.baselines()
    elif isinstance(exp, (FilterEnv, ParticleCountEnv)):
        env, exp = exp, None
        if n_steps is not None and n_steps != env.n_steps:
            raise ValueError(f"n_steps={n_steps} for an environment with horizon {env.n_steps}: "
                             "build the environment with the horizon you want (FilterEnv(..., n_steps=...))")
        if policies is None:
            raise ValueError("give the policies to evaluate (an environment has no baselines; an Experiment has)")
    else:
        raise TypeError(f"expected an Experiment, an experiment name, a FilterEnv or a ParticleCountEnv, got {type(exp).__name__}")
    policies = list(policies)
    if not policies:
        raise ValueError("no policies to evaluate")
    names = [p.name for p in policies]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"policy names must be unique; repeated: {', '.join(dup)}")
    for p in policies:
        _check_policy(p, env.grid)
    given = traj is not None
    if not given:
        if int(n_runs) < 2:
            raise ValueError(f"n_runs must be at least 2 (bootstrap), got {n_runs}")
        traj = env.truth.simulate(int(n_runs), env.n_steps, rng=np.random.default_rng([TRAJ_SEED_KEY, int(seed)]))
    M = traj.n_runs
    counts = metrics.bootstrap_counts(M, n_boot, rng=np.random.default_rng([TRAJ_SEED_KEY, int(seed), 1]))
    filt = env.filt
    config = {
        "experiment": None if exp is None else exp.name,
        "description": "" if exp is None else exp.description,
        "model": env.model.name, "nx": env.nx, "nz": env.nz, "n_steps": env.n_steps,
        "filter": repr(filt), "param_name": filt.rule.param_name, "default": filt.param,
        "compute_unit": filt.rule.compute_unit,
        "grid": env.grid.tolist(), "cost": None if env.cost is None else env.cost.name,
        "n_runs": M, "seed": int(seed), "n_boot": int(n_boot), "level": float(level),
        "trajectories": "given" if given else f"default_rng([{TRAJ_SEED_KEY}, seed])",
        "policies": names, "version": __version__, "numpy": np.__version__, "command": command,
    }
    return env, policies, traj, counts, config


def _constant(pol) -> tuple | None:
    """What identifies a constant policy's episode (its value in each step), or None."""
    from adaptfilt.policies import FixedPolicy

    return (pol.value, pol.predict_param) if type(pol) is FixedPolicy else None


def _evaluate(targets: list[tuple], env: FilterEnv, policies: list, traj: Trajectory, counts: np.ndarray,
              level: float, progress) -> list[Results]:
    """Roll each policy out once in ``env`` and summarise it for every ``(cost, config)`` of ``targets``
    (the first cost is the environment's own)."""
    bar = policies
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(policies, desc=f"evaluate {targets[0][1]['experiment'] or targets[0][1]['model']}", unit="policy")
    results = [Results(config=config) for _, config in targets]
    extra = [c for c, _ in targets[1:]]
    done: dict[tuple, str] = {}
    for pol in bar:
        if progress:
            bar.set_postfix_str(pol.name)
        t0 = time.perf_counter()
        key = _constant(pol)
        if key is not None and key in done:  # the same episode again: copy its summaries under this name
            for res in results:
                twin = res.policies[done[key]]
                res.policies[pol.name] = PolicyResult(**{**twin.__dict__, "name": pol.name, "wall_time_s": 0.0})
            continue
        run, cost = rollout(env, pol, traj=traj, progress=progress == "steps", extra_costs=extra)
        costs = [cost] + run.info["extra_costs"]
        for res, (c, _), cost_k in zip(results, targets, costs):
            summ = _summarise(pol.name, traj.x[:, : env.n_steps], run, cost_k, env.grid, counts, run.n_repairs, level,
                              compute_weight=0.0 if c is None else c.compute_weight)
            res.policies[pol.name] = PolicyResult(name=pol.name, wall_time_s=time.perf_counter() - t0, **summ)
        del run, cost, costs  # the (M, T, nx, nx) covariances go here
        if key is not None:
            done[key] = pol.name
    return results


def learned_name(path: str | Path, experiment: str) -> str:
    """Result name of a learned policy file: its stem, without the experiment
    prefix when it has one (``data/policies/ungm-ukf-adaptive-faithful.npz`` ->
    ``adaptive-faithful``, ``runs/try3.npz`` -> ``try3``)."""
    stem = Path(path).stem
    return stem[len(experiment) + 1:] if stem.startswith(experiment + "-") and len(stem) > len(experiment) + 1 else stem


def learned_names(paths: Iterable[str | Path], experiment: str) -> list[str]:
    """:func:`learned_name` of each file, made unique: files that would share a
    name (the same stem in different folders) are named ``<folder>/<name>``
    with as many trailing folders of their resolved path as it takes to tell
    them apart (``a/x/adaptive.npz``, ``b/x/adaptive.npz`` -> ``a/x/adaptive``,
    ``b/x/adaptive``). The same file given twice is a ``ValueError``.

    >>> learned_names(["data/policies/ungm-ukf-adaptive.npz", "runs/ungm-ukf-adaptive.npz", "runs/b.npz"], "ungm-ukf")
    ['policies/adaptive', 'runs/adaptive', 'b']
    """
    paths = [Path(p) for p in paths]
    resolved = [p.resolve() for p in paths]
    for i, r in enumerate(resolved):
        if r in resolved[:i]:
            raise ValueError(f"policy file {paths[i]} is given twice")
    names = [learned_name(p, experiment) for p in paths]
    for n in sorted({n for n in names if names.count(n) > 1}):
        group = [i for i, m in enumerate(names) if m == n]
        depth = max(len(resolved[i].parent.parts) for i in group)
        for d in range(1, depth + 1):
            cand = {i: "/".join([*resolved[i].parent.parts[-d:], n]) for i in group}
            if len(set(cand.values())) == len(group):
                break
        else:  # same folder, stems that strip to the same name (ungm-ukf-a.npz, a.npz): the file names
            cand = {i: str(resolved[i].parent / resolved[i].name) for i in group}
        for i in group:
            names[i] = cand[i]
    return names
