"""After the plan's end: the robot holding its last reference and the planning model
extended the same way until the object rests; the PD+ loop's period, its stability check
and the advisories known before a playback runs (``control/playback.py`` uses them)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from pydrake.multibody.tree import JointIndex

from hydroilqr.control.playback_settings import ObjectSpec, PlaybackSettings
from hydroilqr.model.pd import actuated_indices, pd_torque
from hydroilqr.model.plant import Dynamics, SimulationError


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


def _hold_step(dyn, x, u, who: str):
    """One time step of a hold after the plan (quaternions renormalized); a failed step names
    ``who`` ("real system" or "planning model")."""
    try:
        x = dyn.step(x, u)
    except SimulationError as e:
        raise SimulationError(f"{who}, holding after the plan: {e}") from None
    return dyn.layout.normalize(x) if dyn.layout.quaternions else x


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
            break
        if k % every == 0:
            u = pd_torque(hold.u, x[qi], x[vi], hold.q, 0.0, st.kp, st.kd)
            controls += 1
            if st.clip_torques:
                saturated += int(np.count_nonzero(np.abs(u) > limits))
                u = np.clip(u, -limits, limits)
        x = _hold_step(truth, x, u, "real system")
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
        x = _hold_step(dyn, x, u, "planning model")
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
