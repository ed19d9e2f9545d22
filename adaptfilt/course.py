"""Small helpers for the course notebooks (display only; no numerics here)."""
from __future__ import annotations

import inspect
import textwrap


def show_source(obj, lines: tuple[int, int] | None = None):
    """Display the source of a library object in a notebook, highlighted.

    The course shows library code instead of copying it, so that what the
    reader sees is what runs. ``lines=(a, b)`` shows a slice of the source.
    """
    from IPython.display import Markdown

    src = inspect.getsource(obj)
    if lines is not None:
        src = "\n".join(src.splitlines()[lines[0]:lines[1]])
    return Markdown(f"```python\n{textwrap.dedent(src)}\n```")
