"""Files that appear whole or not at all (standard library only): each writer writes a temporary file of its own
beside the target (a unique hidden name, ``tempfile.mkstemp``), then renames it onto the target. Two processes
writing one target at once never share a temporary file (the last rename wins, and each rename is a whole file);
a writer killed before its rename leaves the target as it was, plus its own hidden ``.<name>.*.partial``, which no
reader takes for the target."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, mode: int = 0o644) -> Iterator[Path]:
    """A fresh temporary file beside ``path`` for the block to write; renamed onto ``path`` with permissions
    ``mode`` when the block ends, removed when it raises. ``path``'s directory must exist."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_atomic(path: str | os.PathLike, data: bytes | str, mode: int = 0o644) -> None:
    """Write ``data`` (bytes, or text as UTF-8) to ``path`` whole, flushed to disk before the rename."""
    raw = data.encode() if isinstance(data, str) else data
    with atomic_path(path, mode) as tmp, open(tmp, "wb") as f:
        f.write(raw)
        f.flush()
        os.fsync(f.fileno())
