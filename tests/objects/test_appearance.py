"""Appearance of assets: textures, vertex colours and material colours reach the rendered pixels where the
UVs put them, survive export -> load, and colour randomization tints rather than replaces them."""

from __future__ import annotations

import importlib.util
import colorsys

import numpy as np
import pytest
import trimesh
from PIL import Image

from simtest.camera import CameraModel, look_at_pose
from simtest.generators.builder import SceneBuilder
from simtest.generators.config import GenerateConfig
from simtest.generators.scene_spec import (LightSpec, ObjectPlacement, SceneSpec, SurfaceSpec, object_colour,
                                          sample_scene_spec)
from simtest.io.bop_models import write_bop_models
from simtest.objects import ObjectSet, load_object_set
from simtest.render.rasterizer import Renderer

HALF = 0.03  # cube half size, metres
CELLS = 4  # checkerboard cells per side
TABLE_Z = 0.4
W, H = 96, 72


def cell_colour(i: int, j: int) -> np.ndarray:
    """Colour of checker cell (i along u, j along v): each cell its own hue, so a flip or shift shows."""
    r, g, b = colorsys.hsv_to_rgb((i * CELLS + j) / CELLS ** 2, 0.85, 0.9 if (i + j) % 2 else 0.6)
    return np.round(np.array([r, g, b]) * 255).astype(np.uint8)


def checker_image(texels_per_cell: int = 8) -> np.ndarray:
    """(H, W, 3) uint8, row 0 at the top: cell (i, j) has v from j / CELLS (bottom) up."""
    n = CELLS * texels_per_cell
    img = np.zeros((n, n, 3), dtype=np.uint8)
    for i in range(CELLS):
        for j in range(CELLS):
            rows = slice(n - (j + 1) * texels_per_cell, n - j * texels_per_cell)
            img[rows, i * texels_per_cell:(i + 1) * texels_per_cell] = cell_colour(i, j)
    return img


#: Cube corners and the faces as quads (outward, counter-clockwise), each face mapping the whole texture:
#: corner 0 of a quad at uv (0, 0), 1 at (1, 0), 2 at (1, 1), 3 at (0, 1). The top face (+z) has u along +x.
_CORNERS = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], dtype=float) * HALF
_QUADS = [(4, 5, 7, 6), (0, 2, 3, 1), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]


def write_textured_cube(folder, name: str = "cube") -> None:
    """``name.obj`` + ``name.mtl`` + ``name_checker.png``: a cube with a UV checkerboard on every face."""
    Image.fromarray(checker_image()).save(folder / f"{name}_checker.png")
    (folder / f"{name}.mtl").write_text(f"newmtl checker\nKd 1 1 1\nmap_Kd {name}_checker.png\n")
    lines = [f"mtllib {name}.mtl", "usemtl checker"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in _CORNERS]
    lines += ["vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1"]
    for q in _QUADS:
        a, b, c, d = (k + 1 for k in q)
        lines += [f"f {a}/1 {b}/2 {c}/3", f"f {a}/1 {c}/3 {d}/4"]
    (folder / f"{name}.obj").write_text("\n".join(lines) + "\n")


#: One colour per cube corner (scanned models carry colours like these per vertex).
CORNER_COLOURS = np.array([[230, 30, 30], [30, 200, 40], [40, 60, 220], [240, 220, 30],
                           [200, 40, 200], [30, 210, 210], [250, 140, 20], [120, 60, 20]], dtype=np.uint8)


def write_vertex_colour_ply(path) -> None:
    """A BOP-style PLY (shared vertices, red/green/blue per vertex) of the cube."""
    faces = [f for q in _QUADS for f in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
    mesh = trimesh.Trimesh(_CORNERS, faces, vertex_colors=CORNER_COLOURS, process=False)
    mesh.export(path)


def render(obj, eye=(-0.06, -0.08, TABLE_Z + HALF + 0.2), lights=(), ambient=1.0, rgba=(1.0, 1.0, 1.0, 1.0)):
    """One MuJoCo render of ``obj`` resting on the table at the origin, model axes = world axes.

    Default lighting is flat white (ambient 1, no lights, no specular): pixels show texture x material colour.
    Returns ``(frame, camera, T_world_obj translation)``.
    """
    cfg = GenerateConfig().replace(**{"camera.width": W, "camera.height": H})
    builder = SceneBuilder(ObjectSet([obj], "one"), cfg.build_options())
    pos = (0.0, 0.0, TABLE_Z + HALF)
    flat = SurfaceSpec("flat", (0.2, 0.2, 0.2), (0.2, 0.2, 0.2), 1.0, 0.0)
    spec = SceneSpec(0, 0, (ObjectPlacement(obj.obj_id, pos, (1.0, 0.0, 0.0, 0.0), tuple(rgba), 0.0, 0.0, 0.0),),
                     (), tuple(lights), ambient, flat, flat, flat, ())
    sim = builder.build(spec)
    camera = CameraModel(cfg.camera.K(), W, H, look_at_pose(np.array(eye), np.array(pos)))
    sim.set_camera(camera)
    with Renderer(sim.model, W, H) as r:
        frame = r.render(sim.data, sim.camera_id)
    return frame, camera, np.array(pos), sim


def pixels_at(frame, camera, points_world) -> np.ndarray:
    uv, _ = camera.project_world(np.asarray(points_world))
    px = np.rint(uv).astype(int)
    assert np.all((px >= 0) & (px < [W, H])), px
    return frame.rgb[px[:, 1], px[:, 0]].astype(int)


def top_cell_centres(centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points of the top face's cell centres and their checker colours."""
    pts, cols = [], []
    for i in range(CELLS):
        for j in range(CELLS):
            u, v = (i + 0.5) / CELLS, (j + 0.5) / CELLS
            pts.append(centre + [-HALF + 2 * HALF * u, -HALF + 2 * HALF * v, HALF])
            cols.append(cell_colour(i, j))
    return np.array(pts), np.array(cols, dtype=int)


def assert_checker_rendered(obj) -> None:
    frame, camera, centre, _ = render(obj)
    pts, expected = top_cell_centres(centre)
    got = pixels_at(frame, camera, pts)
    np.testing.assert_allclose(got, expected, atol=12)


@pytest.fixture()
def textured_cube(tmp_path):
    write_textured_cube(tmp_path)
    (obj,) = load_object_set(tmp_path / "cube.obj", units="m")
    return obj


def test_obj_mtl_texture_is_read_with_seams_and_a_closed_mesh(textured_cube):
    obj = textured_cube
    assert obj.appearance.kind == "texture"
    assert obj.appearance.texture.shape == (32, 32, 3)
    assert obj.appearance.face_uv.shape == (12, 3, 2)
    # UV seams stay in the per-corner UVs while the geometry is one closed surface (8 vertices)
    assert len(obj.vertices) == 8 and obj.is_watertight
    assert obj.rgba == (1.0, 1.0, 1.0, 1.0)


def test_obj_texture_rendered_where_the_uvs_put_it(textured_cube):
    assert_checker_rendered(textured_cube)


def test_glb_base_colour_texture_rendered(tmp_path):
    write_textured_cube(tmp_path)
    loaded = trimesh.load(tmp_path / "cube.obj", force="mesh", process=False)
    loaded.export(tmp_path / "cube_gltf.glb")
    (obj,) = load_object_set(tmp_path / "cube_gltf.glb", units="m")
    assert obj.appearance.kind == "texture"
    assert_checker_rendered(obj)


def test_vertex_colours_baked_per_face(tmp_path):
    path = tmp_path / "colours.ply"
    write_vertex_colour_ply(path)
    (obj,) = load_object_set(path, units="m")
    assert obj.appearance.kind == "vertex"
    np.testing.assert_array_equal(obj.appearance.vertex_colors[np.lexsort(obj.vertices.T[::-1])],
                                  CORNER_COLOURS[np.lexsort(_CORNERS.T[::-1])])
    frame, camera, centre, sim = render(obj, eye=(-0.1, -0.12, TABLE_Z + HALF + 0.1))
    # every triangle facing the camera shows the mean colour of its three vertices at its centroid
    normals = obj.mesh.face_normals
    to_cam = camera.T_world_cam.t - (centre + obj.mesh.triangles_center)
    facing = np.flatnonzero(np.einsum("ij,ij->i", normals, to_cam) > 0.3 * np.linalg.norm(to_cam, axis=1))
    assert len(facing) >= 4
    expected = obj.appearance.vertex_colors[obj.faces[facing]].astype(float).mean(axis=1)
    got = pixels_at(frame, camera, centre + obj.mesh.triangles_center[facing])
    np.testing.assert_allclose(got, expected, atol=8)


def test_texture_in_standard_model_fields(textured_cube):
    _, _, _, sim = render(textured_cube)
    m = sim.model
    mat = m.geom_matid[m.body_geomadr[sim.instance_bodies[0]]]
    tex = m.mat_texid[mat].max()
    assert tex >= 0 and m.tex_width[tex] == 32 and m.tex_height[tex] == 32
    assert m.mesh_texcoordnum[m.geom_dataid[m.body_geomadr[sim.instance_bodies[0]]]] > 0


def _chromaticity_spread(frame, sim) -> float:
    mask = np.isin(frame.seg, np.flatnonzero(sim.geom_instance == 0))
    rgb = frame.rgb[mask].astype(float) + 1.0
    chroma = rgb[:, :2] / rgb.sum(axis=1, keepdims=True)
    return float(chroma.std(axis=0).max())


def test_textured_object_varies_in_chromaticity_a_flat_one_does_not(tmp_path, textured_cube):
    trimesh.creation.box(extents=[2 * HALF] * 3).export(tmp_path / "plain.stl")
    (plain,) = load_object_set(tmp_path / "plain.stl", units="m")
    assert plain.appearance is None
    light = LightSpec((0.3, -0.4, TABLE_Z + 1.0), tuple(np.array([-0.3, 0.4, -1.0]) / np.linalg.norm([0.3, 0.4, 1.0])),
                      (0.7, 0.7, 0.7), 0.0)
    kw = dict(lights=(light,), ambient=0.3)
    frame, _, _, sim = render(plain, rgba=(0.8, 0.3, 0.2, 1.0), **kw)
    assert _chromaticity_spread(frame, sim) < 0.01
    frame, _, _, sim = render(textured_cube, **kw)
    assert _chromaticity_spread(frame, sim) > 0.05


def test_export_then_load_keeps_appearance(tmp_path, textured_cube):
    ply = tmp_path / "colours.ply"
    write_vertex_colour_ply(ply)
    (coloured,) = load_object_set(ply, units="m")
    objects = ObjectSet([textured_cube], "tex")
    write_bop_models(objects, tmp_path / "models")
    assert (tmp_path / "models" / "obj_000001.png").is_file()
    (back,) = load_object_set(tmp_path / "models")
    assert back.appearance.kind == "texture"
    np.testing.assert_array_equal(back.appearance.texture, textured_cube.appearance.texture)
    assert_checker_rendered(back)

    write_bop_models(ObjectSet([coloured], "col"), tmp_path / "models2")
    (back2,) = load_object_set(tmp_path / "models2")
    assert back2.appearance.kind == "vertex"
    order = np.lexsort(coloured.vertices.T[::-1])
    order2 = np.lexsort(back2.vertices.T[::-1])
    np.testing.assert_array_equal(back2.appearance.vertex_colors[order2], coloured.appearance.vertex_colors[order])


def test_colour_randomization_tints_a_textured_object(textured_cube, tmp_path):
    rng = np.random.default_rng(3)
    tints = np.array([object_colour(textured_cube, 0.15, 0.15, rng)[:3] for _ in range(200)])
    lowest = (1 - 0.15) * (1 - 0.15 / 2)  # darkest brightness times the most saturated channel
    assert tints.min() >= lowest - 1e-9 and tints.max() <= 1.0  # mild, around its own (white) material colour
    assert np.ptp(tints, axis=0).max() > 0.05  # but it does vary
    cfg = GenerateConfig().replace(**{"scene.objects_per_scene": [2, 2], "scene.distractors": [0, 0]})
    spec = sample_scene_spec(cfg, ObjectSet([textured_cube], "tex"), np.random.default_rng(0), 0)
    for p in spec.objects:
        assert min(p.rgba[:3]) >= lowest - 1e-9
    # a texture tinted stays the texture: the same cells, darker by at most the tint
    frame, camera, centre, _ = render(textured_cube, rgba=(0.9, 0.9, 0.9, 1.0))
    pts, expected = top_cell_centres(centre)
    np.testing.assert_allclose(pixels_at(frame, camera, pts), 0.9 * expected, atol=12)


def test_colours_per_face_survive_merging_and_export(tmp_path):
    faces = np.array([f for q in _QUADS for f in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    face_rgb = np.repeat(CORNER_COLOURS[:6], 2, axis=0)  # one colour per cube side
    split = trimesh.Trimesh(_CORNERS[faces.reshape(-1)], np.arange(36).reshape(-1, 3),
                            vertex_colors=np.repeat(face_rgb, 3, axis=0), process=False)
    split.export(tmp_path / "sides.ply")
    (obj,) = load_object_set(tmp_path / "sides.ply", units="m")
    assert obj.is_watertight and obj.appearance.kind == "face"
    np.testing.assert_array_equal(obj.appearance.face_colors, face_rgb)
    write_bop_models(ObjectSet([obj], "sides"), tmp_path / "models")
    (back,) = load_object_set(tmp_path / "models")
    np.testing.assert_array_equal(back.appearance.face_colors, face_rgb)
    frame, camera, centre, _ = render(back)
    top = 0  # the first quad is the top face (+z)
    got = pixels_at(frame, camera, centre + back.mesh.triangles_center[[2 * top, 2 * top + 1]])
    np.testing.assert_allclose(got, face_rgb[[0, 1]], atol=8)


def test_textures_leave_masks_and_depth_unchanged(textured_cube):
    import dataclasses

    plain = dataclasses.replace(textured_cube, appearance=None)
    textured, _, _, _ = render(textured_cube)
    untextured, _, _, _ = render(plain)
    np.testing.assert_array_equal(textured.seg, untextured.seg)
    np.testing.assert_array_equal(textured.depth, untextured.depth)
    assert not np.array_equal(textured.rgb, untextured.rgb)


def test_preview_of_every_object_in_a_folder(tmp_path):
    from simtest.cli import main

    write_textured_cube(tmp_path)
    write_vertex_colour_ply(tmp_path / "colours.ply")
    out = tmp_path / "preview.png"
    assert main(["objects", "preview", "all", "--set", str(tmp_path), "--units", "m", "--views", "2",
                 "--size", "32", "--out", str(out), "--quiet"]) == 0
    image = np.asarray(Image.open(out))
    assert image.shape == (64, 64, 3)
    assert np.ptp(image[:32].reshape(-1, 3), axis=0).max() > 50  # the vertex colours show


def test_pbr_profile_renders_the_texture_where_the_uvs_put_it(textured_cube):
    """The path tracer reads the mesh's texture coordinates: every checker cell of the top face shows its hue."""
    if importlib.util.find_spec("mitsuba") is None:  # not imported here: simtest picks the libLLVM first
        pytest.skip("the pbr extra (mitsuba) is not installed")
    pytest.importorskip("pyoidn")
    from simtest.render.pbr import PbrRenderer

    _, camera, centre, sim = render(textured_cube)
    rgb = PbrRenderer(sim.model, camera, spp=16, denoise=True).render(sim.data, sim.camera_id).rgb
    pts, expected = top_cell_centres(centre)
    uv, _ = camera.project_world(pts)
    px = np.rint(uv).astype(int)
    got = rgb[px[:, 1], px[:, 0]]

    def hue(colours) -> np.ndarray:
        return np.array([colorsys.rgb_to_hsv(*(np.asarray(c, float) / 255.0))[0] for c in colours])

    d = np.abs(hue(got) - hue(expected))
    assert np.minimum(d, 1.0 - d).max() < 0.03  # cells are 1/16 of the hue circle apart
