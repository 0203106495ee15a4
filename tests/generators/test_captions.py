"""Referring expressions (``--captions``): words agree with the objects, the poses and each other."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from simtest.camera import CameraModel, look_at_pose
from simtest.errors import ConfigError
from simtest.generators.captions import CAPTIONS_FILE, CaptionObject, caption_category, caption_scene, dominant_colour
from simtest.generators.config import GenerateConfig
from simtest.generators.looks import skin_of
from simtest.generators.pipeline import generate
from simtest.io.bop import pose_from_bop
from simtest.objects import load_object_set
from simtest.objects.loaders import load_dataset_objects

TABLE = 0.4


def _cfg(**kw) -> GenerateConfig:
    base = {"scenes": 2, "frames_per_scene": 3, "rig": "sequence", "captions": True, "camera.width": 96,
            "camera.height": 72, "scene.objects_per_scene": [6, 8], "scene.distractors": [0, 1], "seed": 3}
    base.update(kw)
    return GenerateConfig().replace(**base)


def _frame0(scene_dir: Path):
    """Per gt_id of image 0: (obj_id, centre in the camera (m), T_world_cam)."""
    cam = json.loads((scene_dir / "scene_camera.json").read_text())["0"]
    T_world_cam = pose_from_bop(cam["cam_R_w2c"], cam["cam_t_w2c"]).inverse()
    gts = json.loads((scene_dir / "scene_gt.json").read_text())["0"]
    return [(g["obj_id"], pose_from_bop(g["cam_R_m2c"], g["cam_t_m2c"])) for g in gts], T_world_cam


def _geometry(gts, T_world_cam, objects):
    """Per instance: centre in the camera, centre in the world, world z range, horizontal radius."""
    out = []
    for oid, T in gts:
        pts = (T_world_cam @ T).apply(objects.get(oid).vertices)
        cw = T_world_cam.apply(T.t[None])[0]
        out.append({"c": T.t, "w": cw, "zmin": pts[:, 2].min(), "zmax": pts[:, 2].max(),
                    "r": np.linalg.norm(pts[:, :2] - cw[:2], axis=1).max()})
    return out


def _relation(a: dict, b: dict) -> str | None:
    """The relation of ``a`` to ``b`` as the captions document defines it (written from the docs)."""
    def on_top(p, q):
        return (abs(p["zmin"] - q["zmax"]) <= 0.02 and np.hypot(*(p["w"][:2] - q["w"][:2])) <= q["r"]
                and p["w"][2] > q["w"][2] and p["zmin"] - TABLE > 0.01)

    if on_top(a, b):
        return "on top of"
    if on_top(b, a):
        return None
    lat = (b["c"][0] / b["c"][2] - a["c"][0] / a["c"][2]) * 0.5 * (a["c"][2] + b["c"][2])
    dep = a["c"][2] - b["c"][2]
    if abs(lat) >= 0.02 and abs(lat) >= abs(dep):
        return "left of" if lat > 0 else "right of"
    if abs(dep) >= 0.02 and abs(dep) > abs(lat):
        return "behind" if dep > 0 else "in front of"
    return None


def _referents(expr: str, rec: dict, insts: dict, geo: list) -> list[int]:
    """The gt_ids an expression of instance record ``rec`` fits, checked against the geometry."""
    words = expr.split()
    assert words[0] == "the"
    cat = rec["category"]
    head = expr[len("the "):]
    pos = head.index(cat)
    attrs = head[:pos].split()
    rest = head[pos + len(cat):].strip()
    size = next((w for w in attrs if w in ("small", "large")), None)
    colour = next((w for w in attrs if w not in ("small", "large")), None)
    landmark = None
    relation = None
    if rest == "on the table":
        relation = "on"
    elif rest:
        r = next(r for r in rec["relations"] if r["landmark"] and rest == f"{r['relation']} {r['landmark']}")
        relation, landmark = r["relation"], r["gt_id"]
    out = []
    for k, other in insts.items():
        k = int(k)
        if other["category"] != cat or (colour and other["colour"] != colour) or (size and other["size"] != size):
            continue
        if relation == "on" and not geo[k]["zmin"] - TABLE <= 0.01:
            continue
        if landmark is not None and (k == landmark or _relation(geo[k], geo[landmark]) != relation):
            continue
        out.append(k)
    return out


@pytest.fixture(scope="module")
def captioned(tmp_path_factory):
    out = tmp_path_factory.mktemp("captions") / "ds"
    generate(_cfg(), out, progress=False)
    return out


def test_captions_agree_with_objects_poses_and_claims(captioned):
    manifest = json.loads((captioned / "manifest.json").read_text())
    assert manifest["captions"] is True and manifest["config"]["captions"] is True
    categories = {o["obj_id"]: o["category"] for o in manifest["objects"]}
    objects = load_dataset_objects(captioned)
    generated = load_object_set(manifest["config"]["objects"])  # with the prints' recipe (skins)
    n_relational = n_attr = 0
    for scene_dir in sorted((captioned / "train_pbr").iterdir()):
        data = json.loads((scene_dir / CAPTIONS_FILE).read_text())
        insts = data["instances"]
        gts, T_world_cam = _frame0(scene_dir)
        assert sorted(insts, key=int) == [str(i) for i in range(len(gts))]
        geo = _geometry(gts, T_world_cam, objects)
        info = json.loads((scene_dir / "scene_info.json").read_text())
        active = [i for i in range(len(info["spec"]["objects"])) if i not in info["removed_instances"]]
        for key, rec in insts.items():
            k = int(key)
            assert rec["obj_id"] == gts[k][0]
            assert rec["category"] == caption_category(categories[rec["obj_id"]])
            # the named colour is the dominant colour of this instance's print times its material colour
            placement = info["spec"]["objects"][active[k]]
            assert placement["obj_id"] == rec["obj_id"]
            obj = generated.get(rec["obj_id"])
            skin = skin_of(obj, placement["skin_seed"])
            name, rgb = dominant_colour(None if placement["plain"] else obj, placement["rgba"],
                                        None if skin is None else skin.albedo)
            assert rec["colour"] == name
            np.testing.assert_allclose(rec["rgb"], rgb, atol=1e-4)
            for r in rec["relations"]:
                if r["relation"] == "on":
                    assert geo[k]["zmin"] - TABLE <= 0.01
                    continue
                a, b = geo[k], geo[r["gt_id"]]
                assert r["obj_id"] == gts[r["gt_id"]][0]
                u_a, u_b = a["c"][0] / a["c"][2], b["c"][0] / b["c"][2]  # image columns, up to fx and cx
                assert {"left of": u_a < u_b, "right of": u_a > u_b, "behind": a["c"][2] > b["c"][2],
                        "in front of": a["c"][2] < b["c"][2], "on top of": a["w"][2] > b["w"][2]}[r["relation"]]
                assert _relation(a, b) == r["relation"]
            for expr in rec["expressions"]:
                referents = _referents(expr, rec, insts, geo)
                assert k in referents
                assert (len(referents) == 1) == rec["unique"], (expr, referents)
                n_relational += " of " in expr or "behind" in expr
                n_attr += expr.split()[1] != rec["category"].split()[0]
    assert n_relational > 0 and n_attr > 0  # colour / size words and relations were both needed somewhere


def test_same_seed_same_caption_bytes(tmp_path, captioned):
    cfg = _cfg(scenes=1)
    generate(cfg, tmp_path / "a", progress=False)
    assert (tmp_path / "a" / "train_pbr" / "000000" / CAPTIONS_FILE).read_bytes() == \
        (captioned / "train_pbr" / "000000" / CAPTIONS_FILE).read_bytes()


def test_colour_comes_from_material_and_dominant_face_colour(tmp_path):
    """A box with red sides and white ends (mostly red by area, pink on average) is red; a blue can is blue."""
    for cat in ("box", "can", "bowl"):
        (tmp_path / "meshes" / cat).mkdir(parents=True)
    b = trimesh.creation.box(extents=(0.1, 0.1, 0.06))
    fc = np.tile([220, 20, 20, 255], (len(b.faces), 1)).astype(np.uint8)
    fc[np.abs(b.face_normals[:, 2]) > 0.9] = [245, 245, 245, 255]
    b.visual.face_colors = fc
    b.export(tmp_path / "meshes" / "box" / "redbox.ply")
    c = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=24)
    c.visual.vertex_colors = np.tile([30, 60, 210, 255], (len(c.vertices), 1)).astype(np.uint8)
    c.export(tmp_path / "meshes" / "can" / "bluecan.ply")
    trimesh.creation.box(extents=(0.12, 0.12, 0.05)).export(tmp_path / "meshes" / "bowl" / "plain.obj")
    cfg = _cfg(objects=str(tmp_path / "meshes"), scenes=1, frames_per_scene=1, rig="shell",
               **{"materials.randomize_object_colour": False, "scene.objects_per_scene": [3, 3],
                  "scene.allow_repeats": False})
    generate(cfg, tmp_path / "ds", progress=False)
    insts = json.loads((tmp_path / "ds" / "train_pbr" / "000000" / CAPTIONS_FILE).read_text())["instances"]
    named = {r["category"]: r["colour"] for r in insts.values()}
    assert named == {"box": "red", "can": "blue", "bowl": "grey"}  # the plain mesh keeps the 0.7 grey default
    box = next(r for r in insts.values() if r["category"] == "box")
    np.testing.assert_allclose(box["rgb"], np.array([220, 20, 20]) / 255, atol=1e-4)
    assert all(r["unique"] and r["expressions"][0] == f"the {r['category']}" for r in insts.values())


def test_captions_refused_without_category_names(tmp_path):
    (tmp_path / "meshes").mkdir()
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(tmp_path / "meshes" / "000001.obj")
    with pytest.raises(ConfigError, match=r"captions = true needs a category name.*000001.*objects.toml"):
        generate(_cfg(objects=str(tmp_path / "meshes"), scenes=1), tmp_path / "ds", progress=False)
    assert not (tmp_path / "ds" / "train_pbr").exists()


# ---------------------------------------------------------------------------------------------------------
def _obj(gt_id, category, colour, centre, height=0.1, diameter=0.1, radius=0.05):
    z = centre[2]
    return CaptionObject(gt_id, gt_id + 1, category, colour, (0.5, 0.5, 0.5), diameter, tuple(centre),
                         z - height / 2, z + height / 2, radius)


def test_caption_scene_words_by_hand():
    """The camera looks along +y from y = -1 (image right = world +x, farther = larger y)."""
    cam = CameraModel.default(640, 480).with_pose(look_at_pose(np.array([0.0, -1.0, 1.0]), np.array([0, 0, 0.4])))
    objs = [_obj(0, "mug", "red", (-0.2, 0.0, 0.45)), _obj(1, "mug", "red", (0.2, 0.0, 0.45)),
            _obj(2, "bowl", "grey", (0.0, 0.0, 0.45)),
            _obj(3, "box", "brown", (0.0, 0.3, 0.45), radius=0.08),
            _obj(4, "can", "green", (0.0, 0.3, 0.56), height=0.12),  # on the box
            _obj(5, "can", "green", (0.35, 0.35, 0.46), height=0.12),
            _obj(6, "cup", "white", (-0.5, 0.3, 0.45), diameter=0.06),
            _obj(7, "cup", "white", (0.5, 0.0, 0.45), diameter=0.09),
            _obj(8, "cup", "white", (-0.5, 0.5, 0.45), diameter=0.15)]
    out = caption_scene(objs, cam, TABLE)["instances"]
    assert "the mug left of the bowl" in out["0"]["expressions"] and out["0"]["unique"]
    assert "the mug right of the bowl" in out["1"]["expressions"] and out["1"]["unique"]
    assert out["2"]["expressions"][0] == "the bowl"
    assert {"relation": "on top of", "gt_id": 3, "obj_id": 4, "landmark": "the box"} in out["4"]["relations"]
    assert not any(r["relation"] == "on" for r in out["4"]["relations"])
    assert out["5"]["expressions"][0] == "the can on the table"
    assert [out[k]["size"] for k in ("6", "7", "8")] == ["small", None, "large"]
    assert out["6"]["expressions"][0] == "the small cup" and out["8"]["expressions"][0] == "the large cup"
    assert out["7"]["unique"] and out["7"]["expressions"][0] == "the cup right of the bowl"


def test_caption_scene_says_when_nothing_is_unique():
    cam = CameraModel.default(640, 480).with_pose(look_at_pose(np.array([0.0, -1.0, 1.0]), np.array([0, 0, 0.4])))
    objs = [_obj(0, "can", "green", (0.0, 0.0, 0.45)), _obj(1, "can", "green", (0.01, 0.0, 0.45))]
    out = caption_scene(objs, cam, TABLE)["instances"]
    assert [(r["unique"], r["expressions"]) for r in out.values()] == [(False, ["the green can on the table"])] * 2
