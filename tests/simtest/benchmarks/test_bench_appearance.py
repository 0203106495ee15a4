"""The chromaticity spread inside objects: hand-made BOP files with known values, and a generated dataset."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from simtest.benchmarks.appearance import EDGE, chromaticity_spread, instance_spread
from simtest.errors import DatasetError


def write_scene(root, images: list[tuple[np.ndarray, list[tuple[int, np.ndarray]]]], categories: dict[int, str]):
    """A one-scene ``train_pbr`` split: each image with its (obj_id, visible mask) instances."""
    scene = root / "train_pbr" / "000000"
    for sub in ("rgb", "mask_visib"):
        (scene / sub).mkdir(parents=True)
    gt = {}
    for im_id, (rgb, instances) in enumerate(images):
        cv2.imwrite(str(scene / "rgb" / f"{im_id:06d}.png"), rgb[..., ::-1])
        gt[str(im_id)] = [{"obj_id": obj_id, "cam_R_m2c": list(np.eye(3).ravel()), "cam_t_m2c": [0, 0, 500]}
                          for obj_id, _ in instances]
        for k, (_, mask) in enumerate(instances):
            cv2.imwrite(str(scene / "mask_visib" / f"{im_id:06d}_{k:06d}.png"), mask.astype(np.uint8) * 255)
    (scene / "scene_gt.json").write_text(json.dumps(gt))
    (root / "models").mkdir()
    (root / "models" / "simtest_objects.json").write_text(
        json.dumps({str(i): {"name": f"{c}_0", "category": c} for i, c in categories.items()}))


def square(x0, y0, side, shape=(120, 160)):
    mask = np.zeros(shape, dtype=bool)
    mask[y0:y0 + side, x0:x0 + side] = True
    return mask


def test_known_values_per_instance_and_category(tmp_path):
    rgb = np.full((120, 160, 3), 90, dtype=np.uint8)  # grey background
    two = square(10, 10, 40)  # 1600 px; 36 x 36 inside the EDGE
    rgb[10:50, 10:30] = (200, 0, 0)  # left half red, right half green (18 inner columns each)
    rgb[10:50, 30:50] = (0, 200, 0)
    flat = square(80, 10, 30)
    rgb[10:40, 80:110] = (40, 120, 200)
    dark = square(80, 60, 30)
    rgb[60:90, 80:110] = (5, 5, 5)  # r + g + b <= 30: left out
    tiny = square(10, 80, 15)  # 225 px < 400: left out
    rgb[80:95, 10:25] = (250, 0, 0)
    write_scene(tmp_path, [(rgb, [(1, two), (2, flat), (2, dark), (3, tiny)])], {1: "can", 2: "box", 3: "mug"})
    out = chromaticity_spread(tmp_path)
    assert out["instances"] == 2
    assert out["per_category"]["can"]["mean"] == pytest.approx(np.sqrt(0.5), abs=1e-9)  # sqrt(0.25 + 0.25)
    assert out["per_category"]["box"]["instances"] == 1
    assert out["per_category"]["box"]["mean"] == pytest.approx(0.0, abs=1e-12)
    assert "mug" not in out["per_category"]
    assert out["mean"] == pytest.approx(np.sqrt(0.5) / 2, abs=1e-9)
    assert out["median"] == pytest.approx(np.sqrt(0.5) / 2, abs=1e-9)


def test_border_pixels_are_left_out():
    rgb = np.zeros((40, 40, 3), dtype=np.uint8)
    rgb[...] = (0, 0, 200)
    rgb[10:30, 10:30] = (200, 0, 0)
    mask = np.zeros((40, 40), dtype=bool)
    mask[10 - EDGE:30 + EDGE, 10 - EDGE:30 + EDGE] = True  # the object's colour ends EDGE pixels inside
    assert instance_spread(rgb, mask) == pytest.approx(0.0, abs=1e-12)
    assert instance_spread(rgb, np.zeros((40, 40), dtype=bool)) is None


def test_missing_split_is_a_dataset_error(tmp_path):
    with pytest.raises(DatasetError, match="no split folder"):
        chromaticity_spread(tmp_path, split="test")


def test_generated_dataset_is_measured(tmp_path):
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import generate

    cfg = GenerateConfig.from_dict({"objects": "builtin-small", "scenes": 1, "frames_per_scene": 2, "seed": 3,
                                    "camera": {"width": 160, "height": 120}})
    generate(cfg, tmp_path / "ds")
    out = chromaticity_spread(tmp_path / "ds")
    assert out["instances"] >= 1 and 0.0 < out["mean"] < 0.5
    assert set(out["per_category"]) <= {"box", "can", "mug", "banana"}
    assert sum(c["instances"] for c in out["per_category"].values()) == out["instances"]
