"""Show the dense ground truth of one generated image beside it: RGB, instance map, object coordinates,
surface normals and forward flow (trains nothing).

    simtest generate --objects builtin-small --rig sequence --scenes 1 --frames-per-scene 3 --width 320 \\
        --height 240 --channels instances,coords,normals,flow,keypoints --seed 3 --out /tmp/dense
    python examples/dense_channels.py /tmp/dense docs/images/dense_channels.png
"""

from __future__ import annotations

import sys

import cv2
import numpy as np

from simtest.io import bop, dense


def flow_colours(flow: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Flow as colour: hue = direction, brightness = length (the longest valid vector is full brightness)."""
    mag = np.linalg.norm(flow, axis=-1)
    hsv = np.zeros(flow.shape[:2] + (3,), np.uint8)
    hsv[..., 0] = ((np.arctan2(flow[..., 1], flow[..., 0]) + np.pi) / (2 * np.pi) * 179).astype(np.uint8)
    hsv[..., 1] = 255
    hsv[..., 2] = np.where(valid, np.clip(mag / max(float(mag[valid].max()) if valid.any() else 1.0, 1e-6) * 255, 0, 255), 0)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)


def main(dataset: str, out: str, scene: int = 0, im: int = 0) -> None:
    d = bop.dataset_split_dir(dataset, "train_pbr") / f"{scene:06d}"
    rgb = bop.read_image(d, im)
    inst = dense.read_channel(d, "instances", im)
    palette = np.random.default_rng(1).integers(60, 255, (int(inst.max()) + 1, 3)).astype(np.uint8)
    palette[0] = 0
    coords = (dense.read_channel(d, "coords", im) // 257).astype(np.uint8)  # 16 -> 8 bits per axis
    normals = np.nan_to_num((dense.decode_normals(dense.read_channel(d, "normals", im)) + 1) / 2 * 255).astype(np.uint8)
    flow = flow_colours(*dense.decode_flow(dense.read_channel(d, "flow", im)))
    tiles = [("rgb", rgb), ("instances", palette[inst]), ("coords (x, y, z -> R, G, B)", coords),
             ("normals (camera frame)", normals), ("flow to the next image", flow)]
    row = []
    for name, img in tiles:
        img = np.ascontiguousarray(img)
        cv2.putText(img, name, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        row.append(img)
    cv2.imwrite(out, np.concatenate(row, axis=1)[..., ::-1])
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
