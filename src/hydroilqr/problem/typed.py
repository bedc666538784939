"""Typed building: YAML data converted to the configuration dataclasses by their annotations,
with the key path in every error message."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any

from hydroilqr.problem.checks import unknown_key
from hydroilqr.problem.errors import ConfigError


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp)).replace("typing.", "")


def _coerce(value: Any, tp: Any, key: str) -> Any:
    """Converts a YAML value to type ``tp`` (from the dataclass annotations)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return plain_data(value, key)
    if origin in (typing.Union, types.UnionType):
        return _coerce_union(value, args, key)
    if dataclasses.is_dataclass(tp):
        return _coerce_dataclass(value, tp, key)
    if origin is list:
        return _coerce_list(value, args[0], key)
    if origin is dict:
        return _coerce_dict(value, args[1], key)
    scalar = _SCALARS.get(tp)
    if scalar is not None:
        return scalar(value, key)
    raise ConfigError(f"{key}: unsupported type {_type_name(tp)}")


#: Deepest nesting of lists and mappings a task's value may have (a task file needs a few).
MAX_DEPTH = 32


def plain_data(value: Any, key: str) -> Any:
    """``value`` if it is YAML data (None, booleans, numbers, strings, lists and mappings with
    string keys of them), nested at most MAX_DEPTH deep; ConfigError naming ``key`` otherwise
    (a complex number or another Python object from a dict, nesting a file cannot mean)."""
    stack = [(value, key, 0)]
    while stack:
        v, where, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise ConfigError(f"{key}: nested more than {MAX_DEPTH} levels deep")
        if isinstance(v, dict):
            for k, item in v.items():
                if not isinstance(k, (str, int, float, bool)) or isinstance(k, complex):
                    raise ConfigError(f"{where}: a key that is not a name: {type(k).__name__}")
                stack.append((item, f"{where}.{k}", depth + 1))
        elif isinstance(v, (list, tuple)):
            stack.extend((item, f"{where}[{i}]", depth + 1) for i, item in enumerate(v))
        elif not (v is None or isinstance(v, (str, bool, int, float))):
            raise ConfigError(f"{where}: expected YAML data, got a {type(v).__name__}")
    return value


def _coerce_union(value: Any, args: tuple, key: str) -> Any:
    """The first of ``args`` that ``value`` converts to (None for None when allowed)."""
    if value is None and type(None) in args:
        return None
    errors, fitting = [], []
    for a in args:
        if a is type(None):
            continue
        try:
            return _coerce(value, a, key)
        except ConfigError as e:
            errors.append(str(e))
            if _same_shape(value, a):  # (a mapping's error is its own key's, not "a string")
                fitting.append(str(e))
    raise ConfigError((fitting or errors or [f"{key}: invalid value {value!r}"])[0])


def _same_shape(value: Any, tp: Any) -> bool:
    """Whether ``value`` is of the kind ``tp`` holds: a mapping for a section or a mapping
    type, a list for a list type, a scalar for a scalar type."""
    origin = typing.get_origin(tp)
    mapping = dataclasses.is_dataclass(tp) or origin is dict
    if isinstance(value, dict):
        return mapping
    if isinstance(value, (list, tuple)):
        return origin is list
    return not mapping and origin is not list


def _coerce_dataclass(value: Any, tp: Any, key: str) -> Any:
    """A section's mapping; for a class with registered variants (``variant(data, key)``: a
    cost term by its type), the variant its data names."""
    variant = getattr(tp, "variant", None)
    if variant is not None:
        tp, value = variant(value, key)
    if value is None:
        value = {}
    if not isinstance(value, dict):
        raise ConfigError(f"{key}: expected a mapping, got {value!r}")
    return build_dataclass(tp, value, key)


def _coerce_list(value: Any, item: Any, key: str) -> list:
    if value is None:
        return []
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{key}: expected a list, got {value!r}")
    return [_coerce(v, item, f"{key}[{i}]") for i, v in enumerate(value)]


def _coerce_dict(value: Any, item: Any, key: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{key}: expected a mapping, got {value!r}")
    return {str(k): _coerce(v, item, f"{key}.{k}") for k, v in value.items()}


def _coerce_float(value: Any, key: str) -> float:
    if isinstance(value, bool):
        raise ConfigError(f"{key}: expected a number, got {value!r}")
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ConfigError(f"{key}: expected a number, got {value!r}") from None
    if not isinstance(value, (int, float)):
        raise ConfigError(f"{key}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{key}: expected a finite number, got {value!r}")
    return float(value)


def _coerce_int(value: Any, key: str) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, str):
        try:
            value = int(value)
        except ValueError:
            raise ConfigError(f"{key}: expected an integer, got {value!r}") from None
    if not isinstance(value, int) or isinstance(value, bool):
        raise ConfigError(f"{key}: expected an integer, got {value!r}")
    return value


def _coerce_bool(value: Any, key: str) -> bool:
    if isinstance(value, str) and value.lower() in ("true", "false", "yes", "no", "1", "0"):
        return value.lower() in ("true", "yes", "1")
    if not isinstance(value, bool):
        raise ConfigError(f"{key}: expected true/false, got {value!r}")
    return value


def _coerce_str(value: Any, key: str) -> str:
    if isinstance(value, (dict, list)) or value is None:
        raise ConfigError(f"{key}: expected a string, got {value!r}")
    return str(value)


#: The converters of the scalar types a task file's fields have.
_SCALARS = {float: _coerce_float, int: _coerce_int, bool: _coerce_bool, str: _coerce_str}


def build_dataclass(cls: Any, data: dict[str, Any], prefix: str) -> Any:
    """An instance of the dataclass ``cls`` from the mapping ``data`` (the keys a task file
    may set: fields without ``task_file: False`` metadata), each value converted to its
    field's type; a class with a ``check_keys(data, prefix)`` method checks what depends on
    which keys were given."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init and f.metadata.get("task_file", 1)}
    kwargs = {}
    for k, v in data.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if k not in names:
            raise ConfigError(f"{key}: {unknown_key(k, sorted(names), 'key')}")
        kwargs[k] = _coerce(v, hints[k], key)
    obj = cls(**kwargs)
    check = getattr(obj, "check_keys", None)
    if check is not None:
        check(data, prefix)
    return obj
