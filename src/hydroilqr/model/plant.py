"""Discrete dynamics x_{k+1} = f(x_k, u_k) (paper eq. 2) from a task's models and contact config.

``build_diagram`` assembles MultibodyPlant + SceneGraph (and, on request, Meshcat and contact
visualizers) from a ``TaskConfig``; ``Dynamics`` wraps the plant-only diagram with ``step`` and
``rollout``. Two Drake traps are handled here (see drake-notes.md): the plant is built with
``use_sampled_output_ports=False`` so that a forced discrete update really steps, and the
contact approximation is chosen explicitly (``tamsi`` only to reproduce the paper).

Building lives in ``model/build.py``, contact properties and geometry names in
``model/contact_geometry.py``; their public names are importable from here.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydrake.geometry import HydroelasticContactRepresentation as Rep
from pydrake.geometry import (
    SceneGraph,
)

from hydroilqr.model.build import (
    MODEL_INCLUDE_DEPTH,
    Scene,
    _refuse_failed_download,
    apply_actuators,
    build_diagram,
    check_inertias,
    check_model_references,
)
from hydroilqr.model.contact_geometry import (
    NEEDS_RESOLUTION_HINT,
    GeometryNames,
    check_contact_pairs,
    collision_geometries,
    geometry_hits,
    hydroelastic_kind,
    named_geometries,
)
from hydroilqr.model.state import StateLayout
from hydroilqr.problem.plant import PlantSpec
from hydroilqr.problem.task import TaskConfig

__all__ = [
    "DIVERGED",
    "MODEL_INCLUDE_DEPTH",
    "NEEDS_RESOLUTION_HINT",
    "AutoDiffPlant",
    "Dynamics",
    "GeometryNames",
    "PlantSpec",
    "Scene",
    "SimulationError",
    "_refuse_failed_download",
    "apply_actuators",
    "build_diagram",
    "check_contact_pairs",
    "check_inertias",
    "check_model_references",
    "collision_geometries",
    "feedback_rollout",
    "geometry_hits",
    "hydroelastic_kind",
    "named_geometries",
    "position_unit",
]

# A state beyond this (m, rad, m/s, rad/s) is a blown-up simulation, not a motion.
DIVERGED = 1e6


class SimulationError(RuntimeError):
    """A time step failed (contact solver did not converge, or the state became non-finite)."""


class AutoDiffPlant(NamedTuple):
    """The AutoDiffXd copy of a task's diagram (``Dynamics.autodiff``); unpacks as the tuple
    (diagram, context, plant, plant_context, input_port) it used to be."""

    diagram: object
    context: object
    plant: object
    plant_context: object
    input_port: object  # the diagram's actuation input port


_POSITION_UNITS = {"prismatic": "m", "revolute": "rad", "quaternion_floating": "m"}


def position_unit(joint) -> str:
    """The unit of a Drake joint's position coordinates: "m" (prismatic, a floating body's
    position), "rad" (revolute), "" for other joint types."""
    return _POSITION_UNITS.get(joint.type_name(), "")


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
        self._actuation_pinv: np.ndarray | None = None  # pinv(B), on first use
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
        if self._actuation_pinv is None:  # B is the model's: one pseudo-inverse, not one a step
            self._actuation_pinv = np.linalg.pinv(self.plant.MakeActuationMatrix())
        return -self._actuation_pinv @ tau_g

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
