"""Collision parts: convex hulls for convex objects, CoACD parts (cached on disk) for concave ones."""

from __future__ import annotations

import numpy as np

from simtest.objects.builtin import build_object


def test_convex_object_uses_hull(builtin_small):
    can = builtin_small.by_name("can_0")
    (part,) = can.collision_parts
    assert part.is_convex and abs(part.volume - can.mesh.convex_hull.volume) < 1e-12


def test_concave_parts_are_sane(builtin_small):
    mug = builtin_small.by_name("mug_0")
    parts = mug.collision_parts
    assert 2 <= len(parts) <= 24
    total = sum(p.volume for p in parts)
    assert 0.9 * mug.mesh.volume < total < 1.6 * mug.mesh.volume  # far below the hull (3x the mesh)
    assert all(p.is_convex for p in parts)
    # the cavity stays open: the mug's centre is in no part
    axis_xy = -np.asarray(mug.extra["origin_offset"][:2])  # the body axis after bbox centring
    centre = np.array([[axis_xy[0], axis_xy[1], 0.01]])
    assert not any(p.contains(centre)[0] for p in parts)


def test_decomposition_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path))
    banana = build_object("banana", 1, seed=5)
    first = banana.collision_parts
    files = list((tmp_path / "coacd").glob(f"{banana.mesh_hash}_*.npz"))
    assert len(files) == 1
    again = build_object("banana", 1, seed=5)  # a new instance reads the cache
    second = again.collision_parts
    assert len(first) == len(second)
    for a, b in zip(first, second):
        np.testing.assert_allclose(a.vertices, b.vertices)
    files[0].write_bytes(b"corrupt")
    third = build_object("banana", 1, seed=5).collision_parts  # recomputed, not trusted
    assert len(third) == len(first)
