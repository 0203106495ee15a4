"""The recorder hands every file of a scene to its writer; the pipeline keeps only the orchestration."""

from __future__ import annotations

import json

import pytest

from simtest.generators.pipeline import load_objects, prepare_scene
from simtest.generators.recorder import INFO_FILE, OCCLUSION_FILE, SceneRecorder, scene_cameras
from simtest.io.bop import SceneWriter


def test_a_recorded_scene_is_written_only_through_its_writer(small_config, tmp_path):
    cfg = small_config.replace(**{"frames_per_scene": 2, "occlusion.level": "L1", "captions": True,
                                  "annotation.channels": ["flow"]})
    objects = load_objects(cfg)
    scene, settled, attempts, reasons = prepare_scene(cfg, objects, 0)
    cameras = scene_cameras(cfg, scene)
    writer = SceneWriter(tmp_path, 0)
    recorder = SceneRecorder(cfg, objects, scene, writer, 0)
    recorder.record(cameras, finish_behind=False)
    recorder.write_records(settled, attempts, reasons, cameras[0][0])
    assert list(tmp_path.iterdir()) == [writer.dir]  # nothing beside the writer's own partial folder
    final = writer.close()
    assert sorted(p.name for p in (final / "flow").iterdir()) == ["000000.png"]  # the last view has none
    assert set(json.loads((final / OCCLUSION_FILE).read_text())) == {"0", "1"}
    assert json.loads((final / INFO_FILE).read_text())["attempts"] == attempts
    assert (final / "scene_captions.json").is_file()


def test_moved_names_still_import_from_the_pipeline_with_a_warning():
    import simtest.generators.pipeline as pipeline
    from simtest.generators.dense import DenseViews
    from simtest.generators.views_behind import ViewsBehind

    for name, value in (("scene_cameras", scene_cameras), ("ViewsBehind", ViewsBehind), ("DenseViews", DenseViews)):
        with pytest.warns(DeprecationWarning, match=f"simtest.generators.pipeline.{name} moved"):
            assert getattr(pipeline, name) is value
    with pytest.raises(AttributeError, match="no_such_name"):
        pipeline.no_such_name  # noqa: B018
