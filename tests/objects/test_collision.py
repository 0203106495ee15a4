"""Collision parts: convex hulls for convex objects, CoACD parts (cached on disk) for concave ones, also when
the mesh is not watertight; grasp candidates stay out of them."""

from __future__ import annotations

import logging
import re

import numpy as np
import pytest
import trimesh

from simtest.objects import GraspSet, load_object_set
from simtest.objects.builtin import build_object
from simtest.objects.collision import enclosed_volume, open_mesh_is_concave
from simtest.objects.grasps import PANDA, gripper_boxes, penetrating


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


# --- meshes that are not watertight ----------------------------------------------------------------------------

MUG_RADIUS, MUG_HEIGHT, MUG_WALL = 0.04, 0.09, 0.005
HANDLE_REACH, HANDLE_HALF_SPAN, HANDLE_RADIUS = 0.028, 0.03, 0.0055


def open_handled_mug() -> trimesh.Trimesh:
    """A mug as meshes often ship: an open-topped cylindrical shell with 5 mm walls (8 cm across, too wide
    for the gripper: it must be taken by the rim or the handle), and a handle that is an open tube (no end
    caps) pushed through the wall. The handle is not closed, so the mesh is not watertight."""
    r, h, w = MUG_RADIUS, MUG_HEIGHT, MUG_WALL
    body = trimesh.creation.revolve(np.array([(0, 0), (r, 0), (r, h), (r - w, h), (r - w, 0.007), (0, 0.007)]),
                                    sections=48)
    th = np.linspace(np.pi / 2, -np.pi / 2, 25)
    centres = np.stack([MUG_RADIUS - 0.006 + HANDLE_REACH * np.cos(th), np.zeros_like(th),
                        MUG_HEIGHT / 2 + HANDLE_HALF_SPAN * np.sin(th)], axis=1)
    tangents = np.gradient(centres, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    binormal = np.array([0.0, 1.0, 0.0])
    normals = np.cross(binormal, tangents)
    sides = 12
    phi = 2 * np.pi * np.arange(sides) / sides
    rings = centres[:, None] + HANDLE_RADIUS * (np.cos(phi)[None, :, None] * normals[:, None]
                                                + np.sin(phi)[None, :, None] * binormal)
    faces = []
    for i in range(len(th) - 1):
        for j in range(sides):
            a, b = i * sides + j, i * sides + (j + 1) % sides
            faces += [[a, a + sides, b], [b, a + sides, b + sides]]
    handle = trimesh.Trimesh(rings.reshape(-1, 3), np.array(faces))
    trimesh.repair.fix_normals(handle)
    return trimesh.util.concatenate([body, handle])


@pytest.fixture(scope="module")
def mug_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("open_mug")
    mesh = open_handled_mug()
    assert not mesh.is_watertight
    mesh.export(folder / "mug.obj")
    return folder


class _Records(logging.Handler):
    """Keeps the log records it is handed (a module-scoped fixture cannot use ``caplog``)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.fixture(scope="module")
def open_mug(mug_folder):
    logger, handler = logging.getLogger("simtest"), _Records()
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING)
    try:
        (mug,) = load_object_set(mug_folder)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    (line,) = [r.getMessage() for r in handler.records if r.name == "simtest.objects.loaders"]
    assert re.search(r"mug\.obj: mesh is not watertight \(\d+ open edges\).*convex decomposition of a watertight "
                     r"remesh.*grasp candidates", line), line
    assert "\n" not in line
    return mug


def test_enclosed_volume_of_closed_and_open_surfaces():
    box = trimesh.creation.box([0.05, 0.1, 0.2])
    assert box.volume <= enclosed_volume(box) < 1.25 * box.volume  # voxels overestimate by about one layer
    shell = open_handled_mug()
    assert enclosed_volume(shell) < 0.5 * shell.convex_hull.volume  # the cavity stays empty
    assert open_mesh_is_concave(shell) and not open_mesh_is_concave(box)


def test_open_mug_is_decomposed(open_mug):
    assert open_mug.is_concave and not open_mug.is_watertight
    parts = open_mug.collision_parts
    assert 4 <= len(parts) <= 16 and all(p.is_convex for p in parts)
    assert sum(p.volume for p in parts) < 0.5 * open_mug.mesh.convex_hull.volume
    # model frame: the bbox centre is the origin; the body axis and the handle loop's middle stay free
    offset = np.asarray(open_mug.extra["origin_offset"])
    axis = np.array([[0.0, 0.0, z] for z in (0.02, 0.045, 0.07)]) - offset
    loop = np.array([[MUG_RADIUS + 0.5 * (HANDLE_REACH - 0.006), 0.0, MUG_HEIGHT / 2]]) - offset
    cavity = np.array([[MUG_RADIUS - MUG_WALL - 0.008, 0.0, 0.05]]) - offset  # inside, near the wall
    for p in parts:
        assert not p.contains(axis).any() and not p.contains(loop).any() and not p.contains(cavity).any()
    # the parts cover the surface: nearly every surface sample is within 4 mm of a part
    pts = open_mug.surface_points[::8]
    dist = np.min([np.abs(trimesh.proximity.signed_distance(p, pts)) * ~p.contains(pts) for p in parts], axis=0)
    assert np.mean(dist < 0.004) > 0.97


def test_no_grasp_candidate_penetrates_collision_parts(open_mug):
    grasps = open_mug.grasps
    assert len(grasps) >= 20 and open_mug.graspable
    assert not penetrating(grasps, open_mug.collision_parts).any()
    # an independent check: points of the open fingers and the palm lie in no part (trimesh containment)
    for k in range(0, len(grasps), 5):
        boxes = gripper_boxes(float(PANDA.open_width(grasps.widths[k])))
        T = grasps.poses[k]
        for lo, hi in boxes:
            grid = np.stack(np.meshgrid(*[np.linspace(lo[i] + 0.0015, hi[i] - 0.0015, 4) for i in range(3)],
                                        indexing="ij"), axis=-1).reshape(-1, 3)
            world = grid @ T[:3, :3].T + T[:3, 3]
            assert not any(p.contains(world).any() for p in open_mug.collision_parts), k


def test_penetrating_flags_a_gripper_inside_a_part():
    part = trimesh.creation.box([0.04, 0.04, 0.04])
    pose = np.eye(4)
    outside = np.eye(4)
    outside[:3, 3] = [0.0, 0.0, -0.2]  # far below the box
    grasps = GraspSet(np.stack([pose, outside]), np.array([0.04, 0.04]), np.array([0.5, 0.5]))
    # the first one's fingers close on the box's faces: open, they stand clear of it; the second is far away
    assert not penetrating(grasps, [part]).any()
    narrow = GraspSet(np.stack([pose]), np.array([0.02]), np.array([0.5]))  # fingers would be inside the box
    assert penetrating(narrow, [part]).all()


@pytest.mark.slow
def test_oracle_grasps_the_open_mug(mug_folder):
    from simtest.envs.runner import GraspRunConfig, run_grasp_episodes

    cfg = GraspRunConfig(estimator="oracle", objects=str(mug_folder), episodes=3, width=64, height=48)
    report = run_grasp_episodes(cfg, progress=False)
    assert report.summary["successes"] >= 2, report.rows
