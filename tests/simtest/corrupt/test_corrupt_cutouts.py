"""The ``objects`` occlusion kind: cutouts of a generated dataset's unoccluded objects pasted as occluders."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.cli import main
from simtest.corrupt import CorruptionSpec
from simtest.corrupt.cutouts import MIN_VISIB_FRACT, object_cutouts
from simtest.corrupt.dataset import corrupt_dataset, find_scenes
from simtest.errors import DatasetError
from simtest.io.bop import read_image, read_json, read_mask


def test_cutouts_are_unoccluded_objects_with_their_masks(small_dataset):
    scenes = find_scenes(small_dataset)
    cutouts = object_cutouts(scenes)
    assert 0 < len(cutouts) <= 64
    for c in cutouts:
        assert c.dtype == np.uint8 and c.ndim == 3 and c.shape[2] == 4
        alpha = c[..., 3] > 0
        assert alpha[0].any() and alpha[-1].any() and alpha[:, 0].any() and alpha[:, -1].any()  # tight crop
    # The first cutout is the first visible-enough instance in file order: same pixels, same mask.
    scene = scenes[0]
    infos = read_json(scene / "scene_gt_info.json")
    im, gt = next((int(k), g) for k, v in sorted(infos.items(), key=lambda kv: int(kv[0]))
                  for g, inf in enumerate(v) if inf["visib_fract"] >= MIN_VISIB_FRACT and inf["px_count_visib"] >= 64)
    mask = read_mask(scene, im, gt)
    ys, xs = np.nonzero(mask)
    crop = np.s_[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
    np.testing.assert_array_equal(cutouts[0][..., 3] > 0, mask[crop])
    np.testing.assert_array_equal(cutouts[0][..., :3], read_image(scene, im)[crop])


def test_objects_kind_pastes_cutouts(small_dataset):
    scenes = find_scenes(small_dataset)
    bank = object_cutouts(scenes)
    scene = scenes[0]
    rgb = read_image(scene, 0)
    n = len(read_json(scene / "scene_gt.json")["0"])
    masks = [read_mask(scene, 0, g) for g in range(n)]
    spec = CorruptionSpec(occlusion=2, occlusion_kind="objects")
    out, _, occ, info = spec.apply_with_info(rgb, None, masks, np.random.default_rng(0), None, occluder_bank=bank)
    assert occ.any() and not np.array_equal(out[occ], rgb[occ])
    assert set(info["kinds"]) <= {"bank", "none"} and "bank" in info["kinds"]
    # Without cutouts the objects kind pastes noise shapes, as the paste kind does, and says so.
    with pytest.warns(UserWarning, match="objects.*cutouts"):
        fallback = spec.apply(rgb, None, masks, np.random.default_rng(0), None)
    paste = CorruptionSpec(occlusion=2, occlusion_kind="paste").apply(rgb, None, masks, np.random.default_rng(0), None)
    assert np.array_equal(fallback[0], paste[0]) and np.array_equal(fallback[2], paste[2])


def test_objects_is_the_default_kind(small_dataset, tmp_path):
    assert CorruptionSpec().occlusion_kind == "objects" and CorruptionSpec(occlusion=1).label() == "occL1-objects"
    out = tmp_path / "occ"
    assert main(["corrupt", "--in", str(small_dataset), "--out", str(out), "--occlusion", "L1",
                 "--no-progress"]) == 0
    record = json.loads((out / "corruption.json").read_text())
    assert record["spec"]["occlusion_kind"] == "objects" and "cutout_fallback" not in record["occlusion"]
    assert record["occlusion"]["mean_fg_fraction"] > 0.1
    with pytest.raises(SystemExit):
        main(["corrupt", "--in", str(small_dataset), "--out", str(tmp_path / "x"), "--occlusion", "L1",
              "--occlusion-kind", "shapes"])


def test_a_dataset_without_masks_falls_back_to_noise_shapes(small_dataset, tmp_path, caplog, capsys):
    import shutil

    bare = tmp_path / "bare"
    shutil.copytree(small_dataset, bare)
    for scene in find_scenes(bare):
        shutil.rmtree(scene / "mask_visib")
    with pytest.raises(DatasetError, match="mask_visib"):
        object_cutouts(find_scenes(bare))
    with pytest.raises(DatasetError, match="mask_visib"):  # the library call falls back only when asked
        corrupt_dataset(bare, tmp_path / "strict", CorruptionSpec(occlusion=1), seed=0, progress=False)
    assert not (tmp_path / "strict").exists()
    with caplog.at_level("WARNING", logger="simtest.corrupt.dataset"):
        record = corrupt_dataset(bare, tmp_path / "lib", CorruptionSpec(occlusion=1), seed=0, progress=False,
                                 cutout_fallback=True)
    assert "object cutouts unavailable" in caplog.text and "mask_visib" in caplog.text
    assert record["spec"]["occlusion_kind"] == "paste" and "mask_visib" in record["occlusion"]["cutout_fallback"]
    out = tmp_path / "occ"
    assert main(["corrupt", "--in", str(bare), "--out", str(out), "--occlusion", "L1", "--no-progress"]) == 0
    assert "no object cutouts: noise shapes pasted" in capsys.readouterr().out
    record = json.loads((out / "corruption.json").read_text())
    assert record["spec"]["occlusion_kind"] == "paste" and "mask_visib" in record["occlusion"]["cutout_fallback"]
    # An explicit --occlusion-kind objects does not fall back.
    assert main(["corrupt", "--in", str(bare), "--out", str(tmp_path / "explicit"), "--occlusion", "L1",
                 "--occlusion-kind", "objects", "--no-progress"]) != 0
    assert "mask_visib" in capsys.readouterr().err


def test_corrupt_command_with_object_cutouts(small_dataset, tmp_path):
    out = tmp_path / "occ"
    rc = main(["corrupt", "--in", str(small_dataset), "--out", str(out), "--occlusion", "L2",
               "--occlusion-kind", "objects", "--no-progress"])
    assert rc == 0
    record = json.loads((out / "corruption.json").read_text())
    assert record["spec"]["occlusion_kind"] == "objects"
    assert record["occlusion"]["mean_fg_fraction"] > 0.2


def test_enlarged_cutouts_have_smooth_antialiased_outlines():
    """A cutout scaled up 12x keeps a straight diagonal outline (no steps as long as its source pixels), and
    its edge is blended into the image rather than cut at a hard pixel step."""
    from simtest.corrupt.occlusion import paste_occluders
    from simtest.corrupt.patches import bank_coverage, resample

    tri = np.tril(np.ones((8, 8), bool))  # the lower-left triangle: a 45 degree edge in 8 source pixels
    mask = bank_coverage(tri, 48.0) >= 0.5  # 96 x 96 pixels
    widths = mask.sum(axis=1)[10:-10].astype(int)  # the outline's x in each row, away from the corners
    steps = np.abs(np.diff(widths))
    assert mask.shape == (96, 96) and steps.max() <= 2, steps  # a staircase would step by 12 every 12 rows
    # Shrunk, a fine checkerboard averages to grey instead of aliasing into stripes.
    checker = ((np.indices((60, 60)).sum(axis=0) % 2) * 255).astype(np.uint8)
    assert np.abs(resample(checker, (17, 17)).astype(int) - 127).max() <= 4  # bilinear: up to 113
    # Pasted: some pixels just outside the occluder mask take a blend of the patch and the image.
    rgb = np.zeros((120, 160, 3), np.uint8)
    obj = np.zeros((120, 160), bool)
    obj[40:80, 60:100] = True
    white = np.dstack([np.full((8, 8, 3), 255, np.uint8), np.where(tri, 255, 0).astype(np.uint8)])
    out, occ, _ = paste_occluders(rgb, obj, "L2", np.random.default_rng(0), occluder_bank=[white])
    assert (out[occ] == 255).all()
    edge = out[~occ].max(axis=1)
    assert ((edge > 0) & (edge < 255)).any()
