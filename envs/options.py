"""The options of one grasp episode (constructor defaults merged with ``reset(options=...)``), validated, and the
per-process cache of object sets the env loads."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from simtest.corrupt import DEPTH_PRESETS, CorruptionSpec
from simtest.corrupt.occlusion import parse_occlusion_level
from simtest.errors import ConfigError

__all__ = ["EpisodeConfig", "RESET_OPTIONS", "load_objects"]

#: Option names ``reset(options=...)`` takes.
RESET_OPTIONS = ("objects", "target", "n_distractors", "occlusion", "corruption", "depth_noise", "placement",
                  "start")

_ACTION_NAMES = ("dx", "dy", "dz", "rx", "ry", "rz", "g")

_OBJECT_SETS: dict[tuple, Any] = {}


def load_objects(name: str, units: str = "auto", scale: float = 1.0):
    """The object set ``name`` (``"builtin"``, ``"builtin-small"`` or a path; mesh files in ``units`` times
    ``scale``, see :func:`simtest.objects.load_object_set`), loaded once per process."""
    from simtest.objects import load_object_set

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
