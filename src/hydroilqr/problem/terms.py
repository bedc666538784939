"""The ``cost.terms`` entries: one config dataclass per term type, registered by name
(``TERM_TYPES``; model/residuals.py registers a residual class with each), and their checks.

``TermConfig`` holds the keys every term has (name, type, weight, its window and soft
minimum); a type's subclass adds its own keys, its ``check``, ``vector`` (a 3-vector residual
with ``axes`` and a weight per axis) and ``pulls_toward_contact`` (a distance's ``max`` or
``target``: what solve's no-contact remedy asks for). The typed building picks the subclass by a
term's ``type`` (``TermConfig.variant``) and ``hydroilqr schema`` lists one definition per
registered type (``TermConfig.variants``), so a type registered from outside the package
(a test's toy) is taken by both with nothing else edited.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

from hydroilqr.problem.checks import check_length, check_weight, unknown_key
from hydroilqr.problem.errors import ConfigError

# The axis names of a 3-vector term's residual.
AXES = ("x", "y", "z")


def _xyz(*v: float):
    return field(default_factory=lambda: list(v))


@dataclass
class TermConfig:
    """One task-space cost term (``cost.terms``; model/terms.py): a residual r(x) (its type's),
    costing ``weight · |r|²`` at every step of its window (running) or at the last state
    (``terminal``)."""

    kind: ClassVar[str] = ""  # the ``type`` a task file names
    vector: ClassVar[bool] = False  # a 3-vector residual: ``axes`` and a weight per axis

    name: str = ""
    type: str = ""  # a registered term type (TERM_TYPES)
    # A number, or one per axis of ``axes`` (position, orientation, velocity).
    weight: Any = 1.0
    # The time window of a running term (s, inclusive; default the whole trajectory), or the
    # last state only.
    after: float | None = None
    until: float | None = None
    terminal: bool = False
    # Weight factors [at the window's start, at its end], linear in between (default [1, 1]);
    # a window without ``until`` ends at the task's end.
    ramp: list[float] = field(default_factory=list)
    # A running term's cost over its window as a soft minimum of its steps' costs c_k instead
    # of their sum: -τ log(mean_k exp(-c_k / τ)) with this temperature τ (cost units; 0 = the
    # sum). The term then asks for a small residual at some step of the window, not at every
    # one: e.g. an approach term that wants one touch per window and lets the finger leave in
    # between. Between the window's minimum and its mean cost.
    softmin: float = 0.0

    def __post_init__(self) -> None:
        if not self.type:
            self.type = self.kind

    def check(self, key: str) -> None:
        """The type's own keys (the model's names are checked when the plant is built)."""

    def pulls_toward_contact(self) -> bool:
        """Whether the term asks two geometries to approach (the no-contact remedy's)."""
        return False

    @classmethod
    def variants(cls) -> list[type[TermConfig]]:
        """The registered term types (the schema lists each)."""
        return list(TERM_TYPES.values())

    @classmethod
    def variant(cls, data: Any, key: str) -> tuple[type[TermConfig], Any]:
        """The registered type a term's YAML data names, and the data it is built from: keys
        of other types at their defaults dropped (a resolved task saved before the types
        were split lists every key), set ones refused."""
        if not isinstance(data, dict):
            return cls, data
        name = data.get("name")
        where = f"{key.rpartition('[')[0]}.{name}" if isinstance(name, str) and name else key
        kind = data.get("type")
        chosen = TERM_TYPES.get(kind) if isinstance(kind, str) else None
        if chosen is None:
            known = list(TERM_TYPES)
            raise ConfigError(f"{where}.type: {unknown_key(kind, known, 'term type')}")
        own = {f.name for f in dataclasses.fields(chosen)}
        out = {}
        for k, v in data.items():
            default = _other_types_default(k) if k not in own else dataclasses.MISSING
            if default is dataclasses.MISSING:
                out[k] = v
            elif v != default:
                article = "an" if kind[0] in "aeiou" else "a"
                raise ConfigError(f"{where}.{k}: {article} {kind} term has no {k}")
        return chosen, out


def _other_types_default(key: str) -> Any:
    """The default of ``key`` in the registered type that has it (MISSING: no type has it)."""
    for t in TERM_TYPES.values():
        for f in dataclasses.fields(t):
            if f.name == key:
                return f.default_factory() if f.default is dataclasses.MISSING else f.default
    return dataclasses.MISSING


#: Term types by name (``cost.terms[].type``): the built-ins below, and any that
#: ``register_term_type`` (model/residuals.py's ``register``) adds.
TERM_TYPES: dict[str, type[TermConfig]] = {}


def register_term_type(cls: type[TermConfig]) -> type[TermConfig]:
    """Registers a TermConfig subclass under its ``kind`` (the task format takes it)."""
    if not (isinstance(cls, type) and issubclass(cls, TermConfig) and cls.kind):
        raise ValueError(f"{cls!r}: a term type is a TermConfig subclass with a kind")
    TERM_TYPES[cls.kind] = cls
    return cls


def validate_term(term: TermConfig, key: str, names: set[str]) -> None:
    """A term's name (unique), type, weight, its type's checks and its window; the model's
    names are checked when the plant is built."""
    if not term.name or not all(c.isalnum() or c in "-_" for c in term.name):
        raise ConfigError(f"{key}.name: required: letters, digits, - and _ (got {term.name!r})")
    if term.name in names:
        raise ConfigError(f"{key}.name: two terms are named {term.name!r}")
    names.add(term.name)
    key = f"cost.terms.{term.name}"
    if TERM_TYPES.get(term.type) is not type(term):
        raise ConfigError(f"{key}.type: {unknown_key(term.type, list(TERM_TYPES), 'term type')}")
    _validate_term_weight(term, key)
    term.check(key)
    _validate_term_window(term, key)


def _validate_term_window(term: TermConfig, key: str) -> None:
    """terminal, or a window after <= until with a ramp of two non-negative factors."""
    if term.terminal and (term.after is not None or term.until is not None or term.ramp):
        raise ConfigError(f"{key}.terminal: a terminal term has no after, until or ramp")
    if term.after is not None and term.after < 0:
        raise ConfigError(f"{key}.after: must be >= 0 s, got {term.after}")
    if term.after is not None and term.until is not None and term.until < term.after:
        raise ConfigError(f"{key}.until: {term.until} s is before after ({term.after} s)")
    sm = term.softmin
    if isinstance(sm, bool) or not isinstance(sm, (int, float)) or not math.isfinite(sm) or sm < 0:
        raise ConfigError(f"{key}.softmin: a temperature >= 0 (cost units), got {sm!r}")
    if sm and term.terminal:
        raise ConfigError(f"{key}.softmin: a terminal term has one step; softmin needs a window")
    if term.ramp:
        check_length(term.ramp, 2, f"{key}.ramp")
        if min(term.ramp) < 0:
            raise ConfigError(f"{key}.ramp: factors must be non-negative, got {term.ramp}")


def _validate_term_weight(term: TermConfig, key: str) -> None:
    """Distinct axes among x, y, z (vector terms); a weight >= 0, or one per axis."""
    vector = term.vector
    axes = term.axes if vector else []
    if vector and (not axes or any(a not in AXES for a in axes) or len(set(axes)) < len(axes)):
        raise ConfigError(f"{key}.axes: expected distinct axes among x, y, z, got {axes}")
    n = len(axes) if vector else 1
    w = term.weight
    ws = w if isinstance(w, list) and vector else [w]
    for x in ws:
        check_weight(x, w, f"{key}.weight", True)
    if len(ws) not in (1, n):
        raise ConfigError(f"{key}.weight: expected a number or {n} values (one per axis)")


# ---------------------------------------------------------------------------- shared checks
def check_body(term: Any, key: str) -> None:
    """The body or frame of a term's point, and the point (xyz)."""
    if not term.body:
        raise ConfigError(f"{key}.body: required (the body or frame the point is fixed on)")
    check_length(term.point, 3, f"{key}.point")


def check_vector_target(term: Any, key: str, sizes: tuple, required: str) -> None:
    """A 3-vector term's target: ``sizes`` numbers (orientation: 3, roll, pitch, yaw, or 4, a
    quaternion); when None, ``required`` says what it holds unless the term is
    relative_to_start (empty: optional, as a velocity's 0)."""
    t = term.target
    if t is None:
        if required and not getattr(term, "relative_to_start", False):
            raise ConfigError(f"{key}.target: required ({required}), or relative_to_start")
        return
    if not isinstance(t, list) or len(t) not in sizes:
        want = (
            "3 numbers (roll, pitch, yaw) or 4 (a quaternion w, x, y, z)"
            if 4 in sizes
            else "3 numbers (x, y, z)"
        )
        raise ConfigError(f"{key}.target: expected {want}, got {t!r}")
    for x in t:
        check_weight(x, t, f"{key}.target", False)
    if len(t) == 4 and math.hypot(*t) < 1e-9:
        raise ConfigError(f"{key}.target: a quaternion must be non-zero")


def check_scalar_target(term: Any, key: str) -> None:
    """A height's or distance's target number, or min and/or max."""
    t = term.target
    bounds = term.min is not None or term.max is not None
    if (t is None) == (not bounds):
        raise ConfigError(f"{key}: give a target, or min and/or max (not both)")
    if t is not None:
        check_weight(t, t, f"{key}.target", False)
    if term.min is not None and term.max is not None and term.min > term.max:
        raise ConfigError(f"{key}.min: {term.min} is above max {term.max}")


# ------------------------------------------------------------------------- built-in types
@register_term_type
@dataclass
class PositionTerm(TermConfig):
    """``position``: a point fixed on a body or frame against a target position."""

    kind: ClassVar[str] = "position"
    vector: ClassVar[bool] = True

    # The point: fixed on ``body`` (a body or frame name) at ``point`` (xyz in that frame, m).
    body: str = ""
    point: list[float] = _xyz(0.0, 0.0, 0.0)
    # Measured in (and expressed in) this body or frame; default world.
    relative_to: str = ""
    axes: list[str] = _xyz("x", "y", "z")  # the residual's axes (of the world or relative_to)
    # Target xyz (m) at t = 0, moving at ``target_velocity`` (m/s); with ``relative_to_start``
    # an offset from the point's position in the initial state.
    target: Any = None
    target_velocity: list[float] = _xyz(0.0, 0.0, 0.0)
    relative_to_start: bool = False

    def check(self, key: str) -> None:
        check_body(self, key)
        check_length(self.target_velocity, 3, f"{key}.target_velocity")
        check_vector_target(self, key, (3,), "xyz in m")


@register_term_type
@dataclass
class OrientationTerm(TermConfig):
    """``orientation``: a frame's orientation against a target orientation."""

    kind: ClassVar[str] = "orientation"
    vector: ClassVar[bool] = True

    body: str = ""  # the frame (a body or frame name)
    relative_to: str = ""  # measured in this body or frame; default world
    axes: list[str] = _xyz("x", "y", "z")  # the residual's axes (of the target frame)
    # Roll-pitch-yaw [3] (rad) or a quaternion [w, x, y, z]; with ``relative_to_start`` a
    # rotation after the start orientation (default none).
    target: Any = None
    relative_to_start: bool = False

    def check(self, key: str) -> None:
        if not self.body:
            raise ConfigError(f"{key}.body: required (the body or frame the point is fixed on)")
        check_vector_target(self, key, (3, 4), "roll, pitch, yaw in rad")


@register_term_type
@dataclass
class VelocityTerm(TermConfig):
    """``velocity``: a point's translational velocity against a target velocity."""

    kind: ClassVar[str] = "velocity"
    vector: ClassVar[bool] = True

    body: str = ""
    point: list[float] = _xyz(0.0, 0.0, 0.0)
    relative_to: str = ""  # measured in (and expressed in) this body or frame; default world
    axes: list[str] = _xyz("x", "y", "z")
    target: Any = None  # the target velocity (m/s; default 0)

    def check(self, key: str) -> None:
        check_body(self, key)
        check_vector_target(self, key, (3,), "")


@register_term_type
@dataclass
class HeightTerm(TermConfig):
    """``height``: a point's height above a plane (or over another point) against a target or
    one-sided bounds."""

    kind: ClassVar[str] = "height"

    body: str = ""
    point: list[float] = _xyz(0.0, 0.0, 0.0)
    target: Any = None  # m
    # One-sided bounds instead of a target: a cost only below ``min`` (a clearance) or above
    # ``max``.
    min: float | None = None
    max: float | None = None
    # The plane's unit normal through the world origin (height = normal · p).
    normal: list[float] = _xyz(0.0, 0.0, 1.0)
    # Measured from a second point instead of the plane: the point ``above_point`` (xyz, m)
    # fixed on ``above_body`` (height = normal · (p − p_above)); e.g. one foot's height over
    # another's.
    above_body: str = ""
    above_point: list[float] = _xyz(0.0, 0.0, 0.0)

    def check(self, key: str) -> None:
        check_body(self, key)
        check_length(self.normal, 3, f"{key}.normal")
        check_length(self.above_point, 3, f"{key}.above_point")
        if math.hypot(*self.normal) < 1e-9:
            raise ConfigError(f"{key}.normal: must be non-zero")
        check_scalar_target(self, key)


@register_term_type
@dataclass
class DistanceTerm(TermConfig):
    """``distance``: the signed distance of two geometries against a target or bounds (an
    approach ``max``: a gradient before any contact)."""

    kind: ClassVar[str] = "distance"

    # The two geometries (names as in ``geometry:``: a body, a collision name, or
    # BODY/GEOMETRY; the closest pair counts).
    geometry_a: str = ""
    geometry_b: str = ""
    target: Any = None  # m
    min: float | None = None
    max: float | None = None

    def check(self, key: str) -> None:
        if not (self.geometry_a and self.geometry_b):
            raise ConfigError(f"{key}: a distance term needs geometry_a and geometry_b")
        check_scalar_target(self, key)

    def pulls_toward_contact(self) -> bool:
        return self.max is not None or self.target is not None


@register_term_type
@dataclass
class SlipTerm(TermConfig):
    """``slip``: the horizontal (world x, y) velocity of the lowest point of a sphere of
    ``radius`` (m) centred at ``point``, times max(0, 1 - h / clearance), h that point's height
    (m) above z = 0: a foot may move freely only once it is ``clearance`` above the ground."""

    kind: ClassVar[str] = "slip"

    body: str = ""
    point: list[float] = _xyz(0.0, 0.0, 0.0)
    radius: float = 0.0
    clearance: float | None = None

    def check(self, key: str) -> None:
        """The clearance (> 0 m, required) and the sphere's radius (>= 0 m)."""
        check_body(self, key)
        c = self.clearance
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) or c <= 0:
            raise ConfigError(f"{key}.clearance: required, a height > 0 (m), got {c!r}")
        r = self.radius
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not math.isfinite(r) or r < 0:
            raise ConfigError(f"{key}.radius: expected a length >= 0 (m), got {r!r}")


@register_term_type
@dataclass
class JointLimitsTerm(TermConfig):
    """``joint_limits``: joint positions kept ``margin`` inside the model files' limits."""

    kind: ClassVar[str] = "joint_limits"

    # The joints (state blocks of joint coordinates; default every coordinate with finite
    # limits in the model files) and how far inside each limit the cost starts (rad or m).
    joints: list[str] = field(default_factory=list)
    margin: float = 0.0

    def check(self, key: str) -> None:
        check_weight(self.margin, self.margin, f"{key}.margin", False)
        if self.margin < 0:
            raise ConfigError(f"{key}.margin: must be >= 0 (rad or m inside each limit)")
        if any(not isinstance(j, str) or not j for j in self.joints):
            raise ConfigError(f"{key}.joints: expected joint names, got {self.joints!r}")
