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

Sequences: the evaluation calls an estimator's optional ``reset()`` before the first frame of every scene
(a scene is one sequence), and gives frames in order with ``Observation.frame_index`` counting from 0 within
the scene, so an estimator may keep state from frame to frame.
"""

from __future__ import annotations

import ast
import importlib
import importlib.metadata
import importlib.util
import inspect
import numbers
import operator
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from simtest.errors import ConfigError

if TYPE_CHECKING:
    from simtest.objects import ObjectSet

__all__ = ["Observation", "PoseEstimate", "Estimator", "register_estimator", "load_estimator", "ESTIMATORS",
           "parse_value", "parse_options", "option_signature", "check_estimator_options", "ENTRY_POINT_GROUP",
           "installed_estimators", "default_object_set", "gt_access", "estimator_label", "GT_MASKS_LABEL",
           "GT_INIT_LABEL", "needs_gt_init", "needs_depth", "reset_estimator", "check_int_options"]

#: Entry-point group under which installed packages register estimators by name.
ENTRY_POINT_GROUP = "simtest.estimators"

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


#: Built-in estimators by name -> "module:attr" (imported lazily, so torch-based ones cost nothing unused).
ESTIMATORS: dict[str, str] = {}


def check_int_options(who: str, *options: tuple[str, Any, int]) -> None:
    """Raise :class:`ConfigError` unless every ``(name, value, lo)`` is an integer (not a bool) ``>= lo``; the
    message names the estimator ``who``, the option, its value and what is allowed."""
    for name, value, lo in options:
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < lo:
            raise ConfigError(f"{who}: {name} must be an integer >= {lo}, got {value!r}")


def register_estimator(name: str, target: str) -> None:
    """Register a built-in estimator name for ``module:attr``."""
    ESTIMATORS[name] = target


def load_estimator(spec: str | Estimator | Callable, **options: Any) -> Estimator:
    """An estimator from a registered name, an installed entry point, ``module:attr``, ``path/file.py:attr``,
    an instance, or a callable.

    A string is looked up in this order: a built-in name (:data:`ESTIMATORS`); a name registered by an
    installed package in the ``simtest.estimators`` entry-point group; ``module:attr`` (the module imported
    from ``sys.path``); ``path/to/file.py:attr`` (the file imported by path; its folder is appended to
    ``sys.path`` so it can import its sibling modules). ``attr`` may be dotted (``Class.factory``).

    The object found may be a class (instantiated with ``options``), a factory function (called with
    ``options``) or a function ``f(observation) -> list[PoseEstimate]`` (used as is; no options allowed).

    Raises:
        ConfigError: Unknown name (lists the built-in and installed ones), a module that cannot be imported or
            a file that does not exist (with how to fix it), a missing attribute, or options the estimator
            does not accept (lists the valid ones).
    """
    if not isinstance(spec, str):
        if hasattr(spec, "estimate"):
            return spec  # type: ignore[return-value]
        if callable(spec):
            return _FunctionEstimator(spec)
        raise ConfigError(f"estimator must be a name, 'module:attr', 'path/to/file.py:attr', or have an estimate() "
                          f"method; got {spec!r}")
    obj = _resolve(spec)
    if isinstance(obj, type) or (callable(obj) and options):
        _check_options(spec, obj, options)
        try:
            made = obj(**options)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ConfigError):
                raise
            raise ConfigError(f"estimator {spec!r}: bad options {options!r}: {exc}; valid options: "
                              f"{option_signature(obj)}") from exc
        return load_estimator(made) if not hasattr(made, "estimate") else made
    if options:
        raise ConfigError(f"estimator {spec!r} is a plain function and takes no options; got {options!r}")
    return load_estimator(obj)


def installed_estimators() -> dict[str, importlib.metadata.EntryPoint]:
    """Estimators registered by installed packages: ``{name: entry point}`` of the ``simtest.estimators``
    group (``[project.entry-points."simtest.estimators"] my-est = "mypkg.est:MyEstimator"``)."""
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def _resolve(spec: str) -> Any:
    """The class, factory or function a name, entry point, ``module:attr`` or ``file.py:attr`` names."""
    if spec in ESTIMATORS:
        return _import_target(spec, ESTIMATORS[spec])
    if ":" not in spec:
        installed = installed_estimators()
        if spec in installed:
            return _load_entry_point(spec, installed[spec])
        hint = (f"; give the class or function too: {spec}:MyEstimator" if spec.endswith(".py") else
                "; or give 'module:attr' or 'path/to/file.py:attr' for your own")
        names = sorted(ESTIMATORS)
        extra = f"; installed: {', '.join(sorted(installed))}" if installed else ""
        raise ConfigError(f"unknown estimator {spec!r}; built-in: {', '.join(names)}{extra}{hint}")
    return _import_target(spec, spec)


def _load_entry_point(spec: str, ep: importlib.metadata.EntryPoint) -> Any:
    dist = getattr(getattr(ep, "dist", None), "name", None) or "?"
    try:
        return ep.load()
    except Exception as exc:  # noqa: BLE001 - any failure of a plug-in's import is reported as a config error
        raise ConfigError(f"estimator {spec!r}: the entry point {ep.value!r} (group {ENTRY_POINT_GROUP!r}, "
                          f"package {dist!r}) failed to load: {type(exc).__name__}: {exc}") from exc


def is_file_target(module_part: str) -> bool:
    return module_part.endswith(".py") or "/" in module_part or "\\" in module_part


def _import_target(spec: str, target: str) -> Any:
    """Import ``module:attr`` or ``path/file.py:attr`` and return the attribute."""
    mod_name, _, attr = target.rpartition(":")
    if not mod_name or not attr:
        raise ConfigError(f"estimator {spec!r}: expected 'module:attr' or 'path/to/file.py:attr' with both parts "
                          "given")
    module = _import_file(spec, mod_name, attr) if is_file_target(mod_name) else _import_module(spec, mod_name, attr)
    obj: Any = module
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            public = sorted(n for n, v in vars(module).items() if not n.startswith("_") and callable(v)
                            and getattr(v, "__module__", None) == module.__name__)
            raise ConfigError(f"estimator {spec!r}: {mod_name!r} has no attribute {attr!r}; its classes and "
                              f"functions: {', '.join(public) or '(none)'}") from None
    return obj


def _import_module(spec: str, mod_name: str, attr: str) -> Any:
    try:
        return importlib.import_module(mod_name)
    except ImportError as exc:
        missing = getattr(exc, "name", None)
        if missing and (mod_name == missing or mod_name.startswith(missing + ".")):
            raise ConfigError(f"estimator {spec!r}: {exc}: is it on PYTHONPATH (tried the folders of sys.path)? "
                              f"or pass a file path: path/to/{mod_name.split('.')[-1]}.py:{attr}") from exc
        raise ConfigError(f"estimator {spec!r}: importing module {mod_name!r} failed: {exc} (a module it imports "
                          "is missing: install it)") from exc
    except Exception as exc:  # noqa: BLE001 - user code failing at import time
        raise ConfigError(f"estimator {spec!r}: importing module {mod_name!r} raised {type(exc).__name__}: "
                          f"{exc}") from exc


def _import_file(spec: str, path_text: str, attr: str) -> Any:
    """Import a Python file by path (once per resolved path; later calls reuse the module)."""
    path = Path(path_text).expanduser().resolve()
    if not path.is_file():
        raise ConfigError(f"estimator {spec!r}: file not found: {path} (a path relative to the working folder "
                          f"{Path.cwd()}, or absolute)")
    name = f"simtest_plugin_{path.stem}_{zlib.crc32(str(path).encode()):08x}"
    if name in sys.modules:
        return sys.modules[name]
    loader_spec = importlib.util.spec_from_file_location(name, path)
    if loader_spec is None or loader_spec.loader is None:
        raise ConfigError(f"estimator {spec!r}: {path} cannot be imported as a Python module (expected a .py file)")
    module = importlib.util.module_from_spec(loader_spec)
    if str(path.parent) not in sys.path:
        sys.path.append(str(path.parent))
    sys.modules[name] = module
    try:
        loader_spec.loader.exec_module(module)
    except Exception as exc:  # noqa: BLE001 - user code failing at import time
        del sys.modules[name]
        where = f" (line {exc.lineno})" if isinstance(exc, SyntaxError) else ""
        raise ConfigError(f"estimator {spec!r}: importing {path}{where} raised {type(exc).__name__}: {exc}") from exc
    return module


def default_object_set(spec: str | Any, options: dict[str, Any], fallback: str = "builtin") -> str:
    """The object set an estimator works on by default: its class attribute ``default_object_set`` (e.g.
    ``segicp``'s shipped checkpoint knows ``builtin-small``) unless it is given its own ``checkpoint``; else
    ``fallback``."""
    target = _resolve(spec) if isinstance(spec, str) else spec
    own = getattr(target, "default_object_set", None)
    return own if isinstance(own, str) and own and not options.get("checkpoint") else fallback


def check_estimator_options(spec: str | Any, options: dict[str, Any]) -> None:
    """Check option names and types against a named estimator's signature without constructing it (what
    :func:`load_estimator` checks first); instances and callables are not checked.

    Raises:
        ConfigError: As :func:`load_estimator`, listing the valid options.
    """
    if isinstance(spec, str):
        obj = _resolve(spec)
        if isinstance(obj, type) or (callable(obj) and options):
            _check_options(spec, obj, options)


def parse_value(text: str) -> Any:
    """One option value from the command line.

    ``true/false/yes/no/on/off`` -> bool, ``none/null`` -> None, integers and floats -> numbers, text starting
    with ``[``, ``(``, ``{`` or a quote -> that Python literal (a list, tuple, dict or quoted string), anything
    else -> the string itself.

    Raises:
        ConfigError: Text that starts like a literal but does not parse as one.
    """
    stripped = text.strip()
    low = stripped.lower()
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    if low in ("none", "null"):
        return None
    for cast in (int, float):
        try:
            return cast(stripped)
        except ValueError:
            pass
    if stripped[:1] in ("[", "(", "{", "'", '"'):
        try:
            return ast.literal_eval(stripped)
        except (ValueError, SyntaxError):
            raise ConfigError(f"--opt value {text!r} starts like a Python literal (list, tuple, dict or quoted "
                              "string) but does not parse as one") from None
    return text


def parse_options(items: list[str]) -> dict[str, Any]:
    """``["key=value", ...]`` (the repeatable ``--opt``) -> ``{key: parse_value(value)}``; ``-`` in a key
    becomes ``_``.

    Raises:
        ConfigError: An item without ``=`` or whose key is not an identifier.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not key.isidentifier():
            raise ConfigError(f"--opt must be KEY=VALUE with KEY a name such as rot_noise_deg, got {item!r}")
        out[key] = parse_value(value)
    return out


def _option_params(factory: Callable) -> list[inspect.Parameter] | None:
    """Keyword parameters of a class's ``__init__`` or a factory; ``None`` if it takes ``**kwargs`` or has no
    readable signature."""
    try:
        params = list(inspect.signature(factory).parameters.values())
    except (TypeError, ValueError):
        return None
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return None
    return [p for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]


def option_signature(factory: Callable) -> str:
    """``"name=default, ..."`` for the options a class or factory accepts (``name`` alone if required)."""
    params = _option_params(factory)
    if params is None:
        return "(any keyword; see its documentation)"
    if not params:
        return "(none)"
    return ", ".join(p.name if p.default is p.empty else f"{p.name}={p.default!r}" for p in params)


def _type_ok(value: Any, param: inspect.Parameter) -> bool:
    """Whether ``value`` fits the type of the option's default (a ``None`` default fits anything; ``None``
    fits an option annotated as optional)."""
    default = param.default
    if default is None or default is param.empty:
        return True
    if value is None:
        return "None" in str(param.annotation) or "Optional" in str(param.annotation)
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, numbers.Real) and not isinstance(value, bool)
    if isinstance(default, str):
        return isinstance(value, str)
    return True


def _check_options(spec: str, factory: Callable, options: dict[str, Any]) -> None:
    """Raise :class:`ConfigError` listing the valid options for an unknown name or a value of the wrong type."""
    params = _option_params(factory)
    if params is None:
        return
    by_name = {p.name: p for p in params}
    unknown = sorted(set(options) - set(by_name))
    if unknown:
        raise ConfigError(f"estimator {spec!r}: bad options: unknown option(s) {', '.join(unknown)}; valid options: "
                          f"{option_signature(factory)}")
    for name, value in options.items():
        default = by_name[name].default
        if not _type_ok(value, by_name[name]):
            raise ConfigError(f"estimator {spec!r}: bad options: {name} = {value!r} has the wrong type; expected "
                              f"{type(default).__name__} (default {default!r}); valid options: "
                              f"{option_signature(factory)}")


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
    "segicp": "simtest.estimators.segicp:SegICPEstimator",
    "track-icp": "simtest.estimators.track_icp:TrackICPEstimator",
}.items():
    register_estimator(_name, _target)
