"""Estimator options: parsing ``--opt KEY=VALUE`` from the command line, and checking option names and types
against an estimator's signature (the names it accepts, the types of their defaults)."""

from __future__ import annotations

import ast
import inspect
import numbers
from collections.abc import Callable
from typing import Any

from simtest.errors import ConfigError

__all__ = ["parse_value", "parse_options", "option_signature", "check_options", "check_int_options"]


def check_int_options(who: str, *options: tuple[str, Any, int]) -> None:
    """Raise :class:`ConfigError` unless every ``(name, value, lo)`` is an integer (not a bool) ``>= lo``; the
    message names the estimator ``who``, the option, its value and what is allowed."""
    for name, value, lo in options:
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < lo:
            raise ConfigError(f"{who}: {name} must be an integer >= {lo}, got {value!r}")


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


def check_options(spec: str, factory: Callable, options: dict[str, Any]) -> None:
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
            spelled = " (write true or false)" if isinstance(default, bool) else ""
            raise ConfigError(f"estimator {spec!r}: bad options: {name} = {value!r} has the wrong type; expected "
                              f"{type(default).__name__}{spelled} (default {default!r}); valid options: "
                              f"{option_signature(factory)}")
