"""The report's example pictures: the first image of each condition's dataset, as the estimators see it.

Image conditions (clean, occlusion, corruptions) and render conditions show their RGB; depth conditions
(image-space depth noise ``depth-<preset>``, simulated sensors ``depth-<sensor>`` and ``[[renders]]`` that set
``render.depth_sensor``) show their DEPTH map,
colourized (turbo, near blue, far red, over the 1st..99th percentile of the clean image's valid depths, the
same range for every depth picture so their colours compare) with the invalid pixels (depth 0) black, beside
the clean depth drawn the same way. A condition's dataset is the one its pose
cells evaluated (``cell.json``), so a render condition that is the clean dataset shows the clean images.
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Example", "example_pictures", "depth_range", "colourize_depth_range", "DEPTH_FACTORS", "WIDTH"]

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


def _read_depth(scene: Path, im_id: int) -> np.ndarray:
    from simtest.io.bop import read_depth

    cams = json.loads((scene / "scene_camera.json").read_text())
    return read_depth(scene, im_id, float(cams[str(im_id)].get("depth_scale", 1.0)))


def depth_range(depth: np.ndarray) -> tuple[float, float]:
    """The 1st and 99th percentile of the valid depths, metres (``(0, 1)`` without any)."""
    valid = depth[depth > 0]
    if valid.size == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(valid, [1, 99])
    return float(lo), max(float(hi), float(lo) + 1e-6)


def colourize_depth_range(depth: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, str]:
    """Depth (H, W), metres, 0 = invalid, as the turbo colour map over ``[lo, hi]`` (near blue, far red;
    outside clipped), invalid pixels black; RGB uint8 and a caption (range, invalid fraction)."""
    import cv2

    d = np.asarray(depth, dtype=np.float32)
    valid = d > 0
    g = np.clip((d - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8)
    out = np.where(valid[..., None], cv2.applyColorMap(g, cv2.COLORMAP_TURBO)[..., ::-1], 0).astype(np.uint8)
    return out, f"{lo:.2f}-{hi:.2f} m (blue near, red far), {(~valid).mean() * 100:.1f}% invalid (black)"


def _first_scene(data: Path, split: str | None) -> Path:
    from simtest.io.bop import dataset_split_dir, scene_dirs

    return scene_dirs(dataset_split_dir(data, split))[0]


def example_pictures(cfg, out: Path, conds) -> list[Example]:
    """One picture per condition (image 0 of the first scene of its dataset), in table order, with the clean
    depth first among the depth pictures; a condition whose dataset cannot be read is left out."""
    from simtest.io.bop import read_image

    found: list[Example] = []
    span: tuple[float, float] | None = None
    for c in conds:
        try:
            scene = _first_scene(_dataset_of(cfg, out, c), cfg.dataset.split)
            if c.factor not in DEPTH_FACTORS and c.overrides.get("render.depth_sensor", "none") == "none":
                found.append(Example(c.name, "rgb", c.name, _jpeg(read_image(scene, 0), nearest=False)))
                continue
            if span is None:  # every depth picture over the clean depth's range, so colours compare
                clean = _read_depth(_first_scene(_dataset_of(cfg, out, conds[0]), cfg.dataset.split), 0)
                span = depth_range(clean)
                img, caption = colourize_depth_range(clean, *span)
                found.append(Example("clean", "depth", f"clean depth: {caption}", _jpeg(img, nearest=True)))
            img, caption = colourize_depth_range(_read_depth(scene, 0), *span)
            found.append(Example(c.name, "depth", f"{c.name} depth: {caption}", _jpeg(img, nearest=True)))
        except Exception:  # noqa: BLE001 - a picture is an illustration; a missing one must not fail the report
            continue
    return found
