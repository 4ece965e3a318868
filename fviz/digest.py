"""Digests under every layer: of values (numbers, arrays, strings; :func:`digest_of`), of arrays' bytes
(:func:`array_digest`: an image's identity whatever its file is called) and of files (:func:`file_digest`)."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

_FILE_DIGESTS: dict[tuple, str] = {}


def digest_of(*parts) -> str:
    """A short digest of numbers, arrays, strings (None included as such)."""
    h = hashlib.sha256()
    for part in parts:
        if part is None:
            h.update(b"\x00none")
        elif isinstance(part, (str, bytes)):
            h.update(b"\x01" + (part.encode() if isinstance(part, str) else part))
        else:
            a = np.ascontiguousarray(np.asarray(part, dtype=np.float64))
            h.update(b"\x02" + repr(a.shape).encode() + a.tobytes())
    return h.hexdigest()[:20]


def array_digest(*arrays: np.ndarray) -> str:
    """A digest of arrays' shapes, dtypes and bytes (an image's identity, whatever its file is called)."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.shape}{a.dtype.str}".encode())
        h.update(a.data)
    return h.hexdigest()


def file_digest(path: str | Path) -> str:
    """sha256 of a file's bytes (computed once per file version in this process); "missing" when unreadable."""
    try:
        st = os.stat(path)
    except OSError:
        return "missing"
    key = (str(Path(path).resolve()), st.st_size, st.st_mtime_ns, st.st_ino)
    if key not in _FILE_DIGESTS:
        h = hashlib.sha256()
        try:
            with open(path, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
        except OSError:
            return "missing"
        _FILE_DIGESTS[key] = h.hexdigest()[:20]
    return _FILE_DIGESTS[key]
