"""What building and settling a scene need, and nothing of a dataset: :class:`BuildOptions` for
:class:`~simtest.generators.builder.SceneBuilder`, :class:`SettleOptions` for
:func:`~simtest.generators.settle.settle`, and the :class:`Room` both share.

The dataset side makes them from its run config (its ``build_options()`` and ``settle_options()``); a grasp
scene makes them directly (:func:`simtest.envs.scene.scene_config`). Lengths in metres, times in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from simtest.camera import CameraModel
from simtest.errors import ConfigError

__all__ = ["Room", "BuildOptions", "SettleOptions", "QUALITIES", "CONTAINERS", "N_OCCLUDERS"]

#: Mocap occluder boxes a scene holds when physical occlusion is on.
N_OCCLUDERS = 1

#: Render qualities a model is built for: ``fast`` (no shadows, no MSAA), ``quality`` (shadows, 4x MSAA) and
#: ``pbr`` (path-traced RGB: the environment lights the scene, no MuJoCo lights in its place).
QUALITIES = ("fast", "quality", "pbr")
#: What holds the objects: a plain table top or a bin (four low walls on the table).
CONTAINERS = ("table", "bin")


@dataclass(frozen=True)
class Room:
    """The table and the room around it.

    Attributes:
        table_size: Table top (x, y) extent, metres; centred at the world origin.
        table_height: Height of the table top above the floor, metres (0: no table, objects rest on the floor).
        container: ``"table"`` or ``"bin"``.
        room_half_size: Floor and walls reach this far (metres) from the table's centre.
        wall_height: Height of the four walls, metres.
    """

    table_size: tuple[float, float] = (0.8, 0.6)
    table_height: float = 0.4
    container: str = "table"
    room_half_size: float = 3.0
    wall_height: float = 1.6

    def __post_init__(self) -> None:
        if self.container not in CONTAINERS:
            raise ConfigError(f"container must be one of {', '.join(CONTAINERS)}; got {self.container!r}")
        if len(self.table_size) != 2 or min(self.table_size) <= 0:
            raise ConfigError(f"table_size must be two lengths > 0 m; got {self.table_size!r}")
        object.__setattr__(self, "table_size", (float(self.table_size[0]), float(self.table_size[1])))


@dataclass(frozen=True)
class BuildOptions:
    """What :class:`~simtest.generators.builder.SceneBuilder` needs to compile a scene.

    Attributes:
        camera: The render camera's intrinsics and image size (also the wrist camera's, with the Panda); its pose
            is set per view. The one camera object of every scene built with these options.
        room: The table and the room.
        timestep: Physics step, seconds.
        quality: Render quality the model is made for, one of :data:`QUALITIES` (shadow map, MSAA samples,
            which lights stand in for an environment).
        panda: Put the Panda arm at the table's -x edge (with a wrist camera of ``camera``'s intrinsics).
        occluder_slots: Mocap occluder boxes kept out of sight for physical occlusion (0: none).
        material_folder: Where ``"folder:NAME"`` material keys of a spec are found (``None``: no folder).
        texture_size: Pixels per side of a library material's maps.
        distractor_objects: The object set a spec's distractor objects come from (``scene.distractor_objects``;
            ``None``: none).
    """

    camera: CameraModel
    room: Room = field(default_factory=Room)
    timestep: float = 0.002
    quality: str = "fast"
    panda: bool = False
    occluder_slots: int = 0
    material_folder: str | None = None
    texture_size: int = 256
    distractor_objects: str | None = None

    def __post_init__(self) -> None:
        if self.quality not in QUALITIES:
            raise ConfigError(f"quality must be one of {', '.join(QUALITIES)}; got {self.quality!r}")
        if not self.timestep > 0:
            raise ConfigError(f"timestep must be > 0 s; got {self.timestep!r}")
        if isinstance(self.occluder_slots, bool) or int(self.occluder_slots) != self.occluder_slots \
                or self.occluder_slots < 0:
            raise ConfigError(f"occluder_slots must be an integer >= 0; got {self.occluder_slots!r}")


@dataclass(frozen=True)
class SettleOptions:
    """When :func:`~simtest.generators.settle.settle` stops and what counts as fallen off.

    Attributes:
        max_time: Simulated seconds at most.
        velocity: At rest below this speed of any body's fastest point, m/s.
        room: The table the objects must stay on.
    """

    max_time: float = 4.0
    velocity: float = 0.01
    room: Room = field(default_factory=Room)

    def __post_init__(self) -> None:
        if not self.max_time > 0:
            raise ConfigError(f"max_time must be > 0 s; got {self.max_time!r}")
        if not self.velocity > 0:
            raise ConfigError(f"velocity must be > 0 m/s; got {self.velocity!r}")
