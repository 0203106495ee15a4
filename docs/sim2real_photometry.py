"""How bright a dataset's objects are against their own models' colours and against the whole image
(docs/sim2real.md, thirteenth round): a render's photometric gap to a real camera, measured without a network.

Per instance with at least ``--min-pixels`` visible pixels: the mean RGB of its visible pixels divided by the mean
vertex colour of its model (both sRGB values), averaged per object; per dataset the image mean (0-255) and the
objects' mean ratio. Models without vertex colours are skipped with a message. Run from the repository root::

    python docs/sim2real_photometry.py LMO-masked data/lmo-clutter-pbr --scenes 6
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.io import bop  # noqa: E402
from simtest.io.bop_splits import dataset_split_dir, scene_dirs  # noqa: E402


def vertex_colours(data: Path) -> dict[int, np.ndarray]:
    """``{obj_id: mean vertex colour (3,) sRGB 0-255}`` of the dataset's BOP models (``models/obj_*.ply``) that
    carry vertex colours."""
    import trimesh

    out = {}
    for path in sorted((data / "models").glob("obj_*.ply")):
        mesh = trimesh.load(path, process=False)
        if getattr(mesh.visual, "kind", None) != "vertex":
            print(f"{path}: no vertex colours, skipped", file=sys.stderr)
            continue
        out[int(path.stem.split("_")[1])] = np.asarray(mesh.visual.vertex_colors, np.float64)[:, :3].mean(0)
    if not out:
        raise SystemExit(f"{data / 'models'}: no BOP model (obj_*.ply) with vertex colours")
    return out


def measure(data: Path, scenes: int | None, images: int | None, min_pixels: int) -> dict:
    """``{"image_mean": (3,), "ratio": {obj_id: mean ratio}, "instances": n}`` over the dataset's first
    ``scenes`` scenes and their first ``images`` images (None: all)."""
    models = vertex_colours(data)
    per: dict[int, list[float]] = {}
    image_means = []
    for scene in scene_dirs(dataset_split_dir(data))[:scenes]:
        ann = bop.read_scene(scene)
        for im in sorted(ann)[:images]:
            rgb = bop.read_image(scene, im).astype(np.float64)
            image_means.append(rgb.reshape(-1, 3).mean(0))
            for g, gt in enumerate(ann[im]["gt"]):
                if int(gt.obj_id) not in models:
                    continue
                mask = bop.read_mask(scene, im, g, visible=True)
                if int(mask.sum()) < min_pixels:
                    continue
                per.setdefault(int(gt.obj_id), []).append(float((rgb[mask].mean(0) / models[int(gt.obj_id)]).mean()))
    return {"image_mean": np.mean(image_means, 0) if image_means else np.full(3, np.nan),
            "ratio": {o: float(np.mean(v)) for o, v in sorted(per.items())},
            "instances": sum(len(v) for v in per.values())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, nargs="+", help="BOP datasets with mask_visib/ (a real set: simtest masks)")
    ap.add_argument("--scenes", type=int, default=None, help="the first N scenes of each dataset only")
    ap.add_argument("--images", type=int, default=None, help="the first N images of each scene only")
    ap.add_argument("--min-pixels", type=int, default=200)
    args = ap.parse_args(argv)
    for data in args.data:
        m = measure(data, args.scenes, args.images, args.min_pixels)
        ratios = m["ratio"]
        mean = float(np.mean(list(ratios.values()))) if ratios else float("nan")
        print(f"{data}: image mean {' '.join(f'{v:.0f}' for v in m['image_mean'])}, objects at {mean:.2f} of their "
              f"vertex colours ({m['instances']} instances; "
              + ", ".join(f"{o}: {r:.2f}" for o, r in ratios.items()) + ")")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
