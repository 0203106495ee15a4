"""CorruptionSpec, corrupt_dataset on a hand-made BOP folder, and the ``simtest corrupt`` command."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from simtest.cli import main
from simtest.corrupt import CorruptionSpec, corrupt_dataset, depth_m_to_png, depth_png_to_m
from simtest.errors import ConfigError, DatasetError

H, W = 48, 64
FX = 60.0
K = [FX, 0.0, (W - 1) / 2, 0.0, FX, (H - 1) / 2, 0.0, 0.0, 1.0]
DEPTH_SCALE = 0.1


def _png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".png", img)
    assert ok
    path.write_bytes(buf.tobytes())


def _json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj))


def make_bop(root: Path, im_ids: tuple[int, ...] = (0, 1)) -> Path:
    """A 1-scene, 2-image BOP dataset with one object per image."""
    _json(root / "camera.json", {"width": W, "height": H, "fx": FX, "fy": FX, "cx": K[2], "cy": K[5],
                                 "depth_scale": DEPTH_SCALE})
    _json(root / "manifest.json", {"generator": "hand-made test dataset"})
    _json(root / "models" / "models_info.json", {"1": {"diameter": 100.0, "min_x": -50, "min_y": -50, "min_z": -50,
                                                       "size_x": 100, "size_y": 100, "size_z": 100}})
    (root / "models" / "obj_000001.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    scene = root / "train_pbr" / "000000"
    cams, gts, infos = {}, {}, {}
    for im in im_ids:
        rng = np.random.default_rng(im)
        rgb = cv2.GaussianBlur(rng.integers(0, 255, (H, W, 3), dtype=np.uint8), (5, 5), 0)
        mask = np.zeros((H, W), np.uint8)
        cv2.circle(mask, (W // 2 + 3 * im, H // 2), 12, 255, -1)
        visib = mask.copy()
        visib[:, :W // 2 - 8] = 0  # partly hidden by something on the left
        depth_m = np.full((H, W), 1.0, np.float32)
        depth_m[mask > 0] = 0.9
        depth_m[:3, :3] = 0  # missing
        _png(scene / "rgb" / f"{im:06d}.png", rgb)
        _png(scene / "depth" / f"{im:06d}.png", depth_m_to_png(depth_m, DEPTH_SCALE))
        _png(scene / "mask" / f"{im:06d}_000000.png", mask)
        _png(scene / "mask_visib" / f"{im:06d}_000000.png", visib)
        cams[str(im)] = {"cam_K": K, "depth_scale": DEPTH_SCALE}
        gts[str(im)] = [{"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 900]}]
        n_all, n_vis = int((mask > 0).sum()), int((visib > 0).sum())
        infos[str(im)] = [{"bbox_obj": [0, 0, 1, 1], "bbox_visib": [0, 0, 1, 1], "px_count_all": n_all,
                           "px_count_valid": n_all, "px_count_visib": n_vis, "visib_fract": n_vis / n_all}]
    _json(scene / "scene_camera.json", cams)
    _json(scene / "scene_gt.json", gts)
    _json(scene / "scene_gt_info.json", infos)
    return root


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_depth_png_round_trip() -> None:
    d = np.array([[0.0, 0.5, 1.23456, 7.0]], np.float32)
    png = depth_m_to_png(d, 0.1)
    assert png.dtype == np.uint16 and png[0, 0] == 0 and png[0, 3] == 0  # 7 m > 6.5535 m: missing
    np.testing.assert_allclose(depth_png_to_m(png, 0.1)[0, 1:3], [0.5, 1.2346], atol=1e-4)


def test_spec_apply_and_validation() -> None:
    rgb = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 255, (H, W, 3), dtype=np.uint8), (5, 5), 0)
    depth = np.full((H, W), 1.0, np.float32)
    depth[0, 0] = 0
    mask = np.zeros((H, W), bool)
    mask[10:30, 20:40] = True
    spec = CorruptionSpec(weather="fog", severity=3, depth_noise="azure-kinect", occlusion="L2")
    assert spec.occlusion == 2 and spec.label() == "fog-3+occL2-objects+azure-kinect"
    assert CorruptionSpec.from_dict(spec.to_dict()) == spec
    K3 = np.asarray(K).reshape(3, 3)
    a = spec.apply(rgb, depth, [mask], np.random.default_rng(1), K3)
    b = spec.apply(rgb, depth, mask, np.random.default_rng(1), K3)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    out_rgb, out_depth, occ = a
    assert out_rgb.shape == rgb.shape and out_depth.shape == depth.shape and occ.dtype == bool
    assert 0.4 <= (occ & mask).sum() / mask.sum() <= 0.6
    assert out_depth[0, 0] == 0 and not np.array_equal(out_depth, depth)
    # image-only spec leaves depth as given
    r, d, o = CorruptionSpec(weather="snow").apply(rgb, None, None, np.random.default_rng(0), None)
    assert d is None and not o.any()
    with pytest.raises(ConfigError, match="snowy"):
        CorruptionSpec(weather="snowy")
    with pytest.raises(ConfigError, match="7"):
        CorruptionSpec(weather="snow", severity=7)
    with pytest.raises(ConfigError, match="physical"):
        CorruptionSpec(occlusion=1, occlusion_kind="physical")
    with pytest.raises(ConfigError, match="masks"):
        CorruptionSpec(occlusion=1).apply(rgb, depth, None, np.random.default_rng(0), None)


GT_FILES = ("camera.json", "manifest.json", "models/models_info.json", "models/obj_000001.ply",
            "train_pbr/000000/scene_gt.json", "train_pbr/000000/scene_camera.json",
            "train_pbr/000000/mask/000000_000000.png", "train_pbr/000000/mask/000001_000000.png")


def test_corrupt_dataset_full(tmp_path: Path) -> None:
    src = make_bop(tmp_path / "in")
    before = _files(src)
    spec = CorruptionSpec(weather="fog", severity=4, occlusion="L1", depth_noise="azure-kinect")
    record = corrupt_dataset(src, tmp_path / "out", spec, seed=3, progress=False)
    after = _files(src)
    assert before == after  # input untouched
    out = _files(tmp_path / "out")
    assert set(out) == set(before) | {"corruption.json"}
    for name in GT_FILES:
        assert out[name] == before[name], name
    for im in (0, 1):
        assert out[f"train_pbr/000000/rgb/{im:06d}.png"] != before[f"train_pbr/000000/rgb/{im:06d}.png"]
        assert out[f"train_pbr/000000/depth/{im:06d}.png"] != before[f"train_pbr/000000/depth/{im:06d}.png"]
        d = cv2.imread(str(tmp_path / "out" / f"train_pbr/000000/depth/{im:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert d.dtype == np.uint16 and np.all(d[:3, :3] == 0)
        old = cv2.imread(str(src / f"train_pbr/000000/mask_visib/{im:06d}_000000.png"), 0) > 0
        new = cv2.imread(str(tmp_path / "out" / f"train_pbr/000000/mask_visib/{im:06d}_000000.png"), 0) > 0
        assert not np.any(new & ~old) and new.sum() < old.sum()
        info = json.loads(out["train_pbr/000000/scene_gt_info.json"])[str(im)][0]
        assert info["px_count_visib"] == int(new.sum())
        assert info["visib_fract"] == pytest.approx(new.sum() / info["px_count_all"])
    rec = json.loads(out["corruption.json"])
    assert rec["seed"] == 3 and rec["spec"] == spec.to_dict() and rec["images"] == 2
    assert rec == json.loads(json.dumps(record))
    assert len(rec["occlusion"]["per_image"]) == 2 and rec["occlusion"]["definition"] == "pascal3d+"


def test_corrupt_dataset_weather_only_and_order_independence(tmp_path: Path) -> None:
    src = make_bop(tmp_path / "in")
    before = _files(src)
    spec = CorruptionSpec(weather="gaussian_noise", severity=2)
    corrupt_dataset(src, tmp_path / "out", spec, seed=9, progress=False)
    out = _files(tmp_path / "out")
    for name, data in before.items():
        if "/rgb/" in name:
            assert out[name] != data
        else:
            assert out[name] == data, name  # depth, masks, scene_gt_info unchanged
    # image 1 alone gives the same result: per-image seeds do not depend on what else is processed
    only1 = make_bop(tmp_path / "only1", im_ids=(1,))
    corrupt_dataset(only1, tmp_path / "out1", spec, seed=9, progress=False)
    key = "train_pbr/000000/rgb/000001.png"
    assert (tmp_path / "out1" / key).read_bytes() == out[key]
    # rerun with overwrite is identical
    corrupt_dataset(src, tmp_path / "out", spec, seed=9, overwrite=True, progress=False)
    assert _files(tmp_path / "out") == out


def test_corrupted_copy_keeps_jpeg_rgb_and_bop_boxes(tmp_path: Path) -> None:
    """A source with rgb/*.jpg (BOP's PBR layout) gives a copy with rgb/*.jpg; recomputed visible boxes are
    BOP's (``w = xmax - xmin``) boxes of the occluded visible masks."""
    from simtest.io.bop import encode_image, read_image

    src = make_bop(tmp_path / "in")
    rgb_dir = src / "train_pbr" / "000000" / "rgb"
    for p in sorted(rgb_dir.glob("*.png")):
        p.with_suffix(".jpg").write_bytes(encode_image(cv2.imread(str(p)), ".jpg", jpg_quality=95))
        p.unlink()
    spec = CorruptionSpec(weather="fog", severity=2, occlusion="L1")
    corrupt_dataset(src, tmp_path / "out", spec, seed=2, progress=False)
    scene = tmp_path / "out" / "train_pbr" / "000000"
    assert sorted(p.name for p in (scene / "rgb").iterdir()) == ["000000.jpg", "000001.jpg"]
    for im in (0, 1):
        assert (scene / "rgb" / f"{im:06d}.jpg").read_bytes()[:2] == b"\xff\xd8"  # JPEG signature
        assert read_image(scene, im).shape == (H, W, 3)
        assert not np.array_equal(read_image(scene, im), read_image(src / "train_pbr" / "000000", im))
        new = cv2.imread(str(scene / "mask_visib" / f"{im:06d}_000000.png"), 0) > 0
        ys, xs = np.nonzero(new)
        info = json.loads((scene / "scene_gt_info.json").read_text())[str(im)][0]
        assert info["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]


def test_corrupt_dataset_errors(tmp_path: Path) -> None:
    spec = CorruptionSpec(weather="fog")
    with pytest.raises(DatasetError, match="nope"):
        corrupt_dataset(tmp_path / "nope", tmp_path / "out", spec, seed=0, progress=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="scene"):
        corrupt_dataset(tmp_path / "empty", tmp_path / "out", spec, seed=0, progress=False)
    src = make_bop(tmp_path / "in")
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "x.txt").write_text("keep")
    with pytest.raises(DatasetError, match="busy"):
        corrupt_dataset(src, tmp_path / "busy", spec, seed=0, progress=False)
    assert (tmp_path / "busy" / "x.txt").read_text() == "keep"
    with pytest.raises(DatasetError, match="inside"):
        corrupt_dataset(src, src / "sub", spec, seed=0, overwrite=True, progress=False)
    with pytest.raises(ConfigError, match="-1"):
        corrupt_dataset(src, tmp_path / "o2", spec, seed=-1, progress=False)


def test_cli_preview_and_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    img = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 255, (H, W, 3), dtype=np.uint8), (5, 5), 0)
    _png(tmp_path / "img.png", img)
    grid = tmp_path / "grid.png"
    assert main(["corrupt", "--preview", str(tmp_path / "img.png"), "--out", str(grid),
                 "--corruptions", "fog,snow,contrast", "--seed", "1"]) == 0
    g = cv2.imread(str(grid))
    assert g is not None and g.shape[1] == 6 * W and g.shape[0] > 3 * H
    assert main(["corrupt", "--preview", str(tmp_path / "img.png"), "--out", str(tmp_path / "all.png")]) == 0
    assert cv2.imread(str(tmp_path / "all.png")).shape[1] < 4000

    src = make_bop(tmp_path / "in")
    assert main(["corrupt", "--in", str(src), "--out", str(tmp_path / "out"), "--weather", "frost", "--severity",
                 "2", "--occlusion", "L2", "--occlusion-kind", "paste", "--depth-noise", "kinect-v1", "--seed", "4",
                 "--no-progress"]) == 0
    assert json.loads((tmp_path / "out" / "corruption.json").read_text())["spec"]["occlusion"] == 2
    capsys.readouterr()
    assert main(["corrupt", "--in", str(src), "--out", str(tmp_path / "out"), "--weather", "frost"]) == 2
    assert "overwrite" in capsys.readouterr().err
    assert main(["corrupt", "--in", str(src), "--out", str(tmp_path / "o3"), "--weather", "hail"]) == 2
    assert "hail" in capsys.readouterr().err
    assert main(["corrupt", "--in", str(src), "--out", str(tmp_path / "o4")]) == 2
    assert main(["corrupt", "--list"]) == 0
    assert "azure-kinect" in capsys.readouterr().out
