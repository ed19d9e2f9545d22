r"""Study 8, ``gain``: learn the parameter or learn the gain?

A 2 x 2 design on UNGM (``ungm-ukf``, T = 500) and the bearing-only CTM (``ctm-ukf``, T = 150) that
separates *what is learned* from *what it is trained on*:

==============  ===========================================  ==========================================
arm (group)     what is learned                              what it is trained on
==============  ===========================================  ==========================================
``kappa-nis``   the UKF's kappa per step (the reproduction's  the paper's NIS cost ``(NIS - nz)^2``
                fast mode, gamma 0.5: ``ungm-ukf``/``ctm-ukf``) (measurements only)
``kappa-sqerr`` the same learner                             ``||x_{t|t} - x_t||^2`` (``*-ukf-sqerr``)
``gain-unsup``  KalmanNet's gain (:mod:`adaptfilt.kalmannet`)  ``|z_t - h(x_{t|t-1})|^2`` (measurements)
``gain-sup``    KalmanNet's gain                             ``|x_{t|t} - x_t|^2`` (the paper's)
==============  ===========================================  ==========================================

**Budgets matched in CPU seconds, fixed in work units.** A budget is a number of episodes (kappa) or
epochs (KalmanNet), so that the same seed gives the same policy on any machine of the same kind; the
numbers were calibrated once on this 2-core machine (under ``nice -n 19``, other work running) to the
targets :data:`TARGET_CPU_S` = 5, 15 and 45 CPU-s per policy (:data:`CALIBRATION` records the
measurements that set them), and every policy's *measured* training CPU-s is reported beside its
budget. KalmanNet trains once per seed and arm and is snapshotted at the three epoch counts (one
``adaptfilt train-gain ... --snapshots`` each, :func:`knet_spec`, writing a file per budget: a snapshot is
bit for bit the filter of a training that stopped there); the kappa learner
(:func:`adaptfilt.trainers.train_policy` has no snapshots) trains separately at each budget, as the
other studies' ``adaptfilt train`` jobs. Both kinds are trainings of :func:`policies`, run, journaled,
reused and recorded by the one loop of ``adaptfilt beyond``.

**KalmanNet's recipe** (:data:`KNET`, fixed before any evaluation): 100 training and 50 validation
trajectories of the full horizon simulated per seed (``data_seed`` = the seed: both gain arms of a seed
see the same trajectories; the kappa learner simulates its own episodes from its seed), minibatches of
20 trajectories, truncated back-propagation through time over windows of 100 steps (the estimate and the GRU
states carried over, detached; chosen on UNGM, seed 0, 500 test runs of seed 999, before the study: with whole
500-step sequences the unsupervised loss never improved on the untrained network in 10 epochs, best epoch 0,
RMSE 5.965, where windows of 100 reached 5.35 at epoch 3; supervised 5.31 and 5.28; the default UKF 7.58), Adam 1e-3, weight decay 1e-4, gradient
norm clipped at 10, the best validation model kept, a non-finite loss restoring the best weights at half
the learning rate (recorded in the file's history); after 5 such restores the training stops with the best
weights so far (``on_diverged="stop"``: a diverged training is a result to report, not a job to lose; the
study counts such trainings per arm and budget, ``stopped_trainings``). Inputs scaled by fixed scales from a pilot
simulation (``feature_norm="scale"``), not the public code's per-sample L2 norm, which leaves only the
sign of UNGM's and the bearing's one-dimensional features. Plain KalmanNet: it gives **no covariance**,
so its ANEES and its NEES-based divergence are *n/a* (``None`` in the summary, NaN in the stored
evaluation, never averaged), and so is the NIS-type cost (no innovation covariance). The Bayesian
variant (dropout copies, a covariance) costs ``J`` times as much per step and is not an arm here.

**Evaluation.** On the same runs (seed 0) every arm's policies beside the default, every update-only
constant kappa (the best one in hindsight by RMSE is the bar), greedy and ML (on the NIS cost, the
reproduction's), the bootstrap particle filter (:class:`~adaptfilt.exact.BootstrapParticleFilter`,
:data:`PF_PARTICLES`) and, on UNGM, the point-mass filter on the first :attr:`GainScale.floor_runs`
runs with the truth's own model (the Bayes floor; under the mismatch the filter that knows ``Q x 4``).
KalmanNet and the particle filter are filters (:class:`~adaptfilt.filters.Filter`) evaluated beside the
policies by the same :func:`~adaptfilt.evaluation.evaluate` (``filters=``), on the same runs and bootstrap
resamples, so their differences to every other policy are paired. Two regimes (:data:`REGIMES`): the
nominal model and a truth with ``Q x 4`` (:func:`adaptfilt.experiments.ood.mismatched_env`: trained on the
nominal model, the filters keep it).
The final budget is evaluated on :attr:`GainScale.eval_runs` runs (10^4), the budget curve (all three
budgets, default and constants) on :attr:`GainScale.curve_runs` runs (2000: a cheaper, separate set).

**Metrics**: RMSE (the verdicts' metric), MSE in dB (``10 log10`` of the mean squared error over runs
and steps, KalmanNet's unit; per seed, IQM over seeds without an interval), ANEES and the NIS cost where
defined, divergent runs by the error rule (a non-finite estimate, counted as an infinite error, never
dropped, or a run RMSE above :data:`DIVERGED_RMSE`) for every arm and by the library's NEES rule where a
covariance exists, training CPU-s, microseconds per run-step (the evaluation's wall time over its
``M T`` run-steps, one thread). Verdicts (:func:`verdict_rows`) at the seed level by the one rule of
:mod:`adaptfilt.verdicts`, "not worse" with the margin declared for :data:`DECLARED`, for the pairs of
:data:`PAIRS`, at every budget, model and regime.

**Size of the full run.** Estimated before it from one training per arm and budget (seed 0, :data:`SIZE`:
about 250 CPU-s of training per seed and model, ~4,000 CPU-s in all); the CTM's kappa budgets were then set
from the measured fixed cost and slope, (300, 2500, 10300) episodes. The run itself (``adaptfilt beyond --out
data --studies gain``, 2026-11-27, 2 cores shared with other work): KalmanNet 32 trainings in 17 min, the 96
kappa trainings in 21 min, the 20 evaluation jobs (with the anchored learner's 4) in about 21 min; each
policy's training CPU-s is in ``data/beyond/manifest.json`` (last budget: kappa 38-54, KalmanNet 37-49 as
means over seeds; the CTM kappa's first budget took 1.6 CPU-s, not the 5 targeted).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from adaptfilt.experiments.jobs import EvalSpec, GainSpec, Training, TrainSpec, job_key
from adaptfilt.experiments.report import md_table
from adaptfilt.experiments.study import COMPACT, Run, diff_ci

NAME = "gain"

#: The models: the nominal experiment (the kappa-nis arm's, and the evaluation's: its NIS cost, grid, greedy
#: and ML) and its squared-error twin (the kappa-sqerr arm's training experiment).
MODELS = {"ungm-ukf": "ungm-ukf-sqerr", "ctm-ukf": "ctm-ukf-sqerr"}
#: The arms, in the order the tables list them: (group, what is learned, what it is trained on).
ARMS = (("kappa-nis", "kappa", "NIS cost"), ("kappa-sqerr", "kappa", "squared error"),
        ("gain-unsup", "gain", "predicted-measurement error"), ("gain-sup", "gain", "squared error"))
ARM_NAMES = tuple(a for a, _, _ in ARMS)
#: KalmanNet's loss per gain arm.
LOSS = {"gain-unsup": "unsupervised", "gain-sup": "supervised"}
#: The regimes: truth noise scale factors (q, r); the filters keep the nominal model.
REGIMES = {"nominal": (1.0, 1.0), "q4": (4.0, 1.0)}
#: Target training CPU-s of the three budgets (per policy).
TARGET_CPU_S = (5.0, 15.0, 45.0)
#: KalmanNet's training recipe (module docstring); ``n_steps`` is the model's horizon (the scale's at quick).
KNET = dict(n_train=100, n_val=50, batch_size=20, lr=1e-3, weight_decay=1e-4, clip=10.0, feature_norm="scale",
            on_diverged="stop", tbptt=100, model_grad="finite-difference")
#: Particles of the bootstrap particle filter reference (the reproduction's references: bpf-500 on UNGM,
#: bpf-1000 on the CTM).
PF_PARTICLES = {"ungm-ukf": 500, "ctm-ukf": 1000}
#: Error rule of a diverged run, for every arm (plain KalmanNet has no NEES): a run RMSE above this, about
#: the size of UNGM's state itself (|x| < 30) and 25 times the CTM particle filter's RMSE, or a
#: non-finite estimate.
DIVERGED_RMSE = {"ungm-ukf": 30.0, "ctm-ukf": 1000.0}
#: Keys the reference filter's random stream (apart from the trajectories').
_PF_KEY = 38

#: The measurements that set the budgets (2026-12, this machine, 2 cores, ``nice -n 19`` beside other timed
#: work; process CPU-s of one training, one torch thread): the kappa learner (``--algo fast``, seed 0) and
#: KalmanNet (:data:`KNET`, seed 0, per epoch incl. validation; the snapshot's CPU-s at each epoch).
CALIBRATION = {
    "kappa ungm-ukf": {"100 episodes": 1.68, "400 episodes": 5.14},
    "kappa ungm-ukf-sqerr": {"100 episodes": 1.68, "400 episodes": 4.70},
    "kappa ctm-ukf": {"100 episodes": 0.48, "400 episodes": 1.55},
    "kappa ctm-ukf-sqerr": {"100 episodes": 0.48, "400 episodes": 1.56},
    # KNET but 200 training trajectories: per-epoch CPU-s (snapshot CPU-s at epochs 1, 2, 3, ...); the
    # study's 100 halve the training part (validation, 50 trajectories, stays)
    "kalmannet ungm-ukf supervised, n_train=200": {"snapshot CPU-s": [8.36, 17.97, 27.2]},
    "kalmannet ungm-ukf unsupervised, n_train=200": {"snapshot CPU-s": [8.94, 19.84, 30.32]},
    "kalmannet ctm-ukf supervised, n_train=200": {"snapshot CPU-s": [2.95, 5.98, 9.5, 13.03, 16.53, 19.94]},
    # the CTM's kappa learner at the first calibration's budgets, full scale: a fixed ~5.3 CPU-s (scaler fit,
    # set-up) plus ~3.9 ms per episode, so its first budget cannot go below ~6 CPU-s; (300, 2500, 10300)
    # episodes aim at about 6.5, 15 and 45
    "kappa ctm-ukf, full scale": {"1350 episodes": 10.47, "4150 episodes": 21.27},
    # KNET with windows of 100 steps (tbptt=100), UNGM, seed 0: snapshot CPU-s at epochs 1, 3, 10
    "kalmannet ungm-ukf supervised, tbptt=100": {"snapshot CPU-s": [7.5, 19.3, 53.8]},
    "kalmannet ungm-ukf unsupervised, tbptt=100": {"snapshot CPU-s": [6.6, 15.7, 50.8]},
}
#: The full run's measured sizes: one training per arm and budget at full scale, seed 0 (process CPU-s;
#: KalmanNet's per snapshot of its one training). The CTM's rest and the evaluation parts: not measured yet.
SIZE: dict = {
    "ungm-ukf": {"kappa-nis": (6.11, 16.03, 50.45), "kappa-sqerr": (5.5, 13.84, 45.81),
                 "gain-unsup": (6.24, 17.21, 54.54), "gain-sup": (5.01, 17.10, 60.10)},
    "ctm-ukf": {"kappa-nis": (10.47, 21.27, None)},
}


@dataclass(frozen=True)
class GainScale:
    """The study's budgets: seeds, horizon (None: the model's), runs of the final evaluation and of the
    budget curve, runs of the point-mass floor, and per model the three budgets in work units: kappa
    episodes and KalmanNet epochs; ``knet`` overrides :data:`KNET`'s sizes (the quick scale's)."""

    name: str
    seeds: tuple[int, ...]
    n_steps: int | None
    eval_runs: int
    curve_runs: int
    floor_runs: int
    kappa_episodes: dict
    knet_epochs: dict
    knet: dict
    pf_particles: dict

    def words(self) -> str:
        return (f"gain-scale={self.name} seeds={len(self.seeds)} steps={self.n_steps} runs={self.eval_runs} "
                f"curve={self.curve_runs} floor={self.floor_runs} kappa={self.kappa_episodes} "
                f"knet={self.knet_epochs} {self.knet} pf={self.pf_particles}")


#: The full scale: budgets from :data:`CALIBRATION` for :data:`TARGET_CPU_S`.
FULL = GainScale("full", tuple(range(8)), None, 10_000, 2000, 200,
                 {"ungm-ukf": (400, 1250, 4000), "ctm-ukf": (300, 2500, 10300)},
                 {"ungm-ukf": (1, 3, 10), "ctm-ukf": (3, 8, 25)}, {}, PF_PARTICLES)
#: The quick scale of the test suite: 2 seeds, 20 steps, 100 runs, toy budgets (one PPO rollout each).
QUICK = GainScale("quick", (0, 1), 20, 100, 100, 5, {"ungm-ukf": (2, 4, 6), "ctm-ukf": (2, 4, 6)},
                  {"ungm-ukf": (1, 2, 3), "ctm-ukf": (1, 2, 3)}, {"n_train": 8, "n_val": 4, "batch_size": 4},
                  {"ungm-ukf": 50, "ctm-ukf": 50})


def scale_of(run: Run) -> GainScale:
    return QUICK if run.quick else FULL


def budgets(scale: GainScale) -> range:
    return range(1, 1 + len(TARGET_CPU_S))


# ------------------------------------------------------------------ files and names
def policy_name(arm: str, budget: int, seed: int) -> str:
    """``<arm>-b<budget>-s<seed>``: group ``<arm>-b<budget>`` for :func:`adaptfilt.seed_stats.seed_groups`."""
    return f"{arm}-b{budget}-s{seed}"


def policy_rel(experiment: str, arm: str, budget: int, seed: int) -> str:
    """Where a policy of the study lives in ``DIR/beyond``."""
    return f"policies/{experiment}-{policy_name(arm, budget, seed)}.npz"


def knet_options(scale: GainScale) -> dict:
    return {**KNET, **scale.knet}


def knet_spec(experiment: str, arm: str, seed: int, scale: GainScale, root: Path) -> GainSpec:
    """KalmanNet's training for ``arm`` (:data:`LOSS`) on ``experiment``'s model, seed ``seed``: once to the
    top budget's epochs, snapshotted at each budget's into ``root / policy_rel(...)`` (``adaptfilt train-gain``)."""
    k = knet_options(scale)
    epochs = tuple(scale.knet_epochs[experiment])
    return GainSpec(experiment, LOSS[arm], epochs[-1], seed,
                    tuple(str(root / policy_rel(experiment, arm, b, seed)) for b in budgets(scale)), snapshots=epochs,
                    horizon=scale.n_steps, train_runs=k["n_train"], val_runs=k["n_val"], batch_size=k["batch_size"],
                    lr=k["lr"], weight_decay=k["weight_decay"], clip=k["clip"], tbptt=k["tbptt"],
                    feature_norm=k["feature_norm"], on_diverged=k["on_diverged"], model_grad=k["model_grad"])


def prepare(run: Run) -> dict:
    return {}


# ------------------------------------------------------------------ trainings
def policies(run: Run, summary: dict) -> list[Training]:
    """The kappa learner (fast mode, gamma 0.5) on the NIS cost and on the squared error, one training per
    budget (episodes) and seed; KalmanNet once per model, gain arm and seed, snapshotted at the budgets."""
    sc = scale_of(run)
    out: list[Training] = []
    for e, sq in MODELS.items():
        for arm, exp in (("kappa-nis", e), ("kappa-sqerr", sq)):
            for b, episodes in zip(budgets(sc), sc.kappa_episodes[e]):
                for s in sc.seeds:
                    rel = policy_rel(e, arm, b, s)
                    out.append(TrainSpec(exp, 0.5, episodes, s, str(run.out / rel), horizon=sc.n_steps))
    out += [knet_spec(e, arm, s, sc, run.out) for e in MODELS for arm in LOSS for s in sc.seeds]
    return out


# ------------------------------------------------------------------ evaluation
#: The parts of one (model, regime) evaluation, each its own job: the final budget's UKF policies and
#: baselines, KalmanNet's, the references (particle filter, floor), and the budget curve.
PARTS = ("ukf", "gain", "reference", "curve", "anchored")
#: The anchored learner of study 5 (``adaptive-anchored``: candidate-aware state, a residual over greedy), a
#: reference evaluated on the study's runs where ``DIR/beyond`` holds its policies.
ANCHORED = "adaptive-anchored"


def _env(experiment: str, regime: str, scale: GainScale, seed: int = 0):
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.experiments.ood import Condition, mismatched_env

    if regime not in REGIMES:
        raise ValueError(f"unknown regime {regime!r}; known: {', '.join(REGIMES)}")
    if regime == "nominal":
        return get_experiment(experiment).make_env(seed=seed, n_steps=scale.n_steps)
    return mismatched_env(experiment, Condition(*REGIMES[regime]), seed, scale.n_steps)


def _kappa(experiment: str, files: dict[str, str]) -> list:
    """The kappa policies ``{name: file}``, each loaded (and checked) against its training experiment."""
    from adaptfilt.learned import load_policy

    out = []
    for name, f in files.items():
        exp = MODELS[experiment] if name.startswith("kappa-sqerr") else experiment
        out.append(load_policy(f, experiment=exp, name=name))
    return out


def _kalmannets(gains: dict[str, str], model) -> dict:
    """The KalmanNet files ``{name: file}``, each loaded (and checked) for ``model``: filters to evaluate."""
    from adaptfilt.kalmannet import load_kalmannet

    return {name: load_kalmannet(f, model) for name, f in gains.items()}


def evaluate_part(experiment: str, regime: str, part: str, kappa: dict[str, str], gains: dict[str, str],
                  scale: GainScale, seed: int = 0):
    """One part (:data:`PARTS`) of the evaluation of ``experiment`` under ``regime``: a
    :class:`~adaptfilt.results.Results` (``"reference"``: also the floor, in ``config["floor"]``).
    ``kappa``/``gains``: policy name -> file. The UKF's policies and the filters (KalmanNet, the particle
    filter) are evaluated on the same runs by one :func:`~adaptfilt.evaluation.evaluate` (``filters=``), so
    that every difference between them is paired."""
    from adaptfilt.evaluation import evaluate
    from adaptfilt.exact import UNGM_STUDY_FLOOR_GRID, BootstrapParticleFilter, bayes_floor
    from adaptfilt.experiment_registry import get_experiment
    from adaptfilt.runs import EvalRuns

    if part not in PARTS:
        raise ValueError(f"unknown part {part!r}; known: {', '.join(PARTS)}")
    exp = get_experiment(experiment)
    env = _env(experiment, regime, scale, seed)
    runs = EvalRuns(env.truth, scale.curve_runs if part == "curve" else scale.eval_runs, seed, env.n_steps)
    if part == "anchored":  # kappa: the anchored learner's files (study 5's), evaluated as any policy
        from adaptfilt.experiments.jobs import load_learned

        pols = load_learned(exp, list(kappa.values()))
    else:
        named = {"ukf": ("default", "ml", "greedy"), "curve": ("default",)}.get(part, ())
        pols = [p for p in exp.baselines() if p.name in named]
        if part in ("ukf", "curve"):  # every update-only constant: the best one in hindsight is the bar
            pols += exp.baselines(kinds=("fixed",))
            pols += _kappa(experiment, kappa)
    filters = _kalmannets(gains, env.model) if part in ("gain", "curve") else {}
    if part == "reference":  # the particle filter, knowing the nominal model like the others
        N = scale.pf_particles[experiment]
        filters = {f"bpf-{N}": BootstrapParticleFilter(env.model, n_particles=N, seed=[_PF_KEY, seed, N])}
    res = evaluate(env, pols, filters=filters, runs=runs, progress=False)
    if part == "reference":  # the point-mass filter with the truth's model on the first runs (scalar models)
        res.config["floor"] = (bayes_floor(env.truth, runs, scale.floor_runs, UNGM_STUDY_FLOOR_GRID).summary()
                               if env.nx == 1 else {"rmse": None, "runs": 0})
    res.config.update(experiment=experiment, regime=regime)
    return res


def _files(run: Run, experiment: str, budgets_: range) -> tuple[dict, dict]:
    sc = scale_of(run)
    kappa = {policy_name(a, b, s): str(run.out / policy_rel(experiment, a, b, s))
             for a in ("kappa-nis", "kappa-sqerr") for b in budgets_ for s in sc.seeds}
    gains = {policy_name(a, b, s): str(run.out / policy_rel(experiment, a, b, s))
             for a in LOSS for b in budgets_ for s in sc.seeds}
    return kappa, gains


def evaluations(run: Run, summary: dict, trained: list[Training]) -> list[EvalSpec]:
    sc = scale_of(run)
    last = range(len(TARGET_CPU_S), len(TARGET_CPU_S) + 1)
    specs = []
    for e in MODELS:
        for regime in REGIMES:
            for part in PARTS:
                if part == "anchored":
                    files = sorted(run.out.glob(f"policies/{e}-{ANCHORED}-s*.npz"))
                    if files:
                        specs.append(EvalSpec(NAME, e, evaluate_part, (e, regime, part, {f.stem: str(f) for f in files},
                                                                       {}, sc),
                                              job_key("gain", e, regime, part, [str(f) for f in files], sc.words()),
                                              order=2.5, tag=(regime, part)))
                    continue
                kappa, gains = _files(run, e, budgets(sc) if part == "curve" else last)
                kappa = kappa if part in ("ukf", "curve") else {}
                gains = gains if part in ("gain", "curve") else {}
                files = list(kappa.values()) + list(gains.values())
                specs.append(EvalSpec(NAME, e, evaluate_part, (e, regime, part, kappa, gains, sc),
                                      job_key("gain", e, regime, part, files, sc.words()),
                                      order={"ukf": 3, "curve": 2, "reference": 1, "gain": 0}[part], tag=(regime, part)))
    return specs


# ------------------------------------------------------------------ rows
#: The pairs judged: (a, b, what the pair isolates). ``default`` and ``best fixed`` are the references.
#: The declared comparison (:data:`adaptfilt.verdicts.DECLARED_MARGINS`) whose margin judges "not worse".
DECLARED = "learned gain vs learned kappa"
PAIRS = (("gain-sup", "kappa-sqerr", "what is learned (objective: squared error)"),
         ("gain-unsup", "kappa-nis", "what is learned (objective: measurements only)"),
         ("kappa-sqerr", "kappa-nis", "what it is trained on (learning kappa)"),
         ("gain-sup", "gain-unsup", "what it is trained on (learning the gain)"),
         *((a, ref, f"{a} vs the {ref}") for a in ARM_NAMES for ref in ("default", "best fixed")))


def _mse_db(p) -> float:
    """``10 log10`` of the mean squared error over runs and steps (``mean_t RMSE_t^2``)."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return float(10 * np.log10(np.mean(np.asarray(p.rmse_t, float) ** 2)))


def _num(x) -> float | None:
    """A JSON number, or None for n/a (NaN)."""
    x = float(x)
    return None if np.isnan(x) else x


def _train_cpu(run: Run, rel: str) -> float | None:
    """A policy's measured training CPU-s: this run's record, else the manifest's (an earlier run's)."""
    if rel in run.entries and run.entries[rel].get("cpu_time_s") is not None:
        return float(run.entries[rel]["cpu_time_s"])
    man = run.out / "manifest.json"
    if man.exists():
        for f in json.loads(man.read_text())["files"]:
            if f["path"] == rel and f.get("cpu_time_s") is not None:
                return float(f["cpu_time_s"])
    p = run.out / rel
    if p.exists() and "-gain-" in p.name:  # a KalmanNet file records its own
        from adaptfilt.files import read_npz

        cpu = read_npz(p, what="KalmanNet file")[1]["history"].get("cpu_s")  # files before the byte-reproducible ones
        return None if cpu is None else float(cpu)
    return None


def _stopped(run: Run, rel: str) -> bool:
    """Whether a KalmanNet file's training ended by divergence (its history says so)."""
    from adaptfilt.files import read_npz

    p = run.out / rel
    return p.exists() and bool(read_npz(p, what="KalmanNet file")[1]["history"].get("stopped_by_divergence"))


def arm_rows(res, arm: str, budget: int, experiment: str, train_cpu: dict, stopped: int | None = None) -> dict:
    """One arm at one budget: RMSE (IQM over seeds, two-level CI), MSE dB per seed and IQM, ANEES and the NIS
    cost where defined (None: n/a), divergent runs (error rule, every arm; NEES rule, where a covariance
    exists), training CPU-s per seed, microseconds per run-step."""
    from adaptfilt.seed_stats import aggregate, iqm

    members = [policy_name(arm, budget, s) for s in sorted(train_cpu)]
    members = [m for m in members if m in res]
    M, T = res.config["n_runs"], res.config["n_steps"]
    row = {"names": members, "rmse": aggregate(res, members, "rmse").to_dict()}
    db = [_mse_db(res[n]) for n in members]
    row["mse_db"] = {"values": db, "iqm": float(iqm(db))}
    has_cov = all(np.isfinite(res[n].anees) for n in members)
    row["covariance"] = bool(has_cov)
    row["anees"] = aggregate(res, members, "anees").to_dict() if has_cov else None
    row["cost"] = aggregate(res, members, "cost").to_dict() if arm.startswith("kappa") else None
    lim = DIVERGED_RMSE[experiment]
    row["divergent_error_rule"] = [int(np.sum(~(np.asarray(res[n].run_rmse) <= lim))) for n in members]
    row["divergent_nees_rule"] = [int(round(res[n].divergent_frac * M)) for n in members] if has_cov else None
    row["n_runs"] = M
    row["train_cpu_s"] = [train_cpu[int(n.rsplit("-s", 1)[1])] for n in members]
    row["stopped_trainings"] = stopped  # KalmanNet trainings ended by divergence (on_diverged="stop"); None: kappa
    row["us_per_step"] = [1e6 * res[n].wall_time_s / (M * T) for n in members]
    return row


def reference_rows(res, experiment: str) -> dict:
    """Default, best constant in hindsight by RMSE (update-only), ML, greedy, the particle filter: RMSE,
    MSE dB, ANEES, the NIS cost (None where not defined), divergent runs by both rules."""
    fixed = [n for n in res.names if n.startswith("fixed-")]
    best = min(fixed, key=lambda n: res[n].rmse) if fixed else None
    out = {}
    lim = DIVERGED_RMSE[experiment]
    M, T = res.config["n_runs"], res.config["n_steps"]
    for label, name in (("default", "default"), ("best fixed", best), ("ml", "ml"), ("greedy", "greedy"),
                        *((n, n) for n in res.names if n.startswith("bpf-"))):
        if name in res:
            p = res[name]
            out[label] = {"policy": name, "rmse": _num(p.rmse), "rmse_ci": [_num(v) for v in p.rmse_ci],
                          "mse_db": _mse_db(p), "anees": _num(p.anees), "cost": _num(p.cost),
                          "divergent_error_rule": int(np.sum(~(np.asarray(p.run_rmse) <= lim))),
                          "divergent_nees_rule": int(round(p.divergent_frac * M)),
                          "us_per_step": 1e6 * p.wall_time_s / (M * T)}
    seeds = sorted(n for n in res.names if n.startswith(f"{ANCHORED}-s"))
    if seeds:  # the anchored learner: a group of seeds, IQM [two-level CI] as the arms
        from adaptfilt.seed_stats import aggregate, iqm

        agg = {k: aggregate(res, seeds, k) for k in ("rmse", "anees", "cost")}
        out[ANCHORED] = {"policy": f"{ANCHORED}, {len(seeds)} seeds (IQM)", "rmse": agg["rmse"].iqm,
                         "rmse_ci": list(agg["rmse"].iqm_ci), "mse_db": float(iqm([_mse_db(res[n]) for n in seeds])),
                         "anees": agg["anees"].iqm, "cost": agg["cost"].iqm,
                         "divergent_error_rule": int(sum(np.sum(~(np.asarray(res[n].run_rmse) <= lim)) for n in seeds)),
                         "divergent_nees_rule": int(sum(round(res[n].divergent_frac * M) for n in seeds)),
                         "us_per_step": float(np.mean([1e6 * res[n].wall_time_s / (M * T) for n in seeds]))}
    return out


def verdict_rows(res, budget: int, seeds: tuple[int, ...]) -> list[dict]:
    """Seed-level verdicts on RMSE for :data:`PAIRS` at ``budget``: the IQM difference ``a - b`` with its
    two-level interval, "a lower than b" and "a not worse than b" (:func:`adaptfilt.verdicts.judge`, the margin
    declared for :data:`DECLARED` around b's IQM; none where that IQM is infinite)."""
    from adaptfilt.seed_stats import aggregate, difference
    from adaptfilt.verdicts import judge

    fixed = [n for n in res.names if n.startswith("fixed-")]
    refs = {"default": ["default"], "best fixed": [min(fixed, key=lambda n: res[n].rmse)] if fixed else []}
    groups = {a: [policy_name(a, budget, s) for s in seeds if policy_name(a, budget, s) in res] for a in ARM_NAMES}
    out = []
    for a, b, what in PAIRS:
        na, nb = groups.get(a) or [], groups.get(b) or refs.get(b) or []
        if not na or not nb:
            continue
        with np.errstate(invalid="ignore", over="ignore"):
            d = difference(res, na, nb, "rmse")["iqm"]
            ref = aggregate(res, nb, "rmse").iqm
        not_worse, margin = judge("not worse", d, DECLARED, "rmse", ref) if np.isfinite(ref) else (None, None)
        out.append({"a": a, "b": b if b in groups else f"{b} ({nb[0]})", "isolates": what, "budget": budget,
                    "rmse_diff": [_num(v) for v in d], "lower": judge("lower", d)[0],
                    "not_worse": not_worse, "margin": margin})
    return out


def rows(run: Run, summary: dict, specs: list[EvalSpec], values: list) -> dict:
    """Merge each (model, regime)'s parts, save them (``results/gain-<model>-<regime>`` and ``-curve``), and
    summarise: references, every arm at every budget, verdicts; the floor."""
    from adaptfilt.results import Results

    sc = scale_of(run)
    parts: dict = {}
    for spec, v in zip(specs, values):
        regime, part = spec.tag
        parts.setdefault((spec.experiment, regime), {})[part] = v
    cpu, stopped = {}, {}
    for e in MODELS:
        for a in ARM_NAMES:
            for b in budgets(sc):
                cpu[(e, a, b)] = {s: _train_cpu(run, policy_rel(e, a, b, s)) for s in sc.seeds}
                stopped[(e, a, b)] = (sum(_stopped(run, policy_rel(e, a, b, s)) for s in sc.seeds)
                                      if a in LOSS else None)
    out: dict = {"scale": sc.name, "target_cpu_s": list(TARGET_CPU_S), "budgets": {
        e: {"kappa_episodes": list(sc.kappa_episodes[e]), "knet_epochs": list(sc.knet_epochs[e])} for e in MODELS},
        "knet": knet_options(sc), "eval_runs": sc.eval_runs, "curve_runs": sc.curve_runs, "models": {}}
    for (e, regime), p in parts.items():
        floor = p["reference"].config.pop("floor")
        final = Results.merge([p["ukf"], p["gain"], p["reference"]] + ([p["anchored"]] if "anchored" in p else []))
        curve = p["curve"]
        last = len(TARGET_CPU_S)
        entry = {"references": reference_rows(final, e), "floor": floor,
                 "final": {a: arm_rows(final, a, last, e, cpu[(e, a, last)], stopped[(e, a, last)]) for a in ARM_NAMES},
                 "curve": {a: {str(b): arm_rows(curve, a, b, e, cpu[(e, a, b)], stopped[(e, a, b)]) for b in budgets(sc)}
                           for a in ARM_NAMES},
                 "curve_references": reference_rows(curve, e),
                 "verdicts": verdict_rows(final, last, sc.seeds) + [v for b in budgets(sc) if b < last
                                                                     for v in verdict_rows(curve, b, sc.seeds)]}
        run.save(f"gain-{e}-{regime}", final, drop=COMPACT)
        run.save(f"gain-{e}-{regime}-curve", curve, drop=COMPACT)
        out["models"].setdefault(e, {})[regime] = entry
    return {NAME: out}


# ------------------------------------------------------------------ figures and tables
_COLORS = {"kappa-nis": "C0", "kappa-sqerr": "C1", "gain-unsup": "C2", "gain-sup": "C3"}


def figures(run: Run, summary: dict) -> list[str]:
    """The budget curves (:func:`plot_budget_curves`) into ``figures/gain-budget.png``."""
    if NAME not in summary:
        return []
    return [run.figure(plot_budget_curves(summary[NAME]), "gain-budget.png")]


def plot_budget_curves(g: dict):
    """The budget curves of the study's summary ``g`` (``summary["gain"]``): RMSE (IQM over seeds, two-level 95 %
    interval) against the measured training CPU-s (mean over seeds), per arm; a row per model, a column per
    regime; the default, best constant and particle filter as lines. An interval that reaches infinity (a seed
    with a diverged run among the resampled ones) ends in a triangle at the panel's top. Returns the figure."""
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    models = g["models"]
    regimes = list(dict.fromkeys(r for e in models for r in models[e]))
    fig, axes = plt.subplots(len(models), len(regimes), figsize=(4.6 * len(regimes), 3.3 * len(models)),
                             layout="constrained", squeeze=False)
    for i, e in enumerate(models):
        for j, r in enumerate(regimes):
            ax, m = axes[i][j], models[e][r]
            tops = []
            for a in ARM_NAMES:
                pts = m["curve"][a]
                bs = sorted(pts, key=int)
                xs = np.array([float(np.mean([c for c in pts[b]["train_cpu_s"] if c is not None] or [np.nan])) for b in bs])
                ys, lo, hi = (np.array([pts[b]["rmse"][k] if k == "iqm" else pts[b]["rmse"]["iqm_ci"][k]
                                        for b in bs], dtype=float) for k in ("iqm", 0, 1))
                hi = np.where(np.isnan(hi) & np.isfinite(ys), np.inf, hi)  # a percentile between infinite replicates
                up = np.where(np.isfinite(hi), np.maximum(hi - ys, 0), 0.0)
                ax.errorbar(xs, ys, yerr=[np.maximum(ys - lo, 0), up], marker="o", capsize=3, color=_COLORS[a],
                            label=a)
                tops += [(x, _COLORS[a]) for x, h in zip(xs, hi) if np.isposinf(h)]
            for label, style in (("default", ":"), ("best fixed", "--")):
                ref = m["curve_references"].get(label)
                if ref and ref["rmse"] is not None:
                    ax.axhline(ref["rmse"], color="grey", ls=style, lw=1, label=f"{label} ({ref['policy']})")
            for k, ref in m["references"].items():
                if k.startswith("bpf-") and ref["rmse"] is not None:
                    ax.axhline(ref["rmse"], color="k", ls="-.", lw=1, label=f"particle filter ({k})")
            y1 = ax.get_ylim()[1]
            for x, c in tops:
                ax.plot([x], [y1], marker="^", color=c, clip_on=False, ls="none")
            ax.set_xscale("log")
            ax.set_xticks([1, 2, 5, 10, 20, 50])
            ax.xaxis.set_major_formatter(ScalarFormatter())
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_xlabel("training CPU-s per policy (mean over seeds)")
            ax.set_ylabel("RMSE")
            ax.set_title(f"{e}, {'nominal model' if r == 'nominal' else 'truth with Q x 4'}", fontsize=10)
    by_label = {}
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            key = "default" if lab.startswith("default") else "best constant" if lab.startswith("best") else \
                "particle filter" if lab.startswith("particle") else lab
            by_label.setdefault(key, h)
    order = [*ARM_NAMES, "default", "best constant", "particle filter"]
    fig.legend([by_label[k] for k in order if k in by_label], [k for k in order if k in by_label],
               loc="outside lower center", ncol=4, fontsize=8)
    return fig


def _agg(a: dict | None) -> str:
    if a is None:
        return "n/a"
    return f"{a['iqm']:.4g} [{a['iqm_ci'][0]:.4g}, {a['iqm_ci'][1]:.4g}]"


def markdown(summary: dict) -> str:
    """The study's tables for REPRODUCTION.md: per model and regime the references, every arm at the final budget
    and along the budget curve (RMSE, MSE dB, ANEES, cost, divergent runs, training CPU-s beside the budget,
    microseconds per step), then the seed-level verdicts."""
    if NAME not in summary:
        return ""
    g = summary[NAME]
    lines = [f"**Learn the parameter or learn the gain** (IQM over seeds [two-level 95 % CI]; budgets "
             f"targeted at {', '.join(f'{c:g}' for c in g['target_cpu_s'])} CPU-s per policy; final budget on "
             f"{g['eval_runs']} runs, the curve on {g['curve_runs']}; n/a: not defined for the arm)", ""]
    head = ["model", "regime", "policy", "budget (work units)", "train CPU-s (mean)", "RMSE", "MSE dB", "ANEES",
            "NIS cost", "divergent runs (error rule)", "us/step"]
    lines += md_table(head)
    for e, regimes in g["models"].items():
        for r, m in regimes.items():
            for label, ref in m["references"].items():
                lines.append(f"| {e} | {r} | {label} ({ref['policy']}) | | | {ref['rmse']:.4g} | {ref['mse_db']:.3g} | "
                             f"{'n/a' if ref['anees'] is None else format(ref['anees'], '.4g')} | "
                             f"{'n/a' if ref['cost'] is None else format(ref['cost'], '.4g')} | "
                             f"{ref['divergent_error_rule']} | {ref['us_per_step']:.3g} |")
            if m["floor"]["rmse"] is not None:
                lines.append(f"| {e} | {r} | point-mass floor (first {m['floor']['runs']} runs) | | | "
                             f"{m['floor']['rmse']:.4g} | | | | | |")
            for a in ARM_NAMES:
                for b, row in sorted(m["curve"][a].items(), key=lambda kv: int(kv[0])):
                    lines.append(_arm_line(e, r, a, int(b), row, g["budgets"][e]))
                lines.append(_arm_line(e, r, a, len(g["target_cpu_s"]), m["final"][a], g["budgets"][e], final=True))
    lines += ["", "**Learn the parameter or learn the gain: seed-level verdicts on RMSE** (a - b, IQM over seeds "
              "[two-level 95 % CI]; 'not worse' within 5 % of b's RMSE, the margin declared in "
              "adaptfilt.verdicts.DECLARED_MARGINS)", "",
              *md_table(["model", "regime", "budget", "a", "b", "isolates", "RMSE a - b", "a lower", "a not worse"])]
    for e, regimes in g["models"].items():
        for r, m in regimes.items():
            for v in sorted(m["verdicts"], key=lambda v: v["budget"]):
                d = v["rmse_diff"]
                ds = "n/a" if None in d else diff_ci(d)
                lines.append(f"| {e} | {r} | {v['budget']} | {v['a']} | {v['b']} | {v['isolates']} | {ds} | "
                             f"{v['lower']} | {v['not_worse'] or 'n/a (no margin)'} |")
    return "\n".join(lines) + "\n"


def _arm_line(e: str, r: str, arm: str, b: int, row: dict, bud: dict, final: bool = False) -> str:
    units = f"{bud['kappa_episodes'][b - 1]} episodes" if arm.startswith("kappa") else f"{bud['knet_epochs'][b - 1]} epochs"
    if row.get("stopped_trainings"):
        units += f" ({row['stopped_trainings']} of {len(row['names'])} trainings stopped by divergence)"
    cpu = [c for c in row["train_cpu_s"] if c is not None]
    where = f"{row['n_runs']} runs" + (", final" if final else "")
    return (f"| {e} | {r} | {arm} b{b} ({where}) | {units} | {np.mean(cpu) if cpu else float('nan'):.3g} | "
            f"{_agg(row['rmse'])} | {row['mse_db']['iqm']:.3g} | {_agg(row['anees'])} | {_agg(row['cost'])} | "
            f"{', '.join(map(str, row['divergent_error_rule']))} | {np.mean(row['us_per_step']):.3g} |")
