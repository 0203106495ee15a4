"""The path-traced ``pbr`` profile: only ``rgb/`` differs from the fast profile (on every Mitsuba variant), the
image is registered with the exact masks (square pixels with an off-centre principal point, and LM-O's camera,
``fx != fy``, given by ``--camera``), a fixed seed repeats its bytes, and a missing extra says what to install."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.generators.config import GenerateConfig
from simtest.generators.pipeline import generate
from simtest.io.bop import read_image, read_json, read_mask, scene_dirs

W, H = 96, 72
#: LM-O's camera (BOP ``lmo/camera.json``: 640x480, fx 572.4114, fy 573.57043) at a quarter of its size, on the
#: OpenCV pixel grid (principal point ``(c + 0.5) / 4 - 0.5``); depth_scale 1.0 mm per depth unit as in LM-O.
LMO_QUARTER = {"fx": 572.4114 / 4, "fy": 573.57043 / 4, "cx": (325.2611 + 0.5) / 4 - 0.5,
               "cy": (242.04899 + 0.5) / 4 - 0.5, "width": 160, "height": 120, "depth_scale": 1.0}


def _digest(root: Path) -> dict[str, str]:
    """sha1 of every file under ``root`` except the manifest (compared separately)."""
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != "manifest.json"}


def _need_pbr() -> None:
    """Skip without the extra. (Not importorskip: importing mitsuba here would load Dr.Jit before simtest
    chooses its libLLVM, and so rule out the LLVM variant in this process.)"""
    for name in ("mitsuba", "pyoidn"):
        if importlib.util.find_spec(name) is None:
            pytest.skip(f"{name} is not installed (pip install 'simtest[pbr]')")


@pytest.fixture(scope="module")
def runs(tmp_path_factory, small_config):
    """The same seed (plain looks: no library materials, prints or environment) made with the fast profile, twice with the pbr profile (4 spp, denoised, the ``auto``
    variant: llvm_ad_rgb where a libLLVM >= 16 is installed) and once on the scalar variant, with the principal
    point well off the image centre so a registration error would show."""
    _need_pbr()
    cfg = small_config.replace(**{
        "scenes": 1, "frames_per_scene": 2, "camera.width": W, "camera.height": H,
        "camera.cx": (W - 1) / 2 + 6.0, "camera.cy": (H - 1) / 2 - 4.0, "render.pbr_spp": 4,
        # plain looks: the registration test reads image gradients, which textures would add inside objects
        "materials.families": [], "materials.object_textures": False, "lights.environment": "constant"})
    root = tmp_path_factory.mktemp("pbr")
    generate(cfg, root / "fast", progress=False)
    generate(cfg.replace(**{"render.profile": "pbr"}), root / "pbr", progress=False)
    generate(cfg.replace(**{"render.profile": "pbr"}), root / "pbr_again", progress=False)
    generate(cfg.replace(**{"render.profile": "pbr", "render.pbr_variant": "scalar"}), root / "pbr_scalar",
             progress=False)
    return root


@pytest.fixture(scope="module")
def lmo_runs(tmp_path_factory):
    """One scene, two views, made by ``simtest generate --config plain.toml --camera camera.json`` with LM-O's
    camera (:data:`LMO_QUARTER`, a file this test writes) in the fast profile and, with the extra, in the pbr
    profile (4 spp); plain looks as in :func:`runs`."""
    from simtest.cli import main

    root = tmp_path_factory.mktemp("lmo")
    (root / "camera.json").write_text(json.dumps(LMO_QUARTER))
    (root / "plain.toml").write_text(
        'objects = "builtin-small"\nseed = 7\n[scene]\nobjects_per_scene = [3, 5]\ndistractors = [1, 2]\n'
        '[materials]\nfamilies = []\nobject_textures = false\n[lights]\nenvironment = "constant"\n'
        '[render]\npbr_spp = 4\n')
    base = ["generate", "--config", str(root / "plain.toml"), "--camera", str(root / "camera.json"), "--scenes", "1",
            "--frames-per-scene", "2", "--quiet"]
    assert main(base + ["--out", str(root / "fast")]) == 0
    if all(importlib.util.find_spec(n) is not None for n in ("mitsuba", "pyoidn")):
        assert main(base + ["--profile", "pbr", "--out", str(root / "pbr")]) == 0
    return root


def _registration_run(request, name: str) -> tuple[Path, Path, int, int]:
    """``(fast dataset, pbr dataset, width, height)`` of a registration case: ``square`` (fx = fy, principal
    point 6 px right of and 4 px above the centre) or ``lmo`` (LM-O's fx != fy camera from ``--camera``)."""
    _need_pbr()
    if name == "square":
        root = request.getfixturevalue("runs")
        return root / "fast", root / "pbr", W, H
    root = request.getfixturevalue("lmo_runs")
    return root / "fast", root / "pbr", LMO_QUARTER["width"], LMO_QUARTER["height"]


_RENDERER_KEYS = ("mitsuba", "mitsuba_variant", "pyoidn", "libllvm", "libllvm_version")


@pytest.mark.parametrize("name", ["pbr", "pbr_scalar"])
def test_pbr_and_fast_differ_only_in_rgb(runs, name):
    fast, pbr = _digest(runs / "fast"), _digest(runs / name)
    assert fast.keys() == pbr.keys() and len(fast) > 10
    rgb = {k for k in fast if "/rgb/" in k}
    assert len(rgb) == 2
    assert {k: v for k, v in fast.items() if k not in rgb} == {k: v for k, v in pbr.items() if k not in rgb}
    assert all(fast[k] != pbr[k] for k in rgb)
    manifests = []
    for run in ("fast", name):
        m = read_json(runs / run / "manifest.json")
        m.pop("command_line")
        m.pop("runs")  # the log of where and how fast each run went
        m["config"]["render"].pop("profile")
        m["config"]["render"].pop("pbr_variant")
        for key in ("mitsuba", "mitsuba_variant", "pyoidn"):
            assert (key in m["versions"]) == (run != "fast")
        llvm = m["versions"].get("mitsuba_variant") == "llvm_ad_rgb"
        assert ("libllvm" in m["versions"]) == llvm and ("libllvm_version" in m["versions"]) == llvm
        for key in _RENDERER_KEYS:
            m["versions"].pop(key, None)
        manifests.append(m)
    assert manifests[0] == manifests[1]
    assert read_json(runs / "pbr_scalar" / "manifest.json")["versions"]["mitsuba_variant"] == "scalar_rgb"


def test_pbr_variants_differ_in_rgb_only_when_the_variant_differs(runs):
    auto, scalar = _digest(runs / "pbr"), _digest(runs / "pbr_scalar")
    rgb = {k for k in auto if "/rgb/" in k}
    same_variant = (read_json(runs / "pbr" / "manifest.json")["versions"]["mitsuba_variant"] == "scalar_rgb")
    assert all((auto[k] == scalar[k]) == same_variant for k in rgb)


def test_pbr_same_seed_same_bytes(runs):
    assert _digest(runs / "pbr") == _digest(runs / "pbr_again")


def _shifted_gradients(grey: np.ndarray, labels: np.ndarray, axis: int, shifts: range) -> dict[int, float]:
    """Mean |difference of neighbouring pixels| along ``axis`` at the label boundaries moved by each shift."""
    n = grey.shape[axis]
    diff = np.abs(np.diff(grey, axis=axis))
    edge = np.diff(labels, axis=axis) != 0
    out = {}
    for s in shifts:
        lo, hi = max(0, -s), min(n - 1, n - 1 - s)  # keep the shifted pairs inside the image
        src = np.take(edge, range(lo, hi), axis=axis)
        dst = np.take(diff, range(lo + s, hi + s), axis=axis)
        out[s] = float(dst[src].mean())
    return out


@pytest.mark.parametrize("case", ["square", "lmo"])
def test_pbr_object_boundaries_coincide_with_masks(request, case):
    """Image gradients peak on the exact visible-mask boundaries, not 1-3 px off (both axes; off-centre K, and
    LM-O's fx != fy K)."""
    _, pbr, w, h = _registration_run(request, case)
    scene = scene_dirs(pbr / "train_pbr")[0]
    gt = read_json(scene / "scene_gt.json")
    totals: dict[tuple[int, int], list[float]] = {}
    for im_key, anns in gt.items():
        im_id = int(im_key)
        grey = read_image(scene, im_id).astype(np.float64).mean(axis=-1)
        labels = np.zeros((h, w), dtype=np.int32)
        for gt_id in range(len(anns)):
            labels[read_mask(scene, im_id, gt_id, visible=True) > 0] = gt_id + 1
        assert labels.any()
        for axis in (0, 1):
            for s, g in _shifted_gradients(grey, labels, axis, range(-3, 4)).items():
                totals.setdefault((axis, s), []).append(g)
    for axis in (0, 1):
        g = {s: float(np.mean(totals[(axis, s)])) for s in range(-3, 4)}
        assert g[0] > max(g[-1], g[1]), (axis, g)
        assert g[0] > 1.2 * max(g[-3], g[-2], g[2], g[3]), (axis, g)


@pytest.mark.parametrize("case", ["square", "lmo"])
def test_pbr_images_register_with_the_fast_profile(request, case):
    """The path-traced image lines up with the rasterized one (exact K, tested against the masks) to a fraction
    of a pixel: phase correlation of their gradient magnitudes, per image (off-centre K, and LM-O's fx != fy K)."""
    import cv2

    fast_root, pbr_root, _, _ = _registration_run(request, case)
    fast, pbr = scene_dirs(fast_root / "train_pbr")[0], scene_dirs(pbr_root / "train_pbr")[0]
    shifts = []
    for im_id in range(2):
        a, b = (np.hypot(*np.gradient(read_image(s, im_id).astype(np.float64).mean(axis=-1))) for s in (fast, pbr))
        (dx, dy), response = cv2.phaseCorrelate(a, b)
        assert response > 0.3, (im_id, response)
        shifts.append((dx, dy))
    shifts = np.asarray(shifts)
    # one 160x120 image estimates its shift to about +-0.4 px (sampling noise of the path tracer), so the mean over
    # the images carries the test; a half-pixel convention error would show as a consistent 0.5
    assert np.all(np.abs(shifts) < 0.6) and np.all(np.abs(shifts.mean(axis=0)) < 0.3), shifts


@pytest.mark.parametrize("profile", ["fast", "pbr"])
def test_camera_file_puts_model_points_where_its_k_says(lmo_runs, profile):
    """``--camera``: the dataset's camera is the file's (camera.json, every ``cam_K``, depth_scale 1.0, the
    manifest's record); model vertices through the ground-truth pose and the file's K land on the visible masks
    where the rendered depth sees them, and the rendered image's edges lie on those masks' boundaries (its
    gradients peak there on both axes): K, masks, depth and the image agree, in the fast and the pbr profile."""
    import cv2

    from simtest.camera import CameraModel, intrinsics_matrix
    from simtest.io.bop import read_depth, read_scene
    from simtest.objects import load_object_set

    if profile == "pbr":
        _need_pbr()
    root = lmo_runs / profile
    cam_file = dict(LMO_QUARTER)
    assert read_json(root / "camera.json") == cam_file
    manifest = read_json(root / "manifest.json")
    assert manifest["camera_file"] == {"path": str((lmo_runs / "camera.json").resolve()), "values": cam_file}
    assert manifest["config"]["camera"]["file"] == str((lmo_runs / "camera.json").resolve())
    assert manifest["config"]["render"]["depth_scale"] == 1.0
    K = intrinsics_matrix(LMO_QUARTER["fx"], LMO_QUARTER["fy"], LMO_QUARTER["cx"], LMO_QUARTER["cy"])
    cam = CameraModel(K, LMO_QUARTER["width"], LMO_QUARTER["height"])
    objects = load_object_set("builtin-small")
    scene_dir = scene_dirs(root / "train_pbr")[0]
    on_mask, centres, edges = [], 0, {}
    for im_id, im in read_scene(scene_dir).items():
        np.testing.assert_array_equal(im["K"], K)
        assert im["depth_scale"] == 1.0
        depth = read_depth(scene_dir, im_id, im["depth_scale"])
        assert depth.shape == (cam.height, cam.width)
        labels = np.zeros((cam.height, cam.width), dtype=np.int32)
        for gt_id, gt in enumerate(im["gt"]):
            visib = read_mask(scene_dir, im_id, gt_id, visible=True)
            labels[visib > 0] = gt_id + 1
            if gt.px_count_visib < 30:
                continue
            grown = cv2.dilate(visib.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            uv, z = cam.project(gt.T_cam_obj.apply(objects.get(gt.obj_id).vertices))
            px = np.round(uv).astype(int)
            inside = (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
            px, z = px[inside], z[inside]
            d = depth[px[:, 1], px[:, 0]]
            seen = np.abs(d - z) < 0.003  # depth in whole millimetres (depth_scale 1.0)
            if seen.sum() >= 5:
                on_mask.append(grown[px[seen, 1], px[seen, 0]].mean())
            centre, _ = cam.project(gt.T_cam_obj.t[None])
            u, v = np.round(centre[0]).astype(int)
            if visib.sum() > 0.9 * gt.px_count_all and 0 <= u < cam.width and 0 <= v < cam.height:
                ys, xs = np.nonzero(visib)  # an unoccluded object: its centre projects inside its silhouette box
                assert xs.min() <= u <= xs.max() and ys.min() <= v <= ys.max()
                centres += 1
        grey = read_image(scene_dir, im_id).astype(np.float64).mean(axis=-1)
        for axis in (0, 1):
            for shift, g in _shifted_gradients(grey, labels, axis, range(-3, 4)).items():
                edges.setdefault((axis, shift), []).append(g)
    assert len(on_mask) >= 3 and min(on_mask) > 0.97, on_mask
    assert centres >= 1
    for axis in (0, 1):
        g = {shift: float(np.mean(edges[(axis, shift)])) for shift in range(-3, 4)}
        assert g[0] > max(g[-1], g[1]) and g[0] > 1.2 * max(g[-3], g[-2], g[2], g[3]), (axis, g)


def test_pbr_config_fields_are_validated():
    for bad in (0, 2.5, "many", True):
        with pytest.raises(ConfigError, match=r"render\.pbr_spp = .* allowed: 'auto' or an integer in \[1, 65536\]"):
            GenerateConfig().replace(**{"render.pbr_spp": bad})
    with pytest.raises(ConfigError, match="profile"):
        GenerateConfig().replace(**{"render.profile": "raytraced"})
    with pytest.raises(ConfigError, match=r"pbr_variant = 'gpu' is invalid; allowed: 'auto' \| 'cuda'"):
        GenerateConfig().replace(**{"render.pbr_variant": "gpu"})
    render = GenerateConfig().render
    assert (render.pbr_spp, render.pbr_variant) == ("auto", "auto")
    assert GenerateConfig().replace(**{"render.pbr_spp": 8}).render.pbr_spp == 8


_WITHOUT_MITSUBA = "import sys; sys.modules['mitsuba'] = None\n"


def test_missing_extra_names_the_install_command():
    code = _WITHOUT_MITSUBA + (
        "import mujoco\n"
        "from simtest.camera import CameraModel\n"
        "from simtest.errors import RenderError\n"
        "from simtest.render.pbr import PbrRenderer\n"
        "model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=\"0.1\"/></worldbody></mujoco>')\n"
        "try:\n"
        "    PbrRenderer(model, CameraModel.default(32, 24))\n"
        "except RenderError as exc:\n"
        "    print(exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "pip install 'simtest[pbr]'" in out.stdout and "pbr" in out.stdout


def test_generate_without_extra_fails_before_writing(tmp_path):
    out_dir = tmp_path / "ds"
    code = _WITHOUT_MITSUBA + (
        "from simtest.cli import main\n"
        f"sys.exit(main(['generate', '--profile', 'pbr', '--scenes', '1', '--width', '32', '--out', "
        f"{json.dumps(str(out_dir))}, '--quiet']))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    assert "pip install 'simtest[pbr]'" in out.stderr
    assert not out_dir.exists()


def test_bench_profiles_reports_each_profile_and_size():
    _need_pbr()
    from simtest.benchmarks.generate import bench_profiles

    res = bench_profiles(["fast", "pbr"], [(48, 36)], objects_per_scene=1, scenes=2, frames_per_scene=1,
                         objects="builtin-small", pbr_spp=2, pbr_variant="scalar")
    assert [(r.profile, r.width, r.height) for r in res.rows] == [("fast", 48, 36), ("pbr", 48, 36)]
    assert all(r.wall > 0 and r.cpu > 0 and r.wall_2workers > 0 for r in res.rows)
    assert [r.spp for r in res.rows] == [None, 2] and [r.variant for r in res.rows] == [None, "scalar_rgb"]
    table = res.table()
    assert "| pbr (2 spp, denoised) | 48x36 |" in table and "2 workers / 1 worker" in table
    assert "pbr path tracer: scalar_rgb; 2 scenes x 1 views" in table
    from simtest.benchmarks.machine import cpu_name

    assert f"views per measurement; processor: {cpu_name()}" in table  # a machine's change is seen in the table
    one = bench_profiles(["pbr"], [(48, 36)], objects_per_scene=1, scenes=1, frames_per_scene=1,
                         objects="builtin-small", pbr_spp="auto", two_workers=False)
    assert one.rows[0].spp == 12 and one.rows[0].wall_2workers is None and "| - | - |" in one.table()


def test_pbr_same_bytes_with_1_or_2_workers(tmp_path, small_config):
    _need_pbr()
    cfg = small_config.replace(**{"scenes": 2, "frames_per_scene": 1, "camera.width": 48, "camera.height": 36,
                                  "render.profile": "pbr", "render.pbr_spp": 2})
    generate(cfg, tmp_path / "w1", progress=False)
    generate(cfg.replace(workers=2), tmp_path / "w2", progress=False)
    assert _digest(tmp_path / "w1") == _digest(tmp_path / "w2")
