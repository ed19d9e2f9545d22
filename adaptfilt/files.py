"""Files that are either whole or absent: a killed run never leaves a half-written one.

Every file a job or a driver writes goes to a temporary name in the same folder and is then renamed
over the target with :func:`os.replace`, which is atomic on one file system. A run interrupted at
any moment (Ctrl-C, a scheduler's SIGTERM, the OOM killer's SIGKILL) leaves each output either as it
was or complete; a resumed run can trust any file whose checksum its journal recorded
(:mod:`adaptfilt.experiments.journal`). A temporary left by a killed writer is a hidden
``.NAME.PID.tmp`` beside the target and never has the target's name.
"""
from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path
from typing import Iterator

__all__ = ["atomic_path", "atomic_write", "atomic_savefig", "sha256"]


def sha256(path: str | os.PathLike) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path to write ``path`` through: renamed to ``path`` when the block ends, removed if
    it raises. The folder is created. The pid in the name keeps two writers of one file apart."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def atomic_write(path: str | os.PathLike, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` atomically (module docstring)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    return Path(path)


def atomic_savefig(fig, path: str | os.PathLike, **kw) -> Path:
    """``fig.savefig(path, **kw)`` atomically (a matplotlib figure; the format is ``path``'s suffix)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=Path(path).suffix.lstrip(".") or None, **kw)
    return Path(path)
