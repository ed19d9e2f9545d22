"""Files that are either whole or absent: a killed run never leaves a half-written one.

Every file a job or a driver writes goes to a temporary name in the same folder and is then renamed
over the target with :func:`os.replace`, which is atomic on one file system. A run interrupted at
any moment (Ctrl-C, a scheduler's SIGTERM, the OOM killer's SIGKILL) leaves each output either as it
was or complete; a resumed run can trust any file whose checksum its journal recorded
(:mod:`adaptfilt.experiments.journal`). A temporary left by a killed writer is a hidden
``.NAME.PID.tmp`` beside the target and never has the target's name.

The arrays of a file of weights (a learned policy, KalmanNet) go into one ``.npz`` with a JSON record
(:func:`write_npz`, :func:`read_npz`): numpy only, no pickles, byte-reproducible, so that whatever only
reads such a file's record (the pipeline's manifests) needs no torch.
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import os
import zipfile
import zlib
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

__all__ = ["atomic_path", "atomic_write", "atomic_savefig", "sha256", "write_npz", "read_npz"]


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


_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def write_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], metadata: Mapping[str, Any] | None = None) -> Path:
    """Write ``arrays`` (and ``metadata`` as a JSON ``__metadata__`` entry) to a
    byte-reproducible ``.npz``: sorted entries, fixed zip date, no pickles,
    atomic replace. ``np.load(path, allow_pickle=False)`` reads it back."""
    path = Path(path)
    items = dict(arrays)
    # always a metadata entry (possibly {}): it is what tells read_npz the file is ours
    text = json.dumps({} if metadata is None else metadata, sort_keys=True, indent=1, allow_nan=True)
    items["__metadata__"] = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(items):
            arr = np.asarray(items[name])
            if arr.dtype == object:
                raise TypeError(f"{name}: object arrays cannot be stored without pickling")
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(name + ".npy", date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())
    return path


def read_npz(path: str | os.PathLike, what: str = "adaptfilt policy file") -> tuple[dict[str, np.ndarray], dict]:
    """Arrays and metadata of a file written by :func:`write_npz` (no pickles).

    A file that is not one -- missing (``FileNotFoundError``), empty, not a
    zip archive, truncated or damaged, holding pickled objects, or an ``.npz``
    of plain arrays without the ``__metadata__`` JSON entry -- is a
    ``ValueError`` "``<path>: not an <what> (<why>)``".
    """
    path = Path(path)

    def bad(why: str) -> ValueError:
        return ValueError(f"{path}: not an {what} ({why})")

    if not path.exists():
        raise FileNotFoundError(errno.ENOENT, f"no such {what}", str(path))
    if path.is_dir():
        raise bad("it is a directory")
    with open(path, "rb") as f:
        head = f.read(4)
    if not head:
        raise bad("the file is empty")
    if head not in (b"PK\x03\x04", b"PK\x05\x06"):
        raise bad("not a zip/npz archive" + (": a single .npy array" if head == b"\x93NUM" else ""))
    arrays: dict[str, np.ndarray] = {}
    k = None
    try:
        with np.load(path, allow_pickle=False) as z:
            for k in z.files:
                arrays[k] = z[k]
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as e:
        raise bad(f"damaged or truncated archive: {e}") from None
    except ValueError as e:  # numpy's refusal to unpickle, or a damaged .npy header
        why = "holds pickled Python objects, which are never loaded" if "pickle" in str(e) else f"damaged: {e}"
        raise bad(why if k is None else f"entry {k!r} {why}") from None
    meta_bytes = arrays.pop("__metadata__", None)
    if meta_bytes is None:
        held = sorted(arrays)
        raise bad("no __metadata__ entry, so not written by adaptfilt; it holds "
                  + (", ".join(held[:5]) + (f" and {len(held) - 5} more" if len(held) > 5 else "") if held else "nothing"))
    if not isinstance(meta_bytes, np.ndarray) or meta_bytes.dtype != np.uint8 or meta_bytes.ndim != 1:
        raise bad("its __metadata__ entry is not a .npy array of UTF-8 bytes")
    other = [k for k, v in arrays.items() if not isinstance(v, np.ndarray)]
    if other:  # np.load hands non-.npy members of a zip over as raw bytes
        raise bad(f"entry {other[0]!r} is not a .npy array")
    try:
        meta = json.loads(meta_bytes.tobytes().decode("utf-8"))
    except (ValueError, TypeError) as e:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise bad(f"its __metadata__ is not UTF-8 JSON: {e}") from None
    if not isinstance(meta, dict):
        raise bad(f"its __metadata__ is a JSON {type(meta).__name__}, not an object")
    return arrays, meta
