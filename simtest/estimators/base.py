"""The estimator plug-in API: ``estimate(observation) -> list[PoseEstimate]``.

An estimator is any object with an ``estimate`` method (or a plain callable) taking an :class:`Observation`
and returning pose estimates in the camera frame (OpenCV convention, metres). Estimators are chosen by name
(``oracle``, ``icp``, ``umeyama``, ...) or by ``module:attr`` for user code, with keyword options:
``load_estimator("mypkg.est:MyEstimator", threshold=0.5)``.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import numbers
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from simtest.errors import ConfigError

__all__ = ["Observation", "PoseEstimate", "Estimator", "register_estimator", "load_estimator", "ESTIMATORS",
           "parse_value", "parse_options", "option_signature", "check_estimator_options"]


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


def _resolve(spec: str) -> Any:
    """The class, factory or function a registered name or ``module:attr`` names (imported)."""
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
    return obj


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
}.items():
    register_estimator(_name, _target)
