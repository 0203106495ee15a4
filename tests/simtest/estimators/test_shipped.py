"""The shipped networks are chosen by the objects' content: builtin-small's for builtin-small, LM-O's for the
LM-O models (where ../shared/real/lmo and the shipped LM-O files are present), and other sets are refused with
the reason for each shipped set."""

from __future__ import annotations

from pathlib import Path

import pytest

from simtest.errors import ConfigError
from simtest.estimators.keypoints.crop_infer import CROP_FORMAT
from simtest.estimators.segicp.infer import FORMAT as SEG_FORMAT
from simtest.estimators.shipped import choose, shipped_nets, weights_dir
from simtest.objects import load_object_set

LMO = Path(__file__).resolve().parents[3].parent / "shared" / "real" / "lmo"


def test_the_shipped_files_carry_their_object_records():
    nets = shipped_nets("keypoints", CROP_FORMAT)
    assert "builtin-small" in [n.object_set for n in nets]
    for n in nets:
        assert n.path.is_file() and n.path.with_suffix(".onnx").is_file()
        assert n.path.parent == weights_dir() and n.size[0] > n.size[1] > 0
        assert len(n.record["obj_ids"]) == len(n.record["mesh_hashes"]) > 0
    # a detector is not a crop network: the format in the file decides, not the name
    assert all(n.family == "keypoints_detector" for n in shipped_nets("keypoints_detector", SEG_FORMAT))
    assert shipped_nets("keypoints_detector", CROP_FORMAT) == []


def test_builtin_small_gets_its_network_and_other_sets_are_refused_with_reasons():
    net = choose("keypoints", CROP_FORMAT, load_object_set("builtin-small"), what="keypoints")
    assert net.object_set == "builtin-small"
    with pytest.raises(ConfigError) as err:
        choose("keypoints", CROP_FORMAT, load_object_set("builtin"), what="keypoints")
    msg = str(err.value)
    assert "no shipped network was trained for these objects" in msg
    assert "keypoints_builtin-small_320x240.onnx (builtin-small)" in msg and "Train one" in msg
    from simtest.estimators.templates.outline import shipped_outline

    assert shipped_outline(load_object_set("builtin-small")) is None  # no outline network for it: no outline fit


def test_the_estimator_without_options_refuses_an_unknown_set_naming_the_shipped_ones():
    from simtest.estimators import load_estimator

    est = load_estimator("keypoints")
    with pytest.raises(ConfigError, match="builtin-small"):
        est.check_objects(load_object_set("builtin"))


@pytest.mark.skipif(not (LMO / "models").is_dir(), reason=f"the real LM-O frames are not here ({LMO})")
def test_the_lmo_models_get_the_lmo_networks():
    from simtest.estimators import load_estimator

    if not any(n.object_set == "lmo" for n in shipped_nets("keypoints", CROP_FORMAT)):
        pytest.skip(f"no shipped LM-O network in {weights_dir()}")
    objects = load_object_set(LMO / "models")
    assert choose("keypoints", CROP_FORMAT, objects, what="keypoints").object_set == "lmo"
    est = load_estimator("keypoints")  # no options: builtin-small's until it sees other objects
    est.check_objects(objects)
    assert Path(est.checkpoint).name.startswith("keypoints_lmo_")
    assert Path(est.segmenter.checkpoint).name == "keypoints_detector_lmo_640x480.onnx"
    # every shipped LM-O detector is loaded; template matching (LM-O's pose stage) pools their regions
    assert [Path(s.checkpoint).name for s in est.more_segmenters] == ["keypoints_detector_lmo_640x480.clutter.onnx"]
    assert est.class_ids == objects.ids
    # and the outline networks that fit the kept poses (templates, docs/sim2real.md, eighth and seventeenth
    # rounds): two trained on whole silhouettes, read as one
    from simtest.estimators.templates.outline import OutlineNets, load_outline, shipped_outline

    spec = shipped_outline(objects)
    assert [Path(p).name for p in spec.split("+")] == ["templates_outline_lmo_640x480.onnx",
                                                       "templates_outline_lmo_640x480.s2.onnx"]
    assert isinstance(load_outline(spec), OutlineNets)
    # its template stage takes minutes per real frame: the evaluation's default time limit follows it
    assert est.pose == "templates" and est.time_limit_s == 900.0
    assert load_estimator("keypoints").time_limit_s is None  # builtin-small's crop network: the default holds


def test_a_variant_is_a_second_network_of_its_set_and_comes_after_the_first(tmp_path):
    """``<family>_<set>_<W>x<H>.<variant>.onnx`` is one more network of the same set: :func:`choose_all`
    returns every match (the one without a variant first), :func:`choose` the first."""
    from simtest.estimators.shipped import choose_all

    src = weights_dir() / "keypoints_detector_builtin-small_320x240.onnx"
    for name in ["keypoints_detector_builtin-small_320x240.a-2.onnx", "keypoints_detector_builtin-small_320x240.onnx",
                 "keypoints_detector_builtin-small_320x240.b.onnx", "keypoints_detector_builtin-small_320x240.B.onnx"]:
        (tmp_path / name).write_bytes(src.read_bytes())
    nets = shipped_nets("keypoints_detector", SEG_FORMAT, tmp_path)
    assert [n.variant for n in nets] == ["", "a-2", "b"]  # an upper-case variant is not a shipped name
    objects = load_object_set("builtin-small")
    found = choose_all("keypoints_detector", SEG_FORMAT, objects, what="test", folder=tmp_path)
    assert [n.path.name for n in found] == [n.path.name for n in nets]
    assert found[0].path.name == "keypoints_detector_builtin-small_320x240.pt"
    assert choose("keypoints_detector", SEG_FORMAT, objects, what="test", folder=tmp_path) == found[0]
    with pytest.raises(ConfigError, match=r"\.a-2\.onnx \(builtin-small\)"):
        choose_all("keypoints_detector", SEG_FORMAT, load_object_set("builtin"), what="test", folder=tmp_path)


def test_the_pose_stage_follows_the_shipped_set():
    """``keypoints`` with no ``pose`` option: the crop network for builtin-small, template matching for LM-O's
    shipped set; an explicit ``pose`` wins, and a bad one is refused naming it."""
    from simtest.estimators import load_estimator
    from simtest.estimators.keypoints.crop_infer import CropKeypointEstimator
    from simtest.estimators.shipped import ShippedNet, pose_stage

    small = choose("keypoints", CROP_FORMAT, load_object_set("builtin-small"), what="keypoints")
    assert pose_stage(small) == "network"
    assert pose_stage(ShippedNet(small.path, "keypoints", "lmo", (640, 480), small.record)) == "templates"
    est = load_estimator("keypoints")
    est.check_objects(load_object_set("builtin-small"))
    assert est.pose == "network" and est.candidates == 1 and est.templates is None
    assert load_estimator("keypoints", pose="templates").pose == "templates"
    with pytest.raises(ConfigError, match="unknown pose 'mesh'"):
        CropKeypointEstimator(pose="mesh")
    with pytest.raises(ConfigError, match="unknown pose 'templates' for detect='segicp'"):
        CropKeypointEstimator(pose="templates", detect="segicp")


def test_detectors_joined_by_plus_are_pooled_in_that_order():
    from simtest.estimators import load_estimator
    from simtest.estimators.keypoints.crop_infer import default_detector

    det = default_detector().with_suffix(".onnx")
    missing = Path(__file__).parent / "no_such_detector.onnx"
    est = load_estimator("keypoints", detector=f"{det}+{det}")
    assert Path(est.segmenter.checkpoint) == det and [Path(s.checkpoint) for s in est.more_segmenters] == [det]
    with pytest.raises(ConfigError, match="no_such_detector.onnx"):
        load_estimator("keypoints", detector=f"{det}+{missing}")
