"""The splits of a BOP dataset (``DATASET/<split>/<6-digit scene>/``): which there are, which one to read when
none is named, and the complete scene folders of one. Re-exported by :mod:`simtest.io.bop`."""

from __future__ import annotations

from pathlib import Path

from simtest.errors import DatasetError

__all__ = ["split_names", "resolve_split", "dataset_split_dir", "scene_dirs"]


def split_names(dataset_dir: str | Path) -> list[str]:
    """The splits of a dataset: its folders that hold ``<6-digit scene>`` folders, sorted (``withheld/`` and
    other folders of split folders are not splits)."""
    root = Path(dataset_dir)
    return sorted(p.name for p in root.iterdir() if p.is_dir() and any(
        c.is_dir() and c.name.isdigit() and len(c.name) == 6 for c in p.iterdir()))


def resolve_split(dataset_dir: str | Path, split: str | None) -> str:
    """The split to read: ``split`` when given, else the dataset's only split (a real BOP test set has just
    ``test``; a generated dataset just ``train_pbr``).

    Raises:
        DatasetError: The dataset folder is missing; ``split`` is None and the dataset has no split or several
            (they are listed: choose one with ``--split``).
    """
    root = Path(dataset_dir)
    if not root.is_dir():
        raise DatasetError(f"dataset folder {root} does not exist")
    if split is not None:
        return str(split)
    found = split_names(root)
    if len(found) == 1:
        return found[0]
    if not found:
        raise DatasetError(f"dataset {root} has no split folder (no folder holds 6-digit scene folders such as "
                           f"{root}/test/000002)")
    raise DatasetError(f"dataset {root} has several splits ({', '.join(found)}); choose one with --split "
                       "(split= in Python)")


def dataset_split_dir(dataset_dir: str | Path, split: str | None = None) -> Path:
    """The folder of ``split`` in a dataset (None: its only split, :func:`resolve_split`); :class:`DatasetError`
    if the dataset or the split is missing.

    The split error lists the splits found (folders holding ``<6-digit scene>`` folders).
    """
    root = Path(dataset_dir)
    split = resolve_split(root, split)
    split_dir = root / split
    if not split_dir.is_dir():
        found = split_names(root)
        raise DatasetError(f"dataset {root} has no split folder {split!r}; splits found: "
                           f"{', '.join(found) or 'none (no folder holds 6-digit scene folders)'}")
    return split_dir


def scene_dirs(split_dir: str | Path) -> list[Path]:
    """Complete scene folders of a split (``000000``, ``000001``, ...), sorted; partial folders excluded."""
    split_dir = Path(split_dir)
    if not split_dir.is_dir():
        raise DatasetError(f"{split_dir}: split folder does not exist")
    return sorted(p for p in split_dir.iterdir() if p.is_dir() and p.name.isdigit() and len(p.name) == 6)
