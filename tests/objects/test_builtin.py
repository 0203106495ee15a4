"""Built-in procedural set: geometry, ids, determinism, physics."""

from __future__ import annotations


import numpy as np
import pytest

from simtest.errors import AssetError
from simtest.objects import load_builtin, load_object_set
from simtest.objects.builtin import CATEGORIES, SMALL_NAMES, build_object

EXPECTED_ORDER = [f"{c}_{i}" for c in ("can", "bottle", "mug", "bowl", "box", "cup", "marker", "banana", "drill")
                  for i in range(3)]


def test_ids_and_names_are_stable(builtin):
    assert [o.name for o in builtin] == EXPECTED_ORDER
    assert builtin.ids == list(range(1, len(EXPECTED_ORDER) + 1))
    assert len(builtin.categories) >= 8
    for cat in CATEGORIES:
        assert len(cat.instances) >= 3


def test_small_subset_keeps_ids(builtin, builtin_small):
    assert [o.name for o in builtin_small] == list(SMALL_NAMES)
    for o in builtin_small:
        assert builtin.by_name(o.name).obj_id == o.obj_id
        assert o is builtin.get(o.obj_id)


@pytest.mark.parametrize("name", EXPECTED_ORDER)
def test_mesh_is_watertight_centred_metres(builtin, name):
    o = builtin.by_name(name)
    assert o.mesh.is_watertight and o.mesh.is_winding_consistent
    assert o.mesh.volume > 0
    lo, hi = o.bbox
    np.testing.assert_allclose(lo + hi, 0.0, atol=1e-12)
    assert 0.01 < o.diameter < 0.35  # household sizes, metres
    assert 100 <= len(o.faces) <= 3000
    assert 0.01 < o.mass < 1.2  # kg
    eig = np.linalg.eigvalsh(o.inertia)
    assert np.all(eig > 0) and np.allclose(o.inertia, o.inertia.T)
    assert all(0.0 <= c <= 1.0 for c in o.rgba)


def test_same_seed_identical_different_seed_differs():
    a = build_object("mug", 1, seed=3)
    b = build_object("mug", 1, seed=3)
    c = build_object("mug", 1, seed=4)
    assert a.vertices.tobytes() == b.vertices.tobytes()
    assert a.faces.tobytes() == b.faces.tobytes()
    assert a.rgba == b.rgba
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)
    assert abs(a.diameter - c.diameter) > 1e-5


def test_seed_does_not_change_ids():
    s1 = load_builtin("builtin-small", seed=1)
    s0 = load_builtin("builtin-small", seed=0)
    assert s1.ids == s0.ids
    assert not np.array_equal(s1.get(1).vertices, s0.get(1).vertices)


def test_instances_differ_within_category(builtin):
    for cat in CATEGORIES:
        sizes = [tuple(np.round(builtin.by_name(f"{cat.name}_{i}").size, 4)) for i in range(3)]
        assert len(set(sizes)) == 3, cat.name


def test_concave_flags(builtin):
    for name in ("mug_0", "bowl_0", "cup_0", "banana_0", "drill_0"):
        assert builtin.by_name(name).is_concave
    for name in ("can_0", "bottle_0", "box_0", "marker_0"):
        assert not builtin.by_name(name).is_concave


def test_build_is_cached():
    load_builtin.cache_clear()
    load_builtin("builtin", seed=11)
    assert load_builtin("builtin", seed=11) is load_builtin("builtin", seed=11)


def test_bad_names_and_seeds():
    with pytest.raises(AssetError, match="builtin-small"):
        load_object_set("builtin-huge")
    with pytest.raises(AssetError, match="seed"):
        build_object("can", 0, seed=-1)
    with pytest.raises(AssetError, match="instances 0..2"):
        build_object("can", 5)
    with pytest.raises(AssetError, match="known: can, bottle"):
        build_object("teapot", 0)


def test_unknown_id_lists_known(builtin_small):
    with pytest.raises(AssetError) as info:
        builtin_small.get(99)
    msg = str(info.value)
    assert "99" in msg
    for o in builtin_small:
        assert f"{o.obj_id} ({o.name})" in msg
