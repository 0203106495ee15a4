"""Reading a BOP dataset validates its structure and ground truth: bad input is a DatasetError naming the file,
image, instance, field and value, raised before any estimator runs. Each test corrupts a copy of a dataset
written by the real generation pipeline."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from simtest.cli import main
from simtest.corrupt import CorruptionSpec, corrupt_dataset
from simtest.errors import DatasetError
from simtest.evaluation.run import evaluate, load_dataset_objects, score_results
from simtest.io import bop

SCENE = "train_pbr/000000"


class Recording:
    """An estimator that records the images it was called on (it must never be called on a bad dataset)."""

    def __init__(self) -> None:
        self.calls: list[int] = []

    def estimate(self, observation):
        self.calls.append(observation.im_id)
        return []


def _copy(src: Path, dst: Path, name: str | None = None, edit: Callable | None = None) -> Path:
    """A copy of dataset ``src`` at ``dst``; ``edit(data)`` changes ``SCENE/name`` (parsed JSON) in place."""
    shutil.copytree(src, dst)
    if name is not None and edit is not None:
        path = dst / SCENE / name
        data = json.loads(path.read_text())
        edit(data)
        path.write_text(json.dumps(data))  # NaN / Infinity are written as the tokens BOP files may contain
    return dst


def _set(key: str, index: int, field: str, value) -> Callable:
    def edit(data) -> None:
        data[key][index][field] = value
    return edit


def _evaluate_raises(ds: Path, pattern: str) -> None:
    est = Recording()
    with pytest.raises(DatasetError, match=pattern):
        evaluate(ds, est, progress=False, vsd=False)
    assert est.calls == []


# ---------------------------------------------------------------------------------------------------------
# scene_gt.json poses
@pytest.mark.parametrize("field, index, value", [("cam_t_m2c", 2, float("nan")), ("cam_R_m2c", 4, float("inf"))])
def test_non_finite_pose_names_file_image_instance_field(small_dataset, tmp_path, field, index, value):
    def edit(gt) -> None:
        gt["1"][1][field][index] = value

    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt.json", edit)
    _evaluate_raises(ds, rf"{SCENE}/scene_gt\.json: image 1, instance 1: {field} is \[.*(nan|inf).*NaN or "
                         r"infinite.*allowed: \d finite numbers")


@pytest.mark.parametrize("R, what", [
    (2 * np.eye(3), r"max \|R\^T R - I\| = 3"),
    (np.diag([1.0, 1.0, -1.0]), r"det = -1"),
])
def test_non_rotation_is_rejected_before_the_estimator_runs(small_dataset, tmp_path, R, what):
    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt.json", _set("0", 0, "cam_R_m2c", R.reshape(-1).tolist()))
    _evaluate_raises(ds, rf"{SCENE}/scene_gt\.json: image 0, instance 0: cam_R_m2c is .* not a rotation "
                         rf"\(.*{what}.*allowed: a row-major orthonormal 3x3 matrix with det \+1")
    with pytest.raises(DatasetError, match="not a rotation"):  # the oracle too: no "invalid-estimate"
        evaluate(ds, "oracle", progress=False, vsd=False)


def test_rotations_rounded_as_in_bop_files_are_accepted(small_dataset, tmp_path):
    def edit(gt) -> None:
        for insts in gt.values():
            for g in insts:
                g["cam_R_m2c"] = [round(v, 6) for v in g["cam_R_m2c"]]
                g["cam_t_m2c"] = [round(v, 3) for v in g["cam_t_m2c"]]

    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt.json", edit)
    frames = bop.read_scene(ds / SCENE, load_dataset_objects(ds).ids)
    assert frames and all(len(f["gt"]) > 0 for f in frames.values())


@pytest.mark.parametrize("field, value, pattern", [
    ("cam_R_m2c", [1, 0, 0, 0, 1, 0, 0, 0], r"cam_R_m2c is \[1, 0, 0, 0, 1, 0, 0, 0\]; allowed: a list of 9"),
    ("cam_t_m2c", [0, 0, "500"], r"cam_t_m2c is \[0, 0, '500'\]; allowed: a list of 3 finite numbers"),
    ("obj_id", 1.5, r"obj_id is 1\.5; allowed: an integer"),
    ("obj_id", None, r"obj_id is None"),
])
def test_malformed_instance_fields(small_dataset, tmp_path, field, value, pattern):
    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt.json", _set("2", 0, field, value))
    _evaluate_raises(ds, rf"{SCENE}/scene_gt\.json: image 2, instance 0: {pattern}")


def test_missing_instance_field(small_dataset, tmp_path):
    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt.json", lambda gt: gt["0"][0].pop("cam_t_m2c"))
    _evaluate_raises(ds, rf"{SCENE}/scene_gt\.json: image 0, instance 0: field 'cam_t_m2c' is missing "
                         r"\(required: obj_id, cam_R_m2c, cam_t_m2c\)")


def test_unknown_obj_id_names_file_image_and_known_ids(small_dataset, tmp_path):
    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt.json", _set("1", 0, "obj_id", 99))
    known = sorted(load_dataset_objects(ds).ids)
    pattern = (rf"{SCENE}/scene_gt\.json: image 1, instance 0: obj_id 99 is not a dataset object; known obj_ids "
               rf".*: {known}".replace("[", r"\[").replace("]", r"\]"))
    _evaluate_raises(ds, pattern)
    results = tmp_path / "results.csv"
    results.write_text("scene_id,im_id,obj_id,score,R,t,time\n")
    with pytest.raises(DatasetError, match=pattern):
        score_results(results, ds, progress=False, vsd=False)


def test_pose_dataset_reads_through_the_validated_reader(small_dataset, tmp_path):
    pytest.importorskip("torch")
    from simtest.data import PoseDataset

    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt.json", _set("1", 0, "obj_id", 99))
    with pytest.raises(DatasetError, match=rf"{SCENE}/scene_gt\.json: image 1, instance 0: obj_id 99"):
        PoseDataset(ds)
    # A chosen object set drops instances of other objects (documented), but poses are still checked.
    objects = load_dataset_objects(ds)
    assert len(PoseDataset(ds, objects=objects)) > 0
    bad = _copy(small_dataset, tmp_path / "bad", "scene_gt.json", _set("1", 0, "cam_R_m2c", [2, 0, 0, 0, 2, 0,
                                                                                                0, 0, 2]))
    with pytest.raises(DatasetError, match="not a rotation"):
        PoseDataset(bad, objects=objects)


# ---------------------------------------------------------------------------------------------------------
# Scene files and their consistency
@pytest.mark.parametrize("name", ["scene_gt_info.json", "scene_camera.json", "scene_gt.json"])
def test_missing_scene_file_is_named(small_dataset, tmp_path, name):
    ds = _copy(small_dataset, tmp_path / "ds")
    (ds / SCENE / name).unlink()
    _evaluate_raises(ds, rf"{SCENE}/{name}: file is missing")


def test_gt_info_length_must_match_scene_gt(small_dataset, tmp_path):
    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt_info.json", lambda info: info["2"].pop())
    n = len(json.loads((ds / SCENE / "scene_gt.json").read_text())["2"])
    _evaluate_raises(ds, rf"{SCENE}/scene_gt_info\.json: image 2: {n - 1} entries but scene_gt\.json has {n} "
                         "instances")


@pytest.mark.parametrize("field, value, pattern", [
    ("visib_fract", 1.5, r"visib_fract is 1\.5; allowed: a number in \[0, 1\]"),
    ("visib_fract", float("nan"), r"visib_fract is nan; allowed: a finite number"),
    ("px_count_visib", -3, r"px_count_visib is -3; allowed: an integer >= 0"),
    ("bbox_visib", [1, 2, 3], r"bbox_visib is \[1, 2, 3\]; allowed: a list of 4 finite numbers"),
])
def test_malformed_gt_info(small_dataset, tmp_path, field, value, pattern):
    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt_info.json", _set("0", 1, field, value))
    _evaluate_raises(ds, rf"{SCENE}/scene_gt_info\.json: image 0, instance 1: {pattern}")


def test_images_without_camera_are_named(small_dataset, tmp_path):
    def edit(cams) -> None:
        del cams["2"]

    ds = _copy(small_dataset, tmp_path / "ds", "scene_camera.json", edit)
    _evaluate_raises(ds, rf"{SCENE}/scene_gt\.json: image ids \[2\] have no entry in scene_camera\.json")


@pytest.mark.parametrize("field, value, pattern", [
    ("cam_K", [0.0, 0, 80, 0, 100, 60, 0, 0, 1], r"cam_K is .* with fx = 0, fy = 100; allowed: fx > 0 and fy > 0"),
    ("cam_K", [100.0, 0, 80, 0, 100, 60, 0, 0], r"cam_K is .*; allowed: a list of 9 finite numbers"),
    ("cam_K", [100.0, 0, float("nan"), 0, 100, 60, 0, 0, 1], r"cam_K is .*nan.* \(NaN or infinite\)"),
    ("depth_scale", 0, r"depth_scale is 0; allowed: a number > 0"),
    ("cam_R_w2c", [1, 0, 0, 0, 1, 0, 0, 0, 5], r"cam_R_w2c is .* not a rotation"),
])
def test_malformed_scene_camera(small_dataset, tmp_path, field, value, pattern):
    def edit(cams) -> None:
        cams["1"][field] = value

    ds = _copy(small_dataset, tmp_path / "ds", "scene_camera.json", edit)
    _evaluate_raises(ds, rf"{SCENE}/scene_camera\.json: image 1: {pattern}")


def test_invalid_json_names_line_and_column(small_dataset, tmp_path):
    ds = _copy(small_dataset, tmp_path / "ds")
    path = ds / SCENE / "scene_gt.json"
    lines = path.read_text().splitlines()
    lines[1] = lines[1].replace("]", "", 1)  # a bracket lost on line 2
    path.write_text("\n".join(lines))
    _evaluate_raises(ds, rf"{SCENE}/scene_gt\.json: not valid JSON at line 2, column \d+: ")


def test_camera_json_values_are_checked(small_dataset, tmp_path):
    ds = _copy(small_dataset, tmp_path / "ds")
    cam = json.loads((ds / "camera.json").read_text())
    cam["fy"] = -1.0
    (ds / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(DatasetError, match=r"camera\.json: field 'fy' is -1\.0; allowed: a finite number > 0"):
        bop.read_camera_json(ds / "camera.json")


# ---------------------------------------------------------------------------------------------------------
# Dataset and split folders
def test_missing_dataset_folder(tmp_path, capsys):
    missing = tmp_path / "nope"
    with pytest.raises(DatasetError, match=rf"dataset folder {missing} does not exist"):
        evaluate(missing, "oracle", progress=False)
    with pytest.raises(DatasetError, match="does not exist"):
        load_dataset_objects(missing)
    rc = main(["eval", "--estimator", "oracle", "--data", str(missing), "--out", str(tmp_path / "out"),
               "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err
    assert f"dataset folder {missing} does not exist" in err and "models_info" not in err


def test_missing_split_lists_the_splits_found(small_dataset):
    with pytest.raises(DatasetError, match=r"has no split folder 'test'; splits found: train_pbr$"):
        evaluate(small_dataset, "oracle", split="test", progress=False)


# ---------------------------------------------------------------------------------------------------------
# Other consumers and scale
def test_corrupt_dataset_rejects_bad_ground_truth_before_writing(small_dataset, tmp_path):
    ds = _copy(small_dataset, tmp_path / "ds", "scene_gt.json", _set("0", 0, "cam_R_m2c", [float("nan")] * 9))
    out = tmp_path / "out"
    with pytest.raises(DatasetError, match=rf"{SCENE}/scene_gt\.json: image 0, instance 0: cam_R_m2c"):
        corrupt_dataset(ds, out, CorruptionSpec(weather="fog", severity=1), seed=0, progress=False)
    assert not out.exists()


def test_validation_locates_one_bad_instance_among_many(tmp_path):
    """A scene of 20000 instances is checked in one pass; the bad one is found by its image and index."""
    rng = np.random.default_rng(0)
    from scipy.spatial.transform import Rotation

    Rs = Rotation.random(20000, random_state=rng).as_matrix().reshape(-1, 9).round(6)
    gts = {str(im): [{"obj_id": 1 + j % 3, "cam_R_m2c": Rs[im * 10 + j].tolist(), "cam_t_m2c": [0.0, 0.0, 500.0]}
                     for j in range(10)] for im in range(2000)}
    path = tmp_path / "scene_gt.json"
    assert len(bop.validate_scene_gt(gts, path, obj_ids=[1, 2, 3])) == 2000
    gts["1234"][7]["cam_R_m2c"] = (-Rs[12347]).tolist()  # a reflection (det -1)
    with pytest.raises(DatasetError, match=r"scene_gt\.json: image 1234, instance 7: cam_R_m2c .* det = -1"):
        bop.validate_scene_gt(gts, path, obj_ids=[1, 2, 3])
