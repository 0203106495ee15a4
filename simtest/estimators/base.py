"""The estimator plug-in API: ``estimate(observation) -> list[PoseEstimate]``.

An estimator is any object with an ``estimate`` method (or a plain callable) taking an :class:`Observation`
and returning pose estimates in the camera frame (OpenCV convention, metres). Estimators are chosen by name
(``oracle``, ``icp``, ``umeyama``, ...), by ``module:attr`` or ``path/to/file.py:attr`` for user code, or by the
name an installed package registers in the ``simtest.estimators`` entry-point group, with keyword options:
``load_estimator("mypkg.est:MyEstimator", threshold=0.5)``. The contract is written out in ``docs/plugins.md``.

Ground truth reaches an estimator only when it declares that it needs it: ``needs_gt_masks = True`` (class
or instance attribute) gives the targets' ground-truth visible masks and boxes ("GT detections"; its runs are
labelled ``NAME (GT masks)`` in every table, :func:`estimator_label`), ``needs_gt = True`` (the ``oracle``)
also gives their poses. Any other estimator sees the images, ``K``, the object set and the ids of the objects
to look for, never masks, boxes or poses (:func:`gt_access`). A tracker declares ``needs_gt_init = True``
instead: it is given each target's ground-truth pose once, on the first frame of its sequence in which the
target appears (``Observation.init_poses``), and stable track ids on every frame; its runs are labelled
``NAME (GT init)`` (:func:`needs_gt_init`).

Set-up and time: the evaluation calls an estimator's optional ``prepare(objects)`` once per worker before its
first image, outside the per-image time limit (read caches, build template banks; :func:`prepare_estimator`),
and an estimator that needs more than the default 120 s per image declares ``time_limit_s`` (seconds), which
raises the limit when the user sets none (:func:`simtest.estimators.guard.resolve_timeout`).

Sequences: the evaluation calls an estimator's optional ``reset()`` before the first frame of every scene
(a scene is one sequence), and gives frames in order with ``Observation.frame_index`` counting from 0 within
the scene, so an estimator may keep state from frame to frame.
"""

from __future__ import annotations

import importlib
import operator
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from simtest.errors import ConfigError

if TYPE_CHECKING:
    from simtest.objects import ObjectSet

__all__ = ["Observation", "PoseEstimate", "Estimator", "gt_access", "estimator_label", "GT_MASKS_LABEL",
           "GT_INIT_LABEL", "needs_gt_init", "needs_depth", "reset_estimator", "prepare_estimator"]

#: Names that moved out of this module: the loader and registry to :mod:`simtest.estimators.registry`, option
#: parsing to :mod:`simtest.estimators.options`. ``from simtest.estimators.base import NAME`` still works, with
#: a DeprecationWarning.
MOVED = {**{n: "simtest.estimators.registry" for n in (
    "register_estimator", "load_estimator", "ESTIMATORS", "ENTRY_POINT_GROUP", "installed_estimators",
    "default_object_set", "check_estimator_options", "is_file_target")},
    **{n: "simtest.estimators.options" for n in (
        "parse_value", "parse_options", "option_signature", "check_int_options")}}


def __getattr__(name: str) -> Any:
    """The moved names (:data:`MOVED`), from their new module, with a DeprecationWarning."""
    if name in MOVED:
        warnings.warn(f"simtest.estimators.base.{name} moved to {MOVED[name]}.{name}", DeprecationWarning,
                      stacklevel=2)
        return getattr(importlib.import_module(MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

#: Appended to the label of an estimator that is given ground-truth masks.
GT_MASKS_LABEL = " (GT masks)"
#: Appended to the label of an estimator that is given the targets' ground-truth poses on their first frame.
GT_INIT_LABEL = " (GT init)"


def gt_access(estimator: Any) -> tuple[bool, bool]:
    """``(masks, poses)``: whether an (instantiated) estimator is given the targets' ground-truth visible masks
    and boxes (``needs_gt_masks`` or ``needs_gt``), and their ground-truth poses (``needs_gt``)."""
    poses = bool(getattr(estimator, "needs_gt", False))
    return poses or bool(getattr(estimator, "needs_gt_masks", False)), poses


def needs_depth(estimator: Any) -> bool:
    """Whether an estimator reads ``Observation.depth`` (its ``needs_depth``; True when it does not say)."""
    return bool(getattr(estimator, "needs_depth", True))


def needs_gt_init(estimator: Any) -> bool:
    """Whether an (instantiated) estimator declares ``needs_gt_init``: it is given each target's ground-truth
    pose on the target's first frame of a sequence only (``Observation.init_poses``), and track ids."""
    return bool(getattr(estimator, "needs_gt_init", False)) and not bool(getattr(estimator, "needs_gt", False))


def reset_estimator(estimator: Any) -> None:
    """Call the estimator's optional ``reset()`` (start of a new sequence); estimators without one are
    stateless and nothing happens."""
    reset = getattr(estimator, "reset", None)
    if callable(reset):
        reset()


def prepare_estimator(estimator: Any, objects: Any) -> None:
    """Call the estimator's optional ``prepare(objects)`` (once, before its first image, with the dataset's
    object set); estimators without one need no set-up and nothing happens."""
    prepare = getattr(estimator, "prepare", None)
    if callable(prepare):
        prepare(objects)


def estimator_label(name: str, estimator: Any) -> str:
    """The label of an estimator's runs in tables and plots: ``name``, plus `` (GT masks)`` when it declares
    ``needs_gt_masks`` (the ``oracle``, whose name says it, is not relabelled) and `` (GT init)`` when it
    declares ``needs_gt_init``."""
    gt_masks = bool(getattr(estimator, "needs_gt_masks", False))
    label = name + GT_MASKS_LABEL if gt_masks and not name.endswith(GT_MASKS_LABEL) else name
    return label + GT_INIT_LABEL if needs_gt_init(estimator) and not label.endswith(GT_INIT_LABEL) else label


@dataclass(frozen=True)
class Observation:
    """What an estimator sees for one image.

    Attributes:
        rgb: (H, W, 3) uint8.
        depth: (H, W) float32 planar depth in metres, 0 = missing; ``None`` when the dataset has no depth (then
            only estimators declaring ``needs_depth = False`` run, :func:`needs_depth`).
        K: 3x3 intrinsics (pixels, OpenCV).
        width, height: Image size (pixels).
        objects: The :class:`~simtest.objects.ObjectSet` estimates refer to: ``objects.get(obj_id)`` gives the
            :class:`~simtest.objects.ObjectModel` (mesh, vertices, surface samples with normals, symmetries,
            keypoints, diameter; metres, model frame).
        target_obj_ids: Objects to estimate, one entry per instance, as BOP's localisation task names them
            (``None``: whatever the estimator finds, as always in the detection task).
        masks: Per-target ground-truth visible masks (H, W) bool, same order as ``target_obj_ids``; only for
            estimators declaring ``needs_gt_masks`` (or ``needs_gt``, when the dataset has masks), ``None``
            otherwise.
        boxes: Per-target ground-truth visible boxes [x, y, w, h] (pixels); given with ``masks``.
        gt_poses: Ground-truth ``(R, t)`` per target; only for ``needs_gt`` (the ``oracle``), ``None`` otherwise;
            in the detection task their object ids are ``gt_obj_ids`` (``needs_targets = False`` oracles).
        scene_id, im_id: Where the image came from (for logging).
        frame_index: Position of the image within its scene (sequence) in this evaluation, from 0; ``-1`` when
            unknown. Frames of a scene come in order; ``reset()`` is called before frame 0.
        track_ids: Per-target instance ids, stable across the frames of a scene (the BOP ``gt_id``); only for
            ``needs_gt_init`` estimators, ``None`` otherwise.
        init_poses: Per target, the ground-truth ``(R, t)`` on the first frame of the scene in which that target
            appears and ``None`` on every later frame; only for ``needs_gt_init`` estimators.
    """

    rgb: np.ndarray
    depth: np.ndarray | None
    K: np.ndarray
    width: int
    height: int
    objects: ObjectSet
    target_obj_ids: tuple[int, ...] | None = None
    masks: tuple[np.ndarray, ...] | None = None
    boxes: tuple[tuple[int, int, int, int], ...] | None = None
    gt_poses: tuple[tuple[np.ndarray, np.ndarray], ...] | None = None
    scene_id: int = -1
    im_id: int = -1
    frame_index: int = -1
    track_ids: tuple[int, ...] | None = None
    init_poses: tuple[tuple[np.ndarray, np.ndarray] | None, ...] | None = None
    gt_obj_ids: tuple[int, ...] | None = None

    def rng(self, seed: int) -> np.random.Generator:
        """An estimator's generator for this image: seeded by ``(seed, scene_id, im_id)``, so results do not
        depend on the order images are processed in."""
        return np.random.default_rng([int(seed), max(self.scene_id, 0), max(self.im_id, 0)])

    def require_targets(self, estimator: str) -> None:
        """Raise :class:`ConfigError` unless target ids and ground-truth visible masks were given (the estimator
        declares ``needs_gt_masks`` and is evaluated with ``targets='gt-masks'``)."""
        if self.target_obj_ids is None or self.masks is None:
            raise ConfigError(f"{estimator}: needs target object ids and ground-truth masks; declare "
                              "needs_gt_masks = True and evaluate with targets='gt-masks'")


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

    def __post_init__(self) -> None:
        """Check the fields and store ``R`` (3, 3) and ``t`` (3,) as float64 arrays.

        Raises:
            ConfigError: ``obj_id`` not an integer, ``R`` not 3x3 or ``t`` not 3 values, or NaN / inf in them;
                the message names the field and the value.
        """
        if isinstance(self.obj_id, bool):
            raise ConfigError(f"PoseEstimate: obj_id must be an integer object id, got {self.obj_id!r}")
        try:
            object.__setattr__(self, "obj_id", operator.index(self.obj_id))
        except TypeError:
            raise ConfigError(f"PoseEstimate: obj_id must be an integer object id, got {self.obj_id!r} "
                              f"({type(self.obj_id).__name__})") from None
        object.__setattr__(self, "R", _field_array("R", self.R, (3, 3), "a 3x3 rotation matrix (model -> camera)"))
        object.__setattr__(self, "t", _field_array("t", self.t, (3,), "3 values (metres, camera frame)"))

    @classmethod
    def from_matrix(cls, T: Any, obj_id: int, score: float = 1.0, **kwargs: Any) -> "PoseEstimate":
        """An estimate from a 4x4 homogeneous transform ``T_cam_obj`` (model -> camera, translation in metres).

        Args:
            T: (4, 4) array; its top-left 3x3 block is ``R``, its last column's first three entries ``t``.
            obj_id: Object id.
            score: Confidence (higher is better).
            **kwargs: Other fields (``scale``, ``target_index``, ``info``).

        Raises:
            ConfigError: ``T`` is not a finite 4x4 matrix (the message gives its shape), or a field is invalid.
        """
        try:
            M = np.asarray(T, dtype=np.float64)
        except (TypeError, ValueError):
            raise ConfigError(f"PoseEstimate.from_matrix: T must be a 4x4 numeric matrix, got {_short(T)}") from None
        if M.shape != (4, 4):
            raise ConfigError(f"PoseEstimate.from_matrix: T must be a 4x4 matrix (model -> camera, metres), got "
                              f"shape {M.shape}")
        return cls(obj_id=obj_id, R=M[:3, :3].copy(), t=M[:3, 3].copy(), score=score, **kwargs)

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous transform ``T_cam_obj`` (metres)."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.t
        return T

    def is_finite(self) -> bool:
        return bool(np.all(np.isfinite(self.R)) and np.all(np.isfinite(self.t)) and np.isfinite(self.score))


def _short(value: Any) -> str:
    """``repr(value)`` on one line, at most 80 characters."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 80 else text[:77] + "..."


def _field_array(name: str, value: Any, shape: tuple[int, ...], expected: str) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` with finite entries; :class:`ConfigError` naming the field
    ``name``, the value and what is expected otherwise. ``t`` may also come as (3, 1) or (1, 3)."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"PoseEstimate: {name} must be {expected}, got {_short(value)}") from None
    if arr.shape != shape and arr.size == int(np.prod(shape)) and len(shape) == 1:
        arr = arr.reshape(shape)
    if arr.shape != shape:
        raise ConfigError(f"PoseEstimate: {name} must be {expected}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ConfigError(f"PoseEstimate: {name} must be finite, got {_short(value)} (NaN or inf)")
    return arr


@runtime_checkable
class Estimator(Protocol):
    def estimate(self, observation: Observation) -> list[PoseEstimate]: ...
