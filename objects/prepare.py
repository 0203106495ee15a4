"""``prepare_objects``: fill an object set's on-disk caches before a run.

What an object needs is computed on its first use and cached by mesh hash under
:func:`~simtest.objects.cache.cache_dir` (``$SIMTEST_CACHE`` or ``~/.cache/simtest``): the CoACD convex
decomposition of a concave object (0.3-15 s of one core each for the built-in and test meshes) and, for a mesh
library read lazily, the detected symmetries of a mesh that declares none. Without this step the first scenes of
a run wait for them, and on a cluster with a cache per node every node computes each one again.
``simtest objects prepare`` computes them for the whole set, one object per unit of work on the local or Ray back
end (:mod:`simtest.backend`), and reports what was computed and what was already cached.

:func:`prepare_set` does the same for a set already loaded, in this process, with a progress bar naming the
object being worked on (:mod:`simtest.objects.progress`): ``simtest objects list`` uses it, and so can any
caller that is about to need every object's collision parts (a run about to build scenes).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from collections.abc import Iterable, Iterator
from typing import Any

from simtest.backend import Backend, RunStats, run_units
from simtest.objects.progress import ObjectProgress

__all__ = ["PreparedObject", "prepare_objects", "prepare_set"]

#: The object set of this worker process (set by :func:`_init`, or by the caller when units run in process).
_WORKER: dict[str, Any] = {}


@dataclass(frozen=True)
class PreparedObject:
    """What preparing one object did.

    Attributes:
        obj_id, name: The object.
        collision: ``"hull"`` (convex: its hull, nothing to cache), ``"computed"`` (decomposed now and cached),
            ``"cached"`` (the decomposition was already in the cache) or ``"skipped"`` (not asked for).
        parts: Convex collision parts (0 when skipped).
        seconds: Wall time to read the object (a lazily read mesh, its symmetries) and get its parts (and its
            grasp candidates when asked for).
    """

    obj_id: int
    name: str
    collision: str
    parts: int
    seconds: float


def _init(spec: dict) -> None:
    from simtest.objects import load_object_set

    _WORKER["objects"] = load_object_set(**spec)


def _prepare_one(obj_id: int) -> PreparedObject:
    return _prepare(_WORKER["objects"], obj_id)


def _prepare(objects: Any, obj_id: int, collision: bool = True, grasps: bool = False,
             bar: ObjectProgress | None = None) -> PreparedObject:
    """Read object ``obj_id`` of ``objects`` and compute what is asked for (``bar``: told when a decomposition
    is about to be computed, so that it shows at once)."""
    from simtest.objects.collision import decomposition_cache_path

    start = time.perf_counter()
    obj = objects.get(obj_id)  # a lazily read mesh is read (and its symmetries detected) here
    state, parts = "skipped", 0
    if collision or grasps:  # grasp candidates are checked against the collision parts
        path = decomposition_cache_path(obj)
        state = "hull" if path is None else ("cached" if path.exists() else "computed")
        if state == "computed" and bar is not None:
            bar.computing()
        parts = len(obj.collision_parts)
    if grasps:
        obj.grasps  # noqa: B018 - sampled and kept on the object
    return PreparedObject(obj.obj_id, obj.name, state, parts, time.perf_counter() - start)


def prepare_set(objects: Any, ids: Iterable[int] | None = None, *, collision: bool = True, grasps: bool = False,
                progress: bool | None = None) -> list[PreparedObject]:
    """Compute, in this process, what the objects of a loaded set need on first use, one object after the other
    under a progress bar (:class:`~simtest.objects.progress.ObjectProgress`: shown only when the work is slow,
    its description naming the object being worked on; work over 10 s ends with a line naming the slowest
    object). What is computed stays on the objects (and collision parts in the on-disk cache).

    Args:
        objects: The :class:`~simtest.objects.model.ObjectSet` (a lazy set reads the meshes here).
        ids: The objects, by ``obj_id`` (default: all, in set order).
        collision: Get every object's convex collision parts (a CoACD decomposition of a concave object that is
            not in the cache is computed and cached: seconds to tens of seconds each for scanned meshes).
        grasps: Also sample every object's grasp candidates (kept on the object; implies the collision parts).
        progress: Draw the bar and the closing line on stderr (``None``: unless the ``simtest`` logger is set
            to errors only, as ``--quiet`` does; see :func:`~simtest.objects.progress.progress_enabled`).

    Returns:
        One :class:`PreparedObject` per object, in the order of ``ids``.

    Raises:
        AssetError: An unknown id, or a lazily read mesh that cannot be read (naming its file).
    """
    by_id = {e.obj_id: e for e in objects.entries}  # names without reading a lazy set's meshes
    ids = list(by_id) if ids is None else list(ids)
    for i in ids:
        if i not in by_id:
            objects.get(i)  # raises, listing the known ids
    chosen = [by_id[i] for i in ids]
    what = "collision parts + grasps" if grasps else "collision parts" if collision else "read"
    done: list[PreparedObject] = []
    with ObjectProgress(len(chosen), what, progress) as bar:
        for entry in chosen:
            with bar.step(entry.name):
                done.append(_prepare(objects, entry.obj_id, collision, grasps, bar))
    return done


def prepare_objects(spec: str = "builtin", *, units: str = "auto", seed: int = 0, scale: float = 1.0,
                    symmetry: str = "auto", backend: Backend = Backend(), progress: bool = True,
                    stats: RunStats | None = None) -> list[PreparedObject]:
    """Compute and cache what every object of a set needs (see the module docstring).

    Args:
        spec, units, seed, scale, symmetry: The object set, as :func:`~simtest.objects.load_object_set` takes it
            (each worker process loads it the same way).
        backend: Where the objects are prepared, one unit per object.
        progress: Show a progress bar with ETA on stderr when the work is slow, and a line naming the slowest
            object when it took over 10 s (:class:`~simtest.objects.progress.ObjectProgress`).
        stats: Filled with what the back end did.

    Returns:
        One :class:`PreparedObject` per object, by ``obj_id``.

    Raises:
        AssetError: The set cannot be loaded (unknown name, missing path, bad mesh).
        BackendError: The back end cannot start, or objects were lost with their workers.
    """
    from simtest.backend import preflight
    from simtest.objects import load_object_set

    set_spec = {"spec": str(spec), "units": units, "seed": seed, "scale": scale, "symmetry": symmetry}
    objects = load_object_set(**set_spec)  # errors in the set are raised here, before any worker starts
    ids = [e.obj_id for e in objects.entries]
    preflight(backend)
    _WORKER["objects"] = objects  # used when the units run in this process
    done: list[PreparedObject] = []
    try:
        results: Iterator[PreparedObject] = run_units(_prepare_one, ids, backend, init=_init,
                                                      init_args=(set_spec,), stats=stats)
        with ObjectProgress(len(ids), "prepare", progress) as bar:
            for result in results:
                done.append(result)
                bar.advance(result.name, result.seconds)
    finally:
        _WORKER.clear()  # the set is not kept alive by this module after the call
    return sorted(done, key=lambda r: r.obj_id)
