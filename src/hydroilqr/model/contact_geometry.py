"""Contact properties of a task's geometries (hydroelastic or point contact, materials),
their names as a task file gives them, and the checks of its contact pairs
(``model/build.py`` applies them while building a plant)."""

from __future__ import annotations

from pydrake.geometry import (
    AddCompliantHydroelasticProperties,
    AddCompliantHydroelasticPropertiesForHalfSpace,
    AddContactMaterial,
    AddRigidHydroelasticProperties,
    Box,
    CollisionFilterDeclaration,
    Cylinder,
    GeometrySet,
    HalfSpace,
    ProximityProperties,
    Sphere,
)
from pydrake.multibody.plant import CoulombFriction

from hydroilqr.model.names import (
    SCOPE,
    bare,
    body_labels,
    full_body_name,
    scoped_names,
)
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.plant import ContactProperties, SceneObject
from hydroilqr.problem.task import TaskConfig

# ------------------------------------------------------------------------------------------
# Contact properties
# ------------------------------------------------------------------------------------------


# Shapes whose hydroelastic mesh is built from a resolution hint (Drake refuses them without).
NEEDS_RESOLUTION_HINT = ("sphere", "cylinder", "capsule", "ellipsoid")


def _proximity_props(
    p: ContactProperties, old: ProximityProperties | None, shape: str = ""
) -> ProximityProperties:
    """New ProximityProperties: the old material/hydroelastic values overridden by ``p``."""
    props = ProximityProperties()
    _add_material(props, p, old)
    _add_hydroelastic(props, p, old, shape)
    return props


def _old_value(old: ProximityProperties | None, group: str, name: str, default=None):
    """``old``'s value of ``group.name``, ``default`` if it has none."""
    if old is not None and old.HasProperty(group, name):
        return old.GetProperty(group, name)
    return default


def _add_material(props, p: ContactProperties, old: ProximityProperties | None) -> None:
    """Friction, dissipation, point stiffness and relaxation time: ``p``'s, else ``old``'s."""
    friction = _old_value(old, "material", "coulomb_friction")
    if p.friction is not None:
        friction = CoulombFriction(p.friction, p.friction)
    dissipation = p.dissipation
    if dissipation is None:
        dissipation = _old_value(old, "material", "hunt_crossley_dissipation")
    stiffness = _old_value(old, "material", "point_contact_stiffness")
    AddContactMaterial(
        dissipation=dissipation, point_stiffness=stiffness, friction=friction, properties=props
    )
    relaxation = p.relaxation_time
    if relaxation is None:
        relaxation = _old_value(old, "material", "relaxation_time")
    if relaxation is not None:
        props.AddProperty("material", "relaxation_time", relaxation)


def _add_hydroelastic(props, p: ContactProperties, old, shape: str) -> None:
    """The hydroelastic group (compliant, rigid or none) and its margin."""
    old_modulus = _old_value(old, "hydroelastic", "hydroelastic_modulus")
    compliance = _compliance(p, old, shape, old_modulus)
    hint = (
        p.resolution_hint
        if p.resolution_hint is not None
        else _old_value(old, "hydroelastic", "resolution_hint")
    )
    if compliance is not None and hint is None and shape in NEEDS_RESOLUTION_HINT:
        raise ConfigError(
            f"resolution_hint is required for a {compliance} {shape} (the edge length in m of "
            f"its hydroelastic mesh, e.g. a fifth of its radius)"
        )
    if compliance == "compliant":
        modulus = p.hydroelastic_modulus if p.hydroelastic_modulus is not None else old_modulus
        if modulus is None:
            raise ConfigError("compliant geometry needs hydroelastic_modulus")
        if shape == "halfspace":
            slab = p.slab_thickness or _old_value(old, "hydroelastic", "slab_thickness", 1.0)
            AddCompliantHydroelasticPropertiesForHalfSpace(slab, modulus, props)
        else:
            AddCompliantHydroelasticProperties(hint if hint else 0.1, modulus, props)  # box: unused
    elif compliance == "rigid":
        if shape == "halfspace" or hint is None:
            AddRigidHydroelasticProperties(props)
        else:
            AddRigidHydroelasticProperties(hint, props)
    margin = p.margin if p.margin is not None else _old_value(old, "hydroelastic", "margin")
    if margin is not None and compliance is not None:
        props.AddProperty("hydroelastic", "margin", margin)


def _compliance(p: ContactProperties, old, shape: str, old_modulus) -> str | None:
    """The compliance ("compliant", "rigid", or None: no hydroelastic group): ``p``'s, else
    inferred from the modulus and the old properties."""
    if p.compliance is not None:
        return p.compliance
    if p.hydroelastic_modulus is not None or old_modulus is not None:
        return "compliant"
    if (old is not None and old.HasGroup("hydroelastic")) or (old is None and shape):
        return "rigid"
    return None


def _shape(o: SceneObject):
    if o.shape == "box":
        return Box(*o.size)
    if o.shape == "sphere":
        return Sphere(o.radius)
    if o.shape == "cylinder":
        return Cylinder(o.radius, o.length)
    return HalfSpace()


class GeometryNames(dict):
    """GeometryId value -> (collision label, body label): the names shown, scoped by the model
    where two models share them (``model/names.py``); ``full`` holds (MODEL::GEOMETRY,
    MODEL::BODY) per id, so a key may always name the model."""

    full: dict


def _name_matches(label: str, full: str, key: str) -> bool:
    return key in (label, full) or (SCOPE not in key and bare(label) == key)


def geometry_hits(key: str, geoms: dict) -> list:
    """Geometries a ``geometry:`` key names: a body (all its collision geometries), every
    collision geometry of that name (e.g. all fingertips), or one ``BODY/GEOMETRY``; each name
    as labelled, as ``MODEL::NAME``, or bare. A key that names bodies of several models, or a
    body and also a collision name elsewhere, is an error (which was meant?)."""
    full = getattr(geoms, "full", None) or dict(geoms)

    def by(field: int, name: str) -> list:
        return [g for g, v in geoms.items() if _name_matches(v[field], full[g][field], name)]

    if "/" in key:
        body, name = key.split("/", 1)
        inside = set(by(1, body))
        return [g for g in by(0, name) if g in inside]
    by_body, by_name = by(1, key), by(0, key)
    where = sorted({geoms[g][1] for g in by_body + by_name})
    bodies = sorted({geoms[g][1] for g in by_body})
    if len(bodies) > 1:
        raise ConfigError(
            f"geometry.{key}: ambiguous, it names the bodies {', '.join(bodies)}; write one "
            "of them (MODEL::NAME)"
        )
    if by_body and len(where) > 1:
        raise ConfigError(
            f"geometry.{key}: ambiguous, it names geometry on bodies {', '.join(where)}; "
            f"write BODY/{bare(key)} (e.g. {where[0]}/{bare(key)})"
        )
    return by_body or by_name


def named_geometries(key: str, geoms: dict, where: str) -> list:
    """``geometry_hits``, or a ConfigError naming ``where`` and the known names if none."""
    hits = geometry_hits(key, geoms)
    if not hits:
        known = sorted({n for n, _ in geoms.values()} | {b for _, b in geoms.values()})
        raise ConfigError(
            f"{where}: no collision geometry or body named {key!r} (known: {', '.join(known)})"
        )
    return hits


def collision_geometries(plant, scene_graph) -> GeometryNames:
    """GeometryId value -> (collision label, body label): names without their model scope,
    scoped (``MODEL::NAME``) where two models share one (``model/names.py``)."""
    inspector = scene_graph.model_inspector()
    bodies = body_labels(plant)
    ids, items, full = [], [], {}
    for gid in inspector.GetAllGeometryIds():
        if inspector.GetProximityProperties(gid) is None:
            continue
        body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
        name = inspector.GetName(gid).split(SCOPE)[-1]
        world = body is None or body.index() == plant.world_body().index()
        model = "" if world else plant.GetModelInstanceName(body.model_instance())
        ids.append((gid, "world" if world else bodies[int(body.index())]))
        items.append((model, name))
        full[gid] = (
            name if world else f"{model}{SCOPE}{name}",
            "world" if world else full_body_name(plant, body),
        )
    out = GeometryNames({g: (label, b) for (g, b), label in zip(ids, scoped_names(items))})
    out.full = full
    return out


def hydroelastic_kind(props) -> str:
    """ "compliant", "rigid" or "none" for a geometry's ProximityProperties (or None).

    Drake's compliance type is not readable from Python; it is inferred: a hydroelastic
    modulus means compliant, any other hydroelastic property means rigid.
    """
    if props is None or not props.HasGroup("hydroelastic"):
        return "none"
    if props.HasProperty("hydroelastic", "hydroelastic_modulus"):
        return "compliant"
    return "rigid"


def check_contact_pairs(task: TaskConfig, plant, scene_graph) -> None:
    """Rejects collision pairs Drake cannot give a hydroelastic contact surface, naming them:
    a compliant half space against another compliant geometry (always: under the fallback model
    Drake would silently use point contact), and with ``contact_model: hydroelastic`` also
    rigid-rigid pairs and pairs where a geometry has no hydroelastic properties."""
    inspector = scene_graph.model_inspector()
    names = collision_geometries(plant, scene_graph)
    scene_index = {(o.name or f"scene_{i}"): i for i, o in enumerate(task.scene)}

    def label(gid) -> str:
        name, body = names.get(gid, ("?", "?"))
        if body == "world" and name in scene_index:
            return f"scene[{scene_index[name]}] ({name})"
        return f"geometry {name} (body {body})"

    strict = task.plant.contact_model == "hydroelastic"
    for a, b in inspector.GetCollisionCandidates():
        ka = hydroelastic_kind(inspector.GetProximityProperties(a))
        kb = hydroelastic_kind(inspector.GetProximityProperties(b))
        half = [g for g in (a, b) if isinstance(inspector.GetShape(g), HalfSpace)]
        if ka == kb == "compliant" and half:
            other = b if half[0] == a else a
            raise ConfigError(
                f"{label(half[0])}: a compliant half space cannot touch the compliant "
                f"{label(other)} (Drake has no hydroelastic contact between them); make one "
                "of them rigid, or use a compliant box instead of the half space"
            )
        if strict and (ka == kb == "rigid" or "none" in (ka, kb)):
            why = "both rigid" if ka == kb == "rigid" else "one has no hydroelastic properties"
            raise ConfigError(
                f"plant.contact_model: hydroelastic cannot handle the pair {label(a)} / "
                f"{label(b)} ({why}); use hydroelastic_with_fallback or set its compliance"
            )


def _exclude_scene_contacts(task: TaskConfig, plant, scene_graph, scene_ids: list) -> None:
    """Applies each scene object's ``no_contact_with`` as a SceneGraph collision filter.
    scene_ids: the GeometryId of each entry of ``task.scene``."""
    if not any(o.no_contact_with for o in task.scene):
        return
    geoms = collision_geometries(plant, scene_graph)
    manager = scene_graph.collision_filter_manager()
    for i, (o, gid) in enumerate(zip(task.scene, scene_ids)):
        for key in o.no_contact_with:
            hits = named_geometries(key, geoms, f"scene[{i}].no_contact_with")
            manager.Apply(
                CollisionFilterDeclaration().ExcludeBetween(GeometrySet(gid), GeometrySet(hits))
            )
