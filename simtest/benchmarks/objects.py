"""``simtest bench objects``: what a large mesh library costs: load time and first-scene time, small vs large set.

A ``category/instance.ext`` tree of generated meshes (:func:`write_mesh_tree`: boxes, cylinders, cones,
ellipsoids, capsules and hexagonal prisms with perturbed sizes, OBJ and PLY) is written for each set size; each is read
with :func:`simtest.objects.load_object_set` (lazily) and one scene of it is generated with
:func:`simtest.generators.pipeline.generate`, each size against its own empty on-disk cache
(``$SIMTEST_CACHE``), so both pay for the symmetry detection of the objects their scene uses. The ratios
large / small show whether a scene's cost depends on the size of the set it draws from.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["write_mesh_tree", "bench_objects", "ObjectsBench", "SHAPES"]

#: Shape of each category, by category index modulo their number.
SHAPES = ("box", "cylinder", "cone", "ellipsoid", "capsule", "prism")


def _shape(kind: str, size: np.ndarray):
    """One mesh (metres, watertight) of ``kind`` with extents about ``size`` (3,)."""
    import trimesh

    if kind == "box":
        return trimesh.creation.box(size)
    if kind == "cylinder":
        return trimesh.creation.cylinder(radius=size[0] / 2, height=size[2], sections=24)
    if kind == "cone":
        return trimesh.creation.cone(radius=size[0] / 2, height=size[2], sections=24)
    if kind == "ellipsoid":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
        mesh.apply_scale(size)
        return mesh
    if kind == "capsule":
        return trimesh.creation.capsule(height=size[2], radius=size[0] / 3, count=[16, 8])
    if kind == "prism":
        return trimesh.creation.cylinder(radius=size[0] / 2, height=size[2], sections=6)
    raise ValueError(f"unknown shape {kind!r}; known: {', '.join(SHAPES)}")


def write_mesh_tree(root: str | Path, objects: int, categories: int, seed: int = 0) -> Path:
    """Write ``objects`` generated meshes into ``root/<category>/<instance>.(obj|ply)``, spread evenly over
    ``categories`` folders (``cat000_box`` ...), each instance a perturbed copy of its category's shape
    (sizes 3-9 cm, a small random shear); every other file is PLY. Deterministic for ``seed``.

    Returns:
        ``root`` as a Path.
    """
    if not 1 <= categories <= objects:
        raise ValueError(f"need 1 <= categories <= objects, got {categories} categories for {objects} objects")
    rng = np.random.default_rng(seed)
    root = Path(root)
    for i in range(objects):
        c = i % categories
        kind = SHAPES[c % len(SHAPES)]
        base = np.random.default_rng([seed, c]).uniform(0.03, 0.07, 3)
        mesh = _shape(kind, base * rng.uniform(0.8, 1.25, 3))
        shear = np.eye(4)
        shear[0, 2] = rng.uniform(-0.1, 0.1)
        mesh.apply_transform(shear)
        folder = root / f"cat{c:03d}_{kind}"
        folder.mkdir(parents=True, exist_ok=True)
        mesh.export(folder / f"{kind}_{i // categories:03d}.{'ply' if i % 2 else 'obj'}")
    return root


@dataclass
class ObjectsBench:
    """Seconds to read each set and to generate its first scene, and how many objects that scene read."""

    sizes: tuple[int, ...]
    categories: tuple[int, ...]
    load_s: tuple[float, ...]
    scene_s: tuple[float, ...]
    models_written: tuple[int, ...]

    def table(self) -> str:
        rows = ["| objects in the set | categories | load (s) | first scene (s) | models written |",
                "|---:|---:|---:|---:|---:|"]
        for n, c, lo, sc, m in zip(self.sizes, self.categories, self.load_s, self.scene_s, self.models_written):
            rows.append(f"| {n} | {c} | {lo:.3f} | {sc:.2f} | {m} |")
        a, b = 0, len(self.sizes) - 1
        rows.append(f"| ratio {self.sizes[b]} / {self.sizes[a]} | | {self.load_s[b] / self.load_s[a]:.2f} | "
                    f"{self.scene_s[b] / self.scene_s[a]:.2f} | |")
        return "\n".join(rows)


def _one(tmp: Path, n: int, categories: int, width: int, height: int, objects_per_scene: int
         ) -> tuple[float, float, int]:
    import json

    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import generate
    from simtest.objects import load_object_set

    tree = write_mesh_tree(tmp / f"tree{n}", n, categories)
    t0 = time.perf_counter()
    objects = load_object_set(tree, lazy=True)
    load_s = time.perf_counter() - t0
    del objects
    cfg = GenerateConfig().replace(**{
        "objects": str(tree), "scenes": 1, "frames_per_scene": 1, "camera.width": width, "camera.height": height,
        "scene.objects_per_scene": [objects_per_scene, objects_per_scene], "seed": 1})
    t0 = time.perf_counter()
    generate(cfg, tmp / f"ds{n}", progress=False)
    scene_s = time.perf_counter() - t0
    models = json.loads((tmp / f"ds{n}" / "models" / "models_info.json").read_text())
    return load_s, scene_s, len(models)


def bench_objects(sizes: tuple[int, int] = (20, 200), categories: tuple[int, int] = (4, 40), width: int = 320,
                  height: int = 240, objects_per_scene: int = 5) -> ObjectsBench:
    """Load time and first-scene generation time (seconds) of a small and a large generated mesh library.

    Args:
        sizes: Objects in each set.
        categories: Categories of each set (same length as ``sizes``).
        width, height: Image size of the scene (pixels); one frame.
        objects_per_scene: Objects drawn into the scene.
    """
    if len(sizes) != len(categories) or len(sizes) < 2:
        raise ValueError(f"need two or more sizes with one category count each, got {sizes} and {categories}")
    old = os.environ.get("SIMTEST_CACHE")
    out = []
    try:
        with tempfile.TemporaryDirectory(prefix="simtest-bench-objects-") as tmp:
            for n, c in zip(sizes, categories):
                os.environ["SIMTEST_CACHE"] = str(Path(tmp) / f"cache{n}")  # each size starts cold
                out.append(_one(Path(tmp), n, c, width, height, objects_per_scene))
    finally:
        if old is None:
            os.environ.pop("SIMTEST_CACHE", None)
        else:
            os.environ["SIMTEST_CACHE"] = old
    load_s, scene_s, models = zip(*out)
    return ObjectsBench(tuple(sizes), tuple(categories), load_s, scene_s, models)
