"""docs/sim2real_refit.py on a generated dataset: the stage's fit applied afterwards to a run's poses, with the
shipped outline network, gives what the outline stage gives; nearer poses' pixels are found by rendered depth."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from simtest.estimators.keypoints.template_stage import TEMPLATE_OUTLINE_MASK, TEMPLATE_OUTLINE_TEMPERATURE
from simtest.estimators.templates.outline import fit_to_mask, load_outline, outline_fit
from simtest.evaluation.run import evaluate
from simtest.io import bop
from simtest.io.bop_results import read_bop_results, write_bop_results
from simtest.io.bop_splits import dataset_split_dir, scene_dirs
from simtest.objects.loaders import load_dataset_objects

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "docs" / "sim2real_refit.py"


def _module():
    spec = importlib.util.spec_from_file_location("sim2real_refit", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_nearer_pixels_follow_the_rendered_depths():
    far, near = np.zeros((4, 6), np.float32), np.zeros((4, 6), np.float32)
    far[:, :4], near[:, 2:] = 1.0, 0.8  # near overlaps far on columns 2-3 and lies beside it on 4-5
    hidden = _module().nearer_pixels([far, near], 0, 1.0)
    assert hidden[:, 2:].all() and not hidden[:, :2].any()  # in front where both are, and nearer than far's origin
    assert not _module().nearer_pixels([far, near], 1, 0.8).any()  # nothing lies in front of the near one


def test_refit_is_the_stages_fit_of_each_pose(small_dataset, tmp_path):
    evaluate(small_dataset, "oracle", out_dir=tmp_path / "run", max_images=1, vsd=False, progress=False)
    rows = read_bop_results(tmp_path / "run" / "results.csv")
    rows = [replace(r, t=r.t * 1.04) for r in rows]  # 4 % too far along each ray
    write_bop_results(tmp_path / "run" / "results.csv", rows)
    from simtest.estimators.shipped import weights_dir

    net_path = str(weights_dir() / "templates_outline_lmo_640x480.onnx")
    out = tmp_path / "refit.csv"
    cmd = [sys.executable, str(SCRIPT), str(tmp_path / "run"), str(small_dataset), "--net", net_path, "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    fitted = read_bop_results(out)
    assert [(r.scene_id, r.im_id, r.obj_id) for r in fitted] == [(r.scene_id, r.im_id, r.obj_id) for r in rows]
    objects = load_dataset_objects(small_dataset)
    scene = scene_dirs(dataset_split_dir(small_dataset))[0]
    rgb, K = bop.read_image(scene, rows[0].im_id), bop.read_scene(scene)[rows[0].im_id]["K"]
    mod = _module()
    want = outline_fit(load_outline(net_path), objects.get(rows[0].obj_id), rgb, K, rows[0].R, rows[0].t,
                       mod.MAX_SCALE, mod.STEP_DEG, TEMPLATE_OUTLINE_MASK, TEMPLATE_OUTLINE_TEMPERATURE)
    assert np.allclose(fitted[0].t, want.t, atol=1e-9) and np.allclose(fitted[0].R, want.R, atol=1e-9)
    net = load_outline(net_path)

    def read(crop):
        return net.read(crop.rgb, crop.mask, TEMPLATE_OUTLINE_MASK, TEMPLATE_OUTLINE_TEMPERATURE)

    nothing_hidden = fit_to_mask(objects.get(rows[0].obj_id), rgb, K, rows[0].R, rows[0].t, read, net.size,
                                 mod.MAX_SCALE, mod.STEP_DEG, np.zeros(rgb.shape[:2], bool))
    assert np.array_equal(nothing_hidden.t, want.t) and np.array_equal(nothing_hidden.R, want.R)
    assert all(abs(f.t[2] / r.t[2] - 1.0) <= 0.1 + 1e-9 for f, r in zip(fitted, rows))  # the depth bound
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert again.returncode != 0 and "--overwrite" in again.stderr  # never overwrites silently
    done = subprocess.run(cmd + ["--overwrite", "--occluders"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert len(read_bop_results(out)) == len(rows)
