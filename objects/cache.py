"""Where the object library keeps its on-disk caches (collision parts, detected symmetries)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir"]


def cache_dir() -> Path:
    """Folder for on-disk caches (``$SIMTEST_CACHE`` or ``~/.cache/simtest``), created if missing."""
    root = os.environ.get("SIMTEST_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "simtest")
    path = Path(root)
    path.mkdir(parents=True, exist_ok=True)
    return path
