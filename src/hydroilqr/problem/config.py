"""Task configuration: typed dataclasses loaded from YAML, with dotted command-line overrides.

A task file is the one way to define a problem; every built-in task (``hydroilqr tasks``) is
such a file in ``hydroilqr/tasks``. Layout of a task file (all keys optional unless noted)::

    name: my-task
    description: one line
    models:                       # required: one or more SDFormat/URDF files
      - file: robot.sdf           # relative to the YAML file; package:// allowed
        weld: {parent: world, child: base_link, xyz: [0, 0, 0.1], rpy: [0, 0, 0]}
        # welds: [{child: finger1_base, ...}, ...]   # several welds of one model
    package_map: {my_pkg: ./my_pkg}
    scene:                        # static geometry welded to the world
      - {name: ground, shape: box, size: [25, 25, 1], xyz: [0, 0, -0.5],
         compliance: compliant, hydroelastic_modulus: 5e6, dissipation: 0, friction: 0.5}
        # (halfspace: slab_thickness; no_contact_with: [names] keeps it from touching those)
    geometry:                     # overrides of the model's collision properties
      tip: {hydroelastic_modulus: 2e6}      # by body name, collision name (every geometry
                                            # of that name) or BODY/COLLISION_NAME
    plant: {time_step: 0.01, contact_approximation: sap}   # also contact_model, gravity
    actuators:                    # per actuator (names as in `hydroilqr check`); each key optional
      joint_7: {effort_limit: 9, rotor_inertia: 4.0e-6, gear_ratio: 100}
                                  # N·m or N (replaces the model's), kg·m², output/motor speed;
                                  # the reflected inertia rotor_inertia·gear_ratio² is added to
                                  # the joint's mass-matrix diagonal (Drake JointActuator)
    horizon: 1.0                  # seconds (or num_steps: N)
    blocks: {pole_angle: [PolePin]}   # named groups of state coordinates (see state.py)
    initial_state: {pole_angle: 3.64}
    initial_guess: zeros          # zeros | gravity_compensation | hold | U.npz | U.csv
                                  # (a file: >= N rows, or 1 row = a constant control), or
                                  # positions tracked by a rollout (PositionGuess):
                                  # {waypoints: [{t: 0.3, knee: -1.6}, ...], period: 0.5}
    cost:
      Q: {pole_angle: 1.0}
      R: 0.001                    # scalar, list per actuator, or {actuator_name: w}
      Qf: {pole_angle: 200}
      nominal: {pole_angle: 3.14159}
      nominal_rate: {}            # x_nom(t) = nominal + rate * t (per block)
      nominal_rate_until: null    # s: the rate stops here (the nominal then holds)
      nominal_relative_to_start: []   # blocks whose nominal is an offset from the initial state
      nominal_time: step          # step: x̃_k = x_k ⊖ x_nom(t_k); horizon_end: every step of a
                                  # solve aims at x_nom(t_N), the nominal at its horizon's end
      running_cost_dt: false      # true: running Q, R multiplied by dt (paper's code)
      reference: ''               # a solved run to track (its states are the nominal)
      reference_blocks: []        # blocks taken from the reference (empty: all)
      terms: []                   # task-space terms (TermConfig, model/terms.py), e.g.
                                  # [{name: hand, type: position, body: gripper,
                                  #   target: [0.4, 0.3, 0.5], weight: 1000, terminal: true}]
    solver: {max_iterations: 100, derivatives: central}
    receding_horizon: null        # {window_steps: W, shift_steps: S, resolves: R, max_iterations}:
                                  # R windows of W steps, each keeps its first S steps, so the
                                  # trajectory has R*S steps (horizon / num_steps are not used);
                                  # max_iterations: per window after the first one;
                                  # warm_start_tail: last (hold the last control) or guess
    continuation: []              # single solves: stages of dotted overrides solved first,
                                  # each warm-starting the next, e.g.
                                  # [{ball_collision.hydroelastic_modulus: 5.0e+5}]
    ensemble: []                  # single solves: perturbed copies (dotted overrides, e.g.
                                  # [{ball.friction: 0.14}, {ball.friction: 0.26}]) that one
                                  # control sequence is optimized against with the task itself
    ensemble_weight: 1.0          # cost weight of each perturbed member (the task's: 1)
    ensemble_warm_start: true     # solve the task alone first and start the ensemble from it
    mismatch: {}                  # named model errors a plan is played back against
                                  # (`playback --mismatch NAME`, results page), e.g.
                                  # {friction-30: {ball.friction: 0.14}}
    mpc:                          # defaults for `hydroilqr mpc` (see MPCConfig, docs/mpc.md)
      {rate: 50, horizon: 0.3, iterations_per_update: 1, duration: 2.0,
       shrinking_horizon: false, derivative_reuse_tolerance: 0, derivative_steps_per_update: 0}
    metrics: [default]
    metric_params: {}             # names the metric sets need (e.g. ball: ball), and
                                  # camera: {position: [...], target: [...]} for the replays

Overrides use dotted keys (``--set solver.max_iterations=5``). A key whose first part names a
``geometry`` entry or a ``scene`` object may omit the section: ``tip.hydroelastic_modulus`` is
``geometry.tip.hydroelastic_modulus``.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import enum
import json
import math
import re
import types
import typing
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hydroilqr.problem.capabilities import drake_has_tamsi, no_tamsi_message
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import MAX_MODEL_BYTES, check_file, read_text_bounded

TASKS_DIR = Path(__file__).parent.parent / "tasks"


SHAPES = ("box", "sphere", "cylinder", "halfspace")


# --------------------------------------------------------------------------------------------
# Dataclasses
# --------------------------------------------------------------------------------------------


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


NOMINAL_TIMES = ("step", "horizon_end")

# The axis names of a 3-vector term's residual (the term types: TERM_TYPES, below).
AXES = ("x", "y", "z")


@dataclass
class PositionGuess:
    """``initial_guess`` as a path of configurations (model/guess.py): the controls come from a
    tracking rollout on the task's own plant that follows it. Either ``waypoints`` (each
    ``{t: SECONDS, BLOCK: value, ...}``, in increasing time; a waypoint that does not name a
    block keeps the previous one's value) or ``target`` (one configuration, reached at the
    task's end). The path starts from the initial state at t = 0 and holds after its last
    point; with ``period`` > 0 (s, after the last waypoint) it returns to the initial state's
    values at t = period and repeats."""

    waypoints: list[dict[str, Any]] = field(default_factory=list)
    target: dict[str, Any] = field(default_factory=dict)
    period: float = 0.0


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


@dataclass
class CostConfig:
    Q: dict[str, Any] = field(default_factory=dict)
    R: Any = 0.0
    Qf: dict[str, Any] = field(default_factory=dict)
    nominal: dict[str, Any] = field(default_factory=dict)
    nominal_rate: dict[str, Any] = field(default_factory=dict)
    # The time (s) the rate stops: x_nom(t) = nominal + rate * min(t, nominal_rate_until)
    # (None: never).
    nominal_rate_until: float | None = None
    # Blocks (or components) whose ``nominal`` is an offset from their value in the task's
    # initial state (unnamed in ``nominal``: an offset of 0, i.e. stay where they start).
    nominal_relative_to_start: list[str] = field(default_factory=list)
    # When the nominal is taken: "step" (each step's own time, x_nom(t_k)) or "horizon_end"
    # (every step of a solve against x_nom(t_N), the nominal at the end of its horizon: a goal
    # ahead that moves with each receding-horizon window, as in the paper's cheetah code).
    nominal_time: str = "step"
    # Multiply the running weights Q and R by the time step (as the paper's public code does:
    # running cost dt·(x̃ᵀQx̃ + uᵀRu), terminal cost x̃ᵀQ_f x̃ unscaled).
    running_cost_dt: bool = False
    # A solved run (its directory or solution.npz) to track: its states, interpolated in time,
    # are the nominal of the blocks in reference_blocks (empty: every block); after its end
    # the last state is held. Other blocks keep nominal / nominal_rate.
    reference: str = ""
    reference_blocks: list[str] = field(default_factory=list)
    # Task-space terms (TermConfig): named residuals of points, velocities, heights and
    # distances, beside the quadratic terms above.
    terms: list[TermConfig] = field(default_factory=list)


class DerivativeMethod(enum.Enum):
    """How the partials f_x, f_u are taken (``solver.derivatives``; see derivatives.py).

    AUTODIFF: Drake AutoDiffXd through the discrete update (the paper's method); FORWARD and
    CENTRAL: one-sided and central finite differences. Defined here (derivatives.py
    re-exports it) so that validating ``solver.derivatives`` needs nothing from the layers
    that use it."""

    AUTODIFF = "autodiff"
    FORWARD = "forward"
    CENTRAL = "central"


@dataclass
class SolverConfig:
    max_iterations: int = 100
    derivatives: str = "central"  # a DerivativeMethod value: autodiff | forward | central
    fd_epsilon: float = 1e-6
    # Finite differences over applied generalized forces where the model allows (SAP, or TAMSI
    # without joint damping; no PD actuators: Dynamics.force_path): nq + nv perturbed steps per
    # time step instead of nx + nu, f_v and f_u then follow from f_τ
    # (derivatives._force_differences). Same partials up to rounding; pays with many actuators
    # (Mini Cheetah and planar gripper partials 1.25-1.3x faster), not with one (cart-pole: no
    # faster). Off: perturb (x, u) one coordinate at a time.
    fd_forces: bool = False
    threads: int = 0  # 0 = all cores
    relative_cost_tolerance: float = 1e-4
    expected_decrease_tolerance: float = 1e-7
    line_search_factor: float = 0.5
    line_search_max_steps: int = 12
    # Start each line search one factor above the step the previous iteration accepted
    # (ε = min(1, ε_prev / line_search_factor), then ε·f, ...) instead of at ε = 1; after an
    # iteration without an accepted step, and in the first one, at 1. Saves the rejected
    # long trials of a solve whose accepted steps stay short; the start grows back by one
    # factor per iteration while the first trial is accepted. Off by default: it moves every
    # contact-rich solve into other basins.
    line_search_warm_start: bool = False
    # After a failed line search μ grows and the backward pass + line search run again, at
    # most this many times (and while μ <= regularization_max).
    line_search_retries: int = 20
    armijo: float = 1e-4
    regularization_init: float = 1e-6
    regularization_min: float = 1e-9
    regularization_max: float = 1e10
    regularization_factor: float = 10.0
    # After an accepted step shorter than this (line-search ε < short_step) for which longer
    # steps were rejected, μ grows by regularization_factor instead of shrinking (a trust
    # region that shrinks while the quadratic model only holds for short steps); after one
    # accepted as the first trial (line_search_warm_start) μ stays; 0 = always shrink after a
    # success.
    short_step: float = 0.1
    derivative_interval: int = 1  # >1: exact derivatives every k steps, interpolated between
    # With derivative_interval > 1: also exact at both sides of every change of the set of
    # touching geometry pairs (contact made or broken), interpolated only within a contact mode.
    derivative_adaptive: bool = False
    # AutoDiff in this many processes (the time steps split between them; each worker process
    # holds its own plant). 1 = serial in this process, as in the paper; 0 = one per core.
    autodiff_workers: int = 1
    # Line-search trials in this many processes: each round evaluates ε, ε·factor, ... side by
    # side and takes the first acceptable one in that order (the iterates of the serial search).
    # 1 = one trial after another; 0 = one per core. Shares the worker pool with autodiff.
    line_search_workers: int = 1
    # > 0: reuse a step's partials while its (x, u) has moved less than this (scaled max norm,
    # |Δz_i| / max(1, |z_i|)) since they were taken; 0 = recompute every iteration.
    derivative_reuse_tolerance: float = 0.0
    # > 0: after an iteration with exact partials, this many iterations update each step's
    # partials with a secant (Broyden rank-one) correction from the step's own change of
    # (x, u) and of its next state, both known from the rollouts, instead of differentiating;
    # then exact partials again. 0 = exact partials every iteration.
    derivative_secant_updates: int = 0


@dataclass
class RecedingHorizonConfig:
    window_steps: int = 40
    shift_steps: int = 4
    resolves: int = 100
    max_iterations: int = 10  # per resolve (the first window uses solver.max_iterations)
    # The controls a shifted window lacks at its end: "last" holds the previous window's last
    # control (the paper's code), "guess" takes the task's initial guess for those steps.
    warm_start_tail: str = "last"
    # > 0: a window whose cost after max_iterations is above rescue_factor times the median of
    # the previous (up to 5) windows' costs gets up to rescue_iterations more iterations from
    # where it stopped (the better of the two is kept): a window where the motion starts to go
    # wrong gets the effort to turn it around. 0 = off (every window max_iterations).
    rescue_factor: float = 0.0
    rescue_iterations: int = 10


@dataclass
class MPCConfig:
    """The settings of closed-loop MPC (``hydroilqr mpc``, ``control.mpc.run_mpc``): a task
    file's ``mpc:`` section, each key overridable on the command line; also built in Python
    (``control.mpc.mpc_config(task, **overrides)`` starts from a task's section). ``pushes`` is
    not a task-file key (Push objects, from ``--push``)."""

    rate: float = 50.0  # Hz, control updates
    horizon: float = 0.3  # s
    iterations_per_update: int = 1
    duration: float = 2.0  # s
    # Per-update batches are small: one thread avoids waking a second one every update
    # (measured: 13 ms of wake-up per batched call on a busy 2-core machine).
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
    # The simulation keeps running while the controller computes (its latency is felt).
    realtime: bool = False
    # With realtime: each update plans from the state the plan in force is predicted to reach
    # one control period later (the controller's model under that plan's policy), and the new
    # plan takes over at that time, so its first control is the one applied. An update longer
    # than the period applies the new plan late, past its first steps. Off: the plan starts
    # from the state measured when the update began, and the time the update took is already
    # past when it is applied. The period must be whole plan steps.
    delay_compensation: bool = False
    # Scales K in u = ū − K(x − x̄); 0 = feedforward only.
    feedback_scale: float = 1.0
    # key=value overrides for the simulated plant only (model mismatch), e.g. ball.friction=0.3
    truth_overrides: list[str] = field(default_factory=list)
    # key=value overrides of the controller's task only (its cost, model and solver), e.g.
    # [cost.terms.approach.weight=1e5]: an approach term the task as written switches off
    # kept on in the loop, so that the plans keep looking for contact. The time grid, the
    # state and the inputs stay the task's; the simulated robot and the goal are the task's.
    plan_overrides: list[str] = field(default_factory=list)
    # The simulated robot's own time step (s): a divisor of the plan's plant.time_step; between
    # plan steps it holds the step's feed-forward and feeds back against the plan's state
    # interpolated in time. 0: the plan's step (the simulation steps as the controller plans).
    plant_time_step: float = 0.0
    # External pushes (control.mpc.Push: time, body, force, duration); Python / --push only.
    pushes: list[Any] = field(default_factory=list, metadata={"task_file": False})
    # What the closed loop must achieve, judged on its simulated motion (the same metrics as
    # ``goal``, e.g. a tracking error over the run); empty: the task's ``goal`` judges it.
    goal: dict[str, GoalCheck] = field(default_factory=dict)


SEARCH_METHODS = ("predictive", "cem", "mppi")  # search.method
SEARCH_SPACES = ("torque", "position")  # search.space
SEARCH_ORDERS = (0, 1, 3)  # search.order: zero-order hold, linear, cubic
SEARCH_SELECTS = ("goal", "cost", "transfer", "robust")  # search.select
MAX_SEARCH_SAMPLES = 100_000  # samples of one search iteration


@dataclass
class SearchConfig:
    """A sampling search over spline knots before iLQR (``hydroilqr search``, and ``solve``
    on a task with a ``search:`` section; ``solver/sampling.py``, ``solver/search.py``)."""

    method: str = "cem"  # predictive | cem (with iCEM's colored noise and elites kept) | mppi
    samples: int = 64  # rollouts per iteration (the current mean among them)
    iterations: int = 20
    knots: int = 8  # spline knots per actuator over the horizon (1 to the task's steps)
    order: int = 1  # spline order: 0 (zero-order hold), 1 (linear), 3 (cubic)
    # torque: knots are the actuators' commands; position: joint position targets on the
    # actuated joints, tracked by the PD+ law of playback (gains kp, kd) with gravity
    # compensation as feed-forward
    space: str = "torque"
    # sampling standard deviation: in torque space a fraction of each actuator's effort limit
    # (1 N·m or N without one); in position space in the joint's units (rad or m)
    noise: float = 0.3
    elites: int = 8  # cem: samples the mean and spread are refit to
    elite_memory: float = 0.3  # cem: fraction of the elites kept into the next iteration
    colored_noise: float = 2.0  # noise exponent β of a 1/f^β spectrum over the knots (0: white)
    smoothing: float = 0.1  # cem: weight of the previous mean and spread in each refit
    temperature: float = 0.1  # mppi: λ as a fraction of the iteration's cost spread
    kp: float = 100.0  # position space: PD+ stiffness (N·m/rad or N/m)
    kd: float = 10.0  # position space: PD+ damping (N·m·s/rad or N·s/m)
    seed: int = 0
    polish: int = 1  # solve: iLQR from the best this-many distinct samples (0: search only)
    # goal: the first polished plan meeting the goal, else the lowest cost; cost: the lowest
    # cost; transfer: the first whose PD+ playback (half speed, finer simulation) meets it;
    # robust: the one whose perturbed re-solves (robust_runs, robust_noise) meet it most often
    select: str = "goal"
    robust_runs: int = 3  # select robust: re-solves per polished candidate
    # select robust: each re-solve's relative perturbation of the candidate's torques (as
    # ``hydroilqr robustness --noise``)
    robust_noise: float = 1e-9
    batches: int = 0  # evaluation batches per iteration (0: one per worker)


BOUNDS = ("min", "max", "above", "below")  # the bounds of a goal check


@dataclass
class GoalCheck:
    """Bounds on one metric (all given bounds must hold)."""

    min: float | None = None
    max: float | None = None
    above: str | None = None  # the name of another metric that this one must exceed
    below: str | None = None  # the name of another metric that this one must stay under
    # by how much (above: value > other + margin; below: value < other - margin)
    margin: float = 0.0

    def describe(self) -> str:
        parts = []
        if self.min is not None:
            parts.append(f">= {self.min:g}")
        if self.max is not None:
            parts.append(f"<= {self.max:g}")
        extra = f" + {self.margin:g}" if self.margin else ""
        if self.above is not None:
            parts.append(f"> {self.above}{extra}")
        if self.below is not None:
            parts.append(f"< {self.below}{extra.replace('+', '-')}")
        return " and ".join(parts)


def validate_goal(goal: dict[str, GoalCheck], where: str = "goal") -> None:
    """Raises ConfigError for a check with no bound or with inverted bounds."""
    for name, check in goal.items():
        key = f"{where}.{name}"
        if not name:
            raise ConfigError(f"{where}: a check needs a metric name")
        if all(getattr(check, b) is None for b in BOUNDS):
            raise ConfigError(f"{key}: give at least one of {', '.join(BOUNDS)}")
        if check.min is not None and check.max is not None and check.min > check.max:
            raise ConfigError(f"{key}: min {check.min:g} is above max {check.max:g}")
        if check.margin:
            if check.above is None and check.below is None:
                raise ConfigError(f"{key}.margin: a margin needs above or below")
            if not math.isfinite(check.margin) or check.margin < 0:
                raise ConfigError(f"{key}.margin: expected a number >= 0, got {check.margin:g}")


@dataclass
class TaskConfig:
    name: str = ""
    description: str = ""
    models: list[ModelConfig] = field(default_factory=list)
    package_map: dict[str, str] = field(default_factory=dict)
    scene: list[SceneObject] = field(default_factory=list)
    geometry: dict[str, ContactProperties] = field(default_factory=dict)
    plant: PlantConfig = field(default_factory=PlantConfig)
    actuators: dict[str, ActuatorConfig] = field(default_factory=dict)
    horizon: float = 1.0
    num_steps: int = 0  # if > 0, overrides horizon
    blocks: dict[str, list[str]] = field(default_factory=dict)
    initial_state: dict[str, Any] = field(default_factory=dict)
    # zeros | gravity_compensation | hold | a file, or a path of configurations (PositionGuess)
    initial_guess: str | PositionGuess = "zeros"
    cost: CostConfig = field(default_factory=CostConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    receding_horizon: RecedingHorizonConfig | None = None
    mpc: MPCConfig = field(default_factory=MPCConfig)
    metrics: list[str] = field(default_factory=lambda: ["default"])
    metric_params: dict[str, Any] = field(default_factory=dict)
    # What success means in the physical world: bounds on the run's metrics (see
    # hydroilqr.metrics.goals), e.g. {target_error_m: {max: 0.03}}.
    goal: dict[str, GoalCheck] = field(default_factory=dict)
    # Continuation (homotopy) for single solves: first solve the task with each stage's dotted
    # overrides (e.g. a softer contact), each stage warm-starting the next with its controls,
    # then the task as written. Softer contact has smoother gradients (paper §IV-C).
    continuation: list[dict[str, Any]] = field(default_factory=list)
    # Robust (ensemble) iLQR for single solves: perturbed copies of the task, each a mapping of
    # dotted overrides (e.g. {ball.friction: 0.14}); one control sequence is optimized against
    # the task itself (the nominal) and every member at once (model/ensemble.py). Empty: off.
    ensemble: list[dict[str, Any]] = field(default_factory=list)
    # The cost weight of each perturbed member relative to the nominal's 1 (>= 0).
    ensemble_weight: float = 1.0
    # Solve the task alone first (from its initial guess) and start the ensemble solve from
    # that plan; false: the ensemble solve starts from the initial guess itself.
    ensemble_warm_start: bool = True
    # Named model errors to check a plan against: each a mapping of dotted overrides of the
    # "real" system in playback (the keys --truth-set takes), e.g. {friction-30: {ball.friction:
    # 0.14}}; `playback --mismatch NAME` applies one, the results page plays back every one.
    mismatch: dict[str, dict[str, Any]] = field(default_factory=dict)
    # A sampling search before iLQR (SearchConfig); none: iLQR from the initial guess alone.
    search: SearchConfig | None = None
    # Dotted overrides applied by --smoke (a tiny version of the task for tests and quick tries).
    smoke: dict[str, Any] = field(default_factory=dict)
    # Set by the loader: directory that relative paths are resolved against.
    base_dir: str = ""
    # Set by the loader: the task was shrunk by --smoke (its goal is the full task's).
    smoke_run: bool = False

    @property
    def steps(self) -> int:
        if self.num_steps > 0:
            return int(self.num_steps)
        return max(1, int(round(self.horizon / self.plant.time_step)))

    def resolve_path(self, path: str) -> Path:
        p = Path(path).expanduser()
        if not p.is_absolute():
            p = Path(self.base_dir or ".") / p
        return p

    def to_dict(self) -> dict[str, Any]:
        """The resolved task as plain data (a task file with the same content solves it: the
        trajectory length is given once, as num_steps when set, else as horizon)."""
        d = dataclasses.asdict(self)
        d.pop("base_dir", None)
        d.pop("smoke_run", None)
        d["mpc"].pop("pushes", None)  # not a task-file key
        if d.get("num_steps"):
            d.pop("horizon", None)
        return d


# --------------------------------------------------------------------------------------------
# Typed loading with key paths in every error message
# --------------------------------------------------------------------------------------------


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp)).replace("typing.", "")


def _coerce(value: Any, tp: Any, key: str) -> Any:
    """Converts a YAML value to type ``tp`` (from the dataclass annotations)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return plain_data(value, key)
    if origin in (typing.Union, types.UnionType):
        return _coerce_union(value, args, key)
    if dataclasses.is_dataclass(tp):
        return _coerce_dataclass(value, tp, key)
    if origin is list:
        return _coerce_list(value, args[0], key)
    if origin is dict:
        return _coerce_dict(value, args[1], key)
    scalar = _SCALARS.get(tp)
    if scalar is not None:
        return scalar(value, key)
    raise ConfigError(f"{key}: unsupported type {_type_name(tp)}")


#: Deepest nesting of lists and mappings a task's value may have (a task file needs a few).
MAX_DEPTH = 32


def plain_data(value: Any, key: str) -> Any:
    """``value`` if it is YAML data (None, booleans, numbers, strings, lists and mappings with
    string keys of them), nested at most MAX_DEPTH deep; ConfigError naming ``key`` otherwise
    (a complex number or another Python object from a dict, nesting a file cannot mean)."""
    stack = [(value, key, 0)]
    while stack:
        v, where, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise ConfigError(f"{key}: nested more than {MAX_DEPTH} levels deep")
        if isinstance(v, dict):
            for k, item in v.items():
                if not isinstance(k, (str, int, float, bool)) or isinstance(k, complex):
                    raise ConfigError(f"{where}: a key that is not a name: {type(k).__name__}")
                stack.append((item, f"{where}.{k}", depth + 1))
        elif isinstance(v, (list, tuple)):
            stack.extend((item, f"{where}[{i}]", depth + 1) for i, item in enumerate(v))
        elif not (v is None or isinstance(v, (str, bool, int, float))):
            raise ConfigError(f"{where}: expected YAML data, got a {type(v).__name__}")
    return value


def _coerce_union(value: Any, args: tuple, key: str) -> Any:
    """The first of ``args`` that ``value`` converts to (None for None when allowed)."""
    if value is None and type(None) in args:
        return None
    errors, fitting = [], []
    for a in args:
        if a is type(None):
            continue
        try:
            return _coerce(value, a, key)
        except ConfigError as e:
            errors.append(str(e))
            if _same_shape(value, a):  # (a mapping's error is its own key's, not "a string")
                fitting.append(str(e))
    raise ConfigError((fitting or errors or [f"{key}: invalid value {value!r}"])[0])


def _same_shape(value: Any, tp: Any) -> bool:
    """Whether ``value`` is of the kind ``tp`` holds: a mapping for a section or a mapping
    type, a list for a list type, a scalar for a scalar type."""
    origin = typing.get_origin(tp)
    mapping = dataclasses.is_dataclass(tp) or origin is dict
    if isinstance(value, dict):
        return mapping
    if isinstance(value, (list, tuple)):
        return origin is list
    return not mapping and origin is not list


def _coerce_dataclass(value: Any, tp: Any, key: str) -> Any:
    if value is None:
        value = {}
    if not isinstance(value, dict):
        raise ConfigError(f"{key}: expected a mapping, got {value!r}")
    return _build_dataclass(tp, value, key)


def _coerce_list(value: Any, item: Any, key: str) -> list:
    if value is None:
        return []
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{key}: expected a list, got {value!r}")
    return [_coerce(v, item, f"{key}[{i}]") for i, v in enumerate(value)]


def _coerce_dict(value: Any, item: Any, key: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{key}: expected a mapping, got {value!r}")
    return {str(k): _coerce(v, item, f"{key}.{k}") for k, v in value.items()}


def _coerce_float(value: Any, key: str) -> float:
    if isinstance(value, bool):
        raise ConfigError(f"{key}: expected a number, got {value!r}")
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ConfigError(f"{key}: expected a number, got {value!r}") from None
    if not isinstance(value, (int, float)):
        raise ConfigError(f"{key}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{key}: expected a finite number, got {value!r}")
    return float(value)


def _coerce_int(value: Any, key: str) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, str):
        try:
            value = int(value)
        except ValueError:
            raise ConfigError(f"{key}: expected an integer, got {value!r}") from None
    if not isinstance(value, int) or isinstance(value, bool):
        raise ConfigError(f"{key}: expected an integer, got {value!r}")
    return value


def _coerce_bool(value: Any, key: str) -> bool:
    if isinstance(value, str) and value.lower() in ("true", "false", "yes", "no", "1", "0"):
        return value.lower() in ("true", "yes", "1")
    if not isinstance(value, bool):
        raise ConfigError(f"{key}: expected true/false, got {value!r}")
    return value


def _coerce_str(value: Any, key: str) -> str:
    if isinstance(value, (dict, list)) or value is None:
        raise ConfigError(f"{key}: expected a string, got {value!r}")
    return str(value)


#: The converters of the scalar types a task file's fields have.
_SCALARS = {float: _coerce_float, int: _coerce_int, bool: _coerce_bool, str: _coerce_str}


def unknown_key(name: Any, valid: list[str], what: str) -> str:
    """'unknown WHAT (did you mean X? expected one of: ...)' for a name not in ``valid``."""
    close = difflib.get_close_matches(str(name), valid, n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    return f"unknown {what} ({hint}expected one of: {', '.join(valid)})"


LOADER_KEYS = ("base_dir", "smoke_run")  # TaskConfig fields the loader sets, never a file


def _build_dataclass(cls: Any, data: dict[str, Any], prefix: str) -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init and f.metadata.get("task_file", 1)}
    kwargs = {}
    for k, v in data.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if k not in names or k in LOADER_KEYS:
            valid = sorted(n for n in names if n not in LOADER_KEYS)
            raise ConfigError(f"{key}: {unknown_key(k, valid, 'key')}")
        kwargs[k] = _coerce(v, hints[k], key)
    obj = cls(**kwargs)
    if cls is SceneObject and obj.shape not in SHAPES:
        raise ConfigError(
            f"{prefix}.shape: expected {', '.join(SHAPES[:-1])} or {SHAPES[-1]}, got {obj.shape!r}"
        )
    if cls is SceneObject:
        shape_keys = {"box": ["size"], "sphere": ["radius"], "cylinder": ["radius", "length"]}
        used = shape_keys.get(obj.shape, [])
        default = SceneObject()
        for k in ("size", "radius", "length"):
            # (a saved task lists every field: only a value other than the default is an error)
            if k in data and k not in used and getattr(obj, k) != getattr(default, k):
                what = f"uses {' and '.join(used)}" if used else "has no size"
                raise ConfigError(f"{prefix}.{k}: a {obj.shape} {what}, not {k}")
    return obj


# Sections whose keys are names from the model (state blocks such as ``theta.v`` or
# ``body.position``, actuators, geometries), which may themselves contain dots.
_NAME_MAPS = (
    ("cost", "Q"),
    ("cost", "Qf"),
    ("cost", "R"),
    ("cost", "nominal"),
    ("cost", "nominal_rate"),
    ("initial_state",),
    ("blocks",),
)


def _group_free_keys(parts: list[str]) -> list[str]:
    """Rejoins a model name that a dotted key split: ``cost.Q.theta.v`` sets block ``theta.v``
    of ``cost.Q``; ``geometry.a.b.friction`` sets ``friction`` of geometry ``a.b``."""
    for prefix in _NAME_MAPS:
        n = len(prefix)
        if tuple(parts[:n]) == prefix and len(parts) > n + 1:
            return [*prefix, ".".join(parts[n:])]
    if parts[0] == "geometry" and len(parts) > 3:
        return ["geometry", ".".join(parts[1:-1]), parts[-1]]
    if parts[0] == "mismatch" and len(parts) > 3:  # mismatch.CASE.ball.friction
        return ["mismatch", parts[1], ".".join(parts[2:])]
    if parts[0] == "goal" and len(parts) > 3:  # a goal on a nested metric (duty_factor.FL)
        return ["goal", ".".join(parts[1:-1]), parts[-1]]
    if parts[:2] == ["mpc", "goal"] and len(parts) > 4:  # the closed loop's, likewise
        return ["mpc", "goal", ".".join(parts[2:-1]), parts[-1]]
    return parts


def _set_dotted(data: dict[str, Any], key: str, value: Any) -> None:
    parts = key.split(".")
    top = {f.name for f in dataclasses.fields(TaskConfig)}
    if parts[0] not in top:
        geometry = data.get("geometry") or {}
        scene_names = [o.get("name") for o in (data.get("scene") or []) if isinstance(o, dict)]
        if parts[0] in scene_names and parts[0] in geometry:
            raise ConfigError(
                f"{key}: {parts[0]!r} names both a scene object and a geometry entry; write "
                f"scene.{scene_names.index(parts[0])}.{'.'.join(parts[1:])} or geometry.{key}"
            )
        if scene_names.count(parts[0]) > 1:
            raise ConfigError(f"{key}: several scene objects are named {parts[0]!r}")
        if parts[0] in scene_names:
            idx = scene_names.index(parts[0])
            parts = ["scene", str(idx)] + parts[1:]
        elif len(parts) == 2:
            # Shortcut for geometry overrides: tip.hydroelastic_modulus. A geometry the task
            # already names, or a near-miss of a contact property, is taken as one too, so a
            # typo is reported against the contact properties, not the top-level keys.
            fields = [f.name for f in dataclasses.fields(ContactProperties)]
            if (
                parts[0] in geometry
                or parts[1] in fields
                or difflib.get_close_matches(parts[1], fields, n=1)
            ):
                parts = ["geometry"] + parts
    parts = _group_free_keys(parts)
    node: Any = data
    for i, p in enumerate(parts[:-1]):
        where = ".".join(parts[: i + 1])
        if isinstance(node, list):
            node = _list_element(node, p, f"{key}: no list element {where}")
            continue
        if not isinstance(node, dict):
            raise ConfigError(f"{key}: {where} is not a section")
        if node.get(p) is None:
            node[p] = {}
        node = node[p]
    if isinstance(node, list):
        try:
            node[int(parts[-1])] = value
        except (ValueError, IndexError):
            raise ConfigError(f"{key}: no list element") from None
    elif isinstance(node, dict):
        node[parts[-1]] = value
    else:
        parent = ".".join(parts[:-1])
        raise ConfigError(
            f"{key}: {parent} is a single value here; set it as a mapping instead: "
            f"--set '{parent}={{{parts[-1]}: ...}}'"
        )


def _list_element(node: list, p: str, missing: str) -> Any:
    """Element ``p`` of a list in a dotted key: an index, or the one element (a mapping) whose
    ``name`` is ``p`` (``cost.terms.reach.weight``)."""
    named = [e for e in node if isinstance(e, dict) and e.get("name") == p]
    if len(named) == 1 and not p.isdigit():
        return named[0]
    try:
        return node[int(p)]
    except (ValueError, IndexError):
        raise ConfigError(missing) from None


def parse_override(text: str) -> tuple[str, Any]:
    """``key=value`` -> (key, YAML-parsed value)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r}: expected key=value")
    key, raw = text.split("=", 1)
    try:
        value = yaml_value(raw) if raw.strip() else None
    except yaml.YAMLError:
        value = raw
    return key.strip(), value


# What a "real" (simulated) system may differ in from the controller's model: --truth-set.
TRUTH_SECTIONS = ("models", "package_map", "scene", "geometry", "plant", "actuators")
# Keys of the simulated plant that playback's own options set.
PLAYBACK_OWN = {
    "plant.time_step": "--truth-time-step",
    "plant.contact_approximation": "--truth-contact",
}


def check_truth_overrides(overrides: list[str], playback: bool = False) -> None:
    """ConfigError for a --truth-set key the simulated plant does not use (solver, cost, ...);
    with ``playback``, also for a key playback sets with its own options (the time step and
    contact approximation)."""
    top = {f.name for f in dataclasses.fields(TaskConfig)}
    for text in overrides:
        key, value = parse_override(text)
        first = key.split(".")[0]
        if first in top and first not in TRUTH_SECTIONS:
            raise ConfigError(
                f"--truth-set {key}: the simulated plant only uses {', '.join(TRUTH_SECTIONS)} "
                "(and geometry/scene shorthands)"
            )
        if not playback:
            continue
        nested = value if key == "plant" and isinstance(value, dict) else {}
        for own, option in PLAYBACK_OWN.items():
            if key == own or own.split(".")[1] in nested:
                raise ConfigError(f"--truth-set {own}: playback sets it with {option}")


def with_overrides(
    cfg: TaskConfig, overrides: list[str] | dict[str, Any] | str, paths_from: Path | None = None
) -> TaskConfig:
    """A copy of a loaded task with overrides applied (validated again): ``key=value``
    strings, or a dict of dotted keys to values. Relative file paths in them are relative to
    the working directory, or to ``paths_from``."""
    d = cfg.to_dict()
    items = _override_items(overrides)
    _horizon_wins(d, items)
    for key, value in items:
        _set_dotted(d, key, cwd_path(key, value, paths_from))
    return task_from_dict(d, cfg.base_dir)


def _horizon_wins(data: dict, items: list[tuple[str, Any]]) -> None:
    """A horizon given as an override wins over the task's num_steps."""
    keys = {k for k, _ in items}
    if "horizon" in keys and "num_steps" in keys:
        raise ConfigError("--set: give horizon or num_steps, not both")
    if "horizon" in keys:
        data["num_steps"] = 0


def _override_items(overrides) -> list[tuple[str, Any]]:
    if isinstance(overrides, str):
        overrides = [overrides]
    if isinstance(overrides, dict):
        return list(overrides.items())
    return [parse_override(text) for text in overrides or []]


def task_file(name_or_path: str) -> Path:
    """Built-in task name or a path to a task YAML file."""
    if not isinstance(name_or_path, (str, Path)) or "\n" in str(name_or_path):
        raise ConfigError(
            "expected a built-in task name or a task file path (for YAML text: "
            "Task.from_dict(yaml.safe_load(text)))"
        )
    p = Path(name_or_path)
    builtin = TASKS_DIR / f"{name_or_path}.yaml"
    if p.is_dir() and builtin.exists():
        return builtin  # e.g. a run directory named like the task (--out cartpole-wall)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.exists():
            raise ConfigError(f"task file {name_or_path}: no such file")
        if p.is_dir():
            raise ConfigError(f"task file {name_or_path}: a directory, not a task YAML file")
        return p
    if not builtin.exists():
        raise ConfigError(
            f"unknown task {name_or_path!r} (built-in tasks: {', '.join(list_tasks())})"
        )
    return builtin


def list_tasks() -> list[str]:
    return sorted(p.stem for p in TASKS_DIR.glob("*.yaml") if not p.stem.startswith("_"))


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that rejects a key given twice in one mapping (YAML keeps the last silently)."""

    def construct_mapping(self, node, deep=False):
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if not isinstance(key, Hashable):
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    "a key that is a list or a mapping (keys are names)",
                    key_node.start_mark,
                )
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"key {key!r} given twice (first on line {seen[key] + 1})",
                    key_node.start_mark,
                )
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)

    def compose_document(self):
        """The document's node graph, refused (before anything is built from it) when its
        aliases would expand to more than MAX_YAML_NODES nodes, or refer to themselves."""
        node = super().compose_document()
        if node is not None and self.anchors_seen:
            n = _expanded_nodes(node)
            if n < 0 or n > MAX_YAML_NODES:
                problem = (
                    "an alias refers to a node that contains it"
                    if n < 0
                    else f"its aliases expand to more than {MAX_YAML_NODES} values"
                )
                raise yaml.composer.ComposerError(None, None, problem, node.start_mark)
        return node

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self.anchors_seen = True
        return super().compose_node(parent, index)

    anchors_seen = False


MAX_YAML_NODES = 100_000  # nodes of a YAML document with its aliases expanded


def _expanded_nodes(root) -> int:
    """Nodes of the composed YAML graph ``root`` counted as if every alias were a copy of
    its anchor (what a deep copy or a JSON dump of the loaded data holds); counted once per
    distinct node, so an alias bomb is measured without being expanded. -1 for a recursive
    alias (a node inside itself)."""
    size: dict[int, int] = {}
    on_path: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        children = []
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        if done:
            on_path.discard(key)
            size[key] = min(1 + sum(size[id(c)] for c in children), 1 << 62)
            continue
        if key in size:
            continue
        if key in on_path:
            return -1
        on_path.add(key)
        stack.append((node, True))
        for c in children:
            if id(c) in on_path:
                return -1
            if id(c) not in size:
                stack.append((c, False))
    return size[id(root)]


# YAML 1.1 (PyYAML) reads 1e6 (no dot) as the *string* "1e6"; read it as a number, as YAML 1.2
# and every reader of a task file would.
_UniqueKeyLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def yaml_value(text: str) -> Any:
    """A value given on the command line or in an override, read as YAML (1e6 is a number);
    yaml.YAMLError also for nesting too deep to read."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except RecursionError:
        raise yaml.YAMLError(f"nested more than {MAX_DEPTH} levels deep") from None


_KEY_LIKE = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]{0,63}$")  # shown in messages as typed


def _yaml_problem(e: yaml.YAMLError, text: str) -> str:
    """ ": line L: what is wrong" of a YAML error, on one line (a reader's error, such as a NUL
    byte, by the line of its character)."""
    mark = getattr(e, "problem_mark", None)
    line = mark.line + 1 if mark is not None else None
    if isinstance(e, yaml.reader.ReaderError):
        line = text.count("\n", 0, e.position) + 1
    problem = getattr(e, "problem", None) or str(e) or "malformed YAML"
    if isinstance(e, yaml.reader.ReaderError):
        char = f" #x{e.character:04x}" if isinstance(e.character, int) else ""
        problem = f"unacceptable character{char} (a YAML file holds text only)"
    problem = " ".join(str(problem).split())
    return (f": line {line}" if line is not None else "") + f": {problem}"


def load_raw(path: Path, what: str = "task file", _chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    if path.resolve() in _chain:
        loop = " -> ".join(p.name for p in (*_chain, path.resolve()))
        raise ConfigError(f"{what} {path}: `extends` loops back on itself ({loop})")
    text = read_text_bounded(path, what)  # a regular file of at most 1 MiB
    try:
        data = yaml_value(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{what} {path}{_yaml_problem(e, text)}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{what} {path}: expected a mapping at the top level")
    for k, v in data.items():
        if isinstance(k, str) and _KEY_LIKE.match(k):
            plain_data(v, k)  # (nesting a task cannot mean: one line naming the key)
    for k in data:
        if not (isinstance(k, str) and _KEY_LIKE.match(k)):  # not quoted: not a task file?
            raise ConfigError(
                f"{what} {path}: a top-level key that is no task setting (is it a task file?)"
            )
    return _extend(data, path.parent, f"{what} {path}", (*_chain, path.resolve()))


def _extend(data: dict[str, Any], directory: Path, where: str, chain=()) -> dict[str, Any]:
    """``data`` merged over the file its ``extends:`` names (relative to ``directory``, or a
    built-in task's name), if any: `extends: other.yaml` shares a base file between related
    tasks."""
    base = data.pop("extends", None)
    if base is None:
        return data
    if not isinstance(base, str):
        raise ConfigError(f"{where}: extends: expected one file name, got {base!r}")
    base_path = (directory / base).resolve()
    builtin = TASKS_DIR / f"{base}.yaml"
    if not base_path.exists() and "/" not in base and builtin.exists():
        base_path = builtin  # a built-in task by name: extends: cartpole-wall
    if not base_path.exists():
        raise ConfigError(f"{where}: extends: no such file {base_path}")
    parent = load_raw(base_path, _chain=chain)
    if base_path.parent != directory.resolve():
        _anchor_paths(parent, base_path.parent)
    if isinstance(parent.get("smoke"), dict) and isinstance(data.get("smoke"), dict):
        # the child's smoke length wins over the parent's, as at the top level
        parent["smoke"] = _without_other_length(parent["smoke"], data["smoke"])
    return _merge(_without_other_length(parent, data), data)


def _without_other_length(below: dict[str, Any], above: dict[str, Any]) -> dict[str, Any]:
    """``below`` minus its horizon or num_steps when the layer ``above`` gives the other one:
    the upper layer's trajectory length wins (extends, --config, smoke)."""
    below = dict(below)
    if above.get("horizon") is not None and "num_steps" not in above:
        below.pop("num_steps", None)
    if above.get("num_steps") and "horizon" not in above:
        below.pop("horizon", None)
    return below


GUESS_KEYWORDS = ("zeros", "gravity_compensation", "hold")


def _anchor_paths(data: dict[str, Any], base_dir: Path) -> None:
    """Makes the relative file paths of a task read from ``base_dir`` absolute, so a task that
    ``extends`` a file in another directory still finds that file's models and guesses."""

    def anchor(p: Any) -> Any:
        if not isinstance(p, str) or not p or p.startswith("package://"):
            return p
        path = Path(p).expanduser()
        return str(path if path.is_absolute() else base_dir / path)

    for m in data.get("models") or []:
        if isinstance(m, dict) and "file" in m:
            m["file"] = anchor(m["file"])
    if isinstance(data.get("package_map"), dict):
        data["package_map"] = {k: anchor(v) for k, v in data["package_map"].items()}
    guess = data.get("initial_guess")
    if isinstance(guess, str) and guess not in GUESS_KEYWORDS:
        data["initial_guess"] = anchor(guess)
    cost = data.get("cost")
    if isinstance(cost, dict) and isinstance(cost.get("reference"), str):
        cost["reference"] = anchor(cost["reference"])
    mpc = data.get("mpc")
    if isinstance(mpc, dict) and isinstance(mpc.get("warm_start_plan"), str):
        mpc["warm_start_plan"] = anchor(mpc["warm_start_plan"])
    # dotted overrides (smoke:, continuation stages) name paths too
    if isinstance(data.get("smoke"), dict):
        data["smoke"] = {k: cwd_path(k, v, base_dir) for k, v in data["smoke"].items()}
    for section in ("continuation", "ensemble", "mismatch"):
        if section in data:
            data[section] = cwd_path(section, data[section], base_dir)


def cwd_path(key: str, value: Any, base: Path | None = None) -> Any:
    """A relative file path given on the command line is relative to the working directory
    (``base``: to that directory instead, e.g. a task file's for its continuation stages).
    An empty path stays empty (``cost.reference`` / ``mpc.warm_start_plan``: none). The paths
    inside a whole section of overrides (``ensemble``, ``continuation``, ``mismatch`` or one
    of its cases) are anchored the same way."""
    parts = key.split(".")
    if parts[0] in ("ensemble", "continuation") and len(parts) == 1 and isinstance(value, list):
        return [_anchor_mapping(v, base) for v in value]
    if parts[0] == "mismatch" and isinstance(value, dict):
        if len(parts) == 1:
            return {name: _anchor_mapping(case, base) for name, case in value.items()}
        if len(parts) == 2:
            return _anchor_mapping(value, base)
    is_path = (
        key in ("initial_guess", "cost.reference", "mpc.warm_start_plan")
        or parts[0] == "package_map"
        or (parts[0] == "models" and parts[-1] == "file")
    )
    if (
        not is_path
        or not isinstance(value, str)
        or not value
        or value in GUESS_KEYWORDS
        or value.startswith("package://")
        or Path(value).expanduser().is_absolute()
    ):
        return value
    return str((base or Path.cwd()) / Path(value).expanduser())


def _anchor_mapping(overrides: Any, base: Path | None) -> Any:
    """A mapping of dotted overrides with its relative paths anchored (``cwd_path``)."""
    if not isinstance(overrides, dict):
        return overrides
    return {k: cwd_path(str(k), v, base) for k, v in overrides.items()}


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def load_task(
    name_or_path: str,
    overrides: list[str] | dict[str, Any] | None = None,
    config_file: str | None = None,
    smoke: bool = False,
) -> TaskConfig:
    """Loads a built-in task or task file, merges ``config_file`` and ``key=value`` overrides.

    With ``smoke``, the task's own ``smoke`` overrides (or generic ones) shrink it first.
    """
    path = task_file(name_or_path)
    return build_task(load_raw(path), path.resolve().parent, overrides, config_file, smoke, path)


def build_task(
    data: dict[str, Any],
    base_dir: str | Path,
    overrides: list[str] | dict[str, Any] | str | None = None,
    config_file: str | None = None,
    smoke: bool = False,
    path: Path | None = None,
) -> TaskConfig:
    """A TaskConfig from a task's YAML data (paths in it relative to ``base_dir``), with the
    same ``config_file``, ``smoke`` and overrides handling as ``load_task``."""
    data = copy.deepcopy(data)
    base_dir = Path(base_dir).resolve()
    label = path.name if path is not None else "task"
    if path is None and isinstance(data, dict):  # a dict's extends: relative to base_dir
        data = _extend(data, base_dir, label)
    if path is not None and data.get("horizon") is not None and data.get("num_steps"):
        raise ConfigError(f"{label}: give horizon or num_steps, not both")
    if config_file:
        extra = load_raw(Path(config_file), "--config file")
        _anchor_paths(extra, Path(config_file).resolve().parent)  # its paths: relative to it
        data = _merge(_without_other_length(data, extra), extra)
    items = _override_items(overrides)

    def finish(d: dict[str, Any], shrink: dict[str, Any] | None = None) -> TaskConfig:
        d = copy.deepcopy(d)
        _horizon_wins(d, items)
        for key, value in items:
            _set_dotted(d, key, cwd_path(key, value))
        if shrink is not None:  # --smoke: a search section shrunk too (given keys win)
            _shrink_search(d, {**shrink, **dict(items)})
        if path is not None:
            d.setdefault("name", path.stem)
        cfg = _build_dataclass(TaskConfig, d, "")
        cfg.base_dir = str(base_dir)
        validate(cfg)
        return cfg

    if not smoke:
        return finish(data)
    section = _smoke_section(data, items)
    shrunk = _shrunk(data, section)
    finish(data)  # the task's own mistakes, unprefixed, also those the smoke section hides
    try:
        cfg = finish(shrunk, section)
    except ConfigError as e:
        raise ConfigError(f"smoke: {e}") from None
    cfg.smoke_run = True
    return cfg


def _smoke_section(data: dict[str, Any], items: list) -> dict[str, Any]:
    """The overrides --smoke applies: the task's smoke section (or generic ones), changed by
    --set smoke[.KEY]=... items."""
    shrink = data.get("smoke") or _generic_smoke(data)
    keys = {k for k, _ in items}
    if {"smoke.horizon", "smoke.num_steps"} <= keys:
        raise ConfigError("--set: give smoke.horizon or smoke.num_steps, not both")
    for key, value in items:  # --set smoke[.KEY]=... changes what --smoke applies
        head, _, rest = key.partition(".")
        if head != "smoke":
            continue
        if not rest:
            shrink = value  # the whole section
        elif isinstance(shrink, dict):
            # smoke keys are dotted strings themselves; a length given here wins over the
            # section's other one (as every upper layer's does)
            shrink = {**_without_other_length(shrink, {rest: value}), rest: value}
    if not isinstance(shrink, dict):
        raise ConfigError("smoke: expected a mapping of dotted keys to values")
    return shrink


def _shrunk(data: dict[str, Any], shrink: dict[str, Any]) -> dict[str, Any]:
    """A copy of ``data`` with the smoke overrides ``shrink`` applied."""
    shrunk = _without_other_length(copy.deepcopy(data), shrink)
    try:
        for key, value in list(shrink.items()):
            if key.split(".")[0] == "smoke":
                raise ConfigError(f"{key}: the smoke section cannot change itself")
            _set_dotted(shrunk, key, value)
    except ConfigError as e:
        raise ConfigError(f"smoke: {e}") from None
    return shrunk


#: What --smoke makes of a ``search:`` section (keys the smoke section sets itself win).
SEARCH_SMOKE = {"samples": 6, "iterations": 2, "elites": 2, "polish": 1, "robust_runs": 1}


def _shrink_search(shrunk: dict[str, Any], shrink: dict[str, Any]) -> None:
    """A smoke-sized search: a few samples and iterations, at most 3 knots."""
    search = shrunk.get("search")
    if not isinstance(search, dict):
        return
    for key, value in SEARCH_SMOKE.items():
        if f"search.{key}" not in shrink:
            search[key] = value
    if "search.knots" not in shrink and isinstance(search.get("knots", 8), int):
        search["knots"] = min(search.get("knots", 8), 3)


def task_from_dict(data: dict[str, Any], base_dir: str = ".") -> TaskConfig:
    cfg = _build_dataclass(TaskConfig, copy.deepcopy(data), "")
    cfg.base_dir = str(Path(base_dir).resolve())
    validate(cfg)
    return cfg


APPROXIMATIONS = ("sap", "similar", "lagged", "tamsi")
PLAYBACK_POLICIES = ("pd", "ilqr")  # playback: PD+ around the plan, or its iLQR gains
# playback's PD+ feed-forward: ū dynamically scaled to the speed, or the plan's unchanged
PLAYBACK_FEEDFORWARDS = ("scaled", "plan")
CONTACT_MODELS = ("hydroelastic_with_fallback", "hydroelastic", "point")
DERIVATIVES = tuple(m.value for m in DerivativeMethod)  # the YAML/CLI spellings
WARM_START_TAILS = ("last", "guess")  # mpc.warm_start_tail
# mpc.candidates
MPC_CANDIDATES = ("first_plan", "first_plan_controls", "first_plan_policy", "guess")


def _check_contact(p: ContactProperties, key: str) -> None:
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


def _check_length(values: list[float], n: int, key: str) -> None:
    if len(values) != n:
        raise ConfigError(f"{key}: expected {n} numbers, got {len(values)}")


MAX_STEPS = 1_000_000  # time steps of one trajectory (a typo such as horizon: 2e6 is refused)


def validate_mpc(m: Any) -> None:
    """Checks the ``mpc:`` settings that need no plant (an MPCConfig); ConfigError naming the
    key."""
    validate_goal(m.goal, "mpc.goal")
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


def validate_solver(sv: SolverConfig) -> None:
    """ConfigError naming the first invalid solver setting (also for settings built in Python)."""
    if sv.derivatives not in DERIVATIVES:
        raise ConfigError(
            f"solver.derivatives: expected one of {', '.join(DERIVATIVES)}, got {sv.derivatives!r}"
        )
    if sv.max_iterations < 0:
        raise ConfigError("solver.max_iterations: must be >= 0")
    if sv.fd_epsilon <= 0:
        raise ConfigError("solver.fd_epsilon: must be positive")
    for key in ("autodiff_workers", "line_search_workers"):
        if getattr(sv, key) < 0:
            raise ConfigError(f"solver.{key}: must be >= 0 (0 = one per core)")
    if sv.derivative_secant_updates < 0:
        raise ConfigError("solver.derivative_secant_updates: must be >= 0")
    if not sv.derivative_reuse_tolerance >= 0:
        raise ConfigError("solver.derivative_reuse_tolerance: must be >= 0")
    if sv.derivative_interval < 1:
        raise ConfigError("solver.derivative_interval: must be >= 1")
    for name, ok, rule in (
        ("line_search_factor", 0 < sv.line_search_factor < 1, "between 0 and 1"),
        ("armijo", 0 <= sv.armijo < 1, "in [0, 1)"),
        ("line_search_max_steps", sv.line_search_max_steps >= 1, ">= 1"),
        ("line_search_retries", sv.line_search_retries >= 0, ">= 0"),
        ("regularization_init", sv.regularization_init >= 0, ">= 0"),
        ("regularization_min", sv.regularization_min >= 0, ">= 0"),
        ("regularization_max", sv.regularization_max > sv.regularization_min, "> its min"),
        ("regularization_factor", sv.regularization_factor > 1, "> 1"),
        ("short_step", 0 <= sv.short_step <= 1, "in [0, 1]"),
        ("relative_cost_tolerance", sv.relative_cost_tolerance >= 0, ">= 0"),
        ("expected_decrease_tolerance", sv.expected_decrease_tolerance >= 0, ">= 0"),
        ("threads", sv.threads >= 0, ">= 0 (0 = all cores)"),
    ):
        if not ok:
            raise ConfigError(f"solver.{name}: must be {rule}, got {getattr(sv, name)}")


def validate_for_solve(cfg: TaskConfig) -> None:
    """Checks a task must pass to be solved (a task that only describes a plant, e.g. for
    its dynamics, need not): ConfigError for a cost without terms."""
    if not _has_cost_terms(cfg.cost):
        raise ConfigError(
            "cost: no terms (every weight in Q, Qf, R and cost.terms is zero or missing): there "
            "is nothing to optimize; give the cost some positive weights"
        )


def _has_cost_terms(cost: CostConfig) -> bool:
    """Some weight of Q, Qf, R or a task-space term is positive (a malformed R counts: its own
    check says why)."""

    def positive(w: Any) -> bool:
        if isinstance(w, dict):
            return any(positive(v) for v in w.values())
        if isinstance(w, (list, tuple)):
            return any(positive(v) for v in w)
        try:
            return float(w) > 0
        except (TypeError, ValueError):
            return True

    return any(positive(w) for w in (cost.Q, cost.Qf, cost.R)) or any(
        positive(t.weight) for t in cost.terms
    )


def validate(cfg: TaskConfig) -> None:
    """Checks that do not need the model (the model-dependent ones live in plant.py/state.py)."""
    _validate_continuation(cfg)
    _validate_ensemble(cfg)
    _validate_mismatch(cfg)
    if not cfg.models:
        raise ConfigError("models: at least one model file is required")
    _validate_names(cfg)
    _validate_models(cfg)
    _check_length(cfg.plant.gravity, 3, "plant.gravity")
    _validate_actuators(cfg.actuators)
    _validate_plant(cfg.plant)
    if cfg.horizon <= 0 and cfg.num_steps <= 0:
        raise ConfigError(f"horizon: must be positive, got {cfg.horizon}")
    validate_solver(cfg.solver)
    validate_mpc(cfg.mpc)
    validate_goal(cfg.goal)
    _validate_steps(cfg)
    for name, p in cfg.geometry.items():
        _check_contact(p, f"geometry.{name}")
    for i, o in enumerate(cfg.scene):
        _check_scene_object(o, f"scene[{i}]")
    _validate_cost(cfg.cost)
    _validate_receding_horizon(cfg.receding_horizon)
    validate_search(cfg)
    if isinstance(cfg.initial_guess, PositionGuess):
        _validate_position_guess(cfg.initial_guess)


def _validate_position_guess(g: PositionGuess, key: str = "initial_guess") -> None:
    """One of waypoints / target; times positive, increasing and inside the period; block
    names are checked when the plant is built (model/guess.py)."""
    if bool(g.waypoints) == bool(g.target):
        raise ConfigError(f"{key}: give waypoints (a list of {{t: s, BLOCK: value}}) or target")
    if g.period < 0 or not math.isfinite(g.period):
        raise ConfigError(f"{key}.period: must be >= 0 (0: no repetition), got {g.period}")
    if g.target and g.period:
        raise ConfigError(f"{key}.period: only with waypoints")
    if g.target and "t" in g.target:
        raise ConfigError(f"{key}.target: has no time (it is reached at the task's end)")
    last = 0.0
    for i, wp in enumerate(g.waypoints):
        t = wp.get("t")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            raise ConfigError(f"{key}.waypoints[{i}].t: expected a time in seconds, got {t!r}")
        if t <= last:
            raise ConfigError(
                f"{key}.waypoints[{i}].t: {t:g} s must be after the previous point ({last:g} s)"
            )
        if g.period and t >= g.period:
            raise ConfigError(f"{key}.waypoints[{i}].t: {t:g} s must be before period {g.period:g}")
        if len(wp) < 2:
            raise ConfigError(f"{key}.waypoints[{i}]: names no block")
        _check_configuration(wp, f"{key}.waypoints[{i}]")
        last = float(t)
    _check_configuration(g.target, f"{key}.target")


def _check_configuration(point: dict[str, Any], key: str) -> None:
    """Each block's value of a waypoint or target is a number or a flat list of numbers."""
    for name, v in point.items():
        if name == "t":
            continue
        values = v if isinstance(v, list) else [v]
        if not values or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            for x in values
        ):
            raise ConfigError(
                f"{key}.{name}: expected a number or a list of numbers (one per component), "
                f"got {v!r}"
            )


# Keys a continuation stage or an ensemble member cannot override (the time grid and start).
_FIXED_KEYS = ("continuation", "receding_horizon", "smoke", "name", "horizon", "num_steps")
_FIXED_KEYS += (
    "initial_state",
    "initial_guess",
    "ensemble",
    "ensemble_weight",
    "ensemble_warm_start",
    "mismatch",
)


def _check_overrides(section: str, i: int, item: Any, why: str, fixed=()) -> None:
    """``section[i]``: a non-empty mapping of dotted keys, none of which changes the time grid
    or the start (nor a key of ``fixed``); ConfigError saying ``why`` otherwise."""
    if not isinstance(item, dict) or not item:
        raise ConfigError(
            f"{section}[{i}]: expected a mapping of dotted keys to values, e.g. "
            "{ball_collision.hydroelastic_modulus: 5.0e+5}"
        )
    for key in item:
        first = str(key).split(".")[0]
        if first in _FIXED_KEYS + tuple(fixed) or str(key) == "plant.time_step":
            raise ConfigError(f"{section}[{i}]: {key} cannot change {why}")


def _validate_continuation(cfg: TaskConfig) -> None:
    """Each stage: a mapping of dotted keys that leave the time grid and start alone."""
    why = "between stages (every stage solves the task's time grid from its initial state)"
    for i, stage in enumerate(cfg.continuation):
        _check_overrides("continuation", i, stage, why)
    if cfg.continuation and cfg.receding_horizon is not None:
        raise ConfigError("continuation: for single solves (not with receding_horizon)")


def _validate_ensemble(cfg: TaskConfig) -> None:
    """Each member: a mapping of dotted keys that leave the time grid, start and solver alone;
    single solves only; a finite weight >= 0."""
    why = "in an ensemble member (every member shares the task's time grid, start and solver)"
    for i, member in enumerate(cfg.ensemble):
        _check_overrides("ensemble", i, member, why, ("solver", "mpc"))
    if not (math.isfinite(cfg.ensemble_weight) and cfg.ensemble_weight >= 0):
        raise ConfigError(f"ensemble_weight: must be >= 0, got {cfg.ensemble_weight}")
    if cfg.ensemble and cfg.receding_horizon is not None:
        raise ConfigError("ensemble: for single solves (not with receding_horizon)")
    if cfg.ensemble and cfg.continuation:
        raise ConfigError("ensemble: not supported together with continuation (use one of them)")


def _validate_mismatch(cfg: TaskConfig) -> None:
    """Each case: a name usable on the command line and a mapping of dotted keys of the
    sections the simulated plant uses (as --truth-set)."""
    if not isinstance(cfg.mismatch, dict):
        raise ConfigError("mismatch: expected a mapping of names to mappings of dotted keys")
    for name, case in cfg.mismatch.items():
        ok = isinstance(name, str) and name and all(c.isalnum() or c in "+-_" for c in name)
        if not ok or name.startswith("-"):
            raise ConfigError(
                f"mismatch: {name!r}: a name of letters, digits and + - _ only, not starting with -"
            )
        if not isinstance(case, dict) or not case:
            raise ConfigError(
                f"mismatch.{name}: expected a mapping of dotted keys to values, e.g. "
                "{ball.friction: 0.14}"
            )
        try:
            check_truth_overrides([_override_text(k, v) for k, v in case.items()], playback=True)
        except ConfigError as e:
            raise ConfigError(f"mismatch.{name}: {str(e).removeprefix('--truth-set ')}") from None


def mismatch_overrides(cfg: TaskConfig, name: str) -> list[str]:
    """The ``KEY=VALUE`` truth overrides of the task's mismatch case ``name``, relative paths
    in it made absolute (relative to the task file); ConfigError if it has none."""
    if name not in cfg.mismatch:
        if not cfg.mismatch:
            raise ConfigError(
                f"--mismatch {name}: {cfg.name} names no mismatch cases (the task as solved, in "
                "its summary.json, has no mismatch: section); --truth-set KEY=VALUE changes the "
                "real system directly"
            )
        known = ", ".join(cfg.mismatch)
        raise ConfigError(f"--mismatch {name}: {cfg.name} has no such case (it has: {known})")
    case = _anchor_mapping(cfg.mismatch[name], Path(cfg.base_dir) if cfg.base_dir else None)
    return [_override_text(k, v) for k, v in case.items()]


def _override_text(key: str, value: Any) -> str:
    """``KEY=VALUE`` as the command line writes it (a value that is not a string as JSON)."""
    return f"{key}={value if isinstance(value, str) else json.dumps(value)}"


def _validate_names(cfg: TaskConfig) -> None:
    """The task's name (a directory name) and the scene objects' names (unique)."""
    if not all(c.isalnum() or c in "-_.@+" for c in cfg.name) or cfg.name.startswith("."):
        raise ConfigError(
            f"name: {cfg.name!r} is used as a directory name (runs/NAME): letters, digits "
            "and - _ . @ + only"
        )
    scene_names = [o.name for o in cfg.scene if o.name]
    for n in scene_names:
        if scene_names.count(n) > 1:
            raise ConfigError(f"scene: two objects are named {n!r}")


def _validate_models(cfg: TaskConfig) -> None:
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
            _check_length(w.xyz, 3, f"{wkey}.xyz")
            _check_length(w.rpy, 3, f"{wkey}.rpy")


def _validate_actuators(actuators: dict) -> None:
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


def _validate_plant(plant: PlantConfig) -> None:
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
    if plant.contact_surface_representation not in ("polygon", "triangle"):
        raise ConfigError("plant.contact_surface_representation: expected polygon or triangle")


def _validate_steps(cfg: TaskConfig) -> None:
    """num_steps, or a horizon of whole time steps; at most MAX_STEPS of them."""
    if cfg.num_steps < 0:
        raise ConfigError(f"num_steps: must be positive (or 0: use horizon), got {cfg.num_steps}")
    steps = cfg.horizon / cfg.plant.time_step
    if cfg.num_steps == 0 and abs(steps - round(steps)) > 1e-6 * max(1.0, steps):
        raise ConfigError(
            f"horizon: {cfg.horizon:g} s is not a whole number of time steps "
            f"({cfg.plant.time_step:g} s)"
        )
    n = cfg.num_steps or round(steps)
    if n > MAX_STEPS:  # it would not fail, it would allocate and run for ever
        what = "num_steps" if cfg.num_steps else f"horizon: {cfg.horizon:g} s is"
        raise ConfigError(f"{what} {n} time steps; at most {MAX_STEPS} (a longer time step?)")


def _check_scene_object(o: SceneObject, key: str) -> None:
    """Contact properties, size, pose and color of the scene object at ``key``."""
    _check_contact(o, key)
    if o.shape == "box" and (len(o.size) != 3 or min(o.size) <= 0):
        raise ConfigError(f"{key}.size: expected three positive numbers")
    _check_length(o.xyz, 3, f"{key}.xyz")
    _check_length(o.rpy, 3, f"{key}.rpy")
    if len(o.color) not in (3, 4) or not all(0 <= c <= 1 for c in o.color):
        raise ConfigError(
            f"{key}.color: expected 3 or 4 numbers in [0, 1] (RGB or RGBA), got {o.color}"
        )
    if o.shape in ("sphere", "cylinder") and o.radius <= 0:
        raise ConfigError(f"{key}.radius: must be positive, got {o.radius}")
    if o.shape == "cylinder" and o.length <= 0:
        raise ConfigError(f"{key}.length: must be positive, got {o.length}")


def _validate_cost(cost: CostConfig) -> None:
    """The nominal's time base; finite numbers in Q, Qf (non-negative) and nominal_rate."""
    if cost.nominal_time not in NOMINAL_TIMES:
        raise ConfigError(
            f"cost.nominal_time: expected one of {', '.join(NOMINAL_TIMES)}, "
            f"got {cost.nominal_time!r}"
        )
    until = cost.nominal_rate_until
    if until is not None and (
        isinstance(until, bool)
        or not isinstance(until, (int, float))
        or not math.isfinite(until)
        or until < 0
    ):
        raise ConfigError(f"cost.nominal_rate_until: expected a time >= 0 (s), got {until!r}")
    rel = cost.nominal_relative_to_start
    if not isinstance(rel, list) or not all(isinstance(n, str) for n in rel):
        raise ConfigError(
            f"cost.nominal_relative_to_start: expected a list of block names, got {rel!r}"
        )
    for section in ("Q", "Qf", "nominal_rate"):
        for k, v in getattr(cost, section).items():
            vals = v if isinstance(v, list) else [v]
            for x in vals:
                _check_weight(x, v, f"cost.{section}.{k}", section != "nominal_rate")
    # (the nominal's and R's types are checked against the model in model/cost.py)
    named = [(f"cost.nominal.{k}", v) for k, v in cost.nominal.items()]
    named += list(cost.R.items()) if isinstance(cost.R, dict) else [("cost.R", cost.R)]
    for key, v in named:
        for x in v if isinstance(v, list) else [v]:
            _check_magnitude(x, key)
    names: set[str] = set()
    for i, term in enumerate(cost.terms):
        _validate_term(term, f"cost.terms[{i}]", names)


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


def _validate_term(term: TermConfig, key: str, names: set[str]) -> None:
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
    _check_length(term.point, 3, f"{key}.point")


def _check_position(term: TermConfig, key: str) -> None:
    _check_body(term, key)
    _check_length(term.target_velocity, 3, f"{key}.target_velocity")
    _validate_vector_target(term, key, (3,), "xyz in m")


def _check_orientation(term: TermConfig, key: str) -> None:
    _check_body(term, key)
    _validate_vector_target(term, key, (3, 4), "roll, pitch, yaw in rad")


def _check_velocity(term: TermConfig, key: str) -> None:
    _check_body(term, key)
    _validate_vector_target(term, key, (3,), "")


def _check_height(term: TermConfig, key: str) -> None:
    _check_body(term, key)
    _check_length(term.normal, 3, f"{key}.normal")
    _check_length(term.above_point, 3, f"{key}.above_point")
    if math.hypot(*term.normal) < 1e-9:
        raise ConfigError(f"{key}.normal: must be non-zero")
    _validate_scalar_target(term, key)


def _check_distance(term: TermConfig, key: str) -> None:
    if not (term.geometry_a and term.geometry_b):
        raise ConfigError(f"{key}: a distance term needs geometry_a and geometry_b")
    _validate_scalar_target(term, key)


def _check_joint_limits(term: TermConfig, key: str) -> None:
    _check_weight(term.margin, term.margin, f"{key}.margin", False)
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
        _check_length(term.ramp, 2, f"{key}.ramp")
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
        _check_weight(x, w, f"{key}.weight", True)
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
        _check_weight(x, t, f"{key}.target", False)
    if len(t) == 4 and math.hypot(*t) < 1e-9:
        raise ConfigError(f"{key}.target: a quaternion must be non-zero")


def _validate_scalar_target(term: TermConfig, key: str) -> None:
    """A height's or distance's target number, or min and/or max."""
    t = term.target
    bounds = term.min is not None or term.max is not None
    if (t is None) == (not bounds):
        raise ConfigError(f"{key}: give a target, or min and/or max (not both)")
    if t is not None:
        _check_weight(t, t, f"{key}.target", False)
    if term.min is not None and term.max is not None and term.min > term.max:
        raise ConfigError(f"{key}.min: {term.min} is above max {term.max}")


#: The largest magnitude a cost weight or a nominal value may have: beyond it, squares and
#: sums of the cost overflow floating point long before any result could mean anything.
MAX_MAGNITUDE = 1e50


def _check_magnitude(x: Any, key: str) -> None:
    if isinstance(x, (int, float)) and not isinstance(x, bool) and abs(x) > MAX_MAGNITUDE:
        raise ConfigError(
            f"{key}: {x:g} is too large to compute a cost with (at most {MAX_MAGNITUDE:g})"
        )


def _check_weight(x: Any, v: Any, key: str, weight: bool) -> None:
    """``x`` (an entry of the value ``v`` at ``key``): a finite number, >= 0 for a weight."""
    if not isinstance(x, (int, float)) or isinstance(x, bool) or not math.isfinite(x):
        try:
            bad = not math.isfinite(float(x))  # "inf", "nan" given as words
        except (TypeError, ValueError):
            bad = False
        what = "finite numbers" if bad or isinstance(x, float) else "numbers"
        raise ConfigError(f"{key}: expected {what}, got {v!r}")
    if weight and x < 0:
        raise ConfigError(f"{key}: weights must be non-negative, got {x}")
    _check_magnitude(x, key)


def _validate_receding_horizon(rh: RecedingHorizonConfig | None) -> None:
    if rh is None:
        return
    if rh.window_steps < 1 or rh.shift_steps < 1 or rh.resolves < 1:
        raise ConfigError("receding_horizon: window_steps, shift_steps, resolves must be >= 1")
    if rh.shift_steps > rh.window_steps:
        raise ConfigError(
            f"receding_horizon.shift_steps: {rh.shift_steps} is more than the window's "
            f"{rh.window_steps} steps (each window keeps its first shift_steps)"
        )
    if rh.max_iterations < 1:
        raise ConfigError("receding_horizon.max_iterations: must be >= 1")
    if not (rh.rescue_factor == 0 or rh.rescue_factor > 1):
        raise ConfigError(
            f"receding_horizon.rescue_factor: 0 (off) or above 1, got {rh.rescue_factor!r}"
        )
    if rh.rescue_iterations < 1:
        raise ConfigError("receding_horizon.rescue_iterations: must be >= 1")
    if rh.warm_start_tail not in WARM_START_TAILS:
        raise ConfigError(
            f"receding_horizon.warm_start_tail: expected last or guess, got {rh.warm_start_tail!r}"
        )
    if rh.resolves * rh.shift_steps + rh.window_steps > MAX_STEPS:
        raise ConfigError(
            f"receding_horizon: {rh.resolves} resolves of {rh.shift_steps} steps are more than "
            f"{MAX_STEPS} time steps"
        )


def _generic_smoke(data: dict[str, Any]) -> dict[str, Any]:
    """Default shrink for tasks without a ``smoke`` section."""
    out: dict[str, Any] = {"solver.max_iterations": 3}
    if data.get("receding_horizon"):
        out.update(
            {
                "receding_horizon.window_steps": 10,
                "receding_horizon.shift_steps": 2,
                "receding_horizon.resolves": 3,
                "receding_horizon.max_iterations": 2,
            }
        )
    else:
        out["num_steps"] = 20
    return out


def validate_search(cfg: TaskConfig) -> None:
    """ConfigError naming the first invalid ``search:`` setting (none: nothing to check)."""
    sc = cfg.search
    if sc is None:
        return
    if cfg.receding_horizon is not None:
        raise ConfigError("search: a receding-horizon task cannot be searched (one horizon only)")
    for key, value, choices in (
        ("method", sc.method, SEARCH_METHODS),
        ("space", sc.space, SEARCH_SPACES),
        ("order", sc.order, SEARCH_ORDERS),
        ("select", sc.select, SEARCH_SELECTS),
    ):
        if value not in choices:
            raise ConfigError(
                f"search.{key}: expected one of {', '.join(map(str, choices))}, got {value!r}"
            )
    steps = cfg.steps
    for name, ok, rule in (
        ("samples", 2 <= sc.samples <= MAX_SEARCH_SAMPLES, f"from 2 to {MAX_SEARCH_SAMPLES}"),
        ("iterations", 1 <= sc.iterations <= 100_000, "from 1 to 100000"),
        ("knots", 1 <= sc.knots <= steps, f"from 1 to the task's {steps} steps"),
        ("elites", sc.elites >= 1, ">= 1 (at most search.samples are used)"),
        ("seed", sc.seed >= 0, ">= 0"),
        ("polish", 0 <= sc.polish <= 100, "from 0 to 100"),
        ("batches", 0 <= sc.batches <= 10_000, "from 0 (one per worker) to 10000"),
        ("robust_runs", 1 <= sc.robust_runs <= 100, "from 1 to 100"),
    ):
        if not ok:
            raise ConfigError(f"search.{name}: must be {rule}, got {getattr(sc, name)!r}")
    for name, ok, rule in (
        ("noise", 0 < sc.noise < math.inf, "a finite number > 0"),
        ("elite_memory", 0 <= sc.elite_memory <= 1, "in [0, 1]"),
        ("colored_noise", 0 <= sc.colored_noise <= 10, "in [0, 10]"),
        ("smoothing", 0 <= sc.smoothing < 1, "in [0, 1)"),
        ("temperature", 0 < sc.temperature < math.inf, "a finite number > 0"),
        ("kp", 0 <= sc.kp < math.inf and (sc.kp > 0 or sc.space != "position"), "finite, > 0"),
        ("kd", 0 <= sc.kd < math.inf, "a finite number >= 0"),
        ("robust_noise", 0 < sc.robust_noise < math.inf, "a finite number > 0"),
    ):
        if not ok:  # (NaN fails every comparison)
            raise ConfigError(f"search.{name}: must be {rule}, got {getattr(sc, name)!r}")
