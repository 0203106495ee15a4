"""Skins of the built-in objects: textures and UVs on unchanged meshes, determinism, layout, looks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

import simtest.objects.shapes as shapes
from simtest.errors import AssetError
from simtest.objects.builtin import CATEGORIES, JITTER, build_object, load_builtin
from simtest.objects.model import ObjectModel
from simtest.objects.skins import LAYOUTS, SKIN_FAMILIES, WRAP, Skin, skin, skin_uv

NAMES = [(c.name, i) for c in CATEGORIES for i in range(len(c.instances))]
LAYOUT_OF = {"box": "carton", "banana": "banana", "drill": "drill"}


def untextured(category: str, instance: int, seed: int) -> ObjectModel:
    """The built-in object as it was built before skins: the same random stream, the material colour."""
    ci = [c.name for c in CATEGORIES].index(category)
    cat = CATEGORIES[ci]
    rng = np.random.default_rng([seed, ci, instance])
    nominal = cat.instances[instance]
    params = {k: float(nominal[k] * (1.0 + rng.uniform(-JITTER, JITTER))) if isinstance(nominal[k], float)
              else nominal[k] for k in sorted(nominal)}
    shape = cat.build(params, rng)
    mesh, _ = shapes.center_bbox(shape.mesh)
    base = np.asarray(cat.palette[int(rng.integers(len(cat.palette)))])
    rgb = np.clip(base + rng.uniform(-0.04, 0.04, size=3), 0.0, 1.0)
    first = 1 + sum(len(c.instances) for c in CATEGORIES[:ci])
    return ObjectModel(obj_id=first + instance, name=f"{category}_{instance}", category=category, instance=instance,
                       mesh=mesh, density=cat.density, concave=cat.concave, rgba=(*np.round(rgb, 4).tolist(), 1.0),
                       symmetries_discrete=shape.symmetries_discrete,
                       symmetries_continuous=shape.symmetries_continuous)


@pytest.mark.parametrize("seed", [0, 5])
def test_meshes_and_everything_derived_are_unchanged(seed):
    for category, instance in NAMES:
        new, old = build_object(category, instance, seed), untextured(category, instance, seed)
        assert new.vertices.tobytes() == old.vertices.tobytes(), new.name
        assert new.faces.tobytes() == old.faces.tobytes(), new.name
        assert new.mesh_hash == old.mesh_hash and new.obj_id == old.obj_id and new.name == old.name
        assert new.mass == old.mass and np.array_equal(new.inertia, old.inertia)
        assert new.symmetries_continuous == old.symmetries_continuous
        assert len(new.symmetries_discrete) == len(old.symmetries_discrete)
        assert all(np.array_equal(a, b) for a, b in zip(new.symmetries_discrete, old.symmetries_discrete))
        assert np.array_equal(new.keypoints_bbox, old.keypoints_bbox)
        # the colour the stream drew is kept as the skin's base colour; the material colour is white
        assert tuple(new.extra["skin"]["base_rgb"]) == old.rgba[:3]
        assert new.rgba == (1.0, 1.0, 1.0, 1.0)


def test_every_builtin_wears_its_family_skin(builtin):
    for obj in builtin:
        info = obj.extra["skin"]
        assert info["family"] == SKIN_FAMILIES[obj.category]
        app = obj.appearance
        assert app.kind == "texture" and app.texture.shape == (256, 256, 3)
        expected = skin(obj.category, tuple(info["base_rgb"]), info["seed"])
        assert app.texture.tobytes() == expected.albedo.tobytes()
        assert np.array_equal(app.face_uv, skin_uv(obj.category, obj.mesh, obj.extra["params"]))
    seeds = [o.extra["skin"]["seed"] for o in builtin]
    assert len(set(seeds)) == len(seeds)  # each object draws its own variant


def test_fast_keypoints_and_grasps_unchanged_on_one_object():
    new, old = build_object("mug", 0, 0), untextured("mug", 0, 0)
    assert np.array_equal(new.keypoints_fps, old.keypoints_fps)
    assert np.array_equal(new.surface_points, old.surface_points)


def test_skin_is_deterministic_cached_and_read_only():
    a = skin("can", (0.7, 0.1, 0.1), 3)
    assert isinstance(a, Skin) and a is skin("can", (0.70001, 0.1, 0.1), 3)  # cached, colour rounded to 4 digits
    for arr, shape in ((a.albedo, (256, 256, 3)), (a.roughness, (256, 256)), (a.metallic, (256, 256))):
        assert arr.dtype == np.uint8 and arr.shape == shape and not arr.flags.writeable
    assert 0.0 <= a.specular <= 1.0
    small = skin("can", (0.7, 0.1, 0.1), 3, size=64)
    assert small.albedo.shape == (64, 64, 3)


def _digests() -> dict[str, str]:
    import hashlib

    out = {}
    for category in sorted(SKIN_FAMILIES):
        sk = skin(category, (0.3, 0.5, 0.7), 1)
        out[category] = hashlib.sha256(sk.albedo.tobytes() + sk.roughness.tobytes() + sk.metallic.tobytes()).hexdigest()
    return out


def test_the_same_arguments_give_the_same_bytes_in_another_process():
    import json
    import subprocess
    import sys

    code = "import json; from tests.objects.test_skins import _digests; print(json.dumps(_digests()))"
    root = Path(__file__).resolve().parents[2]
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=root)
    assert json.loads(other.stdout.strip().splitlines()[-1]) == _digests()


@pytest.mark.parametrize("category", sorted(SKIN_FAMILIES))
def test_seeds_and_colours_give_variants(category):
    first = skin(category, (0.3, 0.5, 0.7), 1).albedo
    assert not np.array_equal(skin(category, (0.3, 0.5, 0.7), 2).albedo, first)
    assert not np.array_equal(skin(category, (0.8, 0.2, 0.1), 1).albedo, first)


@pytest.mark.parametrize("category,instance", NAMES)
def test_uvs_in_range_and_every_face_inside_one_region(builtin, category, instance):
    obj = builtin.by_name(f"{category}_{instance}")
    uv = obj.appearance.face_uv
    assert uv.shape == (len(obj.faces), 3, 2) and np.all(np.isfinite(uv))
    assert uv.min() >= 0.0 and uv.max() <= 1.0
    inside_any = np.zeros(len(uv), dtype=bool)
    for u0, v0, u1, v1 in LAYOUTS[LAYOUT_OF.get(category, "revolution")].values():
        inside = ((uv[..., 0] >= u0) & (uv[..., 0] <= u1) & (uv[..., 1] >= v0) & (uv[..., 1] <= v1)).all(axis=1)
        inside_any |= inside
    assert inside_any.all(), f"{(~inside_any).sum()} faces straddle atlas regions"


def test_side_faces_do_not_stretch_across_the_seam(builtin):
    side = LAYOUTS["revolution"]["side"]
    for name in ("can_0", "bottle_1", "mug_2", "bowl_0", "cup_1", "marker_0"):
        uv = builtin.by_name(name).appearance.face_uv
        on_side = (uv[..., 1] >= side[1]).all(axis=1)
        span = uv[on_side, :, 0].max(axis=1) - uv[on_side, :, 0].min(axis=1)
        assert on_side.sum() > 48 and span.max() < 2.0 / 48, name  # one segment, never the whole atlas
    uv = builtin.by_name("banana_0").appearance.face_uv
    assert (uv[..., 1].max(axis=1) - uv[..., 1].min(axis=1)).max() < 1.5 / 16 / (1 + WRAP) + 0.01


def test_can_rims_and_lids_are_metal_the_label_paper_ceramics_glossy():
    can = skin("can", (0.7, 0.1, 0.1), 0)
    rows = np.arange(256)
    side_rows = rows[: 192]  # the side region is the top three quarters of the atlas
    v = 1.0 - (side_rows + 0.5) / 256  # v of each row
    h = ((v - 0.25) / 0.75 - 0.02) / 0.96  # side height
    rim = side_rows[(h > 0.005) & (h < 0.04)]
    label = side_rows[(h > 0.3) & (h < 0.7)]
    assert (can.metallic[rim] == 255).mean() > 0.9 and (can.metallic[label] == 0).mean() > 0.9
    assert abs(can.roughness[label].mean() / 255 - 0.6) < 0.05
    assert (can.metallic[200:, 10:50] == 255).mean() > 0.9  # the lids
    mug = skin("mug", (0.2, 0.35, 0.7), 0)
    assert mug.metallic.max() == 0
    assert np.median(mug.roughness[60:150]) / 255 <= 0.21  # the glaze
    drill = skin("drill", (0.75, 0.12, 0.1), 0)
    assert (drill.metallic[140:250, 140:250] == 255).mean() > 0.9  # the chuck region
    banana = skin("banana", (0.95, 0.82, 0.2), 0)
    assert abs(np.median(banana.roughness) / 255 - 0.5) < 0.05


def test_base_colour_is_the_dominant_colour_of_the_print():
    from simtest.generators.captions import colour_name, dominant_colour

    hits, total = 0, 0
    for seed in (0, 1, 2):
        for obj in load_builtin("builtin", seed):
            hits += dominant_colour(obj, obj.rgba)[0] == colour_name(obj.extra["skin"]["base_rgb"])
            total += 1
    assert hits / total > 0.85


def test_textured_preview_varies_in_chromaticity_more_than_the_flat_object():
    import dataclasses

    from simtest.benchmarks.appearance import instance_spread
    from simtest.objects.preview import render_preview

    obj = build_object("can", 0, 0)
    flat = dataclasses.replace(obj, appearance=None, rgba=(*obj.extra["skin"]["base_rgb"], 1.0))
    spreads = []
    for o in (obj, flat):
        image = render_preview(o, size=96, views=2)
        spreads.append(instance_spread(image, image.sum(axis=2) > 30))
    assert spreads[0] > spreads[1] + 0.02


def test_errors_name_the_bad_value():
    mesh = build_object("can", 0, 0).mesh
    with pytest.raises(AssetError, match="unknown category 'spoon'"):
        skin("spoon", (0.5, 0.5, 0.5), 0)
    with pytest.raises(AssetError, match="base_rgb"):
        skin("can", (1.5, 0.5, 0.5), 0)
    with pytest.raises(AssetError, match="seed"):
        skin("can", (0.5, 0.5, 0.5), -1)
    with pytest.raises(AssetError, match="size"):
        skin("can", (0.5, 0.5, 0.5), 0, size=4)
    with pytest.raises(AssetError, match="unknown category"):
        skin_uv("spoon", mesh, {})
    with pytest.raises(AssetError, match="cap_length"):
        skin_uv("marker", build_object("marker", 0, 0).mesh, {})
    with pytest.raises(AssetError, match="swept tube"):
        skin_uv("banana", trimesh.creation.box(extents=(0.1, 0.1, 0.1)), {})
