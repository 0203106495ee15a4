"""Lights for the path tracer: MuJoCo's lights and ambient term as Mitsuba emitters (radiometric units as in
:mod:`simtest.render.pbr`: MuJoCo's display-referred colours linearized, calibrated at ``model.stat.center``)."""

from __future__ import annotations

from typing import Any

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.render.colour import srgb_to_linear
from simtest.render.pbr_shapes import transform

__all__ = ["emitters", "spot", "panel", "LIGHT_RADIUS", "SPOT_SAMPLES"]

#: Radius of the light source that stands in for each MuJoCo spot / point light (metres).
LIGHT_RADIUS = 0.08
#: Point spots that stand in for each MuJoCo spot light, spread over a disk of radius LIGHT_RADIUS.
SPOT_SAMPLES = 8


def emitters(mi, m: mujoco.MjModel, data: mujoco.MjData) -> dict:
    """The constant environment (MuJoCo's ambient; key ``"environment"``) and the emitters of every active light.

    MuJoCo's light colours, like its material colours, are display (sRGB) values: they are linearized, so
    a surface lit by them keeps about the brightness the rasterizer gives it. Each light is calibrated at
    its distance ``d`` to ``model.stat.center``: there its irradiance is ``pi D`` (D the linearized
    ``diffuse``), so a white Lambertian surface facing it reflects radiance ``D``, as MuJoCo's unattenuated
    light does. A spot light becomes ``SPOT_SAMPLES`` spots spread over a disk of radius ``LIGHT_RADIUS``
    across its axis (soft shadows) with MuJoCo's cutoff and a beam width where ``cos^exponent`` halves; a
    point light becomes a sphere of that radius; a directional light stays directional.
    """
    ambient = np.asarray(m.vis.headlight.ambient, dtype=np.float64).copy()
    out: dict[str, Any] = {}
    centre = np.asarray(m.stat.center, dtype=np.float64)
    for i in range(m.nlight):
        if not m.light_active[i]:
            continue
        ambient += m.light_ambient[i]
        diffuse = srgb_to_linear(m.light_diffuse[i])
        pos = np.asarray(data.light_xpos[i], dtype=np.float64)
        axis = np.asarray(data.light_xdir[i], dtype=np.float64)
        d2 = max(float(np.sum((pos - centre) ** 2)), LIGHT_RADIUS ** 2)
        kind = int(m.light_type[i])
        if kind == int(mujoco.mjtLightType.mjLIGHT_DIRECTIONAL):
            out[f"light_{i}"] = {"type": "directional", "direction": axis.tolist(),
                                 "irradiance": {"type": "rgb", "value": (np.pi * diffuse).tolist()}}
        elif kind == int(mujoco.mjtLightType.mjLIGHT_SPOT):
            out.update(spot(mi, m, i, pos, axis, np.pi * diffuse * d2))
        else:
            out[f"light_{i}"] = {"type": "sphere", "center": pos.tolist(), "radius": LIGHT_RADIUS,
                                 "emitter": {"type": "area", "radiance": {
                                     "type": "rgb", "value": (diffuse * d2 / LIGHT_RADIUS ** 2).tolist()}}}
    out["environment"] = {"type": "constant",
                          "radiance": {"type": "rgb", "value": srgb_to_linear(ambient).tolist()}}
    return out


def spot(mi, m: mujoco.MjModel, i: int, pos: np.ndarray, axis: np.ndarray, intensity: np.ndarray) -> dict:
    """Light ``i`` as ``SPOT_SAMPLES`` Mitsuba spots (total on-axis ``intensity``, W/sr) on a Vogel disk."""
    cutoff = float(np.clip(m.light_cutoff[i], 1.0, 89.0))
    exponent = float(m.light_exponent[i])
    half = float(np.degrees(np.arccos(0.5 ** (1.0 / exponent)))) if exponent > 0 else cutoff
    beam = min(half, 0.95 * cutoff)
    axis = axis / max(np.linalg.norm(axis), 1e-12)
    u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    out = {}
    for k in range(SPOT_SAMPLES):
        r = LIGHT_RADIUS * np.sqrt((k + 0.5) / SPOT_SAMPLES)
        a = k * np.pi * (3.0 - np.sqrt(5.0))  # golden angle
        p = pos + r * (np.cos(a) * u + np.sin(a) * v)
        out[f"light_{i}_{k}"] = {
            "type": "spot", "cutoff_angle": cutoff, "beam_width": beam,
            "to_world": mi.ScalarTransform4f().look_at(origin=p.tolist(), target=(p + axis).tolist(),
                                                             up=u.tolist()),
            "intensity": {"type": "rgb", "value": (intensity / SPOT_SAMPLES).tolist()}}
    return out


def panel(mi, m: mujoco.MjModel, data: mujoco.MjData, g: int, display: np.ndarray) -> dict:
    """An emissive box geom ``g`` (a ceiling panel) as a one-sided area light facing down from its bottom face,
    calibrated like the lights: at ``model.stat.center`` its irradiance is ``pi`` times the linearized
    ``rgba x emission`` (a white Lambertian floor there shows that display value)."""
    R, t = data.geom_xmat[g].reshape(3, 3).astype(np.float64), data.geom_xpos[g].astype(np.float64)
    half = m.geom_size[g].astype(np.float64)
    bottom = t - R[:, 2] * half[2]
    offset = bottom - np.asarray(m.stat.center, dtype=np.float64)
    d2 = max(float(offset @ offset), 1e-6)
    cos = abs(float(offset[2])) / np.sqrt(d2)
    solid = 4.0 * half[0] * half[1] * cos * cos / d2  # projected solid angle, small-source approximation
    radiance = np.pi * srgb_to_linear(np.clip(display, 0.0, 1.0)) / max(solid, 1e-9)
    return {"type": "rectangle", "to_world": transform(mi, R @ np.diag([1.0, -1.0, -1.0]), bottom,
                                                       np.array([half[0], half[1], 1.0])),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": radiance.tolist()}},
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}}
