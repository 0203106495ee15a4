"""The grasp env's constants, the options of one episode (constructor defaults merged with ``reset(options=...)``)
and the checks of targets and actions, validated; and the per-process cache of object sets the env loads."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from simtest.corrupt import DEPTH_PRESETS, CorruptionSpec
from simtest.corrupt.occlusion import parse_occlusion_level
from simtest.errors import AssetError, ConfigError
from simtest.objects import load_object_set

__all__ = ["EpisodeConfig", "RESET_OPTIONS", "load_objects", "pick_target", "check_action", "CONTROL_DT",
           "MAX_STEP_TRANSLATION", "MAX_STEP_ROTATION", "SUCCESS_HEIGHT", "HOLD_TIME"]

#: Control period, s (20 Hz).
CONTROL_DT = 0.05
#: Largest TCP displacement per step and axis, m (0.4 m/s).
MAX_STEP_TRANSLATION = 0.02
#: Largest rotation-vector component per step, rad (2 rad/s).
MAX_STEP_ROTATION = 0.1
#: Success: the target at least this high above its resting height (m) ...
SUCCESS_HEIGHT = 0.10
#: ... for at least this long (s), held in the gripper.
HOLD_TIME = 1.0


#: Option names ``reset(options=...)`` takes.
RESET_OPTIONS = ("objects", "target", "n_distractors", "occlusion", "corruption", "depth_noise", "placement",
                  "start")

_ACTION_NAMES = ("dx", "dy", "dz", "rx", "ry", "rz", "g")

_OBJECT_SETS: dict[tuple, Any] = {}


def load_objects(name: str, units: str = "auto", scale: float = 1.0):
    """The object set ``name`` (``"builtin"``, ``"builtin-small"`` or a path; mesh files in ``units`` times
    ``scale``, see :func:`simtest.objects.load_object_set`), loaded once per process."""
    key = (name, units, float(scale))
    if key not in _OBJECT_SETS:
        _OBJECT_SETS[key] = load_object_set(name, units=units, scale=scale)
    return _OBJECT_SETS[key]


@dataclass(frozen=True)
class EpisodeConfig:
    """The validated settings of one episode (constructor defaults merged with ``reset`` options)."""

    objects: str = "builtin"
    target: int | str | None = None
    n_distractors: int = 2
    occlusion: int = 0
    corruption: CorruptionSpec | None = None
    placement: str = "upright"
    start: str = "home"

    @staticmethod
    def build(base: "EpisodeConfig", options: dict | None) -> "EpisodeConfig":
        """``base`` with ``options`` applied and validated.

        Raises:
            ConfigError: Unknown option names or bad values (the message names the allowed ones).
        """
        opts = dict(options or {})
        unknown = sorted(set(opts) - set(RESET_OPTIONS))
        if unknown:
            raise ConfigError(f"unknown reset option(s) {unknown}; allowed: {', '.join(RESET_OPTIONS)}")
        objects = opts.get("objects", base.objects)
        if not isinstance(objects, str) or not objects:
            raise ConfigError(f"objects must be an object set name or path, got {objects!r}")
        target = opts.get("target", base.target)
        if target is not None and not isinstance(target, (str, int, np.integer)) or isinstance(target, bool):
            raise ConfigError(f"target must be an obj_id, an object name or None, got {target!r}")
        n_dis = opts.get("n_distractors", base.n_distractors)
        if isinstance(n_dis, bool) or not isinstance(n_dis, (int, np.integer)) or not 0 <= n_dis <= 10:
            raise ConfigError(f"n_distractors must be an integer in [0, 10], got {n_dis!r}")
        occlusion = parse_occlusion_level(opts.get("occlusion", base.occlusion))
        corruption = base.corruption
        if "corruption" in opts or "depth_noise" in opts:
            c = opts.get("corruption", None if base.corruption is None else base.corruption.to_dict())
            if isinstance(c, CorruptionSpec):
                c = c.to_dict()
            if c is not None and not isinstance(c, dict):
                raise ConfigError(f"corruption must be a dict of CorruptionSpec fields (e.g. "
                                  f"{{'weather': 'fog', 'severity': 4}}) or None, got {c!r}")
            c = dict(c or {})
            if "occlusion" in c and c["occlusion"] not in (None, 0, "L0"):
                raise ConfigError("corruption.occlusion (2D paste) is not used by the grasp env; use the "
                                  "'occlusion' option for physical occluders")
            c.pop("occlusion", None)
            if "depth_noise" in opts:
                dn = opts["depth_noise"]
                if dn is not None and dn not in DEPTH_PRESETS:
                    raise ConfigError(f"unknown depth_noise preset {dn!r}; valid: {', '.join(DEPTH_PRESETS)}")
                c["depth_noise"] = dn
            spec = CorruptionSpec.from_dict(c)
            corruption = None if spec.is_identity else spec
        placement = opts.get("placement", base.placement)
        if placement not in ("upright", "random"):
            raise ConfigError(f"placement must be 'upright' or 'random', got {placement!r}")
        start = opts.get("start", base.start)
        if start not in ("home", "observe"):
            raise ConfigError(f"start must be 'home' or 'observe', got {start!r}")
        return EpisodeConfig(objects, target, int(n_dis), occlusion, corruption, placement, start)


def pick_target(objects, target, rng: np.random.Generator) -> int:
    """The episode's target obj_id: ``target`` (an obj_id or a name) checked against ``objects``, or, for
    ``None``, the first graspable object in a random order.

    Raises:
        ConfigError: An unknown target (listing the names or ids), or no graspable object.
    """
    if target is None:
        # Objects in a random order, the first graspable one (grasp sets are computed only as needed).
        for i in rng.permutation(len(objects)):
            if objects[int(i)].graspable:
                return int(objects[int(i)].obj_id)
        raise ConfigError(f"object set {objects.name!r} has no graspable object")
    if isinstance(target, str) and not target.lstrip("-").isdigit():
        try:
            return int(objects.by_name(target).obj_id)
        except AssetError as exc:
            names = ", ".join(o.name for o in objects)
            raise ConfigError(f"unknown target {target!r} in object set {objects.name!r}; names: {names}"
                              ) from exc
    oid = int(target)
    if oid not in objects.ids:
        raise ConfigError(f"unknown target obj_id {oid} in object set {objects.name!r}; ids: {objects.ids}")
    return oid


def check_action(action) -> np.ndarray:
    """``action`` as a (7,) float64 array; ConfigError naming the bad entries if it is not 7 finite numbers."""
    space = (f"Box(7) [dx, dy, dz, rx, ry, rz, g] with |d*| <= {MAX_STEP_TRANSLATION} m, "
             f"|r*| <= {MAX_STEP_ROTATION} rad, g in [-1, 1] (larger values are clipped)")
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"action must be 7 finite numbers, {space}; got {action!r}") from exc
    if a.shape != (7,):
        raise ConfigError(f"action must have shape (7,), {space}; got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        entries = ", ".join(f"action[{i}] ({_ACTION_NAMES[i]}) = {a[i]}" for i in bad)
        raise ConfigError(f"action has non-finite entries: {entries}; expected finite numbers, {space}")
    return a
