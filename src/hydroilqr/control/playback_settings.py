"""Playback's settings and result types, and loading the solved run it executes
(``control/playback.py`` runs it; re-exported there)."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

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
