"""Validated configs: frozen dataclass trees read from TOML/JSON with errors that name the field.

:func:`build` turns nested dicts into a dataclass tree, checking unknown keys, types and ranges, and raising
:class:`ConfigError` with the source (file), the dotted field path, the bad value and what is allowed. Field
metadata: :func:`bounds` (numeric range and/or choices), :func:`pair` (a ``[min, max]`` range inside limits),
``{"each": (lo, hi)}`` (every element of a fixed tuple in range).
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from pathlib import Path
from typing import Any, Literal

from simtest.errors import ConfigError

__all__ = ["bounds", "pair", "build", "to_plain", "to_toml", "read_config_file", "config_changes"]


def pair(lo_min: float, hi_max: float):
    """Metadata for a [lo, hi] range field whose values must lie in [lo_min, hi_max]."""
    return {"pair": (lo_min, hi_max)}


def bounds(lo: float | None = None, hi: float | None = None, choices: tuple | None = None):
    return {"bounds": (lo, hi), "choices": choices}


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):  # an inline table, keys quoted
        return "{" + ", ".join(f"{json.dumps(str(k))} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {v!r} as TOML")


def to_plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: to_plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_plain(v) for v in obj]
    return obj


def build(cls: type, data: Any, prefix: str, source: str):
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: {prefix.rstrip('.') or 'config'} must be a table/object, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{source}: unknown field(s) {', '.join(prefix + u for u in unknown)}; "
                          f"allowed in {prefix.rstrip('.') or 'the top level'}: {', '.join(fields)}")
    kwargs = {}
    for name, value in data.items():
        f = fields[name]
        kwargs[name] = _check(hints[name], value, f.metadata, prefix + name, source)
    return cls(**kwargs)


def _check(tp: Any, value: Any, meta: Any, path: str, source: str):
    def bad(allowed: str):
        return ConfigError(f"{source}: {path} = {value!r} is invalid; allowed: {allowed}")

    if dataclasses.is_dataclass(tp):
        return build(tp, value, path + ".", source)
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        tp = next(a for a in args if a is not type(None))
        return _check(tp, value, meta, path, source)
    if origin is Literal:
        if value not in args:
            raise bad(" | ".join(map(repr, args)))
        return value
    choices = meta.get("choices") if meta else None
    if choices and tp is str:
        if value not in choices:
            raise bad(" | ".join(map(repr, choices)))
        return value
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:  # a list of any length
        if not isinstance(value, (list, tuple)):
            raise bad("a list")
        out = tuple(_check(args[0], v, meta if not dataclasses.is_dataclass(args[0]) else {}, f"{path}[{i}]",
                           source) for i, v in enumerate(value))
        if meta and meta.get("nonempty") and not out:
            raise bad("a non-empty list")
        return out
    if origin is dict or tp is dict:
        if not isinstance(value, dict):
            raise bad("a table of key = value")
        return dict(value)
    if origin is tuple:
        if not isinstance(value, (list, tuple)) or len(value) != len(args):
            raise bad(f"a list of {len(args)} numbers")
        out = tuple(_check(a, v, {}, f"{path}[{i}]", source) for i, (a, v) in enumerate(zip(args, value)))
        if "each" in meta:
            lo, hi = meta["each"]
            if not all(lo <= v <= hi for v in out):
                raise bad(f"{len(args)} numbers, each in [{lo}, {hi}]")
        if "pair" in meta:
            lo, hi = meta["pair"]
            if not (lo <= out[0] <= out[1] <= hi):
                raise bad(f"[min, max] with {lo} <= min <= max <= {hi}")
        return out
    if tp is bool:
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad("an integer" + _range_text(meta))
        _in_bounds(value, meta, bad)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
            raise bad("a number" + _range_text(meta))
        _in_bounds(value, meta, bad)
        return float(value)
    if tp is str:
        if not isinstance(value, str) or not value:
            raise bad("a non-empty string")
        return value
    return value  # pragma: no cover


def _range_text(meta: Any) -> str:
    lo, hi = meta.get("bounds", (None, None)) if meta else (None, None)
    if lo is None and hi is None:
        return ""
    return f" in [{lo}, {hi}]"


def _in_bounds(value: float, meta: Any, bad) -> None:
    lo, hi = meta.get("bounds", (None, None)) if meta else (None, None)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise bad(f"[{lo}, {hi}]")


def to_toml(data: dict[str, Any]) -> str:
    """TOML text of a plain nested dict: scalars first, then one table per dict value, arrays of tables for
    lists of dicts (``None`` values are omitted)."""
    top, tables = [], []
    for key, value in data.items():
        if isinstance(value, dict):
            body = [f"{k} = {_toml_value(v)}" for k, v in value.items() if v is not None]
            tables.append(f"[{key}]\n" + "\n".join(body))
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            for item in value:
                body = [f"{k} = {_toml_value(v)}" for k, v in item.items() if v is not None]
                tables.append(f"[[{key}]]\n" + "\n".join(body))
        elif value is not None:
            top.append(f"{key} = {_toml_value(value)}")
    return "\n".join(top) + "\n\n" + "\n\n".join(tables) + "\n"


def read_config_file(path: str | Path) -> dict[str, Any]:
    """Parse a TOML (``.toml``) or JSON (``.json``) file into a dict; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file {str(path)!r} does not exist")
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".json"):
        raise ConfigError(f"config file {str(path)!r}: unsupported extension {path.suffix!r}; use .toml or .json")
    text = _read_utf8(path)
    try:
        if suffix == ".toml":
            try:
                import tomllib
            except ModuleNotFoundError:  # Python 3.10
                import tomli as tomllib  # type: ignore[no-redef]
            return tomllib.loads(text)
        return json.loads(text)
    except ValueError as exc:  # tomllib.TOMLDecodeError and json.JSONDecodeError are ValueErrors
        raise ConfigError(f"config file {str(path)!r} does not parse: {exc}") from exc


def _read_utf8(path: Path) -> str:
    """The text of a config file (UTF-8, an optional byte-order mark dropped); errors name the file and line."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"config file {str(path)!r} cannot be read: {exc.strerror}") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise ConfigError(f"config file {str(path)!r} is not UTF-8 text: byte 0x{raw[exc.start]:02x} at line "
                          f"{line}; save it as UTF-8") from None


def config_changes(old: dict, new: dict, defaults: dict, ignore: tuple[str, ...] = ()) -> list[str]:
    """Where a recorded config ``old`` (plain dicts, as written to a manifest) differs from ``new``, as
    ``"dotted.field (old -> new)"`` strings; empty when a resume may go on.

    A field ``old`` lacks counts as its value in ``defaults`` (output made before the field existed was made as
    its default says), so a new field left at its default is no change. Top-level fields in ``ignore`` say
    where or how fast a run goes, not what it makes (``workers``, ``backend``), and are not compared.
    """
    old = _with_defaults(old, defaults)
    old = {k: v for k, v in old.items() if k not in ignore}
    new = {k: v for k, v in new.items() if k not in ignore}
    return _diff(old, new)


def _with_defaults(old: dict, defaults: dict) -> dict:
    out = dict(old)
    for key, value in defaults.items():
        if key not in out:
            out[key] = value
        elif isinstance(value, dict) and isinstance(out[key], dict):
            out[key] = _with_defaults(out[key], value)
    return out


def _diff(a: Any, b: Any, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            out += _diff(a.get(k), b.get(k), f"{prefix}{k}.")
        return out
    return [] if a == b else [f"{prefix.rstrip('.')} ({a!r} -> {b!r})"]
