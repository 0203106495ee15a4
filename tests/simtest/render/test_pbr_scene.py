"""The path tracer draws what MuJoCo draws: planes at their surface, material maps, emissive panels and
environment maps (small real renders)."""

from __future__ import annotations

import numpy as np
import pytest

import simtest  # noqa: F401
import mujoco

from simtest.camera import CameraModel, look_at_pose

pytest.importorskip("mitsuba")
pytest.importorskip("pyoidn")

W, H = 64, 48


def _scene(extra: str = "", light: bool = True) -> tuple[mujoco.MjModel, mujoco.MjData, CameraModel]:
    lights = '<light pos="0 0 2" dir="0 0 -1" diffuse="0.8 0.8 0.8"/>' if light else ""
    xml = f"""<mujoco><visual><headlight ambient="0.3 0.3 0.3" diffuse="0 0 0" specular="0 0 0"/></visual>
      <worldbody>{lights}
        <geom name="floor" type="plane" size="1 1 0.1" rgba="0.2 0.2 0.8 1"/>
        <geom name="box" type="box" size="0.02 0.02 0.02" pos="0 0 0.02" rgba="0.9 0.1 0.1 1"/>{extra}
        <camera name="cam" pos="0 0 0.5"/>
      </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cam = CameraModel(np.array([[60.0, 0, (W - 1) / 2], [0, 60.0, (H - 1) / 2], [0, 0, 1]]), W, H,
                      look_at_pose([0.0, 0.0, 0.5], [0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0]))
    cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "cam")
    pos, R = cam.mujoco_pose()
    data.cam_xpos[cid], data.cam_xmat[cid] = pos, R.reshape(-1)
    return model, data, cam


def test_a_box_resting_on_a_plane_is_seen_above_the_plane():
    """A plane's surface is z = 0 of its frame (its third size is MuJoCo's grid spacing, not a height): a 4 cm
    box standing on it shows its red top, not the plane drawn over it."""
    from simtest.render.pbr import PbrRenderer

    model, data, cam = _scene()
    rgb = PbrRenderer(model, cam, spp=4).render(data, "cam").rgb.astype(int)
    centre, corner = rgb[H // 2 - 2:H // 2 + 2, W // 2 - 2:W // 2 + 2].mean((0, 1)), rgb[:4, :4].mean((0, 1))
    assert centre[0] > centre[2] + 60, centre  # red box
    assert corner[2] > corner[0] + 30, corner  # blue floor


def test_an_environment_map_lights_the_scene_from_its_direction():
    """The map's convention (z up, row 0 the zenith, azimuth from +x toward +y) reaches the path tracer: a map
    bright only toward +x (near the horizon) lights the +x side of a sphere, and one bright toward +y its +y side;
    a map without light leaves the scene dark; a map that is not (H, 2H, 3) is refused."""
    from simtest.render.pbr import PbrRenderer

    sphere = '<geom name="ball" type="sphere" size="0.05" pos="0 0 0.15" rgba="0.8 0.8 0.8 1"/>'
    model, data, cam = _scene(sphere, light=False)
    model.vis.headlight.ambient[:] = 0.0

    def side_brightness(column: int) -> dict[str, float]:
        env = np.full((16, 32, 3), 0.01, np.float32)
        env[7:9, column] = 400.0  # theta ~ 90 deg: the horizon; column c: azimuth 2 pi (c + 0.5) / 32
        rgb = PbrRenderer(model, cam, spp=16, environment=(env, 1.0)).render(data, "cam").rgb.astype(float)
        out = {}
        for name, p in (("+x", (0.035, 0.0, 0.15)), ("-x", (-0.035, 0.0, 0.15)), ("+y", (0.0, 0.035, 0.15)),
                        ("-y", (0.0, -0.035, 0.15))):
            uv, _ = cam.project_world(np.array([p]))
            u, v = int(round(float(uv[0, 0]))), int(round(float(uv[0, 1])))
            out[name] = float(rgb[v - 1:v + 2, u - 1:u + 2].mean())
        return out

    toward_x, toward_y = side_brightness(0), side_brightness(8)  # azimuth ~ 0 (+x) and ~ 90 deg (+y)
    assert toward_x["+x"] > toward_x["-x"] + 20, toward_x
    assert toward_y["+y"] > toward_y["-y"] + 20, toward_y
    dark = PbrRenderer(model, cam, spp=4, environment=(np.zeros((16, 32, 3), np.float32), 1.0)).render(data, "cam")
    assert dark.rgb.mean() < 5
    with pytest.raises(Exception, match="H, 2H, 3"):
        PbrRenderer(model, cam, spp=1, environment=(np.zeros((16, 16, 3), np.float32), 1.0))


def test_an_emissive_panel_lights_the_floor():
    from simtest.render.pbr import PbrRenderer

    panel = ('<geom type="box" size="1.5 1.5 0.01" pos="0 0 10" material="glow" contype="0" conaffinity="0"/>')
    xml_asset = '<asset><material name="glow" rgba="0.6 0.6 0.6 1" emission="1"/></asset>'
    _, _, cam = _scene(light=False)
    model2 = mujoco.MjModel.from_xml_string(
        f"""<mujoco><visual><headlight ambient="0 0 0" diffuse="0 0 0" specular="0 0 0"/></visual>{xml_asset}
        <worldbody><geom type="plane" size="1 1 0.1" rgba="1 1 1 1"/>{panel}<camera name="cam" pos="0 0 0.5"/>
        </worldbody></mujoco>""")
    data2 = mujoco.MjData(model2)
    mujoco.mj_forward(model2, data2)
    cid = mujoco.mj_name2id(model2, mujoco.mjtObj.mjOBJ_CAMERA, "cam")
    pos, R = cam.mujoco_pose()
    data2.cam_xpos[cid], data2.cam_xmat[cid] = pos, R.reshape(-1)
    model2.stat.center[:] = 0.0
    grey = PbrRenderer(model2, cam, spp=8).render(data2, "cam").rgb.astype(float).mean()
    # calibrated so a white floor under the panel shows the panel's display value (0.6 -> ~153)
    assert 120 < grey < 185, grey
