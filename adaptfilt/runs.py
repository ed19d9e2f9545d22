r"""The evaluation's paired runs: the trajectories every policy and filter of one evaluation is scored on, the
bootstrap resampling counts they share, and the seed they come from, derived here and nowhere else.

An evaluation with seed ``s`` simulates its ``M`` runs of ``T`` steps from ``default_rng([TRAJ_SEED_KEY, s])``
(:func:`trajectory_rng`: not the trajectories a training run with the same seed simulates) and resamples
them with the counts :func:`bootstrap_counts` draws from ``default_rng([TRAJ_SEED_KEY, s, 1])`` (one
multinomial ``(n_boot, M)`` set shared by every policy: paired intervals). :class:`EvalRuns` holds both,
drawn when first used, and the first ``n`` runs (:meth:`EvalRuns.first`) on which a reference too slow for
all of them is computed (the Bayes floor, :func:`adaptfilt.exact.bayes_floor`).

More runs than ``chunk_size`` (:data:`CHUNK_SIZE` by default in :func:`~adaptfilt.evaluation.evaluate`) are
a :class:`RunStore` on disk instead: the same draws in the same order, read back a chunk of runs at a
time (:mod:`adaptfilt.evaluation`, "Streaming").

>>> import adaptfilt as af
>>> runs = EvalRuns(af.models.ungm(), n_runs=50, seed=3, n_steps=20, n_boot=10)
>>> runs.traj.x.shape, runs.counts.shape, runs.first(5).z.shape
((50, 20, 1), (10, 50), (5, 20, 1))
>>> bool((runs.first(5).x == runs.traj.x[:5]).all()), runs.trajectories
(True, 'default_rng([59297, seed])')
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from adaptfilt import metrics
from adaptfilt.models import Trajectory

__all__ = ["TRAJ_SEED_KEY", "CHUNK_SIZE", "EvalRuns", "RunStore", "trajectory_rng", "bootstrap_counts"]

#: Trajectories of an evaluation with seed ``s`` come from ``default_rng([TRAJ_SEED_KEY, s])``, so
#: that they are not the trajectories a training run with the same seed simulates.
TRAJ_SEED_KEY = 0xE7A1
#: Runs filtered at a time by default: an evaluation of at most this many runs (every result in ``data/``)
#: is the one-pass evaluation, byte for byte; one of more runs is streamed (:class:`RunStore`).
CHUNK_SIZE = 10_000


def trajectory_rng(seed: int) -> np.random.Generator:
    """The generator an evaluation with ``seed`` simulates its runs from."""
    return np.random.default_rng([TRAJ_SEED_KEY, int(seed)])


def bootstrap_counts(n_runs: int, n_boot: int, seed: int, stream: int = 1) -> np.ndarray:
    """``(n_boot, n_runs)`` multinomial resampling counts of the runs of an evaluation with ``seed``:
    ``metrics.bootstrap_counts`` from ``default_rng([TRAJ_SEED_KEY, seed, stream])``. Stream 1 is the
    evaluation's own (read-only, kept for the next evaluation of the same runs in this process, up to
    :data:`CHUNK_SIZE` runs); another stream resamples a reference of its own (the UNGM floor's is 2)."""
    if int(stream) == 1 and n_runs <= CHUNK_SIZE:
        return _bootstrap_counts(int(n_runs), int(n_boot), int(seed))
    return metrics.bootstrap_counts(n_runs, n_boot, rng=np.random.default_rng([TRAJ_SEED_KEY, int(seed), int(stream)]))


@functools.lru_cache(maxsize=1)
def _bootstrap_counts(M: int, n_boot: int, seed: int) -> np.ndarray:
    """The evaluation's counts, read-only and kept: a worker that evaluates one policy after another
    (``adaptfilt reproduce``'s jobs) draws them once instead of once a policy (0.6 s at 10^4 runs); at most
    80 MB kept."""
    counts = metrics.bootstrap_counts(M, n_boot, rng=np.random.default_rng([TRAJ_SEED_KEY, seed, 1]))
    counts.flags.writeable = False
    return counts


class EvalRuns:
    """The paired runs of one evaluation: ``n_runs`` trajectories of ``n_steps`` steps of ``truth`` from
    ``seed`` (or the given ``traj``) and their bootstrap counts (``n_boot`` resamples), each drawn when
    first used. More runs than ``chunk_size``: a :class:`RunStore` in ``folder`` (:attr:`store`) holds
    them instead (``traj`` and ``counts`` are then not in memory).

    ``n_steps`` defaults to the given trajectories' or the model's horizon. ValueError for fewer than 2 runs
    (the bootstrap needs them), no horizon, or a ``folder`` missing where it is needed.
    """

    def __init__(self, truth, n_runs: int | None = None, seed: int = 0, n_steps: int | None = None, *,
                 n_boot: int = 1000, traj: Trajectory | None = None, chunk_size: int | None = None,
                 folder: str | Path | None = None):
        self.truth, self.seed, self.n_boot = truth, int(seed), int(n_boot)
        self.given = traj is not None
        n_steps = (traj.n_steps if self.given else getattr(truth, "n_steps", None)) if n_steps is None else n_steps
        if n_steps is None or int(n_steps) < 1:
            raise ValueError(f"give n_steps, the runs' horizon (the model {getattr(truth, 'name', '')!r} has none): "
                             f"got {n_steps!r}")
        self.n_steps = int(n_steps)
        if not self.given and (n_runs is None or int(n_runs) < 2):
            raise ValueError(f"n_runs must be at least 2 (bootstrap), got {n_runs}")
        self.n_runs = traj.n_runs if self.given else int(n_runs)
        self._traj, self._counts = traj, None
        self.streamed = chunk_size is not None and self.n_runs > chunk_size
        self.store = None
        if self.streamed:
            if folder is None:
                raise ValueError(f"{self.n_runs} runs in chunks of {chunk_size} are stored on disk: give a folder")
            self.store = RunStore(truth, self.n_runs, self.n_steps, self.seed, self.n_boot, traj, int(chunk_size),
                                  Path(folder))

    def __repr__(self) -> str:
        return (f"EvalRuns({getattr(self.truth, 'name', 'model')!r}, n_runs={self.n_runs}, seed={self.seed}, "
                f"n_steps={self.n_steps}{', given' if self.given else ''}{', streamed' if self.streamed else ''})")

    @property
    def trajectories(self) -> str:
        """Where the runs come from, as results record it."""
        return "given" if self.given else f"default_rng([{TRAJ_SEED_KEY}, seed])"

    @property
    def traj(self) -> Trajectory:
        """All the runs (simulated on first use); not for streamed runs."""
        self._in_memory("traj")
        if self._traj is None:
            self._traj = self.truth.simulate(self.n_runs, self.n_steps, rng=trajectory_rng(self.seed))
        return self._traj

    @property
    def counts(self) -> np.ndarray:
        """The bootstrap counts ``(n_boot, n_runs)`` (drawn on first use); not for streamed runs."""
        self._in_memory("counts")
        if self._counts is None:
            self._counts = bootstrap_counts(self.n_runs, self.n_boot, self.seed)
        return self._counts

    def first(self, n: int) -> Trajectory:
        """The first ``n`` runs: the same trajectories every policy of the evaluation is scored on."""
        if not 1 <= int(n) <= self.n_runs:
            raise ValueError(f"first(n) takes 1 to {self.n_runs} runs, got {n}")
        return self.store.trajectory(0, int(n)) if self.streamed else self.traj[: int(n)]

    def _in_memory(self, what: str) -> None:
        if self.streamed:
            raise ValueError(f"{self.n_runs} runs are streamed from disk ({self.store.chunk_size} at a time): "
                             f"their {what} is read by chunks (store.trajectory, store.counts)")


class RunStore:
    """The runs of a streamed evaluation: trajectories and bootstrap counts on disk, read one chunk at a time.

    The trajectories are those of ``truth.simulate(M, T, rng=trajectory_rng(seed))``, drawn in the same
    order (step by step, all runs: :func:`_simulate_to_files`) and written time-major, so that each step is
    one sequential write; a chunk reads its rows back, step by step. The counts are those of
    :func:`bootstrap_counts` (``multinomial(M, 1/M)`` per resample, drawn one resample at a time: the same
    numbers), as bytes (a count above 255 among ``M`` draws of ``1/M`` has probability ~1e-500). Given
    trajectories stay where they are (in the caller's memory) and are sliced."""

    def __init__(self, truth, n_runs: int, n_steps: int, seed: int, n_boot: int, traj: Trajectory | None,
                 chunk_size: int, folder: Path):
        self.n_runs, self.n_boot, self.chunk_size, self.n_steps = n_runs, n_boot, chunk_size, n_steps
        self.traj, self.folder = traj, Path(folder)
        self.widths = (truth.nx, truth.nz)
        if traj is None:
            _simulate_to_files(truth, n_runs, n_steps, trajectory_rng(seed), self.folder / "x.f8",
                               self.folder / "z.f8")
        rng = np.random.default_rng([TRAJ_SEED_KEY, seed, 1])  # bootstrap_counts' draws, one resample at a time
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
