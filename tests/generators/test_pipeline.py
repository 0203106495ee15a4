"""The generate pipeline: determinism across workers, kill -9 + resume, settling, and clear errors."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest

from simtest.errors import ConfigError, DatasetError
from simtest.generators.config import GenerateConfig
from simtest.generators.pipeline import generate, prepare_scene
from simtest.generators.settle import body_radius, body_speed


def _digest(root: Path) -> dict[str, str]:
    """sha1 of every file under ``root`` except the manifest (it records the command line)."""
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and p.name != "manifest.json":
            out[str(p.relative_to(root))] = hashlib.sha1(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def tiny_config(small_config):
    return small_config.replace(**{"scenes": 3, "frames_per_scene": 2, "camera.width": 96, "camera.height": 72})


def test_same_seed_same_bytes_with_1_or_2_workers(tmp_path, tiny_config):
    a = generate(tiny_config, tmp_path / "a", progress=False)
    generate(tiny_config.replace(workers=2), tmp_path / "b", progress=False)
    assert a.scenes_done == 3 and a.frames_written == 6
    da, db = _digest(tmp_path / "a"), _digest(tmp_path / "b")
    assert len(da) > 20 and da == db
    assert any(k.endswith(".jpg") for k in da)  # JPEG colour (the default) is deterministic too
    c = generate(tiny_config.replace(seed=8), tmp_path / "c", progress=False)
    assert c.frames_written == 6
    assert _digest(tmp_path / "c") != da


def test_resume_after_kill_equals_uninterrupted_run(tmp_path, tiny_config):
    cfg = tiny_config.replace(scenes=8)
    ref = tmp_path / "ref"
    generate(cfg, ref, progress=False)
    out = tmp_path / "killed"
    code = ("import sys; from simtest.generators.config import GenerateConfig; "
            "from simtest.generators.pipeline import generate; import json; "
            f"generate(GenerateConfig.from_dict(json.loads(sys.argv[1])), {str(out)!r}, progress=False)")
    import json

    proc = subprocess.Popen([sys.executable, "-c", code, json.dumps(cfg.to_dict())], env=dict(os.environ))
    deadline = time.time() + 120
    split = out / "train_pbr"
    while time.time() < deadline and proc.poll() is None:
        if split.is_dir() and any(p.name == "000000" for p in split.iterdir()):
            break
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done_before = sorted(p.name for p in split.iterdir() if not p.name.startswith("."))
    assert len(done_before) < 8, "the run finished before it could be killed"
    with pytest.raises(DatasetError, match="--resume"):
        generate(cfg, out, progress=False)
    rep = generate(cfg, out, resume=True, progress=False)
    assert rep.scenes_skipped == len(done_before)
    assert _digest(out) == _digest(ref)
    assert not list(split.glob(".*"))  # no partial scene folders left


def test_resume_refuses_other_config(tmp_path, tiny_config):
    generate(tiny_config.replace(scenes=1), tmp_path / "d", progress=False)
    with pytest.raises(DatasetError, match="frames_per_scene"):
        generate(tiny_config.replace(scenes=1, frames_per_scene=3), tmp_path / "d", resume=True, progress=False)
    rep = generate(tiny_config.replace(scenes=1), tmp_path / "d", overwrite=True, progress=False)
    assert rep.scenes_done == 1


def test_settled_objects_rest_without_interpenetration(tiny_config):
    import simtest.objects as objs

    objects = objs.load_object_set(tiny_config.objects)
    cfg = tiny_config.replace(**{"scene.objects_per_scene": [6, 8]})
    for scene_id in range(2):
        scene, result, _, _ = prepare_scene(cfg, objects, scene_id)
        assert result.at_rest, result
        m, d = scene.model, scene.data
        for i, active in enumerate(scene.active):
            if active:
                b, v = scene.instance_bodies[i], scene.instance_dofs[i]
                assert body_speed(m, d, b, v, body_radius(m, b)) < cfg.scene.settle_velocity
                R, t = scene.object_pose_world(i)
                assert t[2] > cfg.scene.table_height - 0.005
        mujoco.mj_forward(m, d)
        for c in d.contact[:d.ncon]:
            assert c.dist > -0.003, f"penetration {c.dist * 1000:.1f} mm between geoms {c.geom1} and {c.geom2}"
        # bodies slept while settling; afterwards the flag is off again and every body simulates (the grasp env
        # steps the same model)
        assert not m.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        assert d.nbody_awake == m.nbody


def test_bad_config_values_name_the_field(tmp_path):
    with pytest.raises(ConfigError, match=r"camera\.width = 3 is invalid; allowed: \[16, 8192\]"):
        GenerateConfig().replace(**{"camera.width": 3})
    with pytest.raises(ConfigError, match="rig = 'orbit'"):
        GenerateConfig.from_dict({"rig": "orbit"})
    with pytest.raises(ConfigError, match="unknown field"):
        GenerateConfig.from_dict({"scene": {"tabel_height": 1}})
    bad = tmp_path / "bad.toml"
    bad.write_text("scenes = -1\n")
    from simtest.generators.config import load_config

    with pytest.raises(ConfigError, match=str(bad)):
        load_config(bad)


def test_cli_generate_refuses_non_empty_folder(tmp_path, capsys):
    from simtest.cli import main

    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "keep.txt").write_text("user data")
    code = main(["generate", "--objects", "builtin-small", "--scenes", "1", "--frames-per-scene", "1",
                 "--width", "64", "--out", str(tmp_path / "x"), "--quiet"])
    assert code == 2
    assert "not empty" in capsys.readouterr().err
    assert (tmp_path / "x" / "keep.txt").read_text() == "user data"


def test_unplaceable_scene_is_retried_and_reported(tiny_config):
    """Objects that cannot fit are re-sampled with new sub-seeds; after max_attempts the error says why."""
    import simtest.objects as objs

    objects = objs.load_object_set(tiny_config.objects)
    cfg = tiny_config.replace(**{"scene.table_size": [0.1, 0.1], "scene.objects_per_scene": [40, 40],
                                 "scene.max_attempts": 2})
    with pytest.raises(DatasetError, match=r"no usable scene in 2 attempts.*do not fit"):
        prepare_scene(cfg, objects, 0)


def test_rigs_wrist_and_sequence(tmp_path, tiny_config):
    """The wrist rig's frames come from reachable arm poses; a sequence moves the camera smoothly."""
    import json

    from simtest.io.bop import read_scene

    cfg = tiny_config.replace(scenes=1, frames_per_scene=4)
    generate(cfg.replace(rig="wrist"), tmp_path / "wrist", progress=False)
    info = json.loads((tmp_path / "wrist" / "train_pbr" / "000000" / "scene_info.json").read_text())
    assert info["at_rest"] is True
    ims = read_scene(tmp_path / "wrist" / "train_pbr" / "000000")
    dists = [np.linalg.norm(im["T_cam_world"].inverse().t - np.array([-0.5, 0.0, 0.4])) for im in ims.values()]
    assert all(d < 1.0 for d in dists)  # within the arm's reach of its base at the table edge
    generate(cfg.replace(rig="sequence", frames_per_scene=8), tmp_path / "seq", progress=False)
    ims = read_scene(tmp_path / "seq" / "train_pbr" / "000000")
    centres = np.array([ims[i]["T_cam_world"].inverse().t for i in sorted(ims)])
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    # Eased motion: no jumps (the fastest step is at most pi/2 x the mean one, plus slack) and no stops.
    assert steps.min() > 0.0 and steps.max() < 1.8 * steps.mean()


def test_coco_annotations_decode_to_visible_masks(tmp_path, tiny_config):
    import json

    from pycocotools import mask as mask_utils

    from simtest.io.bop import read_mask

    generate(tiny_config.replace(scenes=1, **{"render.coco": True}), tmp_path / "c", progress=False)
    scene = tmp_path / "c" / "train_pbr" / "000000"
    coco = json.loads((scene / "scene_gt_coco.json").read_text())
    gt = json.loads((scene / "scene_gt.json").read_text())
    assert coco["images"] and coco["annotations"]
    for ann in coco["annotations"]:
        im = str(ann["image_id"])
        decoded = mask_utils.decode({"size": ann["segmentation"]["size"],
                                     "counts": ann["segmentation"]["counts"].encode()}).astype(bool)
        matches = [j for j, g in enumerate(gt[im]) if g["obj_id"] == ann["category_id"]
                   and (read_mask(scene, int(im), j) == decoded).all()]
        assert matches and decoded.sum() == ann["area"]


def test_coco_ground_truth_fed_back_scores_ap_1(tmp_path, tiny_config):
    """pycocotools reads scene_gt_coco.json as the BOP toolkit writes it: ids from 1, ``ignore`` below 10 %
    visibility, amodal boxes; the ground truth fed back as detections scores AP 1.0 (segm and bbox)."""
    import contextlib
    import io
    import json

    from pycocotools import mask as mask_utils
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    from simtest.io.bop import read_mask

    generate(tiny_config.replace(scenes=1, frames_per_scene=3, **{"render.coco": True}), tmp_path / "c",
             progress=False)
    scene = tmp_path / "c" / "train_pbr" / "000000"
    path = scene / "scene_gt_coco.json"
    data = json.loads(path.read_text())
    infos = json.loads((scene / "scene_gt_info.json").read_text())
    gts = json.loads((scene / "scene_gt.json").read_text())
    anns = data["annotations"]
    ids = [a["id"] for a in anns]
    assert anns and min(ids) >= 1 and len(set(ids)) == len(ids)
    assert [im["file_name"] for im in data["images"]] == [f"rgb/{i:06d}.jpg" for i in range(3)]
    # Each annotation is, in order, a visible instance of scene_gt: its ignore flag and box follow calc_gt_coco.
    visible = [(int(k), j) for k in gts for j in range(len(gts[k])) if infos[k][j]["px_count_visib"] > 0]
    assert len(visible) == len(anns)
    for a, (im, j) in zip(anns, visible):
        assert a["image_id"] == im and a["category_id"] == gts[str(im)][j]["obj_id"] and a["iscrowd"] == 0
        assert a["ignore"] is (infos[str(im)][j]["visib_fract"] < 0.1)
        amodal = read_mask(scene, im, j, visible=False)
        ys, xs = np.nonzero(amodal)
        assert a["bbox"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
        rle = dict(a["segmentation"], counts=a["segmentation"]["counts"].encode())
        assert np.array_equal(mask_utils.decode(rle).astype(bool), read_mask(scene, im, j))
    with contextlib.redirect_stdout(io.StringIO()):
        coco_gt = COCO(str(path))
        for iou_type in ("segm", "bbox"):
            dets = [{k: a[k] for k in ("image_id", "category_id", "segmentation", "bbox")} | {"score": 1.0}
                    for a in anns]
            ev = COCOeval(coco_gt, coco_gt.loadRes(dets), iou_type)
            ev.evaluate()
            ev.accumulate()
            ev.summarize()
            assert abs(ev.stats[0] - 1.0) < 1e-6, (iou_type, ev.stats[0])


def test_coco_modal_boxes_and_png_rgb_option(tmp_path, tiny_config):
    """render.coco_bbox = "modal" boxes the visible mask; --rgb-format png writes lossless rgb/*.png that the
    readers take like the JPEG default."""
    import json

    from simtest.cli import build_parser
    from simtest.cli.generate import config_from_args
    from simtest.io.bop import read_image, read_mask

    args = build_parser().parse_args(["generate", "--rgb-format", "png", "--out", str(tmp_path / "x")])
    cfg = config_from_args(args)
    assert cfg.render.rgb_format == "png" and GenerateConfig().render.rgb_format == "jpg"
    cfg = tiny_config.replace(scenes=1, frames_per_scene=1, **{"render.coco": True, "render.coco_bbox": "modal",
                                                                "render.rgb_format": "png"})
    generate(cfg, tmp_path / "p", progress=False)
    generate(tiny_config.replace(scenes=1, frames_per_scene=1), tmp_path / "j", progress=False)
    scene = tmp_path / "p" / "train_pbr" / "000000"
    assert sorted(p.name for p in (scene / "rgb").iterdir()) == ["000000.png"]
    jpg = read_image(tmp_path / "j" / "train_pbr" / "000000", 0).astype(int)
    png = read_image(scene, 0).astype(int)
    psnr = 10 * np.log10(255.0 ** 2 / np.mean((png - jpg) ** 2))
    assert png.shape == jpg.shape and 30.0 < psnr < 99.0, psnr  # same render; JPEG at quality 95 is lossy
    data = json.loads((scene / "scene_gt_coco.json").read_text())
    assert data["images"][0]["file_name"] == "rgb/000000.png"
    gts = json.loads((scene / "scene_gt.json").read_text())["0"]
    visible = [j for j in range(len(gts)) if read_mask(scene, 0, j).any()]
    for a, j in zip(data["annotations"], visible):
        ys, xs = np.nonzero(read_mask(scene, 0, j))
        assert a["bbox"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
    with pytest.raises(ConfigError, match="render.coco_bbox = 'full'"):
        GenerateConfig().replace(**{"render.coco_bbox": "full"})


def test_config_toml_round_trip(tmp_path):
    from simtest.generators.config import load_config

    cfg = GenerateConfig().replace(**{"scenes": 3, "camera.fx": 600.0, "occlusion.level": "L2", "rig": "wrist"})
    path = tmp_path / "c.toml"
    path.write_text(cfg.to_toml())
    assert load_config(path) == cfg


def test_scenes_made_ahead_equal_scenes_made_in_turn(tmp_path):
    """One worker prepares the next scene on a helper thread while it renders the current one; every file is
    the same as when each scene is prepared when its turn comes."""
    import hashlib

    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import ScenesAhead, load_objects, prepare_scene, render_scene

    cfg = GenerateConfig().replace(**{"objects": "builtin-small", "scenes": 3, "frames_per_scene": 2,
                                      "camera.width": 96, "camera.height": 72, "seed": 5})
    objects = load_objects(cfg)
    ahead = ScenesAhead(cfg, objects, [2, 0, 1])
    try:
        for i in (2, 0, 1):
            render_scene(cfg, objects, i, tmp_path / "ahead", prepared=ahead.take(i))
    finally:
        ahead.close()
    for i in (0, 1, 2):
        render_scene(cfg, objects, i, tmp_path / "turn", prepared=prepare_scene(cfg, objects, i))

    def digest(root):
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file()}

    a, b = digest(tmp_path / "ahead"), digest(tmp_path / "turn")
    assert len(a) > 10 and a == b


@pytest.mark.parametrize("changes", [{"rig": "wrist"}, {"occlusion.level": "mixed"}],
                         ids=["wrist", "occlusion"])
def test_views_finished_behind_equal_views_finished_in_turn(tmp_path, changes):
    """Each view is annotated and written on a helper thread while the next one renders; every file is the
    same as when each view is finished before the next, also where the scene changes between views (the wrist
    camera moves with the arm; occluders move)."""
    import hashlib

    from simtest.generators.pipeline import load_objects, prepare_scene, render_scene

    cfg = GenerateConfig().replace(**{"objects": "builtin-small", "scenes": 1, "frames_per_scene": 4,
                                      "camera.width": 96, "camera.height": 72, "seed": 11, **changes})
    objects = load_objects(cfg)
    for name, behind in (("behind", True), ("turn", False)):
        render_scene(cfg, objects, 0, tmp_path / name, prepared=prepare_scene(cfg, objects, 0),
                     finish_behind=behind)

    def digest(root):
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file()}

    a, b = digest(tmp_path / "behind"), digest(tmp_path / "turn")
    assert len(a) > 10 and a == b


def test_scene_state_stays_as_taken():
    """``SimScene.state()`` keeps the instances' poses of its moment while the simulation moves on."""
    from simtest.generators.pipeline import load_objects

    cfg = GenerateConfig().replace(**{"objects": "builtin-small", "seed": 2})
    scene, _, _, _ = prepare_scene(cfg, load_objects(cfg), 0)
    state = scene.state()
    before = [(R.copy(), t.copy()) for R, t in state.poses]
    scene.data.qpos[scene.instance_qpos[0]:scene.instance_qpos[0] + 3] += 0.3
    mujoco.mj_forward(scene.model, scene.data)
    assert not np.allclose(scene.object_pose_world(0)[1], before[0][1])
    for (R, t), (R0, t0) in zip(state.poses, before):
        np.testing.assert_array_equal(R, R0)
        np.testing.assert_array_equal(t, t0)
    assert state.object_pose_world(0) is state.poses[0]
    assert state.instance_obj_ids == tuple(scene.instance_obj_ids) and state.active == tuple(scene.active)


def test_views_behind_raise_a_failed_views_error_and_keep_the_first():
    from simtest.generators.views_behind import ViewsBehind

    done = []

    def view(k):
        if k == 2:
            raise ValueError(f"view {k} failed")
        done.append(k)

    behind = ViewsBehind()
    behind.submit(view, 0)
    behind.submit(view, 1)
    behind.submit(view, 2)
    with pytest.raises(ValueError, match="view 2 failed"):
        behind.submit(view, 3)  # the failure surfaces before the next view starts
    behind.close()
    assert done == [0, 1]  # in order; nothing after the failed view
    with pytest.raises(ValueError, match="view 2 failed"):
        with ViewsBehind() as behind:
            behind.submit(view, 2)
    with pytest.raises(KeyError):  # an error of the rendering side is kept over the view's
        with ViewsBehind() as behind:
            behind.submit(view, 2)
            raise KeyError("render failed")
