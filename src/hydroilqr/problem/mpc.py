"""The ``mpc:`` section: the settings of closed-loop MPC (``hydroilqr mpc``, docs/mpc.md)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from hydroilqr.problem.checks import MAX_STEPS, unknown_key
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.goal import GoalCheck, validate_goal
from hydroilqr.problem.receding import WARM_START_TAILS
from hydroilqr.problem.search import MAX_SEARCH_SAMPLES
from hydroilqr.problem.solver import DERIVATIVES

# mpc.candidates
MPC_CANDIDATES = ("first_plan", "first_plan_controls", "first_plan_policy", "guess")


@dataclass
class PlannerSettings:
    """The planner's settings (``control.mpc.Controller``): how each update plans (horizon,
    iterations, partials, line search, warm starts and restarts, its deadline) and how its
    plan is applied (feedback, delay compensation); the controller's own task overrides."""

    horizon: float = 0.3  # s
    iterations_per_update: int = 1
    # Per-update batches are small: one thread avoids waking a second one every update.
    threads: int = 1
    derivatives: str = ""  # empty: the task's solver.derivatives
    derivative_interval: int = 0  # 0: the task's solver.derivative_interval
    # true: the horizon ends at the task's own end time (shrinks as time passes; a
    # point-to-point task such as a push); false: a fixed-length horizon that recedes.
    shrinking_horizon: bool = False
    # Controls for the steps a shifted warm start lacks: "last" repeats the last control,
    # "guess" takes them from the task's initial guess (e.g. standing torques).
    warm_start_tail: str = "last"
    # When the measured state is not the predicted one, start each update from the previous
    # plan's feedback policy u = ū − K(x − x̄) rolled out from the measured state (true), or
    # from its shifted controls open loop (false).
    warm_start_feedback: bool = True
    # Restarts: besides its warm start, each update rolls out these candidates from the
    # measured state and starts from the cheapest: "first_plan_controls" (the first plan's
    # controls open loop, from their first step: the motion that made contact from a
    # standstill, tried again), "first_plan_policy" (the same with the first plan's feedback,
    # steering back towards its motion), "first_plan" (both), "guess" (the task's initial
    # guess for the horizon). Empty: the warm start only.
    candidates: list[str] = field(default_factory=list)
    # The candidates are tried at every this-many-th update (1: every update): each try costs
    # a rollout per candidate, which in a fast loop can leave no time for the line search.
    candidate_period: int = 1
    # A solved run (its directory or solution.npz): its controls, by time step, seed the first
    # plan and the steps each shifted plan appends (past its end, warm_start_tail applies).
    warm_start_plan: str = ""
    # Partials kept across updates (the plan only shifts): a step's partials are recomputed
    # when its (x, u) moved more than this (see solver.derivative_reuse_tolerance); 0 =
    # recompute every step every iteration.
    derivative_reuse_tolerance: float = 0.0
    # At most this many steps differentiated per iteration (those that moved most); 0 = no cap.
    derivative_steps_per_update: int = 0
    # Line search per update: step sizes tried (1, 1/2, ...) and retries with a larger μ. A
    # failed search keeps the previous plan (shifted); it is not an error.
    line_search_steps: int = 3
    line_search_retries: int = 0
    # > 0 and --realtime: an update starts no line-search trial after this fraction of the
    # control period (it keeps the warm start, with fresh gains): late updates return in time.
    # 0 = off; lock-step runs ignore it.
    deadline: float = 0.0
    # With realtime: each update plans from the state the plan in force is predicted to reach
    # one control period later (the controller's model under that plan's policy), and the new
    # plan takes over at that time, so its first control is the one applied. An update longer
    # than the period applies the new plan late, past its first steps. Off: the plan starts
    # from the state measured when the update began, and the time the update took is already
    # past when it is applied. The period must be whole plan steps.
    delay_compensation: bool = False
    # Scales K in u = ū − K(x − x̄); 0 = feedforward only.
    feedback_scale: float = 1.0
    # key=value overrides of the controller's task only (its cost, model and solver), e.g.
    # [cost.terms.approach.weight=1e5]: an approach term the task as written switches off
    # kept on in the loop, so that the plans keep looking for contact. The time grid, the
    # state and the inputs stay the task's; the simulated robot and the goal are the task's.
    plan_overrides: list[str] = field(default_factory=list)
    # The planner: ilqr; sampling (the task's search: settings over the horizon, warm-started
    # by the previous best spline shifted); hybrid (the sampler's best, then at most
    # iterations_per_update iLQR iterations on it, cut by deadline with --realtime)
    planner: str = "ilqr"
    samples: int = 0  # sampling / hybrid: rollouts per sampling iteration (0: search.samples)
    sampling_iterations: int = 1  # per update (the first plan: search.iterations)
    knots: int = 0  # spline knots over the horizon (0: search.knots)
    sampling_workers: int = 0  # processes that roll samples out, this one included (0: cores)

    @classmethod
    def of(cls, settings):
        """Its part of ``settings`` (an MPCConfig), as a PlannerSettings of its own."""
        return cls(**{f.name: getattr(settings, f.name) for f in dataclasses.fields(cls)})


@dataclass
class LoopSettings:
    """The closed loop's settings (``control.mpc.ClosedLoop``): its rate and duration, real
    time or lock-step, and the simulated robot (its time step, model mismatch, pushes)."""

    rate: float = 50.0  # Hz, control updates
    duration: float = 2.0  # s
    # The simulation keeps running while the controller computes (its latency is felt).
    realtime: bool = False
    # The simulated robot's own time step (s): a divisor of the plan's plant.time_step; between
    # plan steps it holds the step's feed-forward and feeds back against the plan's state
    # interpolated in time. 0: the plan's step (the simulation steps as the controller plans).
    plant_time_step: float = 0.0
    # Lock-step only: each update is taken to last this many seconds of simulated time, as
    # --realtime feels the controller's wall time: the plan in force keeps running for them
    # (whole steps of the simulated robot, rounded up; with delay_compensation, at least one
    # period) before the new plan takes over. A real-time run whose updates all take as many
    # steps runs the same. 0: none (the new plan applies at once).
    lockstep_latency: float = 0.0
    # key=value overrides for the simulated plant only (model mismatch), e.g. ball.friction=0.3
    truth_overrides: list[str] = field(default_factory=list)
    # External pushes (control.mpc.Push: time, body, force, duration); Python / --push only.
    pushes: list[Any] = field(default_factory=list, metadata={"task_file": False})

    @classmethod
    def of(cls, settings):
        """Its part of ``settings`` (an MPCConfig), as a LoopSettings of its own."""
        return cls(**{f.name: getattr(settings, f.name) for f in dataclasses.fields(cls)})


@dataclass
class MPCConfig(PlannerSettings, LoopSettings):
    """The settings of closed-loop MPC (``hydroilqr mpc``, ``control.mpc.run_mpc``), a task
    file's ``mpc:`` section (flat: each key overridable on the command line as ``mpc.KEY``):
    the planner's settings (``PlannerSettings``), the loop's (``LoopSettings``) and the closed
    loop's goal. Also built in Python (``control.mpc.mpc_config(task, **overrides)`` starts
    from a task's section). ``pushes`` is not a task-file key (Push objects, from ``--push``)."""

    # What the closed loop must achieve, judged on its simulated motion (the same metrics as
    # ``goal``, e.g. a tracking error over the run); empty: the task's ``goal`` judges it.
    goal: dict[str, GoalCheck] = field(default_factory=dict)


def validate_mpc(m: MPCConfig) -> None:
    """Checks the ``mpc:`` settings that need no plant (an MPCConfig): the planner's and the
    closed loop's goal (the loop's need the task: ``control.mpc.check_settings``);
    ConfigError naming the key."""
    validate_goal(m.goal, "mpc.goal")
    validate_planner(m)


MPC_PLANNERS = ("ilqr", "sampling", "hybrid")  # mpc.planner


def validate_planner(m: PlannerSettings) -> None:
    """The planner's settings that need no plant."""
    _validate_sampler(m)
    if not 0 <= m.deadline <= 1:
        raise ConfigError(
            f"mpc.deadline: a fraction of the control period in [0, 1], got {m.deadline}"
        )
    if m.warm_start_tail not in WARM_START_TAILS:
        raise ConfigError("mpc.warm_start_tail: expected last or guess")
    cp = m.candidate_period
    if isinstance(cp, bool) or not isinstance(cp, int) or cp < 1:
        raise ConfigError(f"mpc.candidate_period: a whole number of updates >= 1, got {cp!r}")
    for c in m.candidates:
        if c not in MPC_CANDIDATES:
            raise ConfigError(
                f"mpc.candidates: {c!r}: {unknown_key(str(c), list(MPC_CANDIDATES), 'candidate')}"
            )
    tried = [
        r
        for c in m.candidates
        for r in ({"first_plan_controls", "first_plan_policy"} if c == "first_plan" else {c})
    ]
    if len(tried) != len(set(tried)):
        raise ConfigError(
            f"mpc.candidates: {list(m.candidates)} names a candidate twice (first_plan is "
            "first_plan_controls and first_plan_policy)"
        )
    if m.derivatives and m.derivatives not in DERIVATIVES:
        raise ConfigError(
            f"mpc.derivatives: expected one of {', '.join(DERIVATIVES)} (or empty: the "
            f"task's solver.derivatives), got {m.derivatives!r}"
        )
    if m.derivative_interval < 0:
        raise ConfigError(
            "mpc.derivative_interval: must be >= 1 (or 0: the task's solver.derivative_interval)"
            f", got {m.derivative_interval}"
        )
    if not m.derivative_reuse_tolerance >= 0 or m.derivative_steps_per_update < 0:
        raise ConfigError(
            "mpc.derivative_reuse_tolerance / derivative_steps_per_update: must be >= 0"
        )


def _validate_sampler(m: PlannerSettings) -> None:
    """mpc.planner and the sampling planners' keys."""
    if m.planner not in MPC_PLANNERS:
        raise ConfigError(
            f"mpc.planner: expected one of {', '.join(MPC_PLANNERS)}, got {m.planner!r}"
        )
    for name, ok, rule in (
        ("samples", m.samples == 0 or 2 <= m.samples <= MAX_SEARCH_SAMPLES,
         f"0 (search.samples) or from 2 to {MAX_SEARCH_SAMPLES}"),
        ("sampling_iterations", 1 <= m.sampling_iterations <= 1000, "from 1 to 1000"),
        ("knots", 0 <= m.knots <= MAX_STEPS, "0 (search.knots) or more"),
        ("sampling_workers", 0 <= m.sampling_workers <= 1024, "from 0 (one per core) to 1024"),
    ):  # fmt: skip
        if not ok:
            raise ConfigError(f"mpc.{name}: must be {rule}, got {getattr(m, name)!r}")
