"""``SceneBuilder``: the only code that turns a :class:`SceneSpec` into a MuJoCo model, through ``MjSpec``.

Each object instance is a free body whose frame *is* the object's model frame (BOP convention); its visual
mesh (geom group 1) is drawn and segmented, its convex collision parts (group 3, never drawn) collide.
Distractors and the room (floor, walls, table or bin) are in group 0 / 2.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.camera import CameraModel
from simtest.errors import AssetError, ConfigError
from simtest.generators.build_options import N_OCCLUDERS, BuildOptions
from simtest.generators.looks import environment_of, material_maps, skin_of
from simtest.generators.scene_spec import SceneSpec, SurfaceSpec
from simtest.objects import ObjectModel, ObjectSet
from simtest.objects.appearance import add_object_visual, texture_roles

__all__ = ["SimScene", "SceneState", "SceneBuilder", "LightValue", "texture_pixels", "library_values", "skin_values",
           "VISUAL_GROUP", "COLLISION_GROUP", "DRAWN_GROUPS", "CAMERA_NAME"]

VISUAL_GROUP = 1
COLLISION_GROUP = 3
DRAWN_GROUPS = (0, 1, 2)
CAMERA_NAME = "render_cam"
#: Height of the ceiling panel above the floor (metres).
CEILING_HEIGHT = 10.0
#: Contact parameters of object collision geoms: sliding, torsional, rolling friction.
OBJECT_FRICTION = (0.9, 0.005, 0.002)


@dataclass
class SimScene:
    """A compiled scene and the maps from MuJoCo ids to object instances.

    Attributes:
        model, data: MuJoCo model and data.
        spec: The scene description it was built from.
        instance_obj_ids: obj_id of each instance (index = instance index, order of ``spec.objects``).
        instance_bodies: Body id of each instance.
        instance_qpos: qpos address of each instance's free joint (7 values: position, quat w x y z).
        instance_dofs: dof address of each instance's free joint (6 values).
        geom_instance: (ngeom,) instance index of each geom, -1 for geoms that are not annotated objects.
        camera_id: Id of the render camera (moved per view).
        active: Instances still on the table (fallen ones are moved away and excluded).
        panda: :mod:`simtest.robot` handles when the arm is in the scene.
        rng: The scene's random stream after sampling its spec; views, wrist configurations and occluder
            levels continue it (``None`` when the scene was built without one).
        camera: The render camera its builder made (intrinsics, image size; posed per view), the one camera
            object of the scene.
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    spec: SceneSpec
    instance_obj_ids: list[int]
    instance_bodies: list[int]
    instance_qpos: list[int]
    instance_dofs: list[int]
    geom_instance: np.ndarray
    camera_id: int
    active: list[bool] = field(default_factory=list)
    panda: object | None = None
    rng: np.random.Generator | None = None
    camera: CameraModel | None = None

    def object_pose_world(self, instance: int) -> tuple[np.ndarray, np.ndarray]:
        """(R (3x3), t (3,) metres) of an instance's model frame in the world."""
        b = self.instance_bodies[instance]
        return self.data.xmat[b].reshape(3, 3).copy(), self.data.xpos[b].copy()

    def state(self) -> "SceneState":
        """What annotation reads of the scene now (instance poses, which are active), kept apart from the
        simulation: it stays as it is while the scene moves on (occluders, the arm, the next view)."""
        return SceneState(tuple(self.instance_obj_ids), tuple(self.active), self.geom_instance,
                          tuple(self.object_pose_world(i) for i in range(len(self.instance_obj_ids))),
                          self.data.geom_xpos.copy(), self.data.geom_xmat.copy())

    def set_arm(self, q: np.ndarray) -> None:
        """Put the Panda (if present) at joint configuration ``q`` (rad) and update kinematics."""
        from simtest.robot import reset_arm

        if self.panda is None:
            raise ValueError("this scene has no Panda arm")
        reset_arm(self.model, self.data, self.panda, q)

    def set_camera(self, camera: CameraModel) -> None:
        """Place the render camera at ``camera.T_world_cam`` (takes effect at the next render)."""
        pos, R_mj = camera.mujoco_pose()
        self.data.cam_xpos[self.camera_id] = pos
        self.data.cam_xmat[self.camera_id] = R_mj.reshape(-1)


@dataclass(frozen=True)
class SceneState:
    """The instances of a :class:`SimScene` at one moment (:meth:`SimScene.state`): what a view's annotation
    needs, with the same names as on the scene.

    Attributes:
        instance_obj_ids: obj_id of each instance.
        active: Instances on the table at that moment.
        geom_instance: (ngeom,) instance index of each geom, -1 for geoms that are not annotated objects.
        poses: ``(R (3x3), t (3,) metres)`` of each instance's model frame in the world.
        geom_xpos, geom_xmat: World poses of every geom ((ngeom, 3) metres, (ngeom, 9)) at that moment (what
            the dense channels carry each pixel's surface point with).
    """

    instance_obj_ids: tuple[int, ...]
    active: tuple[bool, ...]
    geom_instance: np.ndarray
    poses: tuple[tuple[np.ndarray, np.ndarray], ...]
    geom_xpos: np.ndarray | None = None
    geom_xmat: np.ndarray | None = None

    def object_pose_world(self, instance: int) -> tuple[np.ndarray, np.ndarray]:
        """(R (3x3), t (3,) metres) of an instance's model frame in the world at that moment."""
        return self.poses[instance]


class SceneBuilder:
    """Builds MuJoCo scenes for one object set with one set of building options.

    Args:
        objects: The object set (meshes, collision parts, inertia).
        options: What building needs (camera, room, timestep, render quality, Panda, occluder slots); a
            dataset makes them from its config (its ``build_options()``; a config given here is converted so,
            with a DeprecationWarning).
        panda_physics: When the Panda is in the scene, also apply its tuned contact physics
            (:func:`simtest.robot.configure_physics`: 2 ms implicitfast steps, elliptic friction cones,
            impratio 10), which grasping needs. Off by default: generation keeps its own physics options.

    Raises:
        ConfigError: If ``options`` is neither :class:`BuildOptions` nor a config that makes them.
    """

    def __init__(self, objects: ObjectSet, options: BuildOptions, *, panda_physics: bool = False) -> None:
        self.objects = objects
        self.options = _build_options(options)
        self.panda_physics = bool(panda_physics)

    @property
    def camera(self) -> CameraModel:
        """The render camera (intrinsics, image size) of every scene this builder makes."""
        return self.options.camera

    # ------------------------------------------------------------------------------------------------------
    def build(self, spec: SceneSpec, rng: np.random.Generator | None = None) -> SimScene:
        """Compile ``spec`` into a :class:`SimScene`; ``rng`` (the stream the spec was sampled from) is kept as
        the scene's ``rng``."""
        opt, room = self.options, self.options.room
        ms = mujoco.MjSpec()
        ms.modelname = f"scene_{spec.scene_index:06d}"
        ms.option.timestep = opt.timestep
        ms.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        ms.option.noslip_iterations = 0
        ms.stat.extent = 2.0
        ms.stat.center = [0.0, 0.0, room.table_height]
        ms.visual.map.znear = 0.005  # x extent: 1 cm near plane
        ms.visual.map.zfar = 5.0  # x extent: 10 m far plane
        ms.visual.global_.offwidth = max(opt.camera.width, 64)
        ms.visual.global_.offheight = max(opt.camera.height, 64)
        ms.visual.quality.offsamples = 4 if opt.quality == "quality" else 0
        ms.visual.quality.shadowsize = 2048 if opt.quality == "quality" else 0
        ms.visual.headlight.diffuse = [0.0, 0.0, 0.0]
        ms.visual.headlight.specular = [0.0, 0.0, 0.0]

        self._room(ms, spec)
        self._lights(ms, spec)

        # Object assets, one per distinct obj_id (shared by instances); textured ones get their texture.
        textures = {oid: self._mesh_assets(ms, self.objects.get(oid))
                    for oid in sorted({p.obj_id for p in spec.objects})}

        bodies = []
        for i, p in enumerate(spec.objects):
            obj = self.objects.get(p.obj_id)
            mat = ms.add_material(name=f"obj_{i}_mat", rgba=list(p.rgba), specular=p.specular,
                                  shininess=p.shininess, reflectance=p.reflectance)
            skinned = skin_of(obj, p.skin_seed) if textures[p.obj_id] is not None else None
            if skinned is not None:  # this instance's variant of the object's print, on the object's UVs
                self._skin_material(ms, mat, f"obj_{i}", skinned)
            elif textures[p.obj_id] is not None and not p.plain:  # the texture times the material colour (a tint)
                mat.textures = texture_roles(textures[p.obj_id])
            bodies.append(_object_body(ms, f"obj_{i}", obj, f"mesh_{p.obj_id}", p.position, p.quat_wxyz,
                                       VISUAL_GROUP))

        for j, d in enumerate(spec.distractors):
            b = ms.worldbody.add_body(name=f"distractor_{j}", pos=list(d.position), quat=list(d.quat_wxyz))
            b.add_freejoint()
            gtype = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
                     "sphere": mujoco.mjtGeom.mjGEOM_SPHERE, "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE}[d.shape]
            textured = {} if d.image is None and d.material is None else {"material": self._texture_material(
                ms, f"distractor_{j}", SurfaceSpec("flat", (1.0,) * 3, (1.0,) * 3, 1.0, 0.0, d.image, d.material),
                1.0)}
            rgba = list(d.rgba) if not textured else [1.0, 1.0, 1.0, 1.0]  # images are not tinted
            b.add_geom(name=f"distractor_{j}_geom", type=gtype, size=list(d.size), rgba=rgba, density=400,
                       friction=list(OBJECT_FRICTION), condim=6, group=0, **textured)

        self._distractor_objects(ms, spec)

        for k in range(opt.occluder_slots):
            body = ms.worldbody.add_body(name=f"occluder_{k}", mocap=True, pos=[500.0, 600.0 + k, -500.0])
            mat = self._texture_material(ms, f"occluder_{k}", spec.walls, 4.0)
            body.add_geom(name=f"occluder_{k}_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.05, 0.05],
                          material=mat, group=0, contype=0, conaffinity=0)

        ms.worldbody.add_camera(name=CAMERA_NAME, pos=[0, 0, 1], **self.camera.mujoco_intrinsics())

        panda = None
        if opt.panda:
            from simtest.robot import attach_panda
            from simtest.geometry import Pose

            panda = attach_panda(ms, base_pose=Pose(np.eye(3), [-room.table_size[0] / 2 - 0.1, 0.0,
                                                               room.table_height]),
                                 wrist_camera=self.camera, physics=self.panda_physics)

        model = ms.compile()
        data = mujoco.MjData(model)
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"obj_{i}") for i in range(len(spec.objects))]
        geom_instance = np.full(model.ngeom, -1, dtype=np.int32)
        for i, b in enumerate(ids):
            geom_instance[model.body_geomadr[b]:model.body_geomadr[b] + model.body_geomnum[b]] = i
        qpos = [int(model.jnt_qposadr[model.body_jntadr[b]]) for b in ids]
        dofs = [int(model.jnt_dofadr[model.body_jntadr[b]]) for b in ids]
        cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_NAME)
        if panda is not None:
            from simtest.robot import reset_arm

            panda = panda.bind(model)
            reset_arm(model, data, panda)
        mujoco.mj_forward(model, data)
        return SimScene(model, data, spec, [p.obj_id for p in spec.objects], ids, qpos, dofs, geom_instance, cam_id,
                        [True] * len(spec.objects), panda, rng, self.camera)

    # ------------------------------------------------------------------------------------------------------
    def _lights(self, ms: mujoco.MjSpec, spec: SceneSpec) -> None:
        """Add the scene's lights and set its ambient term (:meth:`light_values`)."""
        ambient, lights = self.light_values(spec)
        ms.visual.headlight.ambient = ambient
        shadows = self.options.quality == "quality"
        for light in lights:
            ms.worldbody.add_light(name=light.name, type=light.type, pos=light.position, dir=light.direction,
                                   diffuse=light.diffuse, specular=light.specular, castshadow=shadows)

    def light_values(self, spec: SceneSpec) -> tuple[list[float], list["LightValue"]]:
        """The scene's ambient term (RGB) and lights, in the order they are added. With an environment, the pbr
        profile takes its light from the environment map alone (no MuJoCo light); the other profiles
        approximate the map by its dominant directions as directional lights and the rest as ambient
        (:func:`simtest.materials.light_summary`). A ceiling panel lights the rasterized profiles as a
        directional light straight down. Positions in metres, world frame; directions as given (MuJoCo normalises
        them when compiling)."""
        from simtest.render.colour import linear_to_srgb

        pbr = self.options.quality == "pbr"
        spot, directional = mujoco.mjtLightType.mjLIGHT_SPOT, mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
        lights: list[LightValue] = []
        if spec.environment is None:
            ambient = [float(spec.ambient)] * 3
            for i, light in enumerate(spec.lights):
                lights.append(LightValue(f"light_{i}", spot, list(light.position), list(light.direction),
                                         list(light.diffuse), [light.specular] * 3))
        elif pbr:
            ambient = [0.0, 0.0, 0.0]
        else:
            from simtest.materials import light_summary

            summary, dominant = light_summary(environment_of(spec.environment))
            k = spec.environment.strength
            ambient = np.clip(linear_to_srgb(np.asarray(summary) * k), 0, 1).tolist()
            for i, (toward, irradiance) in enumerate(dominant):
                lights.append(LightValue(
                    f"env_light_{i}", directional, (np.asarray(toward) * 3.0).tolist(),
                    (-np.asarray(toward)).tolist(),
                    np.clip(linear_to_srgb(np.asarray(irradiance) * k / np.pi), 0, 1).tolist(), [0.3] * 3))
        if spec.ceiling is not None and not pbr:
            lights.append(LightValue("ceiling_light", directional, [0.0, 0.0, CEILING_HEIGHT], [0.0, 0.0, -1.0],
                                     list(spec.ceiling), [0.1] * 3))
        return ambient, lights

    def _add_map(self, ms: mujoco.MjSpec, name: str, image: np.ndarray) -> str:
        """Add a 2D texture ``name`` from an (H, W) or (H, W, C) uint8 image (row 0 at the top), stored as
        :func:`texture_pixels` gives it."""
        pixels = texture_pixels(image)
        ms.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, width=pixels.shape[1],
                       height=pixels.shape[0], nchannel=pixels.shape[2]).data = pixels.tobytes()
        return name

    def _pbr_roles(self, ms: mujoco.MjSpec, name: str, rgb: str, roughness=None, normal=None,
                   metallic=None) -> list[str]:
        """A material's texture roles: the colour always; roughness, normal and metallic maps only for the pbr
        profile (the rasterizer draws the colour alone, so the other profiles do not upload them)."""
        roles = [""] * int(mujoco.mjtTextureRole.mjNTEXROLE)
        roles[int(mujoco.mjtTextureRole.mjTEXROLE_RGB)] = rgb
        if self.options.quality == "pbr":
            for role, image, suffix in ((mujoco.mjtTextureRole.mjTEXROLE_ROUGHNESS, roughness, "rough"),
                                        (mujoco.mjtTextureRole.mjTEXROLE_NORMAL, normal, "normal"),
                                        (mujoco.mjtTextureRole.mjTEXROLE_METALLIC, metallic, "metal")):
                if image is not None:
                    roles[int(role)] = self._add_map(ms, f"{name}_{suffix}", image)
        return roles

    def _library_material(self, ms: mujoco.MjSpec, name: str, s: SurfaceSpec, size: float) -> str:
        """Material ``{name}_mat`` of a library material (:func:`simtest.generators.looks.surface_maps`)."""
        maps = material_maps(s.material, self.options.material_folder, self.options.texture_size)
        self._add_map(ms, f"{name}_tex", maps.albedo)
        mat = ms.add_material(name=f"{name}_mat", texrepeat=[s.repeat * size, s.repeat * size], texuniform=False,
                              **library_values(maps))
        mat.textures = self._pbr_roles(ms, name, f"{name}_tex", maps.roughness, maps.normal)
        return f"{name}_mat"

    def _skin_material(self, ms: mujoco.MjSpec, mat, name: str, skin) -> None:
        """Show an instance's print ``skin`` (:class:`simtest.objects.skins.Skin`) on material ``mat``."""
        self._add_map(ms, f"{name}_skin", skin.albedo)
        mat.textures = self._pbr_roles(ms, f"{name}_skin", f"{name}_skin", skin.roughness, None, skin.metallic)
        for key, value in skin_values(skin).items():
            setattr(mat, key, value)

    def _distractor_objects(self, ms: mujoco.MjSpec, spec: SceneSpec) -> None:
        """The scene's distractor objects (:mod:`simtest.generators.distractor_objects`): free bodies whose
        visual mesh is drawn in group 0 (never annotated, an occluder to the masks) and whose convex parts
        collide like a target's."""
        if not spec.distractor_objects:
            return
        from simtest.generators.distractor_objects import distractor_object_set

        if not self.options.distractor_objects:
            raise ConfigError(f"scene {spec.scene_index}: the spec holds {len(spec.distractor_objects)} distractor "
                              "objects but the build options name no set (BuildOptions.distractor_objects)")
        objects = distractor_object_set(self.options.distractor_objects)
        textures = {oid: self._mesh_assets(ms, objects.get(oid), "dmesh")
                    for oid in sorted({d.obj_id for d in spec.distractor_objects})}
        for j, d in enumerate(spec.distractor_objects):
            obj, name = objects.get(d.obj_id), f"dobj_{j}"
            mat = ms.add_material(name=f"{name}_mat", rgba=list(d.rgba), specular=d.specular, shininess=d.shininess)
            skinned = skin_of(obj, d.skin_seed) if textures[d.obj_id] is not None else None
            if skinned is not None:
                self._skin_material(ms, mat, name, skinned)
            elif textures[d.obj_id] is not None:
                mat.textures = texture_roles(textures[d.obj_id])
            _object_body(ms, name, obj, f"dmesh_{d.obj_id}", d.position, d.quat_wxyz, 0)

    # ------------------------------------------------------------------------------------------------------
    def _mesh_assets(self, ms: mujoco.MjSpec, obj: ObjectModel, prefix: str = "mesh") -> str | None:
        """Add the object's visual and collision meshes (``{prefix}_{obj_id}``, ``..._col{k}``); returns the
        name of its texture (None if untextured)."""
        mesh, texture = add_object_visual(ms, obj, f"{prefix}_{obj.obj_id}")
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL  # robust for open meshes; mass: obj
        for k, part in enumerate(obj.collision_parts):
            m = ms.add_mesh(name=f"{prefix}_{obj.obj_id}_col{k}")
            m.uservert = np.asarray(part.vertices, dtype=np.float64).reshape(-1).tolist()
            m.userface = np.asarray(part.faces, dtype=np.int32).reshape(-1).tolist()
            m.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
        return texture

    def _texture_material(self, ms: mujoco.MjSpec, name: str, s: SurfaceSpec, size: float) -> str:
        if s.material is not None:
            return self._library_material(ms, name, s, size)
        if s.image is not None:
            pixels = load_texture_image(s.image)
            ms.add_texture(name=f"{name}_tex", type=mujoco.mjtTexture.mjTEXTURE_2D, width=pixels.shape[1],
                           height=pixels.shape[0], nchannel=3).data = pixels.tobytes()
            return self._material(ms, name, s, size)
        builtin = {"checker": mujoco.mjtBuiltin.mjBUILTIN_CHECKER, "gradient": mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                   "flat": mujoco.mjtBuiltin.mjBUILTIN_FLAT}[s.pattern]
        ms.add_texture(name=f"{name}_tex", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=builtin,
                       rgb1=list(s.rgb1), rgb2=list(s.rgb2), width=128, height=128,
                       mark=mujoco.mjtMark.mjMARK_RANDOM if s.noise > 0 else mujoco.mjtMark.mjMARK_NONE,
                       random=s.noise, markrgb=list(s.rgb2))
        return self._material(ms, name, s, size)

    def _material(self, ms: mujoco.MjSpec, name: str, s: SurfaceSpec, size: float) -> str:
        """Material ``{name}_mat`` showing texture ``{name}_tex`` ``s.repeat * size`` times across a face."""
        mat = ms.add_material(name=f"{name}_mat", texrepeat=[s.repeat * size, s.repeat * size], texuniform=False)
        textures = [""] * int(mujoco.mjtTextureRole.mjNTEXROLE)
        textures[int(mujoco.mjtTextureRole.mjTEXROLE_RGB)] = f"{name}_tex"
        mat.textures = textures
        return f"{name}_mat"

    def _room(self, ms: mujoco.MjSpec, spec: SceneSpec) -> None:
        sc = self.options.room
        r, wh = sc.room_half_size, sc.wall_height
        floor_mat = self._texture_material(ms, "floor", spec.floor, 1.0)
        ms.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[r, r, 0.1],
                              material=floor_mat, group=2, friction=list(OBJECT_FRICTION))
        shared = spec.floor.material is not None and spec.walls == spec.floor  # materials.room_material = "shared"
        wall_mat = floor_mat if shared else self._texture_material(ms, "wall", spec.walls, 1.0)
        for k, (pos, size) in enumerate([([r, 0, wh / 2], [0.05, r, wh / 2]), ([-r, 0, wh / 2], [0.05, r, wh / 2]),
                                          ([0, r, wh / 2], [r, 0.05, wh / 2]), ([0, -r, wh / 2], [r, 0.05, wh / 2])]):
            ms.worldbody.add_geom(name=f"wall_{k}", type=mujoco.mjtGeom.mjGEOM_BOX, pos=pos, size=size,
                                  material=wall_mat, group=2, contype=0, conaffinity=0)
        if spec.ceiling is not None:  # a 3 x 3 m emissive panel 10 m up (BlenderProc's BOP recipe)
            ms.add_material(name="ceiling_mat", rgba=[*spec.ceiling, 1.0], emission=1.0)
            ms.worldbody.add_geom(name="ceiling", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[0.0, 0.0, CEILING_HEIGHT],
                                  size=[1.5, 1.5, 0.01], material="ceiling_mat", group=2, contype=0, conaffinity=0)
        table_mat = self._texture_material(ms, "table", spec.table, 1.0)
        hx, hy = sc.table_size[0] / 2, sc.table_size[1] / 2
        h = sc.table_height
        thick = min(0.04, h / 2) if h > 0 else 0.0
        if h > 0:
            ms.worldbody.add_geom(name="table_top", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[0, 0, h - thick / 2],
                                  size=[hx, hy, thick / 2], material=table_mat, group=2,
                                  friction=list(OBJECT_FRICTION))
            for k, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
                ms.worldbody.add_geom(name=f"table_leg_{k}", type=mujoco.mjtGeom.mjGEOM_BOX,
                                      pos=[sx * (hx - 0.03), sy * (hy - 0.03), (h - thick) / 2],
                                      size=[0.02, 0.02, (h - thick) / 2], material=table_mat, group=2)
        if sc.container == "bin":
            wall_h, t = 0.12, 0.01
            for k, (pos, size) in enumerate([([hx - t, 0, h + wall_h / 2], [t, hy, wall_h / 2]),
                                              ([-hx + t, 0, h + wall_h / 2], [t, hy, wall_h / 2]),
                                              ([0, hy - t, h + wall_h / 2], [hx, t, wall_h / 2]),
                                              ([0, -hy + t, h + wall_h / 2], [hx, t, wall_h / 2])]):
                ms.worldbody.add_geom(name=f"bin_wall_{k}", type=mujoco.mjtGeom.mjGEOM_BOX, pos=pos, size=size,
                                      material=table_mat, group=2, friction=list(OBJECT_FRICTION))


@dataclass(frozen=True)
class LightValue:
    """One MuJoCo light of a scene: name, ``mjtLightType``, position (m, world), direction (any length),
    diffuse and specular RGB."""

    name: str
    type: "mujoco.mjtLightType"
    position: list[float]
    direction: list[float]
    diffuse: list[float]
    specular: list[float]


def texture_pixels(image: np.ndarray) -> np.ndarray:
    """The (H, W, C) uint8 array a 2D texture stores for ``image`` ((H, W) or (H, W, C) uint8, row 0 at the
    top): a grey map becomes RGB (MuJoCo's rasterizer uploads no 1-channel texture, and the pbr profile's depth
    and masks render through it)."""
    pixels = np.asarray(image, dtype=np.uint8)
    if pixels.ndim == 2:
        pixels = np.repeat(pixels[..., None], 3, axis=2)
    return np.ascontiguousarray(pixels)


def library_values(maps) -> dict[str, float]:
    """The material values of a library material's maps (:class:`simtest.materials.MaterialMaps`): specular,
    metallic, roughness (the roughness map's mean; pbr reads the map) and the rasterizer's shininess."""
    rough = float(maps.roughness.mean() / 255.0)
    return {"specular": float(maps.specular), "shininess": 1.0 - rough, "metallic": float(maps.metallic),
            "roughness": rough}


def skin_values(skin) -> dict[str, float]:
    """The material values of a print (:class:`simtest.objects.skins.Skin`): specular, and roughness and metallic
    as its maps' means (the rasterizer's; pbr reads the maps)."""
    return {"specular": float(skin.specular), "roughness": float(skin.roughness.mean() / 255.0),
            "metallic": float(skin.metallic.mean() / 255.0)}


#: Longest side (pixels) of an image texture; larger images are downsampled.
MAX_TEXTURE_SIZE = 512


@functools.lru_cache(maxsize=32)
def load_texture_image(path: str) -> np.ndarray:
    """An image file as an RGB uint8 array (H, W, 3), downsampled to at most ``MAX_TEXTURE_SIZE`` pixels.

    Raises:
        AssetError: If the file cannot be read as an image.
    """
    from PIL import Image

    try:
        with Image.open(path) as im:
            im = im.convert("RGB")
            im.thumbnail((MAX_TEXTURE_SIZE, MAX_TEXTURE_SIZE))
            return np.asarray(im, dtype=np.uint8).copy()
    except (OSError, ValueError) as exc:
        raise AssetError(f"texture image {path!r} could not be read ({exc}); use a png or jpg file") from None


def _object_body(ms: mujoco.MjSpec, name: str, obj: ObjectModel, mesh: str, position, quat_wxyz,
                 group: int):
    """A free body ``name`` of ``obj`` at ``position`` (metres) / ``quat_wxyz`` with the object's mass and
    inertia: its visual mesh ``mesh`` drawn in ``group`` with material ``{name}_mat`` (never colliding) and its
    convex parts ``{mesh}_col{k}`` colliding (group :data:`COLLISION_GROUP`, never drawn). Targets and distractor
    objects are built by this one function."""
    body = ms.worldbody.add_body(name=name, pos=list(position), quat=list(quat_wxyz))
    body.add_freejoint(name=f"{name}_joint")
    body.explicitinertial = True
    body.mass = obj.mass
    body.ipos = obj.center_of_mass.tolist()
    body.fullinertia = _full_inertia(obj.inertia)
    body.add_geom(name=f"{name}_visual", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh, material=f"{name}_mat",
                  group=group, contype=0, conaffinity=0, density=0, mass=0)
    friction = list(OBJECT_FRICTION) if obj.friction is None else [obj.friction, *OBJECT_FRICTION[1:]]
    for k in range(len(obj.collision_parts)):
        body.add_geom(name=f"{name}_col{k}", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"{mesh}_col{k}",
                      group=COLLISION_GROUP, density=0, mass=0, friction=friction, condim=6,
                      rgba=[0.5, 0.5, 0.5, 0.0], solref=[0.004, 1.0])
    return body


def _full_inertia(I: np.ndarray) -> list[float]:
    """MuJoCo ``fullinertia`` order: Ixx, Iyy, Izz, Ixy, Ixz, Iyz (kg m^2)."""
    I = np.asarray(I, dtype=np.float64)
    return [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]


def _build_options(options: BuildOptions) -> BuildOptions:
    """``options``, or the building options of a run config handed in their place (with a DeprecationWarning).

    Raises:
        ConfigError: If ``options`` is neither.
    """
    if isinstance(options, BuildOptions):
        return options
    convert = getattr(options, "build_options", None)
    if not callable(convert):
        raise ConfigError(f"SceneBuilder needs BuildOptions; got {type(options).__name__} {options!r:.80}")
    import warnings

    warnings.warn("SceneBuilder takes BuildOptions; pass cfg.build_options() instead of the config",
                  DeprecationWarning, stacklevel=3)
    return convert()
