"""Atomic file writes: write to a temporary file in the same folder, then ``os.replace`` it into place."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

__all__ = ["atomic_write_bytes", "atomic_write_text", "atomic_write_json", "dump_json", "dump_json_keyed"]


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see either the old file or the complete new one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def dump_json(obj: Any, indent: int | None = 2) -> str:
    """JSON text with a trailing newline; the same input always gives the same bytes."""
    return json.dumps(obj, indent=indent, sort_keys=False, ensure_ascii=False) + "\n"


def atomic_write_json(path: str | Path, obj: Any, indent: int | None = 2) -> None:
    atomic_write_text(path, dump_json(obj, indent))


def dump_json_keyed(obj: dict) -> str:
    """A dict of records, one top-level key per line with its value compact (the BOP toolkit's layout)."""
    if not obj:
        return "{}\n"
    lines = [f"  {json.dumps(str(k))}: {json.dumps(v, ensure_ascii=False)}" for k, v in obj.items()]
    return "{\n" + ",\n".join(lines) + "\n}\n"
