"""The ``adaptfilt`` console command.

Sub-commands (their names and flags are a contract the course, the README and
``data/manifest.json`` rely on)::

    adaptfilt experiments
    adaptfilt evaluate NAME --runs M --seed S --out DIR [--policy FILE ...]
    adaptfilt train NAME [--gamma G] [--episodes N] [--parallel B] [--seed S] --out FILE [--resume]
    adaptfilt reproduce --out DIR [--quick] [--retrain] [--faithful]
    adaptfilt book --out DIR

Each sub-command is a thin wrapper: the work lives in the module named in its
handler, so that a notebook can call the same function directly.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _experiments(args: argparse.Namespace) -> int:
    from adaptfilt.experiments import describe_experiments

    print(describe_experiments())
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from adaptfilt.evaluation import evaluate_experiment

    evaluate_experiment(
        args.name,
        n_runs=args.runs,
        seed=args.seed,
        out_dir=Path(args.out),
        policy_files=[Path(p) for p in args.policy],
        progress=not args.no_progress,
    )
    return 0


def _train(args: argparse.Namespace) -> int:
    from adaptfilt.actor_critic import train_experiment

    train_experiment(
        args.name,
        out=Path(args.out),
        gamma=args.gamma,
        episodes=args.episodes,
        parallel=args.parallel,
        seed=args.seed,
        resume=args.resume,
        progress=not args.no_progress,
        command=" ".join(["adaptfilt", *sys.argv[1:]]) if args.command_line is None else args.command_line,
    )
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    from adaptfilt.reproduce import reproduce

    reproduce(out_dir=Path(args.out), quick=args.quick, retrain=args.retrain, progress=not args.no_progress,
              faithful=args.faithful)
    return 0


def _book(args: argparse.Namespace) -> int:
    from adaptfilt.book import build_book

    index = build_book(out_dir=Path(args.out))
    print(f"book built: open {index}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="adaptfilt",
        description="Learning adaptive parameter policies for nonlinear Bayesian filters.",
    )
    sub = parser.add_subparsers(dest="cmd", required=True)

    p = sub.add_parser("experiments", help="list the named experiments of the paper")
    p.set_defaults(func=_experiments)

    p = sub.add_parser("evaluate", help="evaluate every baseline (and learned policies) of an experiment")
    p.add_argument("name", help="experiment name, see `adaptfilt experiments`")
    p.add_argument("--runs", type=int, default=10_000, help="Monte-Carlo runs (default 10^4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--policy", action="append", default=[], help="a learned policy file (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_evaluate)

    p = sub.add_parser("train", help="train a policy with the TD(0) actor-critic (Algorithm 2)")
    p.add_argument("name", help="experiment name, see `adaptfilt experiments`")
    p.add_argument("--gamma", type=float, default=0.5, help="discount factor (0 = myopic)")
    p.add_argument("--episodes", type=int, default=1000, help="training episodes N_MC")
    p.add_argument("--parallel", type=int, default=1,
                   help="episodes run in parallel; 1 = paper-faithful (one update per step of one episode)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="policy file to write")
    p.add_argument("--resume", action="store_true", help="continue from the checkpoint next to --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--command-line", default=None, help=argparse.SUPPRESS)
    p.set_defaults(func=_train)

    p = sub.add_parser("reproduce", help="train + evaluate + figures + tables of the paper")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--quick", action="store_true", help="toy scale, about a minute")
    p.add_argument("--retrain", action="store_true", help="retrain even where data/ has the artefact")
    p.add_argument("--faithful", action="store_true",
                   help="also train the paper-faithful (parallel=1) policies data/ lacks (slow: minutes each)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_reproduce)

    p = sub.add_parser("book", help="build the static course book (mdBook) from the executed notebooks")
    p.add_argument("--out", required=True, help="output directory (DIR/index.html)")
    p.set_defaults(func=_book)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
