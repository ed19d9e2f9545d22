r"""Can the learner's network represent a rule's choice? Supervised imitation of maximum likelihood.

On the CTM, maximum likelihood (:class:`~adaptfilt.policies.MaxLikelihoodPolicy`, ML) costs less over
the run than greedy, the one-step optimum, and no learner trained by PPO gets near it. Before asking
whether the objective, the exploration or the budget stops the learner, this asks whether its actor
network *can* act as ML from what it sees: fit the actor by supervised learning to ML's choices and
measure how often it agrees with ML on states it was not fitted on, and what the fitted policy costs
when it acts.

**The data** (:func:`teacher_data`): ``runs`` trajectories of the experiment's environment driven by ML
(the states ML itself visits, from ``default_rng([seed, KEY])``, stream ``seed``), the raw information
state of each feature set asked for and ML's choice at every step. The runs are split, whole runs to one
side (a run's steps are correlated), into a fitting set and a held-out set (the last ``holdout`` of them).

**The fit** (:func:`imitate`): the learner's actor (:class:`~adaptfilt.learned.Actor`, two hidden layers
of 64 ReLU units, the PPO learners' policy network) on the learner's feature scaling
(:func:`~adaptfilt.features.fit_scaler` with the seed, what the Gymnasium adapter fits), cross-entropy of
its softmax against ML's choice, Adam, shuffled minibatches; the network of the epoch with the best
held-out accuracy is kept (early stopping on the held-out set: the accuracy reported is then an
optimistic estimate by at most the choice among ``epochs`` networks). The result is an ordinary
:class:`~adaptfilt.learned.LearnedPolicy` (not anchored: it acts from its features alone) whose metadata
records the accuracies; evaluated like any policy, its cost says what the agreement is worth.

The feature sets that matter (:mod:`adaptfilt.features`): the learners' own (``paper+circ``, and the
candidate-aware ``paper+circ+cand``, whose costs are greedy's inputs) and the same with the candidates'
log-likelihoods (``+lik``, what ML ranks: ML's choice is where that block is 0).

Example
-------
>>> from adaptfilt.imitation import imitate
>>> pol = imitate("ctm-ukf", "paper+circ+cand+lik", seed=0, runs=40, epochs=2, n_steps=10)
>>> pol.feature_set.name, 0.0 <= pol.metadata["imitation"]["heldout_accuracy"] <= 1.0
('paper+circ+cand+lik', True)
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["TEACHERS", "teacher_data", "imitate", "imitation_command"]

#: The rules a network can be fitted to: maximum likelihood (the CTM's better one-step rule) and greedy.
TEACHERS = ("ml", "greedy")
#: keys the imitation's trajectories apart from training, evaluation and distillation runs
_KEY = 0x1A17


def _teacher(name: str):
    from adaptfilt.policies import GreedyPolicy, MaxLikelihoodPolicy

    if name not in TEACHERS:
        raise ValueError(f"unknown teacher {name!r}; choose one of {', '.join(TEACHERS)}")
    return MaxLikelihoodPolicy() if name == "ml" else GreedyPolicy()


def teacher_data(experiment, features: Sequence[str], seed: int = 0, *, runs: int = 2000, teacher: str = "ml",
                 n_steps: int | None = None) -> dict:
    """The states the teacher visits and its choices: ``{"features": {set: (runs, T, d)}, "choice": (runs, T),
    "env", "experiment"}`` (module docstring). ``features``: the feature sets to record (the same states)."""
    from adaptfilt.experiment_registry import resolve
    from adaptfilt.features import FeatureSet, observe

    if not isinstance(runs, (int, np.integer)) or runs < 2:
        raise ValueError(f"runs must be an integer >= 2 (a fitting and a held-out part), got {runs!r}")
    sets = [FeatureSet.parse(f).name for f in features]
    pol = _teacher(teacher)
    target = resolve(experiment, seed=seed, n_steps=n_steps)
    env = target.env
    d = env.reset(n_runs=int(runs), rng=np.random.default_rng([seed, _KEY]), stream=seed)
    X: dict[str, list] = {f: [] for f in sets}
    a = []
    while d is not None:
        for f in sets:
            X[f].append(observe(d, f))
        a.append(pol.act(d))
        d, _, _, _ = env.step(a[-1])
    return {"features": {f: np.stack(v, axis=1) for f, v in X.items()}, "choice": np.stack(a, axis=1),
            "env": env, "experiment": target.name, "teacher": teacher}


def imitation_command(experiment: str, features: str, seed: int, *, runs: int, epochs: int, out: str,
                      teacher: str = "ml", n_steps: int | None = None, holdout: float = 0.2, lr: float = 1e-3,
                      batch_size: int = 1024) -> str:
    """The ``adaptfilt imitate`` line that makes an imitation policy (``out``), as a manifest records it."""
    return (f"adaptfilt imitate {experiment} --features {features} --seed {seed} --runs {runs} --epochs {epochs} "
            f"--teacher {teacher}" + ("" if n_steps is None else f" --horizon {n_steps}")
            + f" --holdout {holdout!r} --lr {lr!r} --batch-size {batch_size} --out {out}")


def imitate(experiment, features: str, seed: int = 0, *, runs: int = 2000, epochs: int = 30, teacher: str = "ml",
            n_steps: int | None = None, holdout: float = 0.2, lr: float = 1e-3, batch_size: int = 1024,
            data: dict | None = None, name: str | None = None, command: str | None = None):
    """Fit the learner's actor network to the teacher's choices from ``features`` (module docstring) and return
    it as a :class:`~adaptfilt.learned.LearnedPolicy`; ``metadata["imitation"]`` holds the fitting and
    held-out accuracy (per epoch too), the held-out cross-entropy, the runs and the teacher. Deterministic
    for a seed (data, initialisation, minibatches; one torch thread). ``data``: :func:`teacher_data`'s, to fit
    several feature sets on the same states."""
    import torch

    from adaptfilt._version import __version__
    from adaptfilt.features import FeatureSet, fit_scaler
    from adaptfilt.learned import Actor, LearnedPolicy, one_torch_thread

    for k, v, lo in (("epochs", epochs, 1), ("batch_size", batch_size, 1)):
        if not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{k} must be an integer >= {lo}, got {v!r}")
    if not (0.0 < holdout < 1.0):
        raise ValueError(f"holdout must be a fraction in (0, 1), got {holdout!r}")
    if not (np.isfinite(lr) and lr > 0):
        raise ValueError(f"lr must be finite and > 0, got {lr!r}")
    fs = FeatureSet.parse(features).name
    data = data or teacher_data(experiment, [fs], seed, runs=runs, teacher=teacher, n_steps=n_steps)
    if fs not in data["features"]:
        raise ValueError(f"the data hold the feature sets {sorted(data['features'])}, not {fs!r}")
    env = data["env"]
    X3, y2 = data["features"][fs], data["choice"]
    R = X3.shape[0]
    n_out = max(1, int(round(holdout * R)))
    if n_out >= R:
        raise ValueError(f"{R} runs leave none to fit on with holdout={holdout:g}")
    G = env.grid.size
    scaler = fit_scaler(env, fs, seed=seed)  # as the Gymnasium adapter fits it for the same seed
    Xfit = torch.from_numpy(scaler.network_input(X3[: R - n_out].reshape(-1, X3.shape[-1])))
    yfit = torch.from_numpy(y2[: R - n_out].reshape(-1).astype(np.int64))
    Xout = torch.from_numpy(scaler.network_input(X3[R - n_out:].reshape(-1, X3.shape[-1])))
    yout = torch.from_numpy(y2[R - n_out:].reshape(-1).astype(np.int64))
    N = Xfit.shape[0]
    hist = {"fit_accuracy": [], "heldout_accuracy": [], "heldout_xent": []}
    with one_torch_thread(), torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        actor = Actor(Xfit.shape[1], G)
        opt = torch.optim.Adam(actor.parameters(), lr=lr)
        gen = torch.Generator().manual_seed(seed)
        xent = torch.nn.CrossEntropyLoss()
        best, best_state = -1.0, None
        for _ in range(int(epochs)):
            perm = torch.randperm(N, generator=gen)
            for lo in range(0, N, int(batch_size)):
                i = perm[lo:lo + int(batch_size)]
                loss = xent(actor(Xfit[i]), yfit[i])
                opt.zero_grad()
                loss.backward()
                opt.step()
            with torch.no_grad():
                out = actor(Xout)
                acc = float((out.argmax(dim=1) == yout).double().mean())
                hist["heldout_accuracy"].append(acc)
                hist["heldout_xent"].append(float(xent(out, yout)))
                hist["fit_accuracy"].append(float((actor(Xfit).argmax(dim=1) == yfit).double().mean()))
            if acc > best:
                best, best_state = acc, {k: v.clone() for k, v in actor.state_dict().items()}
        actor.load_state_dict(best_state)
    k = int(np.argmax(hist["heldout_accuracy"]))
    info = {"teacher": teacher, "runs": int(R), "heldout_runs": int(n_out), "epochs": int(epochs), "best_epoch": k + 1,
            "fit_accuracy": hist["fit_accuracy"][k], "heldout_accuracy": hist["heldout_accuracy"][k],
            "heldout_xent": hist["heldout_xent"][k], "lr": float(lr), "batch_size": int(batch_size),
            # how often the teacher's choice is the commonest one: what a constant would score
            "majority_accuracy": float(np.bincount(y2[R - n_out:].ravel(), minlength=G).max() / y2[R - n_out:].size)}
    meta = {**env.describe(fs), "experiment": data["experiment"], "feature_set": fs, "algo": "imitation",
            "seed": int(seed), "n_steps": int(env.n_steps), "imitation": info, "command": command,
            "version": __version__, "torch_version": torch.__version__.split("+")[0]}
    return LearnedPolicy(actor, scaler, env.grid, gamma=0.0, name=name or f"imitation-{teacher}", metadata=meta,
                         curve={k2: np.asarray(v) for k2, v in hist.items()})
