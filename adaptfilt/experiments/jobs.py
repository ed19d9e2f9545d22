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
    of the command)."""

    experiment: str
    gamma: float
    episodes: int
    seed: int
    out: str
    algo: str = "fast"
    features: str | None = None
    repair_penalty: float = 0.0
    horizon: int | None = None
    actions: Sequence[float] | None = None  # as given: the safe set, a list read from the selection's JSON
    cost_transform: str = "log1p"
    anchor: tuple[str, float | None, float | None, float | None] | None = None
    recorded_out: str | None = None
    parallel: int | None = None

    @property
    def command(self) -> str:
        """The ``adaptfilt train`` line that makes this file; options in one fixed order, the defaults left out
        (``cli`` records this line too: it is the one author of it)."""
        anchor = ""
        if self.anchor:
            policy, strength, kl, shield = self.anchor
            anchor = (f" --anchor {policy}" + _flag("anchor-strength", strength, "g") + _flag("anchor-kl", kl, "g")
                      + _flag("anchor-shield", shield, "g"))
        return (f"adaptfilt train {self.experiment} --algo {self.algo} --gamma {self.gamma:g} "
                f"--episodes {self.episodes}" + _flag("parallel", self.parallel) + f" --seed {self.seed}"
                + (f" --features {self.features}" if self.features else "")
                + (f" --repair-penalty {self.repair_penalty:g}" if self.repair_penalty else "")
                + (f" --horizon {self.horizon}" if self.horizon else "")
                + (" --actions " + ",".join(f"{v:g}" for v in self.actions) if self.actions else "")
                + (f" --cost-transform {self.cost_transform}" if self.cost_transform != "log1p" else "")
                + anchor + f" --out {self.recorded_out or self.out}")

    @property
    def key(self) -> tuple[str, int]:
        """The journal's key of this job."""
        return self.command, self.seed

    @property
    def outputs(self) -> tuple[str, ...]:
        return (str(self.out),)

    def run(self, progress: bool = False, resume: bool = False) -> dict[str, dict]:
        """Train into ``out``; its wall and CPU time and its command. ``resume``: from the checkpoint next to
        ``out`` (the paper-faithful and batched learners write one)."""
        from adaptfilt.trainers import train_policy

        t0, c0 = time.perf_counter(), time.process_time()
        kw = dict(zip(("anchor", "anchor_strength", "anchor_kl", "anchor_shield"), self.anchor)) if self.anchor else {}
        train_policy(self.experiment, self.algo, self.gamma, self.episodes, self.seed, parallel=self.parallel,
                     n_steps=self.horizon, progress=progress, out=self.out, command=self.command,
                     features=self.features, repair_penalty=self.repair_penalty, actions=self.actions,
                     cost_transform=self.cost_transform, resume=resume, **kw)
        return {str(self.out): {"command": self.command, "wall_time_s": time.perf_counter() - t0,
                                "cpu_time_s": time.process_time() - c0}}


#: The learned-gain architectures ``adaptfilt train-gain --arch`` knows: KalmanNet's architecture 2
#: (:mod:`adaptfilt.kalmannet`).
GAIN_ARCHS = ("kalmannet",)
#: KalmanNet's input scalings (:data:`adaptfilt.kalmannet.FEATURE_NORMS`, named here so that the command line
#: offers them without importing torch).
GAIN_FEATURE_NORMS = ("l2", "none", "scale")


@dataclass(frozen=True)
class GainSpec:
    """One learned-gain training: the arguments of ``adaptfilt train-gain`` (a :class:`Training`).

    A filter with a learned gain (``arch``, :data:`GAIN_ARCHS`) for ``experiment``'s model, trained on
    ``loss`` (``"supervised"``: the squared error against the true state; ``"unsupervised"``: the predicted
    measurement's) for ``epochs`` epochs from ``seed``, on ``train_runs`` training and ``val_runs`` validation
    trajectories of ``horizon`` steps (None: the model's), simulated from the model itself or, with ``truth``
    (:func:`adaptfilt.experiment_registry.parse_truth`, e.g. ``"q=4,r=1"``), from a truth that differs from it
    (the filter keeps the nominal model). ``snapshots``: the epochs at which the filter is kept, one file of
    ``outs`` each, in order (a snapshot is bit for bit the filter of a training that stopped there: one
    training serves a budget curve); None: one file, the trained filter. The rest is the recipe of
    :func:`adaptfilt.kalmannet.train_kalmannet`, written out in full in the command (no default of the
    library is relied on)."""

    experiment: str
    loss: str
    epochs: int
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

    def __post_init__(self):
        from adaptfilt.kalmannet import MODEL_GRADS

        if self.model_grad not in MODEL_GRADS:
            raise ValueError(f"unknown model_grad {self.model_grad!r}; known: {', '.join(MODEL_GRADS)}")
        if self.arch not in GAIN_ARCHS:
            raise ValueError(f"unknown learned-gain architecture {self.arch!r}; known: {', '.join(GAIN_ARCHS)}")
        n = 1 if self.snapshots is None else len(self.snapshots)
        if len(self.outs) != n:
            raise ValueError(f"{n} file{'s' if n > 1 else ''} to write (one per snapshot), "
                             f"got {len(self.outs)} --out: {', '.join(map(str, self.outs))}")

    @property
    def command(self) -> str:
        """The ``adaptfilt train-gain`` line that makes these files (every file of the training records it)."""
        snaps = "" if self.snapshots is None else " --snapshots " + ",".join(str(e) for e in self.snapshots)
        return (f"adaptfilt train-gain {self.experiment} --arch {self.arch} --loss {self.loss} "
                f"--epochs {self.epochs}{snaps} --seed {self.seed}" + _flag("truth", self.truth)
                + _flag("horizon", self.horizon) + f" --train-runs {self.train_runs} --val-runs {self.val_runs} "
                f"--batch-size {self.batch_size} --lr {_exact(self.lr)} --weight-decay {_exact(self.weight_decay)}"
                + ("" if self.clip is None else f" --clip {_exact(self.clip)}") + _flag("tbptt", self.tbptt)
                + f" --feature-norm {self.feature_norm} --on-diverged {self.on_diverged}"
                + f" --model-grad {self.model_grad}"
                + "".join(f" --out {o}" for o in self.outs))

    @property
    def key(self) -> tuple[str, int]:
        return self.command, self.seed

    @property
    def outputs(self) -> tuple[str, ...]:
        return tuple(str(o) for o in self.outs)

    def run(self, progress: bool = False) -> dict[str, dict]:
        """Train once, to ``epochs``, and write each snapshot (or the filter) to its file; per file its
        command and its training CPU-s up to it (the file's own ``history["cpu_s"]``)."""
        import numpy as np

        from adaptfilt.experiment_registry import get_experiment, parse_truth, scaled_truth
        from adaptfilt.kalmannet import train_kalmannet

        model = get_experiment(self.experiment).make_model()
        T = self.horizon or model.n_steps
        data = {}
        if self.truth is not None:  # the generators train_kalmannet draws its own trajectories from
            truth = scaled_truth(model, **parse_truth(self.truth))
            data = {"train": truth.simulate(self.train_runs, T, rng=np.random.default_rng([self.seed, 0])),
                    "val": truth.simulate(self.val_runs, T, rng=np.random.default_rng([self.seed, 1]))}
        knet = train_kalmannet(model, loss=self.loss, n_steps=T, epochs=self.epochs, seed=self.seed,
                               progress=progress, snapshots=self.snapshots or (), n_train=self.train_runs,
                               n_val=self.val_runs, batch_size=self.batch_size, lr=self.lr,
                               weight_decay=self.weight_decay, clip=self.clip, tbptt=self.tbptt,
                               feature_norm=self.feature_norm, on_diverged=self.on_diverged,
                               model_grad=self.model_grad, **data)
        filters = [knet] if self.snapshots is None else [knet.snapshot(e) for e in self.snapshots]
        out = {}
        for f, path in zip(filters, self.outputs):
            f.save(path)
            out[path] = {"command": self.command, "wall_time_s": None, "cpu_time_s": float(f.history["cpu_s"])}
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
