"""Make docs/images/looks.jpg: 8 random views per row of the built-in set, rendered by the fast and the pbr profile,
with the default recipe and with ``--recipe bop-pbr``.

Run from the repository root (needs the pbr extra): ``python docs/looks_figure.py [OUT.png]``. Each row is the
first image of 8 scenes of
``simtest generate --objects builtin --seed 5 --scenes 8 --frames-per-scene 1 --width 320 --height 240``
with ``--profile fast`` or ``pbr`` and with or without ``--recipe bop-pbr``; within a recipe the two rows share
every ground-truth file (only rgb/ differs). The chromaticity spread inside the objects' masks of each dataset
(:func:`simtest.benchmarks.appearance.chromaticity_spread`) is printed.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from simtest.cli import main
from simtest.io.bop import read_image, scene_dirs

ROWS = (("tabletop", "fast"), ("tabletop", "pbr"), ("bop-pbr", "fast"), ("bop-pbr", "pbr"))
VIEWS = 8


def _dataset(root: Path, recipe: str, profile: str) -> Path:
    ds = root / f"{recipe}_{profile}"
    rc = main(["generate", "--objects", "builtin", "--seed", "5", "--scenes", str(VIEWS), "--frames-per-scene", "1",
               "--width", "320", "--height", "240", "--recipe", recipe, "--profile", profile, "--out", str(ds),
               "--quiet"])
    if rc != 0:
        raise SystemExit(rc)
    return ds


def figure(out: Path) -> None:
    from simtest.benchmarks.appearance import chromaticity_spread

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for recipe, profile in ROWS:
            ds = _dataset(Path(tmp), recipe, profile)
            spread = chromaticity_spread(str(ds))
            print(f"{recipe} / {profile}: chromaticity spread inside masks, mean {spread['mean']:.3f}")
            panels = []
            for scene in scene_dirs(ds / "train_pbr")[:VIEWS]:
                img = Image.fromarray(read_image(scene, 0))
                panels.append(np.asarray(img))
            row = np.concatenate(panels, axis=1)
            label = Image.fromarray(row)
            ImageDraw.Draw(label).text((6, 4), f"{recipe}, {profile}", fill=(255, 255, 255))
            rows.append(np.asarray(label))
            rows.append(np.full((4, row.shape[1], 3), 255, dtype=np.uint8))
    grid = np.concatenate(rows[:-1], axis=0)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(grid).resize((grid.shape[1] // 2, grid.shape[0] // 2), Image.LANCZOS).save(out, quality=85, optimize=True)


if __name__ == "__main__":
    figure(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/images/looks.jpg"))
