"""Generation conditions of a sweep: render profiles and a simulated depth sensor over the same scenes, the
ground truth byte-identical to the clean dataset's, in the tables and the report; refusals of overrides."""

from __future__ import annotations

import base64
import importlib.util
import csv
import json
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.sweeps.grid import SweepConfig, conditions_of, run_sweep
from simtest.sweeps.renders import check_same_ground_truth

W, H = 80, 60
GEN = {"objects": "builtin-small", "scenes": 1, "frames_per_scene": 2, "camera": {"width": W, "height": H}}
SWEEP = {
    "seed": 0,
    "estimators": [{"name": "icp", "estimator": "icp"}],
    "dataset": {"generate": GEN},
    "factors": {"occlusion": [], "corruptions": [], "depth_noise": ["realsense-d435"],
                "renderers": ["fast", "quality"], "depth_sensors": ["d435-stereo"]},
}
GT_FILES = ("scene_gt.json", "scene_gt_info.json", "scene_camera.json")


def _scene(dataset: Path) -> Path:
    return dataset / "train_pbr" / "000000"


def _same_bytes(a: Path, b: Path) -> bool:
    return bool(a.read_bytes() == b.read_bytes())


def _files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _cell_dataset(out: Path, cond: str) -> Path:
    return Path(json.loads((out / "cells" / "icp" / cond / "pose" / "cell.json").read_text())["dataset"])


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    cfg = SweepConfig.from_dict(SWEEP)
    out = tmp_path_factory.mktemp("gen-sweep") / "s"
    rep = run_sweep(cfg, out, progress=False)
    return cfg, out, rep


def test_conditions_and_cells_of_generation_conditions(sweep):
    cfg, out, rep = sweep
    conds = {c.name: c for c in conditions_of(cfg)}
    assert conds["quality"].factor == "render" and conds["quality"].overrides == {"render.profile": "quality"}
    assert conds["depth-d435-stereo"].factor == "sensor"
    assert conds["depth-d435-stereo"].overrides == {"render.depth_sensor": "d435-stereo"}
    assert sorted(rep.cells_run) == sorted(f"icp/{c}/pose" for c in conds)


def test_render_condition_has_the_clean_ground_truth_byte_for_byte(sweep):
    _, out, _ = sweep
    clean, quality = _scene(out / "data" / "clean"), _scene(out / "data" / "quality")
    assert _cell_dataset(out, "quality") == out / "data" / "quality"
    for name in GT_FILES:
        assert _same_bytes(clean / name, quality / name), name
    for folder in ("mask", "mask_visib", "depth"):
        assert _files(clean / folder) == _files(quality / folder) and _files(clean / folder)
        for f in _files(clean / folder):
            assert _same_bytes(clean / folder / f, quality / folder / f), f"{folder}/{f}"
    # it is another rendering: the RGB differs
    assert not all(_same_bytes(clean / "rgb" / f, quality / "rgb" / f) for f in _files(clean / "rgb"))


def test_condition_equal_to_the_clean_generation_is_the_clean_dataset(sweep):
    _, out, _ = sweep
    assert _cell_dataset(out, "fast") == out / "data" / "clean"  # the clean set is rendered with "fast"
    assert not (out / "data" / "fast").exists()


def test_depth_sensor_condition_senses_depth_and_keeps_the_exact_one(sweep):
    _, out, _ = sweep
    clean, sensed = _scene(out / "data" / "clean"), _scene(out / "data" / "depth-d435-stereo")
    for name in GT_FILES:
        assert _same_bytes(clean / name, sensed / name), name
    for folder in ("mask", "mask_visib"):
        for f in _files(clean / folder):
            assert _same_bytes(clean / folder / f, sensed / folder / f), f"{folder}/{f}"
    for f in _files(clean / "depth"):  # the same 16-bit values (the two folders' PNG settings may differ)
        exact = cv2.imread(str(sensed / "depth_exact" / f), cv2.IMREAD_UNCHANGED)
        assert exact.dtype == np.uint16 and np.array_equal(cv2.imread(str(clean / "depth" / f), cv2.IMREAD_UNCHANGED),
                                                           exact), f
    assert not all(_same_bytes(clean / "depth" / f, sensed / "depth" / f) for f in _files(clean / "depth"))
    assert all(_same_bytes(clean / "rgb" / f, sensed / "rgb" / f) for f in _files(clean / "rgb"))


def test_renderer_and_sensor_columns_are_filled(sweep):
    _, out, _ = sweep
    tables = (out / "tables.md").read_text()
    header = re.compile(r"\| estimator \| L0 \(n=(\d+)\) \| realsense-d435 \(n=\1\) \| d435-stereo \(n=\1\) \| "
                        r"fast \(n=\1\) \| quality \(n=\1\) \|")  # the same targets in every column
    assert header.search(tables), tables
    rows = [line for line in tables.splitlines() if line.startswith("| icp (GT masks) |")]
    assert rows and all("-" not in [c.strip() for c in r.strip("|").split("|")] for r in rows), rows
    assert "renderer: fast quality" in tables
    with open(out / "summary.csv", newline="") as fh:
        summary = list(csv.DictReader(fh))
    factors = {(r["condition"], r["factor"], r["level"]) for r in summary if r["metric"] == "add_s_or_add_01d"}
    assert {("quality", "render", "quality"), ("fast", "render", "fast"),
            ("depth-d435-stereo", "sensor", "d435-stereo")} <= factors
    with open(out / "results.csv", newline="") as fh:
        results = list(csv.DictReader(fh))
    for cond in ("quality", "fast", "depth-d435-stereo"):
        assert any(r["condition"] == cond and r["te_m"] not in ("", None) for r in results), cond


class _Examples(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.found: dict[tuple[str, str], str] = {}
        self._current: tuple[str, str] | None = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "figure" and "data-condition" in a:
            self._current = (a["data-condition"], a["data-channel"])
        if tag == "img" and self._current is not None:
            self.found[self._current] = a["src"].split(",", 1)[1]
            self._current = None


def _decode(b64: str) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(base64.b64decode(b64), np.uint8), cv2.IMREAD_COLOR)[..., ::-1].astype(float)


def _picture(img: np.ndarray, size: tuple[int, int], nearest: bool) -> np.ndarray:
    return cv2.resize(img, size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA).astype(float)


def test_report_shows_the_depth_map_of_depth_conditions(sweep):
    from simtest.io.bop import read_depth, read_image
    from simtest.sweeps.examples import colourize_depth_range, depth_range

    _, out, _ = sweep
    p = _Examples()
    p.feed((out / "report.html").read_text())
    assert {("clean", "rgb"), ("clean", "depth"), ("depth-realsense-d435", "depth"), ("depth-d435-stereo", "depth"),
            ("quality", "rgb"), ("fast", "rgb")} <= set(p.found)
    def depth_of(data: Path) -> np.ndarray:
        scale = json.loads((_scene(data) / "scene_camera.json").read_text())["0"]["depth_scale"]
        return read_depth(_scene(data), 0, scale)

    span = depth_range(depth_of(out / "data" / "clean"))
    for cond, data in (("depth-d435-stereo", out / "data" / "depth-d435-stereo"),
                       ("depth-realsense-d435", out / "data" / "depth-realsense-d435")):
        shown = _decode(p.found[(cond, "depth")])
        size = (shown.shape[1], shown.shape[0])
        depth, _ = colourize_depth_range(depth_of(data), *span)
        assert (depth_of(data) == 0).any()  # the sensed / noisy depth has invalid pixels, drawn black
        rgb = read_image(_scene(data), 0)
        err_depth = np.abs(shown - _picture(depth, size, True)).mean()
        err_rgb = np.abs(shown - _picture(rgb, size, False)).mean()
        assert err_depth < 8 and err_rgb > 3 * err_depth, (cond, err_depth, err_rgb)
    # the render condition shows its own RGB
    shown = _decode(p.found[("quality", "rgb")])
    rgb = read_image(_scene(out / "data" / "quality"), 0)
    assert np.abs(shown - _picture(rgb, (shown.shape[1], shown.shape[0]), False)).mean() < 8


def test_resume_skips_finished_cells_and_keeps_the_generated_dataset(sweep):
    cfg, out, _ = sweep
    rgb = _scene(out / "data" / "quality") / "rgb" / "000000.jpg"
    before = rgb.stat().st_mtime_ns
    (out / "cells" / "icp" / "quality" / "pose" / "cell.json").unlink()
    rep = run_sweep(cfg, out, resume=True, progress=False)
    assert rep.cells_run == ["icp/quality/pose"]
    assert len(rep.cells_skipped) == len(conditions_of(cfg)) - 1
    assert rgb.stat().st_mtime_ns == before


def test_ground_truth_check_names_the_first_changed_file(sweep, tmp_path):
    _, out, _ = sweep
    copy = tmp_path / "copy"
    shutil.copytree(out / "data" / "quality", copy)
    check_same_ground_truth(out / "data" / "clean", copy, "train_pbr", "quality")  # unchanged: accepted
    mask = sorted((_scene(copy) / "mask_visib").iterdir())[0]
    mask.write_bytes(mask.read_bytes() + b"\0")
    with pytest.raises(ConfigError, match=r"'quality' changed the ground truth: .*mask_visib/000000_000000\.png "
                                          r"differs.*not a render condition"):
        check_same_ground_truth(out / "data" / "clean", copy, "train_pbr", "quality")


def test_override_that_moves_the_room_is_refused(tmp_path):
    gen = {**GEN, "frames_per_scene": 1}
    cfg = SweepConfig.from_dict({**SWEEP, "dataset": {"generate": gen},
                                 "factors": {**SWEEP["factors"], "renderers": [], "depth_sensors": [],
                                             "depth_noise": []},
                                 "renders": [{"name": "high-table", "overrides": {"scene.table_height": 0.6}}]})
    with pytest.raises(ConfigError, match=r"sweep condition 'high-table' changed the ground truth: \S+/train_pbr/"
                                          r"000000/\S+ (differs|has no counterpart).*different dataset, not a "
                                          r"render condition"):
        run_sweep(cfg, tmp_path / "s", progress=False)


@pytest.mark.parametrize("renders, message", [
    ([{"name": "x", "overrides": {"render.profil": "pbr"}}],
     r"renders\[0\]\.overrides: 'render\.profil' is not a generation config field.*allowed in render: profile"),
    ([{"name": "x", "overrides": {"lighting.count": 2}}], r"'lighting\.count' is not a generation config field"),
    ([{"name": "x", "overrides": {"render.profile": "raytrace"}}],
     r"renders\[0\]\.overrides: render\.profile = 'raytrace' is invalid; allowed: 'fast' \| 'quality' \| 'pbr'"),
    ([{"name": "x", "overrides": {"seed": 3}}], r"'seed' cannot be overridden"),
    ([{"name": "x", "overrides": {}}], r"renders\[0\]\.overrides = \{\} is invalid"),
    ([{"name": "clean", "overrides": {"render.profile": "pbr"}}], r"renders\[\]\.name = 'clean' is invalid"),
    ([{"name": "quality", "overrides": {"render.profile": "pbr"}}], r"renders\[\]\.name = 'quality' is invalid"),
])
def test_bad_render_condition_is_a_config_error_naming_it(renders, message):
    with pytest.raises(ConfigError, match=message):
        SweepConfig.from_dict({**SWEEP, "renders": renders})


@pytest.mark.parametrize("factors, message", [
    ({"renderers": ["raytrace"]}, r"factors\.renderers = 'raytrace' is invalid; allowed: fast \| quality \| pbr"),
    ({"depth_sensors": ["kinect"]}, r"factors\.depth_sensors = 'kinect' is invalid; allowed: d435-stereo"),
    ({"occlusion_kind": "boxes"}, r"factors\.occlusion_kind"),
])
def test_bad_generation_factor_is_a_config_error(factors, message):
    with pytest.raises(ConfigError, match=message):
        SweepConfig.from_dict({**SWEEP, "factors": {**SWEEP["factors"], **factors}})


def test_nested_override_tables_read_as_dotted_keys():
    cfg = SweepConfig.from_dict({**SWEEP, "renders": [{"name": "spp4", "overrides": {"render": {"pbr_spp": 4,
                                                                                               "profile": "pbr"}}}]})
    cond = conditions_of(cfg)[-1]
    assert cond.name == "spp4" and cond.overrides == {"render.pbr_spp": 4, "render.profile": "pbr"}
    assert cond.level == "render.pbr_spp=4;render.profile=pbr"


@pytest.mark.skipif(any(importlib.util.find_spec(m) is None for m in ("mitsuba", "pyoidn")),
                    reason="mitsuba / pyoidn not installed (pip install 'simtest[pbr]')")
def test_pbr_render_condition_at_one_sample_per_pixel(tmp_path):
    gen = {**GEN, "frames_per_scene": 1, "camera": {"width": 64, "height": 48}}
    cfg = SweepConfig.from_dict({**SWEEP, "estimators": [{"name": "oracle", "estimator": "oracle"}],
                                 "dataset": {"generate": gen}, "factors": {"occlusion": [], "corruptions": [],
                                                                           "depth_noise": []},
                                 "renders": [{"name": "pbr", "overrides": {"render.profile": "pbr",
                                                                           "render.pbr_spp": 1}}]})
    out = tmp_path / "s"
    run_sweep(cfg, out, progress=False)
    clean, pbr = _scene(out / "data" / "clean"), _scene(out / "data" / "pbr")
    for name in GT_FILES:
        assert _same_bytes(clean / name, pbr / name), name
    for folder in ("mask", "mask_visib", "depth"):
        assert all(_same_bytes(clean / folder / f, pbr / folder / f) for f in _files(clean / folder)), folder
    assert not _same_bytes(clean / "rgb" / "000000.jpg", pbr / "rgb" / "000000.jpg")
    assert "| estimator | L0 (n=3) | pbr (n=3) |" in (out / "tables.md").read_text()
    assert "| oracle | 100.0 [43.9, 100.0] | 100.0 [43.9, 100.0] |" in (out / "tables.md").read_text()


def test_paste_occlusion_uses_object_cutouts_unless_told(tmp_path):
    cfg = SweepConfig.from_dict({**SWEEP, "estimators": [{"name": "oracle", "estimator": "oracle"}],
                                 "dataset": {"generate": {**GEN, "camera": {"width": 160, "height": 120}}},
                                 "factors": {"occlusion": ["L1"], "corruptions": [], "depth_noise": []}})
    assert cfg.factors.occlusion_kind == "objects"
    out = tmp_path / "s"
    run_sweep(cfg, out, progress=False)
    record = json.loads((out / "data" / "L1" / "corruption.json").read_text())
    assert record["spec"]["occlusion_kind"] == "objects"
    paste = SweepConfig.from_dict({**SWEEP, "factors": {"occlusion": ["L1"], "occlusion_kind": "paste"}})
    l1 = [c for c in conditions_of(paste) if c.name == "L1"][0]
    assert l1.corruption_spec(paste.factors.occlusion_definition, paste.factors.occlusion_kind).occlusion_kind == "paste"


def test_shipped_renderer_sweep_config_reads():
    from simtest.sweeps.grid import load_sweep_config

    cfg = load_sweep_config(Path(__file__).parents[3] / "configs" / "sweep-renderers.toml")
    conds = {c.name: c for c in conditions_of(cfg)}
    assert conds["depth-d435-stereo"].factor == "sensor" and conds["quality"].factor == "render"
    assert conds["pbr"].overrides == {"render.profile": "pbr", "render.pbr_spp": 8}


def test_generation_conditions_over_a_given_dataset_use_its_manifest(sweep, tmp_path):
    _, out, _ = sweep
    clean = out / "data" / "clean"
    cfg = SweepConfig.from_dict({**SWEEP, "estimators": [{"name": "oracle", "estimator": "oracle"}],
                                 "dataset": {"path": str(clean)},
                                 "factors": {"occlusion": [], "corruptions": [], "depth_noise": [],
                                             "renderers": ["quality"]}})
    run_sweep(cfg, tmp_path / "s", progress=False)
    for name in GT_FILES:
        assert _same_bytes(_scene(clean) / name, _scene(tmp_path / "s" / "data" / "quality") / name), name
    # the same scenes and settings as the first sweep's quality condition: the same RGB bytes
    assert _same_bytes(_scene(out / "data" / "quality") / "rgb" / "000000.jpg",
                       _scene(tmp_path / "s" / "data" / "quality") / "rgb" / "000000.jpg")
    bare = tmp_path / "bare"
    shutil.copytree(clean, bare, ignore=shutil.ignore_patterns("manifest.json"))
    cfg = SweepConfig.from_dict({**cfg.to_dict(), "dataset": {"path": str(bare)}})
    with pytest.raises(ConfigError, match=r"manifest\.json' is missing or records no generation config"):
        run_sweep(cfg, tmp_path / "s2", progress=False)
