"""Dense ground truth checked against the pixels: object coordinates, normals, flow, instance maps and keypoints
of real generated sequences (MuJoCo physics and rendering, built-in meshes)."""

from __future__ import annotations

import importlib.util
import json

import cv2
import numpy as np
import pytest

from simtest.generators.config import GenerateConfig
from simtest.generators.pipeline import generate
from simtest.io import bop, dense
from simtest.objects.loaders import load_dataset_objects

CHANNELS = ["instances", "coords", "normals", "flow", "keypoints"]


def _config(**kw) -> GenerateConfig:
    base = {"objects": "builtin-small", "scenes": 1, "frames_per_scene": 3, "camera.width": 160,
            "camera.height": 120, "rig": "sequence", "scene.objects_per_scene": [3, 4], "scene.distractors": [1, 1],
            "annotation.channels": CHANNELS, "render.coco": True, "seed": 11}
    return GenerateConfig().replace(**{**base, **kw})


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    out = tmp_path_factory.mktemp("dense") / "seq"
    generate(_config(), out, progress=False)
    return out


def _scene(ds):
    return ds / "train_pbr" / "000000"


def _frames(ds):
    d = _scene(ds)
    cams, gts = bop.read_json(d / "scene_camera.json"), bop.read_json(d / "scene_gt.json")
    info = {int(k): v for k, v in bop.read_json(ds / "models" / "models_info.json").items()}
    for im in sorted(cams, key=int):
        K = np.asarray(cams[im]["cam_K"], np.float64).reshape(3, 3)
        poses = [(np.asarray(g["cam_R_m2c"], np.float64).reshape(3, 3), np.asarray(g["cam_t_m2c"], np.float64) / 1000,
                  int(g["obj_id"])) for g in gts[im]]
        yield int(im), K, float(cams[im]["depth_scale"]), poses, info


def _bbox_m(info, obj_id):
    e = info[obj_id]
    return (np.array([e["min_x"], e["min_y"], e["min_z"]]) / 1000, np.array([e["size_x"], e["size_y"], e["size_z"]]) / 1000)


def test_instance_maps_equal_the_visible_masks(seq):
    d = _scene(seq)
    for im, *_ , poses, _ in _frames(seq):
        inst = dense.read_channel(d, "instances", im)
        assert inst.dtype == np.uint16
        for k in range(len(poses)):
            np.testing.assert_array_equal(inst == k + 1, bop.read_mask(d, im, k, visible=True))
        assert not np.any(inst > len(poses))


def test_coords_land_on_their_own_pixel_centre_at_the_depth_png_depth(seq):
    d = _scene(seq)
    checked = 0
    for im, K, scale, poses, info in _frames(seq):
        code, inst, depth = dense.read_channel(d, "coords", im), dense.read_channel(d, "instances", im), \
            bop.read_depth(d, im, scale)
        assert np.array_equal(code.any(-1), (inst > 0) & (depth > 0))
        for k, (R, t, oid) in enumerate(poses):
            v, u = np.nonzero((inst == k + 1) & (depth > 0))
            if not len(u):
                continue
            X = dense.decode_coords(code[v, u], *_bbox_m(info, oid))
            lo, size = _bbox_m(info, oid)
            assert np.all(X >= lo - 1e-9) and np.all(X <= lo + size + 1e-9)
            cam = X @ R.T + t
            pu, pv = K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2], K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]
            assert np.abs(pu - u).max() < 0.05 and np.abs(pv - v).max() < 0.05
            # depth PNG quantization (depth_scale mm per unit, rounded) plus the coords' own (size / 65534)
            tol = 0.5 * scale / 1000 + float(np.linalg.norm(size)) / 65534 + 1e-6
            assert np.abs(cam[:, 2] - depth[v, u]).max() <= tol
            checked += len(u)
    assert checked > 500


def test_normals_agree_with_the_mesh_and_the_table(seq):
    """Object pixels off the silhouette: the normal of the mesh triangle nearest the decoded model point
    (trimesh's own closest-point query on the object's mesh), in the camera frame; table and floor: the world's
    up axis in the camera frame."""
    import trimesh

    d = _scene(seq)
    objects = load_dataset_objects(seq)
    errs_obj, errs_bg = [], []
    cams = bop.read_json(d / "scene_camera.json")
    for im, K, scale, poses, info in _frames(seq):
        n = dense.decode_normals(dense.read_channel(d, "normals", im))
        code, inst = dense.read_channel(d, "coords", im), dense.read_channel(d, "instances", im)
        for k, (R, t, oid) in enumerate(poses):
            inner = cv2.erode((inst == k + 1).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
            v, u = np.nonzero(inner)
            if len(u) < 10:
                continue
            obj = objects.get(oid)
            mesh = trimesh.Trimesh(obj.vertices, obj.faces, process=False)
            X = dense.decode_coords(code[v, u], *_bbox_m(info, oid))
            _, _, tri = trimesh.proximity.closest_point(mesh, X)
            ref = mesh.face_normals[tri] @ R.T
            ref *= -np.sign(np.einsum("ij,ij->i", ref, X @ R.T + t))[:, None]  # the side facing the camera
            errs_obj += list(np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n[v, u], ref), -1, 1))))
        R_w2c = np.asarray(cams[str(im)]["cam_R_w2c"], np.float64).reshape(3, 3)
        up = R_w2c @ np.array([0.0, 0.0, 1.0])
        bg = (inst == 0) & np.isfinite(n[..., 0])
        cos = n[bg] @ up
        errs_bg += list(np.degrees(np.arccos(np.clip(cos[cos > 0.99], -1, 1))))  # the horizontal surfaces
    assert len(errs_obj) > 300 and np.median(errs_obj) < 1.0, np.median(errs_obj)
    assert len(errs_bg) > 1000 and np.percentile(errs_bg, 99) < 0.1


def test_flow_warps_each_valid_pixel_onto_the_next_projection_of_the_same_model_point(seq):
    d = _scene(seq)
    frames = list(_frames(seq))
    assert not (d / "flow" / f"{frames[-1][0]:06d}.png").exists()  # no flow for the last image
    checked = 0
    for (im, K, scale, poses, info), (im2, K2, _, poses2, _) in zip(frames, frames[1:]):
        flow, valid = dense.decode_flow(dense.read_channel(d, "flow", im))
        inst, inst2 = dense.read_channel(d, "instances", im), dense.read_channel(d, "instances", im2)
        code = dense.read_channel(d, "coords", im)
        assert valid.mean() > 0.3
        for k, (R, t, oid) in enumerate(poses):
            v, u = np.nonzero((inst == k + 1) & valid)
            if not len(u):
                continue
            X = dense.decode_coords(code[v, u], *_bbox_m(info, oid))
            R2, t2, oid2 = poses2[k]
            assert oid2 == oid
            cam = X @ R2.T + t2
            pu, pv = K2[0, 0] * cam[:, 0] / cam[:, 2] + K2[0, 2], K2[1, 1] * cam[:, 1] / cam[:, 2] + K2[1, 2]
            tu, tv = u + flow[v, u, 0], v + flow[v, u, 1]
            assert np.abs(tu - pu).max() < 0.05 and np.abs(tv - pv).max() < 0.05
            # a valid target shows the same instance in the next image (the flow is stored to 1/64 px, so a
            # target within 1/128 px of a pixel border may round to the neighbour)
            hit = inst2[np.clip(np.rint(tv).astype(int), 0, inst2.shape[0] - 1),
                        np.clip(np.rint(tu).astype(int), 0, inst2.shape[1] - 1)] == k + 1
            assert hit.mean() > 0.98
            checked += len(u)
    assert checked > 300


def test_keypoint_visibility_agrees_with_the_instance_map_and_depth(seq):
    d = _scene(seq)
    kps = bop.read_json(d / "scene_keypoints.json")
    model_kps = bop.read_json(seq / "models" / "models_keypoints.json")
    coco = json.loads((d / "scene_gt_coco.json").read_text())
    by_image = {}
    for a in coco["annotations"]:
        by_image.setdefault(a["image_id"], []).append(a)
    counts = np.zeros(3, int)
    for im, K, scale, poses, _ in _frames(seq):
        inst, depth = dense.read_channel(d, "instances", im), bop.read_depth(d, im, scale)
        H, W = inst.shape
        for k, ((R, t, oid), rec) in enumerate(zip(poses, kps[str(im)])):
            assert rec["obj_id"] == oid
            kp = np.asarray(rec["keypoints"])
            P = np.asarray(model_kps[str(oid)]["points_mm"]) / 1000 @ R.T + t
            pu, pv = K[0, 0] * P[:, 0] / P[:, 2] + K[0, 2], K[1, 1] * P[:, 1] / P[:, 2] + K[1, 2]
            assert np.abs(kp[:, 0] - pu).max() < 1e-3 and np.abs(kp[:, 1] - pv).max() < 1e-3
            iu, iv = np.rint(pu).astype(int), np.rint(pv).astype(int)
            inside = (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
            for j in range(len(kp)):
                vis = int(kp[j, 2])
                counts[vis] += 1
                if not inside[j]:
                    assert vis == 0
                    continue
                seen = inst[iv[j], iu[j]] == k + 1 and abs(depth[iv[j], iu[j]] - P[j, 2]) <= 0.005
                assert vis == (2 if seen else 1)
        for a in by_image.get(im, []):
            assert len(a["keypoints"]) == 3 * len(model_kps[str(a["category_id"])]["names"])
    assert counts[2] > 0 and counts[1] > 0
    names = {c["id"]: c.get("keypoints") for c in coco["categories"]}
    assert all(n and n[0] == "bbox_0" for n in names.values())


def test_channels_are_the_same_for_every_profile_and_worker_count(tmp_path, seq):
    """The channels come from the exact geometry only: the pbr profile and two workers give the same files."""
    cfg = _config(**{"scenes": 2, "frames_per_scene": 2, "camera.width": 64, "camera.height": 48})
    generate(cfg, tmp_path / "fast", progress=False)
    generate(cfg.replace(**{"workers": 2}), tmp_path / "two", progress=False)
    if importlib.util.find_spec("mitsuba") is None:  # not imported here: simtest picks the libLLVM first
        pytest.skip("the pbr extra (mitsuba) is not installed")
    generate(cfg.replace(**{"render.profile": "pbr", "render.pbr_spp": 1}), tmp_path / "pbr", progress=False)
    names = sorted(p.relative_to(tmp_path / "fast") for p in (tmp_path / "fast").rglob("*")
                   if p.is_file() and p.parent.name in ("instances", "coords", "normals", "flow")
                   or p.name == "scene_keypoints.json")
    assert len(names) > 10
    for other in ("two", "pbr"):
        for n in names:
            same = (tmp_path / "fast" / n).read_bytes() == (tmp_path / other / n).read_bytes()
            assert same, (other, str(n))  # no byte-string diff in the report


def test_a_feed_reads_the_channels_and_nocs_is_one_function_away(seq):
    torch = pytest.importorskip("torch")
    from simtest.data import PoseDataset, nocs_from_coords

    ds = PoseDataset(seq, channels=("instances", "coords", "normals", "flow"))
    s = ds[0]
    H, W = s["rgb"].shape[1:]
    assert s["coords"].shape == (3, H, W) and s["normals"].shape == (3, H, W) and s["flow"].shape == (2, H, W)
    assert torch.equal(s["instances"] > 0, s["masks"].any(0)) and torch.equal(s["coords_mask"],
                                                                              s["masks"].any(0) & (s["depth"][0] > 0))
    obj = load_dataset_objects(seq).get(int(s["obj_ids"][0]))
    m = (s["instances"] == 1).numpy()
    nocs = nocs_from_coords(s["coords"].numpy().transpose(1, 2, 0)[m], obj.bbox[0], obj.size)
    assert np.all(nocs > -1e-6) and np.all(nocs < 1 + 1e-6)
    with pytest.raises(Exception, match="unknown dense channel 'depthx'"):
        PoseDataset(seq, channels=("depthx",))


def test_coords_and_normals_on_a_textured_user_mesh(tmp_path):
    """A user's textured OBJ (a 6 cm cube with a UV checkerboard): the coords reproject onto their pixels and
    the normals are the cube's face normals."""
    from tests.objects.test_appearance import write_textured_cube

    lib = tmp_path / "lib"
    lib.mkdir()
    write_textured_cube(lib)
    out = tmp_path / "ds"
    generate(_config(**{"objects": str(lib), "rig": "shell", "frames_per_scene": 2, "scene.objects_per_scene": [2, 2],
                        "annotation.channels": ["coords", "normals", "instances"]}), out, progress=False)
    d = _scene(out)
    objects = load_dataset_objects(out)
    checked = 0
    for im, K, scale, poses, info in _frames(out):
        code, inst = dense.read_channel(d, "coords", im), dense.read_channel(d, "instances", im)
        n = dense.decode_normals(dense.read_channel(d, "normals", im))
        for k, (R, t, oid) in enumerate(poses):
            inner = cv2.erode((inst == k + 1).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            v, u = np.nonzero(inner)
            if not len(u):
                continue
            X = dense.decode_coords(code[v, u], *_bbox_m(info, oid))
            cam = X @ R.T + t
            assert np.abs(K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2] - u).max() < 0.05
            half = objects.get(oid).size / 2
            face = np.argmin(half - np.abs(X - objects.get(oid).bbox[0] - half), axis=1)  # the face each point is on
            ref = np.zeros_like(X)
            ref[np.arange(len(X)), face] = np.sign((X - objects.get(oid).bbox[0] - half)[np.arange(len(X)), face])
            cos = np.einsum("ij,ij->i", n[v, u], ref @ R.T)
            assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) < 0.5
            checked += len(u)
    assert checked > 100
