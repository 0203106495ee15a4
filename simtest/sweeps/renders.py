"""Generation conditions of a sweep: the clean dataset's scenes generated again with other generation settings
(a render profile, a simulated depth sensor, any generation-config override), the ground truth held fixed.

A *render condition* is a named set of generation-config overrides, dotted keys as
:meth:`simtest.generators.config.GenerateConfig.replace` takes them (``{"render.profile": "pbr"}``). Its
dataset is generated with the clean dataset's generation config (same seed, scenes, views) plus the overrides,
in ``OUT/data/<name>/``, and must have the clean dataset's ground truth byte for byte
(:func:`check_same_ground_truth`): every file of ``camera.json``, ``models/``, the BOP target lists and the
split's scene folders, except ``rgb/``. Depth is compared as the exact depth (``depth_exact/`` when a depth
sensor wrote ``depth/``, else ``depth/``; across the two folders as equal 16-bit values, since their PNG
encodings may differ); ``depth/`` itself also, byte for byte, when both datasets use the same depth sensor.
An override that changes anything else (the room, the objects, the poses) makes a different dataset, not a
render condition, and is refused.

A condition whose generation config equals the clean one (``renderers = ["fast"]`` over a fast clean set) is
the clean dataset itself: nothing is generated for it.
"""

from __future__ import annotations

import filecmp
import json
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

from simtest.errors import ConfigError

__all__ = ["RenderEntry", "PROFILES", "DEPTH_SENSORS", "FIXED_KEYS", "flatten_overrides", "check_override_keys",
           "check_overrides", "clean_generate_config", "condition_generate_config", "same_generation",
           "prepare_condition_dataset", "check_same_ground_truth", "overrides_text"]

#: Short forms: ``factors.renderers`` entries (``render.profile``) and ``factors.depth_sensors`` entries
#: (``render.depth_sensor``) of the sweep config.
PROFILES: tuple[str, ...] = ("fast", "quality", "pbr")
DEPTH_SENSORS: tuple[str, ...] = ("d435-stereo", "passive-stereo")

#: Generation fields a condition cannot override: they choose the scenes and views (held fixed), where the
#: labels go, or where the generation runs (the sweep's own ``workers`` / ``backend``).
FIXED_KEYS: tuple[str, ...] = ("seed", "scenes", "frames_per_scene", "split", "unlabelled", "workers", "backend",
                               "ray_address")

#: Top-level entries of a generated dataset compared between the clean and a condition's dataset (plus the split).
_COMPARED_TOP = ("camera.json", "models", "test_targets_bop19.json", "test_targets_bop24.json")


@dataclass(frozen=True)
class RenderEntry:
    """One render condition of the sweep (``[[renders]]``): a table label and generation-config overrides
    (dotted keys, e.g. ``{"render.profile" = "pbr", "render.pbr_spp" = 4}``)."""

    name: str
    overrides: dict = field(default_factory=dict)


def flatten_overrides(overrides: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"render": {"profile": "pbr"}}`` (TOML's unquoted dotted keys) as ``{"render.profile": "pbr"}``;
    dotted keys pass as they are."""
    out: dict[str, Any] = {}
    for key, value in overrides.items():
        if isinstance(value, dict):
            out.update(flatten_overrides(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def check_override_keys(overrides: dict[str, Any], where: str) -> None:
    """Every key names a leaf field of the generation config and none is in :data:`FIXED_KEYS`.

    Raises:
        ConfigError: Naming ``where``, the key, and the fields allowed at the level where it went wrong.
    """
    from simtest.generators.config import GenerateConfig

    for key in overrides:
        if key.split(".")[0] in FIXED_KEYS:
            raise ConfigError(f"{where}: {key!r} cannot be overridden: a render condition generates the clean "
                              f"dataset's scenes again (its seed, scenes, views and split) and runs where the "
                              f"sweep runs; fixed: {', '.join(FIXED_KEYS)}")
        node: Any = GenerateConfig
        done = []
        for part in key.split("."):
            names = {f.name: f for f in fields(node)} if is_dataclass(node) else {}
            if part not in names:
                level = ".".join(done) or "the top level"
                allowed = " | ".join(names) if names else f"none ({'.'.join(done)} is a value, not a table)"
                raise ConfigError(f"{where}: {key!r} is not a generation config field (see simtest generate "
                                  f"--print-config); allowed in {level}: {allowed}")
            done.append(part)
            node = _field_type(node, part)
        if is_dataclass(node):
            raise ConfigError(f"{where}: {key!r} is a table of the generation config; override its fields "
                              f"({' | '.join(f'{key}.{f.name}' for f in fields(node))})")


def _field_type(cls: type, name: str) -> Any:
    import typing

    return typing.get_type_hints(cls)[name]


def check_overrides(overrides: dict[str, Any], where: str) -> None:
    """Keys (:func:`check_override_keys`) and values (the generation config's own checks, on its defaults)."""
    from simtest.generators.config import GenerateConfig

    check_override_keys(overrides, where)
    try:
        GenerateConfig().replace(**overrides)
    except ConfigError as exc:
        text = str(exc).removeprefix("overrides: ")
        raise ConfigError(f"{where}: {text}") from None


def overrides_text(overrides: dict[str, Any]) -> str:
    """``render.profile=pbr;render.pbr_spp=4``: the overrides in one cell of a table."""
    return ";".join(f"{k}={v}" for k, v in overrides.items())


def clean_generate_config(cfg, clean: Path):
    """The generation config of the sweep's clean dataset: ``[dataset.generate]`` with the sweep's seed, or the
    ``config`` recorded in the ``manifest.json`` of a ``dataset.path``; run fields from the sweep.

    Raises:
        ConfigError: A ``dataset.path`` without a simtest ``manifest.json`` (its scenes cannot be generated again).
    """
    from simtest.generators.config import GenerateConfig

    run = {"workers": cfg.workers, "backend": cfg.backend, "ray_address": cfg.ray_address}
    if cfg.dataset.generate is not None:
        return GenerateConfig.from_dict({"seed": cfg.seed, **run, **cfg.dataset.generate}, source="[dataset.generate]")
    manifest = clean / "manifest.json"
    try:
        recorded = json.loads(manifest.read_text())["config"]
    except (OSError, ValueError, KeyError, TypeError):
        raise ConfigError(f"render and depth-sensor conditions generate the dataset's scenes again, but "
                          f"{str(manifest)!r} is missing or records no generation config; use a dataset made by "
                          f"simtest generate or a [dataset.generate] table") from None
    return GenerateConfig.from_dict({**recorded, **run}, source=str(manifest))


def condition_generate_config(clean_gen, overrides: dict[str, Any], name: str):
    """The clean generation config with a condition's overrides."""
    try:
        return clean_gen.replace(**overrides)
    except ConfigError as exc:
        raise ConfigError(f"sweep condition {name!r}: {exc}") from None


def same_generation(a, b) -> bool:
    """Whether two generation configs make the same dataset (run fields aside)."""
    from simtest.backend import RUN_FIELDS
    from simtest.generators.config import GenerateConfig
    from simtest.schema import config_changes

    return not config_changes(a.to_dict(), b.to_dict(), GenerateConfig().to_dict(), ignore=RUN_FIELDS)


def prepare_condition_dataset(clean_gen, clean: Path, cond_gen, name: str, path: Path, progress: bool) -> Path:
    """Generate a render condition's dataset in ``path`` (resumed when its manifest exists) and check its
    ground truth against ``clean``; returns the folder holding it (``clean`` itself when the configs agree).

    Raises:
        ConfigError: The overrides changed the ground truth (:func:`check_same_ground_truth`).
    """
    if same_generation(clean_gen, cond_gen):
        return clean
    from simtest.generators.pipeline import generate

    if (path / "manifest.json").exists():
        generate(cond_gen, path, resume=True, progress=progress)
    else:
        generate(cond_gen, path, overwrite=True, progress=progress)
    check_same_ground_truth(clean, path, clean_gen.split, name,
                            same_sensor=clean_gen.render.depth_sensor == cond_gen.render.depth_sensor)
    return path


def _ground_truth_files(root: Path, split: str, with_depth: bool) -> dict[str, Path]:
    """``{key: file}`` of what must not change: every compared file but ``rgb/``; exact depth as
    ``<scene>/exact-depth/NAME`` (``depth_exact/`` if the scene has it, else ``depth/``); ``depth/`` as itself
    only ``with_depth``."""
    out: dict[str, Path] = {}
    tops = [root / t for t in (split, *_COMPARED_TOP)]  # the scenes' files first
    for top in tops:
        items = [top] if top.is_file() else sorted(p for p in top.rglob("*") if p.is_file()) if top.is_dir() else []
        for p in items:
            rel = p.relative_to(root)
            parts = rel.parts
            if parts[0] == split and len(parts) >= 4 and not parts[1].startswith("."):
                folder = parts[2]
                scene = root.joinpath(*parts[:2])
                if folder == "rgb":
                    continue
                exact = "depth_exact" if (scene / "depth_exact").is_dir() else "depth"
                if folder == exact:
                    out[str(Path(*parts[:2], "exact-depth", *parts[3:]))] = p
                if folder == "depth_exact" or (folder == "depth" and not with_depth):
                    continue
            elif parts[0] == split and any(s.startswith(".") for s in parts[1:]):
                continue  # an interrupted scene's temporary folder or file
            out[str(rel)] = p
    return out


def _same_file(a: Path, b: Path, exact_depth: bool) -> bool:
    """Byte-equal files; exact depth PNGs (``depth/`` against ``depth_exact/``, which the generator may encode
    with other PNG settings) as equal 16-bit values."""
    if filecmp.cmp(a, b, shallow=False):
        return True
    if not exact_depth:
        return False
    import cv2
    import numpy as np

    da, db = cv2.imread(str(a), cv2.IMREAD_UNCHANGED), cv2.imread(str(b), cv2.IMREAD_UNCHANGED)
    return da is not None and db is not None and da.dtype == db.dtype and bool(np.array_equal(da, db))


def check_same_ground_truth(clean: Path, other: Path, split: str, name: str, same_sensor: bool = True) -> None:
    """Refuse a condition's dataset whose ground truth is not the clean dataset's, byte for byte.

    Args:
        clean, other: The two dataset folders.
        split: The split folder compared (with ``camera.json``, ``models/`` and the target lists).
        name: The condition, for the message.
        same_sensor: Both used the same depth sensor: ``depth/`` is compared too (else only the exact depth).

    Raises:
        ConfigError: Naming the first file that differs, is missing or is extra (scene files first, by path).
    """
    a = _ground_truth_files(clean, split, same_sensor)
    b = _ground_truth_files(other, split, same_sensor)
    order = {key: i for i, key in enumerate([*a, *(k for k in b if k not in a)])}
    for key in sorted(set(a) | set(b), key=order.__getitem__):
        if key not in b:
            what = f"{a[key]} has no counterpart in {other}"
        elif key not in a:
            what = f"{b[key]} has no counterpart in the clean dataset {clean}"
        elif not _same_file(a[key], b[key], exact_depth=key.split("/")[2:3] == ["exact-depth"]):
            what = f"{b[key]} differs from the clean {a[key]}"
        else:
            continue
        if any("depth_exact" in f.parts for f in (a.get(key), b.get(key)) if f is not None):
            what += " (exact depth: depth_exact/ of a depth-sensor dataset against depth/, as 16-bit values)"
        raise ConfigError(f"sweep condition {name!r} changed the ground truth: {what}. Its overrides make a "
                          f"different dataset, not a render condition (render conditions may change only rgb/ "
                          f"and, with a depth sensor, depth/); sweep that dataset in a sweep of its own")
