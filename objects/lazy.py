"""Object sets whose meshes are read on first use: large mesh libraries (``category/instance.ext`` trees).

Reading such a folder gives every object's id, name, category and file at once (from the paths and the
manifest, no mesh is opened); the mesh, its appearance, its detected symmetries and everything derived from
them (collision parts, grasp candidates) are made only when the object is asked for by id, and kept. A scene
that uses five objects of a 200-object library therefore costs what it costs with a 5-object set.

``LazyObjectSet`` is an :class:`~simtest.objects.model.ObjectSet`: ``ids``, ``categories``, ``entries``,
``len``, ``by_name`` and ``subset`` never read meshes; ``get(obj_id)`` reads one object; iterating reads them
all (as an eager set would have at load time).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator

from simtest.errors import AssetError
from simtest.objects.model import ObjectEntry, ObjectModel, ObjectSet

__all__ = ["LazyObjectSet"]

#: Reads one object of the set from its entry.
Loader = Callable[[ObjectEntry], ObjectModel]


class LazyObjectSet(ObjectSet):
    """An object set that reads each object when it is first asked for (see the module docstring).

    Args:
        entries: One per object (unique ids); kept in id order.
        loader: Makes the :class:`ObjectModel` of an entry (its ``obj_id``, ``name`` and ``category`` must
            be the entry's).
        name: Name of the set (the folder path).
    """

    lazy = True

    def __init__(self, entries: Iterable[ObjectEntry], loader: Loader, name: str = "custom",
                 _models: dict[int, ObjectModel] | None = None) -> None:
        self.name = name
        self._entries = sorted(entries, key=lambda e: e.obj_id)
        self._loader = loader
        self._by_entry: dict[int, ObjectEntry] = {}
        for e in self._entries:
            if e.obj_id in self._by_entry:
                raise AssetError(f"object set {name!r}: duplicate obj_id {e.obj_id} ({self._by_entry[e.obj_id].source}"
                                 f" and {e.source})")
            self._by_entry[e.obj_id] = e
        self._models: dict[int, ObjectModel] = {} if _models is None else _models

    # --- metadata only ---------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._entries)

    @property
    def ids(self) -> list[int]:
        return [e.obj_id for e in self._entries]

    @property
    def entries(self) -> list[ObjectEntry]:
        return list(self._entries)

    @property
    def categories(self) -> list[str]:
        return sorted({e.category for e in self._entries})

    @property
    def loaded_ids(self) -> list[int]:
        """Ids of the objects read so far (sorted)."""
        return sorted(self._models)

    def subset(self, obj_ids: Iterable[int], name: str | None = None) -> "LazyObjectSet":
        entries = [self._entry(i) for i in obj_ids]
        return LazyObjectSet(entries, self._loader, name or f"{self.name}-subset", _models=self._models)

    def mapped(self, transform: Callable[[ObjectModel], ObjectModel]) -> "LazyObjectSet":
        """The same set with ``transform`` applied to every object as it is read (keeps id, name, category)."""
        loader = self._loader
        return LazyObjectSet(self._entries, lambda e: transform(loader(e)), self.name)

    # --- reading objects -------------------------------------------------------------------------------------
    def _entry(self, obj_id) -> ObjectEntry:
        try:
            return self._by_entry[int(obj_id)]
        except (KeyError, TypeError, ValueError):
            raise self._unknown_id(obj_id) from None

    def get(self, obj_id: int) -> ObjectModel:
        """The object with ``obj_id``, read on first use; :class:`AssetError` listing the known ids if there is
        none, or naming the file when it cannot be read."""
        entry = self._entry(obj_id)
        obj = self._models.get(entry.obj_id)
        if obj is None:
            obj = self._loader(entry)
            if (obj.obj_id, obj.name, obj.category) != (entry.obj_id, entry.name, entry.category):
                raise AssetError(f"{entry.source}: read as obj_id {obj.obj_id} {obj.name!r} ({obj.category}), "
                                 f"listed as obj_id {entry.obj_id} {entry.name!r} ({entry.category})")
            self._models[entry.obj_id] = obj
        return obj

    def __getitem__(self, index):  # type: ignore[override]
        if isinstance(index, slice):
            return [self.get(e.obj_id) for e in self._entries[index]]
        return self.get(self._entries[index].obj_id)

    def __iter__(self) -> Iterator[ObjectModel]:
        return (self.get(e.obj_id) for e in self._entries)

    def __repr__(self) -> str:
        return f"LazyObjectSet(name={self.name!r}, {len(self)} objects, {len(self._models)} read)"
