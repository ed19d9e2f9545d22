r"""The pipeline's jobs, written once: what a training or an evaluation is, the command a manifest
records for it, the key the journal files it under, and the function a worker runs.

* :class:`Training`: what every training job of the pipeline is. ``.command`` is the ``adaptfilt ...`` line
  recorded in its files and in the manifest (``data/manifest.json``, ``data/beyond/manifest.json``; the tests
  rebuild each one byte for byte), ``.key`` the journal's ``(command, seed)``, ``.outputs`` the files it
  writes, ``.run()`` the training itself; :func:`run_training` runs one in a worker. Two kinds meet it:

  * :class:`TrainSpec`: one policy file, ``adaptfilt train`` (the parameter's learners);
  * :class:`GainSpec`: one learned-gain training, ``adaptfilt train-gain`` (KalmanNet), snapshotted into one
    file per budget.
* :class:`EvalSpec`: one evaluation job of a study (a module-level function and its arguments), with its
  journal key; :func:`evaluate_spec` runs it, :func:`save_value` / :func:`load_value` keep its value.
* :func:`evaluate_command`: the ``adaptfilt evaluate ...`` line (``adaptfilt evaluate`` and the reproduction).
* :func:`load_learned`: a study's policy files as policies named after their files.

The functions run in worker processes (a local pool or Dask): they import what they need when called.
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

from adaptfilt.files import sha256

__all__ = ["Training", "TrainSpec", "GainSpec", "GAIN_ARCHS", "GAIN_FEATURE_NORMS", "run_training", "same_command", "EvalSpec",
           "evaluate_spec", "evaluate_command", "load_learned", "job_key", "save_value", "load_value", "take_times"]


class Training(Protocol):
    """A training job of the pipeline (module docstring): what ``adaptfilt beyond`` and ``adaptfilt reproduce``
    run, journal and record. ``run()`` writes ``outputs`` and returns, per output, what the manifest records of
    it: ``{"command", "wall_time_s", "cpu_time_s"}``."""

    experiment: str
    seed: int

    @property
    def command(self) -> str: ...

    @property
    def key(self) -> tuple[str, int]: ...

    @property
    def outputs(self) -> tuple[str, ...]: ...

    def run(self, progress: bool = False) -> dict[str, dict]: ...


def run_training(spec: Training) -> dict[str, dict]:
    """Run ``spec`` (a worker's job): its outputs' records (:class:`Training`)."""
    return spec.run()


def same_command(a: str, b: str) -> bool:
    """Whether two recorded commands make the same files, wherever they were written (their ``--out``
    arguments aside: a folder may have moved)."""
    def strip(c: str) -> str:
        return re.sub(r" --out \S+", "", c)

    return strip(a) == strip(b)


def _flag(name: str, value, fmt: str = "") -> str:
    """`` --name value`` (numbers by ``fmt``), or nothing for None."""
    return "" if value is None else f" --{name} {format(value, fmt)}"


def _exact(x: float) -> str:
    """A number as short as ``:g`` writes it where that reads back the same float, else in full."""
    short = f"{x:g}"
    return short if float(short) == x else repr(float(x))


@dataclass(frozen=True)
class TrainSpec:
    """One policy to train: the arguments of ``adaptfilt train`` (a :class:`Training`).

    ``out`` is where the file is written; ``recorded_out`` what the command says instead (the reproduction
    records ``data/policies/...`` wherever it writes, so that its files are the same in any folder).
    ``anchor``: ``(policy, strength, KL weight, shield)``, a None value left to the trainer's default (and out
    of the command). The SB3 trainers' recipe may be overridden (``lr``, ``n_epochs``: PPO's learning rate and
    epochs per rollout); ``truth`` (:func:`adaptfilt.experiment_registry.truth_model`'s words) trains on episodes
    of a truth the filter does not know; ``snapshots``: episode counts at which the policy is kept
    (:func:`adaptfilt.trainers.train_sb3`: each bit for bit the policy of a training of that many episodes),
    ``out`` then a tuple of files, one per snapshot in their order."""

    experiment: str
    gamma: float
    episodes: int
    seed: int
    out: str | tuple[str, ...]
    algo: str = "fast"
    features: str | None = None
    repair_penalty: float = 0.0
    horizon: int | None = None
    actions: Sequence[float] | None = None  # as given: the safe set, a list read from the selection's JSON
    cost_transform: str = "log1p"
    anchor: tuple[str, float | None, float | None, float | None] | None = None
    recorded_out: str | None = None
    parallel: int | None = None
    lr: float | None = None
    n_epochs: int | None = None
    truth: str | None = None
    snapshots: tuple[int, ...] | None = None

    def __post_init__(self):
        n = 1 if self.snapshots is None else len(self.snapshots)
        outs = (self.out,) if isinstance(self.out, (str, Path)) else tuple(self.out)
        if len(outs) != n or (self.snapshots is None and not isinstance(self.out, (str, Path))):
            raise ValueError(f"{n} file{'s' if n > 1 else ''} to write (one per snapshot), "
                             f"got {len(outs)} --out: {', '.join(map(str, outs))}")
        if self.snapshots is not None and (list(self.snapshots) != sorted(set(self.snapshots))
                                           or self.snapshots[0] < 1 or self.snapshots[-1] > self.episodes):
            raise ValueError(f"snapshots must be increasing episode counts in 1..{self.episodes}, got "
                             f"{list(self.snapshots)}")
        if self.snapshots is not None and self.recorded_out is not None:
            raise ValueError("recorded_out names one file: not with snapshots")
        if (self.lr is not None or self.n_epochs is not None or self.truth is not None or self.snapshots) \
                and self.algo not in ("fast", "ppo", "a2c"):
            raise ValueError(f"--lr, --n-epochs, --truth and --snapshots need an SB3 trainer (fast, a2c or ppo), "
                             f"not {self.algo}")

    @property
    def command(self) -> str:
        """The ``adaptfilt train`` line that makes this file; options in one fixed order, the defaults left out
        (``cli`` records this line too: it is the one author of it)."""
        anchor = ""
        if self.anchor:
            policy, strength, kl, shield = self.anchor
            anchor = (f" --anchor {policy}" + _flag("anchor-strength", strength, "g") + _flag("anchor-kl", kl, "g")
                      + _flag("anchor-shield", shield, "g"))
        snaps = "" if self.snapshots is None else " --snapshots " + ",".join(str(e) for e in self.snapshots)
        outs = "".join(f" --out {o}" for o in self.outputs) if self.snapshots else f" --out {self.recorded_out or self.out}"
        return (f"adaptfilt train {self.experiment} --algo {self.algo} --gamma {self.gamma:g} "
                f"--episodes {self.episodes}{snaps}" + _flag("parallel", self.parallel) + f" --seed {self.seed}"
                + (f" --features {self.features}" if self.features else "")
                + (f" --repair-penalty {self.repair_penalty:g}" if self.repair_penalty else "")
                + (f" --horizon {self.horizon}" if self.horizon else "")
                + (" --actions " + ",".join(f"{v:g}" for v in self.actions) if self.actions else "")
                + (f" --cost-transform {self.cost_transform}" if self.cost_transform != "log1p" else "")
                + ("" if self.lr is None else f" --lr {_exact(self.lr)}") + _flag("n-epochs", self.n_epochs)
                + _flag("truth", self.truth) + anchor + outs)

    @property
    def key(self) -> tuple[str, int]:
        """The journal's key of this job."""
        return self.command, self.seed

    @property
    def outputs(self) -> tuple[str, ...]:
        return (str(self.out),) if isinstance(self.out, (str, Path)) else tuple(str(o) for o in self.out)

    def run(self, progress: bool = False, resume: bool = False) -> dict[str, dict]:
        """Train into ``out``; its wall and CPU time and its command (with snapshots: each snapshot into its
        file, its CPU time that spent up to it). ``resume``: from the checkpoint next to ``out`` (the
        paper-faithful and batched learners write one)."""
        from adaptfilt.trainers import train_policy

        t0, c0 = time.perf_counter(), time.process_time()
        kw = dict(zip(("anchor", "anchor_strength", "anchor_kl", "anchor_shield"), self.anchor)) if self.anchor else {}
        sb3 = {k: v for k, v in (("learning_rate", self.lr), ("n_epochs", self.n_epochs)) if v is not None}
        if sb3:
            kw["sb3"] = sb3
        if self.truth is not None:
            kw["truth"] = self.truth
        pol = train_policy(self.experiment, self.algo, self.gamma, self.episodes, self.seed, parallel=self.parallel,
                           n_steps=self.horizon, progress=progress, out=None if self.snapshots else self.out,
                           command=self.command, features=self.features, repair_penalty=self.repair_penalty,
                           actions=self.actions, cost_transform=self.cost_transform, resume=resume,
                           snapshots=self.snapshots or (), **kw)
        if not self.snapshots:
            return {str(self.out): {"command": self.command, "wall_time_s": time.perf_counter() - t0,
                                    "cpu_time_s": time.process_time() - c0}}
        out = {}
        for e, path in zip(self.snapshots, self.outputs):
            snap = pol.snapshots[e]
            snap.save(path)
            out[path] = {"command": self.command, "wall_time_s": None, "cpu_time_s": float(snap.cpu_s)}
        return out


#: The learned-gain architectures ``adaptfilt train-gain --arch`` knows and KalmanNet's architecture number of each
#: (:mod:`adaptfilt.kalmannet`, :mod:`adaptfilt.gainnets`): ``kalmannet`` is architecture 2 (the library's default,
#: the name files recorded before architecture 1 was offered), ``kalmannet-arch1`` architecture 1.
GAIN_ARCHS = {"kalmannet": 2, "kalmannet-arch1": 1}
#: KalmanNet's input scalings (:data:`adaptfilt.kalmannet.FEATURE_NORMS`, named here so that the command line
#: offers them without importing torch).
GAIN_FEATURE_NORMS = ("l2", "none", "scale")
#: What a non-finite loss does (:func:`adaptfilt.kalmannet.train_kalmannet`'s ``on_diverged``).
GAIN_ON_DIVERGED = ("raise", "restore", "stop", "restart")


@dataclass(frozen=True)
class GainSpec:
    """One learned-gain training: the arguments of ``adaptfilt train-gain`` (a :class:`Training`).

    A filter with a learned gain (``arch``, :data:`GAIN_ARCHS`; ``hidden_mult``: architecture 2's width
    multiplier of its GRUs and FC2, None: the paper's widths) for ``experiment``'s model, trained on ``loss``
    (``"supervised"``: the squared error against the true state; ``"unsupervised"``: the predicted
    measurement's) from ``seed``, for ``epochs`` epochs or, with ``epochs=None``, ``steps`` optimiser steps, on
    ``train_runs`` training trajectories (per epoch; ``fresh="batch"`` or ``"epoch"``: new ones each minibatch or
    epoch) and ``val_runs`` validation trajectories (validated every ``val_every`` optimiser steps, None: once
    per epoch) of ``horizon`` steps (None: the model's), simulated from the model itself or, with ``truth``
    (:func:`adaptfilt.experiment_registry.truth_model`'s words, e.g. ``"q=4,r=1"`` or ``"forcing=10"``), from a
    truth that differs from it (the filter keeps the nominal model). ``snapshots`` (epochs) or
    ``snapshot_steps`` (optimiser steps, multiples of ``val_every``): where the filter is kept, one file of
    ``outs`` each, in order (a snapshot is bit for bit the filter of a training that stopped there: one training
    serves a budget curve); neither: one file, the trained filter. ``clamp="auto"``: the state estimate clamped
    to the model's range; ``on_diverged="restart"`` with ``restarts`` and ``patience``: the restart rule;
    ``collapse_after``: a finite collapse of the validation loss counts as a divergence. The rest
    is the recipe of :func:`adaptfilt.kalmannet.train_kalmannet`, written out in the command; an option left
    out of it is one whose value is the absence of that feature (no clip, whole-sequence back-propagation, a
    fixed training set, per-epoch validation, no clamp, the paper's widths, no restarts, only non-finite
    divergence), as files recorded
    before those options existed say."""

    experiment: str
    loss: str
    epochs: int | None
    seed: int
    outs: tuple[str, ...]
    snapshots: tuple[int, ...] | None = None
    arch: str = "kalmannet"
    truth: str | None = None
    horizon: int | None = None
    train_runs: int = 100
    val_runs: int = 50
    batch_size: int = 20
    lr: float = 1e-3
    weight_decay: float = 1e-4
    clip: float | None = None
    tbptt: int | None = None
    feature_norm: str = "scale"
    on_diverged: str = "raise"
    model_grad: str = "jacobian"
    steps: int | None = None
    snapshot_steps: tuple[int, ...] | None = None
    hidden_mult: int | None = None
    fresh: str | None = None
    val_every: int | None = None
    clamp: str | None = None
    restarts: int = 0
    patience: int | None = None
    collapse_after: int | None = None

    def __post_init__(self):
        from adaptfilt.kalmannet import FRESH, MODEL_GRADS

        if self.model_grad not in MODEL_GRADS:
            raise ValueError(f"unknown model_grad {self.model_grad!r}; known: {', '.join(MODEL_GRADS)}")
        if self.arch not in GAIN_ARCHS:
            raise ValueError(f"unknown learned-gain architecture {self.arch!r}; known: {', '.join(GAIN_ARCHS)}")
        if self.hidden_mult is not None and GAIN_ARCHS[self.arch] != 2:
            raise ValueError(f"hidden_mult widens architecture 2 (--arch kalmannet), not {self.arch}")
        if (self.epochs is None) == (self.steps is None):
            raise ValueError("a learned-gain training's budget is either epochs or optimiser steps (--steps), "
                             f"got epochs={self.epochs}, steps={self.steps}")
        if self.snapshots is not None and self.snapshot_steps is not None:
            raise ValueError("snapshots are epochs or optimiser steps (--snapshot-steps), not both")
        if self.snapshots is not None and (self.epochs is None or max(self.snapshots) > self.epochs):
            raise ValueError(f"--snapshots {','.join(map(str, self.snapshots))}: epochs up to --epochs {self.epochs}")
        if self.snapshot_steps is not None:
            if self.steps is None or max(self.snapshot_steps) > self.steps:
                raise ValueError(f"--snapshot-steps {','.join(map(str, self.snapshot_steps))}: optimiser steps up to "
                                 f"--steps {self.steps}")
            if self.val_every is None or any(s % self.val_every for s in self.snapshot_steps):
                raise ValueError(f"--snapshot-steps must be multiples of --val-every {self.val_every}, got "
                                 f"{','.join(map(str, self.snapshot_steps))}")
        if self.fresh not in FRESH:
            raise ValueError(f"unknown fresh {self.fresh!r}; known: batch, epoch")
        if self.clamp not in (None, "auto"):
            raise ValueError(f"clamp is 'auto' or None, got {self.clamp!r}")
        if self.on_diverged not in GAIN_ON_DIVERGED:
            raise ValueError(f"unknown on_diverged {self.on_diverged!r}; known: {', '.join(GAIN_ON_DIVERGED)}")
        if (self.restarts or self.patience is not None) and self.on_diverged != "restart":
            raise ValueError("--restarts and --patience belong to the restart rule: give --on-diverged restart")
        if self.collapse_after is not None and (int(self.collapse_after) != self.collapse_after
                                                or self.collapse_after < 1):
            raise ValueError(f"--collapse-after is a positive number of validations, got {self.collapse_after}")
        snaps = self.snapshots if self.snapshots is not None else self.snapshot_steps
        n = 1 if snaps is None else len(snaps)
        if len(self.outs) != n:
            raise ValueError(f"{n} file{'s' if n > 1 else ''} to write (one per snapshot), "
                             f"got {len(self.outs)} --out: {', '.join(map(str, self.outs))}")

    @property
    def command(self) -> str:
        """The ``adaptfilt train-gain`` line that makes these files (every file of the training records it)."""
        def listed(name, values):
            return "" if values is None else f" --{name} " + ",".join(str(v) for v in values)

        budget = f"--epochs {self.epochs}" if self.epochs is not None else f"--steps {self.steps}"
        restart = (f" --restarts {self.restarts}" + _flag("patience", self.patience)
                   if self.on_diverged == "restart" else "")
        return (f"adaptfilt train-gain {self.experiment} --arch {self.arch}" + _flag("hidden-mult", self.hidden_mult)
                + f" --loss {self.loss} {budget}" + listed("snapshots", self.snapshots)
                + listed("snapshot-steps", self.snapshot_steps) + f" --seed {self.seed}" + _flag("truth", self.truth)
                + _flag("horizon", self.horizon) + f" --train-runs {self.train_runs} --val-runs {self.val_runs} "
                f"--batch-size {self.batch_size}" + _flag("fresh", self.fresh) + _flag("val-every", self.val_every)
                + f" --lr {_exact(self.lr)} --weight-decay {_exact(self.weight_decay)}"
                + ("" if self.clip is None else f" --clip {_exact(self.clip)}") + _flag("tbptt", self.tbptt)
                + f" --feature-norm {self.feature_norm}" + _flag("clamp", self.clamp)
                + f" --on-diverged {self.on_diverged}{restart}" + _flag("collapse-after", self.collapse_after)
                + f" --model-grad {self.model_grad}"
                + "".join(f" --out {o}" for o in self.outs))

    @property
    def key(self) -> tuple[str, int]:
        return self.command, self.seed

    @property
    def outputs(self) -> tuple[str, ...]:
        return tuple(str(o) for o in self.outs)

    @property
    def checkpoint(self) -> Path:
        """Where the training keeps its checkpoint while it runs (``train_kalmannet(checkpoint=...)``): beside its
        last file, ``OUT.ckpt.npz`` (:func:`adaptfilt.actor_critic.checkpoint_path`, as ``adaptfilt train``'s); the
        same job, run again, resumes from it, bit for bit, and deletes it once its files are written."""
        from adaptfilt.actor_critic import checkpoint_path

        return checkpoint_path(self.outs[-1])

    def train(self, progress: bool = False, checkpoint: str | Path | None = None):
        """The training itself: :func:`adaptfilt.kalmannet.train_kalmannet` with this recipe (the trained
        filter, its snapshots kept), through ``checkpoint`` if given (the results are the same)."""
        from adaptfilt.experiment_registry import get_experiment, truth_model
        from adaptfilt.kalmannet import train_kalmannet

        model = get_experiment(self.experiment).make_model()
        options = {} if self.hidden_mult is None else {"hidden_mult": self.hidden_mult}
        if self.clamp is not None:
            options["clamp"] = self.clamp
        if self.on_diverged == "restart":
            options.update(restarts=self.restarts, patience=self.patience)
        if self.collapse_after is not None:
            options["collapse_after"] = self.collapse_after
        return train_kalmannet(model, loss=self.loss, n_steps=self.horizon or model.n_steps, epochs=self.epochs,
                               seed=self.seed, progress=progress, snapshots=self.snapshots or (),
                               n_train=self.train_runs, n_val=self.val_runs, batch_size=self.batch_size, lr=self.lr,
                               weight_decay=self.weight_decay, clip=self.clip, tbptt=self.tbptt,
                               feature_norm=self.feature_norm, on_diverged=self.on_diverged,
                               model_grad=self.model_grad, arch=GAIN_ARCHS[self.arch], fresh=self.fresh,
                               val_every=self.val_every, max_steps=self.steps,
                               snapshot_steps=self.snapshot_steps or (),
                               truth=None if self.truth is None else truth_model(model, self.truth),
                               checkpoint=checkpoint, **options)

    def run(self, progress: bool = False) -> dict[str, dict]:
        """Train once and write each snapshot (or the filter) to its file; per file its command and its
        training CPU-s up to it (the file's own ``history["cpu_s"]``, every sitting of a resumed training together).
        The training keeps a checkpoint (:attr:`checkpoint`) while it runs."""
        knet = self.train(progress, checkpoint=self.checkpoint)
        if self.snapshots is not None:
            filters = [knet.snapshot(e) for e in self.snapshots]
        elif self.snapshot_steps is not None:
            filters = [knet.snapshot(step=s) for s in self.snapshot_steps]
        else:
            filters = [knet]
        out = {}
        for f, path in zip(filters, self.outputs):
            f.save(path)
            out[path] = {"command": self.command, "wall_time_s": None, "cpu_time_s": float(f.history["cpu_s"])}
        self.checkpoint.unlink(missing_ok=True)  # only now: a stop before the files are whole resumes from it
        return out


def evaluate_command(experiment: str, runs: int, seed: int, out: str | Path, policies: Sequence[str | Path] = (),
                     horizon: int | None = None, chunk_size: int | None = None) -> str:
    """The ``adaptfilt evaluate`` line of an evaluation (``chunk_size``: only when not the default)."""
    return (f"adaptfilt evaluate {experiment} --runs {runs} --seed {seed}"
            + ("" if horizon is None else f" --horizon {horizon}")
            + ("" if chunk_size is None else f" --chunk-size {chunk_size}") + f" --out {out}"
            + "".join(f" --policy {p}" for p in policies))


def load_learned(experiment, files: Sequence[str | Path]) -> list:
    """The policy files of ``experiment`` (an :class:`~adaptfilt.experiment_registry.Experiment`), each
    named after its file (:func:`adaptfilt.learned.learned_name`: ``adaptive-s3``)."""
    from adaptfilt.learned import learned_name, load_policy

    return [load_policy(f, experiment=experiment, name=learned_name(f, experiment.name)) for f in files]


@dataclass(frozen=True)
class EvalSpec:
    """One evaluation job of a study: ``fn(*args)`` in a worker, filed in the journal under ``key`` (seed
    ``seed``). ``experiment`` says whose result it is; ``order``: larger starts first (the longest jobs)."""

    study: str
    experiment: str
    fn: Callable
    args: tuple
    key: str
    seed: int = 0
    order: float = 0.0
    tag: Any = field(default=None, compare=False)  # what the study needs to place the value (a part's name)


def evaluate_spec(spec: EvalSpec) -> Any:
    """Run an evaluation job (in a worker)."""
    return spec.fn(*spec.args)


def job_key(kind: str, *parts) -> str:
    """What identifies a job of ``adaptfilt beyond`` for the journal: its words, the policy files by their
    name and contents (a scale gives its budgets as words: its ``words()``)."""
    def word(x) -> str:
        if isinstance(x, (list, tuple)):
            return "[" + ",".join(f"{Path(f).name}@{sha256(f)[:16]}" if str(f).endswith(".npz") else str(f)
                                  for f in x) + "]"
        return str(x)

    return f"beyond {kind} " + " ".join(word(x) for x in parts)


def save_value(folder: Path, value) -> tuple[list[Path], Any]:
    """An evaluation job's value for the journal: Results (one, or a list) as files, anything else as JSON."""
    from adaptfilt.experiments.journal import save_results
    from adaptfilt.results import Results

    if isinstance(value, Results):
        return save_results(folder, [value]), 1
    if isinstance(value, list) and value and all(isinstance(v, Results) for v in value):
        return save_results(folder, value), {"parts": len(value)}
    return [], {"json": value}


def load_value(folder: Path, stored) -> Any:
    """What :func:`save_value` kept, bit for bit."""
    from adaptfilt.experiments.journal import load_results

    if isinstance(stored, int):
        return load_results(folder, stored)[0]
    if "parts" in stored:
        return load_results(folder, stored["parts"])
    return stored["json"]


def take_times(res) -> float:
    """The evaluation's wall time, moved from its policies to the manifest: the same command then
    writes byte-identical results, resumed or not."""
    wall = sum(p.wall_time_s for p in res.policies.values())
    for p in res.policies.values():
        p.wall_time_s = 0.0
    return round(wall, 2)
