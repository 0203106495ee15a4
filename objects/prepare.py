"""``prepare_objects``: fill an object set's on-disk caches before a run.

What an object needs is computed on its first use and cached by mesh hash under
:func:`~simtest.objects.cache.cache_dir` (``$SIMTEST_CACHE`` or ``~/.cache/simtest``): the CoACD convex
decomposition of a concave object (0.3-15 s of one core each for the built-in and test meshes) and, for a mesh
library read lazily, the detected symmetries of a mesh that declares none. Without this step the first scenes of
a run wait for them, and on a cluster with a cache per node every node computes each one again.
``simtest objects prepare`` computes them for the whole set, one object per unit of work on the local or Ray back
end (:mod:`simtest.backend`), and reports what was computed and what was already cached.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Iterator

from simtest.backend import Backend, RunStats, run_units

__all__ = ["PreparedObject", "prepare_objects"]

#: The object set of this worker process (set by :func:`_init`, or by the caller when units run in process).
_WORKER: dict[str, Any] = {}


@dataclass(frozen=True)
class PreparedObject:
    """What preparing one object did.

    Attributes:
        obj_id, name: The object.
        collision: ``"hull"`` (convex: its hull, nothing to cache), ``"computed"`` (decomposed now and cached)
            or ``"cached"`` (the decomposition was already in the cache).
        parts: Convex collision parts.
        seconds: Wall time to read the object (a lazily read mesh, its symmetries) and get its parts.
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
    from simtest.objects.collision import decomposition_cache_path

    start = time.perf_counter()
    obj = _WORKER["objects"].get(obj_id)  # a lazily read mesh is read (and its symmetries detected) here
    path = decomposition_cache_path(obj)
    collision = "hull" if path is None else ("cached" if path.exists() else "computed")
    parts = len(obj.collision_parts)
    return PreparedObject(obj.obj_id, obj.name, collision, parts, time.perf_counter() - start)


def prepare_objects(spec: str = "builtin", *, units: str = "auto", seed: int = 0, scale: float = 1.0,
                    symmetry: str = "auto", backend: Backend = Backend(), progress: bool = True,
                    stats: RunStats | None = None) -> list[PreparedObject]:
    """Compute and cache what every object of a set needs (see the module docstring).

    Args:
        spec, units, seed, scale, symmetry: The object set, as :func:`~simtest.objects.load_object_set` takes it
            (each worker process loads it the same way).
        backend: Where the objects are prepared, one unit per object.
        progress: Show a progress bar with ETA on stderr.
        stats: Filled with what the back end did.

    Returns:
        One :class:`PreparedObject` per object, by ``obj_id``.

    Raises:
        AssetError: The set cannot be loaded (unknown name, missing path, bad mesh).
        BackendError: The back end cannot start, or objects were lost with their workers.
    """
    from tqdm import tqdm

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
        with tqdm(total=len(ids), desc="prepare", unit="obj", disable=not progress, dynamic_ncols=True) as bar:
            for result in results:
                done.append(result)
                bar.set_postfix_str(result.name, refresh=False)
                bar.update()
    finally:
        _WORKER.clear()  # the set is not kept alive by this module after the call
    return sorted(done, key=lambda r: r.obj_id)
