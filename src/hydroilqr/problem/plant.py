"""The sections that describe the physical system: ``models``, ``package_map``, ``scene``,
``geometry``, ``plant``, ``actuators`` (with ``blocks`` and ``initial_state``, the
``PlantSpec`` a plant is built from; ``TaskConfig`` extends it)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hydroilqr.problem.capabilities import drake_has_tamsi, no_tamsi_message
from hydroilqr.problem.checks import check_length
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import MAX_MODEL_BYTES, check_file

SHAPES = ("box", "sphere", "cylinder", "halfspace")
APPROXIMATIONS = ("sap", "similar", "lagged", "tamsi")
CONTACT_MODELS = ("hydroelastic_with_fallback", "hydroelastic", "point")
SURFACES = ("polygon", "triangle")  # plant.contact_surface_representation


@dataclass
class WeldConfig:
    parent: str = "world"
    child: str = ""
    xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    rpy: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclass
class ModelConfig:
    file: str = ""
    # The model instance's name (default: the one in the file). Needed to load one file twice,
    # or two files whose models share a name; duplicate joint names then read NAME::joint.
    name: str = ""
    weld: WeldConfig | None = None
    welds: list[WeldConfig] = field(default_factory=list)  # more welds (e.g. several bases)
    # False: gravity does not act on this model's bodies (an arm whose own controller
    # compensates it); plant.gravity acts on the others.
    gravity: bool = True


@dataclass
class ContactProperties:
    """Hydroelastic/contact properties of one collision geometry (None = keep the model's)."""

    compliance: str | None = None  # "rigid" | "compliant"
    hydroelastic_modulus: float | None = None  # Pa
    dissipation: float | None = None  # Hunt-Crossley, s/m
    friction: float | None = None  # Coulomb (static = dynamic)
    resolution_hint: float | None = None  # m
    margin: float | None = None  # m
    relaxation_time: float | None = None  # s (SAP)
    slab_thickness: float | None = None  # m (compliant half spaces)


@dataclass
class SceneObject(ContactProperties):
    """Static collision + visual geometry welded to the world."""

    name: str = ""
    shape: str = "box"  # box | sphere | cylinder | halfspace
    size: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])  # box
    radius: float = 0.1  # sphere / cylinder
    length: float = 1.0  # cylinder
    xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    rpy: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    color: list[float] = field(default_factory=lambda: [0.6, 0.6, 0.6, 1.0])
    # Collision geometries of the models this object never touches (names as in ``geometry:``:
    # a body, a collision name, or BODY/GEOMETRY). Lets one ground be two geometries, e.g. a
    # compliant half space for rigid feet and a compliant box for a compliant body.
    no_contact_with: list[str] = field(default_factory=list)

    def check_keys(self, data: dict[str, Any], prefix: str) -> None:
        """Called by the typed building with the keys the file gave (``data``): a known shape,
        and no size key its shape does not use."""
        if self.shape not in SHAPES:
            raise ConfigError(
                f"{prefix}.shape: expected {', '.join(SHAPES[:-1])} or {SHAPES[-1]}, "
                f"got {self.shape!r}"
            )
        shape_keys = {"box": ["size"], "sphere": ["radius"], "cylinder": ["radius", "length"]}
        used = shape_keys.get(self.shape, [])
        default = SceneObject()
        for k in ("size", "radius", "length"):
            # (a saved task lists every field: only a value other than the default is an error)
            if k in data and k not in used and getattr(self, k) != getattr(default, k):
                what = f"uses {' and '.join(used)}" if used else "has no size"
                raise ConfigError(f"{prefix}.{k}: a {self.shape} {what}, not {k}")


@dataclass
class PlantConfig:
    time_step: float = 0.01
    contact_approximation: str = "sap"  # sap | similar | lagged | tamsi
    contact_model: str = "hydroelastic_with_fallback"
    contact_surface_representation: str = "polygon"  # polygon | triangle
    gravity: list[float] = field(default_factory=lambda: [0.0, 0.0, -9.81])
    # The model files' joint position limits as Drake's own constraints of the time step (sap,
    # similar, lagged; tamsi ignores them). false: removed when the plant is built (a
    # ``joint_limits`` cost term still reads them).
    joint_limits: bool = True


@dataclass
class ActuatorConfig:
    """One actuator's drive (None = keep the model's; Drake's JointActuator defaults)."""

    effort_limit: float | None = None  # N·m (revolute) or N (prismatic): commands clip here
    rotor_inertia: float | None = None  # kg·m² (or kg), of the motor's rotor
    gear_ratio: float | None = None  # joint speed = motor speed / gear_ratio


@dataclass
class PlantSpec:
    """What a plant is built from: the parts of a task that describe the physical system
    (model files, scene, contact properties, plant settings, state blocks, initial state),
    and nothing about cost or solver. ``TaskConfig`` extends it; model/plant.py's ``Dynamics``
    keeps only this part of a task (``PlantSpec.of``), e.g. to send it to worker processes."""

    name: str = ""
    models: list[ModelConfig] = field(default_factory=list)
    package_map: dict[str, str] = field(default_factory=dict)
    scene: list[SceneObject] = field(default_factory=list)
    geometry: dict[str, ContactProperties] = field(default_factory=dict)
    plant: PlantConfig = field(default_factory=PlantConfig)
    actuators: dict[str, ActuatorConfig] = field(default_factory=dict)
    blocks: dict[str, list[str]] = field(default_factory=dict)
    initial_state: dict[str, Any] = field(default_factory=dict)
    # Set by the loader: directory that relative paths are resolved against.
    base_dir: str = field(default="", metadata={"task_file": False})
    # Joints given a virtual actuator each (no effort limit), appended after the model's:
    # set only by a position guess's realization (initial_guess.realize), never by a file.
    virtual_forces: list[str] = field(default_factory=list, metadata={"task_file": False})

    @classmethod
    def of(cls, task: PlantSpec) -> PlantSpec:
        """The plant part of a task (a PlantSpec as it is)."""
        if type(task) is PlantSpec:
            return task
        return PlantSpec(**{f.name: getattr(task, f.name) for f in dataclasses.fields(PlantSpec)})

    def resolve_path(self, path: str) -> Path:
        """``path`` relative to the task file's directory (``base_dir``), ``~`` expanded."""
        p = Path(path).expanduser()
        if not p.is_absolute():
            p = Path(self.base_dir or ".") / p
        return p


def check_contact(p: ContactProperties, key: str) -> None:
    if p.compliance is not None and p.compliance not in ("rigid", "compliant"):
        raise ConfigError(f"{key}.compliance: expected rigid or compliant, got {p.compliance!r}")
    for name in ("hydroelastic_modulus", "resolution_hint", "slab_thickness"):
        v = getattr(p, name)
        if v is not None and v <= 0:
            raise ConfigError(f"{key}.{name}: must be positive, got {v}")
    for name in ("dissipation", "friction", "margin", "relaxation_time"):
        v = getattr(p, name)
        if v is not None and v < 0:
            raise ConfigError(f"{key}.{name}: must be non-negative, got {v}")


def check_scene_object(o: SceneObject, key: str) -> None:
    """Contact properties, size, pose and color of the scene object at ``key``."""
    check_contact(o, key)
    if o.shape == "box" and (len(o.size) != 3 or min(o.size) <= 0):
        raise ConfigError(f"{key}.size: expected three positive numbers")
    check_length(o.xyz, 3, f"{key}.xyz")
    check_length(o.rpy, 3, f"{key}.rpy")
    if len(o.color) not in (3, 4) or not all(0 <= c <= 1 for c in o.color):
        raise ConfigError(
            f"{key}.color: expected 3 or 4 numbers in [0, 1] (RGB or RGBA), got {o.color}"
        )
    if o.shape in ("sphere", "cylinder") and o.radius <= 0:
        raise ConfigError(f"{key}.radius: must be positive, got {o.radius}")
    if o.shape == "cylinder" and o.length <= 0:
        raise ConfigError(f"{key}.length: must be positive, got {o.length}")


def validate_plant(spec: PlantSpec) -> None:
    """The plant part of a task: model files and welds, scene objects (unique names, shapes),
    contact properties, actuators and the plant's settings; the names from the model are
    checked when the plant is built (model/plant.py)."""
    if not spec.models:
        raise ConfigError("models: at least one model file is required")
    scene_names = [o.name for o in spec.scene if o.name]
    for n in scene_names:
        if scene_names.count(n) > 1:
            raise ConfigError(f"scene: two objects are named {n!r}")
    validate_models(spec)
    check_length(spec.plant.gravity, 3, "plant.gravity")
    validate_actuators(spec.actuators)
    validate_plant_settings(spec.plant)
    for name, p in spec.geometry.items():
        check_contact(p, f"geometry.{name}")
    for i, o in enumerate(spec.scene):
        check_scene_object(o, f"scene[{i}]")


def validate_models(cfg: PlantSpec) -> None:
    """Model files that exist (within the size limit) and welds of 3 + 3 numbers."""
    for i, m in enumerate(cfg.models):
        if not m.file:
            raise ConfigError(f"models[{i}].file: required")
        if not m.file.startswith("package://") and not cfg.resolve_path(m.file).exists():
            raise ConfigError(f"models[{i}].file: no such file {cfg.resolve_path(m.file)}")
        if not m.file.startswith("package://"):
            check_file(cfg.resolve_path(m.file), f"models[{i}].file:", MAX_MODEL_BYTES)
    for i, m in enumerate(cfg.models):
        welds = [(f"models[{i}].weld", m.weld)] if m.weld is not None else []
        welds += [(f"models[{i}].welds[{j}]", w) for j, w in enumerate(m.welds)]
        for wkey, w in welds:
            check_length(w.xyz, 3, f"{wkey}.xyz")
            check_length(w.rpy, 3, f"{wkey}.rpy")


def validate_actuators(actuators: dict) -> None:
    for name, a in actuators.items():
        if a.effort_limit is not None and not a.effort_limit > 0:
            raise ConfigError(
                f"actuators.{name}.effort_limit: must be positive, got {a.effort_limit}"
            )
        if a.rotor_inertia is not None and not a.rotor_inertia >= 0:
            raise ConfigError(
                f"actuators.{name}.rotor_inertia: must be non-negative, got {a.rotor_inertia}"
            )
        if a.gear_ratio is not None and not a.gear_ratio > 0:
            raise ConfigError(f"actuators.{name}.gear_ratio: must be positive, got {a.gear_ratio}")


def validate_plant_settings(plant: PlantConfig) -> None:
    if plant.time_step <= 0:
        raise ConfigError(f"plant.time_step: must be positive, got {plant.time_step}")
    if plant.contact_approximation not in APPROXIMATIONS:
        raise ConfigError(
            f"plant.contact_approximation: expected one of {', '.join(APPROXIMATIONS)}, "
            f"got {plant.contact_approximation!r}"
        )
    if plant.contact_approximation == "tamsi" and not drake_has_tamsi():
        raise ConfigError(
            no_tamsi_message("plant.contact_approximation=tamsi") + ": use sap, similar or lagged"
        )
    if plant.contact_model not in CONTACT_MODELS:
        raise ConfigError(
            f"plant.contact_model: expected one of {', '.join(CONTACT_MODELS)}, "
            f"got {plant.contact_model!r}"
        )
    if plant.contact_surface_representation not in SURFACES:
        raise ConfigError("plant.contact_surface_representation: expected polygon or triangle")
