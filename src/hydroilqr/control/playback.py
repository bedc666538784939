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
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any, NamedTuple

import numpy as np
from pydrake.multibody.tree import JointIndex

from hydroilqr import metrics
from hydroilqr.metrics.common import SATURATION_WARNING
from hydroilqr.metrics.goals import judge
from hydroilqr.model.contacts import touched_pairs
from hydroilqr.model.pd import actuated_indices, pd_torque
from hydroilqr.model.plant import Dynamics, SimulationError, position_unit
from hydroilqr.model.scene import left_scene, scene_box
from hydroilqr.model.state import quat_conj, quat_mul
from hydroilqr.model.task import Task
from hydroilqr.problem.checks import MAX_STEPS
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.files import TASKS_DIR
from hydroilqr.problem.inputs import MAX_JSON_BYTES, read_bounded
from hydroilqr.problem.load import task_from_dict, with_overrides
from hydroilqr.problem.plant import APPROXIMATIONS
from hydroilqr.problem.playback import PLAYBACK_FEEDFORWARDS, PLAYBACK_POLICIES
from hydroilqr.problem.variants import check_truth_overrides
from hydroilqr.solver.solution import Solution, load_run_solution

#: Default "real" contact approximation for each planner approximation (always a different one).
TRUTH_CONTACT = {"sap": "similar", "similar": "sap", "lagged": "sap", "tamsi": "sap"}
POLICIES = PLAYBACK_POLICIES


def damping_law(approximation: str) -> str:
    """How Drake damps contact under a discrete contact approximation: SAP by each geometry's
    relaxation time (a linear Kelvin-Voigt model; Hunt-Crossley dissipation ignored), the
    others by Hunt-Crossley dissipation (relaxation time ignored)."""
    return "relaxation_time" if approximation == "sap" else "hunt_crossley"


def damping_note(planner_contact: str, truth_contact: str) -> str | None:
    """A note when the planner and the real system damp contact by different laws (then a
    rolling or sliding object meets different resistance in the two), else None."""
    a, b = damping_law(planner_contact), damping_law(truth_contact)
    if a == b:
        return None
    name = {"relaxation_time": "relaxation times", "hunt_crossley": "Hunt-Crossley dissipation"}
    return (
        f"the planner ({planner_contact}) damps contact by {name[a]}, the real system "
        f"({truth_contact}) by {name[b]}: a rolling or sliding object meets different "
        "resistance in the two (docs/playback.md)"
    )


def plan_touches(task, X: np.ndarray) -> bool:
    """Some state of the plan X: [N+1, nx] has contact (else no contact is damped, and a note
    about contact damping says nothing)."""

    if not task.dynamics.scene_graph.model_inspector().GetCollisionCandidates():
        return False
    return bool(touched_pairs(task, X))


# ------------------------------------------------------------------------------------------
# Settings and result
# ------------------------------------------------------------------------------------------


#: The paper's hardware playback (§IV-B): PD+ at the paper's gains, the plan at half speed,
#: on the finer simulation with the other contact approximation (PlaybackSettings' keys).
HALF_SPEED = {"speed": 0.5}


@dataclass
class PlaybackSettings:
    """How the plan is executed. Times in seconds of playback (wall) time unless noted."""

    # plan time advances s per second of playback; None: 0.5 for pd, 1 for ilqr (its gains
    # hold only at the plan's own timing)
    speed: float | None = None
    kp: float = 500.0  # PD+ stiffness (N·m/rad or N/m), same for every actuated joint
    kd: float = 5.0  # PD+ damping (N·m·s/rad or N·s/m)
    rate: float = 1000.0  # Hz, PD+ control loop
    update_period: float = 0.02  # s, reference (ū, q̄_J, v̄_J) update period
    policy: str = "pd"  # pd (eq. 11) | ilqr (eq. 8)
    truth_time_step: float = 0.001  # s, time step of the "real" system
    truth_contact: str | None = None  # None: TRUTH_CONTACT[planner's approximation]
    truth_overrides: list[str] = field(default_factory=list)  # KEY=VALUE on the truth task
    clip_torques: bool = True  # saturate at the actuators' effort limits
    scale_velocity_reference: bool = True  # v̄_J = s · v_plan (pd policy)
    # PD+ feed-forward ū: "scaled" g + s²·(ū_plan − g) (Hollerbach 1984), "plan" ū_plan
    feedforward: str = "scaled"
    object: str | None = None  # state block compared planned vs actual (None: automatic)
    # After the plan's end the robot holds its last reference until the object is at rest:
    # its speed below rest_speed (m/s or rad/s) for rest_time seconds, or rest_max seconds
    # passed (0: stop at the plan's end, no resting measurement).
    rest_speed: float = 0.005
    rest_time: float = 0.2
    rest_max: float = 3.0

    def check_against(self, task, plan_duration: float | None = None) -> None:
        """Settings that cannot fit ``task``'s plan (ConfigError); with ``plan_duration`` (s),
        also a playback too short (under one truth step) or too long to simulate."""
        check_truth_overrides(self.truth_overrides, playback=True)
        dt = task.config.plant.time_step
        if self.truth_time_step > dt * (1 + 1e-9):
            raise ConfigError(
                f"playback truth-time-step {self.truth_time_step:g} s: coarser than the plan's "
                f"time step ({dt:g} s); the 'real' system must be simulated at least as finely"
            )
        if plan_duration is not None:
            # A plan step may last less than a truth step (the reference is sampled every
            # update period anyway); the whole playback may not: it would be one step.
            if plan_duration / self.speed < self.truth_time_step * (1 - 1e-9):
                raise ConfigError(
                    f"playback speed {self.speed:g}: the {plan_duration:g} s plan would play in "
                    f"{plan_duration / self.speed:.3g} s, less than one truth step "
                    f"({self.truth_time_step:g} s): lower --speed or --truth-time-step"
                )
            steps = plan_duration / self.speed / self.truth_time_step
            if steps > MAX_STEPS:  # a mistyped --speed (the limit of any trajectory)
                raise ConfigError(
                    f"playback speed {self.speed:g}: {plan_duration / self.speed:.3g} s of "
                    f"playback is {steps:.3g} truth steps (at most {MAX_STEPS:.0e}): raise "
                    "--speed or --truth-time-step"
                )
        rest_steps = self.rest_max / self.truth_time_step
        if rest_steps > MAX_STEPS:  # the hold after the plan is stepped (and kept) as well
            raise ConfigError(
                f"playback rest-max {self.rest_max:g} s: {rest_steps:.3g} truth steps of hold "
                f"(at most {MAX_STEPS:.0e}): lower --rest-max or raise --truth-time-step"
            )

    def truth_contact_for(self, task) -> str:
        """The "real" system's contact approximation: ``truth_contact``, else the default
        other than the planner's (TRUTH_CONTACT)."""
        return self.truth_contact or TRUTH_CONTACT[task.config.plant.contact_approximation]

    def __post_init__(self) -> None:
        if self.speed is None:
            self.speed = 0.5 if self.policy == "pd" else 1.0

    def validate(self) -> None:
        for name in ("speed", "rate", "update_period", "truth_time_step"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"playback {name.replace('_', '-')}: must be positive, got {v}")
        for name in ("kp", "kd", "rest_speed", "rest_time", "rest_max"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"playback {name}: must be non-negative, got {v}")
        if self.policy not in POLICIES:
            raise ConfigError(f"playback policy: expected pd or ilqr, got {self.policy!r}")
        if self.feedforward not in PLAYBACK_FEEDFORWARDS:
            raise ConfigError(
                f"playback feedforward: expected scaled or plan, got {self.feedforward!r}"
            )
        if self.truth_contact is not None and self.truth_contact not in APPROXIMATIONS:
            raise ConfigError(
                f"playback truth-contact: expected one of "
                f"{', '.join(APPROXIMATIONS)}, got {self.truth_contact!r}"
            )


@dataclass
class Reference:
    """The held PD+ reference, one row per update (what a real robot would be sent).

    t: [M] playback time (s); q: [M, nJ] q̄_J; v: [M, nJ] v̄_J; u: [M, nu] ū.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray


@dataclass
class ObjectSpec:
    """The unactuated thing whose planned and actual motion are compared."""

    name: str  # state block name, e.g. "ball.position" or "pole_pin"
    kind: str  # "floating" (3-D position of a free body) or "joint" (joint coordinates)
    coords: tuple[int, ...]  # indices into x
    orientation: tuple[int, ...] = ()  # quaternion coords of a floating body
    unit: str = "m"
    velocity: tuple[int, ...] = ()  # indices into x of its velocity (rest detection)


@dataclass
class HoldPhase:
    """After the plan's end, on the truth time grid: t: [M] playback time (s), continuing the
    playback's; X: [M, nx] actual states; U: [M, nu] applied inputs; X_plan: [M, nx] the
    planning model's extension (settle_plan) at the same times since the plan's end. Its own
    states: X_settle: [P+1, nx] at the planner's time step. rested / rested_plan: whether the
    object came to rest before rest_max (else it was still moving when measured)."""

    t: np.ndarray
    X: np.ndarray
    U: np.ndarray
    X_plan: np.ndarray
    X_settle: np.ndarray
    rested: bool
    rested_plan: bool

    def summary(self) -> dict:
        dt_plan = (self.X_settle.shape[0] - 1) if len(self.X_settle) else 0
        return {
            "actual": {"rested": bool(self.rested), "hold_s": self.seconds},
            "planned": {"rested": bool(self.rested_plan), "hold_steps": int(dt_plan)},
        }

    @property
    def seconds(self) -> float:
        return float(self.t[-1] - self.t[0]) + self.step if len(self.t) else 0.0

    @property
    def step(self) -> float:
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else 0.0


@dataclass
class PlaybackResult:
    """Everything a playback produced. Arrays are sampled at every truth time step."""

    settings: PlaybackSettings
    planner_contact: str
    truth_contact: str
    planner_time_step: float
    t: np.ndarray  # [T+1] playback time (s)
    X: np.ndarray  # [T+1, nx] actual state
    U: np.ndarray  # [T, nu] applied (clipped) inputs
    X_plan: np.ndarray  # [T+1, nx] plan at plan time speed·t
    reference: Reference
    joints: list[str]  # actuated joint of each actuator, in input order
    joint_units: list[str]  # "rad", "m" (plant.position_unit)
    actuators: list[str]
    q_indices: np.ndarray  # [nu] index into x of each actuated joint's position
    v_indices: np.ndarray  # [nu] index into x of each actuated joint's velocity
    obj: ObjectSpec
    metrics: dict
    wall_seconds: float
    U_plan: np.ndarray | None = None  # [T, nu] the plan's input at plan time speed·t
    # After the plan's end: the robot holding its last reference until the object rests, and
    # the planning model extended the same way (None with rest_max 0).
    hold: HoldPhase | None = None


# ------------------------------------------------------------------------------------------
# Loading a solved run
# ------------------------------------------------------------------------------------------


class SolvedRun(NamedTuple):
    """A ``hydroilqr solve`` output directory, loaded: unpacks as ``task, sol, summary``."""

    task: Any  # hydroilqr.Task (rebuilt from summary.json's config)
    solution: Solution
    summary: dict  # summary.json


def load_run(run_dir: str | Path) -> SolvedRun:
    """The task, Solution and summary.json of a ``hydroilqr solve`` output directory."""

    run_dir = Path(run_dir)
    summary_path, sol_path = run_dir / "summary.json", run_dir / "solution.npz"
    if run_dir.is_file():
        raise ConfigError(f"{run_dir}: a file; give the run directory that holds summary.json")
    if not run_dir.is_dir():
        raise ConfigError(f"{run_dir}: no such directory")
    for p in (summary_path, sol_path):
        if not p.exists():
            raise ConfigError(f"{run_dir}: no {p.name} (is this a `hydroilqr solve` output?)")
    try:
        summary = json.loads(read_bounded(summary_path, "summary", MAX_JSON_BYTES))
        config = summary["config"]
    except (OSError, ValueError, KeyError, TypeError):
        raise ConfigError(f"{summary_path}: unreadable or has no 'config'") from None
    if not isinstance(config, dict):
        raise ConfigError(f"{summary_path}: its 'config' is not a mapping")
    candidates = [summary.get("base_dir"), str(TASKS_DIR), str(run_dir)]
    err: ConfigError | None = None
    task = None
    # A smoke-sized plan's task is the shrunk one (its config holds the shrunk values), and
    # its goal is the full task's: recorded as not judged, as the solve did.
    smoke = bool(summary.get("smoke"))
    for base in candidates:
        if not base:
            continue
        try:
            task = Task(dataclasses.replace(task_from_dict(config, base), smoke_run=smoke))
            break
        except ConfigError as e:
            err = err or e
    if task is None:
        raise ConfigError(f"{summary_path}: cannot rebuild the task: {err}")
    sol, _ = load_run_solution(sol_path, str(run_dir))
    return SolvedRun(task, sol, summary)


def truth_config(task, settings: PlaybackSettings):
    """The "real" system's TaskConfig: planner's config, finer step, other contact solver."""
    cfg = task.config
    d = cfg.to_dict()
    d["plant"]["time_step"] = float(settings.truth_time_step)
    d["plant"]["contact_approximation"] = settings.truth_contact_for(task)
    try:
        truth = task_from_dict(d, cfg.base_dir)
    except ConfigError as e:  # the task's own checks of its time grid, under the new step
        raise ConfigError(
            f"playback truth-time-step {settings.truth_time_step:g} s: {e} (a divisor of the "
            f"plan's {cfg.plant.time_step:g} s always fits)"
        ) from None
    return with_overrides(truth, settings.truth_overrides)


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


class _Trajectory(NamedTuple):
    """A state sequence on a uniform grid, as PlanSampler reads a Solution."""

    X: np.ndarray
    U: np.ndarray
    dt: float

    @property
    def K(self):
        return np.zeros((len(self.U), 0, 0))

    @property
    def t(self):
        return self.dt * np.arange(len(self.X))


class Hold(NamedTuple):
    """The reference a robot holds after the plan's end: its last joint positions, zero joint
    velocity, and the torque that holds that posture against gravity."""

    q: np.ndarray  # [nu] q̄_J of the plan's last state
    u: np.ndarray  # [nu] gravity compensation at the plan's last state


def hold_reference(dyn: Dynamics, x_end: np.ndarray, q_indices) -> Hold:
    """The hold reference of ``dyn`` at the plan's last state x_end: [nx]."""
    return Hold(np.asarray(x_end)[q_indices].copy(), dyn.gravity_compensation(x_end))


def _object_speed(x: np.ndarray, obj: ObjectSpec) -> float:
    return float(np.linalg.norm(x[list(obj.velocity)])) if obj.velocity else 0.0


def _hold(truth: Dynamics, x, hold: Hold, qi, vi, limits, obj, st: PlaybackSettings):
    """The robot after the plan: PD+ on the hold reference (paper gains of ``st``, its
    control period; clipped at the effort limits) until the object's speed has stayed below
    rest_speed for rest_time seconds, or rest_max seconds. Returns (states [M, nx] after x,
    inputs [M, nu], saturated commands, control updates, rested)."""
    dt = float(st.truth_time_step)
    need = max(1, int(math.ceil(st.rest_time / dt - 1e-9)))
    steps = int(round(st.rest_max / dt))
    every = max(1, int(round(pd_period(st) / dt)))
    X, U = [], []
    still = 1 if _object_speed(x, obj) < st.rest_speed else 0
    saturated = controls = 0
    u = hold.u
    for k in range(steps):
        if still >= need:
            return (
                np.array(X).reshape(-1, len(x)),
                np.array(U).reshape(-1, len(u)),
                saturated,
                controls,
                True,
            )
        if k % every == 0:
            u = pd_torque(hold.u, x[qi], x[vi], hold.q, 0.0, st.kp, st.kd)
            controls += 1
            if st.clip_torques:
                saturated += int(np.count_nonzero(np.abs(u) > limits))
                u = np.clip(u, -limits, limits)
        try:
            x = truth.step(x, u)
        except SimulationError as e:
            raise SimulationError(f"real system, holding after the plan: {e}") from None
        if truth.layout.quaternions:
            x = truth.layout.normalize(x)
        X.append(x)
        U.append(u)
        still = still + 1 if _object_speed(x, obj) < st.rest_speed else 0
    rested = still >= need
    return (
        np.array(X).reshape(-1, len(x)),
        np.array(U).reshape(-1, len(u)),
        saturated,
        controls,
        rested,
    )


def settle_plan(dyn: Dynamics, x_end: np.ndarray, obj: ObjectSpec, st: PlaybackSettings):
    """The planning model's extension past the plan's end: the robot holds its last planned
    posture exactly (its actuated joints locked there at zero velocity before and after
    every step, gravity-compensating torques; an explicit PD+ hold at the planner's coarse
    step would not be stable), everything else moves on under the planner's own contact
    model and time step, until the object rests (``st``'s rest_speed / rest_time) or
    rest_max seconds. Returns (states [M+1, nx] from x_end, rested)."""
    qi, vi = actuated_indices(dyn.plant)
    x = np.array(x_end, dtype=float)
    q_hold = x[qi].copy()
    x[vi] = 0.0
    u = dyn.gravity_compensation(x)
    dt = dyn.dt
    need = max(1, int(math.ceil(st.rest_time / dt - 1e-9)))
    steps = int(round(st.rest_max / dt))
    X = [np.array(x_end, dtype=float)]
    still = 1 if _object_speed(X[0], obj) < st.rest_speed else 0
    for _ in range(steps):
        if still >= need:
            return np.array(X), True
        try:
            x = dyn.step(x, u)
        except SimulationError as e:
            raise SimulationError(f"planning model, holding after the plan: {e}") from None
        if dyn.layout.quaternions:
            x = dyn.layout.normalize(x)
        x[qi], x[vi] = q_hold, 0.0
        X.append(x.copy())
        still = still + 1 if _object_speed(x, obj) < st.rest_speed else 0
    return np.array(X), still >= need


def _pd_check(truth: Dynamics, x0, joints, v_indices, st: PlaybackSettings) -> dict:
    """Discrete-time stability of the explicit PD+ loop. With control period h and the same
    gains on every actuated joint, one control step scales a velocity error along each mode
    of the actuated joints' inverse inertia (the actuated block of M⁻¹, all joints free) by
    about 1 − (Kd·h + Kp·h²)·λ: a mode with (Kd·h + Kp·h²)·λ ≥ 2 grows each step (chatter,
    torques pinned at the limits). M is the plant's mass matrix, which includes each
    actuator's reflected (rotor) inertia ρ·G² on its joint's diagonal, so a geared joint with
    a light link is not flagged. The warning names the joint that dominates an unstable mode.
    Per joint, ``inertia`` is M_ii, ``reflected_inertia`` its actuator's share and
    ``damping_per_step`` the joint's own ratio (Kd·h + Kp·h²)/M_ii (others held).
    ``joints``, ``v_indices``: the actuated joints and their velocities' indices into x
    (actuated_joints)."""
    plant = truth.plant
    ctx = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(ctx, x0)
    M = plant.CalcMassMatrix(ctx)
    h = pd_period(st)
    c = st.kd * h + st.kp * h * h
    cols = np.asarray(v_indices) - plant.num_positions()
    reflected = {}
    for i in plant.GetJointActuatorIndices():
        a = plant.get_joint_actuator(i)
        reflected[a.joint().name()] = float(a.default_reflected_inertia())
    per = {}
    for name, j in zip(joints, cols):
        m = float(M[j, j])
        per[name] = {
            "inertia": m,
            "reflected_inertia": reflected.get(name, 0.0),
            "damping_per_step": c / m if m > 0 else math.inf,
        }
    warnings = []
    modes: list[float] = []
    try:
        Minv = np.linalg.inv(M)[np.ix_(cols, cols)]
        lam, vec = np.linalg.eigh(0.5 * (Minv + Minv.T))
    except np.linalg.LinAlgError:
        lam, vec = np.array([]), np.zeros((len(cols), 0))
    flagged: dict[str, float] = {}
    for k in range(len(lam)):
        ratio = float(c * lam[k])
        modes.append(ratio)
        if ratio >= 2.0:
            name = joints[int(np.argmax(np.abs(vec[:, k])))]
            flagged[name] = max(ratio, flagged.get(name, 0.0))
    for name, ratio in flagged.items():
        m = per[name]["inertia"]
        warnings.append(
            f"{name}: (Kd·h + Kp·h²)·λ = {ratio:.2f} ≥ 2 at {1.0 / h:g} Hz (joint inertia "
            f"{m:.3g}, of it reflected {per[name]['reflected_inertia']:.3g}): the PD+ loop is "
            "unstable on this joint; lower --kd/--kp or raise --rate (at most "
            "1/--truth-time-step), or give its actuator its rotor inertia (task actuators:)"
        )
    return {
        "pd_loop": per,
        "pd_loop_modes": sorted(modes, reverse=True),
        "pd_loop_rate_hz": 1.0 / h,
        "warnings": warnings,
    }


def pd_period(st: PlaybackSettings) -> float:
    """The PD+ loop's period: 1/rate rounded up to whole truth time steps (the loop acts on
    them; a rate above 1/truth_time_step runs once per step)."""
    dt = st.truth_time_step
    return dt * max(1, math.ceil(1.0 / (st.rate * dt) - 1e-9))


def advisories(plant, settings: PlaybackSettings) -> list[str]:
    """Warnings about a policy that cannot do what the plan needs (known before running)."""
    out = []
    if settings.policy == "pd":
        passive = [j.name() for j in _passive_joints(plant)]
        if passive:
            out.append(
                f"unactuated joints ({', '.join(passive)}): PD+ tracks only the actuated ones "
                "and nothing steers these; an underactuated task needs --policy ilqr"
            )
        if settings.rate * settings.truth_time_step > 1 + 1e-9:
            out.append(
                f"--rate {settings.rate:g} Hz: the PD+ loop runs at most once per truth step, "
                f"so at {1.0 / settings.truth_time_step:g} Hz (a finer --truth-time-step "
                "allows more)"
            )
    elif abs(settings.speed - 1.0) > 1e-12:
        out.append(
            f"--policy ilqr at speed {settings.speed:g}: the plan's controls and gains K hold "
            "only at its own timing (speed 1); at another speed they do not reproduce the "
            "plan (use --policy pd to slow a plan down)"
        )
    return out


def _passive_joints(plant) -> list:
    """The 1-DoF joints without an actuator (e.g. the cart-pole's pole pin), in index order."""
    actuated = {
        plant.get_joint_actuator(i).joint().index() for i in plant.GetJointActuatorIndices()
    }
    joints = (plant.get_joint(JointIndex(i)) for i in range(plant.num_joints()))
    return [j for j in joints if j.num_positions() == 1 and j.index() not in actuated]


def _angle_between(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Rotation angle (rad) between quaternions (wxyz). [..., 4] -> [...]."""
    e = quat_mul(quat_conj(qb), qa)
    return 2.0 * np.arctan2(np.linalg.norm(e[..., 1:], axis=-1), np.abs(e[..., 0]))


def _rest_caveat(task, r: PlaybackResult) -> tuple[str, bool]:
    """Why the resting gap would measure an artefact, and whether to drop it: ('', False)
    when both sides rest in the scene; (why, True) when the planning model's extension or
    the playback carried a floating object out of the scene (a joint object has no scene to
    leave); (why, False) when the extension did not come to rest (the gap is kept as data,
    against where the extension was at --rest-max, but is no headline)."""
    h, ob = r.hold, r.metrics["object"]
    if h is None or ob.get("resting_gap") is None:
        return "", False
    where = ""
    if r.obj.kind == "floating":
        box = scene_box(task, r.X[0])
        for side, key in (("the planning model's extension", "planned_resting"),
                          ("the playback", "actual_resting")):  # fmt: skip
            p = np.asarray(ob[key], float)
            if left_scene(box, p):
                where = f"{side} carried the object out of the scene (to {_xyz(p)} m)"
                break
    if where:
        return f"{where}; the plan's end is the measure (final gap)", True
    if not h.rested_plan:
        return (
            f"the planning model's extension did not come to rest within "
            f"{r.settings.rest_max:g} s (--rest-max), so the resting gap compares with where "
            "it was then; the plan's end is the measure (final gap)",
            False,
        )
    return "", False


def _xyz(p: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.3g}" for v in p) + "]"


def _gap_key(name: str, unit: str) -> str:
    """``resting_gap_m`` for an object measured in metres (``_rad`` in radians)."""
    return f"{name}_{unit}" if unit else name


def _metrics(r: PlaybackResult, qi, vi, limits, vscale, saturated, controls, x_plan_final) -> dict:
    o = r.obj
    c = list(o.coords)
    e = len(r.t) - 1
    actual, planned = r.X[:, c], r.X_plan[:, c]
    err = np.linalg.norm(actual - planned, axis=1)
    kmax = int(np.argmax(err))
    planned_final, actual_final = x_plan_final[c], r.X[e, c]
    planned_disp = planned_final - r.X[0, c]
    actual_disp = actual_final - r.X[0, c]
    pd2 = float(planned_disp @ planned_disp)
    obj = {
        "name": o.name,
        "kind": o.kind,
        "unit": o.unit,
        "initial": r.X[0, c],
        "planned_final": planned_final,
        "actual_final": actual_final,
        "final_error": actual_final - planned_final,
        "final_gap": float(np.linalg.norm(actual_final - planned_final)),
        "max_deviation": float(err[kmax]),
        "max_deviation_time_s": float(r.t[kmax]),
        "planned_displacement": float(np.sqrt(pd2)),
        "actual_displacement": float(np.linalg.norm(actual_disp)),
        # Fraction of the planned displacement achieved along its direction.
        "progress_ratio": float(actual_disp @ planned_disp / pd2) if pd2 > 1e-12 else None,
    }
    h = r.hold
    if h is not None:
        # Where the object came to rest (the robot holding its last reference), against where
        # the planning model, extended the same way, puts it to rest.
        planned_rest = h.X_settle[-1, c]
        actual_rest = h.X[-1, c] if len(h.X) else r.X[-1, c]
        rest_disp = actual_rest - r.X[0, c]
        obj.update(
            {
                "planned_resting": planned_rest,
                "actual_resting": actual_rest,
                "resting_error": actual_rest - planned_rest,
                "resting_gap": float(np.linalg.norm(actual_rest - planned_rest)),
                "planned_rest_drift": float(np.linalg.norm(planned_rest - planned_final)),
                "resting_progress_ratio": (
                    float(rest_disp @ planned_disp / pd2) if pd2 > 1e-12 else None
                ),
                "rest": h.summary(),
            }
        )
    if o.orientation:
        oc = list(o.orientation)
        ang = _angle_between(r.X[:, oc], r.X_plan[:, oc])
        obj["final_orientation_error_deg"] = float(
            np.degrees(_angle_between(r.X[e, oc], x_plan_final[oc]))
        )
        obj["max_orientation_deviation_deg"] = float(np.degrees(ang.max()))
    q_err = r.X[: e + 1, qi] - r.X_plan[: e + 1, qi]  # tracking: while the plan runs
    v_err = r.X[: e + 1, vi] - vscale * r.X_plan[: e + 1, vi]
    joints = {
        name: {
            "unit": unit,
            "rms_error": float(np.sqrt(np.mean(q_err[:, i] ** 2))),
            "max_abs_error": float(np.max(np.abs(q_err[:, i]))),
            "rms_velocity_error": float(np.sqrt(np.mean(v_err[:, i] ** 2))),
            "final_error": float(q_err[-1, i]),
        }
        for i, (name, unit) in enumerate(zip(r.joints, r.joint_units))
    }
    torques = {
        name: {
            "max_abs": float(np.max(np.abs(r.U[:, i]))) if len(r.U) else 0.0,
            "effort_limit": float(limits[i]) if np.isfinite(limits[i]) else None,
        }
        for i, name in enumerate(r.actuators)
    }
    st = r.settings
    return {
        "policy": st.policy,
        "settings": asdict(st),
        "truth": {
            "time_step": st.truth_time_step,
            "contact_approximation": r.truth_contact,
            "damping": damping_law(r.truth_contact),
            "overrides": list(st.truth_overrides),
        },
        "planner": {
            "time_step": r.planner_time_step,
            "contact_approximation": r.planner_contact,
            "damping": damping_law(r.planner_contact),
        },
        "plan_duration_s": float(r.t[e] * st.speed),
        "playback_duration_s": float(r.t[e]),
        "hold_duration_s": h.seconds if h is not None else 0.0,
        "truth_steps": int(len(r.U)),
        "hold_truth_steps": int(len(h.U)) if h is not None else 0,
        # the headline: where the object rests against where the plan puts it to rest (None
        # without a resting measurement, rest_max 0); final_gap: at the plan's last instant
        _gap_key("resting_gap", o.unit): obj.get("resting_gap"),
        _gap_key("final_gap", o.unit): obj["final_gap"],
        "control_updates": int(controls),
        "reference_updates": int(len(r.reference.t)),
        "object": obj,
        "joint_tracking": joints,
        "joint_rms_error_max": max((j["rms_error"] for j in joints.values()), default=0.0),
        "torques": torques,
        "saturated_fraction": float(saturated / max(1, controls * max(1, len(r.actuators)))),
    }


def executed(task, sol, r: PlaybackResult):
    """The executed motion as a plan-shaped trajectory, for the task's metrics and goal: the
    actual state at each plan time (playback time (t_k - t_0) / speed), except that the last
    state is where the robot left things at rest (the end of the hold, when there is one).
    t: [N+1], X: [N+1, nx], U: [N, nu] (the plan's inputs)."""

    tau = (np.asarray(sol.t, float) - float(sol.t[0])) / r.settings.speed
    idx = np.clip(np.searchsorted(r.t, tau - 1e-9), 0, len(r.t) - 1)
    X = np.array(r.X[idx], float)
    if r.hold is not None and len(r.hold.X):
        X[-1] = r.hold.X[-1]
    return SimpleNamespace(t=np.asarray(sol.t, float), X=X, U=np.asarray(sol.U, float))


def executed_goal(task, sol, r: PlaybackResult) -> dict:
    """The task's metrics on the executed motion (``executed``) and its goal judged on them:
    {"metrics": ..., "goal": {met, checks, judged}} (``judged`` false for a smoke-sized plan,
    as its solve recorded); a metric the truth state cannot give is an error entry (and fails
    the checks that need it)."""

    try:
        m = metrics.compute(task, executed(task, sol, r))
    except (RuntimeError, SimulationError, ValueError) as e:
        m = {"error": str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__}
    return {"metrics": m, "goal": judge(task.config, m)}
