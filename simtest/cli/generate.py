"""``simtest generate``: make a BOP dataset from an object set."""

from __future__ import annotations

import argparse
import sys

from simtest.cli.common import add_backend_options, common_parser, locks_output
from simtest.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("generate", parents=[common_parser()], help="generate a BOP-format RGB-D dataset of physically settled scenes",
                       description="Generate a BOP-format RGB-D dataset (train_pbr layout) of physically settled "
                                   "MuJoCo scenes with exact ground truth. Command-line values override the "
                                   "config file; every other value keeps its default (`simtest generate --print-config` shows them all).")
    p.add_argument("--config", help="TOML or JSON config file")
    p.add_argument("--objects", help="object set: builtin, builtin-small, or a path (mesh folder/file, BOP models/)")
    p.add_argument("--units", choices=["m", "cm", "mm", "auto"],
                   help="units of user meshes (default auto: metres, refusing a diameter outside 1 cm .. 1.5 m)")
    p.add_argument("--scale", type=float, help="factor on top of --units (metres = file units x units x scale)")
    p.add_argument("--scenes", type=int, help="number of scenes")
    p.add_argument("--frames-per-scene", type=int, help="images per scene")
    p.add_argument("--objects-per-scene", type=int, nargs=2, metavar=("MIN", "MAX"))
    p.add_argument("--rig", choices=["shell", "wrist", "sequence"], help="camera rig")
    p.add_argument("--width", type=int, help="image width (pixels)")
    p.add_argument("--height", type=int, help="image height (pixels)")
    p.add_argument("--camera", metavar="PATH",
                   help="a BOP camera.json (fx, fy, cx, cy, width, height, optional depth_scale in mm per depth "
                        "unit): the dataset's intrinsics, image size and depth unit (config camera.file); it "
                        "replaces the config file's camera values; --width/--height must agree with it")
    p.add_argument("--profile", choices=["fast", "quality", "pbr"],
                   help="render profile (quality: shadows, MSAA; pbr: path-traced RGB, needs simtest[pbr])")
    p.add_argument("--depth-sensor", choices=["none", "d435-stereo", "passive-stereo"],
                   help="depth/ from a simulated active/passive stereo sensor; the exact depth goes to depth_exact/")
    p.add_argument("--occlusion", choices=["L0", "L1", "L2", "L3", "mixed"],
                   help="physical occluders so a target per image lands in this level's band")
    p.add_argument("--occlusion-definition", choices=["pascal3d+", "objectcentric"],
                   help="level bands used by --occlusion (default pascal3d+)")
    p.add_argument("--recipe", choices=["tabletop", "bop-pbr"],
                   help="preset of scene, camera and lighting values (bop-pbr: BlenderProc's BOP recipe: room, "
                        "ceiling panel, objects on the floor, 25 views at 0.61-1.24 m); other options win over it")
    p.add_argument("--textures", metavar="DIR",
                   help="folder of materials for the table, floor, walls and distractors: CC0 sets "
                        "(NAME_Color/_Roughness/_NormalGL images) or plain png/jpg images (default: procedural)")
    p.add_argument("--hdri", metavar="DIR",
                   help="folder of equirectangular .hdr/.exr maps lighting the pbr profile (default: procedural sky "
                        "and studio environments)")
    p.add_argument("--materials", metavar="FAMILY,FAMILY",
                   help="procedural material families of the table, floor, walls and distractors (default: all; "
                        "none: MuJoCo's checker and gradient patterns)")
    p.add_argument("--distractor-objects", metavar="SET",
                   help="also drop unannotated objects of another set among the targets (builtin, builtin-small, a "
                        "mesh folder or BOP models folder; scene.distractor_objects; count: "
                        "scene.distractor_object_count, default 2-6)")
    p.add_argument("--coco", action="store_true", default=None, help="also write COCO RLE annotations")
    p.add_argument("--channels", metavar="NAME,NAME",
                   help="dense ground truth per image: instances, coords, normals, flow, keypoints (comma-separated; "
                        "docs/generate.md gives the file formats)")
    p.add_argument("--rgb-format", choices=["jpg", "png"],
                   help="rgb/ image format: jpg (BOP's PBR layout, default) or png (lossless)")
    p.add_argument("--captions", action="store_true", default=None,
                   help="also write scene_captions.json per scene: referring expressions per instance "
                        "(category, colour, size, relations in the first image's camera)")
    p.add_argument("--unlabelled", action="store_true", default=None,
                   help="unlabelled split: only rgb, depth and camera files in the split; the labels go to "
                        "OUT/withheld/SPLIT/ (for evaluation: simtest eval reads them from there)")
    p.add_argument("--workers", type=int, help="worker processes (each owns whole scenes)")
    add_backend_options(p, "scene")
    p.add_argument("--seed", type=int, help="master seed (default 0)")
    p.add_argument("--out", help="dataset folder (required unless --print-config)")
    p.add_argument("--print-config", action="store_true",
                   help="print the resolved config as TOML (a starting point for --config) and exit")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    g.add_argument("--overwrite", action="store_true", help="replace the contents of --out")
    p.set_defaults(func=run)
    locks_output(p)


def config_from_args(args: argparse.Namespace):
    from simtest.generators.config import GenerateConfig, load_config

    cfg = load_config(args.config) if args.config else GenerateConfig()
    overrides = {
        "objects": args.objects, "units": args.units, "scale": args.scale, "scenes": args.scenes,
        "frames_per_scene": args.frames_per_scene, "rig": args.rig, "camera.width": args.width,
        "camera.height": args.height, "camera.file": args.camera, "render.profile": args.profile,
        "render.depth_sensor": args.depth_sensor, "render.coco": args.coco,
        "render.rgb_format": args.rgb_format, "captions": args.captions, "unlabelled": args.unlabelled,
        "workers": args.workers, "backend": args.backend, "ray_address": args.ray_address, "seed": args.seed,
        "occlusion.level": args.occlusion,
        "occlusion.definition": args.occlusion_definition, "materials.textures": args.textures,
        "lights.hdri": args.hdri, "recipe": args.recipe,
        "materials.families": None if args.materials is None else [c.strip() for c in args.materials.split(",")
                                                                   if c.strip() and c.strip() != "none"],
        "scene.objects_per_scene": list(args.objects_per_scene) if args.objects_per_scene else None,
        "scene.distractor_objects": args.distractor_objects,
        "annotation.channels": None if args.channels is None else [c.strip() for c in args.channels.split(",")
                                                                    if c.strip() and c.strip() != "none"],
    }
    overrides = {k: v for k, v in overrides.items() if v is not None}
    if args.width is not None and args.height is None and not args.config and args.camera is None:
        overrides["camera.height"] = args.width * 3 // 4
    try:
        return cfg.replace(**overrides) if overrides else cfg
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("overrides: ", "command line: ")) from None


def run(args: argparse.Namespace) -> int:
    from simtest.generators.pipeline import generate

    cfg = config_from_args(args)
    if args.print_config:
        print(cfg.to_toml(), end="")
        return 0
    if not args.out:
        raise ConfigError("--out DIR is required (the dataset folder)")
    report = generate(cfg, args.out, resume=args.resume, overwrite=args.overwrite, progress=not args.quiet,
                      command_line=sys.argv)
    if not args.quiet:
        print(report.run.summary(), file=sys.stderr)
    print(summary_text(report))
    return 0


def summary_text(report) -> str:
    lines = [f"dataset: {report.out_dir.resolve()}",
             f"scenes: {report.scenes_done} made, {report.scenes_skipped} already complete, "
             f"{report.scenes_total} total",
             f"frames: {report.frames_written} in {report.seconds:.1f} s ({report.frames_per_second:.2f} frames/s)"]
    for s in report.retried:
        lines.append(f"  scene {s.scene_id} re-sampled {s.attempts - 1}x: {'; '.join(s.retry_reasons)}")
    removed = sum(s.removed for s in report.scenes)
    if removed:
        lines.append(f"objects removed after falling off the table: {removed}")
    return "\n".join(lines)
