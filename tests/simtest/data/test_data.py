"""simtest.data: sample contents and units, keypoint projections, seeded transforms, workers, imports."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from simtest.io import bop


def test_import_without_torch():
    """simtest, simtest.data and simtest.estimators (incl. the keypoints package) import with torch blocked."""
    code = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'torch' or name.startswith('torch.'):\n"
        "            raise ImportError('torch blocked')\n"
        "sys.meta_path.insert(0, Block())\n"
        "import simtest, simtest.data, simtest.estimators, simtest.estimators.keypoints, simtest.evaluation.run\n"
        "from simtest.data import PoseDataset, augmentation, collate\n"
        "import simtest.cli.train\n"
        "assert 'torch' not in sys.modules\n"
        "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


torch = pytest.importorskip("torch")

from simtest.data import (Compose, Corrupt, PoseDataset, RandomCorrupt, augmentation, canonical_symmetry,  # noqa: E402
                          collate, project_points, sample_rng)
from simtest.errors import ConfigError  # noqa: E402


def test_sample_shapes_units_and_keypoints(small_dataset):
    ds = PoseDataset(small_dataset)
    assert len(ds) == 6
    s = ds[0]
    n = len(s["obj_ids"])
    assert n >= 1
    assert s["rgb"].shape == (3, 120, 160) and s["rgb"].dtype == torch.float32
    assert 0.0 <= float(s["rgb"].min()) and float(s["rgb"].max()) <= 1.0
    assert s["depth"].shape == (1, 120, 160)
    d = s["depth"][s["depth"] > 0]
    assert 0.2 < float(d.min()) and float(d.max()) < 5.0  # metres, not millimetres
    assert s["masks"].shape == (n, 120, 160) and s["masks"].dtype == torch.bool
    assert s["keypoints_2d"].shape == (n, 8, 2) and s["keypoints_3d"].shape == (n, 8, 3)
    assert s["R"].shape == (n, 3, 3) and s["t"].shape == (n, 3) and s["boxes"].shape == (n, 4)
    assert set(s["labels"].tolist()) <= set(range(1, ds.num_classes + 1))
    # ground truth agrees with the files
    scene_dir = sorted((small_dataset / "train_pbr").iterdir())[0]
    gt = bop.read_scene(scene_dir)[s["im_id"]]
    assert np.allclose(s["K"].numpy(), gt["K"])
    assert np.allclose(s["t"].numpy(), [g.T_cam_obj.t for g in gt["gt"]][:n])
    depth = bop.read_depth(scene_dir, s["im_id"], gt["depth_scale"])
    assert np.allclose(s["depth"][0].numpy(), depth)
    objects = {o.obj_id: o for o in __import__("simtest.evaluation.run", fromlist=["x"]).load_dataset_objects(small_dataset)}
    for k in range(n):
        obj = objects[int(s["obj_ids"][k])]
        R, t = s["R"][k].numpy(), s["t"][k].numpy()
        Rs, ts = s["R_sym"][k].numpy(), s["t_sym"][k].numpy()
        if not obj.is_symmetric:
            assert np.allclose(Rs, R) and np.allclose(ts, t)
        # the keypoints are the model's bbox corners projected with the (symmetry-equivalent) GT pose and K
        pc = obj.keypoints_bbox @ Rs.T + ts
        uv = pc @ gt["K"].T
        assert np.allclose(s["keypoints_2d"][k].numpy(), uv[:, :2] / uv[:, 2:], atol=1e-9)
        # the equivalent pose maps the mesh onto the GT-posed mesh: every vertex lands within 1 mm of the GT mesh
        if obj.is_symmetric:
            v_e = obj.vertices @ Rs.T + ts
            v_g = obj.vertices @ R.T + t
            dist = np.sqrt(((v_e[:, None] - v_g[None]) ** 2).sum(-1)).min(1)
            assert dist.max() < 2e-3
        # boxes are BOP's boxes (bop_toolkit misc.calc_2d_bbox: w = xmax - xmin) of the visible masks
        m = s["masks"][k].numpy()
        if m.any():
            ys, xs = np.nonzero(m)
            assert s["boxes"][k].tolist() == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]


def test_crop_shifts_intrinsics_and_keypoints(small_dataset):
    full = PoseDataset(small_dataset)[2]
    crop = PoseDataset(small_dataset, crop=(64, 80), seed=5)[2]
    assert crop["rgb"].shape == (3, 64, 80) and crop["masks"].shape[1:] == (64, 80)
    dx = float(full["K"][0, 2] - crop["K"][0, 2])
    dy = float(full["K"][1, 2] - crop["K"][1, 2])
    assert dx == int(dx) and dy == int(dy)
    shift = torch.tensor([dx, dy], dtype=torch.float64)
    assert torch.allclose(crop["keypoints_2d"], full["keypoints_2d"] - shift)
    x0, y0 = int(dx), int(dy)
    ys = slice(max(0, y0), min(120, y0 + 64))
    xs = slice(max(0, x0), min(160, x0 + 80))
    inner = crop["rgb"][:, ys.start - y0:ys.stop - y0, xs.start - x0:xs.stop - x0]
    assert torch.equal(inner, full["rgb"][:, ys, xs])


def test_transforms_deterministic_per_seed_and_epoch(small_dataset):
    tf = augmentation("occlusion,weather,depth", p=1.0)
    a = PoseDataset(small_dataset, transform=tf, seed=11)
    b = PoseDataset(small_dataset, transform=tf, seed=11)
    c = PoseDataset(small_dataset, transform=tf, seed=12)
    clean = PoseDataset(small_dataset)
    for i in range(len(a)):
        sa, sb = a[i], b[i]
        assert torch.equal(sa["rgb"], sb["rgb"]) and torch.equal(sa["depth"], sb["depth"])
        assert torch.equal(sa["masks"], sb["masks"])
    assert any(not torch.equal(a[i]["rgb"], c[i]["rgb"]) for i in range(len(a)))
    assert any(not torch.equal(a[i]["rgb"], clean[i]["rgb"]) for i in range(len(a)))
    e0 = [a[i]["rgb"] for i in range(len(a))]
    a.set_epoch(1)
    assert any(not torch.equal(e0[i], a[i]["rgb"]) for i in range(len(a)))
    a.set_epoch(0)
    assert all(torch.equal(e0[i], a[i]["rgb"]) for i in range(len(a)))
    # reading order does not matter
    assert torch.equal(a[4]["rgb"], e0[4])
    # ground truth is unchanged by the corruptions; a paste only removes visible pixels
    for i in range(len(a)):
        s, g = a[i], clean[i]
        assert torch.equal(s["keypoints_2d"], g["keypoints_2d"]) and torch.equal(s["R"], g["R"])
        assert not bool((s["masks"] & ~g["masks"]).any())


def test_color_jitter_changes_colours_only_and_leaves_the_other_draws_alone(small_dataset):
    """``--augment ...,color``: a seeded photometric jitter of RGB; depth, masks and geometry are untouched, and
    adding it does not change which corruptions the other kinds draw."""
    from simtest.data.augment import ColorJitter

    jit = PoseDataset(small_dataset, transform=Compose((ColorJitter(p=1.0),)), seed=4)
    clean = PoseDataset(small_dataset)
    for i in range(3):
        s, g = jit[i], clean[i]
        assert s["rgb"].dtype == g["rgb"].dtype and s["rgb"].shape == g["rgb"].shape
        assert not torch.equal(s["rgb"], g["rgb"])
        for k in ("depth", "masks", "keypoints_2d", "R", "t"):
            assert torch.equal(s[k], g[k]), k
        assert torch.equal(s["rgb"], PoseDataset(small_dataset, transform=Compose((ColorJitter(p=1.0),)),
                                                 seed=4)[i]["rgb"])
    mixed = augmentation("weather,color", p=1.0)
    assert [type(t).__name__ for t in mixed.transforms] == ["ColorJitter", "RandomCorrupt"]
    assert [type(t).__name__ for t in augmentation("weather").transforms] == ["RandomCorrupt"]
    with pytest.raises(ConfigError, match="color"):
        augmentation("colour")


def test_background_swap_keeps_every_object_pixel_and_the_ground_truth(small_dataset):
    """``--augment ...,background``: all but the annotated objects' visible pixels become a random cluttered
    background; object pixels, depth, masks and poses are the rendered ones; seeded."""
    from simtest.data.augment import BackgroundSwap

    swap = PoseDataset(small_dataset, transform=Compose((BackgroundSwap(p=1.0),)), seed=2)
    clean = PoseDataset(small_dataset)
    for i in range(3):
        s, g = swap[i], clean[i]
        fg = g["masks"].any(0)
        assert fg.any() and torch.equal(s["rgb"][:, fg], g["rgb"][:, fg])
        changed = (s["rgb"] != g["rgb"]).any(0)
        assert float(changed[~fg].float().mean()) > 0.5  # most of the background is new
        for k in ("depth", "masks", "keypoints_2d", "R", "t"):
            assert torch.equal(s[k], g[k]), k
        again = PoseDataset(small_dataset, transform=Compose((BackgroundSwap(p=1.0),)), seed=2)[i]
        assert torch.equal(s["rgb"], again["rgb"])
    assert [type(t).__name__ for t in augmentation("background,color,occlusion").transforms] == [
        "BackgroundSwap", "ColorJitter", "RandomCorrupt"]


def test_object_light_scales_each_object_by_its_own_gain_and_nothing_else(small_dataset):
    """``--augment ...,object-light``: each annotated object's visible pixels are multiplied by one gain of its
    own (the rendered value times the gain, rounded and clipped); the other pixels, depth, masks and poses are
    the rendered ones; seeded; its slot sits between the background swap and the colour jitter."""
    from simtest.data.augment import ObjectLight

    lit = PoseDataset(small_dataset, transform=Compose((ObjectLight(gain=(1.2, 1.6), p=1.0),)), seed=3)
    clean = PoseDataset(small_dataset)
    checked = 0
    for i in range(3):
        s, g = lit[i], clean[i]
        fg = g["masks"].any(0)
        assert fg.any() and torch.equal(s["rgb"][:, ~fg], g["rgb"][:, ~fg])
        for m in g["masks"]:
            own = m & ~(g["masks"].sum(0) > 1)  # pixels of this instance only (visible masks do not overlap)
            a, b = g["rgb"][:, own].double() * 255.0, s["rgb"][:, own].double() * 255.0  # the 8-bit values
            keep = (a > 8) & (b < 254.5)  # away from rounding at black and clipping at white
            if int(keep.sum()) < 20:
                continue
            gains = (b[keep] / a[keep])
            assert 1.2 - 0.07 < float(gains.median()) < 1.6 + 0.07
            assert float((gains - gains.median()).abs().max()) < 0.5 / 8 + 1e-9  # one gain: only rounding differs
            checked += 1
        for k in ("depth", "masks", "keypoints_2d", "R", "t"):
            assert torch.equal(s[k], g[k]), k
        again = PoseDataset(small_dataset, transform=Compose((ObjectLight(gain=(1.2, 1.6), p=1.0),)), seed=3)[i]
        assert torch.equal(s["rgb"], again["rgb"])
    assert checked >= 3  # instances large enough to read their gain were checked
    assert [type(t).__name__ for t in augmentation("color,object-light,background").transforms] == [
        "BackgroundSwap", "ObjectLight", "ColorJitter", "RandomCorrupt"]


def test_corrupt_spec_transform_updates_visible_masks(small_dataset):
    from simtest.corrupt import CorruptionSpec

    ds = PoseDataset(small_dataset, transform=Compose((Corrupt(CorruptionSpec(occlusion=3, occlusion_kind="paste")),)), seed=0)
    clean = PoseDataset(small_dataset)
    s, g = ds[0], clean[0]
    assert int(s["masks"].sum()) < int(g["masks"].sum())
    assert bool((s["visib_fract"] <= g["visib_fract"] + 1e-6).all())


def test_worker_count_does_not_change_batches(small_dataset):
    from torch.utils.data import DataLoader

    ds = PoseDataset(small_dataset, transform=augmentation("occlusion,weather", p=1.0), seed=3, crop=(64, 64))
    ds.set_epoch(2)

    def batches(workers: int) -> list[dict]:
        dl = DataLoader(ds, batch_size=2, shuffle=True, num_workers=workers, collate_fn=collate,
                        generator=torch.Generator().manual_seed(5))
        return list(dl)

    b0, b2 = batches(0), batches(2)
    assert len(b0) == len(b2) == 3
    for x, y in zip(b0, b2):
        assert x.keys() == y.keys()
        for k in x:
            assert torch.equal(x[k], y[k]), k


def test_collate_variable_instance_counts(small_dataset):
    ds = PoseDataset(small_dataset)
    samples = [ds[i] for i in range(3)]
    b = collate(samples)
    counts = [len(s["obj_ids"]) for s in samples]
    assert b["rgb"].shape == (3, 3, 120, 160)
    assert b["masks"].shape[0] == sum(counts) == len(b["batch_index"])
    assert b["batch_index"].tolist() == sum(([i] * c for i, c in enumerate(counts)), [])
    assert torch.equal(b["keypoints_2d"][counts[0]:counts[0] + counts[1]], samples[1]["keypoints_2d"])
    with pytest.raises(ConfigError, match="different sizes"):
        collate([samples[0], PoseDataset(small_dataset, crop=(64, 64))[0]])


def test_bad_options_are_named(small_dataset):
    with pytest.raises(ConfigError, match="'corners'.*bbox, fps"):
        PoseDataset(small_dataset, keypoints="corners")
    with pytest.raises(ConfigError, match="'rain'.*occlusion, weather, depth"):
        augmentation("occlusion,rain")
    with pytest.raises(ConfigError, match="scenes"):
        PoseDataset(small_dataset, scenes=[42])


def test_helpers():
    rng1, rng2 = sample_rng(1, 2, 3), sample_rng(1, 2, 3)
    assert rng1.integers(1 << 30) == rng2.integers(1 << 30)
    assert sample_rng(1, 2, 3).integers(1 << 30) != sample_rng(1, 3, 3).integers(1 << 30)
    K = np.array([[100.0, 0, 50], [0, 100, 40], [0, 0, 1]])
    uv = project_points(np.array([[0.0, 0, 0], [0.1, 0, 0]]), np.eye(3), np.array([0, 0, 1.0]), K)
    assert np.allclose(uv, [[50, 40], [60, 40]])
    syms = np.stack([np.eye(4), np.diag([-1.0, -1.0, 1.0, 1.0])])  # 180 deg about z
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    assert canonical_symmetry(R, syms) == 0
    assert canonical_symmetry(R @ syms[1, :3, :3], syms) == 1
    assert isinstance(RandomCorrupt(weather=("fog",))(
        {"rgb": np.zeros((32, 32, 3), np.uint8), "depth": None, "masks": np.zeros((0, 32, 32), bool),
         "K": np.eye(3)}, np.random.default_rng(0)), dict)
