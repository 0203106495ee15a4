"""``simtest demo``: the main job on the built-in defaults, small enough for a couple of minutes on 2 cores."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="generate a small BOP dataset from the built-in objects and summarize it")
    p.add_argument("--out", default="demo_out", help="output folder (replaced if it holds a previous demo)")
    p.add_argument("--scenes", type=int, default=4)
    p.add_argument("--frames-per-scene", type=int, default=5)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from simtest.cli.generate import summary_text
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import generate

    out = Path(args.out)
    previous = (out / "manifest.json").is_file()
    if out.exists() and any(out.iterdir()) and not previous:
        print(f"simtest demo: {out} exists and is not a simtest dataset; choose another --out", file=sys.stderr)
        return 2
    cfg = GenerateConfig().replace(scenes=args.scenes, frames_per_scene=args.frames_per_scene, seed=args.seed,
                                   **{"render.coco": True})
    data_dir = out / "dataset"
    report = generate(cfg, data_dir, overwrite=True, command_line=sys.argv)
    print(summary_text(report))
    print(describe_dataset(data_dir))
    return 0


def describe_dataset(path: Path) -> str:
    """A short human summary of a BOP dataset folder: layout, objects, instances, visibility."""
    from simtest.io.bop import read_scene, scene_dirs

    manifest = json.loads((path / "manifest.json").read_text())
    split = path / manifest["config"]["split"]
    n_img = n_inst = 0
    visib = []
    per_obj: dict[int, int] = {}
    for sd in scene_dirs(split):
        for im in read_scene(sd).values():
            n_img += 1
            for g in im["gt"]:
                n_inst += 1
                visib.append(g.visib_fract)
                per_obj[g.obj_id] = per_obj.get(g.obj_id, 0) + 1
    names = {o["obj_id"]: o["name"] for o in manifest["objects"]}
    lines = [f"contents: {n_img} RGB-D images, {n_inst} annotated instances of {len(per_obj)} objects",
             f"  layout: {path}/camera.json, models/ (PLY, mm + models_info.json), "
             f"{manifest['config']['split']}/<scene>/rgb, depth, mask, mask_visib, scene_camera.json, "
             f"scene_gt.json, scene_gt_info.json",
             "  instances per object: " + ", ".join(f"{names.get(k, k)}={v}" for k, v in sorted(per_obj.items()))]
    if visib:
        import numpy as np

        v = np.asarray(visib)
        lines.append(f"  visibility: median visib_fract {np.median(v):.2f}; {np.mean(v < 0.5) * 100:.0f}% of "
                     f"instances less than half visible")
    return "\n".join(lines)
