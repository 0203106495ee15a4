"""Diameter, keypoints and physical properties of built-in objects."""

from __future__ import annotations

import numpy as np
from meshcheck import surface_distance


def test_diameter_matches_brute_force(builtin):
    for name in ("can_0", "mug_0", "box_2", "banana_1", "drill_0"):
        obj = builtin.by_name(name)
        v = obj.vertices
        brute = max(float(np.linalg.norm(v[i:i + 256, None] - v[None], axis=-1).max()) for i in range(0, len(v), 256))
        assert abs(obj.diameter - brute) < 1e-9, name


def test_bbox_keypoints_are_corners(builtin):
    for obj in builtin:
        lo, hi = obj.bbox
        kp = obj.keypoints_bbox
        assert kp.shape == (8, 3)
        for i, p in enumerate(kp):
            expected = [hi[a] if i & (1 << a) else lo[a] for a in range(3)]
            np.testing.assert_allclose(p, expected)


def test_fps_keypoints_on_surface(builtin):
    for obj in builtin:
        kp = obj.keypoints_fps
        assert kp.shape == (obj.num_keypoints, 3)
        dist = surface_distance(obj.mesh, kp)
        assert dist.max() < 1e-6, obj.name
        assert len(np.unique(np.round(kp, 6), axis=0)) == len(kp)


def test_nocs_inside_unit_cube(builtin):
    for obj in builtin:
        n = obj.to_nocs(obj.vertices)
        assert n.min() >= 0.0 and n.max() <= 1.0
