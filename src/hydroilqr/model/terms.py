"""Task-space cost terms (``cost.terms``): residuals of points on bodies and of distances.

Each term is a residual r(x) of the state, costing ``f_k · Σ_i w_i r_i²`` at every step k of
its window (``f_k``: 1, or the linear ``ramp``, times the time step with
``running_cost_dt``) or at the last state (``terminal``), beside the quadratic terms of
``cost.py`` and in their convention (no ½):

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
  against a ``target`` (``r = s − target``) or one-sided bounds (``r = min(0, s − min) +
  max(0, s − max)``: a clearance ``min``).
* ``distance``: ``s`` = the signed distance between two named geometries (the closest pair of
  the sets they name; SceneGraph's ``ComputeSignedDistancePairClosestPoints``), against a
  target or bounds as for height: an approach term that has a gradient before any contact.
* ``joint_limits``: ``r_i = min(0, q_i − (lo_i + margin)) + max(0, q_i − (hi_i − margin))`` for
  each joint coordinate with finite position limits in the model files (``Scene.
  position_limits``, also where ``plant.joint_limits: false`` removed them from the plant).
* ``slip``: ``r = g(h) (v_WC)_xy``, the horizontal velocity of C, the lowest point of a sphere
  of ``radius`` about P (a foot), as a material point of P's body (``v_WC = v_WP + ω_WB ×
  (−radius ẑ)``), with ``g(h) = max(0, 1 − h/clearance)``, h = C's height above z = 0: a foot
  that slides while it is down, or moves horizontally while it is low, costs; one that is
  ``clearance`` above the ground moves freely. No clock and no reference: it asks stance feet
  to stay put and swing feet to lift before they travel.

A running term with ``softmin`` τ > 0 costs instead the soft minimum of its steps' costs c_k
over its window, ``S = −τ log(mean_k exp(−c_k/τ))`` (between their minimum and their mean): a
small residual at some step, not at every one. ``∂S/∂c_k = p_k``, the softmax of −c_k/τ, so
each step's derivatives below are scaled by p_k (the coupling between steps is dropped from
the Hessian: it is negative semidefinite, and the rest stays positive semidefinite).

Derivatives are Gauss-Newton, ``l_x = 2 f Jᵀ W r`` and ``l_xx = 2 f Jᵀ W J`` with
``J = ∂r/∂x`` in the state's coordinates x = [q; v], from MultibodyPlant kinematics: position
Jacobians with respect to q̇ (``JacobianWrtVariable.kQDot``: the partials in q itself, also
for quaternion coordinates, which Drake normalizes), for an orientation the angular-velocity
Jacobian mapped through ∂e/∂ω (q̇_AB = ½ [0; ω] ⊗ q_AB), the witness points' Jacobians projected
on the distance's gradient direction ``nhat_BA_W`` for a distance, and for a velocity the
Jacobian with respect to v, its change with q by central differences of that Jacobian over
the coordinates that move the point (a slip's: of the point's translational and its body's
angular velocity Jacobians; its weight g(h) through P's position Jacobian). One plant
context (of its own diagram context, for the geometry queries) is reused for every step; a
state is set once per step for all terms.
Times are the task's (``t_k = t0 + k·dt``), so windows and moving targets hold across
receding-horizon windows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RollPitchYaw
from pydrake.multibody.tree import FrameIndex, JacobianWrtVariable

from hydroilqr.model.plant import named_geometries
from hydroilqr.model.state import left_mul_matrix, quat_conj
from hydroilqr.problem.config import AXES, ConfigError, TermConfig, unknown_key

# Central-difference step (in q's units) of a velocity term's ∂v_P/∂q.
VELOCITY_FD_STEP = 1e-6


@dataclass
class _Term:
    """One term, resolved against the plant."""

    cfg: TermConfig
    weights: np.ndarray  # [m] per residual component
    sel: list[int]  # the axes (position, velocity)
    frame: object = None  # the point's frame (position, velocity, height; orientation's B)
    point: np.ndarray | None = None  # P in that frame
    frame_a: object = None  # measured in (position, orientation, velocity)
    # position: the target at t = 0; orientation: the target quaternion; velocity: the target
    target0: np.ndarray | None = None
    q_moving: np.ndarray | None = None  # velocity: coordinates of q that move P or A
    normal: np.ndarray | None = None  # height
    frame_q: object = None  # height over a point: Q's frame (None: over the plane)
    point_q: np.ndarray | None = None  # Q in that frame
    pairs: list | None = None  # distance: (GeometryId a, GeometryId b)
    coords: np.ndarray | None = None  # joint_limits: indices into q
    lower: np.ndarray | None = None  # joint_limits: where the cost starts, margin included
    upper: np.ndarray | None = None

    @property
    def name(self) -> str:
        return self.cfg.name

    @property
    def size(self) -> int:
        return len(self.weights)


class TaskSpaceTerms:
    """The task's ``cost.terms`` on a plant. ``dynamics``: a ``plant.Dynamics``; ``x0``: the
    initial state (for ``relative_to_start``); ``end_time``: the task's end (s), where a
    window without ``until`` ends for its ramp."""

    def __init__(
        self,
        dynamics,
        configs: list[TermConfig],
        dt: float,
        running_cost_dt: bool,
        x0: np.ndarray,
        end_time: float,
    ):
        self.dynamics = dynamics
        self.plant = dynamics.plant
        self.nq, self.nv = self.plant.num_positions(), self.plant.num_velocities()
        self.nx = self.nq + self.nv
        self.dt = dt
        self.running_cost_dt = running_cost_dt
        self.end_time = float(end_time)
        self._context = dynamics.diagram.CreateDefaultContext()
        self._pc = self.plant.GetMyMutableContextFromRoot(self._context)
        self.terms = [self._resolve(c) for c in configs]
        # [n_terms, 1]: terms that cost something (weight 0: left out of the cost's evaluation)
        self._weighted = np.array([bool(np.any(t.weights)) for t in self.terms])[:, None]
        x0 = np.asarray(x0, float)
        self._set(x0)
        for t in self.terms:
            if t.cfg.type == "position" and t.cfg.relative_to_start:
                p0 = self._position(t)
                t.target0 = p0 + (np.zeros(3) if t.cfg.target is None else t.target0)
            if t.cfg.type == "orientation" and t.cfg.relative_to_start:
                q0 = self._quaternion(t)
                extra = np.array([1.0, 0, 0, 0]) if t.cfg.target is None else t.target0
                t.target0 = _quat_product(q0, extra)
            if t.cfg.type == "distance":
                self._distance(t)  # every pair is supported (a ConfigError names it)

    # ------------------------------------------------------------------ resolving names
    def _frame(self, name: str, key: str):
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

    def _moving_coordinates(self, frames) -> np.ndarray:
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

    def _root_translations(self) -> np.ndarray:
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

    def _resolve(self, c: TermConfig) -> _Term:
        key = f"cost.terms.{c.name}"
        vector = c.type in ("position", "orientation", "velocity")
        sel = [AXES.index(a) for a in c.axes] if vector else [0]
        if c.type == "slip":
            sel = [0, 1]  # the world's horizontal axes
        w = np.asarray(c.weight, float).reshape(-1)
        weights = np.full(len(sel), w[0]) if w.size == 1 else w
        t = _Term(c, weights, sel)
        if c.type == "joint_limits":
            return self._resolve_limits(t, key)
        if c.type == "distance":
            geoms = self.dynamics.geometry_names()
            a = named_geometries(c.geometry_a, geoms, f"{key}.geometry_a")
            b = named_geometries(c.geometry_b, geoms, f"{key}.geometry_b")
            t.pairs = [(ga, gb) for ga in a for gb in b if ga != gb]
            if not t.pairs:
                raise ConfigError(f"{key}: geometry_a and geometry_b name the same geometry")
            self._geometry_frames(a + b)
            return t
        t.frame = self._frame(c.body, f"{key}.body")
        t.point = np.asarray(c.point, float)
        t.frame_a = (
            self._frame(c.relative_to, f"{key}.relative_to")
            if c.relative_to
            else self.plant.world_frame()
        )
        if c.type == "position" and c.target is not None:
            t.target0 = np.asarray(c.target, float)
        if c.type == "orientation" and c.target is not None:
            t.target0 = _quaternion(c.target)
        if c.type == "velocity":
            t.target0 = np.zeros(3) if c.target is None else np.asarray(c.target, float)
            t.q_moving = self._moving_coordinates([t.frame, t.frame_a])
        if c.type == "height":
            t.normal = np.asarray(c.normal, float) / np.linalg.norm(c.normal)
            if c.above_body:
                t.frame_q = self._frame(c.above_body, f"{key}.above_body")
                t.point_q = np.asarray(c.above_point, float)
        if c.type == "slip":
            t.q_moving = np.setdiff1d(
                self._moving_coordinates([t.frame]), self._root_translations()
            )
        return t

    def _resolve_limits(self, t: _Term, key: str) -> _Term:
        """A joint_limits term's coordinates and bounds (the margin inside the model's limits)."""
        c = t.cfg
        lower, upper = self.dynamics.scene.position_limits
        limited = np.isfinite(lower) | np.isfinite(upper)
        if c.joints:
            coords = []
            for name in c.joints:
                b = self.dynamics.layout.block(name, f"{key}.joints")
                if b.kind == "quaternion" or max(b.coords) >= self.nq:
                    raise ConfigError(f"{key}.joints: {name} is not a block of joint positions")
                if not limited[list(b.coords)].any():
                    raise ConfigError(
                        f"{key}.joints: {name} has no position limits in the model files"
                    )
                coords += [i for i in b.coords if limited[i] and i not in coords]
        else:
            coords = list(np.flatnonzero(limited))
            if not coords:
                raise ConfigError(f"{key}: the model files limit no joint's position")
        t.coords = np.array(coords, dtype=int)
        t.lower = lower[t.coords] + c.margin
        t.upper = upper[t.coords] - c.margin
        if np.any(t.lower > t.upper):
            raise ConfigError(
                f"{key}.margin: {c.margin} is more than half of a joint's range of motion"
            )
        t.weights = np.full(len(coords), t.weights[0])
        return t

    def _geometry_frames(self, ids) -> None:
        """Records each geometry's body frame and its pose there (for witness points)."""
        if not hasattr(self, "_gframe"):
            self._gframe: dict = {}
        inspector = self.dynamics.scene_graph.model_inspector()
        for g in ids:
            body = self.plant.GetBodyFromFrameId(inspector.GetFrameId(g))
            frame = body.body_frame() if body is not None else self.plant.world_frame()
            X = inspector.GetPoseInFrame(g)  # geometry in its body's frame, as (R, p)
            self._gframe[g] = (frame, X.rotation().matrix(), X.translation())

    # ------------------------------------------------------------------ residuals
    def _set(self, x: np.ndarray) -> None:
        self.plant.SetPositionsAndVelocities(self._pc, x)

    def _position(self, t: _Term) -> np.ndarray:
        return self.plant.CalcPointsPositions(self._pc, t.frame, t.point, t.frame_a).ravel()

    def _quaternion(self, t: _Term) -> np.ndarray:
        """Frame B's orientation in A as a unit quaternion [w, x, y, z]."""
        q = self.plant.CalcRelativeRotationMatrix(self._pc, t.frame_a, t.frame).ToQuaternion()
        return np.array([q.w(), q.x(), q.y(), q.z()])

    def _jq(self, frame, point, frame_a=None) -> np.ndarray:
        """∂p_AP/∂q (expressed in A, default world): [3, nq]."""
        a = self.plant.world_frame() if frame_a is None else frame_a
        return self.plant.CalcJacobianTranslationalVelocity(
            self._pc, JacobianWrtVariable.kQDot, frame, point, a, a
        )

    def _jv(self, t: _Term) -> np.ndarray:
        return self.plant.CalcJacobianTranslationalVelocity(
            self._pc, JacobianWrtVariable.kV, t.frame, t.point, t.frame_a, t.frame_a
        )

    def _distance(self, t: _Term):
        """The closest pair's SignedDistancePair."""
        query = self.plant.get_geometry_query_input_port().Eval(self._pc)
        best = None
        for a, b in t.pairs:
            try:
                sd = query.ComputeSignedDistancePairClosestPoints(a, b)
            except RuntimeError as e:
                names = self.dynamics.geometry_names()
                msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
                raise ConfigError(
                    f"cost.terms.{t.name}: Drake has no signed distance between "
                    f"{names[a][0]} and {names[b][0]} ({msg})"
                ) from None
            if best is None or sd.distance < best.distance:
                best = sd
        return best

    def _scalar(self, t: _Term, s: float) -> tuple[float, float]:
        """(r, dr/ds) of a height or distance s against its target or bounds."""
        c = t.cfg
        if c.target is not None:
            return s - float(c.target), 1.0
        if c.min is not None and s < c.min:
            return s - c.min, 1.0
        if c.max is not None and s > c.max:
            return s - c.max, 1.0
        return 0.0, 0.0

    def _residual(self, t: _Term, x: np.ndarray, time: float, jac: bool):
        """(r [m], J [m, nx] or None, the measured quantity) at the state set in the context
        (x: that state)."""
        nq = self.nq
        J = np.zeros((t.size, self.nx)) if jac else None
        kind = t.cfg.type
        if kind == "position":
            p = self._position(t)
            target = t.target0 + np.asarray(t.cfg.target_velocity, float) * time
            r = (p - target)[t.sel]
            if jac:
                J[:, :nq] = self._jq(t.frame, t.point, t.frame_a)[t.sel]
            return r, J, p
        if kind == "orientation":
            q = self._quaternion(t)
            L = left_mul_matrix(quat_conj(t.target0))
            qe = L @ q
            s = -1.0 if qe[0] < 0 else 1.0
            r = (2.0 * s * qe[1:])[t.sel]
            if jac:
                # ė = s (L(q*⁻¹) R(q))[1:, 1:] ω_AB (q̇ = ½ [0; ω] ⊗ q), ω_AB = J_ω q̇
                Jw = self.plant.CalcJacobianAngularVelocity(
                    self._pc, JacobianWrtVariable.kQDot, t.frame, t.frame_a, t.frame_a
                )
                J[:, :nq] = (s * (L @ _right_mul_matrix(q))[1:, 1:] @ Jw)[t.sel]
            return r, J, _rpy(q)
        if kind == "velocity":
            Jv = self._jv(t)
            v = Jv @ x[nq:]
            r = (v - t.target0)[t.sel]
            if jac:
                J[:, nq:] = Jv[t.sel]
                J[:, t.q_moving] = self._dvdq(t, x)[t.sel]
            return r, J, v
        if kind == "joint_limits":
            q = x[t.coords]
            r = np.minimum(0.0, q - t.lower) + np.maximum(0.0, q - t.upper)
            if jac:
                rows = np.flatnonzero(r)
                J[rows, t.coords[rows]] = 1.0
            return r, J, q
        if kind == "slip":
            return self._slip(t, x, jac)
        if kind == "height":
            p = self.plant.CalcPointsPositions(
                self._pc, t.frame, t.point, self.plant.world_frame()
            ).ravel()
            if t.frame_q is not None:
                p = (
                    p
                    - self.plant.CalcPointsPositions(
                        self._pc, t.frame_q, t.point_q, self.plant.world_frame()
                    ).ravel()
                )
            s = float(t.normal @ p)
            r, d = self._scalar(t, s)
            if jac and d:
                Jp = self._jq(t.frame, t.point)
                if t.frame_q is not None:
                    Jp = Jp - self._jq(t.frame_q, t.point_q)
                J[0, :nq] = d * (t.normal @ Jp)
            return np.array([r]), J, s
        sd = self._distance(t)
        s = float(sd.distance)
        r, d = self._scalar(t, s)
        if jac and d:
            fa, Ra, pa = self._gframe[sd.id_A]
            fb, Rb, pb = self._gframe[sd.id_B]
            Ja = self._jq(fa, Ra @ sd.p_ACa + pa)  # the witness points on their bodies
            Jb = self._jq(fb, Rb @ sd.p_BCb + pb)
            J[0, :nq] = d * (np.asarray(sd.nhat_BA_W).ravel() @ (Ja - Jb))
        return np.array([r]), J, s

    def _slip_jacobian(self, t: _Term) -> np.ndarray:
        """∂(v_WC)_xy/∂v [2, nv] at the context's positions, C = P − radius ẑ a point of P's
        body: v_WC = v_WP + ω_WB × (−radius ẑ) = v_WP + radius (−ω_y, ω_x, 0)."""
        world = self.plant.world_frame()
        Jv = self.plant.CalcJacobianTranslationalVelocity(
            self._pc, JacobianWrtVariable.kV, t.frame, t.point, world, world
        )
        Jw = self.plant.CalcJacobianAngularVelocity(
            self._pc, JacobianWrtVariable.kV, t.frame, world, world
        )
        rad = t.cfg.radius
        return np.array([Jv[0] - rad * Jw[1], Jv[1] + rad * Jw[0]])

    def _slip(self, t: _Term, x: np.ndarray, jac: bool):
        """(r [2], J [2, nx] or None, [C's horizontal speed, its height]) of a slip term."""
        nq, v = self.nq, x[self.nq :]
        c = t.cfg
        world = self.plant.world_frame()
        h = float(self.plant.CalcPointsPositions(self._pc, t.frame, t.point, world)[2, 0])
        h -= c.radius
        g = max(0.0, 1.0 - h / c.clearance)
        Js = self._slip_jacobian(t)
        vc = Js @ v
        J = np.zeros((2, self.nx)) if jac else None
        if jac and g > 0.0:
            J[:, nq:] = g * Js
            # g'(h) ∂h/∂q (h = p_z − radius), then g ∂(v_WC)_xy/∂q on the coordinates that
            # move P other than a floating base's translation
            J[:, :nq] = np.outer(vc, -self._jq(t.frame, t.point)[2] / c.clearance)
            J[:, t.q_moving] += g * self._dq(t, x, lambda: self._slip_jacobian(t) @ v, 2)
        return g * vc, J, np.array([float(np.hypot(*vc)), h])

    def _dq(self, t: _Term, x: np.ndarray, f, m: int) -> np.ndarray:
        """∂f/∂q on the coordinates that move the point ([m, len(q_moving)]), f() -> [m]
        evaluated at the context's positions, by central differences (the context is left
        at x)."""
        h = VELOCITY_FD_STEP
        out = np.empty((m, len(t.q_moving)))
        q = x[: self.nq].copy()
        for col, i in enumerate(t.q_moving):
            vals = []
            for s in (h, -h):
                qi = q.copy()
                qi[i] += s
                self.plant.SetPositions(self._pc, qi)
                vals.append(f())
            out[:, col] = (vals[0] - vals[1]) / (2 * h)
        self.plant.SetPositions(self._pc, q)
        return out

    def _dvdq(self, t: _Term, x: np.ndarray) -> np.ndarray:
        """∂(J_v(q) v)/∂q on the coordinates that move the point: [3, len(q_moving)], by
        central differences of Drake's Jacobian (the context is left at x)."""
        v = x[self.nq :]
        return self._dq(t, x, lambda: self._jv(t) @ v, 3)

    # ------------------------------------------------------------------ over a trajectory
    def windows(self, N: int, t0: float, times=None) -> tuple[np.ndarray, np.ndarray]:
        """(active [n_terms, N+1] bool, factor [n_terms, N+1]): where each term counts in an
        N-step solve from t0 and its weight factor there (ramp × dt for running terms with
        running_cost_dt; 0 outside the window). ``times``: [N+1] the states' times, if not
        t0 + k·dt (e.g. a closed-loop run sampled otherwise)."""
        times = self._times(N, t0, times)
        active = np.zeros((len(self.terms), N + 1), bool)
        factor = np.zeros((len(self.terms), N + 1))
        eps = 1e-9
        for i, t in enumerate(self.terms):
            c = t.cfg
            if c.terminal:
                active[i, N] = True
                factor[i, N] = 1.0
                continue
            a = 0.0 if c.after is None else c.after
            b = np.inf if c.until is None else c.until
            on = (times >= a - eps) & (times <= b + eps)
            on[N] = False  # running terms: steps 0..N-1, as Q
            ramp = np.ones(N + 1)
            if c.ramp:
                end = self.end_time if c.until is None else c.until
                span = end - a
                s = np.clip((times - a) / span, 0.0, 1.0) if span > 0 else np.ones(N + 1)
                ramp = c.ramp[0] + (c.ramp[1] - c.ramp[0]) * s
            active[i] = on
            factor[i] = np.where(on, ramp * (self.dt if self.running_cost_dt else 1.0), 0.0)
        return active, factor

    def _times(self, N: int, t0: float, times=None) -> np.ndarray:
        if times is not None and len(times) == N + 1:
            return np.asarray(times, float)
        return t0 + self.dt * np.arange(N + 1)

    def _evaluate(self, X: np.ndarray, t0: float, jac: bool, times=None, unweighted=False):
        """Per term: residuals R [N+1, m] (0 outside its window), Jacobians [N+1, m, nx] (with
        ``jac``) and the measured quantity at each active step (dict k -> value). Terms of
        weight 0 (e.g. an approach term that only a continuation stage switches on) cost
        nothing and are left out (their R stays 0) unless ``unweighted``: a report measures
        them."""
        X = np.asarray(X, float)
        N = X.shape[0] - 1
        active, factor = self.windows(N, t0, times)
        if not unweighted:
            active = active & self._weighted
        R = [np.zeros((N + 1, t.size)) for t in self.terms]
        Js = [np.zeros((N + 1, t.size, self.nx)) for t in self.terms] if jac else None
        meas: list[dict] = [{} for _ in self.terms]
        times = self._times(N, t0, times)
        for k in np.flatnonzero(active.any(axis=0)):
            self._set(X[k])
            for i in np.flatnonzero(active[:, k]):
                t = self.terms[i]
                need = jac and factor[i, k] > 0
                r, J, m = self._residual(t, X[k], float(times[k]), need)
                R[i][k] = r
                if need:
                    Js[i][k] = J
                meas[i][int(k)] = m
        return active, factor, R, Js, meas

    def stage_costs(self, X: np.ndarray, t0: float = 0.0) -> np.ndarray:
        """The terms' cost at each step: [N+1]."""
        return np.sum(self._costs(X, t0), axis=0)

    def _costs(self, X, t0) -> np.ndarray:
        """[n_terms, N+1]."""
        active, factor, R, _, _ = self._evaluate(X, t0, False)
        out = np.empty((len(self.terms), X.shape[0]))
        with np.errstate(over="ignore", invalid="ignore"):
            for i, t in enumerate(self.terms):
                out[i] = _step_costs(t, factor[i], R[i])
                if t.cfg.softmin > 0:
                    mask = active[i] & (factor[i] > 0)
                    value, p = softmin(out[i], mask, t.cfg.softmin)
                    # the soft minimum, spread over the window's steps (an infinite one on each)
                    out[i] = p * value if np.isfinite(value) else np.where(mask, value, 0.0)
        return out

    def breakdown(self, X: np.ndarray, t0: float = 0.0) -> dict[str, float]:
        """``terms.<name>`` -> the term's cost along X."""
        c = self._costs(X, t0)
        return {f"terms.{t.name}": float(np.sum(c[i])) for i, t in enumerate(self.terms)}

    def quadratize(self, X: np.ndarray, t0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Gauss-Newton lx: [N+1, nx] and lxx: [N+1, nx, nx] of the terms along X."""
        active, factor, R, Js, _ = self._evaluate(X, t0, True)
        n = X.shape[0]
        lx, lxx = np.zeros((n, self.nx)), np.zeros((n, self.nx, self.nx))
        for i, t in enumerate(self.terms):
            f = factor[i][:, None]
            if t.cfg.softmin > 0:  # d(soft minimum)/dc_k = p_k: each step's own terms times p_k
                c = _step_costs(t, factor[i], R[i])
                f = f * softmin(c, active[i] & (factor[i] > 0), t.cfg.softmin)[1][:, None]
            lx += 2.0 * f * np.einsum("kmj,m,km->kj", Js[i], t.weights, R[i])
            lxx += 2.0 * f[:, :, None] * np.einsum("kmj,m,kml->kjl", Js[i], t.weights, Js[i])
        return lx, lxx

    def report(self, X: np.ndarray, t0: float = 0.0, times=None) -> dict[str, dict]:
        """Per term, at the last step of its window in X: ``error`` (|r|, unweighted: m, m/s),
        ``final`` (the point's position or velocity [3], the height or distance), ``step``;
        and ``cost`` (its cost along X). Empty for a term whose window holds no step.
        ``times``: [N+1] the states' times, if not t0 + k·dt."""
        active, factor, R, _, meas = self._evaluate(X, t0, False, times, unweighted=True)
        out = {}
        for i, t in enumerate(self.terms):
            steps = np.flatnonzero(active[i])
            if steps.size == 0:
                continue
            k = int(steps[-1])
            c = _step_costs(t, factor[i], R[i])
            cost = float(np.sum(c))
            if t.cfg.softmin > 0:  # a soft minimum: its value, at the step it is smallest
                cost = softmin(c, active[i] & (factor[i] > 0), t.cfg.softmin)[0]
                k = int(steps[np.argmin(c[steps])])
            m = meas[i][k]
            out[t.name] = {
                "error": float(np.linalg.norm(R[i][k])),
                "final": np.asarray(m, float).tolist() if np.ndim(m) else float(m),
                "step": k,
                "cost": cost,
            }
        return out


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


def _step_costs(t: _Term, factor: np.ndarray, R: np.ndarray) -> np.ndarray:
    """One term's cost at each step, f_k · Σ_i w_i r_i²: [N+1] (factor [N+1], R [N+1, m])."""
    return factor * np.einsum("ki,i,ki->k", R, t.weights, R)


def softmin(c: np.ndarray, active: np.ndarray, tau: float) -> tuple[float, np.ndarray]:
    """The soft minimum S = -τ log(mean_k exp(-c_k / τ)) of the costs c: [N+1] over the active
    steps (a bool mask [N+1]), and its gradient p = dS/dc: [N+1] (softmax weights of -c/τ on
    the active steps, summing to 1; 0 elsewhere). S lies between min and mean of the active
    c_k. (0, zeros) when no step is active; (inf or NaN, zeros) when an active c_k is (as a
    sum of the costs would be)."""
    p = np.zeros_like(c)
    idx = np.flatnonzero(active)
    if idx.size == 0:
        return 0.0, p
    ca = c[idx]
    if not np.all(np.isfinite(ca)):
        return float(np.sum(ca)), p
    m = float(np.min(ca))
    e = np.exp(-(ca - m) / tau)  # shifted by the minimum: no overflow for a small τ
    value = m - tau * np.log(np.mean(e))
    p[idx] = e / np.sum(e)
    return float(value), p
