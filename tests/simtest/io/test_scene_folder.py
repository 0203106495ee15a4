"""The scene folder: written whole or not at all, every file through the writer, no name outside it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.errors import DatasetError
from simtest.io.bop import SceneWriter, decode_depth
from simtest.io.scene_folder import UNLABELLED_KEEP, SceneFolder, withhold_labels


@pytest.mark.parametrize("name", ["../escape.json", "/tmp/abs.json", "", "a/../../b.json", "..\\b.json"])
def test_the_writer_refuses_a_file_outside_its_folder(tmp_path, name):
    writer = SceneWriter(tmp_path / "split", 3)
    try:
        with pytest.raises(DatasetError, match="not a relative path inside the scene folder '000003'"):
            writer.write_json(name, {"a": 1})
        with pytest.raises(DatasetError):
            writer.add_image("../flow", 0, np.zeros((2, 2), np.uint16))
    finally:
        writer.discard()
    assert not (tmp_path / "escape.json").exists() and not (tmp_path / "split" / "000003").exists()
    assert not list((tmp_path / "split").iterdir())  # discarded: nothing left


def test_records_and_depth_go_through_the_writer_into_the_finished_folder(tmp_path):
    writer = SceneWriter(tmp_path, 0, depth_scale=0.1)
    writer.write_json("scene_info.json", {"scene_id": 0})
    writer.write_json("scene_occlusion.json", {"0": {"a": 1}, "1": {"a": 2}}, keyed=True)
    depth = np.array([[0.0, 0.5], [1.25, 2.0]], dtype=np.float32)
    writer.add_depth("depth_exact", 4, depth)
    final = writer.close()
    assert final == tmp_path / "000000" and json.loads((final / "scene_info.json").read_text()) == {"scene_id": 0}
    assert (final / "scene_occlusion.json").read_text().count("\n") >= 3  # one key per line
    import cv2

    back = cv2.imread(str(final / "depth_exact" / "000004.png"), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16 and np.allclose(decode_depth(back, 0.1), depth, atol=1e-4)


def test_a_folder_is_in_place_whole_or_not_at_all(tmp_path):
    folder = SceneFolder(tmp_path, "000001")
    folder.write_json("a.json", [1])
    assert not folder.final.exists() and folder.dir.name.startswith(".000001.")
    assert folder.commit() == tmp_path / "000001" and (tmp_path / "000001" / "a.json").is_file()
    assert not folder.dir.exists()
    other = SceneFolder(tmp_path, "000002")
    other.write_json("b.json", [2])
    other.discard()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["000001"]


def test_withheld_labels_leave_only_images_and_cameras(tmp_path):
    scene = tmp_path / "scene"
    for name in (*UNLABELLED_KEEP, "mask", "scene_gt.json"):
        (scene / name).mkdir(parents=True) if "." not in name else (scene / name).write_text("{}")
    withhold_labels(scene, tmp_path / "labels")
    assert sorted(p.name for p in scene.iterdir()) == sorted(UNLABELLED_KEEP)
    assert sorted(p.name for p in (tmp_path / "labels").iterdir()) == ["mask", "scene_camera.json", "scene_gt.json"]


def test_the_old_bop_names_forward_with_a_deprecation_warning():
    import simtest.io.bop as bop
    import simtest.io.scene_folder as scene_folder

    for name in bop.MOVED:
        with pytest.warns(DeprecationWarning, match=f"simtest.io.scene_folder.{name}"):
            assert getattr(bop, name) is getattr(scene_folder, name)
