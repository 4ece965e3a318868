"""Nothing is lost: files are written under a temporary name in the same folder, then renamed."""

from __future__ import annotations

import os
from pathlib import Path


def tmp_path(path: str | Path) -> Path:
    """The temporary sibling of ``path`` (hidden, per process)."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp{os.getpid()}")


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically."""
    path = Path(path)
    tmp = tmp_path(path)
    tmp.write_text(text)
    os.replace(tmp, path)
    return path
