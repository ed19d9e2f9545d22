r"""Results over training seeds: a learned policy is one draw of a random process.

A policy trained with seed ``s`` and evaluated on ``M`` Monte-Carlo runs has a
metric value ``v_s`` (time-averaged RMSE, ANEES, cost ...) that is uncertain
twice: the training seed (another seed, another policy) and the runs (another
set of trajectories, another estimate). A claim about a *learning method*
must hold over seeds. Following Agarwal et al. (2021, "Deep RL at the edge of
the statistical precipice", the ``rliable`` library), we report per-seed
values and two aggregates over the ``n`` seeds,

* the **interquartile mean** ``IQM`` (the mean of the middle 50 %: with 8
  seeds, of the middle 4; robust to one diverged seed, less noisy than the
  median), and
* the **mean**,

each with a percentile interval from a **two-level (stratified) bootstrap**:
replicate ``b`` resamples the seeds with replacement and takes each drawn
seed's value on run-resample ``b``, the run-level bootstrap replicate that
:func:`adaptfilt.evaluation.evaluate` stores for every policy (``boot_*``:
the same multinomial run counts for every policy of one evaluation). The
interval therefore covers both sources of variation; with a single seed it
reduces to the run-level interval, and without run noise to ``rliable``'s
stratified bootstrap over seeds (a test checks both).

A **difference** between two groups of seeds (e.g. the fast trainer's 8
policies minus the faithful trainer's 8) resamples the two groups'
seeds independently (they are different trainings) and uses the *same*
run-resample for both (they were evaluated on the same runs: paired), so
that run-to-run noise common to both cancels.

Seed groups are found by name: policies named ``<group>-s<seed>`` (e.g.
``adaptive-s3``) form group ``adaptive`` (:func:`seed_groups`). What such an
interval says about a claim ("lower", "not worse", "equal", with a declared
margin) is the one rule of :mod:`adaptfilt.verdicts`.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from adaptfilt.metrics import percentile_ci

__all__ = ["iqm", "seed_groups", "SeedAggregate", "aggregate", "difference", "collapse_seeds", "METRICS"]

#: Metrics with run-level bootstrap replicates in an evaluation (``PolicyResult.boot_<metric>``).
METRICS = ("rmse", "anees", "cost", "objective", "cost_charged")
_SEED = re.compile(r"^(?P<group>.+)-s(?P<seed>\d+)$")


def iqm(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the 25 %-trimmed mean (``scipy.stats.trim_mean(x, 0.25)``), as ``rliable``."""
    from scipy import stats  # on first use: scipy.stats is most of the import time of the library

    return stats.trim_mean(np.asarray(x, dtype=float), 0.25, axis=axis)


def seed_groups(names) -> dict[str, list[str]]:
    """``{"adaptive": ["adaptive-s0", "adaptive-s1", ...], ...}`` for names ending in ``-s<seed>``,
    each group sorted by seed; names without a seed suffix are left out."""
    groups: dict[str, list[tuple[int, str]]] = {}
    for n in names:
        m = _SEED.match(n)
        if m:
            groups.setdefault(m["group"], []).append((int(m["seed"]), n))
    return {g: [n for _, n in sorted(v)] for g, v in groups.items()}


@dataclass
class SeedAggregate:
    """One metric of one group of seeds: per-seed values, IQM and mean with their intervals.

    ``boot_iqm``/``boot_mean`` ``(B,)`` are the two-level bootstrap replicates."""

    metric: str
    names: list[str]
    values: np.ndarray
    iqm: float
    iqm_ci: tuple[float, float]
    mean: float
    mean_ci: tuple[float, float]
    boot_iqm: np.ndarray = field(repr=False)
    boot_mean: np.ndarray = field(repr=False)

    @property
    def n_seeds(self) -> int:
        return len(self.names)

    def to_dict(self) -> dict:
        return {"metric": self.metric, "names": list(self.names), "values": self.values.tolist(),
                "iqm": self.iqm, "iqm_ci": list(self.iqm_ci), "mean": self.mean, "mean_ci": list(self.mean_ci),
                "n_seeds": self.n_seeds}


def _boot(results, names, metric) -> tuple[np.ndarray, np.ndarray]:
    """Point values ``(n,)`` and run-level replicates ``(n, B)`` of ``metric`` for ``names``."""
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    if not names:
        raise ValueError("no policies to aggregate")
    vals = np.array([getattr(results[n], metric) for n in names], dtype=float)
    boot = np.stack([np.asarray(getattr(results[n], "boot_" + metric), dtype=float) for n in names])
    return vals, boot


def _resample_seeds(boot: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``(B, n)``: replicate b draws n seeds with replacement, each at run-resample b."""
    n, B = boot.shape
    idx = rng.integers(0, n, size=(B, n))
    return boot[idx, np.arange(B)[:, None]]


def _ci(x: np.ndarray, level: float) -> tuple[float, float]:
    """The percentile interval of replicates (infinite ones included: :func:`adaptfilt.metrics.percentile_ci`)."""
    return percentile_ci(x, level)


def aggregate(results, names, metric: str = "rmse", level: float = 0.95, seed: int = 0) -> SeedAggregate:
    """IQM and mean of ``metric`` over the policies ``names`` (one per training seed) of one
    :class:`~adaptfilt.evaluation.Results`, with two-level bootstrap intervals (module docstring).

    >>> agg = aggregate(res, seed_groups(res.names)["adaptive"], "anees")   # doctest: +SKIP
    >>> agg.iqm, agg.iqm_ci                                                   # doctest: +SKIP
    """
    names = list(names)
    vals, boot = _boot(results, names, metric)
    rs = _resample_seeds(boot, np.random.default_rng([0xA66, seed]))
    bi, bm = iqm(rs, axis=1), rs.mean(axis=1)
    return SeedAggregate(metric, names, vals, float(iqm(vals)), _ci(bi, level), float(vals.mean()), _ci(bm, level), bi, bm)


def difference(results, names_a, names_b, metric: str = "rmse", level: float = 0.95, seed: int = 0,
               paired: bool = False) -> dict:
    """``aggregate(a) - aggregate(b)`` for two seed groups evaluated on the same runs:
    ``{"iqm": (diff, lo, hi), "mean": (diff, lo, hi), ...}``. Runs are resampled jointly (paired);
    seeds independently per group, or, with ``paired`` (``names_a[i]`` and ``names_b[i]`` come from the
    same training seed, e.g. two snapshots of one training), jointly too: the same seeds drawn for both."""
    va, ba = _boot(results, list(names_a), metric)
    vb, bb = _boot(results, list(names_b), metric)
    if ba.shape[1] != bb.shape[1]:
        raise ValueError("the two groups have different numbers of run-level bootstrap replicates")
    rng = np.random.default_rng([0xD1F, seed])
    if paired:
        if ba.shape[0] != bb.shape[0]:
            raise ValueError(f"paired seed groups need one policy per seed on both sides, got {ba.shape[0]} "
                             f"and {bb.shape[0]}")
        idx = rng.integers(0, ba.shape[0], size=(ba.shape[1], ba.shape[0]))
        cols = np.arange(ba.shape[1])[:, None]
        ra, rb = ba[idx, cols], bb[idx, cols]
    else:
        ra, rb = _resample_seeds(ba, rng), _resample_seeds(bb, rng)
    with np.errstate(invalid="ignore"):  # inf - inf: both sides diverged in a replicate, undefined (see _ci)
        d_iqm, d_mean = iqm(ra, axis=1) - iqm(rb, axis=1), ra.mean(axis=1) - rb.mean(axis=1)
        point_iqm, point_mean = float(iqm(va) - iqm(vb)), float(va.mean() - vb.mean())
    return {"metric": metric, "a": list(names_a), "b": list(names_b),
            "iqm": (point_iqm, *_ci(d_iqm, level)), "mean": (point_mean, *_ci(d_mean, level))}


def collapse_seeds(results, level: float = 0.95):
    """A :class:`~adaptfilt.evaluation.Results` in which every seed group is one policy: its IQM
    over seeds with the two-level interval (``rmse``, ``anees``, ``cost``, ``objective``; the
    replicates as ``boot_*``), per-step curves and choices averaged over seeds, usage summed, and
    ``seed_points = {metric: per-seed values}`` for figures that show each seed beside the aggregate."""
    import copy

    from adaptfilt.results import Results

    groups = seed_groups(results.names)
    out = Results(config=dict(results.config))
    done = set()
    for n in results.names:
        g = next((k for k, v in groups.items() if n in v), None)
        if g is None:
            out.policies[n] = results[n]
            continue
        if g in done:
            continue
        done.add(g)
        names = groups[g]
        p = copy.copy(results[names[0]])
        p.name = g
        p.seed_points = {}
        for m in METRICS:
            if m in ("objective", "cost_charged") and not all(len(getattr(results[x], "boot_" + m, ())) for x in names):
                continue  # evaluations stored before the metric existed
            agg = aggregate(results, names, m, level)
            setattr(p, m, agg.iqm)
            setattr(p, m + "_ci", agg.iqm_ci)
            setattr(p, "boot_" + m, agg.boot_iqm)
            p.seed_points[m] = agg.values
        for k in ("rmse_t", "anees_t", "nis_t", "choices", "cost_t"):
            arrs = [np.asarray(getattr(results[x], k)) for x in names]
            if all(a.size for a in arrs):
                setattr(p, k, np.mean(arrs, axis=0))
        p.usage = sum(results[x].usage for x in names)
        p.rmse_run_median = float(np.median([results[x].rmse_run_median for x in names]))
        out.policies[g] = p
    return out
