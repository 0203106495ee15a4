"""Distractor objects (``scene.distractor_objects``): meshes of another set dropped among the targets, drawn,
colliding and occluding, never annotated; scenes without them keep their bytes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.io.bop import read_depth, read_mask, read_scene, scene_dirs
from simtest.objects import load_object_set
from tests.generators.test_ground_truth import bop_rule_mask, model_surface_depth


@pytest.fixture(scope="module")
def distractor_config(small_config):
    # the distractor set is the target set: the same ids must still never be annotated
    return small_config.replace(**{"scenes": 1, "frames_per_scene": 3, "scene.distractors": [0, 0],
                                   "scene.distractor_objects": "builtin-small",
                                   "scene.distractor_object_count": [6, 6], "scene.objects_per_scene": [2, 2],
                                   "scene.drop_area": 0.3})


@pytest.fixture(scope="module")
def distractor_dataset(distractor_config, tmp_path_factory):
    from simtest.generators.pipeline import generate

    out = tmp_path_factory.mktemp("ds") / "distractor_objects"
    generate(distractor_config, out, progress=False)
    return out


def test_spec_draws_them_after_everything_else(distractor_config, small_config):
    """The targets and primitive distractors are the same with or without distractor objects (drawn after
    them), the count and the ids follow the config, and without them nothing more is drawn."""
    from simtest.generators.pipeline import load_objects
    from simtest.generators.scene_spec import sample_scene_spec
    from simtest.rng import child_rng

    cfg_without = distractor_config.replace(**{"scene.distractor_objects": None})
    objects = load_objects(distractor_config)
    with_them = sample_scene_spec(distractor_config, objects, child_rng(7, 0, 0), 0)
    without = sample_scene_spec(cfg_without, objects, child_rng(7, 0, 0), 0)
    assert with_them.objects == without.objects and with_them.distractors == without.distractors
    assert len(with_them.distractor_objects) == 6 and without.distractor_objects == ()
    assert {d.obj_id for d in with_them.distractor_objects} <= set(objects.ids)
    again = sample_scene_spec(distractor_config, objects, child_rng(7, 0, 0), 0)
    assert again == with_them
    # the default config draws no distractor objects at all: same spec as before the option existed
    assert sample_scene_spec(small_config, objects, child_rng(7, 0, 0), 0).distractor_objects == ()


def test_they_are_drawn_and_never_annotated(distractor_dataset):
    """Every image holds only the scene's targets (2), while the distractor objects' bodies are in the scene
    file's spec; their pixels belong to no target's visible mask."""
    for scene_dir in scene_dirs(distractor_dataset / "train_pbr"):
        info = json.loads((scene_dir / "scene_info.json").read_text())
        assert len(info["spec"]["distractor_objects"]) == 6
        for im in read_scene(scene_dir).values():
            assert len(im["gt"]) == 2 - len(info["removed_instances"])


def test_they_occlude_by_the_bop_rule(distractor_dataset):
    """Visible masks agree with the BOP visibility rule on the rendered depth, which holds the distractor
    objects (IoU > 0.9 per target), and targets lose pixels to them: surface pixels hidden by something
    nearer that is no other target (no primitive distractors here)."""
    objects = load_object_set("builtin-small")
    hidden_by_distractors = 0
    for scene_dir in scene_dirs(distractor_dataset / "train_pbr"):
        for im_id, im in read_scene(scene_dir).items():
            depth = read_depth(scene_dir, im_id, im["depth_scale"])
            amodal = [read_mask(scene_dir, im_id, k, visible=False) for k in range(len(im["gt"]))]
            for gt_id, gt in enumerate(im["gt"]):
                if gt.px_count_visib < 30:
                    continue
                model_depth = model_surface_depth(objects.get(gt.obj_id), gt, im, depth.shape)
                visib = read_mask(scene_dir, im_id, gt_id)
                rule = bop_rule_mask(model_depth, depth)
                assert (rule & visib).sum() / (rule | visib).sum() > 0.9
                others = np.any([a for k, a in enumerate(amodal) if k != gt_id], axis=0) if len(amodal) > 1 \
                    else np.zeros_like(visib)
                hidden_by_distractors += int(((model_depth - depth > 0.005) & (depth > 0) & ~others & ~visib).sum())
    assert hidden_by_distractors > 0, "no target pixel was hidden by a distractor object: the test shows nothing"


def test_bad_set_is_refused_with_the_key(small_config, tmp_path):
    from simtest.generators.pipeline import generate

    bad = small_config.replace(**{"scene.distractor_objects": str(tmp_path / "nowhere")})
    with pytest.raises(ConfigError, match="scene.distractor_objects"):
        generate(bad, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_they_are_free_drawn_colliding_bodies(distractor_config):
    """Each distractor object is a free body with its visual mesh drawn in group 0 (an occluder, never an
    annotated instance) and its convex parts colliding; it settles on the table like a target."""
    from simtest.generators.builder import COLLISION_GROUP
    from simtest.generators.pipeline import load_objects, prepare_scene

    scene, settled, *_ = prepare_scene(distractor_config, load_objects(distractor_config), 0)
    m = scene.model
    visual = [g for g in range(m.ngeom) if m.geom(g).name.startswith("dobj_") and m.geom(g).name.endswith("_visual")]
    parts = [g for g in range(m.ngeom) if m.geom(g).name.startswith("dobj_") and "_col" in m.geom(g).name]
    assert len(visual) == 6 and parts
    assert np.all(m.geom_group[visual] == 0) and np.all(m.geom_group[parts] == COLLISION_GROUP)
    assert np.all(scene.geom_instance[visual + parts] == -1)
    bodies = {int(m.geom_bodyid[g]) for g in visual}
    table = distractor_config.scene.table_height
    heights = [scene.data.xpos[b][2] - table for b in bodies]
    assert settled.at_rest
    # dropped from <= 0.25 m above the table: at rest on it, or fallen off and parked out of sight by settling
    assert all(-0.01 < h < 0.15 or h > 100.0 for h in heights), heights
    assert sum(h < 0.15 for h in heights) >= 3
