"""Generation config: every randomization parameter with a sane default, validated at the boundary.

A config is a tree of frozen dataclasses. :func:`load_config` reads TOML or JSON, :meth:`GenerateConfig.
from_dict` validates (unknown keys, types, ranges) and raises :class:`ConfigError` naming the field (dotted
path), the bad value and what is allowed. Lengths are metres, angles degrees (as users write them), times
seconds.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from simtest.backend import check_backend
from simtest.errors import ConfigError, DatasetError
from simtest.generators.build_options import N_OCCLUDERS, BuildOptions, Room, SettleOptions
from simtest.schema import bounds as _bounds
from simtest.schema import build, pair as _rng_pair, read_config_file, to_plain, to_toml

__all__ = [
    "CameraConfig", "OcclusionConfig", "ShellRig", "SequenceRig", "SceneConfig", "LightConfig", "MaterialConfig", "RenderConfig",
    "GenerateConfig", "load_config", "CAMERA_FILE_FIELDS", "camera_file_values", "AIM_FIELDS", "check_weights",
]

#: The ``camera`` fields a BOP ``camera.json`` named by ``camera.file`` sets (its ``depth_scale``, when it has
#: one, sets ``render.depth_scale``).
CAMERA_FILE_FIELDS = ("fx", "fy", "cx", "cy", "width", "height")


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole intrinsics (pixels) and image size. Defaults: RealSense-D435-like colour camera at 640x480.

    ``file``: a BOP ``camera.json`` (``simtest generate --camera PATH``) whose ``fx, fy, cx, cy, width, height``
    become these fields and whose optional ``depth_scale`` (mm per depth unit) becomes ``render.depth_scale``
    (:func:`camera_file_values`); kept as an absolute path. A field given next to it must equal the file's value
    (else a :class:`ConfigError` naming both); :meth:`GenerateConfig.replace` with a new ``camera.file`` takes
    all of the new file's values (the command line's ``--camera`` over a config file's camera fields).
    """

    file: str | None = None
    width: int = field(default=640, metadata=_bounds(16, 8192))
    height: int = field(default=480, metadata=_bounds(16, 8192))
    fx: float | None = field(default=None, metadata=_bounds(1.0, 1e5))  # None: 615 * width / 640
    fy: float | None = field(default=None, metadata=_bounds(1.0, 1e5))
    cx: float | None = field(default=None, metadata=_bounds(-1e4, 1e4))  # None: (width - 1) / 2
    cy: float | None = field(default=None, metadata=_bounds(-1e4, 1e4))

    def K(self):
        from simtest.camera import default_intrinsics

        return default_intrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy)


@dataclass(frozen=True)
class ShellRig:
    """Cameras on a spherical shell around a point of interest on the table (degrees, metres)."""

    distance: tuple[float, float] = field(default=(0.45, 0.9), metadata=_rng_pair(0.05, 20.0))
    elevation_deg: tuple[float, float] = field(default=(25.0, 80.0), metadata=_rng_pair(-89.0, 89.9))
    azimuth_deg: tuple[float, float] = field(default=(0.0, 360.0), metadata=_rng_pair(-360.0, 720.0))
    roll_deg: float = field(default=10.0, metadata=_bounds(0.0, 180.0))  # in-plane jitter, +/-
    poi_jitter: float = field(default=0.05, metadata=_bounds(0.0, 1.0))  # metres, around the objects' centre
    # where the views aim (simtest adapt; docs/adapt.md). The in-plane rotation range [min, max] degrees replaces
    # the +/- roll_deg jitter when given; each *_weights splits its range into len(weights) equal parts and draws
    # a part in proportion to its weight, then uniformly inside it (empty: uniform over the whole range)
    roll_range_deg: tuple[float, float] | None = field(default=None, metadata=_rng_pair(-180.0, 180.0))
    distance_weights: tuple[float, ...] = field(default=(), metadata=_bounds(0.0, 1e6))
    elevation_weights: tuple[float, ...] = field(default=(), metadata=_bounds(0.0, 1e6))
    roll_weights: tuple[float, ...] = field(default=(), metadata=_bounds(0.0, 1e6))

    def __post_init__(self) -> None:
        for name in ("distance_weights", "elevation_weights", "roll_weights"):
            check_weights(f"shell.{name}", getattr(self, name))

    def roll_range(self) -> tuple[float, float]:
        """The in-plane rotation range of a view, degrees: ``roll_range_deg``, else ``(-roll_deg, roll_deg)``."""
        return self.roll_range_deg if self.roll_range_deg is not None else (-self.roll_deg, self.roll_deg)


@dataclass(frozen=True)
class SequenceRig:
    """A smooth camera trajectory per scene: approach from ``start_distance`` toward ``end_distance``."""

    start_distance: tuple[float, float] = field(default=(0.8, 1.0), metadata=_rng_pair(0.05, 20.0))
    end_distance: tuple[float, float] = field(default=(0.35, 0.5), metadata=_rng_pair(0.05, 20.0))
    elevation_deg: tuple[float, float] = field(default=(30.0, 70.0), metadata=_rng_pair(-89.0, 89.9))
    sweep_deg: float = field(default=40.0, metadata=_bounds(0.0, 360.0))  # azimuth swept over the sequence


@dataclass(frozen=True)
class SceneConfig:
    """What is on the table and how it settles."""

    objects_per_scene: tuple[int, int] = field(default=(3, 6), metadata=_rng_pair(1, 200))
    distractors: tuple[int, int] = field(default=(0, 2), metadata=_rng_pair(0, 100))
    allow_repeats: bool = True  # the same object may appear more than once in a scene
    # unannotated distractor *objects*: an object set ("builtin", "builtin-small", a folder of meshes or a BOP
    # models folder, read in its own units) whose meshes are dropped among the targets with their prints; they
    # occlude and clutter like the primitive distractors and are never annotated (unset: none)
    distractor_objects: str | None = None
    distractor_object_count: tuple[int, int] = field(default=(2, 6), metadata=_rng_pair(0, 100))
    container: Literal["table", "bin"] = field(default="table", metadata=_bounds(choices=("table", "bin")))
    table_size: tuple[float, float] = field(default=(0.8, 0.6), metadata={"each": (0.1, 10.0)})  # x, y metres
    table_height: float = field(default=0.4, metadata=_bounds(0.0, 2.0))
    drop_height: tuple[float, float] = field(default=(0.05, 0.25), metadata=_rng_pair(0.0, 2.0))
    drop_area: float = field(default=0.6, metadata=_bounds(0.05, 1.0))  # fraction of the table objects drop over
    settle_max_time: float = field(default=4.0, metadata=_bounds(0.1, 60.0))  # seconds of simulated time
    settle_velocity: float = field(default=0.01, metadata=_bounds(1e-5, 1.0))  # m/s (and rad/s) at rest
    timestep: float = field(default=0.002, metadata=_bounds(1e-4, 0.01))
    panda: bool = False  # put the Panda arm in the scene (always on for the wrist rig)
    max_attempts: int = field(default=5, metadata=_bounds(1, 100))  # re-sample a scene that cannot be placed
    # the room: floor and four walls at +-room_half_size (metres) from the table's centre, wall_height tall; its
    # top is open (light from the environment and the lights enters there)
    room_half_size: float = field(default=3.0, metadata=_bounds(0.5, 50.0))
    wall_height: float = field(default=1.6, metadata=_bounds(0.1, 20.0))
    # an emissive panel above the room (BlenderProc's BOP recipe: 3 x 3 m, 10 m up), brightness drawn per scene
    ceiling_light: bool = False
    # relative frequency of each object id as a target ({"13" = 2.0}; ids left out weigh 1; empty: uniform)
    object_weights: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key, value in self.object_weights.items():
            if not str(key).isdigit() or isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not 0.0 <= value <= 1e6:
                raise ConfigError(f"scene.object_weights.{key} = {value!r} is invalid; allowed: an object id as key "
                                  f"and a weight in [0, 1e6]")


@dataclass(frozen=True)
class LightConfig:
    count: tuple[int, int] = field(default=(1, 4), metadata=_rng_pair(0, 8))
    distance: tuple[float, float] = field(default=(0.8, 2.0), metadata=_rng_pair(0.1, 20.0))
    intensity: tuple[float, float] = field(default=(0.3, 0.9), metadata=_rng_pair(0.0, 1.0))  # diffuse
    ambient: tuple[float, float] = field(default=(0.1, 0.35), metadata=_rng_pair(0.0, 1.0))
    colour_jitter: float = field(default=0.15, metadata=_bounds(0.0, 1.0))
    # pbr lighting beyond the lights: "auto" = an equirectangular map of `hdri` when given, else a procedural
    # sky with sun or studio (one at random per scene); "sky" / "studio" / "hdri" force one; "constant" = the
    # ambient term only (earlier releases). The fast and quality profiles approximate the environment with
    # directional lights and the ambient term (simtest.materials.light_summary).
    environment: Literal["auto", "sky", "studio", "hdri", "constant"] = field(
        default="auto", metadata=_bounds(choices=("auto", "sky", "studio", "hdri", "constant")))
    hdri: str | None = None  # folder of .hdr / .exr equirectangular maps (z up: row 0 is the zenith)
    environment_strength: tuple[float, float] = field(default=(0.6, 1.3), metadata=_rng_pair(0.0, 100.0))
    # brightness of the ceiling panel (scene.ceiling_light): the irradiance it gives the floor's centre, as the
    # display value a white floor would show (0.5 = mid grey)
    ceiling_strength: tuple[float, float] = field(default=(0.3, 0.6), metadata=_rng_pair(0.0, 10.0))


#: The sampling weights and targeting ranges ``simtest adapt`` writes (section, field); :meth:`GenerateConfig.
#: to_dict` leaves them out while unset, so a config without them records exactly what it did before they existed.
AIM_FIELDS = (("shell", "roll_range_deg"), ("shell", "distance_weights"), ("shell", "elevation_weights"),
              ("shell", "roll_weights"), ("scene", "object_weights"), ("occlusion", "visib_band"),
              ("occlusion", "visib_weights"))
#: At most this many parts per weighted range.
MAX_WEIGHTS = 64


def check_weights(name: str, weights: tuple[float, ...]) -> None:
    """Raise a :class:`ConfigError` naming ``name`` unless ``weights`` is empty or 1..MAX_WEIGHTS values >= 0
    with a positive sum."""
    if weights and (len(weights) > MAX_WEIGHTS or sum(weights) <= 0):
        raise ConfigError(f"{name} = {list(weights)} is invalid; allowed: 1 to {MAX_WEIGHTS} weights >= 0 with a "
                          f"positive sum, or [] for uniform")


#: The procedural material families (simtest.materials.FAMILIES), all on by default.
MATERIAL_FAMILIES = ("wood", "tiles", "fabric", "concrete", "marble", "brushed_metal", "painted_plastic",
                     "cardboard", "paper")


@dataclass(frozen=True)
class MaterialConfig:
    """Per-object and background appearance randomization (MuJoCo material parameters, each in [0, 1])."""

    randomize_object_colour: bool = True
    colour_jitter: float = field(default=0.15, metadata=_bounds(0.0, 1.0))  # around each object's own colour
    # textured / vertex-coloured objects keep their texture, times a tint: brightness 1 - [0, jitter], saturation
    # [0, jitter / 2] (simtest.objects.appearance.tint_rgba)
    texture_jitter: float = field(default=0.15, metadata=_bounds(0.0, 1.0))
    specular: tuple[float, float] = field(default=(0.0, 0.7), metadata=_rng_pair(0.0, 1.0))
    shininess: tuple[float, float] = field(default=(0.0, 0.8), metadata=_rng_pair(0.0, 1.0))
    reflectance: tuple[float, float] = field(default=(0.0, 0.15), metadata=_rng_pair(0.0, 1.0))
    background_textures: bool = True  # procedural table / floor / wall textures
    # folder of materials for the table, floor, walls and distractors: CC0 sets (NAME_Color / _Roughness /
    # _NormalGL|DX images, as ambientCG and Poly Haven ship them) are full materials, other png / jpg images
    # albedo only (simtest.materials.folder_materials); replaces the procedural families
    textures: str | None = None
    # procedural PBR families (simtest.materials) the table, floor, walls and distractors draw from, with
    # weights (one per family, any scale; empty = equal); empty families = MuJoCo's checker / gradient patterns
    families: tuple[str, ...] = field(default=MATERIAL_FAMILIES, metadata=_bounds(choices=MATERIAL_FAMILIES))
    family_weights: tuple[float, ...] = field(default=(), metadata=_bounds(0.0, 1e6))
    variants: int = field(default=12, metadata=_bounds(1, 100_000))  # seeds per family (each made once, cached)
    # the first of those seeds: seeds first_variant .. first_variant + variants - 1 (a test set with looks no
    # training set drew: e.g. 1000 against the default 0)
    first_variant: int = field(default=0, metadata=_bounds(0, 1_000_000_000))
    texture_size: int = field(default=256, metadata=_bounds(32, 2048))  # pixels per side of a material's maps
    room_material: Literal["per_surface", "shared"] = field(
        default="per_surface", metadata=_bounds(choices=("per_surface", "shared")))  # shared: one for floor and walls
    # per-instance variants of textured built-in objects' prints (labels, cartons, glazes: simtest.objects.skins)
    object_textures: bool = True

    def __post_init__(self) -> None:
        if self.family_weights and len(self.family_weights) != len(self.families):
            raise ConfigError(f"materials.family_weights has {len(self.family_weights)} values for "
                              f"{len(self.families)} families {list(self.families)}; give one weight per family")
        if self.family_weights and sum(self.family_weights) <= 0:
            raise ConfigError(f"materials.family_weights = {list(self.family_weights)} sums to 0; give a positive weight")
        size = self.texture_size
        if size & (size - 1):
            raise ConfigError(f"materials.texture_size = {size} is not a power of two; allowed: 32, 64, ..., 2048")


@dataclass(frozen=True)
class RenderConfig:
    profile: Literal["fast", "quality", "pbr"] = field(default="fast",
                                                       metadata=_bounds(choices=("fast", "quality", "pbr")))
    depth_scale: float = field(default=0.1, metadata=_bounds(1e-3, 100.0))  # mm per depth PNG unit (BOP)
    # rgb/ images: JPEG as in BOP's PBR layout, or lossless PNG; JPEG quality 1-100.
    rgb_format: Literal["jpg", "png"] = field(default="jpg", metadata=_bounds(choices=("jpg", "png")))
    jpg_quality: int = field(default=95, metadata=_bounds(1, 100))
    coco: bool = False  # also write scene_gt_coco.json (RLE masks, pycocotools)
    # box of each COCO annotation: whole object in the image (BOP toolkit default) or its visible part
    coco_bbox: Literal["amodal", "modal"] = field(default="amodal", metadata=_bounds(choices=("amodal", "modal")))
    # path-traced samples per pixel (pbr profile): an integer in [1, 65536], or "auto": 12 at 320x240 and below,
    # 6 at 640x480 and above, round(12 * sqrt(320 * 240 / pixels)) between (simtest.render.pbr.auto_spp).
    # Typed `object` because the schema checks one type per field; __post_init__ checks int | "auto".
    pbr_spp: object = "auto"
    pbr_denoise: bool = True  # denoise pbr images with Open Image Denoise (albedo + normal guides)
    # the path tracer's sampler: multijitter (default), independent (earlier releases), stratified (square counts)
    pbr_sampler: Literal["multijitter", "independent", "stratified"] = field(
        default="multijitter", metadata=_bounds(choices=("multijitter", "independent", "stratified")))
    # samples per pixel of the albedo / normal guide pass (at most pbr_spp; 4 or more: handed over as noise-free)
    pbr_guide_spp: int = field(default=4, metadata=_bounds(1, 1024))
    # Open Image Denoise quality: fast (default; half the time of high at 640x480), balanced, high
    pbr_denoise_quality: Literal["fast", "balanced", "high"] = field(
        default="fast", metadata=_bounds(choices=("fast", "balanced", "high")))
    # Mitsuba variant of the pbr profile: "auto" = cuda (a CUDA device), else llvm (a libLLVM >= 16), else
    # scalar; an explicit "cuda" / "llvm" that cannot run is an error (simtest.render.llvm.choose_variant)
    pbr_variant: Literal["auto", "cuda", "llvm", "scalar"] = field(
        default="auto", metadata=_bounds(choices=("auto", "cuda", "llvm", "scalar")))
    # depth/ from a simulated depth sensor (simtest.sensors.stereo presets) instead of the exact render; the exact
    # depth then goes to depth_exact/ (same encoding); masks, poses and every other label stay exact
    depth_sensor: Literal["none", "d435-stereo", "passive-stereo"] = field(
        default="none", metadata=_bounds(choices=("none", "d435-stereo", "passive-stereo")))

    def __post_init__(self) -> None:
        spp = self.pbr_spp
        if spp != "auto" and (isinstance(spp, bool) or not isinstance(spp, int) or not 1 <= spp <= 65536):
            raise ConfigError(f"render.pbr_spp = {spp!r} is invalid; allowed: 'auto' or an integer in [1, 65536]")


@dataclass(frozen=True)
class OcclusionConfig:
    """Physical occluders: 3D boxes placed between the camera and a target so its visible fraction lands in
    the requested level's band (see :mod:`simtest.generators.occlusion`). ``level=None`` adds none."""

    level: Literal["L0", "L1", "L2", "L3", "mixed"] | None = field(
        default=None, metadata=_bounds(choices=("L0", "L1", "L2", "L3", "mixed")))
    definition: Literal["pascal3d+", "objectcentric"] = field(
        default="pascal3d+", metadata=_bounds(choices=("pascal3d+", "objectcentric")))
    standing_first: bool = True  # try a box standing on the table before a floating plate
    # a band [min, max] of the target's visible fraction (instead of ``level``): the occluder aims at it in every
    # view; visib_weights splits it into equal sub-bands drawn in proportion (simtest adapt; docs/adapt.md)
    visib_band: tuple[float, float] | None = field(default=None, metadata=_rng_pair(0.0, 1.0))
    visib_weights: tuple[float, ...] = field(default=(), metadata=_bounds(0.0, 1e6))

    def __post_init__(self) -> None:
        if self.visib_band is not None and self.level is not None:
            raise ConfigError(f"occlusion.visib_band = {list(self.visib_band)} and occlusion.level = {self.level!r} "
                              f"are both set; give one of them")
        if self.visib_weights and self.visib_band is None:
            raise ConfigError(f"occlusion.visib_weights = {list(self.visib_weights)} needs occlusion.visib_band")
        check_weights("occlusion.visib_weights", self.visib_weights)

    @property
    def physical(self) -> bool:
        """Whether views get a physical occluder (a level or a visibility band)."""
        return self.level is not None or self.visib_band is not None


@dataclass(frozen=True)
class AnnotationConfig:
    """Ground truth beyond BOP's files (default: none, so a plain BOP set stays as small as it is)."""

    #: Dense channels per image: instances, coords, normals, flow, keypoints (:mod:`simtest.generators.dense`).
    channels: tuple[str, ...] = field(default=(), metadata=_bounds(choices=("instances", "coords", "normals", "flow",
                                                                           "keypoints")))


@dataclass(frozen=True)
class GenerateConfig:
    """Everything ``simtest generate`` needs. See the module docstring for units."""

    # a preset of the values below (simtest.generators.recipes); values given in the config win over it
    recipe: Literal["tabletop", "bop-pbr"] = field(default="tabletop",
                                                   metadata=_bounds(choices=("tabletop", "bop-pbr")))
    objects: str = "builtin"  # "builtin", "builtin-small", or a path (mesh folder, mesh file, BOP models/)
    # units of mesh files; auto: metres, refusing a diameter outside 1 cm .. 1.5 m
    units: Literal["m", "cm", "mm", "auto"] = field(default="auto",
                                                   metadata=_bounds(choices=("m", "cm", "mm", "auto")))
    scale: float = field(default=1.0, metadata=_bounds(1e-6, 1e6))  # times the units: metres per file unit
    scenes: int = field(default=10, metadata=_bounds(1, 10_000_000))
    frames_per_scene: int = field(default=10, metadata=_bounds(1, 100_000))
    rig: Literal["shell", "wrist", "sequence"] = field(
        default="shell", metadata=_bounds(choices=("shell", "wrist", "sequence")))
    split: str = "train_pbr"
    seed: int = field(default=0, metadata=_bounds(0, 2**63 - 1))
    workers: int = field(default=1, metadata=_bounds(1, 256))
    # where the scenes run (simtest.backend): local processes or Ray tasks; not part of what is made
    backend: Literal["local", "ray"] = field(default="local", metadata=_bounds(choices=("local", "ray")))
    ray_address: str | None = None  # with backend "ray": "auto" or HOST:PORT of a running cluster; None starts one
    camera: CameraConfig = field(default_factory=CameraConfig)
    shell: ShellRig = field(default_factory=ShellRig)
    sequence: SequenceRig = field(default_factory=SequenceRig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    lights: LightConfig = field(default_factory=LightConfig)
    materials: MaterialConfig = field(default_factory=MaterialConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    occlusion: OcclusionConfig = field(default_factory=OcclusionConfig)
    annotation: AnnotationConfig = field(default_factory=AnnotationConfig)
    # scene_captions.json per scene: referring expressions per instance (simtest.generators.captions)
    captions: bool = False
    # the split holds only rgb/, depth/ and scene_camera.json; every label goes to <out>/withheld/<split>/
    unlabelled: bool = False

    @staticmethod
    def from_dict(data: dict[str, Any], source: str = "config") -> "GenerateConfig":
        """Validate ``data`` (nested dicts) into a config; errors name ``source`` and the dotted field. A
        ``recipe`` fills the values ``data`` leaves out (:func:`simtest.generators.recipes.with_recipe`)."""
        from simtest.generators.recipes import with_recipe

        data = _with_camera_file(data, source)  # before the recipe: the file's values are given, not preset
        cfg = build(GenerateConfig, with_recipe(data, source), prefix="", source=source)
        try:
            check_backend(cfg.backend, cfg.ray_address, cfg.workers)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
        return cfg

    def to_dict(self, camera_file: bool = True) -> dict[str, Any]:
        """The config as nested dicts; ``camera_file=False``: without ``camera.file``, its values kept (what a
        process rebuilds the config from without reading the file again)."""
        data = to_plain(dataclasses.asdict(self))
        if not camera_file:
            data["camera"]["file"] = None
        for section, name in AIM_FIELDS:  # unset: recorded as before they existed
            if data[section][name] in (None, [], {}):
                del data[section][name]
        return data

    def build_options(self) -> BuildOptions:
        """What :class:`~simtest.generators.builder.SceneBuilder` needs of this config: the camera, the room,
        the timestep, the render profile, the Panda (asked for, or the wrist rig), occluder slots (physical
        occlusion on), where library materials come from and the distractor objects' set."""
        from simtest.camera import CameraModel

        sc = self.scene
        return BuildOptions(
            camera=CameraModel(self.camera.K(), self.camera.width, self.camera.height), room=self.room(),
            timestep=sc.timestep, quality=self.render.profile, panda=bool(sc.panda or self.rig == "wrist"),
            occluder_slots=N_OCCLUDERS if self.occlusion.physical else 0,
            material_folder=self.materials.textures, texture_size=self.materials.texture_size,
            distractor_objects=sc.distractor_objects)

    def room(self) -> Room:
        """The table and room of ``scene.*``."""
        sc = self.scene
        return Room(table_size=sc.table_size, table_height=sc.table_height, container=sc.container,
                    room_half_size=sc.room_half_size, wall_height=sc.wall_height)

    def settle_options(self) -> SettleOptions:
        """When settling stops (``scene.settle_max_time``, ``scene.settle_velocity``) on this config's room."""
        return SettleOptions(max_time=self.scene.settle_max_time, velocity=self.scene.settle_velocity,
                             room=self.room())

    def to_toml(self) -> str:
        """The config as TOML text that :func:`load_config` reads back (``None`` values are omitted)."""
        return to_toml(self.to_dict())

    def replace(self, **overrides: Any) -> "GenerateConfig":
        """A copy with dotted-path overrides, validated: ``cfg.replace(**{"camera.width": 320})``. A new
        ``recipe`` keeps the values this config sets apart from its own recipe's and takes the rest from the
        new recipe."""
        full = self.to_dict()
        data = full
        if "recipe" in overrides and overrides["recipe"] != self.recipe:
            data = _changed(full, GenerateConfig.from_dict({"recipe": self.recipe}).to_dict())
        if overrides.get("camera.file") is not None:  # a new camera file: its values replace this config's
            data = _without_camera_values(data, overrides["camera.file"])
        for key, value in overrides.items():
            node, known = data, full
            parts = key.split(".")
            for p in parts[:-1]:
                if p not in known or not isinstance(known[p], dict):
                    raise ConfigError(f"unknown config field {key!r}")
                node, known = node.setdefault(p, {}), known[p]
            node[parts[-1]] = value
        return GenerateConfig.from_dict(data, source="overrides")


def camera_file_values(path: str | Path, source: str = "config") -> dict[str, float | int]:
    """The values a BOP ``camera.json`` gives a generation config: ``fx, fy, cx, cy`` (pixels, OpenCV: pixel
    centres at integers), ``width, height`` (pixels) and, when the file has it, ``depth_scale`` (mm per depth
    PNG unit). Other keys of the file are ignored.

    Raises:
        ConfigError: Naming ``source``, ``camera.file``, the file and the field: the file is missing or not JSON,
            a field is missing, not a number or out of range (:func:`simtest.io.bop.read_camera_json`; the
            config's bounds: fx, fy in [1, 1e5], width, height in [16, 8192], depth_scale in [0.001, 100]), or
            the principal point lies outside the image (``cx`` in [-0.5, width - 0.5], ``cy`` likewise: a swapped
            or mistyped K).
    """
    from simtest.io.bop import read_camera_json

    where = f"{source}: camera.file"
    try:
        data = read_camera_json(path)
    except DatasetError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    values: dict[str, float | int] = {k: float(data[k]) for k in ("fx", "fy", "cx", "cy")}
    values.update(width=int(data["width"]), height=int(data["height"]))
    try:
        build(CameraConfig, values, prefix="", source=str(path))
        if "depth_scale" in data:
            values["depth_scale"] = build(RenderConfig, {"depth_scale": data["depth_scale"]}, prefix="",
                                          source=str(path)).depth_scale
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    for key, size in (("cx", "width"), ("cy", "height")):
        if not -0.5 <= values[key] <= values[size] - 0.5:
            raise ConfigError(f"{where}: {path}: field {key!r} is {data[key]!r}; allowed: a principal point inside "
                              f"the image, [-0.5, {values[size] - 0.5}] for {size} {values[size]}")
    return values


def _with_camera_file(data: dict[str, Any], source: str) -> dict[str, Any]:
    """``data`` (a config as nested dicts) with ``camera.file`` read into its camera fields and
    ``render.depth_scale`` and the path made absolute; a field given with a different value is an error."""
    cam = data.get("camera") if isinstance(data, dict) else None
    if not isinstance(cam, dict) or cam.get("file") is None:
        return data
    file = cam["file"]
    if not isinstance(file, str) or not file.strip():
        raise ConfigError(f"{source}: camera.file = {file!r} is invalid; allowed: the path of a BOP camera.json")
    path = os.path.abspath(os.path.expanduser(file))
    values = camera_file_values(path, source)
    cam = {**cam, "file": path}
    render = data.get("render", {})
    render = dict(render) if isinstance(render, dict) else render  # not a table: build says so
    for key, value in values.items():
        table, name = (render, "render") if key == "depth_scale" else (cam, "camera")
        if not isinstance(table, dict):
            continue
        given = table.get(key)
        if given is not None and not (isinstance(given, (int, float)) and not isinstance(given, bool)
                                      and float(given) == float(value)):
            raise ConfigError(f"{source}: {name}.{key} = {given!r} conflicts with camera.file {path!r}, whose "
                              f"{key} is {value!r}; give one or the other (the file's values are used for the "
                              f"fields left out)")
        table[key] = value
    return {**data, "camera": cam, "render": render}


def _without_camera_values(data: dict[str, Any], file: Any) -> dict[str, Any]:
    """``data`` without the camera fields a new ``camera.file`` sets (and ``render.depth_scale`` when the file
    has one), so that file's values replace them instead of conflicting with them."""
    out = dict(data)
    if isinstance(out.get("camera"), dict):
        out["camera"] = {k: v for k, v in out["camera"].items() if k not in CAMERA_FILE_FIELDS}
    if isinstance(file, str) and file.strip() and isinstance(out.get("render"), dict):
        values = camera_file_values(os.path.abspath(os.path.expanduser(file)), "overrides")
        if "depth_scale" in values:
            out["render"] = {k: v for k, v in out["render"].items() if k != "depth_scale"}
    return out


def _changed(data: dict, base: dict) -> dict:
    """The entries of ``data`` (nested dicts) that differ from ``base``."""
    out = {}
    for key, value in data.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            sub = _changed(value, base[key])
            if sub:
                out[key] = sub
        elif key not in base or base[key] != value:
            out[key] = value
    return out


def load_config(path: str | Path) -> GenerateConfig:
    """Read a TOML (``.toml``) or JSON (``.json``) generation config and validate it."""
    return GenerateConfig.from_dict(read_config_file(path), source=str(path))
