"""Where the shipped keypoint estimator fails on the unseen builtin-small sets: ADD(-S)-0.1d per object, per
visibility band and per camera distance, pooled over the runs given (their errors.csv and datasets).

    python docs/heldout_breakdown.py runs/kp-4101 runs/kp-4102 runs/kp-4103

Distance: the ground-truth translation's norm (metres), read from each run's dataset (metrics.json settings).
"""

from __future__ import annotations

import csv
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from simtest.metrics.intervals import wilson_interval

VISIB = ((0.1, 0.4), (0.4, 0.7), (0.7, 0.9), (0.9, 1.01))
DIST = ((0.0, 0.45), (0.45, 0.6), (0.6, 0.8), (0.8, 9.0))


def _distances(dataset: Path) -> dict[tuple[int, int, int], float]:
    out = {}
    for scene in sorted((dataset / "train_pbr").iterdir()):
        gt = json.loads((scene / "scene_gt.json").read_text())
        for im, rows in gt.items():
            for k, r in enumerate(rows):
                out[(int(scene.name), int(im), k)] = float(np.linalg.norm(r["cam_t_m2c"])) / 1000.0
    return out


def main(runs: list[str]) -> None:
    rows = []
    names = {}
    for run in map(Path, runs):
        settings = json.loads((run / "metrics.json").read_text())["settings"]
        dataset = Path(settings["dataset"])
        dist = _distances(dataset)
        models = json.loads((dataset / "manifest.json").read_text()).get("objects", [])
        for m in models if isinstance(models, list) else []:
            names[int(m.get("obj_id", -1))] = m.get("name", "?")
        with (run / "errors.csv").open() as f:
            for r in csv.DictReader(f):
                ok = r["matched"] == "1" and float(r["add_s_or_add"]) < 0.1 * float(r["diameter_m"])
                key = (int(r["scene_id"]), int(r["im_id"]), int(r["gt_id"]))
                rows.append((int(r["obj_id"]), float(r["visib_fract"]), dist[key], ok))
    groups: dict[str, dict[str, list[bool]]] = {"object": defaultdict(list), "visib_fract": defaultdict(list),
                                                "distance [m]": defaultdict(list)}
    for obj, vis, d, ok in rows:
        groups["object"][f"{names.get(obj, 'obj')} ({obj})"].append(ok)
        groups["visib_fract"][next(f"{a:.1f}-{min(b, 1.0):.1f}" for a, b in VISIB if a <= vis < b)].append(ok)
        groups["distance [m]"][next(f"{a:.2f}-{b:.2f}" if b < 9 else f">= {a:.2f}" for a, b in DIST
                                    if a <= d < b)].append(ok)
    for name, g in groups.items():
        print(f"\n| {name} | targets | ADD(-S)-0.1d [%] |\n|---|---:|---:|")
        for k in sorted(g):
            hits = g[k]
            lo, hi = wilson_interval(sum(hits), len(hits))
            print(f"| {k} | {len(hits)} | {100 * np.mean(hits):.1f} [{100 * lo:.1f}, {100 * hi:.1f}] |")


if __name__ == "__main__":
    main(sys.argv[1:])
