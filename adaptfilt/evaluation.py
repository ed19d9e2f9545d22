r"""Monte-Carlo evaluation of parameter policies and filters (Section VI-E of the paper).

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

Filters that no policy tunes, a reference (the bootstrap particle filter) or a learned filter
(KalmanNet), are evaluated on the same runs beside the policies and reduced by the same summary
(``evaluate(..., filters={name: filter})``, any :class:`~adaptfilt.filters.Filter`): their differences to
every policy are paired too, and a filter without a covariance has its ANEES reported as n/a (NaN) here,
once. The runs themselves, trajectories and bootstrap counts from the evaluation's seed, are an
:class:`~adaptfilt.runs.EvalRuns` (their seed is derived there and nowhere else).

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

**Streaming** (``chunk_size``, default :data:`~adaptfilt.runs.CHUNK_SIZE` = 10^4 runs; the runs on
disk: :class:`~adaptfilt.runs.RunStore`). Up to
``chunk_size`` runs, the evaluation is the one-pass evaluation: its files are
byte for byte those it always wrote (every result in ``data/`` has at most 10^4
runs). Beyond, memory is bounded in ``M``: each policy is rolled out one chunk
of runs at a time and only sums over runs, per-run values (``run_*``) and counts
are kept (about 60 KB per run of a chunk, 24 bytes per run and policy kept; UNGM:
~0.5 GB at any ``M``, plus the ``run_*`` arrays: ~0.7 GB for the 29 baselines
at 10^6). What goes to disk, in a temporary folder, instead of memory: the
trajectories (written as simulated, ``8 (nx + nz) M T`` bytes), the bootstrap
counts (one byte per count, ``n_boot M``) and one policy's one-step costs
(``8 M T`` per cost, for their exact quantiles). The decision on draws:

* the trajectories are the same runs as the one-pass evaluation's for every
  ``M`` (the same draws of :meth:`StateSpaceModel.simulate` in the same order,
  step by step for all runs, written to disk: one pass, ``O(M)`` memory), and so
  are the bootstrap counts (the same multinomial draws, one resample at a time);
* a deterministic rule (UKF, CKF, GH, ...) and deterministic policies therefore
  give every run exactly the one-pass values (a run's filter does not depend on
  the other runs of its batch): ``run_rmse``, ``run_anees``, ``run_cost``, their
  medians, ``usage``, ``choices``, ``n_repairs``, ``divergent_frac``,
  ``cost_max`` and the exact quantiles ``cost_median``/``q99``/``q999`` are
  byte-identical; means over runs (``rmse``, ``anees_t``, ``cost``, ...) and the
  bootstrap replicates are sums over chunks, equal up to the order of the
  additions (relative differences ~1e-15; the ANEES band, a streamed variance,
  ~1e-12);
* random numbers drawn per step for all runs of a batch cannot be split by runs
  without drawing all of them in every chunk: a stochastic rule (SIF) draws each
  chunk's from its own stream (``_CHUNK_STREAM + c``, the same for every
  policy, so the comparison stays paired), particle filters key their runs by
  that stream, and a :class:`~adaptfilt.policies.RandomPolicy` goes on with its
  generator. Their streamed results are other draws of the same evaluation, not
  the one-pass numbers. The config of a streamed result records ``chunk_size``.

What ``adaptfilt evaluate`` runs (files, tables, figures) is
:func:`adaptfilt.experiments.evaluate.evaluate_experiment`, in the pipeline.
"""
from __future__ import annotations

import contextlib
import numbers
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Mapping, Sequence

import numpy as np

from adaptfilt import metrics
from adaptfilt.filters import Filter, FilterRun, has_covariance, has_nis
from adaptfilt.mdp import rollout
from adaptfilt.models import Trajectory
from adaptfilt.paramenv import ParamEnv
from adaptfilt.results import PolicyResult, Results
from adaptfilt.runs import CHUNK_SIZE, EvalRuns, RunStore

__all__ = ["evaluate", "evaluate_costs"]

#: Quantiles of the one-step cost that are reported besides its mean.
COST_QUANTILES = (0.5, 0.99, 0.999)
#: Chunk ``c`` of a streamed evaluation keys a stochastic rule's random numbers with the stream
#: ``_CHUNK_STREAM + c`` (a training episode's stream is its index, far below).
_CHUNK_STREAM = 2**30


def _summarise(x: np.ndarray, run, cost: np.ndarray | None, grid: np.ndarray, counts: np.ndarray, level: float,
               compute_weight: float = 0.0) -> dict:
    """Reduce one rollout (a policy's) or one filter run on the evaluation's runs ``x`` to the
    :class:`~adaptfilt.results.PolicyResult` fields (wall time excluded), with the bootstrap ``counts``.
    A run without a covariance (:func:`~adaptfilt.filters.has_covariance`) has no NEES: its ANEES fields and
    its NEES-based ``divergent_frac`` are NaN (n/a); a run without a cost, its cost fields."""
    M, T = run.nis.shape
    B = counts.shape[0]
    nan = float("nan")
    se = metrics.squared_error(x, run.mean)  # (M, T)
    a = (1.0 - level) / 2.0
    # RMSE: bootstrap the per-step mean squared error, then sqrt and time-average
    # (RMSE is not a mean over runs, so it is resampled through se, not per run).
    boot_mse_t = metrics.resampled_sums(counts, se) / M  # (B, T); a run with an infinite error: see there
    boot_rmse_t = np.sqrt(boot_mse_t)
    rmse_t = np.sqrt(se.mean(axis=0))
    out = dict(rmse_t=rmse_t, rmse_t_band=np.quantile(boot_rmse_t, [a, 1 - a], axis=0), nis_t=run.nis.mean(axis=0),
               boot_rmse=boot_rmse_t.mean(axis=1), run_rmse=np.sqrt(se.mean(axis=1)))
    if has_covariance(run):
        # a clipped filter stores the rare indefinite P_filt before repairing it: see metrics.nees
        # filters return positive definite P_filt (gaf.update_rl); a particle cloud collapsed onto one
        # point has none, and its run says so (info["on_indefinite"] = "inf": it counts as diverged)
        ne = metrics.nees(x, run.mean, run.cov, on_indefinite=(getattr(run, "info", None) or {}).get("on_indefinite", "raise"))
        run_anees = ne.mean(axis=1)
        anees_t = ne.mean(axis=0)
        # ANEES_k is a mean over runs: its pointwise band is the normal one from the
        # standard error (a second (B, M) x (M, T) bootstrap product would double the cost).
        from scipy import stats  # on first use: scipy.stats is most of the import time of the library

        half = stats.norm.ppf(1 - a) * ne.std(axis=0, ddof=1) / np.sqrt(M)
        out.update(anees_t=anees_t, anees_t_band=np.stack([anees_t - half, anees_t + half]),
                   boot_anees=metrics.bootstrap_mean(run_anees, counts), run_anees=run_anees)
        out["anees"] = float(anees_t.mean())
        out["anees_ci"] = metrics.percentile_ci(out["boot_anees"], level)
        out["anees_run_median"] = float(np.median(run_anees))
        out["divergent_frac"] = float(metrics.divergent(ne, x.shape[-1], run.mean).mean())
    else:  # the declared "no covariance" (filters.py): n/a, never averaged
        out.update(anees_t=np.full(T, nan), anees_t_band=np.full((2, T), nan), boot_anees=np.full(B, nan),
                   run_anees=np.full(M, nan), anees=nan, anees_ci=(nan, nan), anees_run_median=nan,
                   divergent_frac=nan)
    out["rmse"] = float(rmse_t.mean())
    out["nis"] = float(out["nis_t"].mean())
    out["rmse_ci"] = metrics.percentile_ci(out["boot_rmse"], level)
    out["rmse_run_median"] = float(np.median(out["run_rmse"]))
    info = getattr(run, "info", None) or {}
    extra = np.broadcast_to(np.asarray(info.get("extra_spent", 0.0), dtype=float), (M,))
    out["extra_spent"] = float(extra.mean())
    out["spent"] = float(np.mean(info["spent"])) if "spent" in info else nan
    if cost is None:
        out.update(cost=nan, cost_ci=(nan, nan), cost_median=nan, cost_q99=nan, cost_q999=nan, cost_max=nan,
                   boot_cost=np.full(B, nan), run_cost=np.full(M, nan), objective=nan,
                   objective_ci=(nan, nan), boot_objective=np.full(B, nan), cost_charged=nan,
                   cost_charged_ci=(nan, nan), boot_cost_charged=np.full(B, nan), cost_t=np.full(T, nan))
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
    out["n_repairs"] = int(run.n_repairs)
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


def _check_filter(name: str, filt, env) -> None:
    if not isinstance(filt, Filter):
        raise TypeError(f"filter {name!r}: a filter needs .model and .run(z) -> FilterRun (adaptfilt.filters.Filter); "
                        f"got {type(filt).__name__}")
    for dim in ("nx", "nz"):
        if getattr(filt.model, dim, None) != getattr(env, dim):
            raise ValueError(f"filter {name!r} filters a model with {dim} = {getattr(filt.model, dim, None)}, the "
                             f"evaluation's has {getattr(env, dim)}")


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
    chunk_size: int = CHUNK_SIZE,
    filters: Mapping[str, Filter] | None = None,
    runs: EvalRuns | None = None,
    on_filter_error: Literal["raise", "skip"] = "raise",
) -> Results:
    """Evaluate ``policies`` and ``filters`` on the same ``n_runs`` simulated trajectories.

    Parameters
    ----------
    experiment_or_env : Experiment, str or ParamEnv
        A registered experiment (or its name), or an environment built by hand
        (a :class:`~adaptfilt.mdp.FilterEnv` or any other :class:`~adaptfilt.paramenv.ParamEnv`: its
        filter, grid, cost and horizon are used as they are), read by
        :func:`~adaptfilt.experiment_registry.resolve`.
    policies : sequence of policies, optional
        Objects with ``.name`` and ``.act(decision)``; default: the
        experiment's baselines (``Experiment.baselines()``); ``[]``: filters only.
    n_runs, seed : int
        Monte-Carlo runs; the seed fixes the trajectories
        (:func:`adaptfilt.runs.trajectory_rng`), a stochastic rule's random
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
    chunk_size : int
        Runs filtered at a time (default :data:`~adaptfilt.runs.CHUNK_SIZE`). Up to this many
        runs the evaluation is the one-pass evaluation, bit for bit; beyond, it
        streams the runs in chunks in bounded memory (see "Streaming" in the
        module docstring for what is the same and what is not).
    filters : {name: Filter}, optional
        Filters that no policy tunes (:class:`adaptfilt.filters.Filter`: a reference such as the
        bootstrap particle filter, a learned filter such as KalmanNet), each run once on the same
        trajectories and reduced by the same summary as the policies (paired with them; one pass
        only, not streamed). A non-finite estimate counts as an infinite error from that step on (the
        run is kept, diverged); a covariance that is not positive definite as an infinite NEES. Without a
        covariance (:func:`~adaptfilt.filters.has_covariance`) the ANEES fields are NaN (n/a). The
        parameter a filter declares (``param_name``) counts as the environment's choices and compute
        when it is the environment's parameter. The environment's cost is charged where the filter
        gives what it reads: the NIS-type costs on the filter's NIS, ``sqerr`` on its estimate (plus the
        compute weight times its parameter); otherwise the cost fields are NaN.
        ``results.config["filters"]`` records each filter's ``repr``.
    runs : EvalRuns, optional
        The evaluation's runs, made by the caller (to use them again: a Bayes floor on the first runs,
        :func:`adaptfilt.exact.bayes_floor`); then ``n_runs``, ``seed``, ``n_boot`` and ``traj`` are theirs.
    on_filter_error : "raise" or "skip"
        What a filter's ``ValueError`` or ``FloatingPointError`` (numerical trouble it names, e.g. a
        particle filter whose particles explain no measurement) does: raise, or leave the filter out,
        its message in ``results.config["failed_filters"][name]``.

    Returns
    -------
    Results
    """
    with _setup(experiment_or_env, policies, filters, n_runs, seed, n_boot, traj, level, command, n_steps,
                chunk_size, runs) as s:
        return _evaluate([(s.env.cost, s.config)], s, level, progress, on_filter_error)[0]


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
    chunk_size: int = CHUNK_SIZE,
    filters: Mapping[str, Filter] | None = None,
    on_filter_error: Literal["raise", "skip"] = "raise",
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
    between the experiments and are evaluated per experiment. ``chunk_size``,
    ``filters`` (run once, charged every cost) and ``on_filter_error`` as in :func:`evaluate`.

    Example
    -------
    >>> from adaptfilt.evaluation import evaluate_costs
    >>> from adaptfilt.experiment_registry import get_experiment
    >>> exps = ["ctm-sif-stateinnov", "ctm-sif-nis"]
    >>> pols = [p for p in get_experiment(exps[0]).baselines() if p.name in ("default", "fixed-n_iter=3")]
    >>> res = evaluate_costs(exps, pols, n_runs=20, progress=False)  # doctest: +SKIP
    >>> sorted(res), res["ctm-sif-nis"]["default"].rmse == res["ctm-sif-stateinnov"]["default"].rmse  # doctest: +SKIP
    (['ctm-sif-nis', 'ctm-sif-stateinnov'], True)
    """
    if isinstance(experiments, str) or len(experiments) == 0:
        raise ValueError(f"give a non-empty sequence of experiments, got {experiments!r}")
    with contextlib.ExitStack() as stack:
        # the first experiment's runs are simulated (and, streamed, written to disk); the others' are the same
        # runs by construction (same truth, seed and horizon: checked below), so only their configs are needed
        setups = [stack.enter_context(_setup(e, policies, filters, n_runs, seed, n_boot, None, level, command, n_steps,
                                             chunk_size, None, simulate=not k)) for k, e in enumerate(experiments)]
        return _evaluate_costs(setups, level, progress, on_filter_error)


def _evaluate_costs(setups: list, level: float, progress, on_filter_error: str) -> dict[str, Results]:
    first, env = setups[0].config, setups[0].env
    names = [s.config["experiment"] for s in setups]
    if len(set(names)) < len(names):
        raise ValueError(f"experiments must be distinct, got {names}")
    shared = ("model", "nx", "nz", "n_steps", "filter", "param_name", "default", "grid", "n_runs", "seed", "policies")
    for s in setups[1:]:
        c = s.config
        for k in shared:
            if c[k] != first[k]:
                raise ValueError(f"experiments {first['experiment']!r} and {c['experiment']!r} differ in {k} "
                                 f"({first[k]!r} vs {c[k]!r}): only experiments that differ in their cost share rollouts")
        if s.env.truth.name != env.truth.name:
            raise ValueError(f"experiments {first['experiment']!r} and {c['experiment']!r} simulate different truths")
    for p in setups[0].policies:
        if not getattr(p, "cost_blind", False):
            raise ValueError(f"policy {p.name!r} may choose by the cost (greedy, candidate features, or a policy that "
                             "does not declare cost_blind = True): evaluate it per experiment")
    out = _evaluate([(s.env.cost, s.config) for s in setups], setups[0], level, progress, on_filter_error)
    return dict(zip(names, out))


@dataclass
class _Setup:
    """What one evaluation runs: the environment, checked policies and filters, the runs (of another
    experiment that differs in its cost only: the same, never drawn, :func:`evaluate_costs`) and the results'
    config."""

    env: ParamEnv
    policies: list
    filters: dict
    runs: EvalRuns
    config: dict


@contextlib.contextmanager
def _setup(experiment_or_env, policies, filters, n_runs, seed, n_boot, traj, level, command, n_steps, chunk_size,
           runs: EvalRuns | None, simulate: bool = True):
    """The :class:`_Setup` of one evaluation, as :func:`evaluate` makes it; a streamed evaluation's runs are
    stored in a temporary folder, removed at the end."""
    from adaptfilt._version import __version__
    from adaptfilt.experiment_registry import resolve

    if isinstance(chunk_size, (bool, np.bool_)) or not isinstance(chunk_size, numbers.Integral) or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer (runs filtered at a time), got {chunk_size!r}")
    target = resolve(experiment_or_env, seed=seed if runs is None else runs.seed, n_steps=n_steps)
    env, exp = target.env, target.experiment
    if policies is None:
        if exp is None:
            raise ValueError("give the policies to evaluate (an environment has no baselines; an Experiment has)")
        policies = exp.baselines()
    policies, filters = list(policies), dict(filters or {})
    if not policies and not filters:
        raise ValueError("nothing to evaluate: give policies or filters")
    names = [p.name for p in policies] + list(filters)
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"policy names must be unique; repeated: {', '.join(dup)}")  # a filter's name too
    for p in policies:
        _check_policy(p, env.grid)
    for name, f in filters.items():
        _check_filter(name, f, env)
    with tempfile.TemporaryDirectory(prefix="adaptfilt-evaluate-") as tmp:
        if runs is not None:
            _check_runs(runs, env, traj)
        else:  # simulate=False: another experiment's runs (nothing is drawn unless used)
            runs = EvalRuns(env.truth, n_runs, seed, env.n_steps, n_boot=n_boot, traj=traj,
                            chunk_size=int(chunk_size) if simulate else None, folder=tmp)
        if filters and runs.streamed:
            raise ValueError(f"filters are evaluated in one pass: give at most chunk_size = {chunk_size} runs "
                             f"(got {runs.n_runs})")
        M = runs.n_runs
        desc = env.describe()
        config = {
            "experiment": None if exp is None else exp.name,
            "description": "" if exp is None else exp.description,
            "model": desc["model"], "nx": env.nx, "nz": env.nz, "n_steps": env.n_steps,
            "filter": desc["filter"], "param_name": env.param_name, "default": env.default,
            "compute_unit": env.compute_unit,
            "grid": env.grid.tolist(), "cost": desc["cost"],
            "n_runs": M, "seed": runs.seed, "n_boot": runs.n_boot, "level": float(level),
            "trajectories": runs.trajectories,
            "policies": names, "version": __version__, "numpy": np.__version__, "command": command,
        }
        if filters:  # only then: an evaluation of policies alone writes the file it always wrote
            config["filters"] = {name: repr(f) for name, f in filters.items()}
        if M > chunk_size:
            # only streamed results say so: a one-pass evaluation's file is byte for byte what it always was
            config["chunk_size"] = int(chunk_size)
        yield _Setup(env, policies, filters, runs, config)


def _check_runs(runs: EvalRuns, env, traj) -> None:
    if traj is not None:
        raise ValueError("give the runs or the trajectories, not both")
    if runs.n_steps < env.n_steps or (runs.truth.nx, runs.truth.nz) != (env.nx, env.nz) or \
            getattr(runs.truth, "name", None) != getattr(env.truth, "name", None):
        raise ValueError(f"the runs {runs!r} are not the evaluation's: it simulates {env.truth.name!r} for "
                         f"{env.n_steps} steps")


def _constant(pol) -> tuple | None:
    """What identifies a constant policy's episode (its value in each step), or None."""
    from adaptfilt.policies import FixedPolicy

    return (pol.value, pol.predict_param) if type(pol) is FixedPolicy else None


def _evaluate(targets: list[tuple], s: _Setup, level: float, progress, on_filter_error: str = "raise") -> list[Results]:
    """Roll each policy out once in ``s.env`` and run each filter once on the runs, and summarise each for
    every ``(cost, config)`` of ``targets`` (the first cost is the environment's own); streamed runs chunk by
    chunk."""
    if on_filter_error not in ("raise", "skip"):
        raise ValueError(f"on_filter_error must be 'raise' or 'skip', got {on_filter_error!r}")
    env, runs = s.env, s.runs
    items = [(p.name, p) for p in s.policies] + list(s.filters.items())
    bar = items
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(items, desc=f"evaluate {targets[0][1]['experiment'] or targets[0][1]['model']}", unit="policy")
    results = [Results(config=config) for _, config in targets]
    costs = [c for c, _ in targets]
    weights = [0.0 if c is None else c.compute_weight for c in costs]
    done: dict[tuple, str] = {}
    for name, item in bar:
        if progress:
            bar.set_postfix_str(name)
        t0 = time.perf_counter()
        if name in s.filters:
            summs = _filter_summaries(name, item, env, runs, costs, weights, level, on_filter_error, results)
            if summs is None:
                continue
        else:
            key = _constant(item)
            if key is not None and key in done:  # the same episode again: copy its summaries under this name
                for res in results:
                    twin = res.policies[done[key]]
                    res.policies[name] = PolicyResult(**{**twin.__dict__, "name": name, "wall_time_s": 0.0})
                continue
            summs = _policy_summaries(item, env, runs, costs[1:], weights, level, progress)
            if key is not None:
                done[key] = name
        for res, summ in zip(results, summs):
            res.policies[name] = PolicyResult(name=name, wall_time_s=time.perf_counter() - t0, **summ)
    return results


def _policy_summaries(pol, env, runs: EvalRuns, extra: list, weights: list[float], level: float,
                      progress) -> list[dict]:
    """:func:`_summarise` of ``pol``'s rollout for each cost (the environment's, then ``extra``)."""
    if runs.streamed:
        return _streamed(env, pol, runs.store, extra, weights, level, progress)
    traj = runs.traj
    run, cost = rollout(env, pol, traj=traj, progress=progress == "steps", extra_costs=extra)
    out = [_summarise(traj.x[:, : env.n_steps], run, cost_k, env.grid, runs.counts, level, compute_weight=w)
           for cost_k, w in zip([cost] + run.info["extra_costs"], weights)]
    del run, cost  # the (M, T, nx, nx) covariances go here
    return out


def _filter_summaries(name: str, filt, env, runs: EvalRuns, costs: list, weights: list[float], level: float,
                      on_filter_error: str, results: list[Results]) -> list[dict] | None:
    """:func:`_summarise` of filter ``filt``'s run on the evaluation's runs for each cost; None (and its
    message in every result's ``config["failed_filters"]``) when it fails and ``on_filter_error`` is "skip"."""
    traj = runs.traj
    x = traj.x[:, : env.n_steps]
    try:
        run = _filter_run(filt, env, traj)
    except (ValueError, FloatingPointError) as err:
        if on_filter_error != "skip":
            raise
        for res in results:
            res.config.setdefault("failed_filters", {})[name] = str(err)
            res.config["policies"].remove(name)
            del res.config["filters"][name]
        return None
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged run's infinite error, kept as such
        return [_summarise(x, run, _filter_cost(c, env, run, x), env.grid, runs.counts, level, compute_weight=w)
                for c, w in zip(costs, weights)]


def _filter_run(filt, env, traj: Trajectory) -> FilterRun:
    """``filt.run`` on the runs, in the evaluation's terms: a non-finite estimate is an infinite error from that
    step on (the recursion has no way back: the run is kept, diverged), a non-finite covariance an infinite
    one, a covariance that is not positive definite an infinite NEES (``on_indefinite="inf"``); the
    parameter the filter declares is the environment's choice and compute only when it is the
    environment's parameter (else none, NaN)."""
    T = env.n_steps
    with np.errstate(over="ignore", invalid="ignore"):
        r = filt.run(traj.z[:, :T])
    M = r.mean.shape[0]
    mean = np.where(np.isfinite(r.mean).all(axis=-1, keepdims=True), r.mean, np.inf)
    bad = np.maximum.accumulate(~np.isfinite(mean).all(axis=-1), axis=1)
    mean = np.where(bad[..., None], np.inf, mean)
    cov = np.where(np.isfinite(r.cov), r.cov, np.inf) if has_covariance(r) else r.cov
    info: dict = {"on_indefinite": "inf"}
    if getattr(filt, "param_name", None) == env.param_name:
        params, spent = r.params, np.zeros(M)
        for t in range(T):  # as a rollout counts a policy's compute
            spent += env.spent(params[:, t])
        info["spent"] = spent / T
    else:
        params = np.full((M, T), np.nan)
    return FilterRun(mean=mean, cov=cov, nis=r.nis, loglik=r.loglik, params=params, n_repairs=r.n_repairs, info=info)


def _filter_cost(cost, env, run: FilterRun, x: np.ndarray) -> np.ndarray | None:
    """The environment's one-step cost ``(M, T)`` of a filter's run, where the filter gives what the cost reads:
    the NIS-type costs (``kind`` "nis", "logmaxnis") its NIS, ``"sqerr"`` its estimate against the truth ``x``
    (an infinite error where the estimate is not finite), plus the compute weight times the parameter it
    declares when that is the environment's. None (n/a) otherwise: ``stateinnov``, a cost of one's own,
    a filter without a NIS, a priced parameter the filter does not have."""
    from types import SimpleNamespace

    from adaptfilt.costs import NIS_COSTS

    kind = getattr(cost, "kind", None)
    if not ((kind in NIS_COSTS and has_nis(run)) or kind == "sqerr"):
        return None
    own = "spent" in run.info
    if cost.compute_weight and not own:
        return None
    M, T, nx = run.mean.shape
    ok = np.isfinite(run.mean).all(axis=-1).reshape(M * T)
    est = np.where(ok[:, None], run.mean.reshape(M * T, nx), x.reshape(M * T, nx))  # a diverged step: see below
    err = est - x.reshape(M * T, nx)
    # both families' layouts of an update (costs.py): the GAF's run-last x_filt and truth, the particle filter's err
    u = SimpleNamespace(nis=run.nis.reshape(M * T), err=err, dx=np.full_like(err, np.nan), x_filt=est.T)
    kw = {"truth": np.ascontiguousarray(x.reshape(M * T, nx).T)} if getattr(cost, "needs_truth", False) else {}
    theta = run.params.reshape(M * T) if own else np.zeros(M * T)
    c = np.asarray(cost(u, theta, env.nz, **kw), dtype=float)
    return np.where(ok, c, np.inf).reshape(M, T) if kind == "sqerr" else c.reshape(M, T)


def _streamed(env, pol, store: RunStore, extra: list, weights: list[float], level: float, progress) -> list[dict]:
    """:func:`_summarise` of ``pol``'s rollout over all the store's runs, for each cost (the environment's,
    then ``extra``), one chunk of runs at a time: per run and per step only sums (and the per-run values
    the results keep) stay, and each cost's one-step values go to a file for their quantiles."""
    M, T, B, G = store.n_runs, env.n_steps, store.n_boot, env.grid.size
    acc = _ChunkSums(M, T, B, G)
    per_cost = [_CostSums(M, T, B, w, store.folder / f"cost{k}.f8") for k, w in enumerate(weights)]
    on_indefinite = (getattr(env, "run_info", None) or {}).get("on_indefinite", "raise")
    for c, (a, b) in enumerate(store.chunks()):
        traj = store.trajectory(a, b)
        # each chunk its own random numbers for a stochastic rule (the same for every policy: paired)
        run, cost = rollout(env, pol, traj=traj, stream=_CHUNK_STREAM + c, progress=progress == "steps",
                            extra_costs=extra)
        cnt = store.counts(a, b)
        acc.add(a, traj.x[:, :T], run, env.grid, cnt, on_indefinite)
        extra_spent = np.broadcast_to(np.asarray(run.info.get("extra_spent", 0.0), dtype=float), (b - a,))
        for cs, cost_k in zip(per_cost, [cost] + run.info["extra_costs"]):
            if cost_k is not None:
                cs.add(a, cost_k, extra_spent, cnt)
        del run, cost, traj, cnt
    base = acc.finish(level, env.nx)
    return [{**base, **cs.finish(level, acc.extra_sum / M)} for cs in per_cost]

class _ChunkSums:
    """The cost-free summaries of :func:`_summarise`, summed over chunks of runs.

    Per run (the values a one-pass evaluation computes, bit for bit where the rollout's are), integer
    counts (usage, choices, repairs, divergent runs: exact) and maxima are exact; what is a mean over runs
    (``rmse_t``, ``anees_t``, ``nis_t``, the bootstrap replicates) is summed chunk by chunk, the same
    numbers up to the order of the additions (relative differences ~1e-15)."""

    def __init__(self, M: int, T: int, B: int, G: int):
        self.M = M
        self.se_t, self.ne_t, self.nis_t = np.zeros(T), np.zeros(T), np.zeros(T)
        self.n, self.ne_mean, self.ne_m2 = 0, np.zeros(T), np.zeros(T)  # Chan et al.'s pairwise variance
        self.boot_se_t, self.boot_ne = np.zeros((B, T)), np.zeros(B)
        self.run_rmse, self.run_anees = np.empty(M), np.empty(M)
        self.chosen = np.zeros((T, G), dtype=np.int64)
        self.n_bad, self.n_repairs, self.extra_sum, self.spent_sum, self.has_spent = 0, 0, 0.0, 0.0, True

    def add(self, a: int, x: np.ndarray, run, grid: np.ndarray, cnt: np.ndarray, on_indefinite: str) -> None:
        C = x.shape[0]
        se = metrics.squared_error(x, run.mean)
        ne = metrics.nees(x, run.mean, run.cov, on_indefinite=on_indefinite)
        self.run_rmse[a:a + C] = np.sqrt(se.mean(axis=1))
        self.run_anees[a:a + C] = ne.mean(axis=1)
        self.se_t += se.sum(axis=0)
        self.ne_t += ne.sum(axis=0)
        self.nis_t += run.nis.sum(axis=0)
        self.boot_se_t += cnt @ se
        self.boot_ne += cnt @ self.run_anees[a:a + C]
        with np.errstate(invalid="ignore"):  # an infinite NEES (a collapsed particle cloud): NaN, as np.std
            m = ne.mean(axis=0)
            m2 = ((ne - m) ** 2).sum(axis=0)
            n = self.n + C
            d = m - self.ne_mean
            self.ne_mean = self.ne_mean + d * (C / n)
            self.ne_m2 = self.ne_m2 + m2 + d * d * (self.n * C / n)
        self.n = n
        self.n_bad += int(np.count_nonzero(metrics.divergent(ne, x.shape[-1], run.mean)))
        self.n_repairs += int(run.n_repairs)
        info = getattr(run, "info", None) or {}
        self.extra_sum += float(np.broadcast_to(np.asarray(info.get("extra_spent", 0.0), dtype=float), (C,)).sum())
        if "spent" in info:
            self.spent_sum += float(np.sum(info["spent"]))
        else:
            self.has_spent = False
        for g, v in enumerate(grid):
            self.chosen[:, g] += np.count_nonzero(run.params == v, axis=0)

    def finish(self, level: float, nx: int) -> dict:
        M, a = self.M, (1.0 - level) / 2.0
        boot_rmse_t = np.sqrt(self.boot_se_t / M)
        rmse_t, anees_t = np.sqrt(self.se_t / M), self.ne_t / M
        from scipy import stats

        half = stats.norm.ppf(1 - a) * np.sqrt(self.ne_m2 / (M - 1)) / np.sqrt(M)
        out = dict(
            rmse_t=rmse_t, rmse_t_band=np.quantile(boot_rmse_t, [a, 1 - a], axis=0),
            anees_t=anees_t, anees_t_band=np.stack([anees_t - half, anees_t + half]),
            nis_t=self.nis_t / M, boot_rmse=boot_rmse_t.mean(axis=1), boot_anees=self.boot_ne / M,
            run_rmse=self.run_rmse, run_anees=self.run_anees,
        )
        out["rmse"] = float(rmse_t.mean())
        out["anees"] = float(anees_t.mean())
        out["nis"] = float(out["nis_t"].mean())
        out["rmse_ci"] = metrics.percentile_ci(out["boot_rmse"], level)
        out["anees_ci"] = metrics.percentile_ci(out["boot_anees"], level)
        out["rmse_run_median"] = float(np.median(self.run_rmse))
        out["anees_run_median"] = float(np.median(self.run_anees))
        out["divergent_frac"] = self.n_bad / M
        out["extra_spent"] = self.extra_sum / M
        out["spent"] = self.spent_sum / M if self.has_spent else float("nan")
        out["choices"] = self.chosen / M  # a mean of booleans is their count over M: the same number
        out["usage"] = self.chosen.sum(axis=0).astype(np.int64)
        out["n_repairs"] = self.n_repairs
        return out


class _CostSums:
    """The cost summaries of :func:`_summarise`, summed over chunks of runs (see :class:`_ChunkSums`); the
    one-step costs themselves go to ``path`` for their exact quantiles (:func:`_file_quantiles`)."""

    def __init__(self, M: int, T: int, B: int, weight: float, path: Path):
        self.M, self.T, self.weight, self.path, self.used = M, T, weight, path, False
        self.total, self.obj_total, self.max, self.cost_t = 0.0, 0.0, -np.inf, np.zeros(T)
        self.run_cost = np.empty(M)
        self.boot_cost, self.boot_obj, self.boot_charged = np.zeros(B), np.zeros(B), np.zeros(B)
        path.unlink(missing_ok=True)

    def add(self, a: int, cost: np.ndarray, extra: np.ndarray, cnt: np.ndarray) -> None:
        self.used = True
        C = cost.shape[0]
        run_cost = self.run_cost[a:a + C] = cost.mean(axis=1)
        self.total += float(cost.sum())
        self.cost_t += cost.sum(axis=0)
        self.max = float(np.maximum(self.max, cost.max()))  # NaN stays NaN, as in cost.max()
        obj = np.log1p(np.where(np.isfinite(cost), np.maximum(cost, 0.0), np.finfo(float).max))
        self.obj_total += float(obj.sum())
        self.boot_cost += cnt @ run_cost
        self.boot_obj += cnt @ obj.mean(axis=1)
        # per run, so that a charged difference between two policies is paired like any other
        self.boot_charged += cnt @ (run_cost + self.weight * extra)
        with open(self.path, "ab") as f:
            f.write(np.ascontiguousarray(cost, dtype=float).tobytes())

    def finish(self, level: float, extra_mean: float) -> dict:
        M, T, B = self.M, self.T, self.boot_cost.size
        nan = float("nan")
        if not self.used:  # no cost: what _summarise reports then
            return dict(cost=nan, cost_ci=(nan, nan), cost_median=nan, cost_q99=nan, cost_q999=nan, cost_max=nan,
                        boot_cost=np.full(B, nan), run_cost=np.full(M, nan), objective=nan, objective_ci=(nan, nan),
                        boot_objective=np.full(B, nan), cost_charged=nan, cost_charged_ci=(nan, nan),
                        boot_cost_charged=np.full(B, nan), cost_t=np.full(T, nan))
        q = _file_quantiles(self.path, M * T, COST_QUANTILES)
        self.path.unlink()
        out = dict(cost=self.total / (M * T), run_cost=self.run_cost, boot_cost=self.boot_cost / M,
                   cost_median=q[0], cost_q99=q[1], cost_q999=q[2], cost_max=self.max, cost_t=self.cost_t / M,
                   boot_cost_charged=self.boot_charged / M, objective=self.obj_total / (M * T),
                   boot_objective=self.boot_obj / M)
        out["cost_charged"] = out["cost"] + self.weight * extra_mean
        out["cost_ci"] = metrics.percentile_ci(out["boot_cost"], level)
        out["cost_charged_ci"] = metrics.percentile_ci(out["boot_cost_charged"], level)
        out["objective_ci"] = metrics.percentile_ci(out["boot_objective"], level)
        return out


def _float_keys(v: np.ndarray) -> np.ndarray:
    """Unsigned integers in the order of the floats ``v`` (no NaN; -0.0 as 0.0, which compare equal)."""
    bits = (v + 0.0).view(np.uint64)
    neg = (bits >> np.uint64(63)).astype(bool)
    return np.where(neg, ~bits, bits | np.uint64(1 << 63))


def _file_quantiles(path: Path, N: int, qs: Sequence[float], block: int = 1 << 20) -> list[float]:
    """``np.quantile(values, qs)`` (the linear method) of the ``N`` float64 values in ``path``, exactly, in
    memory ``O(block)``: each order statistic it needs is found digit by digit (16 bits of the float's
    order-preserving key per pass over the file), and interpolated as numpy does."""
    q = np.asarray(qs, dtype=float)
    vi = (N - 1) * q  # numpy's virtual indexes, previous and next order statistic, and weight
    prev = np.floor(vi).astype(np.intp)
    nxt = prev + 1
    above = vi >= N - 1
    prev[above], nxt[above] = N - 1, N - 1
    gamma = vi - prev
    ranks = sorted({int(r) for r in np.concatenate([prev, nxt])})

    def blocks():
        with open(path, "rb") as f:
            while True:
                v = np.fromfile(f, dtype=float, count=block)
                if v.size == 0:
                    return
                yield v

    if any(np.isnan(v).any() for v in blocks()):
        return [float("nan")] * len(q)  # as np.quantile: a NaN among the values makes every quantile NaN
    # per rank: the known leading bits of its key (prefix over `shift` remaining bits) and the count below
    state = {r: (0, 64, 0) for r in ranks}
    while any(shift for _, shift, _ in state.values()):
        groups = sorted({(p, s) for p, s, _ in state.values() if s})
        hists = {g: np.zeros(1 << 16, dtype=np.int64) for g in groups}
        for v in blocks():
            k = _float_keys(v)
            for p, s in groups:
                sel = k if s == 64 else k[(k >> np.uint64(s)) == np.uint64(p)]
                hists[(p, s)] += np.bincount(((sel >> np.uint64(s - 16)) & np.uint64(0xFFFF)).astype(np.intp),
                                             minlength=1 << 16)
        for r, (p, s, below) in state.items():
            if s:
                cum = np.cumsum(hists[(p, s)])
                d = int(np.searchsorted(cum, r - below, side="right"))
                state[r] = ((p << 16) | d, s - 16, below + (int(cum[d - 1]) if d else 0))
    value = {}
    for r, (key, _, _) in state.items():
        key = np.uint64(key)
        bits = ~key if not key >> np.uint64(63) else key & ~np.uint64(1 << 63)
        value[r] = float(np.array([bits], dtype=np.uint64).view(float)[0])
    lo, hi = np.array([value[int(r)] for r in prev]), np.array([value[int(r)] for r in nxt])
    diff = hi - lo  # numpy's _lerp, step for step
    out = lo + diff * gamma
    np.subtract(hi, diff * (1 - gamma), out=out, where=gamma >= 0.5)
    return [float(x) for x in out]
