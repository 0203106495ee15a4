"""Write a small folder of textured objects with an ``objects.toml`` manifest (see docs/objects.md).

    python docs/examples/textured_objects.py /tmp/textured
    simtest objects list --set /tmp/textured --no-grasps
    simtest objects preview all --set /tmp/textured --views 3 --size 128 --out docs/images/textured.png

The folder holds the three kinds of appearance simtest draws, each in other units:

* ``can/soup.obj`` + ``soup.mtl`` + ``soup_label.png``: a can in centimetres with a UV-mapped label (OBJ + MTL);
* ``box/cereal.glb``: a box in millimetres with a base-colour texture (glTF binary);
* ``fruit/plum.ply``: a fruit in metres with colours per vertex (as BOP's scanned models).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image, ImageDraw

MANIFEST = """\
# What each file is: simtest loads exactly the files listed here (docs/objects.md).
units = "cm"                     # default of every entry

[[object]]
file = "can/soup.obj"
name = "soup_can"
category = "can"                 # default: the folder name (can)
mass = 0.35                      # kg; or density in kg/m^3
friction = 0.9
symmetry = "none"                # the label breaks the can's rotational symmetry

[[object]]
file = "box/cereal.glb"
units = "mm"
symmetry = "discrete 2 z"        # front and back print alike

[[object]]
file = "fruit/plum.ply"
units = "m"
symmetry = "continuous z"
graspable = true
"""


def label_image(size: int = 256) -> Image.Image:
    """A can label: a red band with white stripes and a yellow panel (row 0 at the top)."""
    img = Image.new("RGB", (2 * size, size), (200, 30, 40))
    draw = ImageDraw.Draw(img)
    draw.rectangle([0, 0, 2 * size, size // 6], fill=(240, 240, 235))
    draw.rectangle([0, size - size // 6, 2 * size, size], fill=(240, 240, 235))
    draw.rectangle([size // 3, size // 3, size, 2 * size // 3], fill=(250, 200, 40))
    for k in range(8):
        x = size + k * size // 8
        draw.rectangle([x, size // 4, x + size // 32, 3 * size // 4], fill=(255, 255, 255))
    return img


def write_can(folder: Path, radius: float = 3.3, height: float = 10.0, segments: int = 48) -> None:
    """A closed cylinder (centimetres); the side carries the label, u around, v up, with a UV seam."""
    folder.mkdir(parents=True, exist_ok=True)
    label_image().save(folder / "soup_label.png")
    (folder / "soup.mtl").write_text("newmtl label\nKd 1 1 1\nmap_Kd soup_label.png\n")
    ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    lines = ["mtllib soup.mtl", "usemtl label"]
    lines += [f"v {radius * np.cos(a):.5f} {radius * np.sin(a):.5f} {z:.5f}" for z in (0.0, height) for a in ang]
    lines += [f"v 0 0 {z:.5f}" for z in (0.0, height)]  # cap centres: 2n+1, 2n+2
    lines += [f"vt {k / segments:.5f} {v:.5f}" for v in (0.0, 1.0) for k in range(segments + 1)]
    lines += ["vt 0.02 0.02", "vt 0.98 0.98"]  # caps take the label's white rims
    n, m = segments, segments + 1
    for k in range(n):
        a, b = k + 1, (k + 1) % n + 1  # bottom ring, 1-based
        ta, tb = k + 1, k + 2  # uv of the bottom row (the seam gets its own uv)
        lines += [f"f {a}/{ta} {b}/{tb} {b + n}/{tb + m}", f"f {a}/{ta} {b + n}/{tb + m} {a + n}/{ta + m}"]
        lines += [f"f {2 * n + 1}/{2 * m + 1} {b}/{2 * m + 1} {a}/{2 * m + 1}",
                  f"f {2 * n + 2}/{2 * m + 2} {a + n}/{2 * m + 2} {b + n}/{2 * m + 2}"]
    (folder / "soup.obj").write_text("\n".join(lines) + "\n")


def write_box(folder: Path, size=(190.0, 70.0, 260.0)) -> None:
    """A box (millimetres) with a printed texture on every side, as glTF binary."""
    folder.mkdir(parents=True, exist_ok=True)
    img = Image.new("RGB", (256, 256), (250, 210, 60))
    draw = ImageDraw.Draw(img)
    draw.ellipse([60, 60, 196, 196], fill=(30, 90, 200))
    draw.rectangle([0, 0, 256, 40], fill=(220, 60, 30))
    half = np.asarray(size) / 2
    corners = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], dtype=float) * half
    quads = [(4, 5, 7, 6), (0, 2, 3, 1), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    verts = np.concatenate([corners[list(q)] for q in quads])
    uv = np.tile([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], (6, 1))
    faces = np.array([[4 * i, 4 * i + 1, 4 * i + 2] for i in range(6)]
                     + [[4 * i, 4 * i + 2, 4 * i + 3] for i in range(6)])
    visual = trimesh.visual.TextureVisuals(uv=uv, image=img)
    trimesh.Trimesh(verts, faces, visual=visual, process=False).export(folder / "cereal.glb")


def write_fruit(folder: Path, radius: float = 0.03) -> None:
    """An oblate fruit (metres) with colours per vertex: purple at the top, green toward the stem end."""
    folder.mkdir(parents=True, exist_ok=True)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    mesh.vertices[:, 2] *= 0.85
    t = (mesh.vertices[:, 2] / (0.85 * radius) + 1.0) / 2.0
    purple, green = np.array([110, 30, 120]), np.array([90, 160, 50])
    colours = np.rint(green + (purple - green) * t[:, None] ** 3).astype(np.uint8)
    trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=colours, process=False).export(folder / "plum.ply")


def main(out: str) -> None:
    root = Path(out)
    write_can(root / "can")
    write_box(root / "box")
    write_fruit(root / "fruit")
    (root / "objects.toml").write_text(MANIFEST)
    print(f"wrote {root}: can/soup.obj, box/cereal.glb, fruit/plum.ply, objects.toml")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "textured_objects")
