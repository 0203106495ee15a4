"""Finding estimators: built-in names, installed entry points, ``module:attr`` and ``path/file.py:attr``; the
loader that makes an estimator from any of them with checked options (:mod:`simtest.estimators.options`)."""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import sys
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from simtest.errors import ConfigError
from simtest.estimators.options import check_options, option_signature

if TYPE_CHECKING:
    from simtest.estimators.base import Estimator, Observation, PoseEstimate

__all__ = ["ESTIMATORS", "ENTRY_POINT_GROUP", "register_estimator", "load_estimator", "installed_estimators",
           "default_object_set", "check_estimator_options", "is_file_target"]

#: Entry-point group under which installed packages register estimators by name.
ENTRY_POINT_GROUP = "simtest.estimators"

#: Built-in estimators by name -> "module:attr" (imported lazily, so torch-based ones cost nothing unused).
ESTIMATORS: dict[str, str] = {}


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
        check_options(spec, obj, options)
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
            check_options(spec, obj, options)


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
    "templates": "simtest.estimators.templates:TemplateEstimator",
}.items():
    register_estimator(_name, _target)
