"""Building a task's MultibodyPlant + SceneGraph diagram (``build_diagram``): model files
and their references, welds, the scene, geometry overrides, actuators, visualizers; the
checks of what Drake parsed (inertias, downloads). ``model/plant.py``'s ``Dynamics`` steps it.
"""

from __future__ import annotations

import contextlib
import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Role,
    RoleAssign,
)
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.meshcat import ContactVisualizer, ContactVisualizerParams
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import DiagramBuilder

from hydroilqr.model.contact_geometry import (
    _exclude_scene_contacts,
    _proximity_props,
    _shape,
    check_contact_pairs,
    collision_geometries,
    named_geometries,
)
from hydroilqr.model.names import (
    actuator_labels,
    actuator_names,
)
from hydroilqr.problem.checks import unknown_key
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import (
    MAX_MESH_BYTES,
    MAX_MODEL_BYTES,
    check_file,
    model_file_references,
    read_bounded,
)
from hydroilqr.problem.task import TaskConfig


class _NoDeformableNotice(logging.Filter):
    """Drops Drake's notice, on registering any HalfSpace, that half spaces do not touch
    deformable bodies: this project has none, and the notice reads like a problem."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "not currently supported for deformable contact" not in record.getMessage()


logging.getLogger("drake").addFilter(_NoDeformableNotice())


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


#: The prefix of a virtual actuator's name (``PlantSpec.virtual_forces``).
VIRTUAL_PREFIX = "virtual_"


def add_virtual_actuators(task: TaskConfig, plant) -> None:
    """One actuator without an effort limit on each joint of ``virtual_forces`` (a position
    guess's realization, solver/realize.py), after the model's own, named ``virtual_JOINT``;
    none for a task as written."""
    for name in getattr(task, "virtual_forces", ()):
        plant.AddJointActuator(VIRTUAL_PREFIX + name, plant.GetJointByName(name), np.inf)


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
    add_virtual_actuators(task, plant)
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
