"""The estimator plug-in API: ``estimate(observation) -> list[PoseEstimate]``.

An estimator is any object with an ``estimate`` method (or a plain callable) taking an :class:`Observation`
and returning pose estimates in the camera frame (OpenCV convention, metres). Estimators are chosen by name
(``oracle``, ``icp``, ``umeyama``, ...) or by ``module:attr`` for user code, with keyword options:
``load_estimator("mypkg.est:MyEstimator", threshold=0.5)``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from simtest.errors import ConfigError

__all__ = ["Observation", "PoseEstimate", "Estimator", "register_estimator", "load_estimator", "ESTIMATORS"]


@dataclass(frozen=True)
class Observation:
    """What an estimator sees for one image.

    Attributes:
        rgb: (H, W, 3) uint8.
        depth: (H, W) float32 planar depth in metres, 0 = missing.
        K: 3x3 intrinsics (pixels, OpenCV).
        width, height: Image size (pixels).
        objects: The object set (models, symmetries, keypoints, grasps) estimates refer to.
        target_obj_ids: Objects to estimate (``None``: whatever the estimator finds).
        masks: Optional per-target visible masks (H, W) bool, same order as ``target_obj_ids``
            (evaluation "with GT detections", as common protocols allow).
        boxes: Optional per-target boxes [x, y, w, h] (pixels).
        gt_poses: Ground-truth ``(R, t)`` per target; only for the ``oracle`` (calibration), ``None`` otherwise.
        scene_id, im_id: Where the image came from (for logging).
    """

    rgb: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    width: int
    height: int
    objects: Any
    target_obj_ids: tuple[int, ...] | None = None
    masks: tuple[np.ndarray, ...] | None = None
    boxes: tuple[tuple[int, int, int, int], ...] | None = None
    gt_poses: tuple[tuple[np.ndarray, np.ndarray], ...] | None = None
    scene_id: int = -1
    im_id: int = -1

    def rng(self, seed: int) -> np.random.Generator:
        """An estimator's generator for this image: seeded by ``(seed, scene_id, im_id)``, so results do not
        depend on the order images are processed in."""
        return np.random.default_rng([int(seed), max(self.scene_id, 0), max(self.im_id, 0)])

    def require_targets(self, estimator: str) -> None:
        """Raise :class:`ConfigError` unless target ids and visible masks were given (``targets='gt-masks'``)."""
        if self.target_obj_ids is None or self.masks is None:
            raise ConfigError(f"{estimator}: needs target object ids and masks; evaluate with targets='gt-masks'")


@dataclass(frozen=True)
class PoseEstimate:
    """One estimated object pose in the camera frame.

    Attributes:
        obj_id: Object id.
        R: 3x3 rotation, model -> camera.
        t: (3,) translation, metres.
        score: Confidence (higher is better); BOP matching is greedy by score.
        scale: Estimated scale for category-level estimators (1.0 for instance level).
        target_index: Index into ``Observation.target_obj_ids`` this estimate answers, if known.
        info: Free-form extras (e.g. ICP fitness).
    """

    obj_id: int
    R: np.ndarray
    t: np.ndarray
    score: float = 1.0
    scale: float = 1.0
    target_index: int | None = None
    info: dict = field(default_factory=dict)

    def is_finite(self) -> bool:
        return bool(np.all(np.isfinite(self.R)) and np.all(np.isfinite(self.t)) and np.isfinite(self.score))


@runtime_checkable
class Estimator(Protocol):
    def estimate(self, observation: Observation) -> list[PoseEstimate]: ...


#: Built-in estimators by name -> "module:attr" (imported lazily, so torch-based ones cost nothing unused).
ESTIMATORS: dict[str, str] = {}


def register_estimator(name: str, target: str) -> None:
    """Register a built-in estimator name for ``module:attr``."""
    ESTIMATORS[name] = target


def load_estimator(spec: str | Estimator | Callable, **options: Any) -> Estimator:
    """An estimator from a registered name, a ``module:attr`` path, an instance, or a callable.

    ``module:attr`` may name a class (instantiated with ``options``), a factory function (called with
    ``options``) or a function ``f(observation) -> list[PoseEstimate]`` (used as is; no options allowed).

    Raises:
        ConfigError: Unknown name (lists the known ones), unimportable module, missing attribute, or options
            the estimator does not accept.
    """
    if not isinstance(spec, str):
        if hasattr(spec, "estimate"):
            return spec  # type: ignore[return-value]
        if callable(spec):
            return _FunctionEstimator(spec)
        raise ConfigError(f"estimator must be a name, 'module:attr', or have an estimate() method; got {spec!r}")
    target = ESTIMATORS.get(spec, spec)
    if ":" not in target:
        raise ConfigError(f"unknown estimator {spec!r}; built-in: {', '.join(sorted(ESTIMATORS))}; or give "
                          f"'module:attr' for your own")
    mod_name, attr = target.split(":", 1)
    try:
        module = importlib.import_module(mod_name)
    except ImportError as exc:
        raise ConfigError(f"estimator {spec!r}: cannot import module {mod_name!r}: {exc}") from exc
    try:
        obj = getattr(module, attr)
    except AttributeError:
        raise ConfigError(f"estimator {spec!r}: module {mod_name!r} has no attribute {attr!r}") from None
    if isinstance(obj, type) or (callable(obj) and options):
        try:
            made = obj(**options)
        except TypeError as exc:
            raise ConfigError(f"estimator {spec!r}: bad options {options!r}: {exc}") from exc
        return load_estimator(made) if not hasattr(made, "estimate") else made
    if options:
        raise ConfigError(f"estimator {spec!r} is a plain function and takes no options; got {options!r}")
    return load_estimator(obj)


class _FunctionEstimator:
    def __init__(self, fn: Callable) -> None:
        self.fn = fn

    def estimate(self, observation: Observation) -> list[PoseEstimate]:
        return self.fn(observation)  # returned as is: the runners check it (simtest.estimators.guard)


for _name, _target in {
    "oracle": "simtest.estimators.oracle:OracleEstimator",
    "icp": "simtest.estimators.icp:ICPEstimator",
    "umeyama": "simtest.estimators.umeyama:UmeyamaEstimator",
    "keypoints": "simtest.estimators.keypoints:KeypointEstimator",
}.items():
    register_estimator(_name, _target)
