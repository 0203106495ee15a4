"""Symmetry detection: agrees with the exact built-in symmetries, maps meshes onto themselves, ignores how a
surface is tessellated, and feeds the loaders, the object table and the pose metrics."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from simtest.cli import main
from simtest.errors import AssetError, ConfigError
from simtest.geometry import rotation_about
from simtest.metrics import add_01d, mssd
from simtest.objects import ObjectModel, detect_symmetries, load_object_set
from simtest.objects.symmetry_detect import apply_symmetry_policy, symmetry_status

CHECKED = ("can", "bottle", "box", "bowl", "cup", "marker")


def surface_deviation(mesh: trimesh.Trimesh, T: np.ndarray, n: int = 600) -> float:
    """Largest distance (m) from transformed surface samples to the mesh surface (exact closest points)."""
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=np.random.default_rng(3))
    _, dist, _ = trimesh.proximity.closest_point(mesh, pts @ T[:3, :3].T + T[:3, 3])
    return float(dist.max())


def continuous_rotation(sym, angle: float) -> np.ndarray:
    T = np.eye(4)
    R = rotation_about(np.asarray(sym.axis), angle)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(sym.offset) - R @ np.asarray(sym.offset)
    return T


def same_transforms(a, b) -> bool:
    """Whether two lists of 4x4 transforms hold the same elements (any order)."""
    if len(a) != len(b):
        return False
    return all(any(np.allclose(x, y, atol=1e-6) for y in b) for x in a)


def test_detection_agrees_with_builtin_symmetries(builtin, builtin_small):
    objects = list(builtin_small) + [o for o in builtin if o.category in CHECKED]
    for obj in objects:
        discrete, continuous = detect_symmetries(obj, colors=False)  # the declared ones are the shape's
        assert len(continuous) == len(obj.symmetries_continuous), obj.name
        for found, declared in zip(continuous, obj.symmetries_continuous):
            np.testing.assert_allclose(found.axis, declared.axis, atol=1e-9, err_msg=obj.name)
            np.testing.assert_allclose(found.offset, declared.offset, atol=1e-6, err_msg=obj.name)
        assert same_transforms(discrete, obj.symmetries_discrete), (
            f"{obj.name}: detected {len(discrete)} discrete symmetries, declared {len(obj.symmetries_discrete)}")


def test_asymmetric_builtins_have_none(builtin):
    for name in ("mug_0", "mug_2", "banana_1", "drill_0"):
        assert detect_symmetries(builtin.by_name(name)) == ([], []), name


def _prism(sides: int) -> trimesh.Trimesh:
    return trimesh.creation.cylinder(radius=0.03, height=0.08, sections=sides)


def _rotated(mesh: trimesh.Trimesh, euler_deg) -> trimesh.Trimesh:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix()
    return mesh.copy().apply_transform(T)


@pytest.mark.parametrize("name,mesh,n_discrete,n_continuous", [
    ("triangular prism", _prism(3), 5, 0),                 # D3
    ("pentagonal prism", _prism(5), 9, 0),                 # D5
    ("hexagonal prism", _prism(6), 11, 0),                 # D6
    ("nonagonal prism", _prism(9), 17, 0),                 # D9: from the 3-fold axis and the flips
    ("cube", trimesh.creation.box([0.05] * 3), 23, 0),     # the rotation group of the cube
    ("tilted box", _rotated(trimesh.creation.box([0.04, 0.07, 0.12]), (20, 35, 10)), 3, 0),
    ("tilted cylinder", _rotated(_prism(64), (20, 35, 10)), 1, 1),
    ("cone", trimesh.creation.cone(radius=0.03, height=0.1, sections=64), 0, 1),
    ("tube", trimesh.creation.annulus(r_min=0.02, r_max=0.03, height=0.05, sections=64), 1, 1),
])
def test_detected_symmetries_map_mesh_onto_itself(name, mesh, n_discrete, n_continuous):
    discrete, continuous = detect_symmetries(mesh)
    assert (len(discrete), len(continuous)) == (n_discrete, n_continuous), name
    diameter = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    transforms = list(discrete) + [continuous_rotation(s, a) for s in continuous for a in (0.3, 2.0, 4.5)]
    for T in transforms:
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9) and np.linalg.det(T[:3, :3]) > 0
        assert surface_deviation(mesh, T) < 0.01 * diameter, name


def test_a_small_asymmetric_feature_breaks_the_symmetry():
    body = trimesh.creation.box([0.04, 0.07, 0.12])
    nub = trimesh.creation.box([0.02, 0.02, 0.02])
    nub.apply_translation([0.02, 0.03, 0.05])
    assert detect_symmetries(trimesh.util.concatenate([body, nub])) == ([], [])
    can = _prism(64)
    dent = trimesh.creation.box([0.01, 0.01, 0.03])
    dent.apply_translation([0.033, 0.0, 0.0])
    discrete, continuous = detect_symmetries(trimesh.util.concatenate([can, dent]))
    assert continuous == []  # the label breaks the turn about the axis; the half turn about x remains
    assert len(discrete) == 1 and np.allclose(discrete[0][:3, :3], np.diag([1.0, -1.0, -1.0]))


def test_detection_ignores_tessellation():
    coarse = _prism(64)
    fine = coarse.subdivide_to_size(0.003)  # ~20x the faces, sliver triangles along the caps
    assert len(fine.faces) > 10_000
    rng = np.random.default_rng(0)
    noisy = fine.copy()
    noisy.vertices = noisy.vertices + rng.normal(scale=0.0001, size=noisy.vertices.shape)
    results = [detect_symmetries(m) for m in (coarse, fine, noisy)]
    for discrete, continuous in results:
        assert len(discrete) == 1 and len(continuous) == 1
        np.testing.assert_allclose(continuous[0].axis, (0.0, 0.0, 1.0), atol=1e-6)
        np.testing.assert_allclose(continuous[0].offset, (0.0, 0.0, 0.0), atol=5e-4)


def test_tolerance_is_checked():
    with pytest.raises(ConfigError, match="tolerance"):
        detect_symmetries(_prism(8), tol=0.0)
    # an octagonal prism is 8-fold; at 5 % of the diameter its facets pass for a continuous surface
    assert detect_symmetries(_prism(8), tol=0.05)[1] != []
    assert detect_symmetries(_prism(8), tol=0.01)[1] == []


@pytest.fixture()
def mesh_folder(tmp_path):
    folder = tmp_path / "meshes"
    folder.mkdir()
    trimesh.creation.cylinder(radius=0.03, height=0.1, sections=64).export(folder / "can.stl")
    body = trimesh.creation.box([0.04, 0.07, 0.12])
    nub = trimesh.creation.box([0.02, 0.02, 0.02])
    nub.apply_translation([0.02, 0.03, 0.05])
    trimesh.util.concatenate([body, nub]).export(folder / "odd.stl")
    return folder


def test_loader_uses_detected_symmetries_by_default(mesh_folder):
    objects = load_object_set(mesh_folder)
    can, odd = objects.by_name("can"), objects.by_name("odd")
    assert can.symmetry_label() == "continuous(z)+discrete(1)" and can.extra["symmetry"] == "detected"
    assert not odd.is_symmetric and odd.extra["symmetry"] == "detected"
    assert symmetry_status(can) == "continuous(z)+discrete(1) detected"
    assert symmetry_status(odd) == "none detected"
    single = load_object_set(mesh_folder / "can.stl")
    assert single[0].symmetry_label() == "continuous(z)+discrete(1)"


def test_loader_symmetry_none_and_bad_values(mesh_folder):
    objects = load_object_set(mesh_folder, symmetry="none")
    can = objects.by_name("can")
    assert not can.is_symmetric and can.extra["symmetry"] == "off"
    assert symmetry_status(can) == "continuous(z)+discrete(1) detected, not used"
    with pytest.raises(AssetError, match="symmetry must be one of auto, geometry, none, got 'maybe'"):
        load_object_set(mesh_folder, symmetry="maybe")
    with pytest.raises(ConfigError, match="symmetry must be one of"):
        apply_symmetry_policy(objects, "yes")


def test_declared_symmetries_win(builtin_small):
    kept = apply_symmetry_policy(builtin_small)
    for before, after in zip(builtin_small, kept):
        assert after is before or not after.is_symmetric  # built-in: exact symmetries untouched
    box = builtin_small.by_name("box_0")
    assert kept.by_name("box_0") is box and symmetry_status(box) == "discrete(3)"
    # a manifest that declares "no symmetry" marks it, and detection leaves the object alone
    from dataclasses import replace

    can = replace(builtin_small.by_name("can_0"), symmetries_discrete=(), symmetries_continuous=(),
                  extra={"symmetry": "declared"})
    from simtest.objects import ObjectSet

    assert not apply_symmetry_policy(ObjectSet([can]))[0].is_symmetric


def test_objects_list_shows_detected_symmetries(mesh_folder, capsys):
    assert main(["objects", "list", "--set", str(mesh_folder), "--no-grasps"]) == 0
    out = capsys.readouterr().out
    assert "continuous(z)+discrete(1) detected" in out and "none detected" in out
    assert main(["objects", "list", "--set", str(mesh_folder), "--no-grasps", "--symmetry", "none"]) == 0
    assert "continuous(z)+discrete(1) detected, not used" in capsys.readouterr().out


def test_can_turned_about_its_axis_scores_correct_with_detected_symmetries(mesh_folder):
    """An estimate that matches the surface but is turned about the can's axis (what ICP returns) is
    correct once the detected symmetry is used, and wrong without it."""
    detected = load_object_set(mesh_folder).by_name("can")
    plain = load_object_set(mesh_folder, symmetry="none").by_name("can")
    R_g, t_g = Rotation.from_euler("xyz", [30, -20, 50], degrees=True).as_matrix(), np.array([0.02, -0.01, 0.6])
    R_e = R_g @ rotation_about([0.0, 0.0, 1.0], 1.1)  # turned by 63 degrees about the model z axis
    pts = detected.vertices
    assert mssd(R_e, t_g, R_g, t_g, pts, detected.symmetry_transforms()) < 0.001
    assert mssd(R_e, t_g, R_g, t_g, pts, plain.symmetry_transforms()) > 0.02
    assert add_01d(detected, R_e, t_g, R_g, t_g) and not add_01d(plain, R_e, t_g, R_g, t_g)
    # upside down is the same can too (the half turn that swaps its ends)
    R_flip = R_g @ rotation_about([1.0, 0.0, 0.0], np.pi) @ rotation_about([0.0, 0.0, 1.0], 0.4)
    assert mssd(R_flip, t_g, R_g, t_g, pts, detected.symmetry_transforms()) < 0.001


def test_results_are_cached_and_copies():
    mesh = _prism(6)
    first, _ = detect_symmetries(mesh)
    first[0][0, 3] = 99.0  # callers may modify what they get
    second, _ = detect_symmetries(mesh)
    assert second[0][0, 3] != 99.0 and len(second) == 11


def test_detects_on_object_models():
    obj = ObjectModel(1, "hex", "nut", 0, _prism(6))
    assert len(detect_symmetries(obj)[0]) == 11


def test_detected_symmetries_are_exported_as_bop_models(mesh_folder, tmp_path):
    """``objects export`` writes what was detected into models_info.json, and reading it back keeps it."""
    out = tmp_path / "models"
    assert main(["objects", "export", "--set", str(mesh_folder), "--out", str(out)]) == 0
    exported = load_object_set(out)
    original = load_object_set(mesh_folder)
    for a, b in zip(original, exported):
        assert b.symmetry_label() == a.symmetry_label(), a.name
        assert same_transforms(list(b.symmetries_discrete), list(a.symmetries_discrete))


# ---------------------------------------------------------------------------------------------------------
# Appearance: symmetry is visual indistinguishability, so printed faces count

#: Pip centres of the six faces of a die, in face coordinates [0, 1]^2 (opposite faces sum to seven).
_PIPS = {1: [(0.5, 0.5)], 2: [(0.25, 0.25), (0.75, 0.75)], 3: [(0.25, 0.25), (0.5, 0.5), (0.75, 0.75)],
         4: [(0.25, 0.25), (0.25, 0.75), (0.75, 0.25), (0.75, 0.75)],
         5: [(0.25, 0.25), (0.25, 0.75), (0.5, 0.5), (0.75, 0.25), (0.75, 0.75)],
         6: [(0.25, 0.2), (0.25, 0.5), (0.25, 0.8), (0.75, 0.2), (0.75, 0.5), (0.75, 0.8)]}


def _printed_cube(path, faces: dict[int, list[tuple[float, float]]], side: float = 0.05) -> None:
    """An OBJ cube (with its MTL and PNG texture) whose six faces are printed white with black pips: face ``k``
    of the +x, -x, +y, -y, +z, -z faces shows ``faces[k + 1]``'s pips; an atlas of 3 x 2 cells of 64 px."""
    from PIL import Image

    cell = 64
    atlas = np.full((2 * cell, 3 * cell, 3), 255, np.uint8)
    yy, xx = np.mgrid[0:cell, 0:cell] + 0.5
    verts, uvs, tris = [], [], []
    for k, (axis, sign) in enumerate([(0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)]):
        row, col = divmod(k, 3)
        img = atlas[row * cell:(row + 1) * cell, col * cell:(col + 1) * cell]
        for u, v in faces[k + 1]:
            img[(xx - u * cell) ** 2 + (yy - (1 - v) * cell) ** 2 < (0.13 * cell) ** 2] = 0
        a, b = [i for i in range(3) if i != axis]
        base = len(verts)
        for u, v in [(0, 0), (1, 0), (1, 1), (0, 1)]:
            p = np.zeros(3)
            p[axis], p[a], p[b] = sign * side / 2, (u - 0.5) * side, (v - 0.5) * side
            verts.append(p)
            uvs.append(((col + u) / 3, 1 - (row + 1 - v) / 2))
        quad = [[0, 1, 2], [0, 2, 3]] if sign > 0 else [[0, 2, 1], [0, 3, 2]]
        tris += [[base + i for i in t] for t in quad]
    material = trimesh.visual.material.SimpleMaterial(image=Image.fromarray(atlas), name=path.stem)
    mesh = trimesh.Trimesh(np.array(verts), np.array(tris), process=False,
                           visual=trimesh.visual.TextureVisuals(uv=np.array(uvs), material=material))
    mesh.export(path, mtl_name=f"{path.stem}.mtl")  # its own material and texture files beside it


def test_a_die_has_no_symmetry_and_a_plain_cube_keeps_its_24(tmp_path, capsys):
    folder = tmp_path / "printed"
    folder.mkdir()
    _printed_cube(folder / "die.obj", _PIPS)
    _printed_cube(folder / "dotted.obj", {k: [(0.5, 0.5)] for k in range(1, 7)})  # one centred dot per face
    trimesh.creation.box([0.05, 0.05, 0.05]).export(folder / "plain.stl")
    objects = load_object_set(folder)
    die, dotted, plain = (objects.by_name(n) for n in ("die", "dotted", "plain"))
    assert die.appearance is not None and die.appearance.kind == "texture"
    assert not die.is_symmetric and symmetry_status(die) == "none detected (shape and colours)"
    assert len(dotted.symmetries_discrete) == 23  # the centred dots map onto each other under every rotation
    assert symmetry_status(dotted) == "discrete(23) detected (shape and colours)"
    assert len(plain.symmetries_discrete) == 23 and symmetry_status(plain) == "discrete(23) detected"
    shape_only = load_object_set(folder, symmetry="geometry").by_name("die")
    assert len(shape_only.symmetries_discrete) == 23
    assert symmetry_status(shape_only) == "discrete(23) detected (shape only)"
    # the die's faces are told apart: a quarter turn is an error under its symmetries, as the pips show
    quarter = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    t = np.array([0.0, 0.0, 0.6])
    assert mssd(quarter, t, np.eye(3), t, die.vertices, die.symmetry_transforms()) > 0.01
    assert mssd(quarter, t, np.eye(3), t, plain.vertices, plain.symmetry_transforms()) < 1e-6
    assert main(["objects", "list", "--set", str(folder), "--no-grasps"]) == 0  # the table says how it was found
    out = capsys.readouterr().out
    assert "none detected (shape and colours)" in out and "discrete(23) detected (shape and colours)" in out
