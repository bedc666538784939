"""Partials kept across trajectories (derivatives.Linearizer) and MPC on a shrinking horizon."""

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.control.mpc import mpc_config, run_mpc
from hydroilqr.model.derivatives import Linearizer, linearize
from hydroilqr.solver.loop import solve


def test_tolerance_zero_is_plain_linearize(cartpole_rollout):
    task, X, U = cartpole_rollout
    lin = Linearizer(task.dynamics, "forward", threads=1)
    A, B = lin(X, U)
    A0, B0 = linearize(task.dynamics, X, U, "forward", threads=1, rollout=True)
    assert np.array_equal(A, A0) and np.array_equal(B, B0)
    assert lin.last_computed == 30
    A1, _ = lin(X, U)  # nothing moved: nothing recomputed, same partials
    assert lin.last_computed == 0 and np.array_equal(A1, A0)


def test_reuse_tolerance_cap_and_shift(cartpole_rollout):
    task, X, U = cartpole_rollout
    dyn = task.dynamics
    lin = Linearizer(dyn, "forward", threads=1, reuse_tolerance=1e-3)
    lin(X, U)
    U2 = U.copy()
    U2[[3, 17]] += 1.0  # two inputs move by far more than the tolerance ...
    U2[5] += 1e-6  # ... one by much less
    X2 = dyn.rollout(task.x0, U2)
    Z, Z2 = np.c_[X[:30], U], np.c_[X2[:30], U2]
    moved = np.max(np.abs(Z2 - Z) / np.maximum(1.0, np.abs(Z2)), axis=1)  # the scaled max norm
    lin(X2, U2)
    assert lin.last_computed == int(np.sum(moved > 1e-3))
    capped = Linearizer(dyn, "forward", threads=1, reuse_tolerance=1e-3, max_steps=2)
    capped(X, U)
    capped(X2, U2)
    assert capped.last_computed == 2
    # After shift(s) the cached partials of step k + s serve step k.
    lin = Linearizer(dyn, "forward", threads=1)
    A, _ = lin(X, U)
    lin.shift(10)
    A_shifted, _ = lin(X[10:], U[10:])
    assert lin.last_computed == 0 and np.array_equal(A_shifted, A[10:])


def test_known_rollout_is_not_recomputed(cartpole_rollout, monkeypatch):
    task, X, U = cartpole_rollout
    problem = task.problem()
    dyn = problem.dynamics
    calls, real = [], dyn.rollout

    def counted(x0, U):
        calls.append(len(U))
        return real(x0, U)

    monkeypatch.setattr(dyn, "rollout", counted)
    a = solve(problem, U, task.config.solver, max_iterations=2, final_gains=False)
    assert calls == [30]  # the initial rollout (the line search rolls out in closed loop)
    b = solve(problem, U, task.config.solver, max_iterations=2, final_gains=False, X0=X)
    assert calls == [30]  # X0 is that rollout: not computed again
    assert np.array_equal(a.X, b.X) and np.array_equal(a.K, b.K)
    X_off = X.copy()
    X_off[0, 0] += 1e-9  # not a rollout from x0: ignored, the rollout is computed
    c = solve(problem, U, task.config.solver, max_iterations=2, final_gains=False, X0=X_off)
    assert calls == [30, 30] and np.array_equal(c.X, a.X)


def test_mpc_shrinking_horizon_on_prediction():
    task = Task.load("kinova-forward", smoke=True)  # 10 steps of 10 ms
    settings = mpc_config(task, duration=0.1, rate=20.0)
    assert settings.shrinking_horizon and settings.derivative_steps_per_update == 1
    res = run_mpc(task, settings)
    s = res.stats()
    assert res.X.shape[0] == 11 and s["updates"] == 1
    # Lock-step, same model, no push: the plant goes exactly where the plan said, so the
    # update starts from the plan's own prediction and differentiates at most one step.
    assert s["updates_on_prediction"] == 1
    assert max(res.derivative_steps) <= 1
    assert set(s["phase_seconds_mean"]) == {
        "rollout",
        "derivatives",
        "backward_pass",
        "line_search",
    }


def test_mpc_warm_start_tail_from_guess():
    """A shifted receding-horizon plan takes its missing last controls from the task's guess
    (the cheetah's standing torques), not from its own end-of-horizon controls."""
    from hydroilqr.control.mpc import Controller, mpc_config

    task = Task.load("cheetah-trot-1.0", smoke=True)
    settings = mpc_config(task, horizon=0.05, iterations_per_update=1)
    assert settings.warm_start_tail == "guess"
    ctrl = Controller(task, 10, settings)
    plan, ok = ctrl.update(task.x0, 0.0, 1, full=True)
    assert ok
    ctrl.update(plan.X[4], 4 * task.dynamics.dt, 0)  # 0 iterations: the shifted warm start
    np.testing.assert_array_equal(ctrl.U[:6], plan.U[4:])
    np.testing.assert_array_equal(ctrl.U[6:], task.initial_guess(4, plan.X[4]))


def test_tail_from_a_multi_row_guess_takes_the_rows_of_its_time_steps(tmp_path):
    """A guess file is a time series: the steps a shifted plan appends get their own rows."""
    from hydroilqr.control.mpc import Controller, mpc_config

    base = Task.load("cheetah-trot-1.0", smoke=True)
    rows = base.initial_guess(1)[0] + 0.01 * np.arange(30)[:, None]  # row k differs from k+1
    guess = tmp_path / "guess.csv"
    np.savetxt(guess, rows, delimiter=",")
    task = Task.load("cheetah-trot-1.0", smoke=True, overrides=[f"initial_guess={guess}"])
    np.testing.assert_array_equal(task.initial_guess(3, start=28), rows[[28, 29, 29]])
    settings = mpc_config(task, horizon=0.05, iterations_per_update=1)
    ctrl = Controller(task, 10, settings)
    plan, ok = ctrl.update(task.x0, 0.0, 1, full=True)
    assert ok
    ctrl.update(plan.X[4], 4 * task.dynamics.dt, 0)
    np.testing.assert_array_equal(ctrl.U[6:], rows[10:14])


def test_shrinking_horizon_longer_than_task_is_a_config_error():
    from hydroilqr.problem.errors import ConfigError

    task = Task.load("kinova-forward", smoke=True)
    with pytest.raises(ConfigError, match="shrinking horizon"):
        run_mpc(task, mpc_config(task, duration=1.0))


def test_interval_interpolates_linearly_between_keypoints():
    from hydroilqr.model.derivatives import keypoints, linearize

    task = Task.load("cartpole-wall", ["horizon=0.6"])
    dyn = task.dynamics
    U = np.zeros((task.steps, dyn.nu))
    X = dyn.rollout(task.x0, U)
    A1, _ = linearize(dyn, X, U, "forward")
    Ai, _ = linearize(dyn, X, U, "forward", interval=4, rollout=True)
    keys = keypoints(dyn, X, task.steps, 4, False)
    k0, k1 = keys[0], keys[1]
    for k in range(k0 + 1, k1):
        s = (k - k0) / (k1 - k0)
        np.testing.assert_allclose(Ai[k], (1 - s) * A1[k0] + s * A1[k1], rtol=1e-12, atol=1e-12)


def test_linearize_at_one_point_gives_one_pair(cartpole_rollout):
    task = cartpole_rollout[0]
    dyn = task.dynamics
    x, u = task.x0, np.array([1.0])
    A, B = linearize(dyn, x, u, "autodiff")
    assert A.shape == (4, 4) and B.shape == (4, 1)
    At, Bt = linearize(dyn, x[None], u[None], "autodiff")
    np.testing.assert_array_equal(A, At[0])
    np.testing.assert_array_equal(B, Bt[0])
    Af, Bf = linearize(dyn, x, 1.0, "central")  # a number for the single actuator
    np.testing.assert_allclose(Af, A, atol=1e-6)
    np.testing.assert_allclose(Bf, B, atol=1e-6)
    with pytest.raises(ValueError, match=r"state x must have shape \[4\]"):
        linearize(dyn, x[:3], u)


@pytest.mark.parametrize("method", ["central", "forward"])
def test_batched_finite_differences_equal_a_per_step_per_column_reference(method):
    """The batched path (every perturbed (x, u) of every step in one Drake call, on 1 or 2
    threads) against the textbook loop: one dyn.step per perturbed column per time step, with
    the same relative steps h_i = eps * max(1, |z_i|). Free flight and the tip in the wall."""
    task = Task.load("cartpole-wall", ["num_steps=5"])
    dyn = task.dynamics
    free = np.array([0.013, 3.52, -0.21, 0.37])
    theta = np.pi + np.arcsin((0.45 - 0.05 + 0.003 - 0.011) / 0.5)
    touching = np.array([-0.011, theta, -0.05, 0.12])
    assert not dyn.contact_surfaces(free) and dyn.contact_surfaces(touching)
    X = np.stack([free, touching, touching])
    U = np.array([[1.3], [-2.1], [0.7]])
    X[2, 2:] += [0.3, -0.4]  # a different velocity at the same pose
    eps, nx = 1e-6, dyn.nx
    A_ref, B_ref = np.empty((3, nx, nx)), np.empty((3, nx, 1))
    for k in range(3):
        z = np.concatenate([X[k], U[k]])
        cols = []
        for i in range(z.size):
            h = eps * max(1.0, abs(z[i]))
            zp, zm = z.copy(), z.copy()
            zp[i] += h
            zm[i] -= h
            fp = dyn.step(zp[:nx], zp[nx:])
            if method == "central":
                cols.append((fp - dyn.step(zm[:nx], zm[nx:])) / (2 * h))
            else:
                cols.append((fp - dyn.step(X[k], U[k])) / h)
        J = np.stack(cols, axis=1)
        A_ref[k], B_ref[k] = J[:, :nx], J[:, nx:]
    for threads in (1, 2):
        A, B = linearize(dyn, X, U, method, eps, threads=threads)
        # The same arithmetic (bitwise equal when written); a few ulp of a state over h allowed.
        np.testing.assert_allclose(A, A_ref, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(B, B_ref, rtol=1e-12, atol=1e-9)
    assert np.abs(A[1] - A[0]).max() > 1e-3  # the contact step's partials differ (the wall)


def test_secant_updates_between_exact_partials(cartpole_rollout):
    """derivative_secant_updates: exact partials, then Broyden updates (no differentiation):
    rank-one changes that satisfy each step's secant equation; then exact again."""
    task, X, U = cartpole_rollout
    dyn = task.dynamics
    lin = Linearizer(dyn, "central", threads=1, secant_updates=2)
    A0, B0 = lin(X, U, rollout=True)
    assert lin.last_computed == 30
    U2 = U + 0.05
    X2 = dyn.rollout(task.x0, U2)
    A1, B1 = lin(X2, U2, rollout=True)
    assert lin.last_computed == 0
    dz = np.c_[X2[:30], U2] - np.c_[X[:30], U]
    J1 = np.concatenate([A1, B1], axis=2)
    np.testing.assert_allclose(np.einsum("kij,kj->ki", J1, dz), X2[1:] - X[1:], atol=1e-10)
    J0 = np.concatenate([A0, B0], axis=2)
    assert all(np.linalg.matrix_rank(d, tol=1e-9) <= 1 for d in J1 - J0)  # rank-one change
    lin(X2, U2 + 0.01, rollout=False)  # not a rollout: exact, and no next states to update
    assert lin.last_computed == 30
    lin(X, U, rollout=True)
    assert lin.last_computed == 30
    lin(X2, U2, rollout=True)  # secant 1 of 2
    lin(X, U, rollout=True)  # secant 2 of 2
    assert lin.last_computed == 0
    lin(X2, U2, rollout=True)
    assert lin.last_computed == 30


def test_solver_with_secant_partials_differentiates_less_and_still_descends():
    """solver.derivative_secant_updates: iterations without differentiation (0 steps, or all
    steps when the secant partials found no step and exact ones were taken), costs decrease."""
    task = Task.load("cartpole-wall", ["num_steps=40", "solver.derivative_secant_updates=2"])
    s = task.config.solver
    U0 = task.initial_guess(task.steps)
    sol = solve(task.problem(), U0, s, max_iterations=6, final_gains=False)
    steps = sol.extra["derivative_steps"]
    assert steps[0] == 40 and 0 in steps
    assert all(n in (0, 40) for n in steps)
    assert sol.costs[-1] < sol.costs[0]
    assert all(b <= a for a, b in zip(sol.costs, sol.costs[1:]))
