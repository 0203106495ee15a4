"""The report's example pictures: the first image of each condition's dataset, as the estimators see it.

Image conditions (clean, occlusion, corruptions) and render conditions show their RGB; depth conditions
(image-space depth noise ``depth-<preset>`` and simulated sensors ``depth-<sensor>``) show their DEPTH map,
colourized (turbo, near blue, far red, over the 1st..99th percentile of the valid depths) with the invalid
pixels (depth 0) black, beside the clean depth drawn the same way. A condition's dataset is the one its pose
cells evaluated (``cell.json``), so a render condition that is the clean dataset shows the clean images.
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Example", "example_pictures", "DEPTH_FACTORS", "WIDTH"]

#: Condition factors whose picture is the depth map.
DEPTH_FACTORS: tuple[str, ...] = ("depth", "sensor")
#: Width of an example picture, pixels.
WIDTH = 240


@dataclass(frozen=True)
class Example:
    """One example picture: the condition, what the picture shows (``rgb`` | ``depth``), a caption and the
    JPEG bytes in base64."""

    condition: str
    channel: str
    caption: str
    jpeg_b64: str


def _dataset_of(cfg, out: Path, cond) -> Path:
    """The folder the condition's pose cells evaluated (recorded in their ``cell.json``), else where the sweep
    puts it."""
    from simtest.sweeps.cells import cell_dir

    for e in cfg.estimators:
        marker = cell_dir(out, e.name, cond.name, "pose") / "cell.json"
        try:
            return Path(json.loads(marker.read_text())["dataset"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
    clean = Path(cfg.dataset.path) if cfg.dataset.path else out / "data" / "clean"
    return clean if cond.factor == "clean" else out / "data" / cond.name


def _jpeg(rgb: np.ndarray, nearest: bool) -> str:
    import cv2

    h, w = rgb.shape[:2]
    size = (WIDTH, int(round(WIDTH * h / w)))
    small = cv2.resize(rgb, size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(small[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 85])
    return base64.b64encode(buf.tobytes()).decode("ascii")


def _depth_picture(scene: Path, im_id: int) -> tuple[np.ndarray, str]:
    """The colourized depth of one image and its caption (range, invalid fraction)."""
    from simtest.io.bop import read_depth
    from simtest.viz.channels import colourize_depth

    cams = json.loads((scene / "scene_camera.json").read_text())
    depth = read_depth(scene, im_id, float(cams[str(im_id)].get("depth_scale", 1.0)))
    pic = colourize_depth(depth)
    return pic.image, pic.caption.replace("holes (black)", "invalid (black)")


def _first_scene(data: Path, split: str) -> Path:
    from simtest.io.bop import scene_dirs

    return scene_dirs(data / split)[0]


def example_pictures(cfg, out: Path, conds) -> list[Example]:
    """One picture per condition (image 0 of the first scene of its dataset), in table order, with the clean
    depth first among the depth pictures; a condition whose dataset cannot be read is left out."""
    from simtest.io.bop import read_image

    found: list[Example] = []
    clean_depth_shown = False
    for c in conds:
        try:
            scene = _first_scene(_dataset_of(cfg, out, c), cfg.dataset.split)
            if c.factor not in DEPTH_FACTORS:
                found.append(Example(c.name, "rgb", c.name, _jpeg(read_image(scene, 0), nearest=False)))
                continue
            if not clean_depth_shown:
                clean = _first_scene(_dataset_of(cfg, out, conds[0]), cfg.dataset.split)
                img, caption = _depth_picture(clean, 0)
                found.append(Example("clean", "depth", f"clean depth: {caption}", _jpeg(img, nearest=True)))
                clean_depth_shown = True
            img, caption = _depth_picture(scene, 0)
            found.append(Example(c.name, "depth", f"{c.name} depth: {caption}", _jpeg(img, nearest=True)))
        except Exception:  # noqa: BLE001 - a picture is an illustration; a missing one must not fail the report
            continue
    return found
