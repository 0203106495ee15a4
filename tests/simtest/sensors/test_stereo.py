"""The simulated active-stereo sensor on real MuJoCo renders: projector shadows beside edges, error growing as
z^2, dark, mirror-like and textureless surfaces losing depth, exact ground truth untouched, seeded bytes, and the
depth-to-colour registration."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.camera import CameraModel, intrinsics_matrix, look_at_pose, mujoco_model_intrinsics
from simtest.errors import ConfigError
from simtest.generators.builder import SceneBuilder
from simtest.generators.config import GenerateConfig
from simtest.generators.scene_spec import DistractorSpec, LightSpec, ObjectPlacement, SceneSpec, SurfaceSpec
from simtest.geometry import Pose
from simtest.objects import load_object_set
from simtest.render.rasterizer import Renderer
from simtest.sensors.stereo import STEREO_PRESETS, StereoSensor, register_depth, stereo_preset

W, H = 212, 120
FLAT = SurfaceSpec("flat", (0.7, 0.7, 0.7), (0.7, 0.7, 0.7), 1.0, 0.0)
CHECKER = SurfaceSpec("checker", (0.9, 0.9, 0.9), (0.2, 0.2, 0.2), 40.0, 0.3)
BRIGHT, DARK = (0.9, 0.9, 0.9, 1.0), (0.02, 0.02, 0.02, 1.0)


@pytest.fixture(scope="module")
def make_scene():
    cfg = GenerateConfig().replace(**{"camera.width": W, "camera.height": H})
    builder = SceneBuilder(load_object_set("builtin"), cfg.build_options())
    tz = cfg.scene.table_height

    def make(table, boxes, objects=()):
        """A table (``table`` surface) with boxes ``(half sizes, centre, rgba)`` and ``objects``
        (``ObjectPlacement``) on it, one overhead light."""
        ds = tuple(DistractorSpec("box", s, p, (1.0, 0.0, 0.0, 0.0), c) for s, p, c in boxes)
        light = LightSpec((0.0, 0.0, tz + 2.0), (0.0, 0.0, -1.0), (0.5, 0.5, 0.5), 0.0)
        return builder.build(SceneSpec(0, 0, tuple(objects), ds, (light,), 0.6, table, FLAT, FLAT, ()))

    return make, cfg.camera.K(), tz


def _camera(K, eye, target) -> CameraModel:
    return CameraModel(K, W, H, look_at_pose(np.asarray(eye, float), np.asarray(target, float)))


def _sense(sim, cam, preset="d435-stereo", seed=0):
    sim.set_camera(cam)
    with Renderer(sim.model, W, H) as r:
        exact = r.render(sim.data, sim.camera_id)
        view = stereo_preset(preset).sense_view(r, sim.data, sim.camera_id, cam, np.random.default_rng(seed))
        after = r.render(sim.data, sim.camera_id)
    return exact, view, after


def _side_holes(exact, view, band: int = 10) -> tuple[int, int, int]:
    """Invalid pixels in ``band`` columns left and right of the centre object's silhouette, and its rows."""
    box = exact.seg == exact.seg[H // 2, W // 2]
    invalid = view.depth == 0
    left = right = rows = 0
    for row in range(H):
        cols = np.nonzero(box[row])[0]
        if cols.size < 3:
            continue
        a, b = cols.min(), cols.max()
        left += int(invalid[row, max(0, a - band):a].sum())
        right += int(invalid[row, b + 1:b + 1 + band].sum())
        rows += 1
    return left, right, rows


def test_projector_shadow_holes_lie_on_the_side_away_from_the_projector(make_scene):
    make, K, tz = make_scene
    sim = make(FLAT, [((0.03, 0.03, 0.1), (0.0, 0.0, tz + 0.1), BRIGHT)])
    cam = _camera(K, (0.0, -0.2, tz + 0.55), (0.0, 0.0, tz))
    exact, view, _ = _sense(sim, cam)
    left, right, rows = _side_holes(exact, view)
    assert rows > 30
    # The projector sits at +x of the left camera: its shadow (and the right camera's occlusion) is on the left.
    assert left > 2 * rows and left > 5 * max(right, 1), (left, right, rows)
    # A projector moved to the other side of the left camera casts its shadow on the right.
    sensor = STEREO_PRESETS["d435-stereo"].replace(projector_offset=(-0.04, 0.0, 0.0))
    with Renderer(sim.model, W, H) as r:
        moved = sensor.sense_view(r, sim.data, sim.camera_id, cam, np.random.default_rng(0))
    _, right_moved, _ = _side_holes(exact, moved)
    assert right_moved > right + rows // 3, (right, right_moved, rows)


def _robust_error(exact, view) -> float:
    ok = (view.depth > 0) & (exact.depth > 0)
    ok[:, : W // 4] = ok[:, -W // 8:] = False  # SGBM's unmatched left band, the image border
    ok[: H // 6] = ok[-H // 6:] = False
    assert ok.sum() > 0.1 * ok.size
    return float(1.4826 * np.median(np.abs(view.depth - exact.depth)[ok]))


def test_error_grows_with_the_square_of_the_distance(make_scene):
    make, K, tz = make_scene
    sim = make(CHECKER, [])
    direction = np.array([0.0, -0.5, np.sqrt(0.75)])
    z1, z2 = 0.5, 0.8
    e1, e2 = (_robust_error(*_sense(sim, _camera(K, np.array([0.0, 0.0, tz]) + z * direction, (0.0, 0.0, tz)))[:2])
              for z in (z1, z2))
    expected = (z2 / z1) ** 2
    assert expected / 2 < e2 / e1 < expected * 2, (e1, e2)
    # and the size: z^2 / (f b) x a sub-pixel accuracy between 0.05 and 0.5 px
    f_ir = STEREO_PRESETS["d435-stereo"].ir_focal_ratio * W
    assert 0.05 * z1 ** 2 / (f_ir * 0.05) < e1 < 0.5 * z1 ** 2 / (f_ir * 0.05)


def _geom_mask(exact, cam, point) -> np.ndarray:
    """The pixels of the geom seen at world ``point``."""
    uv, _ = cam.project_world(np.asarray([point], float))
    u, v = np.rint(uv[0]).astype(int)
    return exact.seg == exact.seg[v, u]


def _valid_fraction(exact, view, cam, point) -> float:
    return float((view.depth[_geom_mask(exact, cam, point)] > 0).mean())


def test_dark_and_textureless_patches_lose_depth(make_scene):
    make, K, tz = make_scene
    cam = _camera(K, (0.0, -0.3, tz + 0.55), (0.0, 0.0, tz))
    patch = (0.04, 0.04, 0.01)
    sim = make(FLAT, [(patch, (-0.06, 0.0, tz + 0.01), BRIGHT), (patch, (0.06, 0.0, tz + 0.01), DARK)])
    exact, view, _ = _sense(sim, cam)
    bright = _valid_fraction(exact, view, cam, (-0.06, 0.0, tz + 0.02))
    dark = _valid_fraction(exact, view, cam, (0.06, 0.0, tz + 0.02))
    assert bright > 0.9 and dark < bright - 0.3, (bright, dark)
    # Passive stereo: the same bright matte patch, now textureless, loses depth; the checker table keeps it.
    sim = make(CHECKER, [(patch, (-0.06, 0.0, tz + 0.01), BRIGHT)])
    exact, view, _ = _sense(sim, cam, "passive-stereo")
    flat = _valid_fraction(exact, view, cam, (-0.06, 0.0, tz + 0.02))
    table = _geom_mask(exact, cam, (0.06, 0.0, tz))
    table[:, : W // 3] = False
    textured = float((view.depth[table] > 0).mean())
    assert flat < bright - 0.3 and textured > flat + 0.2, (flat, textured, bright)


def test_exact_render_unchanged_and_seeded_bytes(make_scene):
    make, K, tz = make_scene
    sim = make(FLAT, [((0.03, 0.03, 0.05), (0.0, 0.0, tz + 0.05), BRIGHT)])
    cam = _camera(K, (0.0, -0.4, tz + 0.5), (0.0, 0.0, tz))
    intr = sim.model.cam_intrinsic.copy()
    exact, a, after = _sense(sim, cam, seed=3)
    for x, y in ((exact.rgb, after.rgb), (exact.depth, after.depth), (exact.seg, after.seg)):
        assert np.array_equal(x, y)
    assert np.array_equal(sim.model.cam_intrinsic, intr)
    _, b, _ = _sense(sim, cam, seed=3)
    _, c, _ = _sense(sim, cam, seed=4)
    assert a.depth.dtype == np.float32 and a.depth.shape == (H, W)
    assert a.depth.tobytes() == b.depth.tobytes() and a.ir_left.tobytes() == b.ir_left.tobytes()
    assert a.depth.tobytes() != c.depth.tobytes()
    assert 0.5 < (a.depth > 0).mean() < 1.0


def test_register_depth_with_an_offset_and_other_intrinsics():
    K_src, K_dst = intrinsics_matrix(80.0, 80.0, 49.5, 39.5), intrinsics_matrix(120.0, 120.0, 49.5, 39.5)
    depth = np.full((80, 100), 1.0, dtype=np.float32)
    depth[30:50, 40:60] = 0.6  # a nearer square in front of the wall
    T = Pose(np.eye(3), np.array([-0.02, 0.0, 0.0]))  # destination 2 cm to the +x of the source
    out = register_depth(depth, K_src, T, K_dst, 100, 80)
    assert set(np.unique(out)) <= {0.0, np.float32(0.6), np.float32(1.0)}
    assert (out > 0).mean() > 0.97  # the wider source covers the destination: no holes from the splat
    # The square lands where the pinhole model puts it: its centre shifted by f * dx / z.
    rows, cols = np.nonzero(out == np.float32(0.6))
    centre_src = (49.5 - K_src[0, 2]) * 0.6 / 80.0  # x of the square's centre, source frame
    u_expected = 120.0 * (centre_src - 0.02) / 0.6 + K_dst[0, 2]
    assert abs(cols.mean() - u_expected) < 1.0 and abs(rows.mean() - 39.5) < 1.0
    # identity pose and intrinsics: the same image
    same = register_depth(depth, K_src, Pose.identity(), K_src, 100, 80)
    assert np.array_equal(same, depth)
    # one centre, other intrinsics (the preset's IR -> colour): the shortcut agrees with the splat
    shortcut = register_depth(depth, K_src, Pose.identity(), K_dst, 100, 80)
    tiny = Pose(np.eye(3), np.array([1e-6, 0.0, 0.0]))
    splat = register_depth(depth, K_src, tiny, K_dst, 100, 80)
    assert (shortcut != splat).mean() < 0.02


def test_presets_and_config_errors():
    assert set(STEREO_PRESETS) == {"d435-stereo", "passive-stereo"}
    d435 = STEREO_PRESETS["d435-stereo"]
    assert d435.baseline == 0.05 and 380 <= d435.ir_focal_ratio * 640 <= 430 and d435.projector
    assert not STEREO_PRESETS["passive-stereo"].projector
    assert d435.num_disparities(d435.ir_focal_ratio * 640) % 16 == 0
    with pytest.raises(ConfigError, match="known"):
        stereo_preset("kinect")
    with pytest.raises(ConfigError, match="block_size"):
        StereoSensor(block_size=4)


def test_mirror_like_object_loses_depth(make_scene):
    make, K, tz = make_scene
    # box_0 (0.2 m tall) twice: a matte one and a MuJoCo mirror (reflectance 1)
    matte = ObjectPlacement(13, (-0.08, 0.0, tz + 0.1), (1.0, 0.0, 0.0, 0.0), BRIGHT, 0.0, 0.0, 0.0)
    mirror = ObjectPlacement(13, (0.08, 0.0, tz + 0.1), (1.0, 0.0, 0.0, 0.0), BRIGHT, 0.5, 0.5, 1.0)
    sim = make(FLAT, [], (matte, mirror))
    cam = _camera(K, (0.0, -0.2, tz + 0.75), (0.0, 0.0, tz))
    m = sim.model
    materials = [a.copy() for a in (m.mat_rgba, m.mat_specular, m.mat_reflectance, m.geom_rgba)]
    exact, view, after = _sense(sim, cam)
    # the IR renders darken the materials by their reflectance; the model and the colour camera's render are
    # restored byte for byte
    for a, b in zip(materials, (m.mat_rgba, m.mat_specular, m.mat_reflectance, m.geom_rgba)):
        assert a.tobytes() == b.tobytes()
    for x, y in ((exact.rgb, after.rgb), (exact.depth, after.depth), (exact.seg, after.seg)):
        assert np.array_equal(x, y)
    on_matte = _valid_fraction(exact, view, cam, (-0.08, 0.0, tz + 0.2))
    on_mirror = _valid_fraction(exact, view, cam, (0.08, 0.0, tz + 0.2))
    assert on_matte > 0.9 and on_mirror < on_matte - 0.3, (on_matte, on_mirror)
    # without the reflectance term the mirror is as good as the matte box
    plain = STEREO_PRESETS["d435-stereo"].replace(mirror=False)
    with Renderer(sim.model, W, H) as r:
        v2 = plain.sense_view(r, sim.data, sim.camera_id, cam, np.random.default_rng(0))
    assert _valid_fraction(exact, v2, cam, (0.08, 0.0, tz + 0.2)) > 0.9


def test_materials_restored_when_an_ir_render_fails(make_scene):
    make, K, tz = make_scene
    mirror = ObjectPlacement(13, (0.0, 0.0, tz + 0.1), (1.0, 0.0, 0.0, 0.0), BRIGHT, 0.5, 0.5, 1.0)
    sim = make(FLAT, [], (mirror,))
    cam = _camera(K, (0.0, -0.2, tz + 0.75), (0.0, 0.0, tz))
    sim.set_camera(cam)
    m = sim.model
    saved = [a.copy() for a in (m.mat_rgba, m.mat_specular, m.mat_reflectance, m.geom_rgba, m.cam_intrinsic)]

    class Failing:
        """A renderer whose second pass (the left IR camera's) fails."""

        def __init__(self, renderer):
            self.model, self.renderer, self.calls = renderer.model, renderer, 0

        def render(self, *args, **kwargs):
            self.calls += 1
            if self.calls == 2:
                assert not np.any(m.mat_reflectance)  # inside the IR renders
                raise RuntimeError("render failed")
            return self.renderer.render(*args, **kwargs)

    with Renderer(m, W, H) as r, pytest.raises(RuntimeError, match="render failed"):
        stereo_preset("d435-stereo").sense_view(Failing(r), sim.data, sim.camera_id, cam, np.random.default_rng(0))
    for a, b in zip(saved, (m.mat_rgba, m.mat_specular, m.mat_reflectance, m.geom_rgba, m.cam_intrinsic)):
        assert a.tobytes() == b.tobytes()


def test_matching_window_agrees_with_the_whole_image(make_scene):
    make, K, tz = make_scene
    sim = make(CHECKER, [((0.03, 0.03, 0.1), (0.0, 0.0, tz + 0.1), BRIGHT)])
    cam = _camera(K, (0.0, -0.3, tz + 0.6), (0.0, 0.0, tz))
    sensor = stereo_preset("d435-stereo")
    r0, r1, c0, c1 = sensor.match_window(cam)
    assert (r1 - r0) * (c1 - c0) < 0.8 * W * H  # the colour camera sees a part of the wider IR view
    whole = sensor.replace(match_margin=None)
    assert whole.match_window(cam) == (0, H, 0, W)
    sim.set_camera(cam)
    with Renderer(sim.model, W, H) as r:
        a = sensor.sense_view(r, sim.data, sim.camera_id, cam, np.random.default_rng(5))
        b = whole.sense_view(r, sim.data, sim.camera_id, cam, np.random.default_rng(5))
    assert a.window == (r0, r1, c0, c1) and b.window == (0, H, 0, W)
    # the IR pair is the same inside the window (the window's render is the crop of the whole one, its depth to
    # float32 rounding, which moves some intensities across a quantisation step) and 0 outside
    inside = np.zeros((H, W), dtype=bool)
    inside[r0 + 1:r1 - 1, c0 + 1:c1 - 1] = True  # the depth gradients at the window's border are one-sided
    for x, y in ((a.ir_left, b.ir_left), (a.ir_right, b.ir_right)):
        diff = np.abs(x.astype(int) - y.astype(int))[inside]
        assert diff.max() <= 2 and (diff == 0).mean() > 0.85, np.bincount(diff)
        assert not x[:r0].any() and not x[r1:].any() and not x[:, :c0].any() and not x[:, c1:].any()
    # the sensed depth agrees to a sub-pixel step of the matcher (1/16 px of disparity: z^2 / (16 f b)), but
    # for SGBM's aggregation paths cut at the window's edge
    assert (a.depth > 0).mean() > 0.5
    step = b.depth.astype(np.float64) ** 2 / (16.0 * a.K_ir[0, 0] * sensor.baseline)
    assert (np.abs(a.depth - b.depth) <= 1.01 * step + 1e-6).mean() > 0.99
    assert ((a.depth > 0) == (b.depth > 0)).mean() > 0.995


def test_window_render_is_the_crop_of_the_whole_render(make_scene):
    from simtest.render.rasterizer import RenderError
    from simtest.sensors.ir_render import RenderAt

    make, K, tz = make_scene
    sim = make(CHECKER, [((0.03, 0.03, 0.1), (0.0, 0.0, tz + 0.1), BRIGHT)])
    cam = _camera(K, (0.05, -0.3, tz + 0.6), (0.0, 0.0, tz))
    sim.set_camera(cam)
    sensor = stereo_preset("d435-stereo")
    left = sensor.poses(cam)[0]
    window = (13, 101, 7, 190)
    saved = [a.copy() for a in (sim.model.cam_intrinsic, sim.model.cam_sensorsize, sim.model.cam_resolution)]
    # what MuJoCo compiled the scene's camera into is what RenderAt writes for the colour intrinsics
    intr, size, res = mujoco_model_intrinsics(cam.K, W, H)
    c = sim.camera_id
    assert np.allclose(sim.model.cam_intrinsic[c], intr, rtol=1e-6, atol=1e-12)
    assert np.allclose(sim.model.cam_sensorsize[c], size) and list(sim.model.cam_resolution[c]) == res
    with Renderer(sim.model, W, H) as r:
        with RenderAt(r, sim.data, sim.camera_id, cam, sensor.ir_K(cam)) as at:
            whole = at.render(left, rgb=True, seg=True)
            part = at.render(left, rgb=True, seg=True, window=window)
            again = at.render(left, rgb=True, seg=True)
        with pytest.raises(RenderError, match="render size"):
            r.render(sim.data, sim.camera_id, size=(W + 1, H))
    for a, b in zip(saved, (sim.model.cam_intrinsic, sim.model.cam_sensorsize, sim.model.cam_resolution)):
        assert a.tobytes() == b.tobytes()
    assert np.array_equal(whole.rgb, again.rgb)
    r0, r1, c0, c1 = window
    assert part.rgb.shape == (r1 - r0, c1 - c0, 3) and part.depth.shape == part.seg.shape == (r1 - r0, c1 - c0)
    crop = whole.rgb[r0:r1, c0:c1].astype(int)
    # another projection matrix: the interpolated shading moves some pixels by one 8-bit level, no more
    assert np.abs(part.rgb - crop).max() <= 1 and np.abs(part.rgb - crop).mean() < 0.25
    assert (part.seg == whole.seg[r0:r1, c0:c1]).mean() > 0.999
    zc = whole.depth[r0:r1, c0:c1]
    same = (part.seg == whole.seg[r0:r1, c0:c1]) & (zc > 0)
    assert np.allclose(part.depth[same], zc[same], rtol=1e-4, atol=0.0)


def test_figure_script_draws_the_sensors(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    import cv2

    script = Path(__file__).resolve().parents[3] / "examples" / "stereo_depth.py"
    out = tmp_path / "stereo.png"
    subprocess.run([sys.executable, str(script), str(out), "--width", "160", "--height", "120"], check=True,
                   capture_output=True, timeout=300)
    img = cv2.imread(str(out))
    assert img is not None and img.shape[1] >= 5 * 160 and img.shape[0] > 120
