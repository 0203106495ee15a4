"""Make docs/images/profiles.png: one scene, one view, rendered by the fast, quality and pbr profiles.

Run from the repository root (needs the pbr extra): ``python docs/profiles_figure.py [OUT.png]``.
Every panel is the first image of ``simtest generate --seed 3 --scenes 1 --frames-per-scene 1 --width 320``
with ``--profile fast``, ``quality`` and ``pbr``; only the RGB differs between them.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from simtest.cli import main
from simtest.io.bop import read_image, scene_dirs

PROFILES = ("fast", "quality", "pbr")


def figure(out: Path) -> None:
    panels = []
    with tempfile.TemporaryDirectory() as tmp:
        for profile in PROFILES:
            ds = Path(tmp) / profile
            rc = main(["generate", "--seed", "3", "--scenes", "1", "--frames-per-scene", "1", "--width", "320",
                       "--profile", profile, "--out", str(ds), "--quiet"])
            if rc != 0:
                raise SystemExit(rc)
            img = Image.fromarray(read_image(scene_dirs(ds / "train_pbr")[0], 0))
            ImageDraw.Draw(img).text((6, 4), profile, fill=(255, 255, 255))
            panels.append(np.asarray(img))
    gap = np.full((panels[0].shape[0], 4, 3), 255, dtype=np.uint8)
    row = np.concatenate([p for panel in panels for p in (panel, gap)][:-1], axis=1)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(row).save(out, optimize=True)


if __name__ == "__main__":
    figure(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/images/profiles.png"))
