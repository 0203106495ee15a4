"""Cost of the simulated active-stereo sensor (:mod:`simtest.sensors.stereo`) against the frame it senses.

One generated scene (the default config at ``width`` x ``height``, scene 0, settled), each of its views rendered
with the ``fast`` profile (RGB, depth, segmentation: what ``generate`` renders per view) and sensed by a stereo
preset; best of ``repeat`` runs per view, milliseconds, averaged over the views.

Where the sensor's time goes: ``passes_ms`` is what its GL passes cost (:meth:`StereoSensor.render_ir`: the
projector's depth-only pass over its window and the left and right IR RGB + depth passes over the matching
window), ``sgbm_ms`` the matcher on the view's IR pair
(the window), and ``other_ms`` the rest (the sensor noise, the two IR images, the texture threshold and the
registration).
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["run", "table"]


def _best_ms(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return 1000.0 * best


def run(width: int = 640, height: int = 480, preset: str = "d435-stereo", repeat: int = 3,
        views: int = 3) -> dict[str, float]:
    """``{"frame_ms", "stereo_ms", "ratio", "valid", "passes_ms", "sgbm_ms", "other_ms"}``: the fast profile's
    frame, the sensor's view, their ratio, the sensed depth's valid fraction (of the pixels with exact depth) and
    the sensor's time split (see the module)."""
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import load_objects, prepare_scene
    from simtest.generators.recorder import scene_cameras
    from simtest.render.rasterizer import Renderer
    from simtest.sensors.stereo import stereo_preset

    cfg = GenerateConfig().replace(**{"camera.width": width, "camera.height": height, "scenes": 1})
    scene, *_ = prepare_scene(cfg, load_objects(cfg), 0)
    sensor = stereo_preset(preset)
    frame_ms, stereo_ms, valid, passes_ms, sgbm_ms = [], [], [], [], []
    with Renderer(scene.model, width, height, profile="fast") as renderer:
        for cam, _ in scene_cameras(cfg, scene)[:views]:
            scene.set_camera(cam)
            frame_ms.append(_best_ms(lambda: renderer.render(scene.data, scene.camera_id), repeat))
            stereo_ms.append(_best_ms(lambda: sensor.sense(renderer, scene.data, scene.camera_id, cam,
                                                           np.random.default_rng(0)), repeat))
            exact = renderer.render(scene.data, scene.camera_id, rgb=False, seg=False).depth
            view = sensor.sense_view(renderer, scene.data, scene.camera_id, cam, np.random.default_rng(0))
            valid.append(float((view.depth[exact > 0] > 0).mean()))
            passes_ms.append(_best_ms(lambda: sensor.render_ir(renderer, scene.data, scene.camera_id, cam), repeat))
            matcher = sensor.matcher(cam)
            r0, r1, c0, c1 = view.window
            pair = [np.ascontiguousarray(a[r0:r1, c0:c1]) for a in (view.ir_left, view.ir_right)]
            sgbm_ms.append(_best_ms(lambda: matcher.compute(*pair), repeat))
    f, s = float(np.mean(frame_ms)), float(np.mean(stereo_ms))
    p, m = float(np.mean(passes_ms)), float(np.mean(sgbm_ms))
    return {"frame_ms": f, "stereo_ms": s, "ratio": s / f, "valid": float(np.mean(valid)), "passes_ms": p,
            "sgbm_ms": m, "other_ms": max(0.0, s - p - m)}


def table(result: dict[str, float]) -> str:
    line = (f"fast frame {result['frame_ms']:.1f} ms, stereo {result['stereo_ms']:.1f} ms "
            f"({result['ratio']:.1f}x), valid {100 * result['valid']:.0f}%")
    if "passes_ms" in result:
        line += (f"; stereo = GL passes {result['passes_ms']:.1f} + SGBM {result['sgbm_ms']:.1f} "
                 f"+ IR images and the rest {result['other_ms']:.1f} ms")
    return line
