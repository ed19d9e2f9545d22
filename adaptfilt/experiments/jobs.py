r"""The pipeline's jobs, written once: what a training or an evaluation is, the command a manifest
records for it, the key the journal files it under, and the function a worker runs.

* :class:`TrainSpec`: one policy file. ``.command`` is the ``adaptfilt train ...`` line recorded in the
  file and in the manifest (``data/manifest.json``, ``data/beyond/manifest.json``; the tests rebuild each
  one byte for byte), ``.key`` the journal's ``(command, seed)``; :func:`train` runs it in a worker.
* :class:`EvalSpec`: one evaluation job of a study (a module-level function and its arguments), with its
  journal key; :func:`evaluate_spec` runs it, :func:`save_value` / :func:`load_value` keep its value.
* :func:`evaluate_command`: the ``adaptfilt evaluate ...`` line (``adaptfilt evaluate`` and the reproduction).
* :func:`load_learned`: a study's policy files as policies named after their files.

The functions run in worker processes (a local pool or Dask): they import what they need when called.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

from adaptfilt.files import sha256

__all__ = ["TrainSpec", "EvalSpec", "train", "evaluate_spec", "evaluate_command", "load_learned", "job_key",
           "save_value", "load_value", "take_times"]


@dataclass(frozen=True)
class TrainSpec:
    """One policy to train: the arguments of ``adaptfilt train`` that the pipeline uses.

    ``out`` is where the file is written; ``recorded_out`` what the command says instead (the reproduction
    records ``data/policies/...`` wherever it writes, so that its files are the same in any folder)."""

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
    anchor: tuple[str, float, float, float] | None = None  # (policy, strength, KL weight, shield)
    recorded_out: str | None = None

    @property
    def command(self) -> str:
        """The ``adaptfilt train`` line that makes this file; options in one fixed order, the defaults left out."""
        return (f"adaptfilt train {self.experiment} --algo {self.algo} --gamma {self.gamma:g} "
                f"--episodes {self.episodes} --seed {self.seed}"
                + (f" --features {self.features}" if self.features else "")
                + (f" --repair-penalty {self.repair_penalty:g}" if self.repair_penalty else "")
                + (f" --horizon {self.horizon}" if self.horizon else "")
                + (" --actions " + ",".join(f"{v:g}" for v in self.actions) if self.actions else "")
                + (f" --cost-transform {self.cost_transform}" if self.cost_transform != "log1p" else "")
                + (" --anchor {} --anchor-strength {:g} --anchor-kl {:g} --anchor-shield {:g}".format(*self.anchor)
                   if self.anchor else "")
                + f" --out {self.recorded_out or self.out}")

    @property
    def key(self) -> tuple[str, int]:
        """The journal's key of this job."""
        return self.command, self.seed


def train(spec: TrainSpec) -> dict:
    """Train ``spec`` into ``spec.out`` (a worker's job); returns its wall and CPU time and its command."""
    from adaptfilt.trainers import train_policy

    t0, c0 = time.perf_counter(), time.process_time()
    kw = dict(zip(("anchor", "anchor_strength", "anchor_kl", "anchor_shield"), spec.anchor)) if spec.anchor else {}
    train_policy(spec.experiment, spec.algo, spec.gamma, spec.episodes, spec.seed, n_steps=spec.horizon,
                 progress=False, out=spec.out, command=spec.command, features=spec.features,
                 repair_penalty=spec.repair_penalty, actions=spec.actions, cost_transform=spec.cost_transform, **kw)
    return {"wall_time_s": time.perf_counter() - t0, "cpu_time_s": time.process_time() - c0, "command": spec.command}


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
    """What identifies an evaluation job of ``adaptfilt beyond`` for the journal: its words, the policy
    files by their name and contents, a scale by its budgets."""
    def word(x) -> str:
        if hasattr(x, "retune_episodes"):
            return f"runs={x.eval_runs} steps={x.n_steps} episodes={x.episodes} retune={x.retune_episodes}"
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
