"""What the exercise checkers share (:mod:`adaptfilt.course.exercises`, :mod:`adaptfilt.course.study_exercises`):
running the reader's function without a traceback, printing the verdict, and telling a percentile convention
from a wrong interval."""
from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["run_answer", "verdict", "within_a_replicate"]


def run_answer(fn: Callable, args: tuple) -> tuple[object, str | None]:
    """``fn(*args)``, or the reason it failed (the reader's code: no traceback)."""
    try:
        out = fn(*args)
    except Exception as e:  # noqa: BLE001 - any error of the reader's code is reported, not raised
        return None, f"raised {type(e).__name__}: {e}"
    if out is None:
        return None, "returned None (fill in the function and return the result)"
    return out, None


def verdict(problems: list[str], right: str, hint: str) -> bool:
    """Print "right: ..." when there are no problems, else "not yet:" with one line per problem and a hint;
    return whether the answer is right."""
    if problems:
        print("not yet:\n  " + "\n  ".join(problems))
        print("hint: " + hint)
        return False
    print("right: " + right)
    return True


def within_a_replicate(ends: np.ndarray, rep: np.ndarray, level: float = 0.95) -> bool:
    """Whether the interval ``ends`` (lo, hi) lies within one replicate of ``np.quantile``'s percentile
    interval of ``rep``: each end between the order statistics one place outside the two that
    ``np.quantile`` interpolates (so every textbook convention, ``sorted[int(B a)]``, the ``(B + 1) a``-th,
    the nearest rank, passes, and a 90 % interval or a normal approximation does not)."""
    r, B = np.sort(rep), len(rep)
    for end, p in zip(ends, ((1 - level) / 2, (1 + level) / 2)):
        q = p * (B - 1)
        lo, hi = r[max(int(np.floor(q)) - 1, 0)], r[min(int(np.ceil(q)) + 1, B - 1)]
        if not lo <= end <= hi:
            return False
    return True
