"""Names of bodies and collision geometries, scoped by their model where they collide.

Two models may share a body name (Drake's acrobot and Drake's ``simple_cuboid`` both have a
``base_link``). Such a body's *label* is ``MODEL::NAME`` (the model instance's name, as the
task's ``models[].name`` sets it); a name no other model uses keeps its bare label. Every
place that takes a name accepts the label, ``MODEL::NAME`` whatever the label, and the bare
name when it names one body only (``find_body``; geometry keys: ``plant.geometry_hits``).
"""

from __future__ import annotations

from pydrake.multibody.tree import BodyIndex

from hydroilqr.problem.errors import ConfigError

SCOPE = "::"


def bare(name: str) -> str:
    """The name without its model scope."""
    return name.rsplit(SCOPE, 1)[-1]


def scoped_names(items: list[tuple[str, str]]) -> list[str]:
    """Labels of (model, name) items: ``name``, or ``model::name`` where another model has an
    item of that name."""
    models: dict[str, set] = {}
    for model, name in items:
        models.setdefault(name, set()).add(model)
    return [f"{m}{SCOPE}{n}" if m and len(models[n]) > 1 else n for m, n in items]


def _bodies(plant) -> list:
    return [plant.get_body(BodyIndex(i)) for i in range(plant.num_bodies())]


def body_labels(plant) -> dict[int, str]:
    """BodyIndex value -> the body's label (the world body is ``world``)."""
    bodies = _bodies(plant)
    items = [(plant.GetModelInstanceName(b.model_instance()), b.name()) for b in bodies]
    labels = scoped_names(items)
    out = {int(b.index()): label for b, label in zip(bodies, labels)}
    out[int(plant.world_body().index())] = "world"
    return out


def body_label(plant, body) -> str:
    return body_labels(plant)[int(body.index())]


def full_body_name(plant, body) -> str:
    """``MODEL::NAME`` of a body (``world`` for the world)."""
    if body.index() == plant.world_body().index():
        return "world"
    return f"{plant.GetModelInstanceName(body.model_instance())}{SCOPE}{body.name()}"


def body_matches(plant, body, label: str, name: str) -> bool:
    """``name`` names ``body`` (its label ``label``): the label, MODEL::NAME or the bare name."""
    if name in (label, full_body_name(plant, body)):
        return True
    return SCOPE not in name and bare(label) == name


def find_body(plant, name, key: str, exclude: set | None = None):
    """The body ``name`` names (the label, MODEL::NAME, or a bare name that one body has), or a
    ConfigError naming ``key`` and the known labels. ``exclude``: labels not to offer."""
    labels = body_labels(plant)
    exclude = exclude or set()
    hits = []
    if isinstance(name, str):
        for b in _bodies(plant):
            label = labels[int(b.index())]
            if label not in exclude and body_matches(plant, b, label, name):
                hits.append(b)
    known = [v for v in labels.values() if v not in exclude]
    if len(hits) > 1:
        raise ConfigError(
            f"{key}: {name!r} names several bodies "
            f"({', '.join(labels[int(b.index())] for b in hits)}); write MODEL::NAME"
        )
    if not hits:
        raise ConfigError(f"{key}: no body named {name!r} (known: {', '.join(known)})")
    return hits[0]


def actuator_names(plant) -> dict[str, object]:
    """Every name of each joint actuator -> the actuator: its label (``MODEL::NAME`` where
    two models share the name), ``MODEL::NAME`` always, and the bare name where it is
    unique; in the plant's actuator order (labels first)."""
    acts = [plant.get_joint_actuator(i) for i in plant.GetJointActuatorIndices()]
    items = [(plant.GetModelInstanceName(a.model_instance()), a.name()) for a in acts]
    labels = scoped_names(items)
    out: dict[str, object] = dict(zip(labels, acts))
    for (model, name), a in zip(items, acts):
        out.setdefault(f"{model}{SCOPE}{name}", a)
        if sum(n == name for _, n in items) == 1:
            out.setdefault(name, a)
    return out


def actuator_labels(plant) -> list[str]:
    """The actuators' labels in the plant's order (``actuator_names``)."""
    acts = [plant.get_joint_actuator(i) for i in plant.GetJointActuatorIndices()]
    return scoped_names([(plant.GetModelInstanceName(a.model_instance()), a.name()) for a in acts])


__all__ = ["bare", "body_label", "body_labels", "find_body", "scoped_names"]
