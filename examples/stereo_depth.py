"""Draw the simulated depth sensors beside the exact depth of one generated view: RGB, exact depth, the
``d435-stereo`` and ``passive-stereo`` sensors and the image-space ``realsense-d435`` preset, one colour scale
(the exact depth's 1st-99th percentile; black = no depth), each panel captioned with its valid fraction and
median |error| (trains nothing; a few seconds).

    python examples/stereo_depth.py docs/images/stereo_depth.png            # scene 0, first view, 320x240
    python examples/stereo_depth.py OUT.png --width 640 --height 480 --view 2
"""

from __future__ import annotations

import argparse

import numpy as np

from simtest.corrupt.depth_presets import apply_depth_noise
from simtest.generators.config import GenerateConfig
from simtest.generators.pipeline import load_objects, prepare_scene
from simtest.generators.recorder import scene_cameras
from simtest.render.rasterizer import Renderer
from simtest.sensors.stereo import stereo_preset
from simtest.viz.channels import colourize_depth
from simtest.viz.sheet import hstack, save_png, titled


def caption(depth: np.ndarray, exact: np.ndarray) -> str:
    ok = (depth > 0) & (exact > 0)
    err = float(np.median(np.abs(depth[ok] - exact[ok]))) * 1000.0 if ok.any() else float("nan")
    return f"valid {100.0 * ok.sum() / max(1, int((exact > 0).sum())):.0f} %, median |error| {err:.1f} mm"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="PNG to write")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--scene", type=int, default=0)
    ap.add_argument("--view", type=int, default=0)
    args = ap.parse_args()
    cfg = GenerateConfig().replace(**{"camera.width": args.width, "camera.height": args.height})
    scene, *_ = prepare_scene(cfg, load_objects(cfg), args.scene)
    cam, _ = scene_cameras(cfg, scene)[args.view]
    scene.set_camera(cam)
    with Renderer(scene.model, args.width, args.height) as r:
        frame = r.render(scene.data, scene.camera_id, seg=False)
        sensed = {name: stereo_preset(name).sense(r, scene.data, scene.camera_id, cam, np.random.default_rng(0))
                  for name in ("d435-stereo", "passive-stereo")}
    exact = frame.depth
    sensed["realsense-d435 (image space)"] = apply_depth_noise(exact, "realsense-d435", np.random.default_rng(0),
                                                               cam.K, frame.rgb)
    scale = tuple(float(x) for x in np.percentile(exact[exact > 0], [1, 99]))
    panels = [titled(frame.rgb, "RGB"),
              titled(colourize_depth(exact, scale).image, "exact depth", [f"{scale[0]:.2f}-{scale[1]:.2f} m"])]
    panels += [titled(colourize_depth(d, scale).image, name, [caption(d, exact)]) for name, d in sensed.items()]
    print(save_png(args.out, hstack(panels)))


if __name__ == "__main__":
    main()
