"""Finite differences over generalized forces (derivatives._force_differences) against the
plain (x, u) differences they replace."""

from pathlib import Path

import numpy as np
import pytest

from hydroilqr import DerivativeMethod, Task
from hydroilqr.model.derivatives import _finite_differences, linearize
from tests.conftest import needs_tamsi

GRIPPER = str(Path(__file__).parents[2] / "examples" / "gripper-brick.yaml")


def _compare(dyn, X, U, central):
    A1, B1 = _finite_differences(dyn, X, U, central, 1e-6, 1, forces=True)
    A0, B0 = _finite_differences(dyn, X, U, central, 1e-6, 1, forces=False)
    J1, J0 = np.concatenate([A1, B1], axis=2), np.concatenate([A0, B0], axis=2)
    return np.array([np.abs(J1[k] - J0[k]).max() / np.abs(J0[k]).max() for k in range(len(J0))])


def test_cartpole_through_wall_contact():
    task = Task.load("cartpole-wall", overrides=["num_steps=40"])
    dyn = task.dynamics
    assert dyn.force_path() is not None
    U = 8.0 * np.random.default_rng(1).standard_normal((40, 1))
    X = dyn.rollout(task.x0, U)
    assert _compare(dyn, X[:-1], U, central=True).max() < 1e-6
    assert _compare(dyn, X[:-1], U, central=False).max() < 1e-4


def test_cheetah_standing_and_commands_beyond_effort_limits():
    """Four feet in contact, a floating base (quaternion), and two commands beyond their
    effort limits, whose columns of f_u are zero either way (Drake clips)."""
    task = Task.load("cheetah-trot-1.0", smoke=True)
    dyn = task.dynamics
    U = np.tile(task.initial_guess(1)[0], (4, 1))
    U += 0.5 * np.random.default_rng(2).standard_normal(U.shape)
    X = dyn.rollout(task.x0, U)
    U[1, 2] = 3.0 * dyn.effort_limits[2]
    U[3, 5] = -3.0 * dyn.effort_limits[5]
    X = X[:-1]
    assert _compare(dyn, X, U, central=True).max() < 1e-5
    _, B = _finite_differences(dyn, X, U, True, 1e-6, 1, forces=True)
    assert np.all(B[1][:, 2] == 0) and np.all(B[3][:, 5] == 0)


def test_kinova_moving_arm_and_falling_ball():
    """A 7-joint chain moving fast (a full mass matrix, Coriolis terms) and a free ball in the
    air: f_v = G_τ (M/dt − ∂(Cv)/∂v) is then checked on its own, without contact. (With the ball
    at rest on the ground, its spin is held by torsional friction, a steep regularized law where
    differences of either kind are off from AutoDiff by up to 1e-2 on some steps, differently.)"""
    task = Task.load("kinova-forward", smoke=True)
    dyn = task.dynamics
    x0 = task.x0.copy()
    x0[dyn.nq - 1] = 0.6  # ball z
    x0[dyn.nq : dyn.nq + 7] = np.linspace(-1.5, 1.5, 7)  # arm joint velocities, rad/s
    x0[dyn.nq + 7 : dyn.nq + 10] = [0.5, -2.0, 1.0]  # ball spin
    U = task.initial_guess(10) + 0.2
    X = dyn.rollout(x0, U)
    assert not dyn.contact_pairs(X[5])
    assert _compare(dyn, X[:-1], U, central=True).max() < 1e-6


@pytest.mark.parametrize("approximation", ["lagged", "similar"])
def test_other_contact_approximations_use_plain_differences(approximation):
    """Lagged and similar approximations take normal forces at the previous velocity: a step
    is then not a function of the free-motion velocity alone, so (x, u) differences are kept."""
    task = Task.load(
        "cartpole-wall",
        overrides=["num_steps=10", f"plant.contact_approximation={approximation}"],
    )
    assert task.dynamics.force_path() is None
    U = np.ones((10, 1))
    X = task.dynamics.rollout(task.x0, U)
    A, B = linearize(task.dynamics, X, U, "central")
    A0, B0 = _finite_differences(task.dynamics, X[:-1], U, True, 1e-6, 0, forces=False)
    assert np.array_equal(A, A0) and np.array_equal(B, B0)


@needs_tamsi
def test_damped_joints_under_sap_but_not_under_tamsi():
    """Drake's planar gripper has damped finger joints (0.1 N m s). SAP applies the damping
    implicitly and the differences over forces match; TAMSI does not, and keeps (x, u)."""
    task = Task.load(GRIPPER, overrides=["num_steps=10"])
    dyn = task.dynamics
    assert dyn.force_path() is not None
    U = task.initial_guess(10) + 0.3 * np.random.default_rng(0).standard_normal((10, dyn.nu))
    X = dyn.rollout(task.x0, U)
    assert any(dyn.contact_pairs(x) for x in X)
    assert _compare(dyn, X[:-1], U, central=True).max() < 1e-6
    tamsi = Task.load(
        GRIPPER,
        overrides=["num_steps=10", "plant.contact_approximation=tamsi"],
    )
    assert tamsi.dynamics.force_path() is None


def test_rollout_next_states_serve_as_the_unperturbed_steps():
    """Forward differences reuse a rollout's next states as f(x_k, u_k); through the force
    input the unperturbed step is bitwise the actuation input's, so both give the same partials."""
    task = Task.load("cartpole-wall", overrides=["num_steps=30", "solver.fd_forces=true"])
    dyn = task.dynamics
    U = 6.0 * np.random.default_rng(4).standard_normal((30, 1))
    X = dyn.rollout(task.x0, U)
    forces = task.config.solver.fd_forces  # (passed explicitly: the plant knows no solver)
    A1, B1 = linearize(dyn, X, U, "forward", rollout=True, fd_forces=forces)
    A0, B0 = linearize(dyn, X, U, "forward", rollout=False, fd_forces=forces)
    assert np.array_equal(A1, A0) and np.array_equal(B1, B0)


def test_check_reports_the_steps_per_time_step():
    from hydroilqr.studies.check import check_task

    grip = check_task(Task.load(GRIPPER, overrides=["num_steps=10"]), rollout_steps=3)
    assert grip["fd_steps_per_time_step"] == 18  # nq + nv = 9 + 9, not nx + nu = 24
    lagged = Task.load(
        "cartpole-wall",
        overrides=["num_steps=10", "solver.fd_forces=true", "plant.contact_approximation=lagged"],
    )
    assert check_task(lagged, rollout_steps=3)["fd_steps_per_time_step"] == 5


def test_autodiff_matches_central_differences_in_and_out_of_contact(cartpole):
    dyn = cartpole.dynamics
    # Out of contact, then the tip pressed ~3 mm into the wall (generic, non-symmetric poses).
    free = np.array([0.013, 3.52, -0.21, 0.37])
    theta = np.pi + np.arcsin((0.45 - 0.05 + 0.003 - 0.011) / 0.5)
    touching = np.array([-0.011, theta, -0.05, 0.12])
    assert not dyn.contact_surfaces(free)
    assert dyn.contact_surfaces(touching), "the tip should touch the wall"
    X = np.stack([free, touching, touching])
    U = np.array([[1.3], [-2.1], [0.7]])
    A_ad, B_ad = linearize(dyn, X, U, DerivativeMethod.AUTODIFF)
    A_fd, B_fd = linearize(dyn, X, U, DerivativeMethod.CENTRAL)
    for k in range(2):
        J_ad = np.hstack([A_ad[k], B_ad[k]])
        J_fd = np.hstack([A_fd[k], B_fd[k]])
        err = np.max(np.abs(J_ad - J_fd)) / np.max(np.abs(J_ad))
        assert err < 1e-4, f"step {k}: relative error {err:.2e}"
    # Contact changes the partials (the wall is felt).
    assert np.max(np.abs(A_ad[1] - A_ad[0])) > 1e-3


def test_forward_differences_close_to_autodiff(cartpole):
    dyn = cartpole.dynamics
    X = np.array([[0.02, 3.3, 0.1, -0.2]])
    U = np.array([[0.5]])
    A_ad, B_ad = linearize(dyn, X, U, "autodiff")
    A_fw, B_fw = linearize(dyn, X, U, "forward")
    assert np.max(np.abs(A_ad - A_fw)) / np.max(np.abs(A_ad)) < 1e-4
    assert np.max(np.abs(B_ad - B_fw)) / np.max(np.abs(B_ad)) < 1e-4
