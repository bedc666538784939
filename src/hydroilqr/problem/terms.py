"""The ``cost.terms`` entries: task-space terms (``TermConfig``), their types as the task file
sees them (``TermType``, registered by model/residuals.py with each residual class) and
their checks."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hydroilqr.problem.checks import check_length, check_weight, unknown_key
from hydroilqr.problem.errors import ConfigError

# The axis names of a 3-vector term's residual (the term types: TERM_TYPES, below).
AXES = ("x", "y", "z")


@dataclass
class TermConfig:
    """One task-space cost term (``cost.terms``; model/terms.py): a residual r(x) of a point on
    a body (or of two geometries' signed distance), costing ``weight · |r|²`` at every step of
    its window (running) or at the last state (``terminal``)."""

    name: str = ""
    type: str = ""  # position | orientation | velocity | height | distance | slip
    # A number, or one per axis of ``axes`` (position, orientation, velocity).
    weight: Any = 1.0
    # position, velocity, height: the point, fixed on ``body`` (a body or frame name) at
    # ``point`` (xyz in that frame, m); orientation: the frame ``body``.
    body: str = ""
    point: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    # position, orientation, velocity: measured in (and expressed in) this body or frame;
    # default world.
    relative_to: str = ""
    # position, orientation, velocity: the residual's axes (of the world or ``relative_to``
    # frame; an orientation's: of the target frame).
    axes: list[str] = field(default_factory=lambda: ["x", "y", "z"])
    # position: target xyz (m) at t = 0, moving at ``target_velocity`` (m/s); with
    # ``relative_to_start`` an offset from the point's position in the initial state.
    # orientation: roll-pitch-yaw [3] (rad) or a quaternion [w, x, y, z], with
    # ``relative_to_start`` a rotation after the start orientation (default none).
    # velocity: the target velocity (m/s; default 0). height, distance: a number (m).
    target: Any = None
    target_velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    relative_to_start: bool = False
    # height, distance: one-sided bounds instead of a target: a cost only below ``min`` or
    # above ``max`` (height: a clearance ``min``; distance: an approach ``max``).
    min: float | None = None
    max: float | None = None
    # height: the plane's unit normal through the world origin (height = normal · p).
    normal: list[float] = field(default_factory=lambda: [0.0, 0.0, 1.0])
    # height: measured from a second point instead of the plane: the point ``above_point`` (xyz,
    # m) fixed on ``above_body`` (height = normal · (p − p_above)); e.g. one foot's height over
    # another's.
    above_body: str = ""
    above_point: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    # distance: the two geometries (names as in ``geometry:``: a body, a collision name, or
    # BODY/GEOMETRY; the closest pair counts).
    geometry_a: str = ""
    geometry_b: str = ""
    # joint_limits: the joints (state blocks of joint coordinates; default every coordinate
    # with finite limits in the model files) and how far inside each limit the cost starts
    # (rad or m).
    joints: list[str] = field(default_factory=list)
    margin: float = 0.0
    # slip: the horizontal (world x, y) velocity of the lowest point of a sphere of ``radius``
    # (m) centred at ``point``, times max(0, 1 - h / clearance), h that point's height (m)
    # above z = 0: a foot may move freely only once it is ``clearance`` above the ground.
    radius: float = 0.0
    clearance: float | None = None
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


@dataclass(frozen=True)
class TermType:
    """A term type as the task file sees it: the keys of ``TermConfig`` it reads (besides
    name, type, weight, the window keys and softmin), whether its residual is a 3-vector with
    ``axes`` and a weight per axis, ``check(term, key)``: its own keys' checks (the model's
    names are checked when the plant is built), and ``approach``: whether its ``max`` or
    ``target`` pulls two geometries towards contact (what solve's no-contact remedy asks
    for). model/residuals.py registers the residual class of each type with its TermType
    (``register``)."""

    name: str
    keys: frozenset[str]
    check: Callable[[TermConfig, str], None]
    vector: bool = False
    approach: bool = False


#: Term types by name (``cost.terms[].type``): the built-ins below, and any that
#: ``register_term_type`` (model/residuals.py's ``register``) adds.
TERM_TYPES: dict[str, TermType] = {}


def register_term_type(spec: TermType) -> TermType:
    TERM_TYPES[spec.name] = spec
    return spec


def validate_term(term: TermConfig, key: str, names: set[str]) -> None:
    """A term's name (unique), type, weight, the keys its type reads (and no other key set),
    its type's checks and its window; the model's names are checked when the plant is built."""
    if not term.name or not all(c.isalnum() or c in "-_" for c in term.name):
        raise ConfigError(f"{key}.name: required: letters, digits, - and _ (got {term.name!r})")
    if term.name in names:
        raise ConfigError(f"{key}.name: two terms are named {term.name!r}")
    names.add(term.name)
    key = f"cost.terms.{term.name}"
    spec = TERM_TYPES.get(term.type)
    if spec is None:
        raise ConfigError(f"{key}.type: {unknown_key(term.type, list(TERM_TYPES), 'term type')}")
    default = TermConfig()
    every = set().union(*(s.keys for s in TERM_TYPES.values()))
    for f in sorted(every):
        if f not in spec.keys and getattr(term, f) != getattr(default, f):
            article = "an" if term.type[0] in "aeiou" else "a"
            raise ConfigError(f"{key}.{f}: {article} {term.type} term has no {f}")
    _validate_term_weight(term, key, spec.vector)
    spec.check(term, key)
    _validate_term_window(term, key)


def _check_body(term: TermConfig, key: str) -> None:
    """The body or frame of a term's point, and the point (xyz)."""
    if not term.body:
        raise ConfigError(f"{key}.body: required (the body or frame the point is fixed on)")
    check_length(term.point, 3, f"{key}.point")


def _check_position(term: TermConfig, key: str) -> None:
    _check_body(term, key)
    check_length(term.target_velocity, 3, f"{key}.target_velocity")
    _validate_vector_target(term, key, (3,), "xyz in m")


def _check_orientation(term: TermConfig, key: str) -> None:
    _check_body(term, key)
    _validate_vector_target(term, key, (3, 4), "roll, pitch, yaw in rad")


def _check_velocity(term: TermConfig, key: str) -> None:
    _check_body(term, key)
    _validate_vector_target(term, key, (3,), "")


def _check_height(term: TermConfig, key: str) -> None:
    _check_body(term, key)
    check_length(term.normal, 3, f"{key}.normal")
    check_length(term.above_point, 3, f"{key}.above_point")
    if math.hypot(*term.normal) < 1e-9:
        raise ConfigError(f"{key}.normal: must be non-zero")
    _validate_scalar_target(term, key)


def _check_distance(term: TermConfig, key: str) -> None:
    if not (term.geometry_a and term.geometry_b):
        raise ConfigError(f"{key}: a distance term needs geometry_a and geometry_b")
    _validate_scalar_target(term, key)


def _check_joint_limits(term: TermConfig, key: str) -> None:
    check_weight(term.margin, term.margin, f"{key}.margin", False)
    if term.margin < 0:
        raise ConfigError(f"{key}.margin: must be >= 0 (rad or m inside each limit)")
    if any(not isinstance(j, str) or not j for j in term.joints):
        raise ConfigError(f"{key}.joints: expected joint names, got {term.joints!r}")


def _check_slip(term: TermConfig, key: str) -> None:
    """A slip term's clearance (> 0 m, required) and sphere radius (>= 0 m)."""
    _check_body(term, key)
    c = term.clearance
    if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) or c <= 0:
        raise ConfigError(f"{key}.clearance: required, a height > 0 (m), got {c!r}")
    r = term.radius
    if isinstance(r, bool) or not isinstance(r, (int, float)) or not math.isfinite(r) or r < 0:
        raise ConfigError(f"{key}.radius: expected a length >= 0 (m), got {r!r}")


_POINT = frozenset({"body", "point"})
for _spec in (
    TermType("position", _POINT | {"relative_to", "axes", "target", "target_velocity",
             "relative_to_start"}, _check_position, vector=True),
    TermType("orientation", frozenset({"body", "relative_to", "axes", "target",
             "relative_to_start"}), _check_orientation, vector=True),
    TermType("velocity", _POINT | {"relative_to", "axes", "target"}, _check_velocity,
             vector=True),
    TermType("height", _POINT | {"target", "min", "max", "normal", "above_body",
             "above_point"}, _check_height),
    TermType("distance", frozenset({"geometry_a", "geometry_b", "target", "min", "max"}),
             _check_distance, approach=True),
    TermType("slip", _POINT | {"radius", "clearance"}, _check_slip),
    TermType("joint_limits", frozenset({"joints", "margin"}), _check_joint_limits),
):  # fmt: skip
    register_term_type(_spec)


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


def _validate_term_weight(term: TermConfig, key: str, vector: bool) -> None:
    """Distinct axes among x, y, z (position, velocity); a weight >= 0, or one per axis."""
    axes = term.axes
    if vector and (not axes or any(a not in AXES for a in axes) or len(set(axes)) < len(axes)):
        raise ConfigError(f"{key}.axes: expected distinct axes among x, y, z, got {axes}")
    n = len(axes) if vector else 1
    w = term.weight
    ws = w if isinstance(w, list) and vector else [w]
    for x in ws:
        check_weight(x, w, f"{key}.weight", True)
    if len(ws) not in (1, n):
        raise ConfigError(f"{key}.weight: expected a number or {n} values (one per axis)")


def _validate_vector_target(term: TermConfig, key: str, sizes: tuple, required: str) -> None:
    """A 3-vector term's target: ``sizes`` numbers (orientation: 3, roll, pitch, yaw, or 4, a
    quaternion); when None, ``required`` says what it holds unless the term is
    relative_to_start (empty: optional, as a velocity's 0)."""
    t = term.target
    if t is None:
        if required and not term.relative_to_start:
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


def _validate_scalar_target(term: TermConfig, key: str) -> None:
    """A height's or distance's target number, or min and/or max."""
    t = term.target
    bounds = term.min is not None or term.max is not None
    if (t is None) == (not bounds):
        raise ConfigError(f"{key}: give a target, or min and/or max (not both)")
    if t is not None:
        check_weight(t, t, f"{key}.target", False)
    if term.min is not None and term.max is not None and term.min > term.max:
        raise ConfigError(f"{key}.min: {term.min} is above max {term.max}")
