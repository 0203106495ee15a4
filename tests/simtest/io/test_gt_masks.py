"""``simtest masks``: the ground-truth masks of a BOP set shipped without them, rendered from its poses and
models, agree with the masks the generator drew for the same frames (a dataset written by the real pipeline,
its masks removed); the real LM-O excerpt's rendered masks agree with its distributed pixel counts."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from simtest.cli import main
from simtest.errors import ConfigError
from simtest.io import bop
from simtest.io.bop_masks import visible_masks, write_gt_masks

REAL_LMO = Path(os.environ.get("SIMTEST_REAL_LMO") or Path(__file__).resolve().parents[4] / "shared" / "real" / "lmo")


def _without_masks(src: Path, dst: Path, keep_depth: bool) -> Path:
    """A copy of generated dataset ``src`` without ``mask*/`` (and without ``depth/`` unless ``keep_depth``)."""
    shutil.copytree(src, dst)
    for scene in bop.scene_dirs(dst / "train_pbr"):
        for sub in ("mask", "mask_visib") + (() if keep_depth else ("depth",)):
            shutil.rmtree(scene / sub)
    return dst


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union; 1 for two empty masks (an object outside the image in both)."""
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def _pairs(small_dataset: Path, rendered: Path):
    """(generator's mask, rendered mask, generator's visible mask, rendered visible mask, gt info) per instance."""
    for scene in bop.scene_dirs(small_dataset / "train_pbr"):
        mine = rendered / "train_pbr" / scene.name
        info = json.loads((scene / "scene_gt_info.json").read_text())
        for im, insts in info.items():
            for k, inf in enumerate(insts):
                yield (bop.read_mask(scene, int(im), k, visible=False), bop.read_mask(mine, int(im), k, visible=False),
                       bop.read_mask(scene, int(im), k), bop.read_mask(mine, int(im), k), inf)


def test_rendered_masks_match_the_generators_with_depth(small_dataset, tmp_path):
    """With depth (the BOP19 rule against measured depth), amodal and visible masks match the generator's:
    IoU >= 0.95 for every instance of 200 pixels or more (edge pixels differ between the GL rasterizer and the
    z-buffer's pixel-centre rule), and the source stays untouched (--out links to it)."""
    src = _without_masks(small_dataset, tmp_path / "src", keep_depth=True)
    assert main(["masks", "--data", str(src), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert not any((s / "mask").exists() for s in bop.scene_dirs(src / "train_pbr"))
    n = 0
    for m_gen, m_ren, v_gen, v_ren, inf in _pairs(small_dataset, tmp_path / "out"):
        if inf["px_count_all"] >= 200:
            assert _iou(m_gen, m_ren) >= 0.95
            n += 1
        if inf["px_count_visib"] >= 200:
            assert _iou(v_gen, v_ren) >= 0.9
        assert not (v_ren & ~m_ren).any()
    assert n >= 5
    out_scene = tmp_path / "out" / "train_pbr" / bop.scene_dirs(src / "train_pbr")[0].name
    assert (out_scene / "rgb").is_symlink() and (tmp_path / "out" / "models").is_symlink()


def test_without_depth_visibility_is_among_the_annotated_objects(small_dataset, tmp_path, capsys):
    """No depth: each pixel goes to the nearest annotated object (no overlap between visible masks of one
    image, each inside its amodal mask); occlusion by the unannotated distractors is not seen, so a visible
    mask holds at least the generator's."""
    src = _without_masks(small_dataset, tmp_path / "src", keep_depth=False)
    assert main(["masks", "--data", str(src), "--quiet"]) == 0  # in place
    for m_gen, m_ren, v_gen, v_ren, inf in _pairs(small_dataset, src):
        assert not (v_ren & ~m_ren).any()
        if inf["px_count_visib"] >= 200:
            assert (v_gen & v_ren).sum() >= 0.95 * v_gen.sum()
    capsys.readouterr()
    assert main(["masks", "--data", str(src), "--quiet"]) != 0
    err = capsys.readouterr().err
    assert "mask exists" in err and "pass --overwrite" in err
    assert main(["masks", "--data", str(src), "--quiet", "--overwrite"]) == 0
    with pytest.raises(ConfigError, match="inside the dataset"):
        write_gt_masks(src, {}, out_dir=src / "sub")


def test_visible_masks_by_nearest_object_and_by_measured_depth():
    K = np.array([[100.0, 0, 2], [0, 100.0, 2], [0, 0, 1]])
    near, far = np.zeros((5, 5)), np.zeros((5, 5))
    near[1:3, 1:3], far[1:4, 1:4] = 0.5, 1.0
    v_near, v_far = visible_masks([near, far], K)
    assert v_near.sum() == 4 and v_far.sum() == 5 and not (v_near & v_far).any()
    measured = np.full((5, 5), 0.7)  # something unannotated at 0.7 m hides the far object
    measured[3, :] = 0.0  # no reading: counted visible
    v_near, v_far = visible_masks([near, far], K, measured)
    assert v_near.sum() == 4 and v_far.sum() == 3  # only the row without a reading


def test_real_lmo_masks_agree_with_the_distributed_pixel_counts(tmp_path):
    """The real LM-O excerpt (no masks, no depth): the rendered amodal masks have the pixel counts of its
    scene_gt_info.json (px_count_all, made by the BOP toolkit) to within 1 % for the median instance."""
    if not (REAL_LMO / "test").is_dir():
        pytest.skip(f"the real LM-O excerpt is not at {REAL_LMO} (set SIMTEST_REAL_LMO to its folder)")
    assert main(["masks", "--data", str(REAL_LMO), "--out", str(tmp_path / "lmo"), "--quiet"]) == 0
    scene = tmp_path / "lmo" / "test" / "000002"
    info = json.loads((scene / "scene_gt_info.json").read_text())
    ratios = [bop.read_mask(scene, int(im), k, visible=False).sum() / g["px_count_all"]
              for im, insts in info.items() for k, g in enumerate(insts) if g["px_count_all"] > 0]
    assert abs(float(np.median(ratios)) - 1.0) < 0.01
