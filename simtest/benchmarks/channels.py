"""``simtest bench channels``: the cost of each dense ground-truth channel per frame (computed and encoded from
rendered views of generated scenes, the way ``simtest generate --channels`` makes them)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

__all__ = ["bench_channels"]


def bench_channels(width: int = 640, height: int = 480, scenes: int = 2, views: int = 5, seed: int = 0,
                   objects: str = "builtin") -> dict[str, Any]:
    """Median milliseconds per frame of each channel (and of the annotation every frame pays anyway), over
    ``scenes`` x ``views`` sequence views at ``width`` x ``height``."""
    from simtest.generators.annotate import annotate
    from simtest.generators.config import GenerateConfig
    from simtest.generators.dense import (forward_flow, instance_map, keypoints_2d, object_coords, surface_normals,
                                          view_geometry)
    from simtest.generators.pipeline import load_objects, prepare_scene
    from simtest.generators.recorder import scene_cameras
    from simtest.io import dense as files
    from simtest.render.rasterizer import Renderer

    cfg = GenerateConfig().replace(**{"objects": objects, "scenes": scenes, "frames_per_scene": views,
                                      "camera.width": width, "camera.height": height, "rig": "sequence",
                                      "seed": seed})
    objs = load_objects(cfg)
    times: dict[str, list[float]] = {k: [] for k in ("annotation", "instances", "coords", "normals", "flow",
                                                     "keypoints")}
    for scene_id in range(scenes):
        scene, *_ = prepare_scene(cfg, objs, scene_id)
        prev, meshes = None, {}
        with Renderer(scene.model, width, height) as r:
            for cam, _ in scene_cameras(cfg, scene):
                scene.set_camera(cam)
                frame = r.render(scene.data, scene.camera_id, rgb=False)
                state = scene.state()
                t = time.perf_counter()
                anns = annotate(state, frame, cam, objs)
                times["annotation"].append(time.perf_counter() - t)
                t = time.perf_counter()
                view = view_geometry(cam, frame.depth, frame.seg, state.geom_xpos, state.geom_xmat)
                inst = instance_map([a.mask_visib for a in anns], frame.depth.shape)
                files.write_png16(None, files.encode_instances(inst))
                shared = time.perf_counter() - t  # every channel needs the view and the instance map
                times["instances"].append(shared)
                for name, fn in (("coords", lambda: files.encode_coords(*object_coords(view, anns, objs))),
                                 ("normals", lambda: files.encode_normals(*surface_normals(view, scene.model,
                                                                                           meshes))),
                                 ("keypoints", lambda: keypoints_2d(view, anns, objs, inst))):
                    t = time.perf_counter()
                    out = fn()
                    if isinstance(out, np.ndarray):
                        files.write_png16(None, out)
                    times[name].append(time.perf_counter() - t)
                if prev is not None:
                    t = time.perf_counter()
                    files.write_png16(None, files.encode_flow(*forward_flow(prev, view)))
                    times["flow"].append(time.perf_counter() - t)
                prev = view
    return {"width": width, "height": height, "frames": scenes * views,
            "ms_per_frame": {k: 1000.0 * float(np.median(v)) for k, v in times.items() if v}}
