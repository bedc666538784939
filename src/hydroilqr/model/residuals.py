"""The residuals of the task-space cost terms (``cost.terms``): one class per term type,
registered by name (``RESIDUALS``, the one place a term's ``type`` is looked up).

A residual r(x) of the state, with its Jacobian J = ∂r/∂x in the state's coordinates
x = [q; v], from MultibodyPlant kinematics at the state set in a shared ``Kinematics``
context. model/terms.py composes each with an activation (its target or bounds, then the
weighted square) and a time shaping (window, ramp, terminal); see there for the cost.

* ``position``: ``r = S (p_AP(q) − p*(t))``, a point P fixed on a body or frame against a target
  that is fixed, moves linearly (``p*(t) = target + target_velocity · t``) or is an offset from
  P's position in the initial state (``relative_to_start``); in the world or in frame A
  (``relative_to``); S selects ``axes``.
* ``orientation``: ``r = S e``, ``e = 2 sign(w) vec(q*⁻¹ ⊗ q_AB) = 2 sin(θ/2)·axis`` (the state
  difference's error of ``state.py``: the rotation from the target to frame B's orientation in
  A, in the target's axes), against a target roll-pitch-yaw or quaternion, or the start
  orientation (``relative_to_start``, then ``target`` is a rotation after it).
* ``velocity``: ``r = S (v_AP(q, v) − v*)``, P's translational velocity measured and expressed in
  A (default the world).
* ``height``: ``s = n · p_WP`` (height above the plane through the origin with unit normal n),
  or ``s = n · (p_WP − p_WQ)`` over a point Q on another body (``above_body``, ``above_point``),
  against a ``target`` or one-sided bounds (the activations ``Target`` and ``Bounds``).
* ``distance``: ``s`` = the signed distance between two named geometries (the closest pair of
  the sets they name; SceneGraph's ``ComputeSignedDistancePairClosestPoints``), against a
  target or bounds as for height: an approach term that has a gradient before any contact.
* ``joint_limits``: ``s = q_i`` for each joint coordinate with finite position limits in the
  model files (``Scene.position_limits``, also where ``plant.joint_limits: false`` removed
  them from the plant), against ``Bounds`` [lo_i + margin, hi_i − margin].
* ``slip``: ``r = g(h) (v_WC)_xy``, the horizontal velocity of C, the lowest point of a sphere
  of ``radius`` about P (a foot), as a material point of P's body (``v_WC = v_WP + ω_WB ×
  (−radius ẑ)``), with ``g(h) = max(0, 1 − h/clearance)``, h = C's height above z = 0: a foot
  that slides while it is down, or moves horizontally while it is low, costs; one that is
  ``clearance`` above the ground moves freely. No clock and no reference: it asks stance feet
  to stay put and swing feet to lift before they travel.
* ``effort_limits``: a residual of the controls, not the state: ``s = u_i`` for each actuator
  with a finite effort limit (the model's ``<effort>`` or the task's ``actuators:``), against
  ``Bounds`` [−e_i + margin, e_i − margin]. Drake applies a command beyond its limit at the
  limit, so the step's derivative in that command is 0 (model/derivatives.py): a plan that
  leans on clipped commands has inputs its linear model cannot use. The term prices the part
  of a command beyond its bound, so plans keep their commands where they act. Its ``value``
  and ``jacobian`` take u (``controls = True``) and ∂s/∂u: [size, nu]; model/terms.py adds it
  to l_u and l_uu at the steps 0..N-1.

Jacobians: of positions with respect to q̇ (``JacobianWrtVariable.kQDot``: the partials in q
itself, also for quaternion coordinates, which Drake normalizes), for an orientation the
angular-velocity Jacobian mapped through ∂e/∂ω (q̇_AB = ½ [0; ω] ⊗ q_AB), the witness points'
Jacobians projected on the distance's gradient direction ``nhat_BA_W`` for a distance, and for
a velocity the Jacobian with respect to v, its change with q by central differences of that
Jacobian over the coordinates that move the point (a slip's: of the point's translational and
its body's angular velocity Jacobians; its weight g(h) through P's position Jacobian).

A new term type: a ``problem.terms.TermConfig`` subclass (its ``kind``, its keys and their
``check``) and a ``Residual`` subclass with ``config`` (that class), ``value`` and
``jacobian``, decorated with ``@register``; the finite-difference test of
tests/unit/test_terms.py runs over ``RESIDUALS``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RollPitchYaw
from pydrake.multibody.tree import FrameIndex, JacobianWrtVariable

from hydroilqr.model.activations import Bounds, Identity, Target
from hydroilqr.model.plant import named_geometries
from hydroilqr.model.state import left_mul_matrix, quat_conj
from hydroilqr.problem.checks import unknown_key
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.terms import (
    AXES,
    DistanceTerm,
    EffortLimitsTerm,
    HeightTerm,
    JointLimitsTerm,
    OrientationTerm,
    PositionTerm,
    SlipTerm,
    TermConfig,
    VelocityTerm,
    register_term_type,
)

# Central-difference step (in q's units) of a velocity term's ∂v_P/∂q.
VELOCITY_FD_STEP = 1e-6


class Kinematics:
    """One plant context (of its own diagram context, for the geometry queries) that every
    term of a cost reads at the state set once per step, and the plant queries they share."""

    def __init__(self, dynamics):
        self.dynamics = dynamics
        self.plant = dynamics.plant
        self.nq, self.nv = self.plant.num_positions(), self.plant.num_velocities()
        self.nx = self.nq + self.nv
        self.context = dynamics.diagram.CreateDefaultContext()
        self.pc = self.plant.GetMyMutableContextFromRoot(self.context)
        self.geometry_frame: dict = {}  # GeometryId -> (body frame, R, p of the geometry there)

    def set(self, x: np.ndarray) -> None:
        self.plant.SetPositionsAndVelocities(self.pc, x)

    def frame(self, name: str, key: str):
        """The body or frame ``name`` (``MODEL::NAME`` where several instances have one)."""
        p = self.plant
        if "::" in name:
            inst, fname = name.rsplit("::", 1)
            if p.HasModelInstanceNamed(inst):
                mi = p.GetModelInstanceByName(inst)
                if p.HasFrameNamed(fname, mi):
                    return p.GetFrameByName(fname, mi)
        elif p.HasFrameNamed(name):
            try:
                return p.GetFrameByName(name)
            except RuntimeError:
                raise ConfigError(
                    f"{key}: several model instances have a frame {name!r}; write MODEL::{name}"
                ) from None
        raise ConfigError(f"{key}: {unknown_key(name, self._frame_names(), 'body or frame')}")

    def _frame_names(self) -> list[str]:
        names = []
        for i in range(self.plant.num_frames()):
            n = self.plant.get_frame(FrameIndex(i)).name()
            if n and not n.startswith("__") and n not in names:
                names.append(n)
        return names

    def moving_coordinates(self, frames) -> np.ndarray:
        """Indices of q whose change moves a point fixed on any of ``frames``."""
        p = self.plant
        bodies = {f.body().index() for f in frames}
        idx: list[int] = []
        for j in p.GetJointIndices():
            joint = p.get_joint(j)
            if joint.num_positions() == 0:
                continue
            if bodies & set(p.GetBodiesKinematicallyAffectedBy([j])):
                idx += range(joint.position_start(), joint.position_start() + joint.num_positions())
        return np.array(sorted(idx), dtype=int)

    def root_translations(self) -> np.ndarray:
        """Indices of q that translate a floating base jointed to the world: a velocity
        expressed in the world does not change with them."""
        p = self.plant
        idx: list[int] = []
        for j in p.GetJointIndices():
            joint = p.get_joint(j)
            floating = joint.type_name() in ("quaternion_floating", "rpy_floating")
            if floating and joint.parent_body().index() == p.world_body().index():
                end = joint.position_start() + joint.num_positions()
                idx += range(end - 3, end)
        return np.array(idx, dtype=int)

    def add_geometry_frames(self, ids) -> None:
        """Records each geometry's body frame and its pose there (for witness points)."""
        inspector = self.dynamics.scene_graph.model_inspector()
        for g in ids:
            body = self.plant.GetBodyFromFrameId(inspector.GetFrameId(g))
            frame = body.body_frame() if body is not None else self.plant.world_frame()
            X = inspector.GetPoseInFrame(g)  # geometry in its body's frame, as (R, p)
            self.geometry_frame[g] = (frame, X.rotation().matrix(), X.translation())

    def position(self, frame, point, frame_a=None) -> np.ndarray:
        """p_AP (in A, default the world): [3]."""
        a = self.plant.world_frame() if frame_a is None else frame_a
        return self.plant.CalcPointsPositions(self.pc, frame, point, a).ravel()

    def jq(self, frame, point, frame_a=None) -> np.ndarray:
        """∂p_AP/∂q (expressed in A, default world): [3, nq]."""
        a = self.plant.world_frame() if frame_a is None else frame_a
        return self.plant.CalcJacobianTranslationalVelocity(
            self.pc, JacobianWrtVariable.kQDot, frame, point, a, a
        )

    def dq(self, coords: np.ndarray, x: np.ndarray, f, m: int) -> np.ndarray:
        """∂f/∂q on the coordinates ``coords`` ([m, len(coords)]), f() -> [m] evaluated at the
        context's positions, by central differences (the context is left at x)."""
        h = VELOCITY_FD_STEP
        out = np.empty((m, len(coords)))
        q = x[: self.nq].copy()
        for col, i in enumerate(coords):
            vals = []
            for s in (h, -h):
                qi = q.copy()
                qi[i] += s
                self.plant.SetPositions(self.pc, qi)
                vals.append(f())
            out[:, col] = (vals[0] - vals[1]) / (2 * h)
        self.plant.SetPositions(self.pc, q)
        return out


#: Residual classes by term type (``cost.terms[].type``).
RESIDUALS: dict[str, type[Residual]] = {}


def register(cls: type[Residual]) -> type[Residual]:
    """Registers a residual class under its config type's ``kind``, and that config type with
    the task format (problem.terms.TERM_TYPES: its keys and their checks)."""
    RESIDUALS[cls.config.kind] = cls
    register_term_type(cls.config)
    return cls


class Residual:
    """A term's residual r(x) on a plant: ``value`` (r or the measured s, what a report shows,
    and what ``jacobian`` reuses) and ``jacobian`` (∂r/∂x [size, nx]) at the state set in the
    shared context. ``start`` runs once at the initial state (for ``relative_to_start``)."""

    config: ClassVar[type[TermConfig]]  # its term type: the task format's keys and checks
    #: True for a residual of the controls u (``value``/``jacobian`` take u, not x).
    controls: ClassVar[bool] = False

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        self.cfg = cfg
        self.sel = [AXES.index(a) for a in cfg.axes] if cfg.vector else [0]

    @property
    def size(self) -> int:
        return len(self.sel)

    def activation(self) -> Any:
        """What the cost squares: r itself (``Identity``), s − target (``Target``) or the
        part of s beyond bounds (``Bounds``)."""
        return Identity()

    def start(self, kin: Kinematics) -> None:
        """At the initial state (set in ``kin``)."""

    def value(self, kin: Kinematics, x: np.ndarray, time: float) -> tuple[np.ndarray, Any, Any]:
        """(r or s [size], the measured quantity, what ``jacobian`` reuses)."""
        raise NotImplementedError

    def jacobian(self, kin: Kinematics, x: np.ndarray, aux: Any) -> np.ndarray:
        """∂r/∂x (or ∂s/∂x): [size, nx]."""
        raise NotImplementedError


class _OnBody(Residual):
    """A residual of a point P fixed on a body or frame (``body``, ``point``), measured in the
    frame A (``relative_to``; default the world)."""

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        super().__init__(cfg, kin, key)
        self.frame = kin.frame(cfg.body, f"{key}.body")
        # (a type without the key: the frame's origin; measured in the world)
        self.point = np.asarray(getattr(cfg, "point", (0.0, 0.0, 0.0)), float)
        relative_to = getattr(cfg, "relative_to", "")
        self.frame_a = (
            kin.frame(relative_to, f"{key}.relative_to") if relative_to else kin.plant.world_frame()
        )


@register
class Position(_OnBody):
    config = PositionTerm

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        super().__init__(cfg, kin, key)
        # the target at t = 0
        self.target0 = None if cfg.target is None else np.asarray(cfg.target, float)

    def start(self, kin: Kinematics) -> None:
        if self.cfg.relative_to_start:
            p0 = kin.position(self.frame, self.point, self.frame_a)
            self.target0 = p0 + (np.zeros(3) if self.cfg.target is None else self.target0)

    def value(self, kin, x, time):
        p = kin.position(self.frame, self.point, self.frame_a)
        target = self.target0 + np.asarray(self.cfg.target_velocity, float) * time
        return (p - target)[self.sel], p, None

    def jacobian(self, kin, x, aux):
        J = np.zeros((self.size, kin.nx))
        J[:, : kin.nq] = kin.jq(self.frame, self.point, self.frame_a)[self.sel]
        return J


@register
class Orientation(_OnBody):
    config = OrientationTerm

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        super().__init__(cfg, kin, key)
        self.target0 = None if cfg.target is None else _quaternion(cfg.target)

    def _quaternion(self, kin: Kinematics) -> np.ndarray:
        """Frame B's orientation in A as a unit quaternion [w, x, y, z]."""
        q = kin.plant.CalcRelativeRotationMatrix(kin.pc, self.frame_a, self.frame).ToQuaternion()
        return np.array([q.w(), q.x(), q.y(), q.z()])

    def start(self, kin: Kinematics) -> None:
        if self.cfg.relative_to_start:
            q0 = self._quaternion(kin)
            extra = np.array([1.0, 0, 0, 0]) if self.cfg.target is None else self.target0
            self.target0 = _quat_product(q0, extra)

    def value(self, kin, x, time):
        q = self._quaternion(kin)
        L = left_mul_matrix(quat_conj(self.target0))
        qe = L @ q
        s = -1.0 if qe[0] < 0 else 1.0
        return (2.0 * s * qe[1:])[self.sel], _rpy(q), (q, L, s)

    def jacobian(self, kin, x, aux):
        # ė = s (L(q*⁻¹) R(q))[1:, 1:] ω_AB (q̇ = ½ [0; ω] ⊗ q), ω_AB = J_ω q̇
        q, L, s = aux
        J = np.zeros((self.size, kin.nx))
        Jw = kin.plant.CalcJacobianAngularVelocity(
            kin.pc, JacobianWrtVariable.kQDot, self.frame, self.frame_a, self.frame_a
        )
        J[:, : kin.nq] = (s * (L @ _right_mul_matrix(q))[1:, 1:] @ Jw)[self.sel]
        return J


@register
class Velocity(_OnBody):
    config = VelocityTerm

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        super().__init__(cfg, kin, key)
        self.target0 = np.zeros(3) if cfg.target is None else np.asarray(cfg.target, float)
        self.q_moving = kin.moving_coordinates([self.frame, self.frame_a])

    def _jv(self, kin: Kinematics) -> np.ndarray:
        return kin.plant.CalcJacobianTranslationalVelocity(
            kin.pc, JacobianWrtVariable.kV, self.frame, self.point, self.frame_a, self.frame_a
        )

    def value(self, kin, x, time):
        Jv = self._jv(kin)
        v = Jv @ x[kin.nq :]
        return (v - self.target0)[self.sel], v, Jv

    def jacobian(self, kin, x, Jv):
        J = np.zeros((self.size, kin.nx))
        J[:, kin.nq :] = Jv[self.sel]
        # ∂(J_v(q) v)/∂q on the coordinates that move the point, by central differences of
        # Drake's Jacobian
        v = x[kin.nq :]
        J[:, self.q_moving] = kin.dq(self.q_moving, x, lambda: self._jv(kin) @ v, 3)[self.sel]
        return J


def _scalar_activation(cfg: TermConfig):
    """A height's or distance's target, or its bounds."""
    if cfg.target is not None:
        return Target(float(cfg.target))
    return Bounds(-np.inf if cfg.min is None else cfg.min, np.inf if cfg.max is None else cfg.max)


@register
class Height(_OnBody):
    config = HeightTerm

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        super().__init__(cfg, kin, key)
        self.normal = np.asarray(cfg.normal, float) / np.linalg.norm(cfg.normal)
        self.frame_q = None  # over a point Q of another body (None: over the plane)
        if cfg.above_body:
            self.frame_q = kin.frame(cfg.above_body, f"{key}.above_body")
            self.point_q = np.asarray(cfg.above_point, float)

    def activation(self):
        return _scalar_activation(self.cfg)

    def value(self, kin, x, time):
        p = kin.position(self.frame, self.point)
        if self.frame_q is not None:
            p = p - kin.position(self.frame_q, self.point_q)
        s = float(self.normal @ p)
        return np.array([s]), s, None

    def jacobian(self, kin, x, aux):
        J = np.zeros((1, kin.nx))
        Jp = kin.jq(self.frame, self.point)
        if self.frame_q is not None:
            Jp = Jp - kin.jq(self.frame_q, self.point_q)
        J[0, : kin.nq] = self.normal @ Jp
        return J


@register
class Distance(Residual):
    config = DistanceTerm

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        super().__init__(cfg, kin, key)
        geoms = kin.dynamics.geometry_names()
        a = named_geometries(cfg.geometry_a, geoms, f"{key}.geometry_a")
        b = named_geometries(cfg.geometry_b, geoms, f"{key}.geometry_b")
        self.pairs = [(ga, gb) for ga in a for gb in b if ga != gb]
        if not self.pairs:
            raise ConfigError(f"{key}: geometry_a and geometry_b name the same geometry")
        kin.add_geometry_frames(a + b)

    def activation(self):
        return _scalar_activation(self.cfg)

    def start(self, kin: Kinematics) -> None:
        self._closest(kin)  # every pair is supported (a ConfigError names it)

    def _closest(self, kin: Kinematics):
        """The closest pair's SignedDistancePair."""
        query = kin.plant.get_geometry_query_input_port().Eval(kin.pc)
        best = None
        for a, b in self.pairs:
            try:
                sd = query.ComputeSignedDistancePairClosestPoints(a, b)
            except RuntimeError as e:
                names = kin.dynamics.geometry_names()
                msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
                raise ConfigError(
                    f"cost.terms.{self.cfg.name}: Drake has no signed distance between "
                    f"{names[a][0]} and {names[b][0]} ({msg})"
                ) from None
            if best is None or sd.distance < best.distance:
                best = sd
        return best

    def value(self, kin, x, time):
        sd = self._closest(kin)
        s = float(sd.distance)
        return np.array([s]), s, sd

    def jacobian(self, kin, x, sd):
        J = np.zeros((1, kin.nx))
        fa, Ra, pa = kin.geometry_frame[sd.id_A]
        fb, Rb, pb = kin.geometry_frame[sd.id_B]
        Ja = kin.jq(fa, Ra @ sd.p_ACa + pa)  # the witness points on their bodies
        Jb = kin.jq(fb, Rb @ sd.p_BCb + pb)
        J[0, : kin.nq] = np.asarray(sd.nhat_BA_W).ravel() @ (Ja - Jb)
        return J


@register
class JointLimits(Residual):
    config = JointLimitsTerm

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        """The coordinates and bounds (the margin inside the model's limits)."""
        super().__init__(cfg, kin, key)
        lower, upper = kin.dynamics.scene.position_limits
        limited = np.isfinite(lower) | np.isfinite(upper)
        coords = self._joint_coords(kin, limited, key) if cfg.joints else []
        if not cfg.joints:
            coords = list(np.flatnonzero(limited))
            if not coords:
                raise ConfigError(f"{key}: the model files limit no joint's position")
        self.coords = np.array(coords, dtype=int)
        self.lower = lower[self.coords] + cfg.margin
        self.upper = upper[self.coords] - cfg.margin
        if np.any(self.lower > self.upper):
            raise ConfigError(
                f"{key}.margin: {cfg.margin} is more than half of a joint's range of motion"
            )
        self.sel = list(range(len(coords)))

    def _joint_coords(self, kin: Kinematics, limited: np.ndarray, key: str) -> list[int]:
        coords: list[int] = []
        for name in self.cfg.joints:
            b = kin.dynamics.layout.block(name, f"{key}.joints")
            if b.kind == "quaternion" or max(b.coords) >= kin.nq:
                raise ConfigError(f"{key}.joints: {name} is not a block of joint positions")
            if not limited[list(b.coords)].any():
                raise ConfigError(f"{key}.joints: {name} has no position limits in the model files")
            coords += [i for i in b.coords if limited[i] and i not in coords]
        return coords

    def activation(self):
        return Bounds(self.lower, self.upper)

    def value(self, kin, x, time):
        q = x[self.coords]
        return q, q, None

    def jacobian(self, kin, x, aux):
        J = np.zeros((self.size, kin.nx))
        J[np.arange(self.size), self.coords] = 1.0
        return J


@register
class EffortLimits(Residual):
    config = EffortLimitsTerm
    controls = True

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        """The actuators with finite effort limits and their bounds (``margin`` inside)."""
        super().__init__(cfg, kin, key)
        limits = np.asarray(kin.dynamics.effort_limits, float)
        self.actuators = np.flatnonzero(np.isfinite(limits))
        if self.actuators.size == 0:
            raise ConfigError(f"{key}: no actuator has an effort limit (model or actuators:)")
        lim = limits[self.actuators]
        if np.any(cfg.margin >= lim):
            raise ConfigError(f"{key}.margin: {cfg.margin} is not below every effort limit")
        self.lower, self.upper = -lim + cfg.margin, lim - cfg.margin
        self.nu = limits.size
        self.sel = list(range(self.actuators.size))
        self._J = np.zeros((self.actuators.size, self.nu))  # constant: u's limited entries
        self._J[np.arange(self.actuators.size), self.actuators] = 1.0

    def activation(self):
        return Bounds(self.lower, self.upper)

    def value(self, kin, u, time):
        s = np.asarray(u, float)[self.actuators]
        return s, s, None

    def jacobian(self, kin, u, aux):
        return self._J


@register
class Slip(_OnBody):
    config = SlipTerm

    def __init__(self, cfg: TermConfig, kin: Kinematics, key: str):
        super().__init__(cfg, kin, key)
        self.sel = [0, 1]  # the world's horizontal axes
        self.q_moving = np.setdiff1d(kin.moving_coordinates([self.frame]), kin.root_translations())

    def _jacobian_v(self, kin: Kinematics) -> np.ndarray:
        """∂(v_WC)_xy/∂v [2, nv] at the context's positions, C = P − radius ẑ a point of P's
        body: v_WC = v_WP + ω_WB × (−radius ẑ) = v_WP + radius (−ω_y, ω_x, 0)."""
        world = kin.plant.world_frame()
        Jv = kin.plant.CalcJacobianTranslationalVelocity(
            kin.pc, JacobianWrtVariable.kV, self.frame, self.point, world, world
        )
        Jw = kin.plant.CalcJacobianAngularVelocity(
            kin.pc, JacobianWrtVariable.kV, self.frame, world, world
        )
        rad = self.cfg.radius
        return np.array([Jv[0] - rad * Jw[1], Jv[1] + rad * Jw[0]])

    def value(self, kin, x, time):
        """(r [2], [C's horizontal speed, its height], (g, v_WC))."""
        v = x[kin.nq :]
        c = self.cfg
        world = kin.plant.world_frame()
        h = float(kin.plant.CalcPointsPositions(kin.pc, self.frame, self.point, world)[2, 0])
        h -= c.radius
        g = max(0.0, 1.0 - h / c.clearance)
        Js = self._jacobian_v(kin)
        vc = Js @ v
        return g * vc, np.array([float(np.hypot(*vc)), h]), (g, Js, vc)

    def jacobian(self, kin, x, aux):
        g, Js, vc = aux
        nq, v = kin.nq, x[kin.nq :]
        J = np.zeros((2, kin.nx))
        if g > 0.0:
            J[:, nq:] = g * Js
            # g'(h) ∂h/∂q (h = p_z − radius), then g ∂(v_WC)_xy/∂q on the coordinates that
            # move P other than a floating base's translation
            J[:, :nq] = np.outer(vc, -kin.jq(self.frame, self.point)[2] / self.cfg.clearance)
            J[:, self.q_moving] += g * kin.dq(
                self.q_moving, x, lambda: self._jacobian_v(kin) @ v, 2
            )
        return J


# ---------------------------------------------------------------------------------- rotations
def _quaternion(target) -> np.ndarray:
    """A unit quaternion [w, x, y, z] from roll-pitch-yaw [3] (rad) or a quaternion [4]."""

    v = np.asarray(target, float)
    if v.size == 3:
        q = RollPitchYaw(v).ToQuaternion()
        v = np.array([q.w(), q.x(), q.y(), q.z()])
    return v / np.linalg.norm(v)


def _quat_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return left_mul_matrix(a) @ b


def _right_mul_matrix(b: np.ndarray) -> np.ndarray:
    """R(b) such that a ⊗ b = R(b) a (quaternions [w, x, y, z])."""
    w, x, y, z = b
    return np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])


def _rpy(q: np.ndarray) -> list[float]:
    """Roll, pitch, yaw (rad) of a unit quaternion [w, x, y, z]."""

    return RollPitchYaw(Quaternion(q / np.linalg.norm(q))).vector().tolist()
