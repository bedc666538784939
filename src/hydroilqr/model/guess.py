"""Guesses in positions: a path of configurations turned into controls by a tracking rollout.

``initial_guess: {waypoints: [...]}`` (or ``{target: {...}}``) in a task file says where the
joints should be and when; this module turns that path into the controls U: [N, nu] that the
solver starts from, by simulating the task's own plant:

- the reference q_ref(t) is piecewise linear in time, from the initial state's values at
  t = 0 through each waypoint, holding after the last one (with ``period`` > 0 it returns to
  the start values at t = period and repeats). It covers every actuated joint (one the path
  never names holds its start value) and the unactuated coordinates the path names (a base's
  x or height: tracked with a smaller weight, through whatever the actuators can do to them);
- at every step k the control u_k is the one whose step of the plant brings those
  coordinates' velocities closest to v_des = v_ref + (q_ref(t_{k+1}) − q_k − dt·v_ref) /
  (SETTLE_STEPS·dt), which closes part of the gap to the reference at each step: Gauss-Newton
  on u through the plant's own step (Drake: contact, gravity, joint limits and the
  unactuated base included; partials by finite differences), with a backtracking search and
  every trial clipped to the effort limits. It is inverse dynamics of the discrete step, with
  the contact forces that step produces; nothing is computed by hand-written kinematics.

The rollout's states are the guess's states exactly: U replayed open loop from the same
state gives the same X (each control is computed at the state it is applied at).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from pydrake.multibody.tree import JointIndex

from hydroilqr.model.build import VIRTUAL_PREFIX
from hydroilqr.model.plant import SimulationError
from hydroilqr.problem.errors import ConfigError

#: Gauss-Newton iterations per time step and the finite-difference step on u (N·m or N).
ITERATIONS = 10
FD_STEP = 1e-3
#: Trials of the backtracking search along a Gauss-Newton step (step sizes 1, 1/2, ...).
SEARCH_STEPS = 12
#: An error from the reference decays by 1/SETTLE_STEPS per step (1: reached at the next step,
#: which asks for large velocity changes).
SETTLE_STEPS = 2.0
#: The weight of a named unactuated coordinate's velocity error against an actuated one's (1).
UNACTUATED_WEIGHT = 0.3


@dataclass
class TrackingRollout:
    """The result of a tracking rollout: U: [N, nu], X: [N+1, nx], the reference of the
    tracked coordinates at each state's time, Q_ref: [N+1, n], and their indices in q,
    q_index: [n] (the actuated joints in actuator order, then the named unactuated ones)."""

    U: np.ndarray
    X: np.ndarray
    Q_ref: np.ndarray
    q_index: list[int]

    def tracking_error(self) -> np.ndarray:
        """|q − q_ref| of each tracked coordinate at each state: [N+1, n]."""
        return np.abs(self.X[:, self.q_index] - self.Q_ref)


class WaypointPath:
    """q_ref(t) of the coordinates a position guess (``PositionGuess``) tracks: every actuated
    joint (those it does not name hold their start values), and the unactuated ones it names
    (a base's x or height) that the tracking asks the actuators to steer through the
    dynamics, as well as they can."""

    def __init__(self, dynamics, guess, end_time: float, key: str = "initial_guess"):
        layout = dynamics.layout
        self.period = float(guess.period)
        points = list(guess.waypoints)
        if guess.target:
            points = [{"t": end_time, **guess.target}]
        # q index -> v index: every actuated joint (one a path never names holds its start
        # value), then the unactuated coordinates the path names, in order of first mention
        coords = {j.position_start(): j.velocity_start() for j in _actuated_joints(dynamics.plant)}
        self.times: list[float] = [0.0]
        self.values: list[dict] = []  # per waypoint: {q index: value}
        for i, wp in enumerate(points):
            where = f"{key}.target" if guess.target else f"{key}.waypoints[{i}]"
            values: dict[int, float] = {}
            for name, value in wp.items():
                if name == "t":
                    continue
                block = layout.block(name, f"{where}.{name}")
                if block.kind == "quaternion" or max(block.coords) >= layout.nq:
                    raise ConfigError(
                        f"{where}.{name}: a position guess names joint positions (not "
                        "velocities, not an orientation quaternion)"
                    )
                vals = np.asarray(value, float).reshape(-1)
                if vals.size == 1:
                    vals = np.full(len(block.coords), vals[0])
                if vals.size != len(block.coords) or not np.all(np.isfinite(vals)):
                    raise ConfigError(
                        f"{where}.{name}: expected {len(block.coords)} finite number(s)"
                    )
                values.update(zip(block.coords, vals.tolist()))
                for q, v in zip(block.coords, block.tangent):
                    coords.setdefault(q, v)
            self.times.append(float(wp["t"]))
            self.values.append(values)
        if self.period > 0:
            self.times.append(self.period)
        self.q_idx = list(coords)
        self.v_idx = [coords[q] for q in self.q_idx]

    def knots(self, q_start: np.ndarray) -> np.ndarray:
        """The reference's values at ``self.times``: [len(times), n] (n: the named
        coordinates, ``q_idx``), from their values ``q_start`` at t = 0; a waypoint that does
        not name a coordinate keeps the previous waypoint's value."""
        out = [np.asarray(q_start, float)]
        col = {q: j for j, q in enumerate(self.q_idx)}
        for values in self.values:
            row = out[-1].copy()
            for q, v in values.items():
                row[col[q]] = v
            out.append(row)
        if self.period > 0:
            out.append(out[0].copy())
        return np.array(out)

    def __call__(self, t: np.ndarray, q_start: np.ndarray) -> np.ndarray:
        """q_ref at the times t: [T] -> [T, n]."""
        t = np.asarray(t, float)
        if self.period > 0:
            t = np.mod(t, self.period)
        knots = self.knots(q_start)
        return np.stack(
            [np.interp(t, self.times, knots[:, j]) for j in range(knots.shape[1])], axis=1
        )


def tracking_rollout(
    dynamics, path: WaypointPath, x0: np.ndarray, N: int, t0: float = 0.0, q_start=None
) -> TrackingRollout:
    """Controls U: [N, nu] that track ``path`` from x0 at time t0 (s) over N steps of the
    plant, and the states they give. ``q_start``: the tracked coordinates' values the path
    starts from at t = 0 (default: x0's). Raises SimulationError (from the plant) if the
    chosen control's step fails."""
    dt = dynamics.dt
    nu = dynamics.nu
    q_idx, v_idx = path.q_idx, path.v_idx
    nq = dynamics.nq
    x0 = np.asarray(x0, float)
    q_start = x0[q_idx] if q_start is None else np.asarray(q_start, float)
    times = t0 + dt * np.arange(N + 1)
    Q_ref = path(times, q_start)
    rows = [nq + v for v in v_idx]
    actuated = {j.velocity_start() for j in _actuated_joints(dynamics.plant)}
    weights = np.array([1.0 if v in actuated else UNACTUATED_WEIGHT for v in v_idx])
    X = np.empty((N + 1, dynamics.nx))
    U = np.zeros((N, nu))
    X[0] = x0
    u = dynamics.clip_to_limits(dynamics.gravity_compensation(x0))
    for k in range(N):
        x = X[k]
        v_ref = (Q_ref[k + 1] - Q_ref[k]) / dt
        v_des = v_ref + (Q_ref[k + 1] - x[q_idx] - dt * v_ref) / (SETTLE_STEPS * dt)
        u, X[k + 1] = _track_step(dynamics, x, u, rows, v_des, weights)
        U[k] = u
    return TrackingRollout(U, X, Q_ref, list(q_idx))


def virtual_joints(dynamics, guess, key: str = "initial_guess.realize") -> list[str]:
    """The names of the joints of the unactuated coordinates the position guess ``guess``
    moves (names with a value other than the initial state's somewhere along the path), in
    the path's order: where its realization puts a virtual actuator each
    (``PlantSpec.virtual_forces``). A coordinate the path holds at its start value gets
    none: the joints hold it, as they must without the virtual forces. ConfigError if it
    moves none, or one of a joint with more than one coordinate (a virtual actuator drives
    a prismatic or revolute joint)."""
    path = WaypointPath(dynamics, guess, 1.0)
    plant = dynamics.plant
    actuated = {j.position_start() for j in _actuated_joints(plant)}
    knots = path.knots(dynamics.initial_state()[path.q_idx])
    held = {q for j, q in enumerate(path.q_idx) if np.ptp(knots[:, j]) == 0.0}
    by_start = {}
    for i in range(plant.num_joints()):
        j = plant.get_joint(JointIndex(i))
        if j.num_positions() > 0:
            by_start.setdefault(j.position_start(), j)
    names = []
    for q in path.q_idx:
        if q in actuated or q in held:
            continue
        j = by_start.get(q)
        if j is None or j.num_positions() != 1 or j.num_velocities() != 1:
            kind = "" if j is None else f" of a {j.type_name()} joint ({j.name()})"
            raise ConfigError(
                f"{key}: coordinate {q}{kind} is not a joint's only coordinate; a virtual "
                "force acts on a one-coordinate joint (prismatic or revolute)"
            )
        names.append(j.name())
    if not names:
        raise ConfigError(
            f"{key}: the guess moves no unactuated coordinate (a base's or an object's x, z, "
            "...; it names none, or holds each at its start value): there is nothing to realize"
        )
    return names


def virtual_config(config, dynamics, r: np.ndarray, weight: float):
    """The task ``config`` on its plant with a virtual actuator on each unactuated
    coordinate its position guess names (``virtual_joints``), their R ``weight``, the model's
    actuators keeping theirs (``r``: [nu]); its guess is the path tracked on that plant (no
    realization), and it has no continuation stages, search or ensemble of its own."""
    guess = config.initial_guess
    joints = virtual_joints(dynamics, guess)
    R = dict(zip(dynamics.layout.actuators, [float(v) for v in r]))
    R.update({VIRTUAL_PREFIX + j: float(weight) for j in joints})
    return dataclasses.replace(
        config,
        virtual_forces=joints,
        cost=dataclasses.replace(config.cost, R=R),
        initial_guess=dataclasses.replace(guess, realize=None),
        continuation=[],
        ensemble=[],
        search=None,
    )


def _actuated_joints(plant) -> list:
    return [plant.get_joint_actuator(i).joint() for i in plant.GetJointActuatorIndices()]


def _track_step(dynamics, x, u, rows, v_des, w):
    """(u, x_next): the control from ``u`` on that brings the velocities ``rows`` of the next
    state closest to ``v_des`` (weighted by ``w``), and its next state. Gauss-Newton on the
    plant's step with a backtracking search along each step (every trial clipped to the
    effort limits): the step is piecewise smooth in u (contact, and joint limits, which can
    take the step's whole velocity change), so a full Gauss-Newton step can overshoot."""
    nu = dynamics.nu
    xn = dynamics.step(x, u)
    r = w * (xn[rows] - v_des)
    for _ in range(ITERATIONS):
        J = np.empty((len(rows), nu))
        for i in range(nu):
            du = np.zeros(nu)
            du[i] = -FD_STEP if u[i] > 0 else FD_STEP  # inwards: at a limit, + is clipped
            J[:, i] = w * (dynamics.step(x, u + du)[rows] - xn[rows]) / du[i]
        H = J.T @ J
        step = np.linalg.solve(H + 1e-9 * max(float(np.trace(H)), 1e-12) * np.eye(nu), -J.T @ r)
        best = None
        for j in range(SEARCH_STEPS):
            u_try = dynamics.clip_to_limits(u + step * 0.5**j)
            try:
                xn_try = dynamics.step(x, u_try)
            except SimulationError:  # a trial the plant cannot step: a worse one
                continue
            r_try = w * (xn_try[rows] - v_des)
            if r_try @ r_try < (r @ r if best is None else best[2] @ best[2]):
                best = (u_try, xn_try, r_try)
        if best is None:
            break  # no trial lowers the residual: keep u
        done = np.max(np.abs(best[0] - u)) < 1e-6
        u, xn, r = best
        if done:
            break
    return u, xn


def position_guess(task, N: int, x=None, start: int = 0) -> TrackingRollout:
    """The tracking rollout of the task's position guess over N steps from x (default: the
    initial state) at the time of step ``start``; the path starts from the initial state's
    values at t = 0 (a receding-horizon window follows the same path). The last few are
    kept in the task's ``position_guesses``, as a rollout costs many plant steps per time
    step."""
    cfg = task.config
    x = task.x0 if x is None else np.asarray(x, float)
    cache = task.position_guesses
    key = (int(N), int(start), x.tobytes())
    if key not in cache:
        rh = cfg.receding_horizon
        end = (rh.resolves * rh.shift_steps if rh is not None else cfg.steps) * cfg.plant.time_step
        path = WaypointPath(task.dynamics, cfg.initial_guess, end)
        try:
            out = tracking_rollout(
                task.dynamics, path, x, int(N), start * cfg.plant.time_step, task.x0[path.q_idx]
            )
        except SimulationError as e:
            raise ConfigError(f"initial_guess: the tracking rollout failed: {e}") from None
        if len(cache) >= 4:
            cache.pop(next(iter(cache)))
        cache[key] = out
    return cache[key]


def describe(guess) -> str:
    """One line for a position guess (``check``, messages): 'positions: 3 waypoints, period
    0.5 s' or 'positions: target'; a keyword or file name as it is."""
    if isinstance(guess, str):
        return guess
    if guess.target:
        return "positions: a target configuration at the end"
    period = f", repeated every {guess.period:g} s" if guess.period else ""
    return f"positions: {len(guess.waypoints)} waypoints{period}"


def rollout_report(task) -> dict | None:
    """What ``check`` shows of a position guess's tracking rollout over the task's horizon
    (or first window): per tracked coordinate its largest |q − q_ref| and the time of it,
    the unnamed coordinates' first and last values, the largest control per actuator
    relative to its effort limit, and where the path asks each unactuated coordinate it
    names to end against where the rollout took it (``unactuated``). The rollout is on the
    task's own plant (with ``realize``, too: solver/realize.py reports the realization).
    None for another kind of guess."""
    if isinstance(task.config.initial_guess, str):
        return None
    out = position_guess(task, task.steps)
    dyn = task.dynamics
    names = {}
    for name, block in dyn.layout.primitives.items():
        if len(block.coords) == 1 and block.coords[0] < dyn.nq:
            names[block.coords[0]] = name
    err = out.tracking_error()
    dt = task.config.plant.time_step
    tracked = {
        names.get(q, str(q)): {
            "max_error": float(err[:, j].max()),
            "at_s": float(np.argmax(err[:, j]) * dt),
        }
        for j, q in enumerate(out.q_index)
    }
    others = {
        name: [float(out.X[0, q]), float(out.X[-1, q])]
        for q, name in names.items()
        if q not in out.q_index
    }
    unactuated = unactuated_ends(dyn, out, names)
    limits = dyn.effort_limits
    effort = {
        a: float(np.max(np.abs(out.U[:, i])) / limits[i]) if np.isfinite(limits[i]) else None
        for i, a in enumerate(dyn.layout.actuators)
    }
    return {
        "tracked": tracked,
        "others": others,
        "effort_to_limit": effort,
        "unactuated": unactuated,
    }


def unactuated_ends(dyn, out: TrackingRollout, names: dict) -> dict:
    """Per unactuated coordinate the path names: where the path asks it to end
    (``asked``, its reference at the last state) and where the rollout ``out`` took it
    (``reached``), in the coordinate's units."""
    actuated = {j.position_start() for j in _actuated_joints(dyn.plant)}
    return {
        names.get(q, str(q)): {"asked": float(out.Q_ref[-1, j]), "reached": float(out.X[-1, q])}
        for j, q in enumerate(out.q_index)
        if q not in actuated
    }
