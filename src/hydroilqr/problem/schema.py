"""A JSON Schema of task files, generated from the typed configuration (the section modules
of ``problem/``).

``task_schema()`` walks the dataclasses the loader builds a task from (``TaskConfig`` and the
sections it holds) with the same type annotations the loader converts values by, so the schema
cannot drift from the format: a key added to a dataclass is in the schema. Editors read it to
complete and check task files (``hydroilqr schema > task.schema.json`` and the line
``# yaml-language-server: $schema=task.schema.json`` at the top of a task file).

The schema describes what a task file should hold; the loader stays the authority (it also
accepts a few spellings the schema does not, such as a number written as a quoted string, and
checks what a schema cannot: names from the model, files, ranges that depend on other keys).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any

from hydroilqr.problem.cost import NOMINAL_TIMES, CostConfig
from hydroilqr.problem.mpc import PlannerSettings
from hydroilqr.problem.plant import (
    APPROXIMATIONS,
    CONTACT_MODELS,
    SHAPES,
    SURFACES,
    ContactProperties,
    PlantConfig,
    SceneObject,
)
from hydroilqr.problem.receding import WARM_START_TAILS, RecedingHorizonConfig
from hydroilqr.problem.search import (
    SEARCH_METHODS,
    SEARCH_ORDERS,
    SEARCH_SELECTS,
    SEARCH_SPACES,
    SearchConfig,
)
from hydroilqr.problem.solver import DERIVATIVES, SolverConfig
from hydroilqr.problem.task import TaskConfig
from hydroilqr.problem.terms import TermConfig

SCHEMA_DIALECT = "http://json-schema.org/draft-07/schema#"

#: Fields whose strings are one of a fixed set (the values each section's validation takes).
_CHOICES: dict[tuple[type, str], tuple[str, ...]] = {
    (ContactProperties, "compliance"): ("rigid", "compliant"),
    (SceneObject, "shape"): SHAPES,
    (PlantConfig, "contact_approximation"): APPROXIMATIONS,
    (PlantConfig, "contact_model"): CONTACT_MODELS,
    (PlantConfig, "contact_surface_representation"): SURFACES,
    (CostConfig, "nominal_time"): NOMINAL_TIMES,
    (SolverConfig, "derivatives"): DERIVATIVES,
    (RecedingHorizonConfig, "warm_start_tail"): WARM_START_TAILS,
    (PlannerSettings, "warm_start_tail"): WARM_START_TAILS,
    (PlannerSettings, "derivatives"): ("", *DERIVATIVES),
    (SearchConfig, "method"): SEARCH_METHODS,
    (SearchConfig, "space"): SEARCH_SPACES,
    (SearchConfig, "select"): SEARCH_SELECTS,
    (SearchConfig, "order"): SEARCH_ORDERS,
}

_SCALARS = {float: "number", int: "integer", bool: "boolean", str: "string"}


def task_schema() -> dict[str, Any]:
    """The JSON Schema (draft-07) of a task file: every key ``TaskConfig`` reads, plus
    ``extends``; unknown keys are errors, as they are for the loader."""
    definitions: dict[str, Any] = {}
    root = _object_schema(TaskConfig, definitions)
    root.pop("description", None)  # (the title and description below say what it is)
    root["properties"] = {
        "extends": {
            "type": "string",
            "description": "a task file (relative to this one) or built-in task name loaded "
            "first; this file is merged over it key by key",
        },
        **root["properties"],
    }
    return {
        "$schema": SCHEMA_DIALECT,
        "title": "hydroilqr task file",
        "description": "A hydroilqr task (docs/task-format.md); generated from "
        "hydroilqr.problem by `hydroilqr schema`.",
        **root,
        "definitions": definitions,
    }


def task_file_fields(cls: type) -> list[dataclasses.Field]:
    """The fields of a configuration dataclass that a task file may set."""
    return [f for f in dataclasses.fields(cls) if f.init and f.metadata.get("task_file", True)]


def _object_schema(cls: type, definitions: dict[str, Any]) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    properties = {}
    for f in task_file_fields(cls):
        prop = _type_schema(hints[f.name], definitions)
        choices = _choices(cls, f.name)
        if choices:
            prop = (
                {"anyOf": [{"enum": list(choices)}, {"type": "null"}]}
                if _optional(hints[f.name])
                else {"enum": list(choices)}
            )
        default = _default(f)
        # (a required choice, such as a term's type, has no default a file could use)
        if default is not dataclasses.MISSING and (not choices or default in (None, *choices)):
            prop["default"] = default
        properties[f.name] = prop
    out: dict[str, Any] = {"type": "object", "properties": properties}
    out["additionalProperties"] = False
    doc = (cls.__doc__ or "").strip()
    if doc and not doc.startswith(cls.__name__ + "("):  # (not the generated signature)
        out["description"] = " ".join(doc.split())
    return out


def _choices(cls: type, name: str) -> tuple[str, ...] | None:
    """The values a string field takes, if a fixed set: ``_CHOICES``, and a term's ``type``
    (the term types registered when the schema is made)."""
    if name == "type" and issubclass(cls, TermConfig) and cls.kind:
        return (cls.kind,)  # a term type's definition (one per registered type)
    return _CHOICES.get((cls, name)) or _CHOICES.get((_base_with(cls, name), name))


def _base_with(cls: type, name: str) -> type | None:
    """The base class of ``cls`` that declares the field ``name`` (choices are declared there)."""
    for base in cls.__mro__[1:]:
        if dataclasses.is_dataclass(base) and name in {f.name for f in dataclasses.fields(base)}:
            return base
    return None


def _optional(tp: Any) -> bool:
    return typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in (
        typing.get_args(tp)
    )


def _type_schema(tp: Any, definitions: dict[str, Any]) -> dict[str, Any]:
    """The schema of values of the annotation ``tp`` (as ``typed._coerce`` converts them)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return {}
    if origin in (typing.Union, types.UnionType):
        options = [_type_schema(a, definitions) for a in args if a is not type(None)]
        if type(None) in args:
            options.append({"type": "null"})
        return options[0] if len(options) == 1 else {"anyOf": options}
    if dataclasses.is_dataclass(tp):
        name = tp.__name__
        if name not in definitions:
            definitions[name] = {}  # (a placeholder against recursion)
            definitions[name] = _object_schema(tp, definitions)
            if "variants" in vars(tp):  # one of its registered variants (cost terms)
                refs = [_type_schema(v, definitions) for v in tp.variants()]
                doc = definitions[name].get("description")
                definitions[name] = {"anyOf": refs, **({"description": doc} if doc else {})}
        return {"$ref": f"#/definitions/{name}"}
    if origin is list:
        return {"type": "array", "items": _type_schema(args[0], definitions)}
    if origin is dict:
        return {"type": "object", "additionalProperties": _type_schema(args[1], definitions)}
    if tp in _SCALARS:
        return {"type": _SCALARS[tp]}
    raise TypeError(f"no JSON Schema for the annotation {tp!r}")


def _default(f: dataclasses.Field) -> Any:
    """The field's default as plain data (MISSING when it has none or it is a section)."""
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return dataclasses.MISSING
    if dataclasses.is_dataclass(value):
        return dataclasses.MISSING  # a section: its own fields carry their defaults
    return value
