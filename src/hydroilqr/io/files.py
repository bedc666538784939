"""Atomic file writes: a reader, a crash or a killed run sees the old file or the new one,
never a torn one (results, checkpoints and sweep points are all written this way)."""

from __future__ import annotations

import hashlib
import io
import os
import re
from pathlib import Path

import numpy as np


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    """Writes ``data`` (text is UTF-8) to a hidden temporary file beside ``path``, flushes it
    to disk and renames it over ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def atomic_savez(path: str | Path, compressed: bool = True, **arrays: np.ndarray) -> Path:
    """``np.savez[_compressed](path, **arrays)``, written atomically (``path`` as given: no
    ``.npz`` is appended)."""
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return atomic_write(path, buf.getvalue())


def content_hash(arrays: dict[str, np.ndarray], text: str = "") -> str:
    """SHA-256 of named arrays (names, dtypes, shapes and bytes, in name order) and a text."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
    h.update(text.encode())
    return h.hexdigest()


def file_name(name: str, suffix: str = ".png") -> str:
    """A file name for a plot named after something in the task (a body, from a model file or
    the task): one name in the output directory, whatever ``name`` holds (``../x``, ``a/b``,
    a leading dot: ``escape_ball.png``, ``a_b.png``)."""

    plain = re.sub(r"[^A-Za-z0-9_.+@-]+", "_", str(name))
    plain = re.sub(r"\.{2,}", "_", plain).strip("._") or "object"
    return plain[:100] + suffix
