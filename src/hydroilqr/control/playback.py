"""Hardware-style playback of a solved trajectory on a second, "real" simulation (paper §V).

The paper executed its Kinova trajectories open loop on the robot with a stiff PD+ law
(eq. 11) at 1 kHz, the trajectory slowed to half speed and the reference (ū, q̄_J, v̄_J)
updated every 20 ms, with no feedback on the ball. Here the robot is a second simulation of
the same task: a finer time step (1 ms by default) and a different discrete contact
approximation from the planner's, started from the plan's initial state.

    from hydroilqr.control.playback import PlaybackSettings, load_run, playback
    from hydroilqr.output.results import write_playback
    task, sol, _ = load_run("runs/kinova-forward")
    result = playback(task, sol, PlaybackSettings(speed=0.5))
    write_playback(task, result, "runs/kinova-forward/playback-pd")

Policies:

* ``pd`` (eq. 11): τ = ū − Kp (q_J − q̄_J) − Kd (v_J − v̄_J) on the actuated joints only,
  computed at ``rate`` Hz from the measured joint state and a reference held for
  ``update_period`` seconds of playback time. At speed s the reference at playback time τ is
  the plan at plan time s·τ (linear interpolation of X, the plan's zero-order-hold input),
  and v̄_J is the plan's velocity times s (the derivative of the time-stretched q̄_J) unless
  ``scale_velocity_reference`` is off. The feed-forward ū (``feedforward``): "scaled"
  (default) is the plan's input dynamically scaled to the speed, ū_s = g(q̄) + s²·(ū − g(q̄))
  with g the planning model's gravity compensation at the reference state: rigid-body
  inverse dynamics of a trajectory slowed to q(s·t) keep the gravity term and scale the
  rest by s² (J. M. Hollerbach, "Dynamic scaling of manipulator trajectories", ASME J. Dyn.
  Sys. Meas. Control 106(1), 1984); "plan" uses ū unchanged at any speed, as the paper did.
  The two are the same at speed 1.
* ``ilqr`` (eq. 8): u = ū_k − K_k (x − x̄_k) with the full state (including unactuated
  coordinates), recomputed once per plan step (plan time). Only speed 1 reproduces the
  conditions under which K was computed; at other speeds x̄ still holds the plan's velocities.

Torques are clipped to the actuators' effort limits (as a robot would), and the fraction of
saturated commands is reported.

Its parts: ``playback_settings.py`` (settings, result types, ``load_run``),
``playback_hold.py`` (the hold after the plan, the PD+ check, advisories),
``playback_metrics.py`` (what a playback measured, the executed motion's goal); their public
names are importable from here.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from pydrake.multibody.tree import JointIndex

from hydroilqr.control.playback_hold import (
    _hold,
    _passive_joints,
    _pd_check,
    _Trajectory,
    advisories,
    hold_reference,
    pd_period,
    settle_plan,
)
from hydroilqr.control.playback_metrics import (
    _gap_key,
    _metrics,
    _rest_caveat,
    executed,
    executed_goal,
)
from hydroilqr.control.playback_settings import (
    HALF_SPEED,
    POLICIES,
    TRUTH_CONTACT,
    HoldPhase,
    ObjectSpec,
    PlaybackResult,
    PlaybackSettings,
    Reference,
    SolvedRun,
    damping_law,
    damping_note,
    load_run,
    truth_config,
)
from hydroilqr.metrics.common import SATURATION_WARNING
from hydroilqr.model.contacts import touched_pairs
from hydroilqr.model.pd import pd_torque
from hydroilqr.model.plant import Dynamics, SimulationError, position_unit
from hydroilqr.problem.errors import ConfigError
from hydroilqr.solver.solution import Solution

__all__ = [
    "HALF_SPEED",
    "POLICIES",
    "SATURATION_WARNING",
    "TRUTH_CONTACT",
    "HoldPhase",
    "ObjectSpec",
    "PlanSampler",
    "PlaybackResult",
    "PlaybackSettings",
    "Reference",
    "SolvedRun",
    "actuated_joints",
    "advisories",
    "choose_object",
    "damping_law",
    "damping_note",
    "executed",
    "executed_goal",
    "feedforward",
    "hold_reference",
    "load_run",
    "pd_period",
    "playback",
    "plan_touches",
    "settle_plan",
    "truth_config",
]


def plan_touches(task, X: np.ndarray) -> bool:
    """Some state of the plan X: [N+1, nx] has contact (else no contact is damped, and a note
    about contact damping says nothing)."""

    if not task.dynamics.scene_graph.model_inspector().GetCollisionCandidates():
        return False
    return bool(touched_pairs(task, X))


# ------------------------------------------------------------------------------------------
# Plant bookkeeping
# ------------------------------------------------------------------------------------------


class ActuatedJoints(NamedTuple):
    """The actuated 1-DoF joints, ordered as the actuation input vector (nu entries each)."""

    actuators: list[str]  # actuator names
    joints: list[str]  # joint names
    units: list[str]  # "m" (prismatic) or "rad"
    q_indices: np.ndarray  # [nu] indices of the joints' positions in x
    v_indices: np.ndarray  # [nu] indices of the joints' velocities in x
    effort_limits: np.ndarray  # [nu], inf where none


def actuated_joints(plant) -> ActuatedJoints:
    """(actuator names, joint names, joint units, q indices, v indices, effort limits),
    ordered as the actuation input vector; unpacks as that 6-tuple."""
    acts = [plant.get_joint_actuator(i) for i in plant.GetJointActuatorIndices()]
    acts.sort(key=lambda a: a.input_start())
    names, joints, units, qi, vi, lim = [], [], [], [], [], []
    for a in acts:
        j = a.joint()
        if j.num_positions() != 1 or j.num_velocities() != 1:
            raise ConfigError(
                f"actuator {a.name()}: joint {j.name()} is not a 1-DoF joint; "
                "PD+ playback needs 1-DoF actuated joints"
            )
        names.append(a.name())
        joints.append(j.name())
        units.append(position_unit(j))
        qi.append(j.position_start())
        vi.append(plant.num_positions() + j.velocity_start())
        e = a.effort_limit()
        lim.append(e if np.isfinite(e) and e > 0 else np.inf)
    return ActuatedJoints(names, joints, units, np.array(qi, int), np.array(vi, int), np.array(lim))


def choose_object(
    dyn: Dynamics, requested: str | None = None, X_plan: np.ndarray | None = None
) -> ObjectSpec:
    """The floating body if any (ball, quadruped body), else the unactuated joint that moves
    most in the plan X_plan: [N+1, nx] (the first one without a plan), else the first joint;
    with the indices of its velocity (``velocity``: the tangent of its position coordinates)."""
    obj = _choose_object(dyn, requested, X_plan)
    layout = dyn.layout
    b = layout.block(obj.name, "playback object")
    nq, nv = dyn.nq, dyn.nv
    vel = tuple(nq + t for t in b.tangent if t < nv)
    return dataclasses.replace(obj, velocity=vel)


def _choose_object(
    dyn: Dynamics, requested: str | None = None, X_plan: np.ndarray | None = None
) -> ObjectSpec:
    layout, plant = dyn.layout, dyn.plant
    if requested:
        b = layout.block(requested, "playback object")
        if b.kind == "quaternion":
            raise ConfigError(
                f"playback object: {requested} is an orientation; give a position block"
            )
        for q in layout.quaternions:  # a floating body's position: the same as chosen by default
            if requested == q.name[: -len(".orientation")] + ".position":
                return ObjectSpec(b.name, "floating", b.coords, q.coords, "m")
        unit = "m" if requested.endswith("position") else ""
        if plant.HasJointNamed(requested) and plant.GetJointByName(requested).num_positions() == 1:
            unit = position_unit(plant.GetJointByName(requested))
        return ObjectSpec(requested, "joint", b.coords, unit=unit)
    for b in layout.quaternions:
        base = b.name[: -len(".orientation")]
        pos = layout.primitives[f"{base}.position"]
        return ObjectSpec(pos.name, "floating", pos.coords, b.coords, "m")
    joints = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
    first = next((j for j in joints if j.num_positions() > 0), None)
    passive = _passive_joints(plant)
    if passive:
        first = passive[0]
        if X_plan is not None and len(X_plan) > 1:  # the one the plan moves (e.g. a turned brick)
            moved = [
                abs(X_plan[-1, j.position_start()] - X_plan[0, j.position_start()]) for j in passive
            ]
            first = passive[int(np.argmax(moved))]
    if first is None:
        raise ConfigError("playback: the model has no moving joint")
    for b in layout.primitives.values():
        if b.coords and b.coords[0] == first.position_start() and b.kind == "euclidean":
            unit = position_unit(first)
            return ObjectSpec(b.name, "joint", b.coords, unit=unit)
    raise ConfigError(f"playback: no state block for joint {first.name()}")


# ------------------------------------------------------------------------------------------
# Plan sampling
# ------------------------------------------------------------------------------------------


class PlanSampler:
    """The plan as a function of plan time p (seconds from its start)."""

    def __init__(self, sol: Solution, quaternions):
        self.X, self.U, self.K = np.asarray(sol.X), np.asarray(sol.U), np.asarray(sol.K)
        t = np.asarray(sol.t, float)
        self.t = t - t[0]
        self.N = self.U.shape[0]
        self.duration = float(self.t[-1])
        self.quats = [list(b.coords) for b in quaternions]

    def index(self, p: float) -> int:
        """Plan step k whose input is active at plan time p (zero-order hold)."""
        k = int(np.searchsorted(self.t, p + 1e-9, side="right")) - 1
        return int(np.clip(k, 0, self.N - 1))

    def state(self, p: float) -> np.ndarray:
        """x̄(p): linear interpolation between knots; quaternions renormalized."""
        p = float(np.clip(p, 0.0, self.duration))
        k = int(np.clip(np.searchsorted(self.t, p, side="right") - 1, 0, self.N - 1))
        h = self.t[k + 1] - self.t[k]
        a = 0.0 if h <= 0 else (p - self.t[k]) / h
        x0, x1 = self.X[k], self.X[k + 1]
        x = (1.0 - a) * x0 + a * x1
        for c in self.quats:
            q1 = x1[c] if np.dot(x0[c], x1[c]) >= 0 else -x1[c]
            q = (1.0 - a) * x0[c] + a * q1
            x[c] = q / np.linalg.norm(q)
        return x

    def input(self, p: float) -> np.ndarray:
        return self.U[self.index(p)]


# ------------------------------------------------------------------------------------------
# Playback
# ------------------------------------------------------------------------------------------


@dataclass
class Playback:
    """A playback checked and ready to run (``prepare``)."""

    task: Any
    sol: Solution
    settings: PlaybackSettings

    def run(self, progress=None) -> PlaybackResult:
        return _run(self.task, self.sol, self.settings, progress)


def prepare(task, sol: Solution, settings: PlaybackSettings | None = None) -> Playback:
    """The playback of ``sol`` on ``task`` under ``settings`` (default PlaybackSettings()),
    its settings checked once, before any work: ConfigError for settings that cannot run."""
    settings = settings or PlaybackSettings()
    settings.validate()
    settings.check_against(task, float(sol.t[-1] - sol.t[0]))
    return Playback(task, sol, settings)


def playback(
    task, sol: Solution, settings: PlaybackSettings | None = None, progress=None
) -> PlaybackResult:
    """Executes ``sol`` on the "real" system with the chosen policy (``prepare``, then
    ``Playback.run``). Raises SimulationError if the real system's time step fails,
    ConfigError on bad settings."""
    return prepare(task, sol, settings).run(progress)


def _run(task, sol: Solution, settings: PlaybackSettings, progress=None) -> PlaybackResult:
    """The playback of checked settings."""
    wall0 = time.perf_counter()
    planner = task.dynamics
    truth = Dynamics(truth_config(task, settings))
    _check_sizes(truth, planner, sol, settings)
    act_names, joint_names, units, qi, vi, limits = actuated_joints(truth.plant)
    obj = choose_object(truth, settings.object, sol.X)
    plan = PlanSampler(sol, truth.layout.quaternions)
    clock = _PlayClock.of(plan, settings)
    ctl = _Controller(task, plan, settings, clock, qi, vi, limits, np.zeros(truth.nu))
    X, U = _simulate(truth, plan.X[0], ctl, clock, progress)
    reference = _reference(task, plan, ctl, clock, qi, vi)

    t = np.arange(clock.n + 1) * clock.dt
    X_plan = np.array([plan.state(clock.s * tk) for tk in t])
    U_plan = np.array([plan.input(clock.s * tk) for tk in t[:-1]])
    hold = None
    if settings.rest_max > 0:
        hold = _hold_phase(truth, planner, plan, X[-1], t, qi, vi, limits, obj, settings, ctl)
    result = PlaybackResult(
        settings=settings,
        planner_contact=task.config.plant.contact_approximation,
        truth_contact=truth.spec.plant.contact_approximation,
        planner_time_step=task.config.plant.time_step,
        t=t,
        X=X,
        U=U,
        X_plan=X_plan,
        U_plan=U_plan,
        reference=reference,
        joints=joint_names,
        joint_units=units,
        actuators=act_names,
        q_indices=qi,
        v_indices=vi,
        obj=obj,
        metrics={},
        wall_seconds=0.0,
        hold=hold,
    )
    m = _metrics(result, qi, vi, limits, clock.vscale, ctl.saturated, ctl.controls, plan.X[-1])
    result.metrics = m
    _add_warnings(result, truth, plan, joint_names, vi, settings)
    caveat, drop = _rest_caveat(task, result)
    if drop:  # no resting gap against an object gone out of the scene
        m["object"].update(resting_gap=None, no_resting_gap=caveat)
        m[_gap_key("resting_gap", obj.unit)] = None
        m["warnings"].append(f"no resting gap: {caveat}")
    elif caveat:  # a gap against an extension still moving: kept, not the headline
        m["object"]["resting_gap_caveat"] = caveat
        m["warnings"].append(f"resting gap not the measure: {caveat}")
    if result.metrics["saturated_fraction"] > SATURATION_WARNING:
        result.metrics["warnings"].append(_saturation_warning(result.metrics, ctl, settings))
    result.wall_seconds = time.perf_counter() - wall0
    result.metrics["wall_seconds"] = result.wall_seconds
    return result


def _check_sizes(truth: Dynamics, planner: Dynamics, sol: Solution, st: PlaybackSettings):
    """ConfigError when the truth model, the plan or its gains do not fit one another."""
    if truth.nx != planner.nx or truth.nu != planner.nu:
        raise ConfigError("playback: the truth model's state/input size differs from the plan's")
    if sol.X.shape[1] != truth.nx or sol.U.shape[1] != truth.nu:
        raise ConfigError(
            f"playback: solution has nx={sol.X.shape[1]}, nu={sol.U.shape[1]} "
            f"but the task has nx={truth.nx}, nu={truth.nu}"
        )
    if st.policy == "ilqr" and np.shape(sol.K) != (sol.U.shape[0], truth.nu, truth.nx):
        raise ConfigError(
            "playback --policy ilqr: the plan has no feedback gains K (saved without them); "
            "use --policy pd"
        )


@dataclass
class _PlayClock:
    """The playback's timing: speed ``s``, truth step ``dt``, ``n`` steps, the control
    period in playback time and the scale of the velocity reference."""

    s: float
    dt: float
    n: int
    tol: float
    ctrl_period: float
    vscale: float

    @classmethod
    def of(cls, plan: PlanSampler, settings: PlaybackSettings) -> _PlayClock:
        s = float(settings.speed)
        dt = float(settings.truth_time_step)
        T_play = plan.duration / s
        n = max(1, int(round(T_play / dt)))
        tol = 1e-9 * max(1.0, T_play)
        ctrl_period = pd_period(settings)  # whole truth steps, as _pd_check assumes
        if settings.policy == "ilqr":
            ctrl_period = float(plan.t[1] - plan.t[0]) / s if plan.N > 0 else dt
        vscale = s if settings.scale_velocity_reference else 1.0
        return cls(s, dt, n, tol, ctrl_period, vscale)


@dataclass
class _Controller:
    """The policy's command at each truth step (held between control instants), the PD+
    references it sent, and how many commands it made and clipped."""

    task: Any
    plan: PlanSampler
    settings: PlaybackSettings
    clock: _PlayClock
    qi: np.ndarray
    vi: np.ndarray
    limits: np.ndarray
    u: np.ndarray
    next_update: float = 0.0
    next_ctrl: float = 0.0
    qbar: Any = None
    vbar: Any = None
    ubar: Any = None
    saturated: int = 0
    controls: int = 0
    hold_saturated: int = 0  # (of saturated and controls: those of the hold after the plan)
    hold_controls: int = 0
    ref_t: list = field(default_factory=list)
    ref_q: list = field(default_factory=list)
    ref_v: list = field(default_factory=list)
    ref_u: list = field(default_factory=list)

    def command(self, tau: float, x: np.ndarray) -> np.ndarray:
        if self.settings.policy == "pd":
            self._pd(tau, x)
        else:
            self._ilqr(tau, x)
        return self.u

    def _pd(self, tau: float, x: np.ndarray) -> None:
        st, c, tol = self.settings, self.clock, self.clock.tol
        if tau >= self.next_update - tol:
            while self.next_update + st.update_period <= tau + tol:
                self.next_update += st.update_period  # update period < truth step
            xr = self.plan.state(c.s * self.next_update)
            self.qbar, self.vbar = xr[self.qi], c.vscale * xr[self.vi]
            u_plan = self.plan.input(c.s * self.next_update)
            self.ubar = feedforward(self.task.dynamics, u_plan, xr, st)
            self.ref_t.append(self.next_update)
            self.ref_q.append(self.qbar)
            self.ref_v.append(self.vbar)
            self.ref_u.append(self.ubar)
            self.next_update += st.update_period
        if tau >= self.next_ctrl - tol:
            self.u = pd_torque(
                self.ubar, x[self.qi], x[self.vi], self.qbar, self.vbar, st.kp, st.kd
            )
            self._count_and_clip(tau)

    def _ilqr(self, tau: float, x: np.ndarray) -> None:
        if tau >= self.next_ctrl - self.clock.tol:
            plan = self.plan
            j = plan.index(self.clock.s * tau)
            self.u = plan.U[j] - plan.K[j] @ (x - plan.X[j])
            self._count_and_clip(tau)

    def _count_and_clip(self, tau: float) -> None:
        while self.next_ctrl <= tau + self.clock.tol:
            self.next_ctrl += self.clock.ctrl_period
        self.controls += 1
        if self.settings.clip_torques:
            self.saturated += int(np.count_nonzero(np.abs(self.u) > self.limits))
            self.u = np.clip(self.u, -self.limits, self.limits)


def feedforward(
    dyn: Dynamics, u_plan: np.ndarray, x_ref: np.ndarray, st: PlaybackSettings
) -> np.ndarray:
    """The PD+ feed-forward ū: [nu] sent with the reference state x_ref: [nx] (the plan at
    plan time p), for the plan's input u_plan: [nu] at p. The plan's input is taken as it
    acted (clipped to ``dyn``'s effort limits: a command beyond a limit acted at it). With
    ``st.feedforward`` "scaled" at speed s ≠ 1 it is dynamically scaled (Hollerbach 1984):
    g + s²·(ū − g), g = ``dyn``'s gravity compensation at x_ref (the planning model's); for
    s ≤ 1 a blend of two torques within the limits when g is. Not clipped again: the PD+
    command is, when torques are clipped."""
    u = dyn.clip_to_limits(u_plan)
    s = float(st.speed)
    if st.feedforward == "plan" or s == 1.0:
        return u  # the plan's torque bitwise (g + 1·(ū − g) could differ in the last bit)
    g = dyn.gravity_compensation(x_ref)
    return g + s * s * (u - g)


def _simulate(truth: Dynamics, x0, ctl: _Controller, clock: _PlayClock, progress):
    """X: [n+1, nx] and U: [n, nu] of the real system under ``ctl``, from ``x0``."""
    n, dt = clock.n, clock.dt
    X = np.empty((n + 1, truth.nx))
    U = np.empty((n, truth.nu))
    X[0] = x0
    for k in range(n):
        tau = k * dt
        x = X[k]
        u = ctl.command(tau, x)
        U[k] = u
        try:
            X[k + 1] = truth.step(x, u)
        except SimulationError as e:
            raise SimulationError(f"real system, t={tau:.3f} s: {e}") from None
        if truth.layout.quaternions:
            X[k + 1] = truth.layout.normalize(X[k + 1])
        if progress is not None and k % 100 == 0:
            progress(k, n)
    return X, U


def _reference(task, plan: PlanSampler, ctl: _Controller, clock: _PlayClock, qi, vi):
    """The exported reference: the PD+ one in any case (what a robot would be sent)."""
    ref_t, ref_q, ref_v, ref_u = ctl.ref_t, ctl.ref_q, ctl.ref_v, ctl.ref_u
    if ctl.settings.policy == "ilqr" or not ref_t:
        # the updates the pd policy makes: every period while a step is left (tau < T_play)
        s, dt, tol = clock.s, clock.dt, clock.tol
        ref_t = list(np.arange(0.0, (clock.n - 1) * dt + tol, ctl.settings.update_period))
        for tr in ref_t:
            xr = plan.state(s * tr)
            ref_q.append(xr[qi])
            ref_v.append(clock.vscale * xr[vi])
            ref_u.append(feedforward(task.dynamics, plan.input(s * tr), xr, ctl.settings))
    return Reference(
        np.array(ref_t),
        np.array(ref_q).reshape(len(ref_t), -1),
        np.array(ref_v).reshape(len(ref_t), -1),
        np.array(ref_u).reshape(len(ref_t), -1),  # from the plan's input clipped where sampled
    )


def _hold_phase(truth, planner, plan, x_end, t, qi, vi, limits, obj, settings, ctl):
    """Where things come to rest: the robot holds its last reference, the planning model
    is extended the same way (settle_plan), both until the object rests or rest_max. The
    hold's commands are counted in ``ctl``."""
    ref = hold_reference(truth, plan.X[-1], qi)
    Xh, Uh, sat_h, ctl_h, rested = _hold(truth, x_end, ref, qi, vi, limits, obj, settings)
    ctl.saturated += sat_h
    ctl.controls += ctl_h
    ctl.hold_saturated, ctl.hold_controls = sat_h, ctl_h
    Xs, rested_plan = settle_plan(planner, plan.X[-1], obj, settings)
    ext = PlanSampler(
        _Trajectory(Xs, np.zeros((len(Xs) - 1, truth.nu)), planner.dt),
        truth.layout.quaternions,
    )
    th = t[-1] + ctl.clock.dt * np.arange(1, len(Xh) + 1)
    Xp = np.array([ext.state(tk - t[-1]) for tk in th]).reshape(len(th), truth.nx)
    return HoldPhase(th, Xh, Uh, Xp, Xs, rested, rested_plan)


def _add_warnings(result: PlaybackResult, truth, plan, joint_names, vi, settings) -> None:
    """The advisories, the PD check (pd policy) and the saturation warning, in the metrics."""
    result.metrics["warnings"] = advisories(truth.plant, settings)
    if settings.policy == "pd":
        pd = _pd_check(truth, plan.X[0], joint_names, vi, settings)
        result.metrics.update({**pd, "warnings": result.metrics["warnings"] + pd["warnings"]})


def _saturation_warning(metrics: dict, ctl: _Controller, settings: PlaybackSettings) -> str:
    """Many commands hit the effort limits: what that means, with the advice that applies to
    the policy and phase where it happened (the hold after the plan is PD+ for either
    policy; the plan's phase under ilqr has no gains to tune)."""
    head = (
        f"{100 * metrics['saturated_fraction']:.0f}% of the commands hit the effort limits: "
        "the playback cannot apply what the controller asks"
    )
    in_hold = ctl.hold_saturated / max(1, ctl.saturated)
    if settings.policy == "pd":
        return f"{head} (lower --kp/--kd, or a slower --speed)"
    where = f"{100 * (1 - in_hold):.0f}% of them while playing the plan, the rest in the hold"
    advice = (
        "under --policy ilqr the plan's own gains act: the real system strays far from the "
        "plan (compare --truth-contact and --truth-time-step with the planner's), or the plan "
        "itself commands near its limits (the solve's commands_beyond_limits)"
    )
    if in_hold > 0.5:
        advice = (
            "mostly in the hold after the plan, PD+ at the default gains under --policy ilqr: "
            "--rest-max 0 skips it"
        )
    return f"{head} ({where}; {advice})"
