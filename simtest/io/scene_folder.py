"""One scene's folder, written whole or not at all: assembled in a private hidden sibling
(``.{name}.<random>.partial``) and renamed into place when complete (:class:`SceneFolder`); an unlabelled split's
labels moved out beside it (:func:`withhold_labels`). Every file of a scene goes through the folder that owns it,
and no name reaches outside it."""

from __future__ import annotations

import os
import shutil
from pathlib import Path, PurePosixPath
from typing import Any

from simtest.errors import DatasetError
from simtest.io.files import atomic_write_json, atomic_write_text, dump_json_keyed, private_partial_dir

__all__ = ["SceneFolder", "withhold_labels", "move_into_place", "UNLABELLED_KEEP"]

#: What a scene folder of an unlabelled split keeps (see :func:`withhold_labels`).
UNLABELLED_KEEP: tuple[str, ...] = ("rgb", "depth", "scene_camera.json")


class SceneFolder:
    """The folder ``parent/name`` of one scene, assembled in a private partial folder (:attr:`dir`) until
    :meth:`commit` moves it into place (:attr:`final`), or :meth:`discard` drops it.

    Args:
        parent: The split folder (``DATASET/train_pbr``); created when missing.
        name: The scene folder's name (six digits).
    """

    def __init__(self, parent: str | Path, name: str) -> None:
        self.final = Path(parent) / name
        self.dir = private_partial_dir(parent, name)

    def path(self, name: str) -> Path:
        """Where the relative file name ``name`` (``"scene_info.json"``, ``"flow/000003.png"``) lies in the
        folder being assembled.

        Raises:
            DatasetError: If ``name`` is absolute, empty or leaves the folder (``..``).
        """
        parts = PurePosixPath(str(name)).parts
        if not parts or PurePosixPath(str(name)).is_absolute() or ".." in parts or "\\" in str(name):
            raise DatasetError(f"scene file name {name!r} is not a relative path inside the scene folder "
                               f"{self.final.name!r}")
        return self.dir.joinpath(*parts)

    def write_json(self, name: str, data: Any, *, keyed: bool = False) -> Path:
        """Write ``data`` as JSON to file ``name`` atomically: as :func:`~simtest.io.files.atomic_write_json`
        writes it, or ``keyed``: one top-level key per line (:func:`~simtest.io.files.dump_json_keyed`, BOP's
        per-image files)."""
        path = self.path(name)
        if keyed:
            atomic_write_text(path, dump_json_keyed(data))
        else:
            atomic_write_json(path, data)
        return path

    def discard(self) -> None:
        """Delete the unfinished folder; the final folder is never touched."""
        shutil.rmtree(self.dir, ignore_errors=True)

    def commit(self, labels_dir: str | Path | None = None) -> Path:
        """Move the finished folder into place (replacing an older one); returns it.

        Args:
            labels_dir: Withhold the labels there first (:func:`withhold_labels`), so a complete scene folder
                always has its labels.
        """
        if labels_dir is not None:
            withhold_labels(self.dir, Path(labels_dir))
        move_into_place(self.dir, self.final)
        return self.final


def withhold_labels(scene_dir: Path, labels_dir: Path) -> None:
    """Move every entry of ``scene_dir`` except :data:`UNLABELLED_KEEP` to ``labels_dir`` (replacing it), with a
    copy of ``scene_camera.json``; ``labels_dir`` appears whole (assembled in a hidden sibling, then renamed)."""
    partial = private_partial_dir(labels_dir.parent, labels_dir.name)
    for entry in sorted(scene_dir.iterdir()):
        if entry.name not in UNLABELLED_KEEP:
            os.replace(entry, partial / entry.name)
    shutil.copyfile(scene_dir / "scene_camera.json", partial / "scene_camera.json")
    move_into_place(partial, labels_dir)


def move_into_place(partial: Path, final: Path) -> None:
    """Rename the finished folder ``partial`` to ``final``, replacing an older ``final``. When another writer
    put the same folder in place meanwhile (a straggling worker of a killed run making the same scene from the
    same seed, hence the same bytes), that one is kept and ``partial`` removed."""
    if final.exists():
        shutil.rmtree(final, ignore_errors=True)
    try:
        os.replace(partial, final)
    except OSError:
        if not final.is_dir():
            raise
        shutil.rmtree(partial, ignore_errors=True)
