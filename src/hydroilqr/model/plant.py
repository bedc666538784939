"""Discrete dynamics x_{k+1} = f(x_k, u_k) (paper eq. 2) from a task's models and contact config.

``build_diagram`` assembles MultibodyPlant + SceneGraph (and, on request, Meshcat and contact
visualizers) from a ``TaskConfig``; ``Dynamics`` wraps the plant-only diagram with ``step`` and
``rollout``. Two Drake traps are handled here (see drake-notes.md): the plant is built with
``use_sampled_output_ports=False`` so that a forced discrete update really steps, and the
contact approximation is chosen explicitly (``tamsi`` only to reproduce the paper).
"""

from __future__ import annotations

import contextlib
import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
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
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    ProximityProperties,
    Role,
    RoleAssign,
    SceneGraph,
    Sphere,
)
from pydrake.geometry import HydroelasticContactRepresentation as Rep
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.meshcat import ContactVisualizer, ContactVisualizerParams
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import DiagramBuilder

from hydroilqr.model.names import (
    SCOPE,
    actuator_labels,
    actuator_names,
    bare,
    body_labels,
    full_body_name,
    scoped_names,
)
from hydroilqr.model.state import StateLayout
from hydroilqr.problem.checks import unknown_key
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import (
    MAX_MESH_BYTES,
    MAX_MODEL_BYTES,
    check_file,
    model_file_references,
    read_bounded,
)
from hydroilqr.problem.plant import (
    ContactProperties,
    PlantSpec,
    SceneObject,
)
from hydroilqr.problem.task import TaskConfig

# A state beyond this (m, rad, m/s, rad/s) is a blown-up simulation, not a motion.
DIVERGED = 1e6


class _NoDeformableNotice(logging.Filter):
    """Drops Drake's notice, on registering any HalfSpace, that half spaces do not touch
    deformable bodies: this project has none, and the notice reads like a problem."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "not currently supported for deformable contact" not in record.getMessage()


logging.getLogger("drake").addFilter(_NoDeformableNotice())


class SimulationError(RuntimeError):
    """A time step failed (contact solver did not converge, or the state became non-finite)."""


@dataclass
class Scene:
    """A built diagram and handles into it."""

    diagram: object
    plant: object
    scene_graph: object
    actuation_port: int  # diagram input port index of the plant's actuation
    force_port: int = -1  # diagram input port index of the plant's applied generalized force
    meshcat: object | None = None
    visualizers: tuple = ()
    # The model files' joint position limits [nq] each (±inf where none), also where
    # ``plant.joint_limits: false`` removed them from the plant.
    position_limits: tuple = ()


class AutoDiffPlant(NamedTuple):
    """The AutoDiffXd copy of a task's diagram (``Dynamics.autodiff``); unpacks as the tuple
    (diagram, context, plant, plant_context, input_port) it used to be."""

    diagram: object
    context: object
    plant: object
    plant_context: object
    input_port: object  # the diagram's actuation input port


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


_POSITION_UNITS = {"prismatic": "m", "revolute": "rad", "quaternion_floating": "m"}


def position_unit(joint) -> str:
    """The unit of a Drake joint's position coordinates: "m" (prismatic, a floating body's
    position), "rad" (revolute), "" for other joint types."""
    return _POSITION_UNITS.get(joint.type_name(), "")


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


# ------------------------------------------------------------------------------------------
# Building
# ------------------------------------------------------------------------------------------


def _add_model(task: TaskConfig, plant, scene_graph, parser, m, key: str) -> list:
    """Parses one ``models`` entry; with ``name``, its model instance gets that name (a parser
    of its own scopes the file's names under it first, so a second copy does not clash)."""
    if m.name:
        if plant.HasModelInstanceNamed(m.name):
            raise ConfigError(f"{key}.name: a model instance named {m.name!r} exists already")
        own = Parser(plant, scene_graph, model_name_prefix=m.name)
        _add_packages(task, own.package_map())
        parser = own
    check_model_references(_model_path(task, parser, m, key), parser.package_map(), f"{key}.file")
    try:
        with _drake_warnings() as warnings:
            if m.file.startswith("package://"):
                instances = parser.AddModels(url=m.file)
            else:
                instances = parser.AddModels(str(task.resolve_path(m.file)))
    except Exception as e:
        _refuse_failed_download(str(e), f"{key}.file", m.file)
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ConfigError(f"{key}.file: could not parse {m.file}: {msg}") from None
    _refuse_replaced_inertia(warnings, f"{key}.file: {m.file}")
    if m.name and len(instances) == 1:
        plant.RenameModelInstance(instances[0], m.name)
    return instances


def _model_path(task: TaskConfig, parser, m, key: str) -> Path | None:
    """The model file of a ``models`` entry (None: a package it cannot resolve; Drake says;
    a package Drake could not download: ConfigError saying how to name a local copy)."""
    if not m.file.startswith("package://"):
        return task.resolve_path(m.file)
    try:
        with _drake_warnings():  # (holds back Drake's "Downloading" line)
            return Path(parser.package_map().ResolveUrl(m.file))
    except Exception as e:  # noqa: BLE001 - AddModels reports the unknown package
        _refuse_failed_download(str(e), f"{key}.file", m.file)
        return None


def _add_packages(task: TaskConfig, package_map) -> None:
    """The task's ``package_map`` on a parser's; a name Drake knows already (its
    ``drake_models``, downloaded on first use) is replaced by the task's local directory."""
    for name, path in task.package_map.items():
        where = task.resolve_path(path)
        if not where.is_dir():
            raise ConfigError(f"package_map.{name}: {where} is not a directory")
        if package_map.Contains(name):
            package_map.Remove(name)
        package_map.Add(name, str(where))


def _refuse_failed_download(message: str, key: str, url: str) -> None:
    """ConfigError if ``message`` is Drake's failure to download a remote package (such as
    ``drake_models``): this machine is offline or blocked; a local copy named in the task's
    ``package_map`` needs no download."""
    pkg = re.search(r"when downloading '([^']+)'", message)
    if pkg is None:
        return
    archive = re.search(r"Candidate (\S+) failed", message)
    source = f" (unpack {archive[1]})" if archive else ""
    raise ConfigError(
        f"{key}: {url} is in Drake's package {pkg[1]!r}, which Drake downloads on first use, "
        f"and the download failed (offline?); use a local copy{source}: package_map: "
        f"{{{pkg[1]}: DIRECTORY}}"
    )


MODEL_INCLUDE_DEPTH = 8  # included model files followed at most this deep


def check_model_references(path: Path | None, package_map, key: str, depth: int = 0) -> None:
    """Every file the model file ``path`` names (meshes, visual or collision, and included
    models, followed) is a regular file within its size cap: ConfigError naming the model
    and the file otherwise, before Drake reads any (a mesh that is /dev/zero or a named pipe
    would exhaust memory or wait forever). An included model that does not exist is an
    error too (Drake's SDFormat parser may drop it); other references it cannot resolve
    (a package it does not know, a missing mesh) are left to Drake."""

    if path is None or depth > MODEL_INCLUDE_DEPTH:
        return
    data = read_bounded(path, f"{key}:", MAX_MODEL_BYTES)
    text = data.decode("utf-8", errors="replace")
    for ref, include in model_file_references(text):
        what = f"{key}: {path.name} names"
        target = _resolve_reference(ref, path.parent, package_map, what)
        if target is None or target.is_dir():
            continue  # (a model directory, an unknown package: Drake resolves or reports it)
        if not (target.exists() or target.is_symlink()):
            if include:
                raise ConfigError(f"{what} {ref}, which does not exist ({target})")
            continue  # (a missing mesh: Drake reports it)
        check_file(target, what, MAX_MODEL_BYTES if include else MAX_MESH_BYTES)
        if include:
            check_model_references(target, package_map, key, depth + 1)


def _resolve_reference(ref: str, directory: Path, package_map, what: str) -> Path | None:
    if ref.startswith(("package://", "model://")):
        try:
            with _drake_warnings():  # (holds back Drake's "Downloading" line)
                return Path(package_map.ResolveUrl(ref))
        except Exception as e:  # noqa: BLE001 - an unknown package: Drake reports it
            _refuse_failed_download(str(e), what, ref)
            return None
    if "://" in ref and not ref.startswith("file://"):
        return None  # (a remote resource)
    ref = ref.removeprefix("file://")
    p = Path(ref).expanduser()
    return p if p.is_absolute() else directory / p


@contextlib.contextmanager
def _drake_warnings():
    """The messages Drake logs (pydrake's "drake" logger) inside the block, as a list; held
    back while it runs and logged as usual after it unless ``_refuse_replaced_inertia``
    turns one into the command's one error line."""

    class _Collect(logging.Handler):
        def emit(self, record):
            records.append(record)
            messages.append(record.getMessage())

    records: list = []
    messages: list[str] = []
    logger = logging.getLogger("drake")
    saved = (logger.handlers[:], logger.propagate)
    logger.handlers[:] = [_Collect(logging.WARNING)]
    logger.propagate = False
    try:
        yield messages
    finally:
        logger.handlers[:], logger.propagate = saved
    if not any(_replaced_inertia(m) for m in messages):
        for record in records:
            logger.handle(record)


def _replaced_inertia(message: str) -> bool:
    return "inertia" in message.lower() or "mass >" in message


def _refuse_replaced_inertia(messages: list[str], where: str) -> None:
    """Drake parses an ``<inertial>`` that no body has (a negative mass, an impossible
    inertia) with a warning and a made-up inertia in its place: refused here, naming the
    line."""

    for msg in messages:
        if _replaced_inertia(msg):
            line = re.search(r":(\d+): warning:", msg)
            at = f" line {line[1]}" if line else ""
            raise ConfigError(
                f"{where}{at}: a mass or inertia no physical body has (a mass must be > 0, "
                "each moment of inertia at most the sum of the other two)"
            )


def apply_actuators(task: TaskConfig, plant) -> None:
    """The task's ``actuators`` section on the (unfinalized) plant's JointActuators: effort
    limit, rotor inertia and gear ratio (Drake adds the reflected inertia ρ·G² to the joint's
    diagonal of the mass matrix). An unknown actuator name is a ConfigError naming the valid
    ones."""
    if not task.actuators:
        return
    acts = actuator_names(plant)  # labels, MODEL::NAME, unique bare names
    for name, cfg in task.actuators.items():
        a = acts.get(name)
        if a is None:
            known = actuator_labels(plant)
            raise ConfigError(f"actuators.{name}: {unknown_key(name, known, 'actuator')}")
        if cfg.effort_limit is not None:
            a.set_effort_limit(float(cfg.effort_limit))
        if cfg.rotor_inertia is not None:
            a.set_default_rotor_inertia(float(cfg.rotor_inertia))
        if cfg.gear_ratio is not None:
            a.set_default_gear_ratio(float(cfg.gear_ratio))


def build_diagram(task: TaskConfig, meshcat=None, contact_visualizer: bool = True) -> Scene:
    """Builds the task's diagram. With ``meshcat``, adds MeshcatVisualizer + ContactVisualizer."""
    builder = DiagramBuilder()
    config = MultibodyPlantConfig(
        time_step=task.plant.time_step,
        discrete_contact_approximation=task.plant.contact_approximation,
        contact_model=task.plant.contact_model,
        contact_surface_representation=task.plant.contact_surface_representation,
        use_sampled_output_ports=False,
    )
    try:
        plant, scene_graph = AddMultibodyPlant(config, builder)
    except Exception as e:  # Drake rejects bad enum strings with a long message
        raise ConfigError(f"plant: {str(e).splitlines()[0]}") from None
    _add_models(task, plant, scene_graph)
    scene_ids = _add_scene(task, plant)
    _override_geometry(task, plant, scene_graph)
    plant.mutable_gravity_field().set_gravity_vector(np.asarray(task.plant.gravity, dtype=float))
    apply_actuators(task, plant)
    check_inertias(plant)
    limits = _model_position_limits(plant, keep=task.plant.joint_limits)
    plant.Finalize()
    lower = np.full(plant.num_positions(), -np.inf)
    upper = np.full(plant.num_positions(), np.inf)
    for j, (lo, hi) in limits.items():
        joint = plant.get_joint(j)
        lower[joint.position_start() : joint.position_start() + joint.num_positions()] = lo
        upper[joint.position_start() : joint.position_start() + joint.num_positions()] = hi
    _exclude_scene_contacts(task, plant, scene_graph, scene_ids)
    check_contact_pairs(task, plant, scene_graph)
    if plant.num_actuated_dofs() == 0:
        raise ConfigError("models: the model has no actuated joints")
    port = builder.ExportInput(plant.get_actuation_input_port(), "actuation")
    # Unfixed (so zero) except in the finite differences over generalized forces (derivatives).
    force_port = builder.ExportInput(
        plant.get_applied_generalized_force_input_port(), "generalized_force"
    )

    visualizers = _add_visualizers(builder, plant, scene_graph, meshcat, contact_visualizer)
    diagram = builder.Build()
    return Scene(
        diagram,
        plant,
        scene_graph,
        int(port),
        int(force_port),
        meshcat,
        visualizers,
        (lower, upper),
    )


def _model_position_limits(plant, keep: bool) -> dict:
    """JointIndex -> (lower, upper) position limits of every joint the model files limit, read
    from the unfinalized plant; without ``keep`` they are removed from it (±inf)."""
    out = {}
    for j in plant.GetJointIndices():
        joint = plant.get_joint(j)
        lo, hi = joint.position_lower_limits(), joint.position_upper_limits()
        if np.all(np.isinf(lo)) and np.all(np.isinf(hi)):
            continue
        out[j] = (np.array(lo, float), np.array(hi, float))
        if not keep:
            n = joint.num_positions()
            joint.set_position_limits(np.full(n, -np.inf), np.full(n, np.inf))
    return out


def check_inertias(plant) -> None:
    """ConfigError naming the first body whose mass or rotational inertia no physical body
    has (a negative or non-finite mass, an inertia that violates the triangle inequality):
    Drake would simulate it, into nonsense."""

    for i in range(1, plant.num_bodies()):  # (0: the world)
        body = plant.get_body(BodyIndex(i))
        mass = body.default_mass()
        if not np.isfinite(mass) or mass < 0:
            raise ConfigError(f"models: body {body.name()!r} has mass {mass:g}: not a mass")
        if not body.default_spatial_inertia().IsPhysicallyValid():
            raise ConfigError(
                f"models: body {body.name()!r} has a rotational inertia no body has (negative "
                "moments, or one larger than the other two together)"
            )


def _add_models(task: TaskConfig, plant, scene_graph) -> None:
    """The task's model files (packages from its package_map) and their welds."""
    parser = Parser(plant)
    _add_packages(task, parser.package_map())
    for i, m in enumerate(task.models):
        instances = _add_model(task, plant, scene_graph, parser, m, f"models[{i}]")
        for inst in instances:  # (Drake: each model instance's gravity on or off)
            plant.set_gravity_enabled(inst, m.gravity)
        welds = [(f"models[{i}].weld", m.weld)] if m.weld is not None else []
        welds += [(f"models[{i}].welds[{j}]", w) for j, w in enumerate(m.welds)]
        for wkey, w in welds:
            _weld(plant, instances, wkey, w)


def _frame_named(plant, name: str):
    """The frame ``name`` names: ``world``, ``MODEL::FRAME`` or a frame name unique in the
    plant (Drake's lookup refuses a name two models share)."""
    if name == "world":
        return plant.world_frame()
    if "::" in name:
        model, frame = name.rsplit("::", 1)
        return plant.GetFrameByName(frame, plant.GetModelInstanceByName(model))
    return plant.GetFrameByName(name)


def _has_frame_named(plant, name: str) -> bool:
    try:
        _frame_named(plant, name)
    except Exception:  # noqa: BLE001 - any lookup failure: no such frame
        return False
    return True


def _weld(plant, instances, wkey: str, w) -> None:
    """Welds ``w.child`` (a frame of ``instances``) to ``w.parent`` at (xyz, rpy)."""
    try:
        parent = _frame_named(plant, w.parent)
        child = None
        for inst in instances:  # the child is a frame of this model, not another's
            if plant.HasFrameNamed(w.child, inst):
                child = plant.GetFrameByName(w.child, inst)
        if child is None:
            raise KeyError(w.child)
    except Exception:
        bad = "parent" if not _has_frame_named(plant, w.parent) else "child"
        frames = sorted(
            {plant.get_frame(f).name() for inst in instances for f in plant.GetFrameIndices(inst)}
        )
        raise ConfigError(
            f"{wkey}.{bad}: unknown frame {getattr(w, bad)!r} "
            f"(frames of the model: {', '.join(frames)})"
        ) from None
    X = RigidTransform(RollPitchYaw(w.rpy), np.asarray(w.xyz, dtype=float))
    try:
        plant.WeldFrames(parent, child, X)
    except Exception as e:
        raise ConfigError(f"{wkey}: {str(e).strip().splitlines()[0]}") from None


def _add_scene(task: TaskConfig, plant) -> list:
    """Static scene geometry, welded to the world; its collision geometry ids."""
    world = plant.world_body()
    scene_ids = []
    for i, o in enumerate(task.scene):
        X = RigidTransform(RollPitchYaw(o.rpy), np.asarray(o.xyz, dtype=float))
        try:
            props = _proximity_props(o, None, shape=o.shape)
        except ConfigError as e:
            raise ConfigError(f"scene[{i}] ({o.name}): {e}") from None
        name = o.name or f"scene_{i}"
        scene_ids.append(plant.RegisterCollisionGeometry(world, X, _shape(o), name, props))
        if o.shape != "halfspace":
            plant.RegisterVisualGeometry(
                world, X, _shape(o), name + "_visual", np.asarray([*o.color, 1.0][:4], dtype=float)
            )
    return scene_ids


def _override_geometry(task: TaskConfig, plant, scene_graph) -> None:
    """Overrides of the models' collision properties (the task's geometry section)."""
    if task.geometry:
        geoms = collision_geometries(plant, scene_graph)
        inspector = scene_graph.model_inspector()
        for key, p in task.geometry.items():
            for gid in named_geometries(key, geoms, f"geometry.{key}"):
                old = inspector.GetProximityProperties(gid)
                shape = type(inspector.GetShape(gid)).__name__.lower()
                try:
                    props = _proximity_props(p, old, shape=shape)
                except ConfigError as e:
                    raise ConfigError(f"geometry.{key}: {e}") from None
                scene_graph.AssignRole(plant.get_source_id(), gid, props, RoleAssign.kReplace)


def _add_visualizers(builder, plant, scene_graph, meshcat, contact_visualizer: bool) -> tuple:
    """MeshcatVisualizer (and ContactVisualizer) on ``meshcat``; none without it."""
    visualizers = ()
    if meshcat is not None:
        vis = MeshcatVisualizer.AddToBuilder(
            builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration)
        )
        visualizers = (vis,)
        if contact_visualizer:
            cparams = ContactVisualizerParams()
            cparams.newtons_per_meter = 40.0
            cparams.newton_meters_per_meter = 1.0
            cvis = ContactVisualizer.AddToBuilder(builder, plant, meshcat, cparams)
            visualizers += (cvis,)
    return visualizers


def feedback_rollout(step, x0, Ubar, Xbar, K, kappa, eps):
    """The forward pass of iLQR (eq. 7) through ``step(x, u) -> x_next``: u_k = ū_k − ε κ_k −
    K_k (x_k − x̄_k). x0: [nx], Ubar: [N, nu], Xbar: [N+1, nx], K: [N, nu, nx], kappa: [N, nu]
    -> X: [N+1, nx], U: [N, nu]. A SimulationError names the step that failed."""
    N = Ubar.shape[0]
    X = np.empty((N + 1, len(x0)))
    U = np.empty_like(Ubar)
    X[0] = x0
    for k in range(N):
        U[k] = Ubar[k] - eps * kappa[k] - K[k] @ (X[k] - Xbar[k])
        try:
            X[k + 1] = step(X[k], U[k])
        except SimulationError as e:
            raise SimulationError(f"step {k}: {e}") from None
    return X, U


class Dynamics:
    """The discrete dynamics f(x, u) of a task's plant, plus its named state layout.

    Built from a ``PlantSpec`` (or a TaskConfig, of which only its plant part is kept, as
    ``spec``): the dynamics know nothing of the solver.
    Attributes: ``nx = nq + nv``, ``nu`` (actuators), ``dt`` (time step), ``layout``.
    """

    def __init__(self, spec: PlantSpec | TaskConfig):
        spec = PlantSpec.of(spec)
        self.spec = spec
        self.scene = build_diagram(spec)
        self.diagram = self.scene.diagram
        self.plant = self.scene.plant
        self.scene_graph = self.scene.scene_graph
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = self.plant.GetMyMutableContextFromRoot(self.context)
        self.nq = self.plant.num_positions()
        self.nv = self.plant.num_velocities()
        self.nx = self.nq + self.nv
        self.nu = self.plant.num_actuated_dofs()
        self.dt = spec.plant.time_step
        self.layout = StateLayout.from_plant(self.plant)
        self.layout.add_groups(spec.blocks)
        self._input = self.diagram.get_input_port(self.scene.actuation_port)
        self._ad = None
        self.effort_limits = self._effort_limits()

    # -------------------------------------------------------------------------- stepping
    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """x_{k+1} = f(x_k, u_k). x: [nx], u: [nu] -> [nx]. Raises SimulationError (also for a
        non-finite x or u) or ValueError (wrong shapes)."""
        u = np.atleast_1d(u)  # a number for a single actuator
        return self._step(*self.check_arguments(x, u))

    def _step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``step`` without the argument checks, for rollouts (whose x0 and U are checked once
        and whose states are checked after every step, so a NaN control gives a
        SimulationError there too)."""
        self.plant.SetPositionsAndVelocities(self.plant_context, x)
        self._input.FixValue(self.context, u)
        try:
            xn = self.plant.EvalUniquePeriodicDiscreteUpdate(self.plant_context).value(0)
        except RuntimeError as e:
            raise SimulationError(str(e).strip().splitlines()[0]) from None
        if not np.all(np.abs(xn) < DIVERGED):  # also catches NaN
            raise SimulationError(
                "non-finite state after a time step"
                if not np.all(np.isfinite(xn))
                else f"the simulation diverged (a state component above {DIVERGED:g})"
            )
        return np.array(xn, copy=True)

    def check_arguments(self, X, U, x_rows: bool = False, u_rows: bool = False):
        """States X: [nx] (or [M, nx] with ``x_rows``) and inputs U: [nu] (or [N, nu] with
        ``u_rows``), as float arrays. ValueError for wrong shapes, SimulationError for NaN or
        infinite entries (Drake's own check of a state ends the process with SystemExit)."""
        X, U = np.asarray(X, dtype=float), np.asarray(U, dtype=float)
        if X.ndim != 1 + x_rows or X.shape[-1] != self.nx:
            want = f"[M, {self.nx}]" if x_rows else f"[{self.nx}]"
            raise ValueError(f"state x must have shape {want} (nx = {self.nx}), got {X.shape}")
        if U.ndim != 1 + u_rows or U.shape[-1] != self.nu:
            want = f"[N, {self.nu}]" if u_rows else f"[{self.nu}]"
            raise ValueError(f"input u must have shape {want} (nu = {self.nu}), got {U.shape}")
        if not np.isfinite(X).all():
            raise SimulationError("non-finite (NaN or infinite) state")
        if not np.isfinite(U).all():
            raise SimulationError("non-finite (NaN or infinite) input")
        return X, U

    def rollout(self, x0: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Open-loop simulation. x0: [nx], U: [N, nu] -> X: [N+1, nx]. Raises SimulationError."""
        x0, U = self.check_arguments(x0, U, u_rows=True)
        N = U.shape[0]
        X = np.empty((N + 1, self.nx))
        X[0] = x0
        for k in range(N):
            try:
                X[k + 1] = self._step(X[k], U[k])
            except SimulationError as e:
                raise SimulationError(f"step {k}: {e}") from None
        return X

    def closed_loop_rollout(self, x0, Ubar, Xbar, K, kappa, eps):
        """Forward pass of iLQR (eq. 7): u_k = ū_k − ε κ_k − K_k (x_k − x̄_k).

        x0: [nx], Ubar: [N, nu], Xbar: [N+1, nx], K: [N, nu, nx], kappa: [N, nu].
        Returns X: [N+1, nx], U: [N, nu]. Feedback acts on the coordinate difference (K is
        expressed in the coordinates in which f was linearized).
        """
        x0, Ubar = self.check_arguments(x0, Ubar, u_rows=True)
        return feedback_rollout(self._step, x0, Ubar, Xbar, K, kappa, eps)

    def clip_to_limits(self, U: np.ndarray) -> np.ndarray:
        """U: [..., nu] clipped to ±effort limit per actuator (no limit: unchanged): what
        Drake's plant applies for the command U (bitwise the same trajectory)."""
        return np.clip(U, -self.effort_limits, self.effort_limits)

    # -------------------------------------------------------------------------- helpers
    def autodiff(self) -> AutoDiffPlant:
        """The AutoDiffXd diagram, its context, plant, plant context and input port: built
        once."""
        if self._ad is None:
            ad_diagram = self.diagram.ToAutoDiffXd()
            ad_context = ad_diagram.CreateDefaultContext()
            ad_plant = ad_diagram.GetSubsystemByName(self.plant.get_name())
            ad_plant_context = ad_plant.GetMyMutableContextFromRoot(ad_context)
            self._ad = AutoDiffPlant(
                ad_diagram,
                ad_context,
                ad_plant,
                ad_plant_context,
                ad_diagram.get_input_port(self.scene.actuation_port),
            )
        return self._ad

    def default_state(self) -> np.ndarray:
        ctx = self.plant.CreateDefaultContext()
        return np.array(self.plant.GetPositionsAndVelocities(ctx))

    def initial_state(self) -> np.ndarray:
        """x0 from the model defaults and the task's ``initial_state`` (by block name)."""
        return self.layout.coordinate_vector(
            self.spec.initial_state, "initial_state", self.default_state()
        )

    def gravity_compensation(self, x: np.ndarray) -> np.ndarray:
        """u with B u = −τ_g(q) on the actuated coordinates. x: [nx] -> [nu]."""
        self.plant.SetPositionsAndVelocities(self.plant_context, x)
        tau_g = self.plant.CalcGravityGeneralizedForces(self.plant_context)
        B = self.plant.MakeActuationMatrix()
        return -np.linalg.pinv(B) @ tau_g

    def hold_torques(self, x: np.ndarray, iterations: int = 8) -> np.ndarray:
        """u: [nu] that best holds x: [nx] still for one step: argmin_u ||v_{k+1}(x, u)||²
        (Gauss-Newton, forward differences). For standing robots whose contacts carry them."""
        u = self.gravity_compensation(x)
        nq = self.nq
        for _ in range(iterations):
            v1 = self.step(x, u)[nq:]
            J = np.empty((self.nv, self.nu))
            h = 1e-4
            for i in range(self.nu):
                du = np.zeros(self.nu)
                du[i] = h
                J[:, i] = (self.step(x, u + du)[nq:] - v1) / h
            step, *_ = np.linalg.lstsq(J, -v1, rcond=None)
            u = u + step
            if np.linalg.norm(step) < 1e-8:
                break
        return u

    def force_path(self):
        """For finite differences over generalized forces (``derivatives``): the diagram
        context with the actuation fixed to zero and the applied generalized force port as the
        input, the actuation matrix ``B: [nv, nu]`` (τ = B u), and whether a step depends on
        (v, u) only through the free-motion velocity v* = v + dt M(q)⁻¹ (B u − C(q, v) v +
        τ_g(q)): SAP or TAMSI contact, no PD-controlled actuators and no force element but
        gravity. Joint damping is allowed under SAP, which applies it implicitly
        (−D v' with the mass matrix M + dt D, so v* keeps the form above; measured: the partials
        of Drake's damped planar gripper match the plain ones to 1e-9), not under TAMSI (off by
        up to 33 % there). ``None`` if the model does not qualify. Built once."""
        if not hasattr(self, "_force_path"):
            p = self.plant
            approximation = self.spec.plant.contact_approximation
            ok = (
                approximation in ("sap", "tamsi")
                and p.num_force_elements() == 1
                and not any(
                    p.get_joint_actuator(i).has_controller() for i in p.GetJointActuatorIndices()
                )
                and (
                    approximation == "sap"
                    or not any(
                        np.any(p.get_joint(j).default_damping_vector() != 0)
                        for j in p.GetJointIndices()
                        if p.get_joint(j).num_velocities() > 0
                    )
                )
            )
            self._force_path = None
            if ok:
                context = self.diagram.CreateDefaultContext()
                self._input.FixValue(context, np.zeros(self.nu))
                port = self.diagram.get_input_port(self.scene.force_port)
                port.FixValue(context, np.zeros(self.nv))
                plant_context = p.GetMyMutableContextFromRoot(context)
                self._force_path = (context, plant_context, port, p.MakeActuationMatrix())
        return self._force_path

    def _effort_limits(self) -> np.ndarray:
        lim = []
        for i in self.plant.GetJointActuatorIndices():
            e = self.plant.get_joint_actuator(i).effort_limit()
            lim.append(e if np.isfinite(e) and e > 0 else np.inf)
        return np.array(lim)

    def geometry_names(self) -> dict:
        if not hasattr(self, "_geometry_names"):
            self._geometry_names = collision_geometries(self.plant, self.scene_graph)
        return self._geometry_names

    def contact_query(self, x: np.ndarray) -> tuple[list, list]:
        """(hydroelastic contact surfaces, point pairs) at x: [nx]: a geometry query, no contact
        solve, so it is cheap and works for any state and contact solver."""

        self.plant.SetPositionsAndVelocities(self.plant_context, x)
        query = self.plant.get_geometry_query_input_port().Eval(self.plant_context)
        rep = (
            Rep.kPolygon
            if self.spec.plant.contact_surface_representation == "polygon"
            else Rep.kTriangle
        )
        model = self.spec.plant.contact_model
        if model == "hydroelastic":
            return query.ComputeContactSurfaces(rep), []
        if model == "point":  # the plant computes point contact only, whatever the geometry
            return [], query.ComputePointPairPenetration()
        return query.ComputeContactSurfacesWithFallback(rep)

    def contact_pairs(self, x: np.ndarray) -> list[tuple[str, str, str, str, int]]:
        """Touching pairs at x: [nx]: (geometry A, body A, geometry B, body B, polygons); point
        contacts have 0 polygons."""
        names = self.geometry_names()
        surfaces, points = self.contact_query(x)
        unknown = ("?", "?")
        out = []
        for s in surfaces:
            a, b = names.get(s.id_M(), unknown), names.get(s.id_N(), unknown)
            out.append((a[0], a[1], b[0], b[1], s.num_faces()))
        for pp in points:
            a, b = names.get(pp.id_A, unknown), names.get(pp.id_B, unknown)
            out.append((a[0], a[1], b[0], b[1], 0))
        return out

    def contact_surfaces(self, x: np.ndarray) -> list[tuple[str, str, int]]:
        """Touching pairs at x: [nx]: (geometry A name, geometry B name, polygons)."""
        return [(ga, gb, n) for ga, _, gb, _, n in self.contact_pairs(x)]


__all__ = ["Dynamics", "PlantSpec", "Scene", "SimulationError", "build_diagram", "SceneGraph"]
