"""Where the object library keeps its on-disk caches (collision parts, detected symmetries), and why an entry
had to be computed again.

Cache entries are found by a key (the mesh hash, a format version, the settings); a key that changes (a new
``--scale`` changes the mesh hash, a new release the version) means a recomputation that can take minutes for a
set of scanned meshes. :func:`key_change` remembers, per object source and cache kind, the fields of the key an
entry was last computed for, so that the next recomputation can say which field changed
(``scale 1 -> 0.01``).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["cache_dir", "cache_root", "key_change", "describe_key_change"]

#: The key field that follows from the others (a new scale gives a new mesh hash): named only when no other
#: field changed.
DERIVED_FIELD = "mesh"


def cache_root() -> Path:
    """Folder for on-disk caches: ``$SIMTEST_CACHE`` or ``~/.cache/simtest`` (not created here)."""
    return Path(os.environ.get("SIMTEST_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "simtest"))


def cache_dir() -> Path:
    """:func:`cache_root`, created if missing."""
    path = cache_root()
    path.mkdir(parents=True, exist_ok=True)
    return path


def describe_key_change(before: Mapping[str, Any], after: Mapping[str, Any]) -> str | None:
    """The fields that differ between two keys, e.g. ``"scale 1 -> 0.01"``, or ``None`` when they are equal.

    The derived field ``mesh`` (the mesh hash) is named only when no other field differs.
    """
    changed = [k for k in after if k != DERIVED_FIELD and before.get(k) != after.get(k)]
    if not changed and before.get(DERIVED_FIELD) != after.get(DERIVED_FIELD):
        changed = [DERIVED_FIELD]
    if not changed:
        return None
    return ", ".join(f"{k} {_short(before.get(k))} -> {_short(after.get(k))}" for k in changed)


def key_change(kind: str, source: str, key: Mapping[str, Any]) -> str | None:
    """Record that ``source``'s ``kind`` cache entry is being computed for ``key``, and say how ``key`` differs
    from the one recorded before (``None``: nothing recorded yet for this source, or no difference).

    Args:
        kind: The cache (``"coacd"``, ``"symmetry"``).
        source: What the object came from (its file, or ``builtin:...``): entries of one source are compared.
        key: The key's fields, JSON-serialisable (e.g. ``{"scale": 0.01, "units": "m", "mesh": "ab12..."}``).
    """
    if not source:
        return None
    name = hashlib.sha1(source.encode("utf-8")).hexdigest()[:16]
    path = cache_dir() / "keys" / kind / f"{name}.json"
    before = None
    try:
        before = json.loads(path.read_text(encoding="utf-8")).get("key")
    except (OSError, ValueError, AttributeError):
        pass  # nothing recorded (or unreadable): a first computation says nothing
    from simtest.io.files import atomic_write_json

    try:
        atomic_write_json(path, {"source": source, "key": dict(key)})
    except OSError:
        pass  # the record only explains; a read-only cache still computes
    return describe_key_change(before, key) if isinstance(before, dict) else None


def _short(value: Any) -> str:
    """A value for the one-line message (hashes cut to 12 characters)."""
    if isinstance(value, float):
        return f"{value:g}"
    text = str(value)
    return text[:12] if len(text) > 16 and " " not in text else text
