"""How much of a pbr frame is ray tracing itself: the path tracer's rays cast alone, against the whole frame.

The ``pbr`` profile's path tracer (Mitsuba's ``path`` integrator, ``max_depth = 3``) casts, per sample, five rays:
the camera ray, a shadow ray toward a light sample, the bounce ray, a second shadow ray and the last bounce ray,
whose hit (or escape to the environment) weighs the emission seen along it. This script builds the settled scenes
of ``simtest generate --profile pbr`` (built-in objects, 10 per scene, the default looks, as
``docs/cycles_comparison.py export`` does), renders each view with :class:`simtest.render.pbr.PbrRenderer` (timed
by its own stages), then casts the same number of rays of the same kinds through the same loaded scene with
Mitsuba's BVH (Embree on the LLVM variants) and nothing else: camera rays through the pixels, cosine-distributed
bounce rays from the surfaces they hit, shadow rays as occlusion tests (``ray_test``) toward cosine-distributed
directions, and the second bounce's rays from the first bounce's hits. Each kind is one kernel, its inputs
evaluated before the clock starts; the surface interactions the next kind starts from are not timed either.
The sum is a floor under the path tracer's time at that sample count: no shading, texture look-ups, light
sampling, BSDF evaluation or film accumulation, only finding what each ray hits::

    python docs/pbr_ray_floor.py --scenes 2 --views 4 --spp 8

Units: wall seconds per 640x480 frame (by default), rays per second of the two cores.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np


def _timed(dr, fn, *args, repeat: int = 3) -> tuple[float, Any]:
    """Median wall seconds of ``fn(*args)`` evaluated (``repeat`` runs after one untimed warm-up that compiles the
    kernel), and the last result."""
    out = fn(*args)
    dr.eval(out)
    dr.sync_thread()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn(*args)
        dr.eval(out)
        dr.sync_thread()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def _count(mask) -> int:
    """How many lanes of a Dr.Jit mask are set."""
    return int(np.asarray(mask, dtype=bool).sum())


def cast_rays(mi, dr, scene, sensor, width: int, height: int, spp: int, seed: int, repeat: int) -> dict[str, float]:
    """The five kinds of rays of ``spp`` samples per pixel cast through ``scene`` from ``sensor``; wall seconds of
    each kind (median of ``repeat``) and the counts of rays cast."""
    n = width * height * spp
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    idx = dr.arange(mi.UInt32, n) // spp
    pos = mi.Point2f((mi.Float(idx % width) + sampler.next_1d()) / width,
                     (mi.Float(idx // width) + sampler.next_1d()) / height)
    rays, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    dr.eval(rays)

    def cosine_rays(si):
        # the hemisphere on the side the ray came from
        n_side = dr.select(dr.dot(si.n, si.to_world(si.wi)) < 0, -si.n, si.n)
        d = mi.Frame3f(n_side).to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d()))
        out = si.spawn_ray(d)
        dr.eval(out)
        return out

    seconds: dict[str, float] = {}
    counts: dict[str, int] = {}
    t, pi = _timed(dr, lambda r: scene.ray_intersect_preliminary(r), rays, repeat=repeat)
    seconds["camera"], counts["camera"] = t, n
    ray, active = rays, mi.Bool(True)
    for k in (1, 2):  # from the surfaces the previous rays hit: a shadow ray and a bounce ray each
        si = pi.compute_surface_interaction(ray, active=active)
        active = active & si.is_valid()
        dr.eval(si, active)
        shadow, ray = cosine_rays(si), cosine_rays(si)
        seconds[f"shadow_{k}"], _ = _timed(dr, lambda r, a: scene.ray_test(r, a), shadow, active, repeat=repeat)
        seconds[f"bounce_{k}"], pi = _timed(dr, lambda r, a: scene.ray_intersect_preliminary(r, active=a), ray,
                                            active, repeat=repeat)
        counts[f"shadow_{k}"] = counts[f"bounce_{k}"] = _count(active)
    return {"seconds": seconds, "rays": counts}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=2)
    ap.add_argument("--views", type=int, default=4, help="views per scene; the first is a warm-up")
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--size", default="640x480", help="WIDTHxHEIGHT")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each ray kernel (median)")
    ap.add_argument("--json", type=Path, default=None, help="also write the record here")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))

    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root))
    import simtest

    if (root / "generators").is_dir() and str(root) not in simtest.__path__:
        simtest.__path__.insert(1, str(root))
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import load_objects, prepare_scene
    from simtest.generators.recorder import pbr_renderer, scene_cameras
    from simtest.render.pbr import frame_seed, renderer_versions

    cfg = GenerateConfig().replace(**{
        "objects": "builtin", "scenes": args.scenes, "frames_per_scene": args.views, "camera.width": width,
        "camera.height": height, "scene.objects_per_scene": [10, 10], "render.profile": "pbr",
        "render.pbr_spp": args.spp, "seed": args.seed})
    objects = load_objects(cfg)
    rows = []
    for sid in range(args.scenes):
        scene, *_ = prepare_scene(cfg, objects, sid)
        renderer = pbr_renderer(cfg, scene)
        mi = renderer._mi
        import drjit as dr

        for k, (cam, _) in enumerate(scene_cameras(cfg, scene)[:args.views]):
            scene.set_camera(cam)
            before = renderer.stages.copy()
            t = time.perf_counter()
            renderer.render(scene.data, scene.camera_id, seed=frame_seed(cfg.seed, sid, k))
            frame_s = time.perf_counter() - t
            stages = renderer.stages.since(before).seconds
            if k == 0:
                continue  # warm-up: scene load and kernel recording
            cast = cast_rays(mi, dr, renderer._loaded[1], renderer._sensor, width, height, args.spp,
                             frame_seed(cfg.seed, sid, k), args.repeat)
            rows.append({"scene": sid, "view": k, "frame_s": frame_s, "trace_s": stages.get("trace", 0.0), **cast})
            total = sum(cast["seconds"].values())
            print(f"scene {sid} view {k}: frame {frame_s:.3f} s, path tracing {stages.get('trace', 0.0):.3f} s, "
                  f"rays alone {total:.3f} s ({', '.join(f'{n} {s:.3f}' for n, s in cast['seconds'].items())})",
                  flush=True)
        renderer.close()
    trace = float(np.mean([r["trace_s"] for r in rows]))
    kinds = rows[0]["seconds"].keys()
    per_kind = {n: float(np.mean([r["seconds"][n] for r in rows])) for n in kinds}
    rays = {n: float(np.mean([r["rays"][n] for r in rows])) for n in kinds}
    floor = sum(per_kind.values())
    record = {"size": [width, height], "spp": args.spp, "views": len(rows), "versions": renderer_versions(),
              "cores": os.cpu_count(), "loadavg": list(os.getloadavg()),
              "frame_s": float(np.mean([r["frame_s"] for r in rows])), "trace_s": trace, "rays_s": per_kind,
              "rays": rays, "floor_s": floor, "floor_share_of_trace": floor / trace if trace else None,
              "rays_per_s": sum(rays.values()) / floor if floor else None}
    print(json.dumps(record, indent=1))
    if args.json:
        args.json.write_text(json.dumps(record, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
