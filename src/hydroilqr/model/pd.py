"""The PD+ law of a joint controller: one function for playback and the search's position space.

    τ = ū − Kp (q_J − q̄_J) − Kd (v_J − v̄_J)        (paper eq. 11)

on the actuated joints J, with the feed-forward ū, the reference positions q̄_J and velocities
v̄_J. ``control/playback.py`` executes a plan with it (ū the plan's torque, the reference the
plan's states); the sampling search's ``position`` space (``solver/search.py``) rolls a spline
of joint position targets out through it (``pd_rollout``: ū gravity compensation), so a plan
found in that space is what a joint controller executes.
"""

from __future__ import annotations

import numpy as np

from hydroilqr.model.plant import SimulationError


def pd_torque(u_ff, q, v, q_ref, v_ref, kp: float, kd: float) -> np.ndarray:
    """τ = u_ff − kp (q − q_ref) − kd (v − v_ref). u_ff, q, v, q_ref, v_ref: [nu] (v_ref may
    be 0) -> [nu]; not clipped (the caller clips to the effort limits, as a drive does)."""
    return u_ff - kp * (q - q_ref) - kd * (v - v_ref)


def actuated_indices(plant) -> tuple[np.ndarray, np.ndarray]:
    """Indices into x of the actuated joints' positions and velocities (any joint type), in
    actuator order."""
    qi, vi = [], []
    for i in plant.GetJointActuatorIndices():
        j = plant.get_joint_actuator(i).joint()
        qi += range(j.position_start(), j.position_start() + j.num_positions())
        vi += range(
            plant.num_positions() + j.velocity_start(),
            plant.num_positions() + j.velocity_start() + j.num_velocities(),
        )
    return np.array(qi, int), np.array(vi, int)


def damping_bounds(plant, x, dt: float) -> np.ndarray:
    """The largest damping the PD+ law, held over a step of ``dt``, keeps stable on each
    actuated joint moving freely: kd < 2 I_j / dt, with I_j = 1 / (M⁻¹)_jj the joint's
    effective inertia at the state x (the mass matrix, reflected rotor inertia included, from
    Drake). Above it a joint out of contact overshoots its own damping each step and rings to
    its effort limit. x: [nx] -> [nu], in actuator order."""
    ctx = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(ctx, np.asarray(x, float))
    m_inv = np.linalg.inv(plant.CalcMassMatrix(ctx))
    _, vi = actuated_indices(plant)
    j = vi - plant.num_positions()
    return 2.0 / (np.diag(m_inv)[j] * dt)


def reference_velocities(Q_ref: np.ndarray, dt: float) -> np.ndarray:
    """v̄_k = (q̄_{k+1} − q̄_k) / dt: Q_ref [N+1, n] -> [N, n] (the reference's own motion)."""
    Q_ref = np.asarray(Q_ref, float)
    return np.diff(Q_ref, axis=0) / dt


def pd_rollout(dynamics, x0, Q_ref, kp: float, kd: float):
    """The plant driven by the PD+ law towards joint position targets. x0: [nx], Q_ref:
    [N+1, nu] targets of the actuated joints at each step's time -> X: [N+1, nx], U: [N, nu],
    with u_k = clip(pd_torque(g(x_k), q_k, v_k, q̄_k, v̄_k, kp, kd)), g the gravity
    compensation at x_k and v̄ from ``reference_velocities``. Raises SimulationError naming
    the step that failed."""
    Q_ref = np.asarray(Q_ref, float)
    qi, vi = actuated_indices(dynamics.plant)
    if Q_ref.ndim != 2 or Q_ref.shape[1] != len(qi):
        raise ValueError(f"Q_ref must have shape [N+1, {len(qi)}], got {Q_ref.shape}")
    V_ref = reference_velocities(Q_ref, dynamics.dt)
    N = V_ref.shape[0]
    X = np.empty((N + 1, dynamics.nx))
    U = np.empty((N, dynamics.nu))
    X[0] = x0
    for k in range(N):
        x = X[k]
        u = pd_torque(dynamics.gravity_compensation(x), x[qi], x[vi], Q_ref[k], V_ref[k], kp, kd)
        U[k] = dynamics.clip_to_limits(u)
        try:
            X[k + 1] = dynamics.step(x, U[k])
        except SimulationError as e:
            raise SimulationError(f"step {k}: {e}") from None
    return X, U
