"""The ``adaptfilt`` console command.

Sub-commands (their names and flags are a contract the course, the README and
``data/manifest.json`` rely on)::

    adaptfilt experiments
    adaptfilt evaluate NAME --runs M --seed S --out DIR [--policy FILE ...] [--horizon T] [--chunk-size C]
    adaptfilt train NAME [--algo faithful|batched|fast|a2c|ppo] [--gamma G] [--episodes N] [--snapshots E1,E2,...]
                         [--parallel B] [--seed S | --seeds 0-7] [--features SPEC] [--horizon T] [--lr LR]
                         [--n-epochs K] [--truth q=4,r=1|forcing=10] [--anchor greedy|ml [--anchor-strength C]
                         [--anchor-kl BETA] [--anchor-shield D]] --out FILE [--out FILE ...] [--resume]
                         [--workers N] [--cluster ADDRESS]
    adaptfilt train-gain NAME [--arch kalmannet|kalmannet-arch1] [--hidden-mult M] [--loss supervised|unsupervised]
                         [--epochs N [--snapshots E1,E2,...] | --steps S [--snapshot-steps S1,S2,...]] [--seed S]
                         [--truth q=4,r=1|forcing=10] [--horizon T] [--train-runs N] [--val-runs N] [--batch-size B]
                         [--fresh batch|epoch] [--val-every K] [--lr LR] [--weight-decay W] [--clip C] [--tbptt L]
                         [--feature-norm l2|none|scale] [--clamp auto]
                         [--on-diverged raise|restore|stop|restart [--restarts N] [--patience P]] [--collapse-after K]
                         [--model-grad jacobian|finite-difference|detach] --out FILE [--out FILE ...]
    adaptfilt imitate NAME --features SPEC [--seed S] [--runs M] [--epochs N] [--teacher ml|greedy] [--horizon T]
                      [--holdout F] [--lr LR] [--batch-size B] --out FILE
    adaptfilt floor --runs M --seed S [--horizon T] [--eval-runs M] --out FILE
    adaptfilt reconcile --runs M --seed S [--horizon T] --out FILE
    adaptfilt reproduce --out DIR [--scale quick|medium|full] [--retrain] [--faithful] [--workers N] [--cluster ADDRESS]
                        [--data DIR]
    adaptfilt reproduce --out DIR --report-only [--data DIR]
    adaptfilt beyond --out DIR [--quick] [--studies cand,sif,ood,raw,anchor,look,particles,gain,mlanchor] [--workers N]
                     [--cluster ADDRESS] [--data DIR]
    adaptfilt beyond --out DIR --report-only
    adaptfilt book --out DIR
    adaptfilt --version

``train-gain`` trains a filter with a learned gain (KalmanNet); ``imitate`` fits the learner's actor network
to a teacher rule's choices by supervised learning (:mod:`adaptfilt.imitation`); ``floor`` and ``reconcile`` are the
reproduction's reference stages of those names (the point-mass Bayes floor on UNGM, the CTM variants), each
writing the JSON that ``adaptfilt reproduce`` writes into ``DIR/results``.

Each sub-command is a thin wrapper: the work lives in the module named in its
handler, so that a notebook can call the same function directly.

Errors: every user error -- a bad flag value (checked by the ``type=``
functions below before any work starts), an unknown experiment, an --out that
cannot be written, a missing, damaged or mismatched policy file, no stored
artefacts, a book built outside the checkout, an unreachable --cluster, a job
that fails with such an error or loses its worker, or any ``ValueError`` /
``KeyError`` / ``OSError`` / ``ImportError`` the library raises -- prints one
line ``adaptfilt: error: ...`` on stderr and exits with status 2. Any other
exception is a bug and keeps its traceback.

Interrupts: Ctrl-C (SIGINT) or SIGTERM stops a command (its workers too) and prints one line
``adaptfilt: interrupted: ...`` saying what was kept and how to resume; the exit status is 130 (SIGINT)
or 143 (SIGTERM). The exit is bounded whatever the command was doing (starting its workers or a Dask
cluster, running jobs, closing): within 10 s of the signal in this process or on the local pool, within
20 s with ``--cluster`` (a local or remote Dask cluster), measured from the signal to the end of the
process (:data:`adaptfilt.experiments.sweep.STOP_SECONDS` and ``STOP_SECONDS_DASK``). A watchdog
guarantees it: 2 s before the bound it ends the process (``os._exit``, same status) whatever still
hangs, after the line, or with a line saying the stop was cut short. A second Ctrl-C or SIGTERM while
stopping ends the process at once (130 or 143). A SIGTERM in the second or so before the handlers are
installed (imports, argument parsing) ends the process at once by its default action.
``reproduce``, ``beyond`` and ``train --seeds`` resume: the same command again
reuses every job that finished (:mod:`adaptfilt.experiments.journal`).
"""
from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import NoReturn


def _experiments(args: argparse.Namespace) -> int:
    from adaptfilt.experiment_registry import describe_experiments

    print(describe_experiments())
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from adaptfilt.experiments.evaluate import evaluate_experiment

    evaluate_experiment(
        args.name,
        n_runs=args.runs,
        seed=args.seed,
        out_dir=Path(args.out),
        policy_files=[Path(p) for p in args.policy],
        progress=not args.no_progress,
        n_steps=args.horizon,
        **({} if args.chunk_size is None else {"chunk_size": args.chunk_size}),
    )
    return 0


def _train_spec(args: argparse.Namespace, seed: int, out: str):
    """The training ``adaptfilt train`` runs for ``seed`` into ``out``: its command line (recorded in the file)
    is :attr:`~adaptfilt.experiments.jobs.TrainSpec.command`, the one author of it."""
    from adaptfilt.experiments.jobs import TrainSpec

    anchor = None if args.anchor is None else (args.anchor, args.anchor_strength, args.anchor_kl, args.anchor_shield)
    return TrainSpec(args.name, args.gamma, args.episodes, seed, out, algo=args.algo, features=args.features,
                     repair_penalty=args.repair_penalty, horizon=args.horizon, actions=args.actions,
                     cost_transform=args.cost_transform, anchor=anchor, parallel=args.parallel, lr=args.lr,
                     n_epochs=args.n_epochs, truth=args.truth, snapshots=args.snapshots)


def train_job(args: argparse.Namespace, seed: int, out: str) -> str:
    """One training of ``adaptfilt train`` (module level: it may run in a worker process)."""
    _train_spec(args, seed, out).run(progress=not args.no_progress, resume=args.resume)
    return out


def _train(args: argparse.Namespace) -> int:
    if args.anchor is None and any(v is not None for v in (args.anchor_strength, args.anchor_kl, args.anchor_shield)):
        raise ValueError("--anchor-strength, --anchor-kl and --anchor-shield set the anchor: give --anchor greedy (or ml) too")
    if args.anchor is not None and args.algo not in ("fast", "a2c", "ppo"):
        raise ValueError(f"--anchor needs an SB3 trainer (--algo fast, a2c or ppo), not {args.algo}")
    if args.snapshots is not None:  # one file per snapshot, written by one training
        if args.seeds is not None or args.resume:
            raise ValueError("--snapshots writes the files of one training: not with --seeds or --resume")
        spec = _train_spec(args, args.seed, tuple(args.out))
        spec.run(progress=not args.no_progress)
        print("wrote " + ", ".join(spec.outputs))
        return 0
    if len(args.out) != 1:
        raise ValueError(f"{len(args.out)} --out for one policy: several only with --snapshots, one each")
    args.out = args.out[0]
    if args.seeds is None:
        try:
            train_job(args, args.seed, args.out)
        except KeyboardInterrupt as e:
            raise _checkpoint_kept(e, args.out) from None
        print(f"wrote {args.out}")
        return 0
    from adaptfilt.experiments.journal import Journal
    from adaptfilt.trainers import seed_path

    progress = not args.no_progress
    args.no_progress = True  # one bar over the seeds instead of one per training
    outs = [str(seed_path(args.out, s)) for s in args.seeds]
    journal = Journal(_seeds_journal(args.out))
    keys = [_train_spec(args, s, o).key for s, o in zip(args.seeds, outs)]
    resumed = journal.count(keys)
    if resumed:
        print(f"{resumed} of {len(keys)} seeds finished by an earlier run ({journal.path}): reused", flush=True)
    journal.run(train_job, [(args, s, o) for s, o in zip(args.seeds, outs)], keys, files=[[o] for o in outs],
                workers=args.workers, cluster=args.cluster, progress=progress,
                desc=f"train {args.name} ({args.algo}, {len(outs)} seeds)")
    journal.finish()
    print("wrote " + ", ".join(outs))
    return 0


def _seeds_journal(out: str | Path) -> Path:
    """``train --seeds --out DIR/p.npz``: the journal of its finished seeds, ``DIR/p.journal.jsonl``."""
    out = Path(out)
    return out.with_name(out.name.removesuffix(".npz") + ".journal.jsonl")


def _checkpoint_kept(e: KeyboardInterrupt, out: str) -> KeyboardInterrupt:
    """One training stopped: the checkpoint it leaves (faithful and batched write one), if any."""
    from adaptfilt.actor_critic import checkpoint_path
    from adaptfilt.experiments.sweep import Interrupted

    ckpt = checkpoint_path(out)
    kept = (f"the checkpoint {ckpt} is kept; add --resume to the same command to continue from it"
            if ckpt.exists() else "nothing was written")
    return Interrupted(kept=kept, signum=getattr(e, "signum", signal.SIGINT))


@contextlib.contextmanager
def _resumable(journal: Path):
    """An interrupt outside the jobs (between stages) says what the run's journal keeps, as one inside does."""
    try:
        yield
    except KeyboardInterrupt as e:
        if getattr(e, "kept", ""):
            raise
        from adaptfilt.experiments.journal import Journal

        raise Journal(journal).interrupted(e) from None


def _reproduce(args: argparse.Namespace) -> int:
    from adaptfilt.experiments.reproduce import JOURNAL, reproduce

    if args.quick and args.scale not in (None, "quick"):
        raise ValueError(f"--quick and --scale {args.scale}: give one of them")
    if args.report_only:
        from adaptfilt.experiments.reproduce import report_only

        other = [f for f, on in (("--quick", args.quick), ("--scale", args.scale), ("--retrain", args.retrain),
                                 ("--faithful", args.faithful)) if on]
        if other:
            raise ValueError(f"--report-only trains and evaluates nothing: drop {' and '.join(other)}")
        report_only(Path(args.out), data=args.data, progress=not args.no_progress)
        return 0
    with _resumable(Path(args.out) / JOURNAL):
        reproduce(out_dir=Path(args.out), quick=args.quick, scale=args.scale, retrain=args.retrain,
                  progress=not args.no_progress, faithful=args.faithful, workers=args.workers, cluster=args.cluster,
                  data=args.data)
    return 0


def _beyond(args: argparse.Namespace) -> int:
    from adaptfilt.experiments.beyond import JOURNAL, report_only, run, summary_md

    if args.report_only:
        if args.quick:
            raise ValueError("--report-only trains and evaluates nothing: drop --quick")
        report_only(Path(args.out), progress=not args.no_progress)
        return 0
    with _resumable(Path(args.out) / "beyond" / JOURNAL):
        summary = run(Path(args.out), quick=args.quick, workers=args.workers, cluster=args.cluster,
                      studies=tuple(args.studies.split(",")), progress=not args.no_progress, data=args.data)
    text = summary_md(summary)
    from adaptfilt.files import atomic_write

    atomic_write(Path(args.out) / "beyond" / "summary.md", text)
    print(text)
    return 0


def gain_spec(args: argparse.Namespace):
    """The training ``adaptfilt train-gain`` runs: its command line (recorded in every file) is
    :attr:`~adaptfilt.experiments.jobs.GainSpec.command`, the one author of it."""
    from adaptfilt.experiments.jobs import GainSpec

    epochs = args.epochs if args.epochs is not None or args.steps is not None else 30
    return GainSpec(args.name, args.loss, epochs, args.seed, tuple(args.out), snapshots=args.snapshots,
                    arch=args.arch, truth=args.truth, horizon=args.horizon, train_runs=args.train_runs,
                    val_runs=args.val_runs, batch_size=args.batch_size, lr=args.lr, weight_decay=args.weight_decay,
                    clip=args.clip, tbptt=args.tbptt, feature_norm=args.feature_norm, on_diverged=args.on_diverged,
                    model_grad=args.model_grad, steps=args.steps, snapshot_steps=args.snapshot_steps,
                    hidden_mult=args.hidden_mult, fresh=args.fresh, val_every=args.val_every, clamp=args.clamp,
                    restarts=args.restarts, patience=args.patience, collapse_after=args.collapse_after)


def _train_gain(args: argparse.Namespace) -> int:
    from adaptfilt.experiments.sweep import Interrupted

    spec = gain_spec(args)
    try:
        spec.run(progress=not args.no_progress)
    except KeyboardInterrupt as e:
        kept = (f"the checkpoint {spec.checkpoint} is kept; run the same command again to continue from it"
                if spec.checkpoint.exists() else "nothing was written")
        raise Interrupted(kept=kept, signum=getattr(e, "signum", signal.SIGINT)) from None
    print("wrote " + ", ".join(spec.outputs))
    return 0


def _reference(args: argparse.Namespace) -> int:
    """``adaptfilt floor`` / ``adaptfilt reconcile``: the JSON the reproduction's stage of that name writes."""
    import json

    from adaptfilt.experiments.references import ctm_reconciliation, ungm_floor
    from adaptfilt.files import atomic_write

    if args.cmd == "floor":
        print(f"the point-mass filter on {args.runs} runs of UNGM (minutes at the full horizon) ...", flush=True)
        value = ungm_floor(args.runs, args.seed, args.horizon, eval_runs=args.eval_runs)
    else:
        value = ctm_reconciliation(args.runs, args.seed, args.horizon)
    atomic_write(Path(args.out), json.dumps(value, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


def _values(text: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, e.g. 5,7,10; got {text!r}") from None
    if not all(math.isfinite(v) for v in vals):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return vals


def _studies(text: str) -> str:
    from adaptfilt.experiments.beyond import STUDIES

    bad = [s for s in text.split(",") if s not in STUDIES]
    if bad or not text:
        raise argparse.ArgumentTypeError(f"studies are a comma-separated subset of {','.join(STUDIES)}; got {text!r}")
    return text


def _book(args: argparse.Namespace) -> int:
    from adaptfilt.course.book import build_book

    index = build_book(out_dir=Path(args.out))
    print(f"book built: open {index}")
    return 0


# --------------------------------------------------------------- validation
# argparse calls these on the raw text; an ArgumentTypeError becomes
# "adaptfilt: error: argument --runs: <message>" before any work starts.

def _int_at_least(lo: int, why: str = ""):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < lo:
            raise argparse.ArgumentTypeError(f"must be an integer >= {lo}{why}, got {value}")
        return value

    parse.__name__ = f"integer >= {lo}"
    return parse


def _float_in(lo: float, hi: float = math.inf, closed: bool = True, name: str | None = None):
    """A parser (argparse ``type=``) of a finite number in ``[lo, hi)`` (``closed``) or ``(lo, hi)``; NaN is
    never in. Its error says "must be a finite number >= 0", or "<name> must be in [0, 1)" when named."""
    bounds = f"{'>=' if closed else '>'} {lo:g}" if hi == math.inf else f"in {'[' if closed else '('}{lo:g}, {hi:g})"
    rule = f"{name} must be {bounds}" if name else f"must be a finite number {bounds}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not ((value >= lo if closed else value > lo) and value < hi):  # also rejects nan
            raise argparse.ArgumentTypeError(f"{rule}, got {text}")
        return value

    parse.__name__ = f"number {bounds}"
    return parse


_nonnegative = _float_in(0.0)
_positive = _float_in(0.0, closed=False)
_gamma = _float_in(0.0, 1.0, name="the discount gamma")


def _counts(what: str):
    """A parser of ``"400,1200,3600"`` -> (400, 1200, 3600): increasing counts >= 1 of ``what``."""
    def parse(text: str) -> tuple[int, ...]:
        try:
            vals = tuple(int(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}, e.g. 400,1200; got {text!r}") from None
        if min(vals) < 1 or list(vals) != sorted(set(vals)):
            raise argparse.ArgumentTypeError(f"expected increasing {what} >= 1, e.g. 400,1200; got {text!r}")
        return vals

    parse.__name__ = what
    return parse


#: ``"3,8,25"`` -> (3, 8, 25): increasing epoch counts >= 1.
_epochs = _counts("epochs")


def _truth(text: str) -> str:
    """A truth that differs from the model (``q=4``, ``q=1,r=0.25``, ``forcing=10``), in its one written form
    (``q=4,r=1``)."""
    from adaptfilt.experiment_registry import parse_truth, truth_words

    try:
        return truth_words(**parse_truth(text))
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _seeds(text: str) -> list[int]:
    """``"8"`` -> 0..7; ``"0-7"``, ``"3,5,9"``, ``"0-3,10"`` -> those seeds."""
    try:
        if text.isdigit():
            n = int(text)
            if n < 1:
                raise ValueError
            return list(range(n))
        seeds: list[int] = []
        for part in text.split(","):
            lo, _, hi = part.partition("-")
            a, b = int(lo), int(hi) if hi else int(lo)
            if a < 0 or b < a:
                raise ValueError
            seeds += range(a, b + 1)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a count (8) or seeds like 0-7 or 0,3,5; got {text!r}") from None
    if len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"seed given twice in {text!r}")
    return seeds


def _features(text: str) -> str:
    from adaptfilt.features import FeatureSet

    try:
        return FeatureSet.parse(text).name
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _experiment(text: str) -> str:
    from adaptfilt.experiment_registry import get_experiment

    try:
        get_experiment(text)
    except KeyError as e:
        raise argparse.ArgumentTypeError(e.args[0]) from None
    return text


def _existing_file(text: str) -> str:
    path = Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: not a file")
    return text


def _writable_parent(path: Path, text: str) -> None:
    """The nearest existing ancestor of ``path`` must be a folder we may write into."""
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: cannot be created, {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"{text}: cannot be written, no write permission in {parent}")


def _out_dir(text: str) -> str:
    path = Path(text)
    if path.exists():
        if not path.is_dir():
            raise argparse.ArgumentTypeError(f"{text}: exists and is not a folder")
        if not os.access(path, os.W_OK | os.X_OK):
            raise argparse.ArgumentTypeError(f"{text}: cannot be written, no write permission")
    else:
        _writable_parent(path, text)
    return text


def _out_file(text: str) -> str:
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a folder, expected a file name")
    _writable_parent(path, text)
    return text


class _Parser(argparse.ArgumentParser):
    """Every usage error is one line ``adaptfilt: error: ...`` and exit status 2,
    sub-commands included (argparse would print the usage and ``adaptfilt evaluate: error:``)."""

    def error(self, message: str) -> NoReturn:
        _fail(f"{message} (see `{self.prog} --help`)")


def _fail(message: str) -> NoReturn:
    sys.stderr.write(f"adaptfilt: error: {' '.join(str(message).split())}\n")
    raise SystemExit(2)


def _user_message(e: BaseException) -> str:
    """One line for a user-facing library error."""
    if isinstance(e, OSError) and e.filename is not None and e.strerror:
        return f"{e.filename}: {e.strerror}"
    if isinstance(e, KeyError) and len(e.args) == 1 and isinstance(e.args[0], str):
        return e.args[0]  # str(KeyError) would add quotes
    return str(e) or type(e).__name__


def build_parser() -> argparse.ArgumentParser:
    """The ``adaptfilt`` command's parser: one ``_add_<command>`` per sub-command."""
    from adaptfilt._version import __version__

    parser = _Parser(
        prog="adaptfilt",
        description="Learning adaptive parameter policies for nonlinear Bayesian filters.",
    )
    parser.add_argument("--version", action="version", version=f"adaptfilt {__version__}")
    sub = parser.add_subparsers(dest="cmd", required=True)
    for add in (_add_experiments, _add_evaluate, _add_train, _add_train_gain, _add_imitate, _add_floor,
                _add_reconcile, _add_reproduce, _add_beyond, _add_book):
        add(sub)
    return parser


def _add_experiments(sub) -> None:
    p = sub.add_parser("experiments", help="list the named experiments of the paper")
    p.set_defaults(func=_experiments)


def _add_evaluate(sub) -> None:
    p = sub.add_parser("evaluate", help="evaluate every baseline (and learned policies) of an experiment")
    p.add_argument("name", type=_experiment, help="experiment name, see `adaptfilt experiments`")
    p.add_argument("--runs", type=_int_at_least(2, " (the bootstrap needs two runs)"), default=10_000,
                   help="Monte-Carlo runs (default 10^4)")
    p.add_argument("--seed", type=_int_at_least(0), default=0)
    p.add_argument("--out", required=True, type=_out_dir, help="output directory")
    p.add_argument("--policy", action="append", default=[], type=_existing_file,
                   help="a learned policy file (repeatable); its result is named after the file; files "
                        "NAME-s0.npz, NAME-s1.npz ... are one policy trained on several seeds")
    p.add_argument("--horizon", type=_int_at_least(1), default=None, help="time steps (default: the model's)")
    p.add_argument("--chunk-size", type=_int_at_least(1), default=None,
                   help="runs filtered at a time (default 10^4): memory stays flat in --runs; up to it the "
                        "evaluation is one pass, beyond it a stochastic filter's draws depend on it")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_evaluate)


def _add_train(sub) -> None:
    from adaptfilt.trainers import ALGOS

    p = sub.add_parser("train", help="train a policy (Algorithm 2's loop with the library's recipe, or the fast mode)")
    p.add_argument("name", type=_experiment, help="experiment name, see `adaptfilt experiments`")
    p.add_argument("--algo", choices=ALGOS, default="faithful",
                   help="faithful: Algorithm 2, one episode at a time (the reference, minutes); batched: the "
                        "same, --parallel episodes per update; fast: the fast mode (Stable-Baselines3 PPO with large "
                        "batches, seconds); a2c: the first fast mode (SB3 A2C); ppo: SB3 PPO with its defaults")
    p.add_argument("--gamma", type=_gamma, default=0.5, help="discount factor in [0, 1) (0 = myopic)")
    p.add_argument("--episodes", type=_int_at_least(1), default=1000,
                   help="training budget N_MC in episodes of T steps (default 1000)")
    p.add_argument("--snapshots", type=_counts("episode counts"), default=None,
                   help="episode counts at which to keep the policy, e.g. 400,1200,3600, one --out each (a snapshot "
                        "is bit for bit the policy of a training of that many episodes; fast/a2c/ppo only)")
    p.add_argument("--parallel", type=_int_at_least(1), default=None,
                   help="batched: episodes per update (default 50); fast/a2c/ppo: runs per batch (default 256/64/16)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--seed", type=_int_at_least(0), default=0)
    g.add_argument("--seeds", type=_seeds, default=None,
                   help="train one policy per seed (8 = 0-7, or 0-7, or 0,3,5) into OUT-s{seed}.npz, in parallel")
    p.add_argument("--features", type=_features, default=None,
                   help="information state, e.g. paper, paper+time, paper+circ (default: the experiment's)")
    p.add_argument("--horizon", type=_int_at_least(1), default=None, help="time steps (default: the model's)")
    p.add_argument("--repair-penalty", type=_nonnegative, default=0.0,
                   help="added to the learner's cost of a run whose covariance was repaired (default 0)")
    p.add_argument("--actions", type=_values, default=None,
                   help="the grid values the policy may choose, e.g. 5,7,10,15,20,30 (a safe subset of the "
                        "experiment's grid holding its default; fast/a2c/ppo only)")
    p.add_argument("--cost-transform", choices=("log1p", "none"), default="log1p",
                   help="reward -log(1 + L) (default, the paper's) or -L (none: the mean cost itself)")
    p.add_argument("--lr", type=_positive, default=None,
                   help="the SB3 learner's learning rate (default: the mode's; fast: 0.002)")
    p.add_argument("--n-epochs", type=_int_at_least(1), default=None,
                   help="PPO's epochs per rollout (default: the mode's; fast: 5)")
    p.add_argument("--truth", type=_truth, default=None,
                   help="train on episodes of a truth that differs from the model, e.g. q=4 (process noise Q x 4) "
                        "or forcing=10 (UNGM's forcing amplitude); the filter keeps the nominal model "
                        "(fast/a2c/ppo only)")
    from adaptfilt.anchor import ANCHORS, DEFAULT_KL, DEFAULT_STRENGTH

    p.add_argument("--anchor", choices=ANCHORS, default=None,
                   help="a residual policy over greedy's (or ML's) choice that acts as that rule before training "
                        "(adaptfilt.anchor; fast/a2c/ppo only)")
    p.add_argument("--anchor-strength", type=_positive, default=None,
                   help=f"logit added to the anchor's choice (default {DEFAULT_STRENGTH:g}; needs --anchor)")
    p.add_argument("--anchor-kl", type=_nonnegative, default=None,
                   help=f"weight of KL(pi || the anchor's prior) in the loss (default {DEFAULT_KL:g}; needs --anchor)")
    p.add_argument("--anchor-shield", type=_nonnegative, default=None,
                   help="never choose a value whose one-step log(1 + L) exceeds greedy's by more than this "
                        "(default 1; 0: no shield; needs --anchor)")
    p.add_argument("--out", required=True, action="append", type=_out_file,
                   help="policy file to write (one per snapshot, in their order, with --snapshots)")
    p.add_argument("--resume", action="store_true", help="continue from the checkpoint next to --out")
    p.add_argument("--workers", type=_int_at_least(1), default=None,
                   help="local processes for --seeds (default: every core)")
    p.add_argument("--cluster", default=None, help="run --seeds on a Dask cluster (scheduler address)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_train)


def _add_train_gain(sub) -> None:
    from adaptfilt.experiments.jobs import GAIN_ARCHS, GAIN_FEATURE_NORMS, GAIN_ON_DIVERGED, GainSpec
    from adaptfilt.kalmannet import CHECKPOINT_EVERY_S, MODEL_GRADS

    d = GainSpec.__dataclass_fields__
    p = sub.add_parser("train-gain", help="train a filter with a learned gain (KalmanNet) on simulated trajectories",
                       description="Train a filter whose gain is learned (KalmanNet's architecture 2, "
                                   "adaptfilt.kalmannet) on trajectories of an experiment's model; every option "
                                   "is recorded in the command line each file keeps. While it runs the training "
                                   f"keeps a checkpoint beside its last --out (OUT.ckpt.npz, every "
                                   f"{CHECKPOINT_EVERY_S:g} s): the "
                                   "same command after an interruption resumes from it, bit for bit the training "
                                   "that was never stopped.")
    p.add_argument("name", type=_experiment, help="experiment name (its model), see `adaptfilt experiments`")
    p.add_argument("--arch", choices=tuple(GAIN_ARCHS), default=d["arch"].default,
                   help="the learned-gain architecture: kalmannet (KalmanNet's architecture 2, the default) or "
                        "kalmannet-arch1 (architecture 1)")
    p.add_argument("--hidden-mult", type=_int_at_least(1), default=None,
                   help="architecture 2: width multiplier of its GRUs and FC2's hidden layer (default: the paper's "
                        "widths)")
    p.add_argument("--loss", choices=("supervised", "unsupervised"), default="supervised",
                   help="supervised: squared error against the true state (default); unsupervised: squared error "
                        "of the predicted measurement (needs no true state)")
    budget = p.add_mutually_exclusive_group()
    budget.add_argument("--epochs", type=_int_at_least(1), default=None,
                        help="passes over the training set (default 30)")
    budget.add_argument("--steps", type=_int_at_least(1), default=None,
                        help="a budget in optimiser steps instead of epochs (all attempts together)")
    snaps = p.add_mutually_exclusive_group()
    snaps.add_argument("--snapshots", type=_epochs, default=None,
                       help="epochs at which to keep the filter, e.g. 3,8,25, one --out each (a snapshot is bit for "
                            "bit the filter of a training that stopped there; default: the trained filter only)")
    snaps.add_argument("--snapshot-steps", type=_counts("optimiser steps"), default=None,
                       help="optimiser steps (multiples of --val-every, up to --steps) at which to keep the filter, "
                            "one --out each")
    p.add_argument("--seed", type=_int_at_least(0), default=0,
                   help="weights, minibatch order and the trajectories (default 0)")
    p.add_argument("--truth", type=_truth, default=None,
                   help="train on trajectories of a truth that differs from the model, e.g. q=4 (process noise Q "
                        "x 4) or q=1,r=0.25; the filter keeps the nominal model (default: the model itself)")
    p.add_argument("--horizon", type=_int_at_least(1), default=None, help="time steps (default: the model's)")
    p.add_argument("--train-runs", type=_int_at_least(1), default=d["train_runs"].default,
                   help=f"training trajectories (default {d['train_runs'].default})")
    p.add_argument("--val-runs", type=_int_at_least(1), default=d["val_runs"].default,
                   help=f"validation trajectories, the best filter on them kept (default {d['val_runs'].default})")
    p.add_argument("--batch-size", type=_int_at_least(1), default=d["batch_size"].default,
                   help=f"trajectories per optimiser step (default {d['batch_size'].default})")
    p.add_argument("--fresh", choices=("batch", "epoch"), default=None,
                   help="draw new training trajectories every minibatch or every epoch (default: one fixed set)")
    p.add_argument("--val-every", type=_int_at_least(1), default=None,
                   help="validate every K optimiser steps (default: once per epoch)")
    p.add_argument("--lr", type=_positive, default=d["lr"].default, help=f"Adam's learning rate (default {d['lr'].default:g})")
    p.add_argument("--weight-decay", type=_nonnegative, default=d["weight_decay"].default,
                   help=f"Adam's weight decay (default {d['weight_decay'].default:g})")
    p.add_argument("--clip", type=_positive, default=None, help="clip the gradient's norm at this (default: no clip)")
    p.add_argument("--tbptt", type=_int_at_least(1), default=None,
                   help="truncated back-propagation through time: windows of this many steps (default: whole runs)")
    p.add_argument("--feature-norm", choices=GAIN_FEATURE_NORMS, default=d["feature_norm"].default,
                   help=f"scaling of the network's inputs (default {d['feature_norm'].default})")
    p.add_argument("--clamp", choices=("auto",), default=None,
                   help="auto: clamp the state estimate to the model's range widened by a quarter (default: none)")
    p.add_argument("--on-diverged", choices=GAIN_ON_DIVERGED, default=d["on_diverged"].default,
                   help="a non-finite loss: raise (default), restore the best weights at half the learning rate, "
                        "or that and stop after 5 such restores, keeping the best weights; restart: the restart "
                        "rule (adaptfilt.kalmannet), with --restarts and --patience")
    p.add_argument("--restarts", type=_int_at_least(0), default=0,
                   help="the restart rule: at most this many restarts from new weights (default 0)")
    p.add_argument("--patience", type=_int_at_least(1), default=None,
                   help="the restart rule: abandon an attempt none of whose validations in its first P optimiser "
                        "steps beats its initial network (default: only divergence abandons)")
    p.add_argument("--collapse-after", type=_int_at_least(1), default=None,
                   help="count a finite validation loss above the untrained network's for K validations in a row, "
                        "after beating it, as a divergence (--on-diverged decides what it does; default: only "
                        "non-finite losses diverge)")
    p.add_argument("--model-grad", choices=MODEL_GRADS, default=d["model_grad"].default,
                   help="how the loss's gradient passes through f and h: jacobian (the model's torch forms, "
                        f"default {d['model_grad'].default}), finite-difference (the numpy path with "
                        "finite-difference Jacobians: the files the gain study stored before the torch forms), "
                        "or detach")
    p.add_argument("--out", required=True, action="append", type=_out_file,
                   help="file to write (.npz); one per snapshot, in their order, with --snapshots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_train_gain)


def _add_imitate(sub) -> None:
    from adaptfilt.imitation import TEACHERS

    p = sub.add_parser("imitate", help="fit the learner's actor network to a rule's choices (supervised imitation)",
                       description="Fit the learner's actor network by cross-entropy to the choices a teacher rule "
                                   "(ML, greedy) makes on the states it visits itself (adaptfilt.imitation); the "
                                   "command line is recorded in the policy file.")
    p.add_argument("name", type=_experiment, help="experiment name (its model and grid), see `adaptfilt experiments`")
    p.add_argument("--features", type=_features, required=True, help="the network's inputs, e.g. paper+circ+cand+lik")
    p.add_argument("--seed", type=_int_at_least(0), default=0, help="the teacher's runs, weights and minibatches")
    p.add_argument("--runs", type=_int_at_least(2, " (a fitting and a held-out part)"), default=2000,
                   help="the teacher's runs (default 2000)")
    p.add_argument("--epochs", type=_int_at_least(1), default=30, help="passes over the fitting part (default 30)")
    p.add_argument("--teacher", choices=TEACHERS, default="ml", help="the rule imitated (default ml)")
    p.add_argument("--horizon", type=_int_at_least(1), default=None, help="time steps (default: the model's)")
    p.add_argument("--holdout", type=_float_in(0.0, 1.0, closed=False, name="--holdout"), default=0.2,
                   help="share of the runs held out for the accuracy (default 0.2)")
    p.add_argument("--lr", type=_positive, default=1e-3, help="Adam's learning rate (default 0.001)")
    p.add_argument("--batch-size", type=_int_at_least(1), default=1024, help="steps per minibatch (default 1024)")
    p.add_argument("--out", required=True, type=_out_file, help="policy file to write (.npz)")
    p.set_defaults(func=_imitate)


def _imitate(args: argparse.Namespace) -> int:
    from adaptfilt.imitation import imitate, imitation_command

    opts = dict(runs=args.runs, epochs=args.epochs, teacher=args.teacher, n_steps=args.horizon,
                holdout=args.holdout, lr=args.lr, batch_size=args.batch_size)
    pol = imitate(args.name, args.features, args.seed, **opts,
                  command=imitation_command(args.name, args.features, args.seed, out=args.out, **opts))
    pol.save(args.out)
    info = pol.metadata["imitation"]
    print(f"wrote {args.out} (held-out agreement with {args.teacher}: {info['heldout_accuracy']:.3f})")
    return 0


def _add_floor(sub) -> None:
    p = sub.add_parser("floor", help="the Bayes floor on UNGM: the point-mass filter on the evaluation's runs "
                                     "(the reproduction's floor stage)")
    p.add_argument("--runs", type=_int_at_least(2), default=2000, help="the first M runs of the evaluation (default 2000)")
    p.add_argument("--seed", type=_int_at_least(0), default=0, help="the evaluation's seed (default 0)")
    p.add_argument("--horizon", type=_int_at_least(1), default=None, help="time steps (default: the model's)")
    p.add_argument("--eval-runs", type=_int_at_least(2), default=10_000,
                   help="runs of the evaluation whose first --runs are filtered (default 10^4)")
    p.add_argument("--out", required=True, type=_out_file, help="JSON file to write")
    p.set_defaults(func=_reference)


def _add_reconcile(sub) -> None:
    p = sub.add_parser("reconcile", help="the CTM variants against Table I's SIF RMSE (the reproduction's "
                                         "reconcile stage)")
    p.add_argument("--runs", type=_int_at_least(2), default=2000, help="runs per variant (default 2000)")
    p.add_argument("--seed", type=_int_at_least(0), default=0)
    p.add_argument("--horizon", type=_int_at_least(1), default=None, help="time steps (default: the model's)")
    p.add_argument("--out", required=True, type=_out_file, help="JSON file to write")
    p.set_defaults(func=_reference)


def _add_reproduce(sub) -> None:
    p = sub.add_parser("reproduce", help="train + evaluate + figures + tables of the paper")
    p.add_argument("--out", required=True, type=_out_dir, help="output directory")
    p.add_argument("--scale", choices=("quick", "medium", "full"), default=None,
                   help="full (default): the paper's protocol, M = 10^4, about 15 min on 2 cores; medium: the same "
                        "8 seeds with half the training episodes and M = 2000, about 6 min; quick: toy scale")
    p.add_argument("--quick", action="store_true", help="toy scale, about a minute (--scale quick)")
    p.add_argument("--retrain", action="store_true", help="retrain the fast-mode policies and recompute every result even where data/ has them (the paper-faithful policies in data/ are reused)")
    p.add_argument("--faithful", action="store_true",
                   help="also train the paper-faithful policies data/ lacks (slow: about 11 CPU-minutes each)")
    p.add_argument("--workers", type=_int_at_least(1), default=None, help="local processes (default: every core)")
    p.add_argument("--cluster", default=None,
                   help="run the jobs on a Dask cluster: a scheduler address, or 'local' for a local one")
    p.add_argument("--data", default=None,
                   help="the stored artefacts to reuse (a copy of the repository's data/; default: $ADAPTFILT_DATA, "
                        "then the checkout's data/)")
    p.add_argument("--report-only", action="store_true",
                   help="recompute the verdicts and the report's tables from what OUT holds (its evaluations, or a "
                        "stored check's intervals), keeping its recorded times; nothing is trained or evaluated")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_reproduce)


def _add_beyond(sub) -> None:
    from adaptfilt.experiments.beyond import STUDIES, STUDY_TITLES

    p = sub.add_parser("beyond", help=f"the studies beyond the paper ({', '.join(STUDIES)}), at the seed level, "
                                      "into OUT/beyond",
                       description="The studies beyond the paper, at the seed level, into OUT/beyond: "
                                   + "; ".join(f"{k}, {v}" for k, v in STUDY_TITLES.items()) + ".")
    p.add_argument("--out", required=True, type=_out_dir, help="output directory (OUT/beyond)")
    p.add_argument("--quick", action="store_true", help="toy scale")
    p.add_argument("--studies", type=_studies, default=",".join(STUDIES),
                   help="which, comma-separated (default all): "
                        + "; ".join(f"{k} ({v})" for k, v in STUDY_TITLES.items()))
    p.add_argument("--workers", type=_int_at_least(1), default=None, help="local processes (default: every core)")
    p.add_argument("--cluster", default=None, help="run the jobs on a Dask cluster (scheduler address or 'local')")
    p.add_argument("--data", default=None,
                   help="where the reproduction's policies are (a copy of the repository's data/; default: "
                        "$ADAPTFILT_DATA, then the checkout's data/)")
    p.add_argument("--report-only", action="store_true",
                   help="judge the stored studies' verdicts again (summary.json, summary.md) from what OUT/beyond "
                        "holds; nothing is trained or evaluated")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_beyond)


def _add_book(sub) -> None:
    p = sub.add_parser("book", help="build the static course book (mdBook) from the executed notebooks")
    p.add_argument("--out", required=True, type=_out_dir, help="output directory (DIR/index.html)")
    p.set_defaults(func=_book)


#: Library errors that are the user's (a bad name, value or file; a missing optional package): one line at
#: the CLI, as are a book that cannot be built and a job of a sweep that failed with one of them or lost
#: its worker (:func:`_is_user_error`). Anything else is a bug and keeps its traceback.
USER_ERRORS = (ValueError, KeyError, OSError, ImportError)


def _is_user_error(e: BaseException) -> bool:
    from concurrent.futures.process import BrokenProcessPool

    from adaptfilt.course.book import BookBuildError
    from adaptfilt.experiments.sweep import JobFailed

    if isinstance(e, JobFailed):  # in a worker: judged by what the job raised
        return e.__cause__ is None or isinstance(e.__cause__, USER_ERRORS + (BrokenProcessPool,))
    return isinstance(e, USER_ERRORS + (BookBuildError,))


@contextlib.contextmanager
def _console_warnings():
    """Warnings in one line (:func:`adaptfilt.experiments.sweep.one_line_warning`) while a command runs;
    a call from Python gets its own format back after it."""
    import warnings

    from adaptfilt.experiments.sweep import one_line_warning

    before = warnings.formatwarning
    warnings.formatwarning = one_line_warning
    try:
        yield
    finally:
        warnings.formatwarning = before


def main(argv: list[str] | None = None) -> int:
    """Run ``adaptfilt ARGS``; a user error exits with status 2 and one line
    ``adaptfilt: error: ...`` on stderr; Ctrl-C or SIGTERM with status 130 or 143 and one line
    ``adaptfilt: interrupted: ...`` saying what was kept and how to resume, within the bound the module
    docstring states. ``argv`` None is this process's own command line (the console script,
    ``python -m adaptfilt``): the bound then holds to the process's exit; a list is a call from Python
    (a test), whose caller goes on: the bound holds until this returns or raises."""
    args = build_parser().parse_args(argv)
    from adaptfilt.experiments.sweep import STOP_SECONDS, STOP_SECONDS_DASK

    bound = STOP_SECONDS_DASK if getattr(args, "cluster", None) else STOP_SECONDS
    try:
        with _stop_on_signals(bound, own_process=argv is None), _console_warnings():
            return args.func(args)
    except KeyboardInterrupt as e:
        _interrupted(e)
    except Exception as e:
        if not _is_user_error(e):
            raise
        _fail(_user_message(e))


#: The watchdog ends the process this many seconds before the stated bound (module docstring): the rest is
#: for the exit itself and for whoever measures it from outside.
_WATCHDOG_MARGIN = 2.0


class _Stop:
    """A command's stop by signal. The first Ctrl-C or SIGTERM raises :class:`~adaptfilt.experiments.sweep.
    Interrupted` in the main thread (which stops the work as Ctrl-C does) and arms the watchdog; a second
    signal, or the watchdog at the bound, ends the process at once (``os._exit``), its output flushed and,
    if the one line ``adaptfilt: interrupted: ...`` is not out yet, a line saying so.

    The watchdog counts from the signal's arrival, which it reads from the interpreter's wakeup fd (written
    by the C-level handler the moment the signal comes, whatever the main thread is doing), not from the
    Python handler's run, which waits for the main thread. That wait can be long: the kernel may deliver the
    signal to another thread (any thread that does not block it), and a main thread blocked in a lock's
    acquire (``concurrent.futures.as_completed`` waiting for a job) is then not woken: the handler would run
    when the next job ends, minutes later. So the watchdog pokes the main thread (``pthread_kill`` with
    :data:`_POKE`, whose handler does nothing: the interrupted call runs the pending handlers) until the
    handler has run. The main thread may also hold the signal on purpose for a moment
    (:func:`adaptfilt.experiments.sweep._deferred_interrupts`)."""

    def __init__(self, bound: float) -> None:
        self.bound = bound
        self.signum: int | None = None  # the first signal's, once its Python handler ran
        self.deadline: float | None = None  # time.monotonic() at which the watchdog ends the process
        self.said = False  # the line is out
        self.done = False  # the command returned: the watchdog leaves
        self.exiting = threading.Lock()  # taken by whoever ends the process
        self.wakeup_r, self.wakeup_w = os.pipe()
        os.set_blocking(self.wakeup_r, False)
        os.set_blocking(self.wakeup_w, False)  # the interpreter requires it

    def arm(self, arrived: float) -> None:
        limit = arrived + self.bound - _WATCHDOG_MARGIN
        if self.deadline is None or limit < self.deadline:
            self.deadline = limit

    def watch(self) -> None:
        """The watchdog (a daemon thread, started with the command: a thread started from a signal handler
        could wait forever on a lock the interrupted main thread holds). The handler takes no lock: it sets
        the deadline too, in case the wakeup fd was taken over (only one per process)."""
        import select

        arrived: list[int] = []
        poked = -1.0
        try:
            while not self.done:
                ready, _, _ = select.select([self.wakeup_r], [], [], 0.1)
                now = time.monotonic()
                if ready:
                    with contextlib.suppress(OSError):
                        arrived += [b for b in os.read(self.wakeup_r, 512) if b in (signal.SIGINT, signal.SIGTERM)]
                    if arrived:
                        self.arm(now)
                    if len(arrived) >= 2:  # a second signal while stopping, even if the main thread is stuck
                        self.exit_now(arrived[1], "a second signal cut the stop short", flush_in_thread=True)
                if arrived and self.signum is None and now >= poked + 0.2 and _POKE is not None:
                    with contextlib.suppress(OSError, ValueError):  # its handler has not run: wake the main thread
                        signal.pthread_kill(threading.main_thread().ident, _POKE)
                    poked = now
                if self.deadline is not None and now >= self.deadline:
                    self.exit_now(self.signum or (arrived or [signal.SIGTERM])[0],
                                  f"stopping took over {self.bound - _WATCHDOG_MARGIN:g} s, so it was cut short",
                                  flush_in_thread=True)
        finally:
            for fd in (self.wakeup_r, self.wakeup_w):
                with contextlib.suppress(OSError):
                    os.close(fd)

    def exit_now(self, signum: int, why: str, flush_in_thread: bool) -> None:
        """End the process (returns only if another thread already does)."""
        if not self.exiting.acquire(blocking=False):
            return
        _flush(flush_in_thread)
        if not self.said:  # after a newline: a progress bar may be mid-line
            line = (f"\nadaptfilt: interrupted: {why}; every file written is whole (reproduce, beyond and "
                    "train --seeds reuse their finished jobs when run again)\n")
            with contextlib.suppress(OSError):
                os.write(2, line.encode())
        os._exit(128 + signum)


def _flush(in_thread: bool) -> None:
    """Flush stdout and stderr, but never wait on them for more than a second: a thread stuck writing holds
    their lock (the watchdog flushes from a helper thread; a signal handler, in the main thread, cannot
    start one safely and a reentrant flush there raises, which is ignored)."""

    def flush() -> None:
        for f in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                f.flush()

    if not in_thread:
        flush()
        return
    t = threading.Thread(target=flush, daemon=True, name="adaptfilt-flush")
    t.start()
    t.join(1.0)


#: The signal the watchdog sends the main thread to wake it (:class:`_Stop`): one nobody uses here (out-of-band
#: socket data), ignored by default, so that only the handler below makes it interrupt a blocked call.
_POKE = getattr(signal, "SIGURG", None) if hasattr(signal, "pthread_kill") else None


def _poked(signum, frame) -> None:
    """The poke's handler: nothing; the call it interrupted runs the pending handlers (SIGINT's, SIGTERM's)."""


#: The stop in force (set by :func:`_stop_on_signals`), for :func:`_interrupted` to mark its line said.
_STOP: _Stop | None = None


@contextlib.contextmanager
def _stop_on_signals(bound: float, own_process: bool):
    """Ctrl-C (SIGINT) and SIGTERM (a scheduler ending the job, a closed terminal's shell) stop a command:
    its workers stopped, what finished kept and said, within ``bound`` seconds (:class:`_Stop`); a second
    signal ends it at once. Only from the main thread (signal's rule); a signal ignored when the command
    started (SIG_IGN, e.g. SIGINT in a background job) stays ignored.

    ``own_process``: the process ends after this command; after a signal the handlers and the watchdog
    then stay in force through the interpreter's exit (its exit hooks and threads can hang too). Otherwise
    they go when the command returns or raises, and the caller goes on."""
    global _STOP
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    from adaptfilt.experiments.sweep import Interrupted  # imported now: not in a handler, mid-import maybe

    stop = _Stop(bound)

    def handle(signum, frame):
        if stop.signum is not None:  # a second signal while stopping: at once
            stop.exit_now(signum, "a second signal cut the stop short", flush_in_thread=False)
            return
        stop.signum = signum
        stop.arm(time.monotonic())
        raise Interrupted(signum=signum)

    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(sig) is not signal.SIG_IGN:
            previous[sig] = signal.signal(sig, handle)
    if _POKE is not None:
        previous[_POKE] = signal.signal(_POKE, _poked)
    previous_wakeup = signal.set_wakeup_fd(stop.wakeup_w, warn_on_full_buffer=False)
    threading.Thread(target=stop.watch, daemon=True, name="adaptfilt-stop-watchdog").start()
    _STOP = stop
    try:
        yield
    finally:
        if stop.signum is None or not own_process:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            signal.set_wakeup_fd(previous_wakeup)
            stop.done = True  # the watchdog leaves (and closes the pipe) within 0.1 s
            _STOP = None


def _interrupted(e: KeyboardInterrupt) -> NoReturn:
    if "tqdm" in sys.modules:  # a bar left open mid-line by the interrupt would swallow the message
        from tqdm import tqdm

        for bar in list(getattr(tqdm, "_instances", ())):
            bar.close()
    kept = getattr(e, "kept", "") or "nothing was written"
    sys.stderr.write(f"adaptfilt: interrupted: {' '.join(kept.split())}\n")
    sys.stderr.flush()
    if _STOP is not None:
        _STOP.said = True
    raise SystemExit(128 + getattr(e, "signum", signal.SIGINT))


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
