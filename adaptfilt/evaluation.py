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

**Streaming** (``chunk_size``, default :data:`CHUNK_SIZE` = 10^4 runs). Up to
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
import functools
import numbers
import tempfile
import time
from pathlib import Path
from typing import Iterable, Literal, Sequence

import numpy as np

from adaptfilt import metrics
from adaptfilt.mdp import rollout
from adaptfilt.models import Trajectory
from adaptfilt.paramenv import ParamEnv
from adaptfilt.results import PolicyResult, Results

__all__ = ["evaluate", "evaluate_costs", "setup_evaluation", "summarise_rollout", "learned_name", "learned_names",
           "TRAJ_SEED_KEY"]

#: Trajectories of an evaluation with seed ``s`` come from ``default_rng([TRAJ_SEED_KEY, s])``, so
#: that they are not the trajectories a training run with the same seed simulates.
TRAJ_SEED_KEY = 0xE7A1
#: Quantiles of the one-step cost that are reported besides its mean.
COST_QUANTILES = (0.5, 0.99, 0.999)

#: Runs filtered at a time by default: an evaluation of at most this many runs (every result in ``data/``)
#: is the one-pass evaluation, byte for byte; one of more runs is streamed (module docstring, "Streaming").
CHUNK_SIZE = 10_000
#: Chunk ``c`` of a streamed evaluation keys a stochastic rule's random numbers with the stream
#: ``_CHUNK_STREAM + c`` (a training episode's stream is its index, far below).
_CHUNK_STREAM = 2**30


@functools.lru_cache(maxsize=1)
def _bootstrap_counts(M: int, n_boot: int, seed: int) -> np.ndarray:
    """The evaluation's bootstrap counts, ``metrics.bootstrap_counts(M, n_boot, default_rng([TRAJ_SEED_KEY,
    seed, 1]))``, read-only and kept for the next evaluation of the same runs in this process: a worker
    that evaluates one policy after another (``adaptfilt reproduce``'s jobs) draws them once instead of
    once a policy (0.6 s at 10^4 runs). Only for at most ``CHUNK_SIZE`` runs: at most 80 MB kept."""
    counts = metrics.bootstrap_counts(M, n_boot, rng=np.random.default_rng([TRAJ_SEED_KEY, seed, 1]))
    counts.flags.writeable = False
    return counts


def summarise_rollout(name: str, x: np.ndarray, run, cost: np.ndarray | None, grid: np.ndarray,
                      counts: np.ndarray, n_repairs: int, level: float, compute_weight: float = 0.0) -> dict:
    """Reduce one rollout to the :class:`~adaptfilt.results.PolicyResult` fields (wall time excluded): what
    :func:`evaluate` stores for a policy, for a filter run made outside an environment (a reference filter on
    the evaluation's runs, :func:`setup_evaluation`'s trajectories and bootstrap ``counts``)."""
    M, T = run.nis.shape
    se = metrics.squared_error(x, run.mean)  # (M, T)
    # a clipped filter stores the rare indefinite P_filt before repairing it: see metrics.nees
    # filters return positive definite P_filt (gaf.update_rl); a particle cloud collapsed onto one
    # point has none, and its run says so (info["on_indefinite"] = "inf": it counts as diverged)
    ne = metrics.nees(x, run.mean, run.cov, on_indefinite=(getattr(run, "info", None) or {}).get("on_indefinite", "raise"))
    a = (1.0 - level) / 2.0
    # RMSE: bootstrap the per-step mean squared error, then sqrt and time-average
    # (RMSE is not a mean over runs, so it is resampled through se, not per run).
    boot_mse_t = metrics.resampled_sums(counts, se) / M  # (B, T); a run with an infinite error: see there
    boot_rmse_t = np.sqrt(boot_mse_t)
    rmse_t = np.sqrt(se.mean(axis=0))
    run_anees = ne.mean(axis=1)
    anees_t = ne.mean(axis=0)
    # ANEES_k is a mean over runs: its pointwise band is the normal one from the
    # standard error (a second (B, M) x (M, T) bootstrap product would double the cost).
    from scipy import stats  # on first use: scipy.stats is most of the import time of the library

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
    chunk_size: int = CHUNK_SIZE,
) -> Results:
    """Evaluate ``policies`` on the same ``n_runs`` simulated trajectories.

    Parameters
    ----------
    experiment_or_env : Experiment, str or ParamEnv
        A registered experiment (or its name), or an environment built by hand
        (a :class:`~adaptfilt.mdp.FilterEnv` or any other :class:`~adaptfilt.paramenv.ParamEnv`: its
        filter, grid, cost and horizon are used as they are), read by
        :func:`~adaptfilt.experiment_registry.resolve`.
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
    chunk_size : int
        Runs filtered at a time (default :data:`CHUNK_SIZE`). Up to this many
        runs the evaluation is the one-pass evaluation, bit for bit; beyond, it
        streams the runs in chunks in bounded memory (see "Streaming" in the
        module docstring for what is the same and what is not).

    Returns
    -------
    Results
    """
    with _runs(experiment_or_env, policies, n_runs, seed, n_boot, traj, level, command, n_steps,
               chunk_size) as (env, policies, traj, counts, config):
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
    chunk_size: int = CHUNK_SIZE,
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
    between the experiments and are evaluated per experiment. ``chunk_size``
    as in :func:`evaluate`.

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
        setups = [stack.enter_context(_runs(experiments[0], policies, n_runs, seed, n_boot, None, level, command,
                                            n_steps, chunk_size))]
        setups += [setup_evaluation(e, policies, n_runs, seed, n_boot, None, level, command, n_steps, chunk_size, simulate=False)
                   for e in experiments[1:]]
        return _evaluate_costs(setups, level, progress)


def _evaluate_costs(setups: list, level: float, progress) -> dict[str, Results]:
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
        if not getattr(p, "cost_blind", False):
            raise ValueError(f"policy {p.name!r} may choose by the cost (greedy, candidate features, or a policy that "
                             "does not declare cost_blind = True): evaluate it per experiment")
    out = _evaluate([(e.cost, c) for e, _, _, _, c in setups], env, pols, traj, counts, level, progress)
    return dict(zip(names, out))


def setup_evaluation(experiment_or_env, policies: Sequence | None, n_runs: int, seed: int, n_boot: int,
                     traj: Trajectory | None, level: float, command: str | None, n_steps: int | None = None,
                     chunk_size: int | None = None, simulate: bool = True,
                     store_dir: Path | None = None) -> tuple[ParamEnv, list, "Trajectory | _RunStore | None",
                                                             np.ndarray | None, dict]:
    """The environment, checked policies, trajectories, bootstrap counts and config of one evaluation, as
    :func:`evaluate` makes them (for a study that adds rows of its own to an evaluation's results).

    ``chunk_size`` None or at least the number of runs: the trajectories and the counts ``(n_boot, M)``
    in memory, as always. More runs than ``chunk_size``: a :class:`_RunStore` in ``store_dir`` in place of
    the trajectories, and None for the counts (the store holds them). ``simulate=False``: neither (for an
    experiment whose runs are another's, :func:`evaluate_costs`)."""
    from adaptfilt._version import __version__
    from adaptfilt.experiment_registry import resolve

    target = resolve(experiment_or_env, seed=seed, n_steps=n_steps)
    env, exp = target.env, target.experiment
    if policies is None:
        if exp is None:
            raise ValueError("give the policies to evaluate (an environment has no baselines; an Experiment has)")
        policies = exp.baselines()
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
    if not given and int(n_runs) < 2:
        raise ValueError(f"n_runs must be at least 2 (bootstrap), got {n_runs}")
    M = traj.n_runs if given else int(n_runs)
    counts = None
    if not simulate:
        traj = None
    elif chunk_size is not None and M > chunk_size:
        traj = _RunStore(env, M, int(seed), int(n_boot), traj, int(chunk_size), store_dir)
    else:
        if not given:
            traj = env.truth.simulate(M, env.n_steps, rng=np.random.default_rng([TRAJ_SEED_KEY, int(seed)]))
        counts = (_bootstrap_counts(M, int(n_boot), int(seed)) if M <= CHUNK_SIZE else
                  metrics.bootstrap_counts(M, n_boot, rng=np.random.default_rng([TRAJ_SEED_KEY, int(seed), 1])))
    desc = env.describe()
    config = {
        "experiment": None if exp is None else exp.name,
        "description": "" if exp is None else exp.description,
        "model": desc["model"], "nx": env.nx, "nz": env.nz, "n_steps": env.n_steps,
        "filter": desc["filter"], "param_name": env.param_name, "default": env.default,
        "compute_unit": env.compute_unit,
        "grid": env.grid.tolist(), "cost": desc["cost"],
        "n_runs": M, "seed": int(seed), "n_boot": int(n_boot), "level": float(level),
        "trajectories": "given" if given else f"default_rng([{TRAJ_SEED_KEY}, seed])",
        "policies": names, "version": __version__, "numpy": np.__version__, "command": command,
    }
    if chunk_size is not None and M > chunk_size:
        # only streamed results say so: a one-pass evaluation's file is byte for byte what it always was
        config["chunk_size"] = int(chunk_size)
    return env, policies, traj, counts, config



@contextlib.contextmanager
def _runs(experiment_or_env, policies, n_runs, seed, n_boot, traj, level, command, n_steps, chunk_size):
    """:func:`setup_evaluation` with a checked ``chunk_size``, the streamed runs' folder removed at the end."""
    if isinstance(chunk_size, (bool, np.bool_)) or not isinstance(chunk_size, numbers.Integral) or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer (runs filtered at a time), got {chunk_size!r}")
    with tempfile.TemporaryDirectory(prefix="adaptfilt-evaluate-") as tmp:
        yield setup_evaluation(experiment_or_env, policies, n_runs, seed, n_boot, traj, level, command, n_steps,
                     int(chunk_size), store_dir=Path(tmp))


class _RunStore:
    """The runs of a streamed evaluation: trajectories and bootstrap counts on disk, read one chunk at a time.

    The trajectories are those of ``truth.simulate(M, T, rng=default_rng([TRAJ_SEED_KEY, seed]))``, drawn in
    the same order (step by step, all runs: :func:`_simulate_to_files`) and written time-major, so that each
    step is one sequential write; a chunk reads its rows back, step by step. The counts are those of
    :func:`metrics.bootstrap_counts` (``multinomial(M, 1/M)`` per resample, drawn one resample at a time:
    the same numbers), as bytes (a count above 255 among ``M`` draws of ``1/M`` has probability ~1e-500).
    Given trajectories stay where they are (in the caller's memory) and are sliced."""

    def __init__(self, env, n_runs: int, seed: int, n_boot: int, traj: Trajectory | None, chunk_size: int,
                 folder: Path):
        self.n_runs, self.n_boot, self.chunk_size, self.n_steps = n_runs, n_boot, chunk_size, env.n_steps
        self.traj, self.folder = traj, Path(folder)
        self.widths = (env.nx, env.nz)
        if traj is None:
            _simulate_to_files(env.truth, n_runs, env.n_steps, np.random.default_rng([TRAJ_SEED_KEY, seed]),
                               self.folder / "x.f8", self.folder / "z.f8")
        rng = np.random.default_rng([TRAJ_SEED_KEY, seed, 1])
        p = np.full(n_runs, 1.0 / n_runs)
        with open(self.folder / "counts.u1", "wb") as f:
            for _ in range(n_boot):
                row = rng.multinomial(n_runs, p)
                if row.max() > 255:
                    raise RuntimeError(f"a bootstrap count of {row.max()} does not fit the byte it is stored in")
                f.write(row.astype(np.uint8).tobytes())

    def chunks(self) -> list[tuple[int, int]]:
        """``(first, stop)`` run of each chunk."""
        return [(a, min(a + self.chunk_size, self.n_runs)) for a in range(0, self.n_runs, self.chunk_size)]

    def trajectory(self, a: int, b: int) -> Trajectory:
        """Runs ``a`` to ``b - 1``, exactly the rows of the one-pass trajectories."""
        if self.traj is not None:
            return Trajectory(x=self.traj.x[a:b], z=self.traj.z[a:b])
        return Trajectory(*(_read_rows(self.folder / n, self.n_steps, self.n_runs, w, a, b)
                            for n, w in zip(("x.f8", "z.f8"), self.widths)))

    def counts(self, a: int, b: int) -> np.ndarray:
        """Columns ``a`` to ``b - 1`` of the counts ``(n_boot, M)``, as floats (what the products take)."""
        out = np.empty((self.n_boot, b - a), dtype=np.uint8)
        with open(self.folder / "counts.u1", "rb") as f:
            for i in range(self.n_boot):
                f.seek(i * self.n_runs + a)
                out[i] = np.fromfile(f, dtype=np.uint8, count=b - a)
        return out.astype(float)


def _simulate_to_files(model, M: int, T: int, rng: np.random.Generator, x_path: Path, z_path: Path) -> None:
    """:meth:`StateSpaceModel.simulate` ``(M, T, rng)``, the same draws in the same order, written step by
    step (``(T, M, n)`` float64) instead of kept: memory ``O(M)``, not ``O(M T)``."""
    from adaptfilt.models import StateSpaceModel

    if type(model).simulate is not StateSpaceModel.simulate:  # a model that simulates otherwise: its own runs
        traj = model.simulate(M, T, rng=rng)
        for path, a in ((x_path, traj.x), (z_path, traj.z)):
            np.ascontiguousarray(np.swapaxes(a, 0, 1)).tofile(path)
        return
    # the lines of StateSpaceModel.simulate, one step at a time (tests check that the runs are the same)
    Lq, Lr, L0 = (np.linalg.cholesky(A) for A in (model.Q, model.R, model.P0))
    with open(x_path, "wb") as fx, open(z_path, "wb") as fz:
        x = model.m0 + rng.standard_normal((M, model.nx)) @ L0.T
        for t in range(T):
            if t:
                x = model.f(x, t) + rng.standard_normal((M, model.nx)) @ Lq.T
            z = model.h(x, t + 1) + rng.standard_normal((M, model.nz)) @ Lr.T
            fx.write(np.ascontiguousarray(x, dtype=float).tobytes())
            fz.write(np.ascontiguousarray(z, dtype=float).tobytes())


def _read_rows(path: Path, T: int, M: int, width: int, a: int, b: int) -> np.ndarray:
    """Runs ``a:b`` of a ``(T, M, width)`` float64 file, as a C-ordered ``(b - a, T, width)`` array."""
    out = np.empty((T, b - a, width))
    with open(path, "rb") as f:
        for t in range(T):
            f.seek((t * M + a) * width * 8)
            out[t] = np.fromfile(f, dtype=float, count=(b - a) * width).reshape(b - a, width)
    return np.ascontiguousarray(np.swapaxes(out, 0, 1))



def _constant(pol) -> tuple | None:
    """What identifies a constant policy's episode (its value in each step), or None."""
    from adaptfilt.policies import FixedPolicy

    return (pol.value, pol.predict_param) if type(pol) is FixedPolicy else None


def _evaluate(targets: list[tuple], env: ParamEnv, policies: list, traj, counts: np.ndarray | None,
              level: float, progress) -> list[Results]:
    """Roll each policy out once in ``env`` and summarise it for every ``(cost, config)`` of ``targets``
    (the first cost is the environment's own); ``traj`` a :class:`_RunStore` (``counts`` None): chunk by
    chunk."""
    bar = policies
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(policies, desc=f"evaluate {targets[0][1]['experiment'] or targets[0][1]['model']}", unit="policy")
    results = [Results(config=config) for _, config in targets]
    extra = [c for c, _ in targets[1:]]
    weights = [0.0 if c is None else c.compute_weight for c, _ in targets]
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
        if isinstance(traj, _RunStore):
            summs = _streamed(env, pol, traj, extra, weights, level, progress)
        else:
            run, cost = rollout(env, pol, traj=traj, progress=progress == "steps", extra_costs=extra)
            costs = [cost] + run.info["extra_costs"]
            summs = [summarise_rollout(pol.name, traj.x[:, : env.n_steps], run, cost_k, env.grid, counts, run.n_repairs,
                                level, compute_weight=w) for cost_k, w in zip(costs, weights)]
            del run, cost, costs  # the (M, T, nx, nx) covariances go here
        for res, summ in zip(results, summs):
            res.policies[pol.name] = PolicyResult(name=pol.name, wall_time_s=time.perf_counter() - t0, **summ)
        if key is not None:
            done[key] = pol.name
    return results


def _streamed(env, pol, store: _RunStore, extra: list, weights: list[float], level: float, progress) -> list[dict]:
    """:func:`summarise_rollout` of ``pol``'s rollout over all the store's runs, for each cost (the environment's,
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
    """The cost-free summaries of :func:`summarise_rollout`, summed over chunks of runs.

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
    """The cost summaries of :func:`summarise_rollout`, summed over chunks of runs (see :class:`_ChunkSums`); the
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
        if not self.used:  # no cost: what summarise_rollout reports then
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
