"""How precisely template matching pins a found object's depth, given its exact rotation (docs/sim2real.md).

Per target (``visib_fract >= 0.5``) of a BOP dataset: the template of the object at its ground-truth rotation
is rendered (as the ``templates`` estimator renders them), the crop is framed where that template would put
the object at its ground-truth pose, and the estimator's framing search runs against this one template in fine
steps (the ``polish`` stage: aim steps from 2 % down to 0.25 % of the window). The pose the searched framing
implies is compared with the ground truth: its depth over the true depth, its translation error, and whether
the translation alone is within 0.1 of the object's diameter (what ADD(-S)-0.1d asks of a pose whose rotation
is exact), also after dividing the translation by a few depth factors. Ground truth is used to set the start
and to score; the search itself sees only the image. Run from the repository root::

    python docs/sim2real_depth.py LMO --images 20                  # real frames
    python docs/sim2real_depth.py data/lmo-val --images 20         # simtest renders of the same objects
    python docs/sim2real_depth.py data/lmo-val --images 20 --blur 1.5   # the renders blurred (sigma, pixels)
    python docs/sim2real_depth.py LMO --images 50 --background 128      # templates on grey, not black
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.estimators.templates.bank import RENDER_SIZE, BankSettings, render_intrinsics, render_templates  # noqa: E402
from simtest.estimators.templates.crops import ray_rotation  # noqa: E402
from simtest.estimators.templates.encoder import FeatureEncoder  # noqa: E402
from simtest.estimators.templates.export import default_encoder  # noqa: E402
from simtest.estimators.templates.framing import framing_search  # noqa: E402
from simtest.estimators.templates.match import template_pose, template_weights  # noqa: E402
from simtest.estimators.templates.render import ObjectRenderer  # noqa: E402
from simtest.io import bop  # noqa: E402
from simtest.metrics.intervals import wilson_interval  # noqa: E402
from simtest.io.bop_splits import dataset_split_dir, scene_dirs  # noqa: E402
from simtest.objects.loaders import load_dataset_objects  # noqa: E402

FACTORS = (1.0, 1.005, 1.01, 1.015, 1.02)


def measure(data: Path, images: int, size: int, blur: float, background: int = 0, min_visib: float = 0.5
            ) -> np.ndarray:
    """Rows ``(obj_id, depth ratio, translation error m, diameter m)`` over ``images`` images spread evenly
    through the dataset (see the module doc)."""
    objects = load_dataset_objects(data)
    settings = BankSettings(size=int(size), background=int(background))
    encoder = FeatureEncoder(settings.stride, str(default_encoder()), 2)
    renderers: dict[int, ObjectRenderer] = {}
    refs = [(s, im, d) for s in scene_dirs(dataset_split_dir(data)) for im, d in sorted(bop.read_scene(s).items())]
    rows = []
    for scene, im, d in refs[::max(1, len(refs) // images)][:images]:
        rgb = bop.read_image(scene, im)
        if blur > 0:
            rgb = cv2.GaussianBlur(rgb, (0, 0), blur)
        K = np.asarray(d["K"], np.float64)
        for g in d["gt"]:
            if g.visib_fract < min_visib or g.obj_id not in objects.ids:
                continue
            obj = objects.get(g.obj_id)
            if obj.obj_id not in renderers:
                renderers[obj.obj_id] = ObjectRenderer(obj, render_intrinsics(obj, settings), RENDER_SIZE,
                                                       RENDER_SIZE)
            R, t = np.asarray(g.T_cam_obj.R, np.float64), np.asarray(g.T_cam_obj.t, np.float64)
            uv = (K @ t)[:2] / t[2]
            bank = render_templates(renderers[obj.obj_id], (ray_rotation(K, uv) @ R)[None], settings, encoder)
            side = K[0, 0] * settings.size * bank.t[0][2] / (np.linalg.norm(t) * bank.K[0][0, 0])
            fr = framing_search(rgb, K, uv, side, 0.0, encoder, template_weights(bank), settings.size,
                                shift=0.02, scale=0.03, roll_deg=2.0, min_shift=0.0025)
            _, t_est = template_pose(bank, 0, fr.crop.K, fr.crop.R_virt)
            rows.append((obj.obj_id, t_est[2] / t[2], *[np.linalg.norm(t_est / f - t) for f in FACTORS],
                         float(obj.diameter)))
    for r in renderers.values():
        r.close()
    return np.array(rows, np.float64)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="BOP dataset (models/, a split with scene_gt.json)")
    ap.add_argument("--images", type=int, default=20, help="images, spread evenly through the dataset")
    ap.add_argument("--size", type=int, default=128, help="crop size of the templates and queries (pixels)")
    ap.add_argument("--blur", type=float, default=0.0, help="Gaussian blur of the images first (sigma, pixels)")
    ap.add_argument("--background", type=int, default=0, help="grey level behind the templates (0-255)")
    args = ap.parse_args(argv)
    r = measure(args.data, args.images, args.size, args.blur, args.background)
    if not len(r):
        print("no target with visib_fract >= 0.5")
        return 1
    ratio, diam = r[:, 1], r[:, -1]
    print(f"{len(r)} targets: depth ratio median {np.median(ratio):.4f} (quartiles {np.percentile(ratio, 25):.4f}"
          f" - {np.percentile(ratio, 75):.4f})")
    for k, f in enumerate(FACTORS):
        te = r[:, 2 + k]
        hits = int(np.sum(te < 0.1 * diam))
        lo, hi = wilson_interval(hits, len(te))
        print(f"translation / {f:.3f}: median error {1000 * np.median(te):.1f} mm, within 0.1 d {hits} of "
              f"{len(te)} = {100 * hits / len(te):.1f} % [{100 * lo:.1f}, {100 * hi:.1f}]")
    for o in np.unique(r[:, 0]):
        m = r[:, 0] == o
        print(f"  obj {int(o)}: {int(m.sum())} targets, depth ratio median {np.median(ratio[m]):.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
