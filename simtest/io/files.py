"""Atomic file writes (a temporary file in the same folder, then ``os.replace``) and output-folder checks.

Every file written here gets the permissions an ordinary ``open()`` would give it under the process umask
(``0644`` under umask ``022``), not the ``0600`` of :func:`tempfile.mkstemp`. :func:`prepare_out_dir` is the
one check every command runs on its output folder before doing any work.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import io
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simtest.errors import ConfigError, DatasetError

__all__ = ["prepare_out_dir", "clear_folder", "file_mode", "atomic_write_bytes", "atomic_write_text",
           "atomic_write_json", "dump_json", "dump_json_keyed", "jsonable", "csv_text", "write_csv", "read_csv"]


@functools.cache
def file_mode() -> int:
    """Permission bits of a new file under the process umask (``0o644`` under umask ``022``); read once."""
    return 0o666 & ~_umask()


def private_partial_dir(parent: str | Path, name: str) -> Path:
    """A new, empty hidden folder ``parent/.NAME.<random>.partial`` owned by this writer alone (a folder is
    assembled there, then renamed into place). Unique per call, so two writers of the same thing (a resumed run
    and a straggling worker of the killed one) never write into each other's folder; its mode follows the
    umask like any new folder (``0o755`` under ``022``)."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    path = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".partial", dir=parent))
    os.chmod(path, 0o777 & ~_umask())
    return path


@functools.cache
def _umask() -> int:
    """The process umask, read once (reading it means setting it for an instant, which must not race with
    threads that create files)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_new_file(path: str | Path, data: bytes) -> None:
    """Create ``path`` (it must not exist) with ``data``, in a folder this writer owns alone and puts in place
    whole (:func:`private_partial_dir`): readers never see the folder before it is complete, so the file needs
    no temporary name and rename of its own (half the CPU time of :func:`atomic_write_bytes` per file). The mode
    follows the umask."""
    with _naming(path), open(path, "xb") as fh:
        fh.write(data)


@contextlib.contextmanager
def _naming(path: str | Path) -> Iterator[None]:
    """An OSError raised without a file name inside the block (``write`` on a full disk) names ``path``."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None:
            exc.filename = str(path)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see either the old file or the complete new one; the file
    gets :func:`file_mode` permissions."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, file_mode())
        with _naming(path), os.fdopen(fd, "wb") as fh:
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


def jsonable(value: Any) -> Any:
    """``value`` with numpy scalars made Python numbers, tuples made lists and NaN/inf made ``None`` (JSON has
    no non-finite numbers), recursively."""
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def csv_text(rows: list[dict[str, Any]], columns: list[str]) -> str:
    """CSV text with a header row; missing or ``None`` cells are empty, booleans are written as 0/1."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow(["" if r.get(c) is None else (int(r[c]) if isinstance(r[c], bool) else r[c]) for c in columns])
    return buf.getvalue()


def write_csv(path: str | Path, rows: list[dict[str, Any]], columns: list[str]) -> None:
    """Atomically write :func:`csv_text` to ``path``."""
    atomic_write_text(path, csv_text(rows, columns))


def read_csv(path: str | Path) -> list[dict[str, str]]:
    """Rows of a CSV file with a header, as dicts of strings."""
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _nearest_existing(path: Path) -> Path:
    """``path`` or its closest existing ancestor."""
    for p in (path, *path.parents):
        if p.exists():
            return p
    return Path(".")  # pragma: no cover - a relative path's root "." always exists


def _check_creatable(out: Path) -> None:
    """Raise :class:`DatasetError` (one line) unless ``out`` is a writable folder or can be made one."""
    base = _nearest_existing(out)
    if base == out:
        if not out.is_dir():
            raise DatasetError(f"output folder {str(out)!r} is a file, not a folder")
        if not os.access(out, os.W_OK | os.X_OK):
            raise DatasetError(f"output folder {str(out)!r}: permission denied (not writable)")
        return
    if not base.is_dir():
        raise DatasetError(f"cannot create output folder {str(out)!r}: {str(base)!r} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise DatasetError(f"cannot create output folder {str(out)!r}: permission denied in {str(base)!r}")


def _overlaps(out: Path, protected: Path, clear: bool) -> bool:
    """True if ``out`` is ``protected``, lies inside it, or (when its contents will be deleted) contains it."""
    return out == protected or protected in out.parents or (clear and out in protected.parents)


def clear_folder(path: Path) -> None:
    """Delete everything inside ``path`` (the folder itself, its owner and permissions stay)."""
    for child in path.iterdir():
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child)
        else:
            child.unlink()


def prepare_out_dir(path: str | os.PathLike, *, overwrite: bool = False, resume: bool = False,
                    can_resume: bool = False, clear: bool = False, protect: Sequence[str | os.PathLike] = (),
                    what: str = "output folder") -> bool:
    """Check an output folder before any work starts; the one rule every command follows.

    A folder that does not exist yet or is empty is always fine (it is not created here). A non-empty folder
    needs ``overwrite`` (or ``resume`` where the caller supports resuming); with ``overwrite`` and ``clear``
    its contents are deleted here, otherwise the caller writes over its own files. The folder must not be,
    or lie inside, any ``protect`` folder (the input dataset), nor contain one when it would be cleared.

    Args:
        path: The output folder.
        overwrite: Allow a non-empty folder (``--overwrite``).
        resume: Allow a non-empty folder to be continued (``--resume``); only with ``can_resume``.
        can_resume: The caller supports ``resume`` (named in the error message).
        clear: With ``overwrite``, delete the folder's contents.
        protect: Input folders the output must stay out of.
        what: How the folder is named in messages.

    Returns:
        True if the folder holds earlier output that is kept (a resume or a non-clearing overwrite).

    Raises:
        ConfigError: ``resume`` and ``overwrite`` together, or ``resume`` where it is not supported.
        DatasetError: The path is a file or lies under one, is not writable, overlaps a ``protect`` folder,
            or is non-empty without ``overwrite``/``resume``; every message is one line naming the path.
    """
    if resume and overwrite:
        raise ConfigError("--resume and --overwrite exclude each other; choose one")
    if resume and not can_resume:
        raise ConfigError(f"this command cannot resume; pass --overwrite to replace the {what}")
    out = Path(path).resolve()
    for p in protect:
        src = Path(p).resolve()
        if _overlaps(out, src, clear):
            inside = "contain or lie inside" if clear else "lie inside"
            raise DatasetError(f"{what} {str(path)!r} must not be, {inside} the input dataset {str(p)!r}; "
                               f"choose another --out")
    _check_creatable(out)
    if not out.is_dir() or not any(out.iterdir()):
        return False
    if resume:
        return True
    if not overwrite:
        flags = "--resume to continue it or --overwrite to replace it" if can_resume else \
            "--overwrite to replace its contents"
        raise DatasetError(f"{what} {str(path)!r} is not empty; pass {flags} (or choose another --out)")
    if clear:
        clear_folder(out)
        return False
    return True
