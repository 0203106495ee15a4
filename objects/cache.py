"""Where the object library keeps its on-disk caches (collision parts, detected symmetries)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir", "cache_root"]


def cache_root() -> Path:
    """Folder for on-disk caches: ``$SIMTEST_CACHE`` or ``~/.cache/simtest`` (not created here)."""
    return Path(os.environ.get("SIMTEST_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "simtest"))


def cache_dir() -> Path:
    """:func:`cache_root`, created if missing."""
    path = cache_root()
    path.mkdir(parents=True, exist_ok=True)
    return path
